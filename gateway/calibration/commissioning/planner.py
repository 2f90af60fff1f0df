"""Commissioning's plans: the identification's and the judging runs'."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ..fitting import adaptive
from ..fitting.plans_scans import cyclic_plan
from ..fitting.takeup_fit import takeup_plan
from ..plans.plans import (
    Plan,
    backlash_plan,
    iso230_linear_plan,
    read_plan,
    targets_plan,
)
from ..plans.xy import xy_grid_plan, xy_verification_plan

if TYPE_CHECKING:
    from .axes import Axes
    from .budget import Budget
    from .record import Record
    from .rotary import RotarySteps
    from .thermal import ThermalSteps


@dataclass(frozen=True)
class Between:
    """What a short budget reads between a table's points, as it is named and said."""

    kind: str  # the identification record's kind (``{kind}-{axis}``)
    step: str  # the ISO step's name (``{step}-{axis}``)
    what: str  # what is read, said
    table: str  # the table judged, said

    def key(self, axis: str) -> str:
        """The identification record's key of ``axis``."""
        return f"{self.kind}-{axis}"


#: what is read between a table's points, by level: its midpoints (0), its quarter points
#: (1) and its eighth points (2), each level between all the points read before it
BETWEEN = (Between("midpoints", "iso-mid", "midpoints", "the first table"),
           Between("quarters", "iso-quarter", "quarter points", "the table with its midpoints"),
           Between("eighths", "iso-eighth", "eighth points",
                   "the table with its quarter points"))  # fmt: skip
QUARTERS, EIGHTHS = 1, 2


#: stations commissioning scans the once-per-lead term at, one way, where the travel holds
#: them a scan apart (:func:`cyclic_scans`)
SCAN_STATIONS = 7
#: leads each of commissioning's scans covers (the plain calibration's: a shorter scan
#: confuses the term with the table's local slope)
SCAN_LEADS = 2.0
#: points per lead of commissioning's scans: seven of them then read fewer points than a
#: plain calibration's three two-way scans (175 against 198), so at its machine time they
#: take no time from its other steps. (Seven scans at 16 points a lead, 231 points, cost
#: rough-3 at 1 x the plain calibration's time its X midpoints: X E cut 92.6 → 87.1 %.
#: Simulated from the ten rough machines' truth, 0.3 µm of noise, the pitch line's peak to
#: peak summed over 20 axes: 46.5 µm at 16 points a lead, 46.8 at 14, 47.7 at 12; the
#: plain three two-way scans 66.3.) Up to 4 harmonics: 12 points a lead read 5.
SCAN_PER_LEAD = 12


def cyclic_scans(axis: str, travel_mm: tuple[float, float], lead_mm: float) -> Plan:
    """Commissioning's dense scans of the once-per-lead term: SCAN_STATIONS stations spread
    evenly from one lead inside each end of the travel, each read one way over SCAN_LEADS
    leads, where the travel holds them a scan apart; else a plain calibration's three
    two-way scans.

    The term is the screw's, the same both ways, so one way reads it for half a scan. Its
    size and phase change along a screw, and a table is taken net of it at its points: a
    term read at three stations leaves its miss in the table, which the spline between the
    points turns into long waves. (Session 77, the ten rough machines' tables kept: the
    truth's term sampled at 3 stations left 63.6 µm of the pitch line's peak to peak summed
    over 20 axes, at 7 stations reaching one lead from each end 40.4, the truth's own term
    24.7. At 1.5 x the plain calibration's time: the parks' E on the pitch line, summed,
    39.1 → 33.6 µm, lower on 16 of 20 axes.) Seven one-way scans at SCAN_PER_LEAD read 175
    points, three two-way ones 198."""
    lo, hi = float(travel_mm[0]), float(travel_mm[1])
    span_mm = SCAN_LEADS * lead_mm + 2.0  # a scan and its take-up moves (1 mm each side)
    if (hi - lo) < SCAN_STATIONS * span_mm:
        return cyclic_plan(axis, (lo, hi), lead_mm)
    edge = span_mm / 2.0 + 0.5  # the outer scans' take-up moves stay 0.5 mm inside the ends
    stations = [float(v) for v in np.linspace(lo + edge, hi - edge, SCAN_STATIONS)]
    return cyclic_plan(axis, (lo, hi), lead_mm, stations, per_lead=SCAN_PER_LEAD,
                       leads=SCAN_LEADS, both_ways=False, least_per_lead=SCAN_PER_LEAD)  # fmt: skip


def steps_below(level: int) -> tuple[str, ...]:
    """The ISO steps whose targets the points of ``level`` are read between: the first
    table's and every level's before it."""
    return ("iso", *(b.step for b in BETWEEN[:level]))


