"""The commissioned axes as the user's config and the command line give them."""

from __future__ import annotations

from typing import TYPE_CHECKING

from ...compensation import PitchStage, PitchTable
from ...compensation.errors import CompensationError, TableError
from ..plans.plans import (
    Plan,
    plan_time_s,
    snap_to_pulses,
)

if TYPE_CHECKING:
    from ...config import GatewayConfig
    from .settings import Settings


class Axes:
    """The commissioned axes as configured: travel, where the other plane axis parks, plans
    snapped to pulses and checked against the soft limits (the user's config and the
    command line; read here, never written)."""

    def __init__(self, settings: Settings, config: GatewayConfig) -> None:
        self.s = settings
        self.config = config

    def ref_axes(self) -> list[str]:
        """The axes the drift references read: the linear ones (the laser sees no angle)."""
        return [a for a in self.s.axes if not self.config.axes[a].rotary]

    def plane_with(self, axes: list[str]) -> bool:
        """Whether the plane is commissioned once ``axes`` are identified: every plane axis
        commissioned here is among them (one that is not had its table before)."""
        return self.s.planar is not None and set(self.s.planar) & set(self.s.axes) <= set(axes)

    def park(self, axis: str) -> dict[str, float]:
        """Where the other plane axis stands while ``axis`` is measured: its lower end."""
        if self.s.planar is None or axis not in self.s.planar:
            return {}
        other = self.s.planar[1] if axis == self.s.planar[0] else self.s.planar[0]
        return {other: float(self.config.axes[other].travel_mm[0])}

    def travel(self, axis: str) -> tuple[float, float]:
        lo, hi = self.config.axes[axis].travel_mm
        return float(lo), float(hi)

    def ref_positions(self, axis: str) -> tuple[float, float]:
        lo, hi = self.travel(axis)
        pulse = self.config.axes[axis].pulse_mm
        return (round((lo + 0.05 * (hi - lo) + 1.0) / pulse) * pulse,
                round((hi - 0.05 * (hi - lo)) / pulse) * pulse)

    def plane_travel(self) -> tuple[tuple[float, float], tuple[float, float]]:
        """The travel (mm) of the plane's two axes, X role first."""
        assert self.s.planar is not None  # (only the plane's steps ask)
        ax, ay = self.s.planar
        return self.travel(ax), self.travel(ay)

    # -- steps ---------------------------------------------------------------------------
    def snap(self, plan: Plan) -> Plan:
        return snap_to_pulses(plan, {n: a.pulse_mm for n, a in self.config.axes.items()})

    def check_limits(self, plan: Plan) -> None:
        for move in plan.moves:
            for name, target in zip(plan.axes, move.target_mm):
                lo, hi = self.config.axes[name].travel_mm
                if not lo <= target <= hi:
                    raise TableError(f"plan {plan.kind}: axis {name} target {target:g} mm is "
                                     f"outside the soft limits {lo:g}..{hi:g} mm")  # fmt: skip

    def estimate_s(self, plan: Plan) -> float:
        return plan_time_s(plan, self.s.speed_mm_s, self.s.stop_s)

    # -- axes and tables ------------------------------------------------------------------
    def rotary(self, axis: str) -> bool:
        return axis in self.config.axes and self.config.axes[axis].rotary

    def wraps(self, axis: str) -> bool:
        return axis in self.config.axes and self.config.axes[axis].wraps

    def within_cap(self, axis: str, table: PitchTable, method: str) -> str:
        """``method``, or straight lines where ``table`` read along it would pass the axis's
        correction cap (the gateway would refuse the config)."""
        if method == "linear":
            return method
        try:
            PitchStage(table, method, wrap=self.wraps(axis)).check_cap(  # type: ignore[arg-type]
                self.config.axes[axis].compensation.max_correction_mm)
        except CompensationError:
            return "linear"
        return method

