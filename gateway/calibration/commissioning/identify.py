"""Commissioning's step 1: the warm-ups and each axis's identification runs."""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import TYPE_CHECKING

from ...compensation.errors import TableError
from ..fitting import adaptive
from ..plans.plans import (
    Plan,
    backlash_from_raw,
    backlash_plan,
    write_plan,
)
from ..plans.rawdata import read_raw_csv
from .planner import EIGHTHS, QUARTERS, cyclic_scans
from .settings import SHORT_WARMUP_S, BudgetSpent
from .sizing import first_table_reading

if TYPE_CHECKING:
    from .axes import Axes
    from .budget import Budget
    from .fit import FitSteps
    from .planner import Planner
    from .record import Record
    from .rotary import RotarySteps
    from .short import ShortBudget
    from .stager import Stager
    from .steps import StepRunner
    from .takeup import TakeUpSteps
    from .thermal import ThermalSteps

Say = Callable[[str], None]


class IdentifySteps:
    """Step 1: the warm-ups and each axis's identification runs, compensation off, and the
    *before* runs."""

    def __init__(self, axes: Axes, record: Record, stager: Stager, budget: Budget,
                 runner: StepRunner, rotary: RotarySteps, thermal: ThermalSteps, plans: Planner,
                 takeup: TakeUpSteps, short: ShortBudget, fit: FitSteps, say: Say) -> None:
        self.s = axes.s
        self.axes = axes
        self.record = record
        self.stager = stager
        self.budget = budget
        self.runner = runner
        self.rotary = rotary
        self.thermal = thermal
        self.plans = plans
        self.takeup = takeup
        self.short = short
        self.fit = fit
        self.say = say

    async def run(self) -> None:
        """The warm-ups and each axis's identification runs, ordered so that no axis is
        measured right after its own zone warm-up: the first zone-warmed axis is identified
        last, every other one before its warm-up (cold, with the configured thermal
        setting; the drift references take what it misses). A zone's heat the sensor's
        model cannot place (a temperature at one spot, the linear spread) then fades for
        hours before its axis is measured, instead of going into its table. On a short
        budget the plain calibration's steps come first, and each warm-up after them only
        where the budget left holds it (:meth:`_plain_steps_first`). An axis with no sensor
        gets its zone warm-up last (:meth:`heat_warm_ups`)."""
        await self.thermal.read_start_temperatures()
        self.short.refs_affordable()  # (before the first reading of the references)
        await self.stager.use("identification")
        zoned = self.thermal.zoned()
        if self.short.applies():  # a plain ISO 230-2 calibration's steps first, warm-ups after
            spent: BudgetSpent | None = None
            try:
                await self._plain_steps_first([a for a in self.s.axes
                                               if not self.axes.rotary(a)])  # fmt: skip
            except BudgetSpent as exc:  # the warm-ups held still follow
                spent = exc
            for a in zoned:  # each where the budget left holds it
                await self._warm_up_if_affordable(a)
            if spent is not None:
                raise spent
            for a in self.s.axes:
                await self._identify_axis(a)
            await self._before_xy_if_affordable()
            self.thermal.weigh_sensors()
            return
        if zoned:
            await self._warm_up(zoned[0])
        for a in zoned[1:]:
            await self._identify_axis(a)
            await self._warm_up(a)
        unzoned = [a for a in self.s.axes if a not in zoned]
        for a in unzoned:  # every such axis's table first
            await self._table_first(a)
        rest = unzoned + zoned[:1]
        for a in rest:
            await self._identify_axis(a)
        await self.before_xy()
        self._hold_heat_warm_ups()  # the rounds' budget is what they leave
        self.thermal.weigh_sensors()  # on the references read so far, before the rounds

    async def _find_lead(self, axis: str) -> None:
        """The lead search of an axis whose lead was not given (--lead-mm); not begun where
        the budget left holds it but not the cyclic scans a lead found would call for (the
        sdss plates at 1.5 x a manual calibration's time spent 8 of their 61 minutes on a
        search whose scans could not have followed)."""
        leads = self.record.state.setdefault("leads", {})
        if axis in self.s.lead_mm or axis in leads or self.s.no_lead_search:
            return
        scans = cyclic_scans(axis, self.axes.travel(axis), min(adaptive.STANDARD_LEADS_MM))
        cost_s = self.budget.step_cost_s
        need_s = cost_s(self.plans.lead_plan(axis)) + cost_s(scans)
        left_s = self.budget.left_s()
        if need_s > left_s:
            note = (f"{axis}: no lead search: it and the cyclic scans it may call for need "
                    f"{need_s / 60:.1f} min of machine time, {max(0.0, left_s) / 60:.1f} min "
                    "left (--lead-mm gives the lead)")  # fmt: skip
            self._note(note)
            return
        await self.runner.step(f"lead-{axis}", lambda: self.plans.lead_plan(axis), "off",
                               self.axes.park(axis))  # fmt: skip
        raw = self.runner.raw(f"lead-{axis}")
        found = adaptive.find_lead(raw.target_mm, raw.deviation_mm)
        leads[axis] = found.lead_mm or 0.0
        self.record.state.setdefault("identify", {})[f"lead-{axis}"] = {
            "lead_mm": found.lead_mm or 0.0, "amplitude_um": found.amplitude_um,
            "f_ratio": found.f_ratio}  # fmt: skip
        if found.lead_mm:
            self.s.lead_mm[axis] = found.lead_mm
            self.say(f"{axis}: a periodic error of {found.amplitude_um:.2f} µm every "
                     f"{found.lead_mm:g} mm, taken as the screw's lead (--lead-mm gives it "
                     "where you know it); the cyclic stage follows it")  # fmt: skip
        else:
            self.say(f"{axis}: no periodic error stands out of the noise: no cyclic stage")
        self.record.save()

    def _iso_runs_that_fit(self, axes: list[str]) -> None:
        """On a short budget, before the first ISO run: how densely and how often each axis's
        ISO runs read (decided once, kept in the state; said). First a plain calibration's
        table (:meth:`.short.ShortBudget.plain_points`) at its first runs
        (:meth:`.short.ShortBudget.first_runs`) down to ``DENSE_LEAST_RUNS``, where it fits
        beside the plane's configured grid and the cyclic scans where the lead is known: no
        round will sweep between a short budget's points (at the plain calibration's time
        rough-0's X read 21 points, 3 runs each, E 11.5 µm at the judge's targets, against
        the plain calibration's 29 points and 5.3 µm). Else the coarse table at the runs
        that fit beside the plane (down to 2, the fewest that show a scatter), then fewer
        targets, so that each axis gets a table and the plane its model rather than the last
        none (at the same time mcu1025's X took 3 runs and Y got no table). Each step with
        the drift references a drift would call for."""
        if "iso_runs" in self.record.state or any(self.record.done(f"iso-{a}") for a in axes):
            return
        plane = self.axes.plane_with(axes)
        keep_s = self.short.plane_held_s(plain=False) if plane else 0.0
        scans_s = self.short.scans_left_s(axes)

        def cost_s(runs: int, points: Mapping[str, int | None]) -> float:
            return sum(self.budget.step_cost_worst_s(self.plans.iso_plan(a, runs, points[a]))
                       for a in axes)  # fmt: skip

        got = first_table_reading(axes, self.short.first_runs(axes),
                                  self.short.plain_points(axes), cost_s,
                                  self.budget.left_s() - keep_s, scans_s)  # fmt: skip
        if got.dense:
            self._note(", ".join(f"{a}: {n} ISO targets" for a, n in got.points.items())
                       + f", {got.runs} runs each: a plain calibration's table (one every "
                       f"{adaptive.PLAIN_STEP_MM:g} mm), which no round on this budget will "
                       "sweep between")  # fmt: skip
        elif got.points:
            points = min(got.points.values())
            self._note(f"{', '.join(axes)}: {points} ISO targets per axis instead of "
                       f"{adaptive.COARSE_POINTS}: the budget holds every axis's table"
                       + (" and the plane's grid" if keep_s else "")
                       + (" only so" if got.fits else " not even so"))  # fmt: skip
        if not got.dense and got.runs < self.s.runs:
            self._note(f"{', '.join(axes)}: {got.runs} ISO runs per target instead of "
                       f"{self.s.runs}: the budget holds every axis's table only so")
        if got.points:
            self.record.state["iso_points"] = dict(got.points)
        self.record.state["iso_runs"] = got.runs
        self.record.save()

    # -- 1. identification ---------------------------------------------------------------

    async def _plain_steps_first(self, cores: list[str]) -> None:
        """On a short budget, a plain ISO 230-2 calibration's steps before anything else,
        thermal settings or not (the zone warm-ups came first and a 0.9 h budget spent 45
        minutes warming X and ended with no table: issue 54): every linear axis's ISO runs,
        its cyclic scans where its lead is known and the plane's grid still fits beside
        them, the plane's grid with their tables on; then the extras where the budget left
        holds them: the verdict (the plane's random points, each axis's before-run) and
        the backlash tests. (At the plain calibration's machine time, the scans last
        left smooth-0 without them: X E 7.5 µm at the judge's targets, its once-per-lead
        error 2.9 µm, against 0.5 µm for the plain calibration. With the plane's verdict
        and the backlash tests before a plain calibration's 5 runs, it read 4, rough-3 2.)"""
        self._iso_runs_that_fit(cores)
        for a in cores:
            await self._iso(a)
        for a in cores:  # where the tables miss between their points (lead not known)
            await self.short.densify(a)
        for a in cores:  # the once-per-lead error, before the plane is measured on the tables
            await self._cyclic_beside_plane(a)
        for a in self.short.by_value(cores):  # where the tables miss between their points
            await self.short.densify(a)  # net of it (lead known), the most per minute first
        self._hold_warm_ups(cores)  # the heat a warm machine meets, first of the extras
        await self.short.more_runs(cores)  # a plain calibration's runs, where time is left
        for a in self.short.by_value(cores, QUARTERS):  # an extra: where the tables
            await self.short.densify(a, QUARTERS)  # still miss between their points
        await self.short.more_runs_later(cores)  # those the quarter points took the place of
        for a in self.short.by_value(cores, EIGHTHS):  # and where they miss even so
            await self.short.densify(a, EIGHTHS)
        plane = self.axes.plane_with(cores)
        if plane:
            if not self.short.grid_affordable():  # no model: the tables alone are what the
                await self._before_xy_if_affordable()  # plane gets, judged there for safety
            await self.fit.fit_axes(cores, curves=True)
            await self.fit.plane()
            await self.stager.use("identification")  # the rest is measured without them
        for a in cores:  # scans that did not fit beside the grid, where they fit now
            await self._cyclic_beside_plane(a)
        # the extras, each where the budget left holds it: the verdict (the plane's, then
        # each axis's), the backlash tests
        if plane:
            await self._before_xy_if_affordable()
        await self._after_alone_if_affordable(cores)
        for a in cores:  # (the bidirectional tables hold the backlash meanwhile)
            await self._backlash(a)

    def _note(self, text: str, replacing: str = "") -> None:
        """Say ``text`` and keep it among the notes, once (:meth:`.record.Record.note`)."""
        if self.record.note(text, replacing):
            self.say(text)
            self.record.save()

    async def _after_alone_if_affordable(self, cores: list[str]) -> None:
        """On a short budget, the verdict on the axes ``cores``: each one's after-run alone,
        at the random targets a before-run would have had (none a table point), held where
        the budget left holds every one of them (their plans kept,
        :meth:`.budget.Budget.reserve_s`); else said, and the steps after it go on. Their
        figures before the tables are their ISO runs', read with the tables off
        (:meth:`.after.AfterSteps.summary`): a before-run would cost the same again. All
        or none: one axis judged leaves the machine without a verdict all the same, and
        its minutes were the plane's (at 1.5 x a plain calibration's time sdss-1396's X
        alone took 4.6 minutes from its grid, 12 x 12 → 9 x 9: XY 3.4 → 6.3 µm at the
        judge's points, the outcome still "budget"). A run begun with before-runs carries
        on with them."""
        alone = []
        for a in cores:
            name = f"before-{a}"
            if self.record.done(name) or name in (self.record.state.get("parts") or {}):
                await self.runner.step(name, lambda a=a: self.plans.before_plan(a), "off",
                                       self.axes.park(a))  # fmt: skip
            elif not self.plans.alone_path(a).exists():
                alone.append(a)
        if not alone:
            return
        plans = {a: self.axes.snap(self.plans.before_plan(a)) for a in alone}
        need_s = sum(self.budget.after_cost_s(p) for p in plans.values())
        if need_s > self.budget.left_s():  # (said once: Record.note)
            self._note(", ".join(alone) + f": no after-run on this budget ({need_s / 60:.1f} "
                       "min): no verdict on the axes; their tables are fitted all the same")
            return
        for a, plan in plans.items():
            self.axes.check_limits(plan)
            path = self.plans.alone_path(a)
            path.parent.mkdir(parents=True, exist_ok=True)
            write_plan(path, plan)
        self.record.save()

    def _verdict_fits(self, name: str, plan: Plan, said: str) -> bool:
        """Whether the verdict's step ``name`` goes on: made or begun already (it carries
        on), or ``plan`` read before and after fits in the budget left; else ``said``
        (formatted with ``min``, what it needs in minutes) is said and kept."""
        if self.record.done(name) or name in (self.record.state.get("parts") or {}):
            return True
        need_s = self.budget.verdict_cost_s(plan)
        if need_s <= self.budget.left_s():
            return True
        self._note(said.format(min=need_s / 60))
        return False

    async def _cyclic_beside_plane(self, a: str) -> None:
        """The cyclic scans of ``a`` where its lead is known and the budget left holds them
        and still the plane's configured grid; else said, and put after the grid
        (:meth:`.short.ShortBudget._grid_room_s` no longer holds room for them): the
        plane's model cuts far more than a once-per-lead term."""
        if a not in self.s.lead_mm or self.record.done(f"cyclic-{a}"):
            return
        scans = cyclic_scans(a, self.axes.travel(a), self.s.lead_mm[a])
        need_s = self.budget.step_cost_s(scans)
        keep_s = self.short.plane_held_s(plain=False) if a in (self.s.planar or ()) else 0.0
        said = f"{a}: no cyclic scans on this budget"
        if self.budget.left_s() - need_s < keep_s:
            if keep_s:  # the grid first: its room no longer held for these (ShortBudget)
                after = self.record.state.setdefault("scans_after_grid", [])
                if a not in after:
                    after.append(a)
            self._note(f"{said}: they ({need_s / 60:.1f} min) do not "
                       + ("fit beside the plane's grid" if keep_s else "fit in the budget left"),
                       replacing=said)  # fmt: skip
            return
        await self.runner.step(f"cyclic-{a}", lambda: scans, "off", self.axes.park(a))
        self.record.drop_notes(said)  # made after all

    async def _warm_up_if_affordable(self, a: str) -> None:
        """The zone warm-up of ``a`` where the budget left holds it; else said, and the
        configured thermal setting kept (no sensor: heat from motion from the drift
        references alone)."""
        if self._warmed(a):
            return
        self._fit_held_warm_up(a)
        cost_s = self._warm_up_cost_s(a)
        if not self.record.done(f"warmup-{a}") and cost_s > self.budget.left_s(a):
            self.record.state.setdefault("identify", {})[f"thermal-{a}"] = {
                "fitted": False, "why": f"its warm-up ({cost_s / 60:.0f} min) is not in the "
                f"budget left ({max(self.budget.left_s(a), 0.0) / 60:.0f} min)"}  # fmt: skip
            (self.record.state.get("warmup_held") or {}).pop(a, None)  # its hold let go
            kept = ("heat from motion from the drift references alone"
                    if self.thermal.heat_warms_up(a) else "thermal setting kept as configured")
            self.say(f"{a}: {kept}: its warm-up ({cost_s / 60:.0f} min) is not in the budget "
                     "left")  # fmt: skip
            return
        await self._warm_up(a)

    def _hold_warm_ups(self, cores: list[str]) -> None:
        """On a short budget, once its ISO runs are read: machine time held for a short
        zone warm-up (SHORT_WARMUP_S) of each axis a warm-up identifies the heat of (a
        sensor's, or with none its own motion's where its references read a growth that
        stands out of their scatter: :meth:`.drift.DriftRefs.least_growth_um`; not merely
        where they do not rule heat out, as after the rounds: at 1.5 x the sdss plates'
        references, off or scattered, ruled out nothing, and warm-ups of screws that grew
        1-2 µm took their plane's verdict and E cut 84 → 76 %),
        where the budget left holds it beside the cyclic scans, the runs that bring the
        tables to a plain calibration's and its grid: an extra never takes the place of a
        plain calibration's step (at its machine time smooth-8 warmed X for 10.5 minutes
        in place of both axes' 4th and 5th runs: Y E 0.83 → 1.14 µm at the judge's targets
        against the plain calibration). The extras after them take what is left. Decided
        once, kept in the state."""
        if "warmup_held" in self.record.state:
            return
        room_s = (self.budget.left_s() - self.short.plane_held_s()
                  - self.short.scans_left_s(cores) - self.short.more_runs_left_s(cores))
        candidates = [a for a in self.thermal.zoned() if a in cores] + [
            a for a in self._heat_read() if a in cores]
        self._hold(candidates, min(self.s.warmup_s, SHORT_WARMUP_S), room_s)

    def _hold_heat_warm_ups(self) -> None:
        """On a budget that is not short, once every axis is identified: machine time held
        for a short zone warm-up (SHORT_WARMUP_S) of each axis with no sensor whose
        references read heat (:meth:`_heat_read`); it grows up to the full one where the
        budget the rounds left holds it (:meth:`_fit_held_warm_up`). The warm-up still
        follows the rounds (:meth:`heat_warm_ups`); they no longer spend all of its time.
        At the guide's 4 h a sweep took 78 minutes of rough-0's, no warm-up was left, and a
        judge after 30 minutes of other work found 99.9 % of X's 9.3 µm of heat left (the
        rough machines' median 27.6 %). A full one held took the rounds' sweeps instead:
        heat left 10.7 %, but rough-8's X table read E 9.4 µm where its sweep had made it
        1.0, rough-0's 4.8 where it was 1.5."""
        if "warmup_held" in self.record.state:
            return
        self._hold([a for a in self._heat_read() if not self._warmed(a)],
                   min(self.s.warmup_s, SHORT_WARMUP_S), self.budget.left_s(),
                   grow_s=self.s.warmup_s)  # fmt: skip

    def _heat_read(self) -> list[str]:
        """The axes with no sensor whose drift references have grown out of their own
        scatter (:meth:`.drift.DriftRefs.least_growth_um`): the heat a warm-up would fit
        is there, not merely not ruled out."""
        drift = self.thermal.drift
        return [a for a in self.thermal.heat_zoned()
                if drift.grown_um(a) >= drift.least_growth_um(a)]  # fmt: skip

    def _hold(self, candidates: list[str], duration_s: float, room_s: float,
              grow_s: float | None = None) -> None:  # fmt: skip
        """Hold each candidate's zone warm-up of ``duration_s`` (s of strokes, shortened to
        what is left of ``room_s``, s of machine time, down to half a short one), in order,
        while the room holds it; ``grow_s``: the strokes it may grow to where the budget
        left holds them when it is made. Decided once, kept in the state and said."""
        held: dict[str, dict[str, float]] = {}
        for a in candidates:
            strokes_s, cost_s = self._warm_up_within(a, duration_s, room_s)
            if cost_s <= room_s:
                held[a] = {"duration_s": strokes_s, "cost_s": cost_s}
                if grow_s is not None and grow_s > strokes_s:
                    held[a]["grow_s"] = grow_s
                room_s -= cost_s
        self.record.state["warmup_held"] = held
        if held:
            self._note("held for a zone warm-up of " + ", ".join(
                f"{a} ({h['duration_s'] / 60:.0f} min of strokes, {h['cost_s'] / 60:.1f} min)"
                for a, h in held.items()) + ": its heat is what the customer's warm machine "
                "meets")  # fmt: skip
        self.record.save()

    def _warm_up_cost_s(self, a: str, duration_s: float | None = None) -> float:
        """Machine time (s) of ``a``'s warm-up as its step runs it (snapped to pulses; a
        warm-up reads no drift references), and the config switches to it and back, where
        the references are read."""
        plan = self.axes.snap(self.thermal.warmup_plan(a, duration_s))
        switches_s = 2 * self.budget.refs_once_s() if "drift_base" in self.record.state else 0.0
        return self.budget.step_cost_s(plan, drift=False) + switches_s

    def _fit_held_warm_up(self, a: str) -> None:
        """A held warm-up (:meth:`_hold_warm_ups`) not begun, fitted to the budget left: grown
        towards its ``grow_s`` where that holds more strokes, shortened where the steps before
        it took longer than estimated (down to half its strokes)."""
        held = (self.record.state.get("warmup_held") or {}).get(a)
        if held is None or (self.record.dir / "plans" / f"warmup-{a}.plan").exists():
            return  # (begun: its plan is kept)
        left_s = self.budget.left_s(a)
        if "grow_s" in held:
            duration_s, cost_s = self._warm_up_within(a, float(held["grow_s"]), left_s)
            if duration_s > float(held["duration_s"]) and cost_s <= left_s:
                held.update(duration_s=duration_s, cost_s=cost_s)
                self.record.save()
                return
        duration_s, cost_s = self._warm_up_within(a, float(held["duration_s"]), left_s)
        if duration_s < float(held["duration_s"]):
            held.update(duration_s=duration_s, cost_s=cost_s)
            self.record.save()

    def _warm_up_within(self, a: str, duration_s: float, room_s: float) -> tuple[float, float]:
        """``a``'s warm-up of ``duration_s`` (s of strokes), shortened by tenths until its
        machine time fits ``room_s`` or it is down to half a short one (SHORT_WARMUP_S / 2):
        its strokes and cost (s); the cost may still be over ``room_s``. Rough-7's Δa
        screw at 1.5 x: 8 minutes did not fit after the midpoints, so it got no warm-up
        and its sensor's model left 12.6 µm of the zone's heat."""
        while True:
            cost_s = self._warm_up_cost_s(a, duration_s)
            if cost_s <= room_s or duration_s <= SHORT_WARMUP_S / 2:
                return duration_s, cost_s
            duration_s = max(0.9 * duration_s, SHORT_WARMUP_S / 2)

    async def _before_xy_if_affordable(self) -> None:
        """On a short budget, the plane's random points (its verdict) where the budget left
        holds them before and after; else said."""
        if self._verdict_fits("before-xy", self.plans.before_xy_plan(),
                              "the plane: no random points before and after on this budget "
                              "({min:.1f} min): no verdict on the plane; its model is fitted "
                              "all the same"):
            await self.before_xy()

    async def before_xy(self) -> None:
        """The plane's random points before anything is fitted (judged again at the end)."""
        if self.s.planar is not None:
            await self.runner.step("before-xy", self.plans.before_xy_plan, "off")

    async def _warm_up(self, a: str) -> None:
        """The axis's warm-up (thermal off) and its fit; the identification config back."""
        if self._warmed(a):
            return  # fitted before an interruption
        results = self.record.state.setdefault("identify", {})
        await self.stager.use("warmup")
        # the travel so far (the drift log's odometers): heat still fading in the warm-up
        self.record.state.setdefault("warmup_log", {}).setdefault(
            a, len(self.record.state.get("drift_log", [])))
        raw = await self.runner.step(f"warmup-{a}", lambda: self.thermal.warmup_plan(a), "off",
                                     drift=False)  # fmt: skip
        try:
            results[f"thermal-{a}"] = self.thermal.fit(a, read_raw_csv(raw))
        except TableError as exc:  # the config's own setting stays
            results[f"thermal-{a}"] = {"fitted": False, "why": str(exc)}
            self.say(f"{a}: thermal setting kept as configured: {exc}")
        await self.stager.use("identification")  # with the length or gain

    async def heat_warm_ups(self) -> None:
        """The zone warm-up of each axis with no sensor, after the rounds, so that no run
        that fits a table measures a screw it warmed (before the rounds,
        their sweeps took its heat into the tables: smooth-3 X E 0.46 → 1.97 µm, rough-3 X
        0.66 → 2.45 at the judge's targets). Not where the drift references read so far
        rule out the heat it would show (:meth:`.thermal.ThermalSteps.too_little_heat`: a
        cold machine's technician needs no hour of warm-up), and where the budget left
        holds it. Its model
        replaces the one fitted to the drift references where it holds on their drift
        (:meth:`.drift.DriftRefs.adopt_warmed_motion`). The after-run follows, on the screw
        it left warm, with the final config: as the customer's laser meets the machine
        (after it, rough-0 read X E 1.81 µm with the references' model, fitted on that very
        drift; a judge after 30 minutes of other work read 2.13 µm with the warm-up's)."""
        for a in self.thermal.heat_zoned():
            if self._warmed(a):
                continue
            why = self.thermal.too_little_heat(a)
            if why is not None:
                self.record.state.setdefault("identify", {})[f"thermal-{a}"] = {
                    "fitted": False, "why": why}  # fmt: skip
                self.say(f"{a}: no warm-up: {why}")
                continue
            await self._warm_up_if_affordable(a)

    def _warmed(self, a: str) -> bool:
        """Its warm-up fitted already (before an interruption)."""
        tables = self.record.tables
        if a in tables.thermal_length_mm or a in tables.thermal_gain:
            return True
        return self.thermal.heat_warms_up(a) and f"thermal-{a}" in self.record.state.get(
            "identify", {})  # fmt: skip

    async def _backlash(self, a: str) -> None:
        """The backlash test at three places (seed 000), and the take-up where it shows
        lost motion; once (a short budget's order asks for it twice)."""
        if a in self.record.state.get("backlash_fitted", []):
            return
        travel = self.axes.travel(a)
        await self.runner.step(f"backlash-{a}", lambda: backlash_plan(a, travel), "off",
                               self.axes.park(a))  # fmt: skip
        b = backlash_from_raw(self.runner.raw(f"backlash-{a}"), a)
        self.record.state.setdefault("identify", {})[f"backlash-{a}"] = {
            "B_um": float(b.backlash_mm * 1e3), "places_um": [float(m * 1e3) for m in b.mean_mm]}
        await self.takeup.identify_takeup(a, b)
        self.record.state.setdefault("backlash_fitted", []).append(a)

    async def _iso(self, a: str) -> None:
        await self.runner.step(f"iso-{a}", lambda: self.plans.iso_plan(a), "off", self.axes.park(a))

    async def _table_first(self, a: str) -> None:
        """A linear axis's lead search and ISO runs, before any axis's other steps: stopped
        at a plain calibration's time (Ctrl-C, then ``--finish``), random machine 3 had X's
        table alone, Y's ISO runs not begun; now both (the rest of :meth:`_identify_axis`
        after)."""
        if not self.axes.rotary(a):
            await self._find_lead(a)
            await self._iso(a)

    async def _identify_axis(self, a: str) -> None:
        """Backlash, the lead search, the coarse ISO run, the cyclic scans and the *before*
        run of one axis, compensation off."""
        if self.axes.rotary(a):  # in degrees, with the angle instrument (rotary.py)
            await self.rotary.identify_rotary(a)
            return
        travel = self.axes.travel(a)
        await self._backlash(a)  # (each done already on a short budget but the lead search)
        await self._find_lead(a)
        await self._iso(a)
        if a in self.s.lead_mm:
            await self.runner.step(f"cyclic-{a}",
                                   lambda: cyclic_scans(a, travel, self.s.lead_mm[a]), "off",
                                   self.axes.park(a))  # fmt: skip
        if not self.plans.alone_path(a).exists():  # (a short budget's verdict: no before-run)
            await self.runner.step(f"before-{a}", lambda: self.plans.before_plan(a), "off",
                                   self.axes.park(a))  # fmt: skip

