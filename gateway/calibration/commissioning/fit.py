"""Commissioning's step 2: the tables and the plane fitted."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace
from typing import TYPE_CHECKING

from ...config import GatewayConfig
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
from ..fitting.plane_frame import fitted_frame, save_frame
from ..plans.runner import read_raw_meta

if TYPE_CHECKING:
    from .axes import Axes
    from .planner import Planner
    from .record import Record
    from .refine import RefineSteps
    from .rotary import RotarySteps
    from .short import ShortBudget
    from .stager import Stager
    from .steps import StepRunner

Say = Callable[[str], None]


class FitSteps:
    """Step 2: the tables fitted from the identification runs, the XY grid measured and the plane
    fitted."""

    def __init__(self, axes: Axes, record: Record, stager: Stager, runner: StepRunner,
                 rotary: RotarySteps, plans: Planner, refine: RefineSteps, short: ShortBudget,
                 say: Say) -> None:
        self.s = axes.s
        self.axes = axes
        self.record = record
        self.stager = stager
        self.runner = runner
        self.rotary = rotary
        self.plans = plans
        self.refine = refine
        self.short = short
        self.say = say

    # -- 2. fit, XY ----------------------------------------------------------------------
    async def fit_identified(self) -> None:
        """The budget ran out before the fit: the tables of the linear axes whose ISO runs
        were made (with the cyclic term where its scans were made too), as a plain ISO
        230-2 calibration would fit them, and said to be unverified; the other axes get
        none. Tables fitted already (a short budget fits them for the plane's grid) take
        in the cyclic scans made since, and are said to be unverified unless a round
        verified them."""
        if self.record.tables.pitch:  # fitted already (on a short budget, for the plane's grid):
            # the scans made since
            ready = [a for a in self.s.axes if a in self.record.tables.pitch]
            await self.fit_axes(ready, curves=True)
            if self.record.state["rounds"]:
                return  # verified in a round
        else:
            ready = [a for a in self.s.axes
                     if not self.axes.rotary(a) and self.record.done(f"iso-{a}")]
            if not ready:
                return
            await self.fit_axes(ready, curves=True)
        rest = [a for a in self.s.axes if a not in ready]
        bare = [a for a in ready if a in self.s.lead_mm and a not in self.record.tables.cyclic]
        note = (f"{', '.join(ready)}: fitted from the identification's runs only, no round "
                "verified them between the points (the budget ran out)"
                + (f"; {', '.join(bare)}: no cyclic term (its scans were not made)"
                   if bare else "")
                + (f"; {', '.join(rest)}: not identified, no table" if rest else ""))
        self.record.state["notes"].append(note)
        self.say(note)
        self.record.save()

    async def fit_axes(self, axes: list[str] | None = None, curves: bool = False) -> None:
        """The tables from the identification runs of ``axes`` (all: the commissioned),
        read along the curve their own leave-one-out prefers with ``curves`` (tables no
        round will measure between their points, :meth:`interpolate`)."""
        axes = list(self.s.axes) if axes is None else axes
        scanned = [a for a in axes if a in self.s.lead_mm and self.record.done(f"cyclic-{a}")]
        if all(a in self.record.tables.pitch for a in axes) and \
                all(a in self.record.tables.cyclic for a in scanned):  # (a short budget's resumed)
            return
        tables_dir = self.record.dir / "tables"
        tables_dir.mkdir(parents=True, exist_ok=True)
        for a in axes:
            self.record.tables.pitch[a] = self.record.rel(tables_dir / f"{a.lower()}_pitch.csv")
            if a in scanned:
                self.record.tables.cyclic[a] = self.record.rel(
                    tables_dir / f"{a.lower()}_cyclic.yaml")
        config, _ = self.stager.staged("pitch")
        for a in axes:
            model = None
            if a in scanned:
                raw_c = self.record.raw_paths(f"cyclic-{a}")[0]
                cr = fit_cyclic_raw(self.runner.raw(f"cyclic-{a}"), read_raw_meta(raw_c), config,
                                    self.record.config_dir, a)  # fmt: skip
                save_cyclic(cr, "compgw commission: dense scans")
                model = cr.model
                self.record.state.setdefault("identify", {})[f"cyclic-{a}"] = {
                    "harmonics": cr.fit.harmonics, "peak_um": cr.model.peak_mm() * 1e3}
            # the reversal per point or as a curve, by what the ISO runs' own scatter says
            # each would leave (a worn zone of the nut: per point)
            r = fit_pitch(self.short.iso_raw(a), config, self.record.config_dir, a,
                          mode="bidirectional", reversal="auto")  # fmt: skip
            r = self.rotary.rotary_fitted(a, r)
            if r.reversal is not None:
                self.record.state.setdefault("identify", {})[f"reversal-{a}"] = r.reversal.summary()
            if model is not None:
                r = net_pitch(r, model, config)
            r = replace(r, table=self.runner.drift.move_zero(
                a, self.refine.smoothed(a, r.table, config)))
            save_pitch(r, "compgw commission: coarse ISO 230-2 run" +
                       (", net of the cyclic term" if model is not None else ""))  # fmt: skip
            # whether the references' drift was off its runs as fitted: more references
            # read later may make it stand out (:meth:`.run_heat.RunHeat.put_back_refs`)
            self.record.state.setdefault("drift_off_at_fit", {})[a] = \
                self.runner.drift.drift_taken_off(a)
            self.refine.interpolate(a, r.table, curves)
            self.record.state.setdefault("spans", {})[a] = None  # every span is new: all verified
        self.record.save()
        await self.stager.use("pitch")

    async def plane(self) -> None:
        if self.s.planar is None or self.record.tables.planar_model is not None:
            return
        grid = self.short.first_grid()
        # each stage loads its phase on entry, as _identify, _rounds and _after do (a no-op
        # when loaded): the fit's own load is skipped on a resume after an abort put your
        # config back (trial 8 read a resumed grid without the tables, round 1's plane 44 µm)
        await self.stager.use("pitch")
        await self.runner.step("xy-grid", lambda: self.plans.grid_plan(grid), "on")
        self.record.tables.planar_axes = self.s.planar
        model = self.record.dir / "tables" / "xy_model.yaml"
        self.record.tables.planar_model = self.record.rel(model)
        config, _ = self.stager.staged("full")
        self.fit_plane(config, "xy-grid", residual=False)
        self.record.save()
        await self.stager.use("full")

    def fit_plane(self, config: GatewayConfig, name: str, residual: bool) -> None:
        """The plane from grid run ``name`` (read with the tables on disk loaded), and its
        frame: those tables' values at the grid's nodes, where the model is faded."""
        assert self.s.planar is not None
        meas = planar_measurement(self.runner.raw(name), self.s.planar)
        ax, ay = self.s.planar
        lines = {ax: self.axes.park(ax)[ay], ay: self.axes.park(ay)[ax]}
        res = fit_planar(meas, config, self.record.config_dir, "auto", residual, lines)
        save_planar(res, "compgw commission")
        save_frame(res.points_path, fitted_frame(res.choice.pinned, meas, config,
                                                 self.record.config_dir, self.s.planar, lines))
        self.record.state.setdefault("planar_fits", []).append(
            {"kind": res.choice.kind, "pinned": res.choice.pinned,
             "loo_rms_um": res.choice.loo_rms_um, "residual": residual})  # fmt: skip

