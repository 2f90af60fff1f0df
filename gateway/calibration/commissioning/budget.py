"""Commissioning's machine time: what each step costs and what the budget has left."""

from __future__ import annotations

import itertools
from typing import TYPE_CHECKING

from ..plans.plans import (
    Plan,
    read_plan,
)

if TYPE_CHECKING:
    from .axes import Axes
    from .drift import DriftRefs
    from .record import Record


class Budget:
    """Machine time: what a step costs with its drift references, what the budget has left, and
    what is kept back for the after-run."""

    def __init__(self, axes: Axes, record: Record, drift: DriftRefs) -> None:
        self.s = axes.s
        self.config = axes.config
        self.axes = axes
        self.record = record
        self.drift = drift

    def refs_around_s(self, plan: Plan, whole: bool = False) -> float:
        """Machine time (s) of the drift references read around ``plan``'s runs (around
        the whole plan with ``whole``): before the first and after each, one run's
        after-reading being the next one's before-reading."""
        parts = 1 if whole or not self.runs_apart() else len(split_runs(plan))
        return (parts + 1) * self.drift.refs_cost_s(self.axes.ref_axes())

    def runs_apart(self) -> bool:
        """Whether a step's runs each get their own drift references, not the whole step
        one pair. One pair only on a short budget (:meth:`short`), and only while no linear
        axis has a temperature sensor and no axis's references have varied by more than
        their own scatter (:meth:`drift_stands_out`, so not before they have been read three
        times): there the references only watch for a drift to begin, and around every
        run they cost a small stage a third of its budget (mcu1025 at 1.5 x a manual
        calibration's time: 6.1 of 17.7 minutes). A long budget keeps them around every
        run: a drift that stands out only later is then taken off run by run, where one
        pair around a whole sweep left its heat in the tables as a bow (mcu1025 at 8 h,
        noise-free: 0.6 → 1.2 µm on X, 1.4 → 2.6 µm on Y)."""
        if not self.record.state.get("short"):
            return True
        return any(self.config.axes[a].compensation.thermal is not None
                   or self.drift.drift_stands_out(a) for a in self.axes.ref_axes())  # fmt: skip

    def step_cost_s(self, plan: Plan, drift: bool = True, whole: bool = False) -> float:
        """Machine time (s) of running ``plan`` as a step: its moves, and the drift
        references read around its runs once drift is counted (see :meth:`step`)."""
        drifting = drift and "drift_base" in self.record.state
        return self.axes.estimate_s(plan) + (self.refs_around_s(plan, whole) if drifting else 0.0)

    def verdict_cost_s(self, plan: Plan) -> float:
        """Machine time (s) of a verdict's ``plan``: read before, and again after."""
        return 2 * self.step_cost_s(plan)

    def step_cost_worst_s(self, plan: Plan) -> float:
        """:meth:`step_cost_s` with the drift references around every run, as they are
        once a drift stands out: what a step decided on now may cost when it runs."""
        if "drift_base" not in self.record.state:
            return self.axes.estimate_s(plan)
        return self.axes.estimate_s(plan) + self.refs_worst_s(plan)

    def refs_once_s(self) -> float:
        """Machine time (s) of one reading of every axis's drift references."""
        return self.drift.refs_cost_s(self.axes.ref_axes())

    def refs_worst_s(self, plan: Plan) -> float:
        """Machine time (s) of the drift references around every run of ``plan``."""
        return (len(split_runs(plan)) + 1) * self.refs_once_s()

    def iso_runs(self) -> int:
        """Runs per target of the ISO runs: the configured ones, or fewer where a short
        budget holds every axis's table only so
        (:meth:`.identify.IdentifySteps._iso_runs_that_fit`)."""
        return int(self.record.state.get("iso_runs") or self.s.runs)

    def left_s(self, warming: str | None = None) -> float:
        """Machine time (s) the budget has left for the steps before the after-run: what is
        neither used nor kept for it (:meth:`reserve_s`) nor held for a warm-up (:meth:`held_s`;
        ``warming``'s own warm-up sees its own hold); negative when overspent."""
        return self.s.budget_s - self.record.used_s - self.reserve_s() - self.held_s(warming)

    def held_s(self, warming: str | None = None) -> float:
        """Machine time (s) a short budget holds for the zone warm-ups not made yet
        (:meth:`.identify.IdentifySteps._hold_warm_ups`), but ``warming``'s own."""
        held = self.record.state.get("warmup_held") or {}
        return sum(float(h["cost_s"]) for a, h in held.items()
                   if a != warming and not self.record.done(f"warmup-{a}"))

    def verify_runs(self, axis: str) -> int:
        """Runs per verification (and refinement) target of an axis: ``verify_runs`` until
        its residuals hide in their noise (see :meth:`.rounds.Rounds._settle`)."""
        return int(self.record.state.get("verify_runs", {}).get(axis, self.s.verify_runs))

    def reserve_s(self) -> float:
        """The after-run (the before-run's targets again, or those of one read alone) is
        kept out of the budget."""
        plans = [self.record.dir / "plans" / f"{kind}-{a}.plan" for a in self.s.axes
                 for kind in ("before", "alone")]  # (an after-run read alone: its own plan)
        if self.s.planar is not None:
            plans.append(self.record.dir / "plans" / "before-xy.plan")
        # and the drift references read around each of its runs and the last config switch
        total = 2 * self.drift.refs_cost_s(self.axes.ref_axes())
        return total + sum(self.after_cost_s(read_plan(p)) for p in plans if p.exists())

    def after_cost_s(self, plan: Plan) -> float:
        """Machine time (s) an after-run of ``plan`` is kept: its moves and the drift
        references around its runs."""
        return self.axes.estimate_s(plan) + self.refs_around_s(plan)


def split_runs(plan: Plan) -> list[Plan]:
    """A plan cut into its runs (each measured with its own drift references), in order;
    a plan whose runs interleave (seed 000's backlash repeats) stays whole."""
    runs = [m.run for m in plan.moves]
    if len(set(runs)) < 2 or any(b < a for a, b in itertools.pairwise(runs)):
        return [plan]
    return [Plan(plan.kind, plan.axes, tuple(m for m in plan.moves if m.run == j), plan.meta)
            for j in sorted(set(runs))]  # fmt: skip
