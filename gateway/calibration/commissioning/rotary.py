"""``compgw commission`` of rotary axes (issue 16): a turntable (a full turn, its table
modulo 360°) and a swing axis (a limited angle range, ``wrap: false``), chosen from the
config (``axes.<A>.rotary``) and measured with the angle instrument (``--angle``).

The steps are the linear axes' (:mod:`.commission`), in degrees:

- identification: seed 000's backlash in angle (1° take-up, 1° on and back, at both ends
  and the middle of the range), a coarse ISO 230-2 run (about 20 points, 3 runs; a
  turntable's over one whole turn, 0° and 360° both measured and merged), dense scans on the
  worm period when one is given (``--lead-mm C=5``: for a rotary axis the period in degrees),
  and the *before* run at random targets off the table's points: a turntable's over a turn
  that crosses 360° (180…540° when the travel allows), so judging exercises the wrap;
- fit: ``compgw fit``'s (the table in degrees, a turntable's modulo 360; a swing axis's
  linkage fitted from the config's file, copied into the commissioning's tables, with the
  table for what it leaves), the interpolation chosen by leave-one-out as ``calibrate
  --angle`` / ``compgw fit`` choose it;
- rounds and refinement: :mod:`..fitting.adaptive`'s judging and refined tables, with the
  tolerance in arcseconds (``--tolerance-arcsec``), a turntable's spans around the circle
  (the span from the last point to the first one turn on is one of them), and the table's
  stage built with the axis's interpolation and wrap;
- no drift references: the laser's references do not see an angle (the angle instrument's
  readings are taken as they are).

Figures are ISO 230-2's in millidegrees internally (the ``_um`` of a degree axis) and
arcseconds in the summary and the report. The other steps call these
hooks; on a linear axis each does what the linear code does.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from ...compensation import PitchTable
from ..fitting import adaptive
from ..fitting.iso230 import ARCSEC_PER_MDEG
from ..fitting.outputs import PitchResult
from ..fitting.plans_scans import cyclic_plan
from ..plans.plans import ROTARY_OVERRUN_DEG as OVERRUN_DEG  # past the ISO runs' end targets
from ..plans.plans import (
    Plan,
    backlash_from_raw,
    backlash_plan,
    iso230_targets_mm,
    read_plan,
    targets_plan,
)
from ..plans.rawdata import AxisDeviations

if TYPE_CHECKING:
    from .axes import Axes
    from .record import Record
    from .steps import StepRunner

Say = Callable[[str], None]

TURN_DEG = 360.0
#: seed 000 in angle (as ``compgw calibrate --backlash`` on a rotary axis): take-up and away
BACKLASH_MOVE_DEG = 1.0
#: a random target keeps this far from every table point (deg)
CLEARANCE_DEG = 0.2
ARCSEC_PER_DEG = 3600.0
#: a swing axis's sweep: a reading every this many degrees, densest first. Its screw turns
#: once every few degrees of angle (seed 003's 5 mm lead: about 1.9°, unevenly, through
#: the linkage), an error the coarse table's points, at least ``adaptive.MIN_SPACING_MM``
#: apart, cannot follow; no lead in degrees exists to tie the step to, so the sweep reads
#: densely enough for a period down to 1° and its fit keeps what cross-validation allows
SWING_SWEEP_STEPS_DEG = (0.25, 0.5)
#: ... and its level's knots keep this many steps from the table's points
SWING_KNOT_GAP_STEPS = 0.4


class RotarySteps:
    """What rotary axes change in a commissioning (the hooks the other steps call; on a
    linear axis each does what the linear code did)."""

    def __init__(self, axes: Axes, record: Record, runner: StepRunner, say: Say) -> None:
        self.s = axes.s
        self.config = axes.config
        self.axes = axes
        self.record = record
        self.runner = runner
        self.say = say

    # -- which axes, where -----------------------------------------------------------------
    def table_range(self, axis: str) -> tuple[float, float]:
        """Where the coarse run measures (deg): a turntable's one turn (0…360° when the
        travel leaves room to approach it from both sides), a swing axis's travel less the
        overrun."""
        lo, hi = self.axes.travel(axis)
        if not self.axes.wraps(axis) or hi - lo < TURN_DEG + 2 * OVERRUN_DEG:
            return lo + OVERRUN_DEG, hi - OVERRUN_DEG
        start = 0.0 if lo <= -OVERRUN_DEG and hi >= TURN_DEG + OVERRUN_DEG else lo + OVERRUN_DEG
        return start, start + TURN_DEG

    def judge_range(self, axis: str) -> tuple[float, float]:
        """Where the before/after and the rounds' targets lie (deg): a turntable's turn half
        a turn on (or back), so it crosses the table's 360° ≡ 0°; a swing axis's range."""
        t0, t1 = self.table_range(axis)
        if not self.axes.wraps(axis) or t1 - t0 < TURN_DEG:
            return t0, t1
        lo, hi = self.axes.travel(axis)
        for shift in (0.5 * TURN_DEG, -0.5 * TURN_DEG):
            if lo + OVERRUN_DEG <= t0 + shift and t1 + shift <= hi - OVERRUN_DEG:
                return t0 + shift, t1 + shift
        return t0, t1

    def tolerance_of(self, name: str) -> float:
        """The tolerance of an axis (or "XY") in its figures' unit: µm, or millidegrees."""
        if self.axes.rotary(name):
            return self.s.tolerance_arcsec / ARCSEC_PER_MDEG
        return self.s.tolerance_um

    def tolerance_text(self) -> str:
        """The tolerances in words: µm for linear axes and the plane, ″ for rotary ones."""
        rotary = [a for a in self.s.axes if self.axes.rotary(a)]
        arcsec = f"{self.s.tolerance_arcsec:g}″"
        if not rotary:
            return f"{self.s.tolerance_um:g} µm"
        if len(rotary) == len(self.s.axes) and self.s.planar is None:
            return arcsec
        return f"{self.s.tolerance_um:g} µm ({', '.join(rotary)}: {arcsec})"

    # -- plans -----------------------------------------------------------------------------
    def rotary_plans(self, axis: str) -> list[tuple[str, Plan]]:
        """The identification plans of a rotary axis (for the printed plan)."""
        out = [(f"backlash-{axis}", self._backlash_plan(axis)),
               (f"iso-{axis}", self._iso_plan_deg(axis))]  # fmt: skip
        if axis in self.s.lead_mm:
            out.append((f"cyclic-{axis}", self._cyclic_plan_deg(axis)))
        return out

    def _backlash_plan(self, axis: str) -> Plan:
        t0, t1 = self.table_range(axis)
        move = min(BACKLASH_MOVE_DEG, (t1 - t0) / 8)
        return backlash_plan(axis, (t0, t1), takeup_mm=move, away_mm=move, margin_mm=0.0)

    def _iso_plan_deg(self, axis: str) -> Plan:
        t0, t1 = self.table_range(axis)
        period = self.s.lead_mm.get(axis)
        targets = iso230_targets_mm((t0, t1), step_mm=adaptive.coarse_step_mm((t0, t1), period),
                                    margin_mm=0.0, seed=self.s.seed, lead_mm=period)  # fmt: skip
        return targets_plan(axis, self.axes.travel(axis), targets, self.s.runs, OVERRUN_DEG,
                            kind="iso230-linear", unit="deg")  # fmt: skip

    def _cyclic_plan_deg(self, axis: str) -> Plan:
        return cyclic_plan(axis, self.table_range(axis), self.s.lead_mm[axis])

    def rotary_before_plan(self, axis: str) -> Plan:
        """The targets judged before and after: random over the judging range (a
        turntable's crosses 360°), none within 0.2° of a coarse run's target."""
        table = read_plan(self.record.dir / "plans" / f"iso-{axis}.plan").targets_mm(axis)
        targets = self._random_deg(axis, 2 * adaptive.RANDOM_TARGETS, 1000 + self.s.seed, table)
        return targets_plan(axis, self.axes.travel(axis), targets, self.s.verify_runs, OVERRUN_DEG,
                            kind="iso230-verification", note="before-after", unit="deg")

    def _random_deg(self, axis: str, count: int, seed: int, avoid: NDArray[np.float64]
                    ) -> NDArray[np.float64]:  # fmt: skip
        return adaptive.random_targets_mm(
            self.judge_range(axis), count, seed, avoid, margin_mm=0.0,
            clearance_mm=CLEARANCE_DEG, period_mm=TURN_DEG if self.axes.wraps(axis) else None)

    def _offset(self, axis: str, d: NDArray[np.float64] | float) -> NDArray[np.float64]:
        """A difference of angles: a turntable's the shortest way round (−180…180°)."""
        d = np.asarray(d, dtype=np.float64)
        return (d + 0.5 * TURN_DEG) % TURN_DEG - 0.5 * TURN_DEG if self.axes.wraps(axis) else d

    # -- 1. identification -------------------------------------------------------------------
    async def identify_rotary(self, axis: str) -> None:
        """Seed 000's backlash, the coarse ISO run, the worm scans, the before-run."""
        results = self.record.state.setdefault("identify", {})
        park = self.axes.park(axis)
        await self.runner.step(f"backlash-{axis}", lambda: self._backlash_plan(axis), "off", park)
        self._check_angle_channel(axis, f"backlash-{axis}")
        b = backlash_from_raw(self.runner.raw(f"backlash-{axis}"), axis)
        results[f"backlash-{axis}"] = {
            "B_arcsec": float(b.backlash_mm * ARCSEC_PER_DEG),
            "places_arcsec": [float(m * ARCSEC_PER_DEG) for m in b.mean_mm],
            "places_um": [float(m * 1e3) for m in b.mean_mm]}  # millidegrees  # fmt: skip
        await self.runner.step(f"iso-{axis}", lambda: self._iso_plan_deg(axis), "off", park)
        if axis in self.s.lead_mm:
            await self.runner.step(f"cyclic-{axis}", lambda: self._cyclic_plan_deg(axis), "off",
                                   park)  # fmt: skip
        await self.runner.step(f"before-{axis}", lambda: self.rotary_before_plan(axis), "off", park)

    def _check_angle_channel(self, axis: str, name: str) -> None:
        """The angle instrument's reading for ``axis`` follows it over its first step (the
        backlash test's three places): its deviations spread over less than 5 % of how far
        it was sent, or the channels
        are not in the order given (a rotary axis has no drift references to check them
        by, as the laser's are). Else the step is forgotten, its readings another axis's,
        and SetupError says what to give. (Swapped, a turntable ran its whole
        identification and failed at the fit: "forward deviation makes the axis run
        backwards".)"""
        from ..measuring.machine import SetupError

        raw = self.runner.raw(name)
        # the spread of the deviations, not of the readings: a turntable's reading is taken
        # in its target's turn, so another axis's standing angle follows it a turn at a time
        sent, off = float(np.ptp(raw.target_mm)), float(np.ptp(raw.deviation_mm))
        if off <= 0.05 * sent:
            return
        self.record.forget(name)
        ins = self.s.instruments
        order = ins.angle_order(self.config)
        given = (f"--angle-axes {','.join(order)}" if ins.angle_axes else
                 f"the config's rotary axes in order, {','.join(order)}; --angle-axes sets it")
        raise SetupError(f"the angle instrument's reading for axis {axis} (channel "
                         f"{order.index(axis) + 1}, by {given}) strayed {off:.3f}° from "
                         f"where {axis} was sent, over {sent:.3f}°: give --angle-axes in the "
                         "instrument's channel order (its readings of this step are "
                         "discarded)")  # fmt: skip

    # -- 2. fit ------------------------------------------------------------------------------
    def rotary_fitted(self, axis: str, result: PitchResult) -> PitchResult:
        """Record a rotary axis's fit: the interpolation leave-one-out chose (linear when the
        chosen one would not load), the linkage fitted; ``result`` unchanged."""
        if not self.axes.rotary(axis):
            return result
        best, scores = result.interpolation_cv or ("linear", {})
        best = self.axes.within_cap(axis, result.table, best)
        info: dict[str, Any] = {"interpolation": best,
                                "loo_rms_arcsec": {k: v * ARCSEC_PER_DEG
                                                   for k, v in scores.items()}}  # fmt: skip
        found = {"interpolation": best}
        if best in scores:
            found["loo_rms_arcsec"] = scores[best] * ARCSEC_PER_DEG
        if result.linkage is not None:
            fit = result.linkage
            info["linkage"] = {"fitted": list(fit.free), "rms_arcsec": fit.rms_deg * 3600,
                               "drawing_rms_arcsec": fit.start_rms_deg * 3600}  # fmt: skip
            found["linkage_rms_arcsec"] = fit.rms_deg * ARCSEC_PER_DEG
            self.say(f"{axis}: linkage fitted ({', '.join(fit.free)}): residual RMS "
                     f"{fit.rms_deg * 3600:.2f}″ (the drawing's values "
                     f"{fit.start_rms_deg * 3600:.2f}″); the table holds the rest")  # fmt: skip
        elif not self.axes.wraps(axis):
            self.say(f"{axis}: swing axis without compensation.linkage: table only")
        self.say(f"{axis}: {best} interpolation (leave-one-out RMS "
                 + ", ".join(f"{k} {v * 3600:.3f}″" for k, v in scores.items()) + ")")
        self.record.state.setdefault("rotary", {})[axis] = info
        cyclic = self.record.state.get("identify", {}).get(f"cyclic-{axis}", {})
        if "peak_um" in cyclic:  # the worm's peak: millidegrees, shown in arcseconds
            cyclic["peak_arcsec"] = cyclic.pop("peak_um") * ARCSEC_PER_MDEG
        self.record.state.setdefault("identify", {})[f"fit-{axis}"] = found
        return result

    # -- 3. rounds -----------------------------------------------------------------------------
    def _circle(self, axis: str, x: NDArray[np.float64]) -> NDArray[np.float64]:
        """A turntable's table points and the first one a turn on (the last span closes the
        circle); anything else's as they are."""
        return np.append(x, x[0] + TURN_DEG) if self.axes.wraps(axis) and x.size else x

    def rotary_verify_targets(self, r: int, axis: str, table_mm: NDArray[np.float64]
                              ) -> NDArray[np.float64]:  # fmt: skip
        """Round ``r``'s targets: the new spans' midpoints and fresh random targets, over the
        judging range (a turntable's midpoints moved into its turn)."""
        spans = self.record.state.get("spans", {}).get(axis)  # None: all spans new
        mids = adaptive.midpoints_mm(self._circle(axis, table_mm), spans)
        if self.axes.wraps(axis):
            lo, _ = self.judge_range(axis)
            mids = lo + np.mod(mids - lo, TURN_DEG)
        rand = self._random_deg(axis, adaptive.RANDOM_TARGETS, 100 * r + self.s.seed, table_mm)
        return np.unique(np.round(np.concatenate([mids, rand]), 4))

    def judge(self, axis: str, dev: AxisDeviations, table_mm: NDArray[np.float64]
              ) -> adaptive.AxisVerdict:  # fmt: skip
        """:func:`..fitting.adaptive.judge_axis` against the axis's tolerance; a turntable's targets
        taken into the table's turn, its spans around the circle."""
        if not self.axes.rotary(axis):
            return adaptive.judge_axis(dev, table_mm, self.s.tolerance_um)
        x = self._circle(axis, table_mm)
        if self.axes.wraps(axis) and x.size:
            dev = replace(dev, target_mm=x[0] + np.mod(dev.target_mm - x[0], TURN_DEG))
        return adaptive.judge_axis(dev, x, self.tolerance_of(axis))

    def score_text(self, name: str, score: float) -> str:
        """A round's score (E, or the plane's max vector error) in its unit."""
        return f"{score * ARCSEC_PER_MDEG:.2f}″" if self.axes.rotary(name) else f"{score:.2f} µm"

    def verdict_text(self, axis: str, v: adaptive.AxisVerdict) -> str:
        if not self.axes.rotary(axis):
            return f"{axis} E {v.E_um:.2f} A {v.A_um:.2f} R {v.R_um:.2f} µm"
        k = ARCSEC_PER_MDEG
        return f"{axis} E {v.E_um * k:.2f} A {v.A_um * k:.2f} R {v.R_um * k:.2f}″"

    def refine_points(self, axis: str, table: PitchTable, verdict: adaptive.AxisVerdict
                      ) -> NDArray[np.float64]:  # fmt: skip
        """The new points in the failing spans: each cut in ``REFINE_PARTS`` (a rotary
        span too short for that in two), none nearer an existing point than
        ``MIN_SPACING_MM`` (a turntable's the short way round, points taken modulo 360)."""
        x = table.position_mm
        if not self.axes.rotary(axis):
            return adaptive.midpoints_mm(x, verdict.failing_spans, adaptive.REFINE_PARTS)
        xc = self._circle(axis, x)
        spans = list(verdict.failing_spans)
        mids = adaptive.midpoints_mm(xc, spans, adaptive.REFINE_PARTS)
        short = [i for i in spans
                 if xc[i + 1] - xc[i] < adaptive.REFINE_PARTS * adaptive.MIN_SPACING_MM]
        mids = np.concatenate([mids, adaptive.midpoints_mm(xc, short, 2)]) if short else mids
        if self.axes.wraps(axis):
            mids = np.round(np.mod(mids, TURN_DEG), 4)
        keep = [float(m) for m in mids
                if np.min(np.abs(self._offset(axis, m - x))) >= adaptive.MIN_SPACING_MM]
        return np.unique(np.array(keep, dtype=np.float64))

    # -- plan and summary ------------------------------------------------------------------------
    def rotary_plan_lines(self) -> None:
        """What the printed plan adds for rotary axes: where, in degrees, and the tolerance."""
        for axis in self.s.axes:
            if not self.axes.rotary(axis):
                continue
            (t0, t1), (j0, j1) = self.table_range(axis), self.judge_range(axis)
            kind = "turntable" if self.axes.wraps(axis) else "swing axis"
            period = self.s.lead_mm.get(axis)
            turn = np.floor((j1 - 1e-9) / TURN_DEG) * TURN_DEG
            across = f" (across {turn:g}°)" if self.axes.wraps(axis) and j0 < turn < j1 else ""
            self.say(f"  {axis}: {kind}, with the angle instrument: table over {t0:g}…{t1:g}°, "
                     f"judged at targets over {j0:g}…{j1:g}°{across}"
                     + (f", worm scans every {period:g}°" if period else
                        ", no cyclic stage (a worm's: --lead-mm AXIS=360/teeth)"
                        if self.axes.wraps(axis) else ", no cyclic stage")
                     + f"; tolerance {self.s.tolerance_arcsec:g}″ (ISO 230-2 E); speeds in "
                     "deg/s")  # fmt: skip

    def rotary_summary(self, out: dict[str, Any]) -> None:
        """A rotary axis's summary figures in arcseconds (``*_arcsec``, no ``*_um``), its
        kind, interpolation, linkage and judging range."""
        rotary = [a for a in self.s.axes if self.axes.rotary(a) and a in out["axes"]]
        if not rotary:
            return
        out["tolerance_arcsec"] = self.s.tolerance_arcsec
        for axis in rotary:
            entry = out["axes"][axis]
            entry.update(unit="deg", kind="turntable" if self.axes.wraps(axis) else "swing",
                         judged_deg=list(self.judge_range(axis)))  # fmt: skip
            for phase in ("before", "after"):
                if phase in entry:
                    entry[phase] = {k[:-3] + "_arcsec": None if v is None else v * ARCSEC_PER_MDEG
                                    for k, v in entry[phase].items()}  # fmt: skip
            entry.update(self.record.state.get("rotary", {}).get(axis, {}))

