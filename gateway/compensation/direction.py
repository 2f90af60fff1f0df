"""Direction of motion of an axis, decided from successive nominal targets.

Backlash and bidirectional tables need the direction of the *approach* to a target. It is
the sign of (new target − previous target); a repeated target keeps the previous direction.
Before the first target after homing, the direction is ``home_direction`` from config,
because homing decides which flank of the nut is engaged.
"""

from __future__ import annotations

from dataclasses import dataclass

from .errors import CompensationError


@dataclass(frozen=True)
class MotionState:
    """Last nominal target (pulses) and the direction of the move that reached it (+1/−1)."""

    direction: int
    last_target_pulses: int | None = None

    def __post_init__(self) -> None:
        if self.direction not in (1, -1):
            raise CompensationError(f"home_direction: {self.direction!r} must be +1 or -1")

    def approach(self, target_pulses: int) -> MotionState:
        """The state after moving to ``target_pulses``."""
        last = self.last_target_pulses
        if last is None or target_pulses == last:
            return MotionState(self.direction, target_pulses)
        return MotionState(1 if target_pulses > last else -1, target_pulses)
