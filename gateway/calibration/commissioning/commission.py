"""``compgw commission``: one command from an uncalibrated machine to verified tables.

The steps, each a plan run through the running gateway (readings appended and fsynced by
:mod:`..plans.runner`), each recorded in ``DIR/commission.json`` once done, so running the same
command again after Ctrl-C, a crash or a power loss carries on where it stopped:

1. identification config (no pitch, backlash, cyclic or planar stage) loaded; per axis
   with a thermal source and its sensor given, a warm-up for the thermal length (Δa) or
   gain (temperature), over a zone read inside and beyond it (:mod:`.thermal`);
   per axis seed 000's backlash at three places (and, where a reversal does not take the
   lost motion up at once, the reversal ladder: :mod:`.takeup`), a coarse ISO
   230-2 run, the cyclic scans
   (when the lead is known), and the *before* verification run (random targets off the
   table), ordered so that no axis is measured right after its own zone warm-up; the
   *before* XY run when the plane is commissioned;
2. tables fitted (the joint pitch + cyclic fit), the *pitch* config loaded, the XY grid
   measured and the planar model fitted (poly or grid by cross-validation), the *full*
   config loaded;
3. rounds of verification at targets never used for fitting (the new spans' midpoints and
   fresh random targets): judged by ISO 230-2 E (XY: maximum vector error) against the
   tolerance; an axis that misses is swept once over its whole travel (:mod:`..fitting.sweep`,
   :mod:`.refine`) when the budget allows; after that, where the residual
   stands out of the repeatability the span gets new table points (their values: the
   table's own plus the residual), a failing plane a denser grid; until within tolerance,
   out of rounds, or out of budget;
4. the *before* targets measured again with everything on (before / after on the same
   points), then random short steps on an axis with a take-up curve in what the budget
   has left (:mod:`.after`), the full config left loaded (the user's own where
   the plane reads worse with the tables than without), the report written.

A budget short of the first steps, the before- and after-runs and one round (the drift
references around each counted) takes every axis's ISO runs first, the plane's grid
right after them (with those tables on, as dense as the budget left allows:
:mod:`.short`), then the
backlash tests and the before-runs, and the lead searches and cyclic scans last (a plain
ISO 230-2 calibration's steps first, then what judges them, then the extras); spent
before the fit, it still fits the axes whose ISO runs were made (no round verified them,
said so). Where no round judged the tables, the after-run judges them as a round would
(:meth:`~.after.AfterSteps.after_verdict`).

The gateway is made to load each config by writing it over the config file it runs and
asking it to reload (the status unit's reload register, or SIGHUP / a command). An abort
puts the user's own config back, reloads it, and says so. Machine time is the plans'
estimate (:func:`..plans.plans.plan_time_s`): the same yardstick for any workflow.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import replace
from typing import Any

import numpy as np

from ...compensation.errors import TableError
from ...config import GatewayConfig
from ...formats import atomic_write_text, read_pitch_csv
from ..fitting import adaptive
from ..fitting.fit import planar_measurement
from ..fitting.outputs import (
    fit_cyclic_raw,
    fit_pitch,
    fit_planar,
    net_pitch,
    save_cyclic,
    save_pitch,
    save_planar,
)
from ..fitting.plane_frame import fitted_frame, reframe_plane, save_frame
from ..fitting.plans_scans import cyclic_plan
from ..fitting.takeup_fit import takeup_plan
from ..measuring.machine import MachineError
from ..plans.plans import (
    Plan,
    backlash_from_raw,
    backlash_plan,
    iso230_linear_plan,
    read_plan,
    targets_plan,
)
from ..plans.rawdata import axis_deviations, read_raw_csv
from ..plans.runner import read_raw_meta
from ..plans.xy import xy_grid_plan, xy_verification_plan
from .command import CommandChecks
from .steps import (
    BudgetSpent,
    CommissionAborted,
    _plain,
)

#: a verification's runs per target are doubled, up to this, before an axis is settled
MAX_VERIFY_RUNS = 8


class Commission(CommandChecks):
    """One commissioning: the plans, the order of the steps, the fits and the rounds."""

    # -- the whole thing -----------------------------------------------------------------
    def initial_plans(self) -> list[tuple[str, Plan]]:
        """The steps before any adaptation, for the printed plan and its estimate."""
        out: list[tuple[str, Plan]] = []
        for a in self.s.axes:
            if self._rotary(a):  # in degrees (rotary.py)
                out += self.rotary_plans(a)
                continue
            travel = self._travel(a)
            if self._thermal(a):
                out.append((f"warmup-{a}", self._warmup_plan(a)))
            out.append((f"backlash-{a}", backlash_plan(a, travel)))
            out.append((f"takeup-{a}", takeup_plan(a, travel)))  # if there is lost motion
            out.append((f"iso-{a}", self._iso_plan(a)))
            if a in self.s.lead_mm:
                out.append((f"cyclic-{a}", cyclic_plan(a, travel, self.s.lead_mm[a])))
            elif not self.s.no_lead_search:
                out.append((f"lead-{a}", self._lead_plan(a)))
        if self.s.planar is not None:
            out.append(("xy-grid", self._grid_plan(self.s.grid)))
        return [(n, self._snap(p)) for n, p in out]

    def _lead_plan(self, axis: str) -> Plan:
        """A dense scan in + around the middle of the travel, for the lead search."""
        from ..plans.plans import Move

        targets = adaptive.lead_scan_targets_mm(self._travel(axis))
        lo = self._travel(axis)[0]
        moves = [Move(1, -1, "takeup", (max(lo, float(targets[0]) - 1.0),))]
        moves += [Move(1, +1, "measure", (float(t),)) for t in targets]
        return Plan("lead-search", (axis,), tuple(moves), (("kind", "lead-search"),
                                                           ("axis", axis)))  # fmt: skip

    async def _find_lead(self, axis: str) -> None:
        """The lead search of an axis whose lead was not given (--lead-mm); not begun where
        the budget left holds it but not the cyclic scans a lead found would call for (the
        sdss plates at 1.5 x a manual calibration's time spent 8 of their 61 minutes on a
        search whose scans could not have followed)."""
        leads = self.state.setdefault("leads", {})
        if axis in self.s.lead_mm or axis in leads or self.s.no_lead_search:
            return
        scans = cyclic_plan(axis, self._travel(axis), min(adaptive.STANDARD_LEADS_MM))
        need_s = self.step_cost_s(self._lead_plan(axis)) + self.step_cost_s(scans)
        left_s = self.left_s()
        if need_s > left_s:
            note = (f"{axis}: no lead search: it and the cyclic scans it may call for need "
                    f"{need_s / 60:.1f} min of machine time, {max(0.0, left_s) / 60:.1f} min "
                    "left (--lead-mm gives the lead)")  # fmt: skip
            if note not in self.state["notes"]:
                self.say(note)
                self.state["notes"].append(note)
                self._save()
            return
        await self.step(f"lead-{axis}", lambda: self._lead_plan(axis), "off", self._park(axis))
        raw = self.raw(f"lead-{axis}")
        found = adaptive.find_lead(raw.target_mm, raw.deviation_mm)
        leads[axis] = found.lead_mm or 0.0
        self.state.setdefault("identify", {})[f"lead-{axis}"] = {
            "lead_mm": found.lead_mm or 0.0, "amplitude_um": found.amplitude_um,
            "f_ratio": found.f_ratio}  # fmt: skip
        if found.lead_mm:
            self.s.lead_mm[axis] = found.lead_mm
            self.say(f"{axis}: a periodic error of {found.amplitude_um:.2f} µm every "
                     f"{found.lead_mm:g} mm, taken as the screw's lead (--lead-mm gives it "
                     "where you know it); the cyclic stage follows it")  # fmt: skip
        else:
            self.say(f"{axis}: no periodic error stands out of the noise: no cyclic stage")
        self._save()

    def _iso_plan(self, axis: str, runs: int | None = None) -> Plan:
        lead = self.s.lead_mm.get(axis)
        return iso230_linear_plan(axis, self._travel(axis),
                                  step_mm=adaptive.coarse_step_mm(self._travel(axis), lead),
                                  runs=runs or self.iso_runs(),
                                  overrun_mm=1.0, lead_mm=lead, seed=self.s.seed)  # fmt: skip

    def _iso_runs_that_fit(self, axes: list[str]) -> None:
        """On a short budget, before the first ISO run: the runs per target every axis's ISO
        runs fit in (down to 2, the fewest that show a scatter), so that each axis gets a
        table rather than the last none (decided once, kept in the state; said). With the
        configured runs fitting, or not even 2, nothing changes."""
        if "iso_runs" in self.state or any(self.done(f"iso-{a}") for a in axes):
            return
        def fits(runs: int) -> bool:
            return sum(self.step_cost_s(self._iso_plan(a, runs)) for a in axes) <= self.left_s()

        runs = self.s.runs
        while runs > 2 and not fits(runs):
            runs -= 1
        if runs < self.s.runs and fits(runs):
            self.state["iso_runs"] = runs
            note = (f"{', '.join(axes)}: {runs} ISO runs per target instead of "
                    f"{self.s.runs}: the budget holds every axis's table only so")
            self.state["notes"].append(note)
            self.say(note)
        else:
            self.state["iso_runs"] = self.s.runs
        self._save()

    def _grid_plan(self, grid: tuple[int, int], runs: int = 2) -> Plan:
        (x0, x1), (y0, y1) = self._plane_travel()
        return xy_grid_plan((x0 + 2, x1 - 2), (y0 + 2, y1 - 2), grid[0], grid[1],
                            self.s.planar, runs=runs, approach_mm=1.0,
                            lower_mm=(x0, y0))  # fmt: skip

    def _before_xy_plan(self) -> Plan:
        """The plane's random points judged before anything is fitted and after."""
        return self._xy_check_plan(10_000 + self.s.seed, self.s.grid)

    def _xy_check_plan(self, seed: int, grid: tuple[int, int]) -> Plan:
        (x0, x1), (y0, y1) = self._plane_travel()
        return xy_verification_plan((x0 + 2, x1 - 2), (y0 + 2, y1 - 2), grid[0], grid[1],
                                    self.s.planar, mode="random", count=adaptive.RANDOM_TARGETS,
                                    seed=seed, approach_mm=1.0, lower_mm=(x0, y0))  # fmt: skip

    async def run(self) -> dict[str, Any]:
        """Commission; returns the summary (also in DIR/summary.json). Raises
        CommissionAborted (after restoring the user's config) on a machine fault."""
        done = self.state.pop("finished", None)
        if done is not None:  # asked for more: carries on
            self._carry_on(done)
        if "what" not in self.state:
            self.state["what"] = self._what()
            self._save()
        self.adopt_edits()
        self.original()
        try:
            await self._identify()
            await self._fit_axes(curves=bool(self.state.get("short")))
            await self._plane()
            outcome = await self._rounds()
            ending = len(self.state["notes"])
        except BudgetSpent as exc:
            ending = len(self.state["notes"])
            self.state["notes"].append(f"budget spent: {exc}")
            self.say(f"budget spent: {exc}")
            outcome = "budget"
            self._restore_best()  # a refinement not yet judged is not kept
            await self._fit_identified()
        except (MachineError, OSError) as exc:
            where = await self.restore(exc)
            raise CommissionAborted(f"{exc}; {where}") from exc
        self.fit_motion_heat()
        try:
            await self._after()
        except BudgetSpent as exc:
            self.state["notes"].append(f"no after-run: {exc}")
        self.motion_for_sensors()  # after the after-run: see its docstring
        worse = self.plane_worse()
        if worse is not None:
            self.state["notes"].append(worse)
            self.say(worse)
        else:
            outcome = self.after_verdict(outcome)
        if self.tables.pitch and worse is None:
            await self.use("full")
        else:
            self.say(await self.restore())
        summary = self.summary(outcome)
        atomic_write_text(self.dir / "summary.json", json.dumps(summary, indent=1,
                                                                default=_plain))  # fmt: skip
        self.state["finished"] = {"outcome": outcome, "asked": self._asked(),
                                  "machine_h": self.used_s / 3600, "notes_from": ending}
        self._save()
        return summary

    def _carry_on(self, done: dict[str, Any]) -> None:
        """A finished commissioning asked for more (budget, rounds, a tighter tolerance):
        what its ending said is dropped (a budget spent, an after-run's verdict) and its
        after-run measured again at the end, with the tables then loaded (its readings
        moved to ``raw/superseded/``); a note says where it carried on from."""
        notes = self.state["notes"]
        del notes[int(done.get("notes_from", len(notes))):]
        for name in [n for n in self.state["steps"] if n.startswith("after-")]:
            self.forget(name, keep_in=self.dir / "raw" / "superseded")
        used = done.get("machine_h")
        notes.append(f"carried on after '{done.get('outcome')}'"
                     + (f" at {used:.2f} h of machine time" if used is not None else ""))
        self._save()

    # -- 1. identification ---------------------------------------------------------------
    async def _identify(self) -> None:
        """The warm-ups and each axis's identification runs, ordered so that no axis is
        measured right after its own zone warm-up: the first zone-warmed axis is identified
        last, every other one before its warm-up (cold, with the configured thermal
        setting; the drift references take what it misses). A zone's heat the sensor's
        model cannot place (a temperature at one spot, the linear spread) then fades for
        hours before its axis is measured, instead of going into its table. On a short
        budget the plain calibration's steps come first, and each warm-up after them only
        where the budget left holds it (:meth:`_plain_steps_first`)."""
        await self.read_start_temperatures()
        await self.use("identification")
        zoned = self._zoned()
        if self.short():  # a plain ISO 230-2 calibration's steps first, warm-ups after
            await self._plain_steps_first([a for a in self.s.axes if not self._rotary(a)])
            for a in zoned:  # each where the budget left holds it
                await self._warm_up_if_affordable(a)
            for a in self.s.axes:
                await self._identify_axis(a)
            await self._before_xy()
            self._save()
            return
        if zoned:
            await self._warm_up(zoned[0])
        for a in zoned[1:]:
            await self._identify_axis(a)
            await self._warm_up(a)
        rest = [a for a in self.s.axes if a not in zoned] + zoned[:1]
        for a in rest:
            await self._identify_axis(a)
        await self._before_xy()
        self._save()

    async def _plain_steps_first(self, cores: list[str]) -> None:
        """On a short budget, a plain ISO 230-2 calibration's steps before anything else,
        thermal settings or not (the zone warm-ups came first and a 0.9 h budget spent 45
        minutes warming X and ended with no table: issue 54): every linear axis's ISO runs,
        the plane's grid with their tables on, the backlash tests, the before-runs."""
        self._iso_runs_that_fit(cores)
        for a in cores:
            await self._iso(a)
        for a in cores:  # where the tables miss between their points
            await self.densify(a)
        if self.s.planar is not None and set(self.s.planar) <= set(cores):
            await self._before_xy()  # (what the plane's check and report need)
            await self._fit_axes(cores, curves=True)
            await self._plane()
            await self.use("identification")  # the rest is measured without them
        for a in cores:  # (the bidirectional tables hold the backlash meanwhile)
            await self._backlash(a)
        for a in cores:  # what the report judges them by, before any lead search
            await self.step(f"before-{a}", lambda a=a: self._before_plan(a), "off",
                            self._park(a))  # fmt: skip

    async def _warm_up_if_affordable(self, a: str) -> None:
        """The zone warm-up of ``a`` where the budget left holds it; else said, and the
        configured thermal setting kept."""
        if a in self.tables.thermal_length_mm or a in self.tables.thermal_gain:
            return
        cost_s = self.step_cost_s(self._warmup_plan(a), drift=False)
        if not self.done(f"warmup-{a}") and cost_s > self.left_s():
            self.state.setdefault("identify", {})[f"thermal-{a}"] = {
                "fitted": False, "why": f"its warm-up ({cost_s / 60:.0f} min) is not in the "
                f"budget left ({max(self.left_s(), 0.0) / 60:.0f} min)"}  # fmt: skip
            self.say(f"{a}: thermal setting kept as configured: its warm-up "
                     f"({cost_s / 60:.0f} min) is not in the budget left")  # fmt: skip
            return
        await self._warm_up(a)

    async def _before_xy(self) -> None:
        """The plane's random points before anything is fitted (judged again at the end)."""
        if self.s.planar is not None:
            await self.step("before-xy", self._before_xy_plan, "off")

    def _zoned(self) -> list[str]:
        """The linear axes with a thermal setting: each gets a zone warm-up (on a short
        budget after the plain calibration's steps, where the budget holds it)."""
        return [a for a in self.s.axes if not self._rotary(a) and self._thermal(a)]

    async def _warm_up(self, a: str) -> None:
        """The axis's warm-up (thermal off) and its fit; the identification config back."""
        if a in self.tables.thermal_length_mm or a in self.tables.thermal_gain:
            return  # fitted before an interruption
        results = self.state.setdefault("identify", {})
        await self.use("warmup")
        # the travel so far (the drift log's odometers): heat still fading in the warm-up
        self.state.setdefault("warmup_log", {}).setdefault(
            a, len(self.state.get("drift_log", [])))
        raw = await self.step(f"warmup-{a}", lambda: self._warmup_plan(a), "off", drift=False)
        try:
            results[f"thermal-{a}"] = self._fit_thermal(a, read_raw_csv(raw))
        except TableError as exc:  # the config's own setting stays
            results[f"thermal-{a}"] = {"fitted": False, "why": str(exc)}
            self.say(f"{a}: thermal setting kept as configured: {exc}")
        await self.use("identification")  # with the length or gain

    async def _backlash(self, a: str) -> None:
        """The backlash test at three places (seed 000), and the take-up where it shows
        lost motion; once (a short budget's order asks for it twice)."""
        if a in self.state.get("backlash_fitted", []):
            return
        travel = self._travel(a)
        await self.step(f"backlash-{a}", lambda: backlash_plan(a, travel), "off", self._park(a))
        b = backlash_from_raw(self.raw(f"backlash-{a}"), a)
        self.state.setdefault("identify", {})[f"backlash-{a}"] = {
            "B_um": float(b.backlash_mm * 1e3), "places_um": [float(m * 1e3) for m in b.mean_mm]}
        await self.identify_takeup(a, b)
        self.state.setdefault("backlash_fitted", []).append(a)

    async def _iso(self, a: str) -> None:
        await self.step(f"iso-{a}", lambda: self._iso_plan(a), "off", self._park(a))

    async def _identify_axis(self, a: str) -> None:
        """Backlash, the lead search, the coarse ISO run, the cyclic scans and the *before*
        run of one axis, compensation off."""
        if self._rotary(a):  # in degrees, with the angle instrument (rotary.py)
            await self.identify_rotary(a)
            return
        travel = self._travel(a)
        await self._backlash(a)  # (each done already on a short budget but the lead search)
        await self._find_lead(a)
        await self._iso(a)
        if a in self.s.lead_mm:
            await self.step(f"cyclic-{a}", lambda: cyclic_plan(a, travel, self.s.lead_mm[a]),
                            "off", self._park(a))  # fmt: skip
        await self.step(f"before-{a}", lambda: self._before_plan(a), "off", self._park(a))

    def _before_plan(self, axis: str, avoid_mm: np.ndarray | None = None) -> Plan:
        """The targets judged before and after: random, off the coarse table's points
        (``avoid_mm``, default the ISO runs' targets)."""
        avoid = self.iso_targets(axis) if avoid_mm is None else avoid_mm
        targets = adaptive.random_targets_mm(self._travel(axis), 2 * adaptive.RANDOM_TARGETS,
                                             1000 + self.s.seed, avoid)  # fmt: skip
        return targets_plan(axis, self._travel(axis), targets, self.s.verify_runs,
                            kind="iso230-verification", note="before-after")  # fmt: skip

    # -- 2. fit, XY ----------------------------------------------------------------------
    async def _fit_identified(self) -> None:
        """The budget ran out before the fit: the tables of the linear axes whose ISO runs
        were made (with the cyclic term where its scans were made too), as a plain ISO
        230-2 calibration would fit them, and said to be unverified; the other axes get
        none. Tables fitted already (a short budget fits them for the plane's grid) take
        in the cyclic scans made since, and are said to be unverified unless a round
        verified them."""
        if self.tables.pitch:  # fitted already (on a short budget, for the plane's grid):
            ready = [a for a in self.s.axes if a in self.tables.pitch]  # the scans made since
            await self._fit_axes(ready, curves=True)
            if self.state["rounds"]:
                return  # verified in a round
        else:
            ready = [a for a in self.s.axes if not self._rotary(a) and self.done(f"iso-{a}")]
            if not ready:
                return
            await self._fit_axes(ready, curves=True)
        rest = [a for a in self.s.axes if a not in ready]
        bare = [a for a in ready if a in self.s.lead_mm and a not in self.tables.cyclic]
        note = (f"{', '.join(ready)}: fitted from the identification's runs only, no round "
                "verified them between the points (the budget ran out)"
                + (f"; {', '.join(bare)}: no cyclic term (its scans were not made)"
                   if bare else "")
                + (f"; {', '.join(rest)}: not identified, no table" if rest else ""))
        self.state["notes"].append(note)
        self.say(note)
        self._save()

    async def _fit_axes(self, axes: list[str] | None = None, curves: bool = False) -> None:
        """The tables from the identification runs of ``axes`` (all: the commissioned),
        read along the curve their own leave-one-out prefers with ``curves`` (tables no
        round will measure between their points, :meth:`interpolate`)."""
        axes = list(self.s.axes) if axes is None else axes
        scanned = [a for a in axes if a in self.s.lead_mm and self.done(f"cyclic-{a}")]
        if all(a in self.tables.pitch for a in axes) and \
                all(a in self.tables.cyclic for a in scanned):  # (a short budget's resumed)
            return
        tables_dir = self.dir / "tables"
        tables_dir.mkdir(parents=True, exist_ok=True)
        for a in axes:
            self.tables.pitch[a] = self._rel(tables_dir / f"{a.lower()}_pitch.csv")
            if a in scanned:
                self.tables.cyclic[a] = self._rel(tables_dir / f"{a.lower()}_cyclic.yaml")
        config, _ = self.staged("pitch")
        for a in axes:
            model = None
            if a in scanned:
                raw_c = self.raw_paths(f"cyclic-{a}")[0]
                cr = fit_cyclic_raw(self.raw(f"cyclic-{a}"), read_raw_meta(raw_c), config,
                                    self.config_dir, a)  # fmt: skip
                save_cyclic(cr, "compgw commission: dense scans")
                model = cr.model
                self.state.setdefault("identify", {})[f"cyclic-{a}"] = {
                    "harmonics": cr.fit.harmonics, "peak_um": cr.model.peak_mm() * 1e3}
            # the reversal per point or as a curve, by what the ISO runs' own scatter says
            # each would leave (a worn zone of the nut: per point)
            r = fit_pitch(self.iso_raw(a), config, self.config_dir, a,
                          mode="bidirectional", reversal="auto")  # fmt: skip
            r = self.rotary_fitted(a, r)
            if r.reversal is not None:
                self.state.setdefault("identify", {})[f"reversal-{a}"] = r.reversal.summary()
            if model is not None:
                r = net_pitch(r, model, config)
            r = replace(r, table=self.smoothed(a, r.table, config))
            save_pitch(r, "compgw commission: coarse ISO 230-2 run" +
                       (", net of the cyclic term" if model is not None else ""))  # fmt: skip
            self.interpolate(a, r.table, curves)
            self.state.setdefault("spans", {})[a] = None  # every span is new: all verified
        self._save()
        await self.use("pitch")

    async def _plane(self) -> None:
        if self.s.planar is None or self.tables.planar_model is not None:
            return
        grid = self._first_grid()
        # each stage loads its phase on entry, as _identify, _rounds and _after do (a no-op
        # when loaded): the fit's own load is skipped on a resume after an abort put your
        # config back (trial 8 read a resumed grid without the tables, round 1's plane 44 µm)
        await self.use("pitch")
        await self.step("xy-grid", lambda: self._grid_plan(grid), "on")
        self.tables.planar_axes = self.s.planar
        self.tables.planar_model = self._rel(self.dir / "tables" / "xy_model.yaml")
        config, _ = self.staged("full")
        self._fit_plane(config, "xy-grid", residual=False)
        self._save()
        await self.use("full")

    def _fit_plane(self, config: GatewayConfig, name: str, residual: bool) -> None:
        """The plane from grid run ``name`` (read with the tables on disk loaded), and its
        frame: those tables' values at the grid's nodes, where the model is faded."""
        assert self.s.planar is not None
        meas = planar_measurement(self.raw(name), self.s.planar)
        ax, ay = self.s.planar
        lines = {ax: self._park(ax)[ay], ay: self._park(ay)[ax]}
        res = fit_planar(meas, config, self.config_dir, "auto", residual, lines)
        save_planar(res, "compgw commission")
        save_frame(res.points_path, fitted_frame(res.choice.pinned, meas, config,
                                                 self.config_dir, self.s.planar, lines))
        self.state.setdefault("planar_fits", []).append(
            {"kind": res.choice.kind, "pinned": res.choice.pinned,
             "loo_rms_um": res.choice.loo_rms_um, "residual": residual})  # fmt: skip

    def before_load(self, phase: str) -> None:
        """The plane re-expressed against the tables it is about to run with, where it is
        faded and they changed since it was fitted (:mod:`..fitting.plane_frame`)."""
        if phase == "full":
            reframe_plane(self.staged("full")[0], self.config_dir)

    # -- 3. verification rounds ----------------------------------------------------------
    async def _rounds(self) -> str:
        """Verify; keep the best tables; refine what misses; a refinement that does not pay
        is taken back and its axis (or the plane) settled at its best."""
        await self.use(self._tables_phase)
        rounds = self.state["rounds"]
        best = self.state.setdefault("best", {})
        settled = self.state.setdefault("settled", [])
        while len(rounds) < self.s.max_rounds:
            r = len(rounds) + 1
            verdicts, xy = await self._verify(r)
            entry: dict[str, Any] = {"round": r, "axes": {a: v.to_json()
                                                          for a, v in verdicts.items()},
                                     "xy": xy, "machine_s": self.used_s}  # fmt: skip
            self.say(f"round {r}: " + "; ".join(
                self.verdict_text(a, v) for a, v in verdicts.items())
                + (f"; XY max {xy['max_um']:.2f} µm" if xy else ""))  # fmt: skip
            scores = {a: v.E_um for a, v in verdicts.items()}
            if xy is not None:
                scores["XY"] = xy["max_um"]
            last = rounds[-1] if rounds else {}
            swept = set(last.get("swept") or [])
            restored = [name for name, score in scores.items() if name not in settled
                        and not self._keep_best(name, score, r,
                                                xy["rms_um"] if name == "XY" and xy else None,
                                                swept=name in swept,
                                                noise=verdicts[name].noise_um
                                                if name in verdicts else 0.0)]  # fmt: skip
            more_runs: dict[str, int] = {}
            for name in restored:
                what = "model" if name == "XY" else "table"
                refined = (name in swept or (last.get("added") or {}).get(name)
                           or (name == "XY" and "grid" in last))  # fmt: skip
                self.say(f"round {r}: {name}: " + (
                    "the last refinement did not pay; back to round " if refined else
                    f"read {self.score_text(name, scores[name])}, not refined since round ")
                    + f"{best[name]['round']}'s {what} "
                    f"({self.score_text(name, best[name]['score'])})")  # fmt: skip
                self._settle(r, name, more_runs)
            names = [*self.s.axes, *(["XY"] if self.s.planar else [])]
            good = {n: n in best and best[n]["score"] <= self.tolerance_of(n) for n in names}
            entry["restored"] = restored
            if all(good.values()):
                entry["outcome"] = "within"
                rounds.append(entry)
                self._save()
                if restored:
                    await self.use(self._tables_phase)
                self.say(f"round {r}: within {self.tolerance_text()} between the points")
                return "within"
            added: dict[str, int] = {}
            refining = [a for a in verdicts
                        if not good[a] and a not in settled and a not in more_runs]
            plane = "XY" in scores and not good["XY"] and "XY" not in settled
            # what the round may spend, shared in turn (the worst axis first, the plane
            # last): each takes an equal share of what is left, a sweep as much as leaves
            # half an equal share for each one after it
            claimants = len(refining) + plane
            keep_s = 0.5 * self._refine_allowance_s(r, claimants)
            trimmed = []
            for i, a in enumerate(sorted(refining, key=lambda n: -verdicts[n].E_um)):
                pool_s = self._refine_allowance_s(r, 1)
                coarser = self._sweeps(r, a, pool_s - (claimants - i - 1) * keep_s)
                if coarser is not None:
                    added[a] = await self._sweep_axis(r, a, coarser)
                    entry.setdefault("swept", []).append(a)
                    continue
                v = self._affordable(r, a, verdicts[a], pool_s / (claimants - i))
                if len(v.failing_spans) < len(verdicts[a].failing_spans):
                    trimmed.append(f"{a} {len(v.failing_spans)} of "
                                   f"{len(verdicts[a].failing_spans)} spans")
                added[a] = await self._refine_axis(r, a, v) if v.failing_spans else 0
                if not added[a] and v.failing_spans == verdicts[a].failing_spans:
                    self._settle(r, a, more_runs)
            if trimmed:
                entry["budget"] = trimmed
                self.say(f"round {r}: the budget allows the worst spans only: "
                         + ", ".join(trimmed))  # fmt: skip
            denser = adaptive.denser_grid(*tuple(self.state.get("grid", self.s.grid)))
            if plane and self.estimate_s(self._grid_plan(denser, runs=1)) \
                    > self._refine_allowance_s(r, 1):
                settled.append("XY")  # a denser grid does not fit in what is left
                entry.setdefault("budget", []).append("XY: no denser grid")
            elif plane:
                if self.state.get("densified", 0) < 2:
                    entry["grid"] = list(await self._refine_plane(r))
                    self.state["densified"] = self.state.get("densified", 0) + 1
                else:
                    settled.append("XY")
            entry["added"] = added
            if more_runs:
                entry["verify_runs"] = more_runs
            rounds.append(entry)
            self._save()
            if not any(added.values()) and "grid" not in entry and not more_runs \
                    and "swept" not in entry:
                if restored:
                    await self.use(self._tables_phase)
                if "budget" in entry:
                    self.say(f"round {r}: no refinement and the round after it fit in the "
                             "budget left")  # fmt: skip
                    return "budget"
                self.say(f"round {r}: nothing left to refine where it misses (repeatability "
                         "or structure below the table's resolution)")  # fmt: skip
                return "floor"
            await self.use(self._tables_phase)
        return "rounds"

    def verify_runs(self, axis: str) -> int:
        """Runs per verification (and refinement) target of an axis: ``verify_runs`` until
        its residuals hide in their noise (see :meth:`_settle`)."""
        return int(self.state.get("verify_runs", {}).get(axis, self.s.verify_runs))

    def _settle(self, r: int, name: str, more_runs: dict[str, int]) -> None:
        """An axis with nothing left to refine at its verification's noise (no span stands
        out of 3 standard errors of a target mean, or the last refinement did not pay) is
        settled, unless it misses its tolerance and the budget affords a verification with
        twice the runs (up to ``MAX_VERIFY_RUNS``): the standard error of a mean falls as
        1/√runs, so residuals the scatter of single stops hid then stand out. The best
        table is judged again at the new runs (its score at fewer runs read more noise)."""
        settled = self.state.setdefault("settled", [])
        best = self.state.get("best", {}).get(name)
        runs = self.verify_runs(name)
        # the next verification costs twice this round's; a refinement about as much again
        if (name == "XY" or best is None or best["score"] <= self.tolerance_of(name)
                or 2 * runs > MAX_VERIFY_RUNS
                or 2 * self._verify_s(r, name) > self._refine_allowance_s(r, 1)):
            settled.append(name)
            return
        self.state.setdefault("verify_runs", {})[name] = 2 * runs
        self.state.setdefault("spans", {})[name] = []  # no new span: random targets only
        del self.state["best"][name]  # its next score, at 2 × runs, is the new baseline
        more_runs[name] = 2 * runs
        self.say(f"round {r}: {name}: what misses is within the noise of {runs} runs; "
                 f"verified again with {2 * runs}")  # fmt: skip

    @property
    def _tables_phase(self) -> str:
        """The config the fitted tables run in: "full" once the plane is fitted."""
        return "full" if self.tables.planar_model else "pitch"

    def reserve_s(self) -> float:
        """The after-run (the before-run's targets again) is kept out of the budget."""
        plans = [self.dir / "plans" / f"before-{a}.plan" for a in self.s.axes]
        if self.s.planar is not None:
            plans.append(self.dir / "plans" / "before-xy.plan")
        # and the drift references read around each of its runs and the last config switch
        total = 2 * self.refs_cost_s(self.ref_axes())
        for path in plans:
            if path.exists():
                plan = read_plan(path)
                total += self.estimate_s(plan) + self.refs_around_s(plan)
        return total

    def _verify_targets(self, r: int, axis: str) -> np.ndarray:
        table = read_pitch_csv(self.config_dir / self.tables.pitch[axis]).position_mm
        if self._rotary(axis):
            return self.rotary_verify_targets(r, axis, table)
        spans = self.state.get("spans", {}).get(axis)  # None: all spans new
        mids = adaptive.midpoints_mm(table, spans)
        rand = adaptive.random_targets_mm(self._travel(axis), adaptive.RANDOM_TARGETS,
                                          100 * r + self.s.seed, table)  # fmt: skip
        targets = np.unique(np.concatenate([mids, rand]))
        return targets

    async def _verify(self, r: int) -> tuple[dict[str, adaptive.AxisVerdict], dict | None]:
        """Round ``r``'s verification of every axis not settled and of the plane; begun only
        where the budget holds all of it (one axis verified alone judges nothing: at 1.5 x a
        manual calibration's time the sdss plates verified X, 5.9 min, and not Y)."""
        settled = self.state.get("settled", [])
        makes: dict[str, Callable[[], Plan]] = {
            a: (lambda a=a: targets_plan(a, self._travel(a), self._verify_targets(r, a),
                                         self.verify_runs(a), kind="iso230-verification",
                                         round=r))
            for a in self.s.axes if a not in settled}  # (settled: nothing new to judge)
        if self.s.planar is not None and "XY" not in settled:
            grid = tuple(self.state.get("grid", self.s.grid))
            makes["xy"] = lambda: self._xy_check_plan(r, grid)
        if not any((self.dir / "plans" / f"verify{r}-{n}.plan").exists() for n in makes):
            need_s = sum(self.step_cost_s(make()) for make in makes.values())
            left_s = self.left_s()
            if need_s > left_s:
                raise BudgetSpent(f"round {r}'s verification needs {need_s / 60:.1f} min of "
                                  f"machine time, {max(0.0, left_s) / 60:.1f} min left")
        verdicts = {}
        for a in [a for a in makes if a != "xy"]:
            await self.step(f"verify{r}-{a}", makes[a], "on", self._park(a))
            table = read_pitch_csv(self.config_dir / self.tables.pitch[a]).position_mm
            dev = axis_deviations(self.raw(f"verify{r}-{a}"), a)
            verdicts[a] = self.judge(a, dev, table)
        xy = None
        if "xy" in makes:
            await self.step(f"verify{r}-xy", makes["xy"], "on")
            xy = self._xy_figures(f"verify{r}-xy")
        return verdicts, xy

    async def _refine_plane(self, r: int) -> tuple[int, int]:
        grid = adaptive.denser_grid(*tuple(self.state.get("grid", self.s.grid)))
        if not self.done(f"refine{r}-xy"):  # the round's new tables loaded: the frame read
            await self.use(self._tables_phase)
        await self.step(f"refine{r}-xy", lambda: self._grid_plan(grid, runs=1), "on")
        config, _ = self.staged("full")
        self._fit_plane(config, f"refine{r}-xy", residual=True)
        self.state["grid"] = list(grid)
        return grid