class Planner:
    """The plans of the identification and of the judging runs (pure of the machine: the axes, the
    settings and the plans already written)."""

    def __init__(self, axes: Axes, record: Record, budget: Budget, rotary: RotarySteps,
                 thermal: ThermalSteps) -> None:
        self.s = axes.s
        self.axes = axes
        self.record = record
        self.budget = budget
        self.rotary = rotary
        self.thermal = thermal

    def midpoints_plan(self, axis: str, runs: int | None = None, level: int = 0
                       ) -> Plan:  # fmt: skip
        """The ISO 230-2 cycle at the midpoints of the first table's points, ``runs`` runs
        per target (default: the first table's); at ``level`` 1 (2), at the midpoints of
        those points and their midpoints (and their quarter points): the first table's
        quarter (eighth) points, read going up only: their reversal is the table's, from
        its points read both ways (:func:`..fitting.fit.with_one_way_points`), for half the
        machine time."""
        steps = [f"{n}-{axis}" for n in steps_below(level)]
        first = np.unique(np.concatenate([
            read_plan(self.record.dir / "plans" / f"{n}.plan").targets_mm(axis) for n in steps]))
        return targets_plan(axis, self.axes.travel(axis), (first[1:] + first[:-1]) / 2,
                            runs or self.budget.iso_runs(), kind="iso230-linear",
                            note=BETWEEN[level].what,
                            one_way=level > 0)  # fmt: skip

    def more_runs_plan(self, axis: str, more: int) -> Plan:
        """The first table's ISO runs again: ``more`` runs on the same targets, numbered on
        from its own (a short budget's time left after a plain calibration's steps,
        :meth:`.short.ShortBudget.more_runs`)."""
        first = self.budget.iso_runs()
        whole = self.iso_plan(axis, runs=first + more)
        meta = tuple((k, str(more) if k == "runs" else v) for k, v in whole.meta)
        return Plan(whole.kind, whole.axes, tuple(m for m in whole.moves if m.run > first),
                    (*meta, ("first_run", str(first + 1))))  # fmt: skip

    def iso_steps(self, axis: str) -> list[str]:
        """The ISO steps of ``axis``, in the order they are read: the first table's points,
        its midpoints, more runs, quarter and eighth points where a short budget read them
        (:meth:`.short.ShortBudget.densify`, :meth:`.short.ShortBudget.more_runs`)."""
        steps = [f"{n}-{axis}" for n in ("iso", BETWEEN[0].step, "iso-more",
                                          *(b.step for b in BETWEEN[1:]))]
        return steps[:1] + [n for n in steps[1:] if self.record.done(n)]

    def iso_targets(self, axis: str) -> np.ndarray:
        """Every target the ISO runs of ``axis`` read (mm)."""
        return np.concatenate([read_plan(self.record.dir / "plans" / f"{n}.plan").targets_mm(axis)
                               for n in self.iso_steps(axis)])  # fmt: skip

    # -- the whole thing -----------------------------------------------------------------
    def initial_plans(self, heat: bool = True) -> list[tuple[str, Plan]]:
        """The steps before any adaptation, for the printed plan and its estimate;
        ``heat`` False: without the zone warm-ups of axes with no sensor (each only where
        the pitch runs showed heat, and where the budget then left holds it)."""
        out: list[tuple[str, Plan]] = []
        for a in self.s.axes:
            if self.axes.rotary(a):  # in degrees (rotary.py)
                out += self.rotary.rotary_plans(a)
                continue
            travel = self.axes.travel(a)
            if self.thermal.warms_up(a):
                out.append((f"warmup-{a}", self.thermal.warmup_plan(a)))
            out.append((f"backlash-{a}", backlash_plan(a, travel)))
            out.append((f"takeup-{a}", takeup_plan(a, travel)))  # if there is lost motion
            out.append((f"iso-{a}", self.iso_plan(a)))
            if a in self.s.lead_mm:
                out.append((f"cyclic-{a}", cyclic_scans(a, travel, self.s.lead_mm[a])))
            elif not self.s.no_lead_search:
                out.append((f"lead-{a}", self.lead_plan(a)))
        if self.s.planar is not None:
            out.append(("xy-grid", self.grid_plan(self.s.grid)))
        # with no sensor: last, where the drift references show the screw warming
        out += [(f"warmup-{a}", self.thermal.warmup_plan(a))
                for a in (self.thermal.heat_zoned() if heat else ())]  # fmt: skip
        return [(n, self.axes.snap(p)) for n, p in out]

    def lead_plan(self, axis: str) -> Plan:
        """A dense scan in + around the middle of the travel, for the lead search."""
        from ..plans.plans import Move

        targets = adaptive.lead_scan_targets_mm(self.axes.travel(axis))
        lo = self.axes.travel(axis)[0]
        moves = [Move(1, -1, "takeup", (max(lo, float(targets[0]) - 1.0),))]
        moves += [Move(1, +1, "measure", (float(t),)) for t in targets]
        return Plan("lead-search", (axis,), tuple(moves), (("kind", "lead-search"),
                                                           ("axis", axis)))  # fmt: skip

    def iso_plan(self, axis: str, runs: int | None = None, points: int | None = None) -> Plan:
        """The first table's ISO 230-2 runs: ``points`` targets (default: as a short budget
        decided, else ``adaptive.COARSE_POINTS``), ``runs`` runs."""
        lead = self.s.lead_mm.get(axis)
        if not points:
            chosen = self.record.state.get("iso_points") or {}
            points = int((chosen.get(axis) if isinstance(chosen, dict) else chosen) or 0)
        return iso230_linear_plan(axis, self.axes.travel(axis),
                                  step_mm=adaptive.coarse_step_mm(self.axes.travel(axis), lead,
                                                                  points),
                                  runs=runs or self.budget.iso_runs(),
                                  overrun_mm=1.0, lead_mm=lead, seed=self.s.seed)  # fmt: skip

    def grid_plan(self, grid: tuple[int, int], runs: int = 2) -> Plan:
        (x0, x1), (y0, y1) = self.axes.plane_travel()
        return xy_grid_plan((x0 + 2, x1 - 2), (y0 + 2, y1 - 2), grid[0], grid[1],
                            self.s.planar, runs=runs, approach_mm=1.0,
                            lower_mm=(x0, y0))  # fmt: skip

    def before_xy_plan(self) -> Plan:
        """The plane's random points judged before anything is fitted and after, each read
        from below and from above: the judge, like a PLC, reaches a point from either side,
        and the reversal the axes' tables leave shows in the plane only so (rough-9: 1.09 µm
        as read one way, 2.19 both ways, its judges 1.65-2.38)."""
        return self.xy_check_plan(10_000 + self.s.seed, self.s.grid, both_ways=True)

    def xy_check_plan(self, seed: int, grid: tuple[int, int], both_ways: bool = False) -> Plan:
        """The plane's random points, approached in + (a round's check of the plane's
        model, which a grid read in + refines); ``both_ways``: in − too, and
        ``plane_points`` of them (the verdict's: ``--plane-points``)."""
        (x0, x1), (y0, y1) = self.axes.plane_travel()
        count = self.s.plane_points if both_ways else adaptive.RANDOM_TARGETS
        return xy_verification_plan((x0 + 2, x1 - 2), (y0 + 2, y1 - 2), grid[0], grid[1],
                                    self.s.planar, mode="random", count=count,
                                    seed=seed, approach_mm=1.0, lower_mm=(x0, y0),
                                    upper_mm=(x1, y1) if both_ways else None)  # fmt: skip

    def judged_alone(self) -> dict[str, Plan]:
        """``--finish``'s after-runs read with no before-run: each linear axis whose ISO runs
        were read and whose before-run was not (nor an after-run held alone,
        :meth:`verdict_alone`), and the plane where any axis's were, at
        the random targets their before-runs would have had (:meth:`before_plan`,
        :meth:`before_xy_plan`)."""
        done = self.record.done
        out = {a: self.before_plan(a) for a in self.s.axes
               if not self.axes.rotary(a) and done(f"iso-{a}") and not done(f"before-{a}")
               and not self.alone_path(a).exists()}  # (a short budget's: verdict_alone)
        if (self.s.planar is not None and not done("before-xy")
                and any(done(f"iso-{a}") for a in self.s.axes)):  # fmt: skip
            out["XY"] = self.before_xy_plan()
        return out

    def alone_path(self, axis: str) -> Path:
        """Where a short budget keeps the plan of an axis's after-run read with no
        before-run (:meth:`.identify.IdentifySteps._after_alone_if_affordable`)."""
        return self.record.dir / "plans" / f"alone-{axis}.plan"

    def verdict_alone(self) -> dict[str, Plan]:
        """The after-runs a short budget holds with no before-run, by axis: their plans."""
        return {a: read_plan(p) for a in self.s.axes if (p := self.alone_path(a)).exists()}

    def before_plan(self, axis: str, avoid_mm: np.ndarray | None = None) -> Plan:
        """The targets judged before and after: random, off the coarse table's points
        (``avoid_mm``, default the ISO runs' targets)."""
        avoid = self.iso_targets(axis) if avoid_mm is None else avoid_mm
        targets = adaptive.random_targets_mm(self.axes.travel(axis), 2 * adaptive.RANDOM_TARGETS,
                                             1000 + self.s.seed, avoid)  # fmt: skip
        return targets_plan(axis, self.axes.travel(axis), targets, self.s.verify_runs,
                            kind="iso230-verification", note="before-after")  # fmt: skip

