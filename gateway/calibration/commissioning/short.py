"""``compgw commission`` on a short budget (:mod:`.identify` and :mod:`.fit` ask it):
whether the budget is short, and the plane's first grid, which on a short budget no
round will refine.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import numpy as np

from ..fitting import adaptive
from ..fitting.fit import one_way_split
from ..fitting.iso230 import iso230_axis
from ..fitting.outputs import scanned_cyclic
from ..fitting.table_cv import between_points, denser_miss, denser_pays, levelled_midpoints
from ..fitting.takeup_fit import MIN_LOST_UM
from ..plans.plans import Plan, backlash_plan
from ..plans.rawdata import RawData, axis_deviations, pooled_variance
from ..plans.runner import read_raw_meta
from ..plans.xy import even_grid
from .planner import BETWEEN, EIGHTHS, QUARTERS, cyclic_scans, steps_below
from .sizing import DENSE_LEAST_RUNS, fitting_grid, hold_each, max_grid_in
from .steps import concat_raw

if TYPE_CHECKING:
    from ...compensation.cyclic import CyclicModel
    from .axes import Axes
    from .budget import Budget
    from .planner import Planner
    from .record import Record
    from .refine import RefineSteps
    from .steps import StepRunner

Say = Callable[[str], None]

#: readings of the drift references at config switches on a short budget (the start, the
#: tables loaded for the plane, back without them, the after-run's)
SWITCH_READINGS = 4
#: a short budget's table is read at its midpoints too where it misses between its points
#: by more than this many times what its own scatter explains (as a reversal per point)
BETWEEN_RATIO = 2.0
#: nodes along the longer travel of a grid the size of a plain calibration's (9 x 7)
PLAIN_GRID_LINES = 9
#: runs per target of the quarter or eighth points read in place of a table's more runs
#: (:meth:`ShortBudget._denser_first`)
RUNS_IN_PLACE = 1




class ShortBudget:
    """What a budget short of the first steps and one round changes in the plan."""

    def __init__(self, axes: Axes, record: Record, budget: Budget, runner: StepRunner,
                 plans: Planner, refine: RefineSteps, say: Say) -> None:
        self.s = axes.s
        self.axes = axes
        self.record = record
        self.budget = budget
        self.runner = runner
        self.plans = plans
        self.refine = refine
        self.say = say

    def applies(self) -> bool:
        """Whether the budget does not hold the first steps, the before- and after-runs and
        one round (:meth:`first_need_s`; decided once, kept in the state): the rounds
        would then verify what they cannot afford to refine (at 2 x a manual calibration's
        time sdss-1396 took the normal order, its lead searches and a round with nothing
        added, and ended on a 7 x 5 grid: E cut −36 %, against 54 % at 1.5 x, short).
        Then a plain ISO 230-2 calibration's steps come
        first (every linear axis's ISO runs, its cyclic scans where its lead is known and
        the plane's grid still fits, the plane's grid with their tables on), then the
        after-runs that judge them and the backlash tests, and the lead searches last, so
        that a budget spent on the way leaves each axis a table
        (:meth:`.fit.FitSteps.fit_identified`) and the plane its model, not one axis a
        verified table and the others none."""
        if "short" not in self.record.state:
            self.record.state["short"] = bool(self.first_need_s() > self.s.budget_s)
            self.record.save()
        return bool(self.record.state["short"])

    def refs_affordable(self) -> bool:
        """Whether the drift references are read (decided once, before the first, kept in
        the state; said when not): on a short budget, only where it holds a plain
        calibration's steps (:meth:`plain_steps`, its 5 runs included, and on an axis
        whose lead is not known its table's midpoints, :meth:`densify`) with them (around
        every run, at every config switch). They are an identification extra: a plain
        calibration's tables are worth more than a drift taken off them. (At the plain
        calibration's 7.8 minutes, mcu1025's references took 2.4 minutes and Y got no
        table: E cut 2 % against 69 %; at its 0.6 h, the random machines' references left
        no room for Y's cyclic scans, Y E cut 65 % against 94 %, and held beside a table
        at 3 runs, rough-3's left it 2 runs, E 1.98 µm at the judge's targets against the
        plain calibration's 1.24. At 1.5 x its time sdss-1396's references, 5.3 minutes,
        read no heat, and the midpoints they had not counted took its fifth run: Y E cut
        43 % at the judge's targets against 61 % at 1 x. The midpoints of an axis whose
        lead is known are an extra after them: counted here, they turned the references off
        at 1.5 x, and with them the heat-from-motion models: smooth-0's XY cut 98 → 94 %,
        smooth-2's 97 → 92 %.)
        Nor where every axis keeps its own sensor (:meth:`.drift.DriftRefs.sensor_kept`):
        its compensation levels the readings, the references' drift is never taken off
        them, and a short budget's references would only log it. (At 1.5 x the plain
        calibration's time the temperature machines' references took 11 of their 51-57
        minutes; without them rough-4 and rough-9 read a zone warm-up of X, whose heat from
        motion replaced its sensor: 30.6 → 5.1 and 49.4 → 6.2 µm of heat left at the
        judge's warm-up, one judge.)"""
        state = self.record.state
        if "refs_off" not in state:
            off = False
            if self.applies():
                linear = [a for a in self.s.axes if not self.axes.rotary(a)]
                steps = self.plain_steps(linear)
                plain = [p for _, p in steps] + [  # and the midpoints it may read
                    p for n, p in steps
                    if n.startswith("iso-") and n.removeprefix("iso-") not in self.s.lead_mm]
                bare_s = sum(self.axes.estimate_s(p) for p in plain)
                refs_s = (sum(self.budget.refs_worst_s(p) for p in plain)
                          + SWITCH_READINGS * self.budget.refs_once_s())  # fmt: skip
                off = bool(linear) and self.s.budget_s < bare_s + refs_s
                kept = bool(linear) and all(self.runner.drift.sensor_kept(a) for a in linear)
                note = None
                if off:
                    note = ("no drift references: " + (
                        f"with them ({refs_s / 60:.1f} min) the budget does not hold"
                        if bare_s <= self.s.budget_s else "the budget does not hold even")
                        + " a plain calibration's steps (ISO runs, cyclic scans"
                        + (", the plane's grid" if self.axes.plane_with(linear) else "")
                        + "); the tables keep the drift while measuring")  # fmt: skip
                elif kept:
                    off = True
                    note = ("no drift references: every axis keeps its own sensor, read with "
                            "its compensation on, and nothing is taken off its readings; "
                            f"their {refs_s / 60:.1f} min go to the steps after the plain "
                            "calibration's")  # fmt: skip
                if note is not None and self.record.note(note):
                    self.say(note)
            state["refs_off"] = off
            self.record.save()
        return not state["refs_off"]

    def plain_points(self, axes: list[str]) -> dict[str, int]:
        """Each axis's targets in a plain calibration's table
        (:func:`..fitting.adaptive.plain_points`): one every 25 mm where the axis's lead is
        known (its cyclic scans read the once-per-lead error, the table the long waves), at
        least the coarse table's 21 where it is not (the table reads the short waves
        itself); none where every axis's is the coarse table's. (At 1 x a plain
        calibration's time smooth-2's 150 mm Y read 21 targets at 2 runs, its reversal
        noisy: 0.74 µm left on the quiet machine against the plain calibration's 7 targets
        at 5 runs, 0.25 µm.)"""
        dense = {a: adaptive.plain_points(self.axes.travel(a), adaptive.ISO_LEAST_POINTS
                                          if a in self.s.lead_mm else adaptive.COARSE_POINTS)
                 for a in axes}  # fmt: skip
        return dense if any(n != adaptive.COARSE_POINTS for n in dense.values()) else {}

    def plain_steps(self, linear: list[str], runs: int | None = None
                    ) -> list[tuple[str, Plan]]:  # fmt: skip
        """A plain ISO 230-2 calibration's steps on ``linear``, named as the steps that read
        them: each axis's table at its targets (:meth:`plain_points`) and ``runs`` runs
        (default :meth:`table_runs`), its cyclic scans where its lead is known, the
        plane's grid of a plain calibration's nodes (:meth:`plain_grid`) where the axes
        make one. What a short budget buys before any extra."""
        dense = self.plain_points(linear)
        steps = [(f"iso-{a}", self.plans.iso_plan(a, runs or self.table_runs(), dense.get(a)))
                 for a in linear]  # fmt: skip
        steps += [(f"cyclic-{a}", cyclic_scans(a, self.axes.travel(a), self.s.lead_mm[a]))
                  for a in linear if a in self.s.lead_mm]  # fmt: skip
        if self.axes.plane_with(linear):
            steps.append(("xy-grid", self.plans.grid_plan(self.plain_grid())))
        return steps

    def table_runs(self) -> int:
        """Runs per target a short budget's table is read at in the end, where the budget
        holds them: a plain calibration's (``adaptive.PLAIN_RUNS``), or the configured runs
        where more. The first runs are the configured ones at most (3: a round would verify
        and refine them); the rest come after the midpoints and the cyclic scans
        (:meth:`more_runs`), which buy more where the table misses (slit-11358's Y misses 46
        times its scatter between its points; read at 5 runs first, its midpoints no longer
        fitted beside the plane's grid)."""
        return max(self.s.runs, adaptive.PLAIN_RUNS)

    def first_runs(self, axes: list[str]) -> int:
        """Runs per target of the first ISO runs on a short budget: the configured runs;
        the rest of a plain calibration's (:meth:`table_runs`) after the midpoints
        (:meth:`densify`, :meth:`more_runs`), which buy more where the table misses between
        its points. The more runs are pooled with the first as read, and the midpoints are
        put on the level of both (:meth:`iso_raw`; more runs mixed as read beside midpoints
        on the first runs' level mixed two heats: rough-3's X table, 1.72 µm left on the
        quiet machine against the plain calibration's 1.09)."""
        return self.s.runs

    def plain_grid(self) -> tuple[int, int]:
        """A grid of a plain calibration's nodes (its 9 x 7: 9 along the longer travel, 7
        across or more where the cells would be longer than wide, fewer on a square
        plane), or the configured one where denser. (9 x 9 on rough-3's square plane cost
        it a fifth ISO run at 1 x a plain calibration's time. With square cells smooth-2's
        900 x 150 mm plane read 10 x 5 nodes and rough-0's 9 x 6: their Y, read at random
        places of X, 1.64 and 1.66 µm at the judge's targets over three readings, the
        plain calibration's 9 x 7 0.96 and 1.28.)"""
        (x0, x1), (y0, y1) = self.axes.plane_travel()
        even = even_grid(x1 - x0, y1 - y0, lines=PLAIN_GRID_LINES, least=PLAIN_GRID_LINES - 2)
        nodes = 1.05 * PLAIN_GRID_LINES * (PLAIN_GRID_LINES - 2)  # (8 x 8 on a square plane)
        even = fitting_grid(even, lambda g: float(g[0] * g[1]), nodes) or even
        return even if even[0] * even[1] > self.s.grid[0] * self.s.grid[1] else self.s.grid

    def scans_left_s(self, axes: list[str]) -> float:
        """Machine time (s) of the cyclic scans not made yet on ``axes`` whose lead is
        known, with the drift references a drift would call for."""
        return sum(self.budget.step_cost_worst_s(
            cyclic_scans(a, self.axes.travel(a), self.s.lead_mm[a]))
            for a in axes if a in self.s.lead_mm and not self.record.done(f"cyclic-{a}"))

    def plane_held_s(self, plain: bool = True) -> float:
        """Machine time (s) a short budget holds for the plane when it decides a step before
        the plane's grid, if not made yet (none without a plane): a grid of a plain
        calibration's nodes (:meth:`plain_grid`), or with ``plain`` False the configured
        one (the least: where the table's reading is decided, whose targets matter more
        than the grid's nodes; at 0.13 h slit-11358 held a 9 x 9 grid and read 8 targets
        instead of 21: E 46 µm at the judge's targets against 9). The plane's random
        points, read before and after, are its verdict: an extra, bought after a plain
        calibration's steps."""
        if self.s.planar is None or self.record.done("xy-grid"):
            return 0.0
        grid = self.plain_grid() if plain else self.s.grid
        return self.budget.step_cost_s(self.plans.grid_plan(grid))

    def verdict_held_s(self, room_s: float) -> float:
        """Machine time (s) an extra decided before the plane's verdict holds for it: its
        random points read before and after, where ``room_s`` (the budget left beside what
        is held already) holds them; none where it does not, or where they were read.
        Held for a verdict that will not fit, the time buys nothing: at 1.5 x the plain
        calibration's time rough-8 held 18.2 minutes for it, left X's eighth points unread
        (their table missed 2.44 µm RMS between its points, 9.4 x its scatter), and then
        had no room for the verdict either."""
        if self.s.planar is None or self.record.done("before-xy"):
            return 0.0
        need_s = self.budget.verdict_cost_s(self.plans.before_xy_plan())
        return need_s if need_s <= room_s else 0.0

    def first_need_s(self) -> float:
        """Machine time (s) of the first steps, the before- and after-runs and one round:
        its verification (the before-run's size) and the least refinement it may call for
        (each linear axis swept at its coarsest step, the plane's grid split once), each
        with the drift references read around its runs."""
        plans = [p for _, p in self.plans.initial_plans(heat=False)]
        for a in [a for a in self.s.axes if not self.axes.rotary(a)]:  # (no ISO runs yet)
            plans += 3 * [self.plans.before_plan(a, avoid_mm=np.zeros(0))]
            plans.append(self.refine.sweep_plan(a, -1, self.s.lead_mm.get(a), estimate=True))
        if self.s.planar is not None:
            plans += 3 * [self.plans.before_xy_plan()]
            plans.append(self.plans.grid_plan(adaptive.denser_grid(*self.s.grid)))
        return sum(self.axes.estimate_s(p) + (0.0 if p.kind == "warmup" else
                                              self.budget.refs_around_s(p))
                   for p in plans)  # (a warm-up reads no drift references)

    async def densify(self, axis: str, level: int = 0) -> None:
        """On a short budget, whose rounds will not sweep a table between its points: the
        ISO runs again at the midpoints of the first table's points where that table misses
        between them by more than BETWEEN_RATIO times what its scatter explains
        (:func:`..fitting.table_cv.between_points`), at as many of the first table's
        runs as the budget left holds (down to DENSE_LEAST_RUNS) beside the plane's grid.
        Decided once.

        - Lead not known: first, beside the plane's configured grid (at 1.5 x a manual
          calibration's time slit-11358's Y kept a dip of 3.5 µm over 2 mm between two of
          its points: E 4.4 µm at the judge's targets, its scatter 0.3 µm).
        - Lead known: after its cyclic scans, the points judged net of the once-per-lead
          term they read (a table every few leads reads it at one phase, its midpoints at
          another), at DENSE_LEAST_RUNS, beside a plain calibration's grid, before the
          table's last runs (:meth:`more_runs`; they cost about as much), the axis that
          misses most per minute first (:meth:`by_value`). (At 1.5 x rough-9's X, waviness
          of 15-80 mm, missed 1.6 µm RMS between its points 25 mm apart against a scatter
          of 0.23 µm: E 3.33 µm at the judge's targets, a perfect table 0.80. At 1 x, held
          behind the last runs and the plane's verdict, no midpoints fitted: rough-3's Y
          read 7.21 µm at the judge's targets, 1.34 with them in place of its last runs.)
          No scans read: none (the term would alias).
        - ``level`` QUARTERS: the quarter points, where the table with its midpoints (and its
          more runs) still misses between its points so, at DENSE_LEAST_RUNS: an extra
          after a plain calibration's steps, held behind its grid and the plane's verdict.
        - ``level`` EIGHTHS: the eighth points, where the table with its quarter points still
          misses so: the same extra, after the quarter points and the more runs. (On the
          quiet machine a perfect point between every two of rough-8's table points, its
          quarter points read, took E at random parks from 4.53 to 2.80 µm on X and 2.09
          to 1.24 on Y, with a reading's noise; its quarter points missed 9.5 and 2.2 x
          their scatter.)"""
        if not self._decidable(axis, level):
            return
        known = axis in self.s.lead_mm
        ident = self.record.state.setdefault("identify", {})  # (the report lists it)
        names = BETWEEN[level]
        key, what = names.key(axis), names.what
        if key not in ident:
            ratio, miss_um = self.between(axis, level)
            keep_s = 0.0
            if self.s.planar is not None and axis in self.s.planar:
                keep_s = self.plane_held_s(plain=known or level > 0)
                if level > 0:  # and the plane's verdict, where it fits
                    keep_s += self.verdict_held_s(self.budget.left_s() - keep_s)
            misses = ratio is not None and ratio > BETWEEN_RATIO
            runs = self._midpoint_runs(axis, keep_s, level) if misses else 0
            ident[key] = {"misses_x_scatter": ratio, "miss_rms_um": miss_um,
                          "measured": bool(runs), "runs": runs}
            if misses:
                need_s = self.budget.step_cost_worst_s(
                    self.plans.midpoints_plan(axis, DENSE_LEAST_RUNS, level))
                net = " (net of its once-per-lead error)" if known else ""
                where = "beside the plane's grid" if keep_s > 0.0 else "in the budget left"
                self.say(f"{axis}: {names.table} misses {miss_um:.2f} µm RMS between its "
                         f"points, {ratio:.1f} x what its scatter explains{net}: " + (
                             f"its {what} read too, {runs} runs each" if runs else
                             f"its {what} ({need_s / 60:.1f} min at {DENSE_LEAST_RUNS} runs) "
                             f"do not fit {where}"))  # fmt: skip
            self.record.save()
        if ident[key]["measured"]:  # (an older state keeps no runs: the first table's)
            runs = ident[key].get("runs")
            await self.runner.step(f"{names.step}-{axis}",
                                   lambda: self.plans.midpoints_plan(axis, runs, level),
                                   "off", self.axes.park(axis))  # fmt: skip

    def decided(self, axis: str, level: int) -> dict[str, Any]:
        """What was decided of the points ``axis`` reads between its table's at ``level``
        (its identification record; empty before)."""
        return self.record.state.get("identify", {}).get(BETWEEN[level].key(axis)) or {}

    def _decidable(self, axis: str, level: int = 0, before_more: bool = False) -> bool:
        """Whether the midpoints of ``axis`` can be decided: its first table read, and
        where its lead is known its cyclic scans too (the term its points are judged net
        of); its quarter points, once its midpoints were read and its more runs decided;
        its eighth points, once its quarter points were read."""
        if level > 0:
            return bool(self.decided(axis, level - 1).get("measured")) and (
                before_more or "more_runs" in self.record.state.get("identify", {}))
        return axis not in self.s.lead_mm or self.record.done(f"cyclic-{axis}")

    def between(self, axis: str, level: int = 0) -> tuple[float | None, float | None]:
        """How much the first table of ``axis`` misses between its points (at ``level`` 1
        and 2, what the table through its points and midpoints, or through those and its
        quarter points, is expected to,
        :func:`..fitting.table_cv.denser_miss`): over what its
        scatter explains, and in µm RMS (:func:`..fitting.table_cv.between_points`, net of
        the once-per-lead term where its scans were read); None, None where it cannot say.
        Along the curve the table will be read along, as the quarter points are judged:
        at 1 x a plain calibration's time smooth-2's Y, 7 points over 150 mm rising 10 µm
        in its last 20 mm, missed 2.31 µm RMS between them along straight lines, 6.5 x its
        scatter, and read its midpoints; the spline through the 7 misses 0.34 µm (1.0 x),
        and the table with the midpoints, levelled, read E 84.5 % over four judges against
        the plain calibration's 88.7 %."""
        if level > 0:  # the points read before the last level's
            first_mm = np.concatenate([self.runner.raw(f"{n}-{axis}").target_mm
                                       for n in steps_below(level - 1)])  # fmt: skip
            found = denser_miss(axis_deviations(self.iso_raw(axis), axis), first_mm,
                                self.scanned(axis))  # fmt: skip
        else:
            found = between_points(axis_deviations(self.runner.raw(f"iso-{axis}"), axis),
                                   self.scanned(axis), curves=True)  # fmt: skip
        return (None, None) if found is None else (found[0], found[1] * 1e3)

    def by_value(self, axes: list[str], level: int = 0,
                 before_more: bool = False) -> list[str]:  # fmt: skip
        """``axes`` in the order what they read between their points at ``level`` buys most per
        machine-minute: what the table misses between its points (µm RMS) over their time
        at DENSE_LEAST_RUNS. Those that cannot be decided yet (lead known, no scans read;
        no midpoints read; the more runs not decided, unless ``before_more``) or are
        decided already keep their place at the end. (In axis order rough-9's X, missing
        1.55 µm, took the time Y's, missing 2.84 µm, needed.)"""
        def value(a: str) -> float:
            if self.decided(a, level) or not self._decidable(a, level, before_more):
                return -1.0
            miss_um = self.between(a, level)[1] or 0.0
            cost_s = self.budget.step_cost_s(
                self.plans.midpoints_plan(a, DENSE_LEAST_RUNS, level))
            return miss_um / max(cost_s, 1.0)

        return sorted(axes, key=value, reverse=True)

    def _midpoint_runs(self, axis: str, keep_s: float, level: int = 0) -> int:
        """The most runs per target at which the midpoints of ``axis`` fit in the budget
        left beside ``keep_s``, 0 where none fit: the first table's down to
        DENSE_LEAST_RUNS where the lead is not known (more runs follow on the first
        targets), DENSE_LEAST_RUNS where it is (the first table's runs read the scatter
        and the reversal; the midpoints read the waves between, and leave room for the
        other axis's: at 4 runs rough-9's X left Y's none)."""
        known = axis in self.s.lead_mm or level > 0
        most = DENSE_LEAST_RUNS if known else self.budget.iso_runs()
        for runs in range(most, DENSE_LEAST_RUNS - 1, -1):
            need_s = self.budget.step_cost_worst_s(
                self.plans.midpoints_plan(axis, runs, level))
            if self.budget.left_s() - need_s >= keep_s:
                return runs
        return 0

    async def more_runs(self, axes: list[str]) -> None:
        """On a short budget, after the first ISO runs and the cyclic scans and before the
        plane's grid: the ISO runs again on the same targets, as many more (up to
        :meth:`table_runs`) as the budget left holds beside the scans not made yet and a
        plane's grid of a plain calibration's nodes: a plain calibration's steps before
        any extra, the verdict's before- and after-runs included. (At 1 x its time,
        holding the verdict first, smooth-0 read 4 runs and then had no room for the
        verdict after all; rough-3 read 2; the plain calibration reads 5: E 0.83 and 1.98
        µm at the judge's targets against 0.56 and 1.24.) An axis whose quarter points take
        more off per reading reads them in their place (:meth:`_denser_first`). Decided
        once."""
        ident = self.record.state.setdefault("identify", {})
        if "more_runs" not in ident:
            first = self.budget.iso_runs()
            plane = self.axes.plane_with(axes)
            held_s = (self.plane_held_s() if plane else 0.0) + self.scans_left_s(axes)
            room_s = self.budget.left_s() - held_s
            room_s -= self._denser_first(axes, room_s, QUARTERS)
            rest = [a for a in axes if a not in self._in_place(axes)]
            more = self._more_that_fit(rest, room_s)
            ident["more_runs"], ident["more_runs_axes"] = more, rest
            if more:
                self.say(f"{', '.join(rest)}: {more} more ISO run(s) on the same targets "
                         f"({first + more} in all): the budget holds them"
                         + (" beside the plane's grid" if plane else ""))  # fmt: skip
            self.record.save()
        for a in self._in_place(axes):  # the quarter points read in place of the more runs
            await self.densify(a, QUARTERS)
        await self._read_more(ident.get("more_runs_axes", axes), int(ident["more_runs"]))

    async def more_runs_later(self, axes: list[str]) -> None:
        """The more runs of the axes that read their quarter points in their place
        (:meth:`_denser_first`), as an extra after the quarter points: where the budget
        left holds them beside the scans not made yet, a plain calibration's grid and the
        plane's verdict (so a larger budget reads at least what a smaller one did: before,
        at 3 x a plain calibration's time the rough machines read both). An axis whose
        eighth points take more off per reading reads them in their place, in turn (at 1.5
        x rough-8's X read a 4th run on its 41 targets, 184 s, where its table with its
        quarter points missed 2.44 µm RMS between them, 9.3 x its scatter: E 3.41 µm at the
        judge's targets, A − R 3.13). Decided once."""
        ident = self.record.state.setdefault("identify", {})
        if "more_runs_later" not in ident:
            keep_s = self.scans_left_s(axes)
            if self.axes.plane_with(axes):
                keep_s += self.plane_held_s()
                keep_s += self.verdict_held_s(self.budget.left_s() - keep_s)
            room_s = self.budget.left_s() - keep_s
            in_place = self._in_place(axes)
            room_s -= self._denser_first(in_place, room_s, EIGHTHS)
            later = [a for a in in_place if a not in self._in_place(in_place, EIGHTHS)]
            more = self._more_that_fit(later, room_s)
            ident["more_runs_later"], ident["more_runs_later_axes"] = more, later
            if more:
                self.say(f"{', '.join(later)}: {more} more ISO run(s) on the same targets "
                         "after the quarter points: the budget holds them")
            self.record.save()
        for a in self._in_place(axes, EIGHTHS):  # the eighth points in place of the more runs
            await self.densify(a, EIGHTHS)
        await self._read_more(ident["more_runs_later_axes"], int(ident["more_runs_later"]))

    async def _read_more(self, axes: list[str], more: int) -> None:
        """``more`` more ISO runs on the first targets of each of ``axes`` (none at 0)."""
        for a in axes if more else ():
            await self.runner.step(f"iso-more-{a}", lambda a=a: self.plans.more_runs_plan(a, more),
                                   "off", self.axes.park(a))  # fmt: skip

    def _in_place(self, axes: list[str], level: int = QUARTERS) -> list[str]:
        """Those of ``axes`` that read their quarter (``level`` EIGHTHS: eighth) points in
        place of their more runs (:meth:`_denser_first`)."""
        return [a for a in axes if self.decided(a, level).get("instead_of_more_runs")]

    def _both_fit(self, axes: list[str], room_s: float, level: int = QUARTERS) -> bool:
        """Whether ``room_s`` (s) holds every axis's more runs and, after them, the quarter
        (``level`` EIGHTHS: eighth) points of each whose points of the level before were
        read, at DENSE_LEAST_RUNS, beside the plane's verdict: then both are read, the
        denser points as the extra they are, and none takes the other's place. (At 3 x a
        plain calibration's time, read at one run in place of the more runs and the more
        runs after them, rough-3's and rough-9's Y read 2.13 → 4.31 and 2.53 → 4.26 µm at
        the judge's targets.)"""
        need_s = sum(self.budget.step_cost_worst_s(self.plans.more_runs_plan(
            a, self.table_runs() - self.budget.iso_runs())) for a in axes)
        need_s += sum(self.budget.step_cost_worst_s(self.plans.midpoints_plan(
            a, DENSE_LEAST_RUNS, level)) for a in axes
            if self.decided(a, level - 1).get("measured"))  # fmt: skip
        if self.axes.plane_with(axes):
            need_s += self.verdict_held_s(room_s)
        return need_s <= room_s

    def more_runs_left_s(self, axes: list[str]) -> float:
        """Machine time (s) of the runs that bring each of ``axes``'s table to a plain
        calibration's (:meth:`table_runs`), where not read or decided yet: what no extra
        takes the place of (:meth:`.identify.IdentifySteps._hold_warm_ups`)."""
        more = self.table_runs() - self.budget.iso_runs()
        if more <= 0 or "more_runs" in self.record.state.get("identify", {}):
            return 0.0
        return sum(self.budget.step_cost_worst_s(self.plans.more_runs_plan(a, more))
                   for a in axes)  # fmt: skip

    def _more_that_fit(self, axes: list[str], room_s: float) -> int:
        """The most more runs (up to :meth:`table_runs` in all) on the first targets of
        every one of ``axes`` that fit in ``room_s`` (s) together; 0 where none do."""
        for k in range(self.table_runs() - self.budget.iso_runs(), 0, -1):
            cost_s = sum(self.budget.step_cost_worst_s(self.plans.more_runs_plan(a, k))
                         for a in axes)  # fmt: skip
            if axes and cost_s <= room_s:
                return k
        return 0

    def _denser_first(self, axes: list[str], room_s: float, level: int) -> float:
        """Machine time (s) held in ``room_s`` for the quarter (``level`` EIGHTHS: eighth)
        points of the axes whose points of the level before were read and whose table with
        them is still expected to miss between its points by more than BETWEEN_RATIO times
        their scatter, and where those take more of its error off per reading than its more
        runs would (:func:`..fitting.table_cv.denser_pays`): read in place of the more
        runs, one run each (the runs before read the scatter; a miss of more than its
        scatter is taken off most per reading so), the axis that misses most per minute
        first; none where the budget holds both (:meth:`_both_fit`). Each is decided here
        and kept as the extra's record. (At 1.5 x a plain calibration's time the rough
        machines' 4th and 5th runs cost what their midpoints had, on screws whose waves of
        15-80 mm the quarter points follow: rough-0's X read 2.77 → 1.68 µm at the judge's
        targets.)"""
        ident = self.record.state.setdefault("identify", {})
        first, last = self.budget.iso_runs(), self.table_runs()
        names = BETWEEN[level]
        held_s = 0.0
        ready = [a for a in self.by_value(axes, level, before_more=True)
                 if not self.decided(a, level) and self.decided(a, level - 1).get("measured")]
        if not ready or last <= first or self._both_fit(axes, room_s, level):
            return 0.0
        for a in ready:
            ratio, miss_um = self.between(a, level)
            s2 = self.scatter_mm2(a)
            if ratio is None or miss_um is None or ratio <= BETWEEN_RATIO or not np.isfinite(s2):
                continue
            runs = RUNS_IN_PLACE
            need_s = self.budget.step_cost_worst_s(self.plans.midpoints_plan(a, runs, level))
            if not denser_pays(miss_um * 1e-3, s2, runs, first, last) or \
                    held_s + need_s > room_s:
                continue
            held_s += need_s
            ident[names.key(a)] = {
                "misses_x_scatter": ratio, "miss_rms_um": miss_um, "measured": True,
                "runs": runs, "instead_of_more_runs": True}  # fmt: skip
            self.say(f"{a}: {names.table} misses {miss_um:.2f} µm RMS between its points, "
                     f"{ratio:.1f} x what its scatter explains: its {names.what} read in "
                     "place of its more runs, one run each, going up (they take more of its "
                     "error off per reading)")  # fmt: skip
        self.record.save()
        return held_s

    def lost_motion(self, axis: str) -> bool:
        """Whether the ISO runs of ``axis`` read a reversal (ISO 230-2 B) of at least
        MIN_LOST_UM, where a backlash test and its take-up ladder may find lost motion
        that a reversal takes up only in part; True before they are read."""
        if not all(self.record.done(n) for n in self.plans.iso_steps(axis)):
            return True
        both = one_way_split(axis_deviations(self.iso_raw(axis), axis))[0]  # (B: both ways)
        b_um = iso230_axis(both).B_um
        return b_um is None or b_um >= MIN_LOST_UM

    def iso_raw(self, axis: str) -> RawData:
        """The ISO runs of ``axis`` (:meth:`.planner.Planner.iso_steps`), as one run set: the
        first table's points with all their runs, its more runs as read (pooled, as a plain
        calibration's 5 runs are: the table holds their mean state), and its midpoints,
        quarter and eighth points each put on the level of the readings before them
        (:func:`..fitting.table_cv.levelled_midpoints`, net of the once-per-lead term): read
        between other points' runs, on a machine that has warmed or cooled meanwhile, they
        would put that as a step between neighbours. (At 1 x a plain calibration's time,
        smooth-8's Y read 3 runs, its scans, then 2 more; put on the first 3 runs' level,
        its table held their colder state: E cut 96.7 % at the judges' targets against the
        plain calibration's 97.5, pooled 97.4.)"""
        steps = self.plans.iso_steps(axis)
        base = [self.runner.raw(n) for n in steps if n in (f"iso-{axis}", f"iso-more-{axis}")]
        later = [self.runner.raw(n) for n in steps
                 if n in [f"{b.step}-{axis}" for b in BETWEEN]]  # fmt: skip
        if not later:
            return concat_raw(base)
        cyclic = self.scanned(axis)
        # a line between the sets is heat, unless the axis's own sensor levels them
        tilt = not self.runner.drift.sensor_kept(axis)
        level = base  # each set against those read before it, put on the table's level
        for raw in later:
            level.append(levelled_midpoints(concat_raw(level), raw, axis, cyclic, tilt))
        return concat_raw(level)

    def scatter_mm2(self, axis: str) -> float:
        """The variance of the ISO runs of ``axis`` about their targets' means (mm², pooled,
        :func:`..plans.rawdata.pooled_variance`; NaN with no repeat)."""
        return pooled_variance(axis_deviations(self.iso_raw(axis), axis))[0]

    def scanned(self, axis: str) -> CyclicModel | None:
        """The once-per-lead term the cyclic scans of ``axis`` read, if they were read
        (:func:`..fitting.outputs.scanned_cyclic`)."""
        if axis not in self.s.lead_mm or not self.record.done(f"cyclic-{axis}"):
            return None
        path = self.record.raw_paths(f"cyclic-{axis}")[0]
        return scanned_cyclic(self.runner.raw(f"cyclic-{axis}"), read_raw_meta(path), axis)

    def grid_affordable(self) -> bool:
        """Whether the budget left holds a plane's grid (:func:`fitting_grid` of a plain
        calibration's shape) beside the cyclic scans not made yet: where not, the plane
        gets no model and its random points judge what the tables alone do to it (fitted
        on their lines, they may make it worse: :mod:`.after` then keeps them unloaded)."""
        if self.record.done("xy-grid"):
            return True
        return fitting_grid(self.plain_grid(), self._grid_cost_s, self._grid_room_s()) is not None

    def _grid_cost_s(self, grid: tuple[int, int]) -> float:
        """Machine time (s) of a plane grid's run."""
        return self.budget.step_cost_s(self.plans.grid_plan(grid))

    def _grid_room_s(self) -> float:
        """Machine time (s) the budget left holds for the plane's grid: what the cyclic
        scans not made yet leave, but those put after the grid for its sake
        (``scans_after_grid``, :meth:`.identify.IdentifySteps._cyclic_beside_plane`). At
        half a plain calibration's time smooth-8's Y scans gave way to the grid, and the
        grid then gave way to them: neither was read, the plane's random points read the
        tables alone worse than none, and the machine kept no table (X E 138 µm at the
        judge's targets; its table alone 0.86 µm, noise-free)."""
        linear = [a for a in self.s.axes if not self.axes.rotary(a)
                  and a not in self.record.state.get("scans_after_grid", [])]  # fmt: skip
        return self.budget.left_s() - self.scans_left_s(linear)

    def first_grid(self) -> tuple[int, int]:
        """The plane's first grid (decided once, kept in the state): the configured one; on a short
        budget, whose rounds will not refine it, a plain calibration's (:meth:`plain_grid`)
        where the budget left holds it beside the cyclic scans not made yet, else the
        densest of its shape that fits there (:func:`fitting_grid`); a denser one
        (:func:`max_grid_in`) only with what is left after the extras that come after it,
        each held where it fits beside those held before it: the plane's verdict (its random
        points before and after), the linear axes' after-runs (read alone, all or none:
        their ISO runs read them before), each one's backlash test, each with the drift
        references a drift would call for. (At the plain calibration's machine time
        smooth-0's grid took 10 minutes at 13 x 9 and its Y got no cyclic scans: Y E 7.1 µm
        at the judge's targets. At 1.5 x a manual calibration's time the sdss plates' 7 x 5
        grid left their Y at the judge's park 13.4 µm, the manual's 9 x 7 5.3 µm.) A
        backlash test is held only where the ISO runs read a reversal it could take up
        (:meth:`lost_motion`)."""
        if "grid" not in self.record.state:
            grid = self.s.grid
            if self.record.state.get("short"):
                cost_s = self._grid_cost_s

                def worst_s(plans: list[Plan]) -> float:  # (with the references a drift
                    return sum(self.budget.step_cost_worst_s(p) for p in plans)  # calls for)

                linear = [a for a in self.s.axes if not self.axes.rotary(a)]
                room_s = self._grid_room_s()
                plain = self.plain_grid()
                if cost_s(plain) <= room_s:
                    extras = ([] if self.record.done("before-xy") else
                              [2 * [self.plans.before_xy_plan()]])  # fmt: skip
                    extras.append([self.plans.before_plan(a) for a in linear  # (after-runs
                                   if not self.record.done(f"before-{a}")])  # alone: all or none)
                    extras += [[backlash_plan(a, self.axes.travel(a))] for a in linear
                               if not self.record.done(f"backlash-{a}") and self.lost_motion(a)]
                    held_s = hold_each(cost_s(plain), [worst_s(p) for p in extras], room_s)
                    grid = max_grid_in(plain, cost_s, room_s - held_s + cost_s(plain))
                else:
                    grid = fitting_grid(plain, cost_s, room_s) or self.s.grid
            self.record.state["grid"] = list(grid)
            self.record.save()
        nx, ny = self.record.state["grid"]
        return int(nx), int(ny)
