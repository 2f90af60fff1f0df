"""Commissioning's take-up steps: whether a reversal takes the lost motion up at once
(seed 000's backlash places, one rung of the reversal ladder, the whole ladder where it
shows less than all; :mod:`..fitting.takeup_fit`), and the short steps that judge the curve where
nothing was fitted: random steps of 5 µm to 2 mm either way, after the after-run, in what
the budget has left."""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import numpy as np

from ..fitting.takeup_fit import (
    MIN_LOST_UM,
    RUNGS_MM,
    fit_takeup_raw,
    full_takeup_um,
    short_steps_plan,
    takeup_plan,
)
from ..plans.plans import BacklashResult, Plan
from .steps import BudgetSpent

if TYPE_CHECKING:
    from .axes import Axes
    from .record import Record
    from .steps import StepRunner

Say = Callable[[str], None]



class TakeUpSteps:
    """The take-up identification, and the short steps of the after-run."""

    def __init__(self, axes: Axes, record: Record, runner: StepRunner, say: Say) -> None:
        self.s = axes.s
        self.axes = axes
        self.record = record
        self.runner = runner
        self.say = say

    async def identify_takeup(self, a: str, b: BacklashResult) -> None:
        """Whether the lost motion is taken up at once on a reversal, and if not, how: one
        rung first, a reversal of 1.5 lost motions (a dead band has taken it all up there;
        a nut that engages softly over twice the play still shows 6 % less); the whole
        ladder only where that rung shows less than the readings' scatter allows."""
        lost_mm = float(b.mean_mm.max())
        if lost_mm * 1e3 < MIN_LOST_UM:
            return
        results = self.record.state.setdefault("identify", {})
        probe, travel = (round(1.5 * lost_mm, 3),), self.axes.travel(a)
        await self.runner.step(f"takeup-probe-{a}", lambda: takeup_plan(a, travel, probe), "off",
                        self.axes.park(a))  # fmt: skip
        fit = fit_takeup_raw(self.runner.raw(f"takeup-probe-{a}"), a, b, probe)
        if fit.curve is not None:
            await self.runner.step(f"takeup-{a}", lambda: takeup_plan(a, travel), "off",
                                   self.axes.park(a))  # fmt: skip
            fit = fit_takeup_raw(self.runner.raw(f"takeup-{a}"), a, b, RUNGS_MM)
        results[f"takeup-{a}"] = {
            "kept": fit.curve is not None, "why": fit.why, "miss_um": fit.miss_um,
            "lost_um": fit.lost_um, "motor_um": [float(v * 1e3) for v in fit.motor_mm],
            "table_um": [float(v * 1e3) for v in fit.table_mm],
            "fraction": [float(v) for v in fit.fraction]}  # fmt: skip
        section = fit.config()
        if section is None:
            self.record.tables.takeup.pop(a, None)
            return
        self.record.tables.takeup[a] = section
        whole = full_takeup_um(section)
        self.say(f"{a}: the lost motion ({fit.lost_um:.1f} µm) is taken up over a reversal of "
                 f"about {whole:.0f} µm, not at once ({fit.why}): a take-up curve of "
                 f"{len(section['fraction'])} points")  # fmt: skip

    def steps_plan(self, axis: str) -> Plan:
        """Random short steps over the middle half of the travel (seeded per run)."""
        return short_steps_plan(axis, self.axes.travel(axis), 2000 + self.s.seed)

    async def after_steps(self) -> None:
        """The short steps, everything on (the after-run's config), on every axis with a
        take-up curve: the curve judged where nothing was fitted. Last, in what the budget
        has left (not reserved: they must not cost a refinement); skipped, and said so,
        when it has not."""
        for a in self.s.axes:
            if a not in self.record.tables.takeup:
                continue
            try:
                # one stop a run: the drift references around the whole of them, not each
                await self.runner.step(f"after-steps-{a}", lambda a=a: self.steps_plan(a), "on",
                                self.axes.park(a), whole=True)  # fmt: skip
            except BudgetSpent as exc:
                self.record.state["notes"].append(f"{a}: short steps not measured: {exc}")
                self.say(f"{a}: short steps not measured: {exc}")

    def steps_summary(self, axis: str) -> dict[str, Any]:
        """RMS and largest deviation (µm) at the short steps, and what a full switch would
        have missed by after such reversals (the ladder's fit)."""
        if not self.record.done(f"after-steps-{axis}"):
            return {}
        dev_um = self.runner.raw(f"after-steps-{axis}").deviation_mm * 1e3
        switch = self.record.state.get("identify", {}).get(f"takeup-{axis}", {}).get("miss_um")
        return {"short_steps": {"rms_um": float(np.sqrt(np.mean(dev_um**2))),
                                "max_um": float(np.abs(dev_um).max()),
                                "stops": int(dev_um.size), "switch_miss_um": switch}}

