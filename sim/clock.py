"""The machine clock: simulated seconds, independent of how fast the sim runs.

At ``time_scale == 0`` the clock moves only when told to (each move advances it by its
nominal duration, and the control block can advance it explicitly), so thermal behaviour is
reproducible and instant. At ``time_scale > 0`` wall time also counts, divided by the scale
(1 = real time, 0.5 = moves take half as long in wall time but the same machine time).
:attr:`MachineClock.listeners` hear every explicit advance (the laser's recorder follows
machine time through them).
"""

from __future__ import annotations

import time
from collections.abc import Callable


class MachineClock:
    """Machine time in seconds since the sim started."""

    def __init__(self, time_scale: float, wall_s: Callable[[], float] = time.monotonic) -> None:
        self.time_scale = float(time_scale)
        self._wall_s = wall_s
        self._wall0_s = wall_s()
        self._offset_s = 0.0
        #: called with (t_old_s, t_new_s) after each :meth:`advance` has moved the clock
        self.listeners: list[Callable[[float, float], None]] = []

    def now_s(self) -> float:
        """Current machine time."""
        if self.time_scale > 0:
            return self._offset_s + (self._wall_s() - self._wall0_s) / self.time_scale
        return self._offset_s

    def advance(self, seconds: float) -> None:
        """Jump forward (explicit control, or a move's duration at time_scale 0)."""
        if seconds < 0:
            raise ValueError("the clock only moves forward")
        t_old_s = self.now_s()
        self._offset_s += seconds
        if self.listeners:
            t_new_s = self.now_s()
            for listener in list(self.listeners):
                listener(t_old_s, t_new_s)
