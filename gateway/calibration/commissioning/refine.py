"""``compgw commission``'s refinements (what :mod:`.rounds` calls): what a
round may spend, the new table points in failing spans (short scans where there is a
cyclic term) and, once per axis, the sweep of the whole travel (:mod:`..fitting.sweep`).

An axis that misses its tolerance is swept first, when the budget affords it: one reading
every eighth of a lead over the whole travel, each way, gives the table a point at every
target read and the cyclic term a station every few leads, each held as smooth as
cross-validation says the readings allow. Spans that still miss after it are refined one
by one. A sweep that does not pay is taken back like any refinement. A swing axis is swept
too, every 0.25° (its screw's turns are uneven in angle, so the fit is its level alone); a
turntable is not (its worm scans and harmonics are its own).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import numpy as np

from ...compensation import PitchStage, PitchTable
from ...compensation.cyclic import CyclicModel
from ...compensation.errors import CompensationError
from ...config import GatewayConfig
from ...formats import atomic_write_text, read_cyclic, read_pitch_csv, write_cyclic
from ..fitting import adaptive
from ..fitting.cyclic_fit import scans_from_raw
from ..fitting.fit import smoothed_table
from ..fitting.iso230 import ARCSEC_PER_MDEG
from ..fitting.plans_scans import cyclic_plan, sweep_plan
from ..fitting.sweep import (
    LINE_MARGIN,
    SweepRefinement,
    fit_sweep,
    harmonics_for_step,
    sweep_refinement,
    sweep_steps_mm,
    sweep_targets_mm,
)
from ..fitting.table_cv import choose_interpolation
from ..plans.plans import ROTARY_OVERRUN_DEG, Plan, read_plan, targets_plan
from ..plans.rawdata import axis_deviations
from .rotary import SWING_KNOT_GAP_STEPS, SWING_SWEEP_STEPS_DEG

if TYPE_CHECKING:
    from .axes import Axes
    from .budget import Budget
    from .drift import DriftRefs
    from .record import Record
    from .rotary import RotarySteps
    from .stager import Stager
    from .steps import StepRunner

Say = Callable[[str], None]

#: a table is read along a curve only where its leave-one-out misses at most this fraction
#: of straight lines' (a near tie is noise of the points; straight lines stay local)
CURVE_GAIN = 0.97
#: a sweep's pieces, each between its own drift references (mm)
SWEEP_PIECE_MM = 120.0


class RefineSteps:
    """What a round refines, and how: new points in failing spans, or the sweep."""

    def __init__(self, axes: Axes, record: Record, drift: DriftRefs, stager: Stager,
                 budget: Budget, runner: StepRunner, rotary: RotarySteps, say: Say) -> None:
        self.axes = axes
        self.record = record
        self.drift = drift
        self.stager = stager
        self.budget = budget
        self.runner = runner
        self.rotary = rotary
        self.say = say

    def interpolation_of(self, axis: str) -> str:
        """The interpolation chosen for ``axis``'s table (a rotary axis's by its fit)."""
        if not self.axes.rotary(axis):
            return self.record.tables.interpolation.get(axis, "linear")
        return str(self.record.state.get("rotary", {}).get(axis, {}).get("interpolation", "linear"))

    def table_stage(self, axis: str, table: PitchTable, method: str | None = None
                    ) -> PitchStage:  # fmt: skip
        """The stage the gateway builds from ``table``: the chosen interpolation (or
        ``method``), the wrap."""
        return PitchStage(table, method or self.interpolation_of(axis),  # type: ignore[arg-type]
                          wrap=self.axes.wraps(axis))  # fmt: skip

    def allowance_s(self, r: int, sharing: int) -> float:
        """Machine time (s) each of ``sharing`` refinements may take: what the budget has
        left once the next round's verification (this round's again) and the after-run
        are kept, shared evenly."""
        steps = self.record.state["steps"]
        verify_s = sum(steps[name]["machine_s"] for name in steps
                       if name.startswith(f"verify{r}-"))  # fmt: skip
        # and the drift references read around the config switch that loads the new tables
        switch_s = 2 * self.drift.refs_cost_s(self.axes.ref_axes())
        left = self.budget.left_s() - verify_s - switch_s
        return max(0.0, left) / max(1, sharing)

    def affordable(self, r: int, axis: str, verdict: adaptive.AxisVerdict,
                    allowance_s: float) -> adaptive.AxisVerdict:
        """``verdict`` with as many of its worst failing spans as a refinement (and the
        four new midpoints each adds to the next verification) can measure in
        ``allowance_s``."""
        count = len(verdict.failing_spans)
        per_target = self._verify_target_s(r, axis)
        while count > 0:
            v = verdict.worst_first(count)
            plan = self._refine_plan(r, axis, v)
            whole = axis in self.record.tables.cyclic
            cost = 0.0 if plan is None else self.budget.step_cost_s(plan, whole=whole)
            if cost + 4 * count * per_target <= allowance_s:
                return v
            count = count * 2 // 3 if count > 3 else count - 1
        return verdict.worst_first(0)

    def _verify_target_s(self, r: int, axis: str) -> float:
        """Machine time (s) one more verification target of ``axis`` costs (this round's)."""
        path = self.record.dir / "plans" / f"verify{r}-{axis}.plan"
        if not path.exists():
            return 0.0
        targets = max(1, len(np.unique(read_plan(path).targets_mm(axis))))
        return self.verify_s(r, axis) / targets

    def verify_s(self, r: int, axis: str) -> float:
        """Machine time (s) of round ``r``'s verification of ``axis`` (0 before it)."""
        path = self.record.dir / "plans" / f"verify{r}-{axis}.plan"
        return self.axes.estimate_s(read_plan(path)) if path.exists() else 0.0

    def _refine_plan(self, r: int, axis: str, verdict: adaptive.AxisVerdict) -> Plan | None:
        """The refinement's plan for ``verdict``'s failing spans (None: no point to add)."""
        table = read_pitch_csv(self.record.config_dir / self.record.tables.pitch[axis])
        mids = self.rotary.refine_points(axis, table, verdict)
        if mids.size == 0:
            return None
        if axis in self.record.tables.cyclic:
            lead = read_cyclic(self.record.config_dir / self.record.tables.cyclic[axis]).lead_mm
            half = 0.5 * adaptive.SCAN_LEADS * lead + 1.0
            lo, hi = self.axes.travel(axis)
            stations = np.unique(np.round(np.clip(mids, lo + half, hi - half), 4))
            return self.axes.snap(cyclic_plan(axis, (lo, hi), lead, stations.tolist(),
                                          per_lead=adaptive.SCAN_PER_LEAD,
                                          leads=adaptive.SCAN_LEADS, kind="refine-scan"))
        return self.axes.snap(targets_plan(axis, self.axes.travel(axis), mids,
                                           self.budget.verify_runs(axis),
                                       kind="iso230-refine", round=r))  # fmt: skip

    async def refine_axis(self, r: int, axis: str, verdict: adaptive.AxisVerdict) -> int:
        """New table points in the failing spans (each cut in ``REFINE_PARTS``); their values
        from the residual measured there with the table on. With a cyclic term, each new
        point is a short scan over a whole lead: its mean gives the point (no cyclic term
        aliased into it) and its harmonics a new cyclic station. Returns the points added."""
        path = self.record.config_dir / self.record.tables.pitch[axis]
        table = read_pitch_csv(path)
        mids = self.rotary.refine_points(axis, table, verdict)
        if mids.size == 0:
            return 0
        config, _ = self.stager.staged(self.record.tables_phase)
        stage = self.table_stage(axis, table)
        cyclic = self.record.tables.cyclic
        cyclic_path = self.record.config_dir / cyclic[axis] if axis in cyclic \
            else None  # fmt: skip
        name = f"refine{r}-{axis}"
        await self.runner.step(name, lambda: self._refine_plan(r, axis, verdict), "on",  # type: ignore[arg-type,return-value]
                        self.axes.park(axis), whole=cyclic_path is not None)  # fmt: skip
        if cyclic_path is not None:  # one scan per new point: a whole plan between references
            model = read_cyclic(cyclic_path)
            stations = [float(s) for s in dict(read_plan(self.record.dir / "plans" / f"{name}.plan")
                                               .meta)["stations_mm"].split()]  # fmt: skip
            where, scans = scans_from_raw(self.runner.raw(name), axis, model.lead_mm, stations)
            ref = adaptive.scan_refinement(table, stage, model, where, scans)
            new, new_model = ref.table, ref.cyclic
        else:
            dev = axis_deviations(self.runner.raw(name), axis)
            new, new_model = adaptive.refined_table(table, stage, dev), None
        if not self._write_tables(axis, config, new, new_model, f"refined in round {r}"):
            return 0
        added = int(new.position_mm.size - table.position_mm.size)
        x = new.position_mm
        self.record.state.setdefault("spans", {})[axis] = [
            int(i) for i in range(x.size - 1)
            if np.any(np.isclose(x[i], mids, atol=1e-3)) or np.any(np.isclose(x[i + 1], mids,
                                                                              atol=1e-3))]
        return added

    def smoothed(self, axis: str, table: PitchTable, config: GatewayConfig) -> PitchTable:
        """A linear axis's table smoothed as much as its own leave-one-out says, its points
        moved by no more than the standard error of an ISO point (the ISO runs' scatter
        over √runs; :func:`..fitting.fit.smoothed_table`), what it changed kept in the state; the
        table as it is for a rotary axis (its interpolation is chosen by leave-one-out
        instead) or where the smoothed one would not load (the raw one is checked by the
        caller)."""
        from ..fitting.outputs import check_pitch

        scatter = self.drift.iso_scatter_um(axis)
        if self.axes.rotary(axis) or scatter is None:
            return table
        fit = smoothed_table(table, scatter * 1e-3, self.budget.iso_runs())
        try:
            check_pitch(fit.table, config, axis)
        except CompensationError:
            return table
        # the last write's (the report's identification list)
        self.record.state.setdefault("identify", {})[f"smoothed-{axis}"] = {
            "change_rms_um": fit.change_rms_mm * 1e3, "weight": max(fit.lambdas)}
        return fit.table

    def interpolate(self, axis: str, table: PitchTable, curve: bool = False) -> None:
        """A linear axis's interpolation between its table's points, kept in the tables.
        Straight lines, unless ``curve``: a table no verification round will measure
        between its points (a short budget's, one fitted when the budget ran out), whose
        points are each the mean of their own readings; then the method whose
        leave-one-out over them misses least, if by ``CURVE_GAIN``
        (:func:`..fitting.table_cv.choose_interpolation`: on a real stage's coarse table, a spline
        found what straight lines cut across), and straight lines where it would pass the
        correction's cap. The rounds measure between the points, and the sweep's fit is
        straight between its knots: read along a spline, the coarse tables the random
        machines' sweeps were folded into left more (rough, noise-free at random parks,
        28.61 → 29.89 µm summed over 20 axes)."""
        if self.axes.rotary(axis):
            return
        best, scores = "linear", {}
        if curve and table.position_mm.size >= 5:
            best, scores = choose_interpolation(table)
            if scores[best] > CURVE_GAIN * scores["linear"]:  # as good: the local one
                best = "linear"
        best = self.axes.within_cap(axis, table, best)
        if best == "linear":
            self.record.tables.interpolation.pop(axis, None)
        else:
            self.record.tables.interpolation[axis] = best
        self.record.state.setdefault("identify", {})[f"interpolation-{axis}"] = {
            "method": best, "why": "leave-one-out" if curve else "verified between the points",
            "loo_rms_um": {k: v * 1e3 for k, v in scores.items()}}  # fmt: skip

    def _write_tables(self, axis: str, config: GatewayConfig, table: PitchTable,
                      cyclic: CyclicModel | None, what: str) -> bool:
        """Write an axis's refined table (and cyclic term) over its files, smoothed
        (:meth:`smoothed`), once the gateway would take them, read along straight lines
        (:meth:`interpolate`); False (a note, the files kept) when it would refuse them."""
        from ..fitting.outputs import check_cyclic, check_pitch, write_table

        table = self.smoothed(axis, table, config)
        try:
            check_pitch(table, config, axis)
            if cyclic is not None:
                check_cyclic(cyclic, config, axis)
        except Exception as exc:  # a refinement the gateway would refuse: keep the table
            self.record.state["notes"].append(f"{axis}: {what}: not applied: {exc}")
            return False
        write_table(self.record.config_dir / self.record.tables.pitch[axis], "csv", table,
                    f"compgw commission: {what}")  # fmt: skip
        if cyclic is not None and axis in self.record.tables.cyclic:
            write_cyclic(self.record.config_dir / self.record.tables.cyclic[axis], cyclic,
                         {"fitted": f"compgw commission: {what}"})  # fmt: skip
        self.interpolate(axis, table)
        return True

    # -- the sweep -------------------------------------------------------------------------
    def _lead_of(self, axis: str) -> float | None:
        """The lead of an axis's cyclic term (mm), or None without one."""
        if axis not in self.record.tables.cyclic:
            return None
        return read_cyclic(self.record.config_dir / self.record.tables.cyclic[axis]).lead_mm

    def _noisy(self, axis: str) -> bool:
        """Whether single stops of ``axis`` scatter more than its tolerance (the ISO runs'
        pooled standard deviation): its sweep may read more densely (``NOISY_STEPS_MM``)."""
        s_um = self.drift.iso_scatter_um(axis)
        return s_um is not None and s_um > self.rotary.tolerance_of(axis)

    def sweep_plan(self, axis: str, coarser: int, lead_mm: float | None = None,
                    estimate: bool = False) -> Plan:  # fmt: skip
        """``axis``'s sweep ``coarser`` steps down its steps (-1: the coarsest); with
        ``estimate``, before its cyclic term and ISO runs exist (the lead ``lead_mm``,
        not noisy)."""
        travel = self.axes.travel(axis)
        if self.axes.rotary(axis):  # a swing axis: over the range its table covers
            targets = sweep_targets_mm(self.rotary.table_range(axis), None, margin_mm=0.0,
                                       step_mm=self._sweep_steps(axis)[coarser])
            return self.axes.snap(sweep_plan(axis, travel, targets, piece_mm=SWEEP_PIECE_MM,
                                         overrun_mm=ROTARY_OVERRUN_DEG))  # fmt: skip
        lead = lead_mm if estimate else self._lead_of(axis)
        targets = sweep_targets_mm(travel, lead, coarser=coarser,
                                   noisy=not estimate and self._noisy(axis))  # fmt: skip
        return self.axes.snap(sweep_plan(axis, travel, targets, piece_mm=SWEEP_PIECE_MM))

    def _sweep_steps(self, axis: str) -> tuple[float, ...]:
        """The distances between a sweep's readings of ``axis`` (mm, or degrees), densest
        first."""
        if self.axes.rotary(axis):
            return SWING_SWEEP_STEPS_DEG
        return sweep_steps_mm(self._lead_of(axis), self._noisy(axis))

    def sweeps(self, r: int, axis: str, allowance_s: float) -> int | None:
        """How coarse round ``r``'s sweep of ``axis`` is (an index into the steps; None: no
        sweep): a linear or swing axis not swept yet (a turntable's worm scans and
        harmonics are its own), the densest step whose sweep and the next round's random
        targets fit in ``allowance_s``; a sweep begun before an interruption carries on as
        it was."""
        if self.axes.wraps(axis) or axis in self.record.state.get("swept", []):
            return None
        begun = self.record.state.get("sweeping", {}).get(axis)
        if begun is not None:
            return int(begun)
        random_s = adaptive.RANDOM_TARGETS * self._verify_target_s(r, axis)
        for coarser in range(len(self._sweep_steps(axis))):
            if self.budget.step_cost_s(self.sweep_plan(axis, coarser)) + random_s <= allowance_s:
                return coarser
        return None

    def fold_sweep(self, name: str, axis: str, table: PitchTable, model: CyclicModel | None,
                   method: str, step_mm: float, line_margin: float = LINE_MARGIN
                   ) -> tuple[SweepRefinement, int]:  # fmt: skip
        """Sweep step ``name``'s readings of ``axis`` (drift taken off) fitted and added to
        the table and cyclic term it was read with (``method``: the table's interpolation);
        not yet smoothed. Returns the refinement and the readings used."""
        raw = self.runner.raw(name)
        rows = np.array([a == axis for a in raw.axis])
        lead = model.lead_mm if model else None
        gap = SWING_KNOT_GAP_STEPS * step_mm if self.axes.rotary(axis) else adaptive.MIN_SPACING_MM
        fit = fit_sweep(raw.target_mm[rows], raw.deviation_mm[rows], raw.direction[rows],
                        lead, model.origin_mm if model else 0.0,
                        harmonics_for_step(step_mm, lead), table=table,
                        stations_mm=model.station_mm if model else (),
                        line_margin=line_margin, gap_mm=gap)  # fmt: skip
        return sweep_refinement(table, self.table_stage(axis, table, method), model, fit), \
            int(rows.sum())  # fmt: skip

    async def sweep_axis(self, r: int, axis: str, coarser: int) -> int:
        """Sweep ``axis`` with its table and cyclic term on and fold the fit into both;
        returns the table points added."""
        path = self.record.config_dir / self.record.tables.pitch[axis]
        cyclic = self.record.tables.cyclic
        cyclic_path = self.record.config_dir / cyclic[axis] if axis in cyclic \
            else None  # fmt: skip
        # the fold starts from the files as they were before the sweep (kept aside once):
        # a resume after the new table was written folds the same readings the same way
        keep = self.record.dir / "tables" / f"sweep{r}-{axis}"
        keep.mkdir(parents=True, exist_ok=True)
        for f in (path, cyclic_path):
            if f is not None and not (keep / f.name).exists():
                atomic_write_text(keep / f.name, f.read_text())
        self.record.state.setdefault("sweeping", {})[axis] = coarser
        # the interpolation the sweep reads the table with (the fold's, on a resume too)
        method = self.record.state.setdefault("sweep_interpolation", {}).setdefault(
            axis, self.interpolation_of(axis))
        self.record.save()
        table = read_pitch_csv(keep / path.name)
        model = read_cyclic(keep / cyclic_path.name) if cyclic_path is not None else None
        name = f"sweep{r}-{axis}"
        await self.runner.step(name, lambda: self.sweep_plan(axis, coarser), "on",
                               self.axes.park(axis))  # fmt: skip
        self.record.state["swept"] = [*self.record.state.get("swept", []), axis]
        self.record.state["sweeping"].pop(axis, None)
        lead = model.lead_mm if model else None
        step_mm = self._sweep_steps(axis)[coarser]
        ref, readings = self.fold_sweep(name, axis, table, model, method, step_mm)
        fit = ref.fit
        record: dict[str, Any] = {
            "round": r, "step_mm": step_mm, "readings": readings,
            "knots": int(fit.knot_mm.size),
            "stations": int(fit.station_mm.size), "harmonics": int(fit.sin_mm.shape[1]),
            "residual_rms_um": fit.residual_rms_um, "level_ptp_um": fit.level_ptp_um,
            "lambdas": list(fit.lambdas), "hold": fit.hold,
            "weighted_out": fit.weighted_out}  # fmt: skip
        self.record.state.setdefault("identify", {})[f"sweep-{axis}"] = record
        config, _ = self.stager.staged(self.record.tables_phase)
        if not self._write_tables(axis, config, ref.table, ref.cyclic, f"swept in round {r}"):
            return 0
        self.record.state.setdefault("spans", {})[axis] = []  # judged at random targets next
        unit, small = ("°", lambda v: f"{v * ARCSEC_PER_MDEG:.2f}″") if self.axes.rotary(axis) \
            else (" mm", lambda v: f"{v:.2f} µm")  # fmt: skip
        scatter = (f"; its stops scatter {small(self.drift.iso_scatter_um(axis))}, more than the "
                   "tolerance: read densely" if self._noisy(axis) and not lead
                   and not self.axes.rotary(axis) else "")  # fmt: skip
        self.say(f"round {r}: {axis}: swept every {step_mm:g}{unit} ({record['readings']} "
                 f"readings{scatter}): a level "
                 f"{small(fit.level_ptp_um)} peak to peak every "
                 f"{float(np.diff(fit.knot_mm).mean()):.2f}{unit}"
                 + (f", {record['harmonics']} harmonic{'s' if record['harmonics'] > 1 else ''}"
                    f" at {record['stations']} stations"
                    if record["harmonics"] else "")
                 + f"; {small(fit.residual_rms_um)} RMS left in the readings"
                 + (f", {fit.weighted_out} readings left out (stops that fell short)"
                    if fit.weighted_out else ""))  # fmt: skip
        return int(ref.table.position_mm.size - table.position_mm.size)
