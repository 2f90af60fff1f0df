"""Direction of motion of an axis, decided from successive nominal targets.

Backlash and bidirectional tables need the direction of the *approach* to a target. It is
the sign of (new target − previous target); a repeated target keeps the previous direction,
unless its command goes the other way (:meth:`MotionState.turned`: the gateway decides that
from the commands it sends).
Before the first target after homing, the direction is ``home_direction`` from config,
because homing decides which flank of the nut is engaged.

The *engagement* (−1..+1) is where the nut is in its play: ±1 on the flank of the last
direction, unless the axis has a take-up curve (:mod:`.takeup`) and the last reversal was
too short to take the play up.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from .errors import CompensationError
from .takeup import TakeUpCurve


@dataclass(frozen=True)
class MotionState:
    """Last nominal target (pulses), the direction of the move that reached it (+1/−1) and
    the nut's engagement there (−1..+1; the direction when not given)."""

    direction: int
    last_target_pulses: int | None = None
    engagement: float = field(default=float("nan"))

    def __post_init__(self) -> None:
        if self.direction not in (1, -1):
            raise CompensationError(f"home_direction: {self.direction!r} must be +1 or -1")
        e = self.engagement
        if e != e:  # not given: on the direction's flank
            object.__setattr__(self, "engagement", float(self.direction))
        elif not -1.0 <= e <= 1.0:
            raise CompensationError(f"engagement: {e!r} must be within -1..1")

    def approach(self, target_pulses: int, takeup: TakeUpCurve | None = None,
                 pulse_mm: float = 1.0) -> MotionState:  # fmt: skip
        """The state after moving to ``target_pulses``; with ``takeup`` the nut crosses its
        play as that curve says (``pulse_mm`` converts the move to mm)."""
        last = self.last_target_pulses
        if last is None or target_pulses == last:
            return MotionState(self.direction, target_pulses, self.engagement)
        direction = 1 if target_pulses > last else -1
        return self.turned(direction, target_pulses, abs(target_pulses - last) * pulse_mm,
                           takeup)  # fmt: skip

    def turned(self, direction: int, target_pulses: int, moved_mm: float,
               takeup: TakeUpCurve | None = None) -> MotionState:  # fmt: skip
        """The state after the motor moved ``moved_mm`` in ``direction`` to reach nominal
        ``target_pulses``, whatever the nominal move says: a target sent again (or moved
        less than its correction changed) whose command goes the other way, because the
        plane's partner moved or the screw grew, turns the nut through its play."""
        if takeup is None:
            return MotionState(direction, target_pulses)
        return MotionState(direction, target_pulses,
                           takeup.advance(self.engagement, direction, moved_mm))  # fmt: skip
