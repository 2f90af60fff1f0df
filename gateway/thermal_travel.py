"""Where each screw has been working: the swept travel behind ``thermal.profile``, and
how warm its own motion has made it (``thermal.motion``, an axis with no sensor).

The nut's friction heats the screw where it runs; a Δa sensor at the free end reads the
whole elongation but not where it is. The gateway sees every target it corrects, so it
counts the travel swept over each stretch of the screw (older travel fading per mm
travelled since, ``memory_mm``, or per second, ``memory_s``) and hands the math
(:func:`~gateway.compensation.thermal.travel_delta_a_mm`) the weights. Nothing here is
persisted: after a restart the profile starts empty and the linear spread applies until
the axis has moved.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .compensation.thermal import (
    EndFold,
    ThermalStage,
    motion_heat_after_m,
    motion_heat_one_m,
    travel_delta_a_mm,
    travel_integral,
    travel_integral_rows,
    travel_swept,
    travel_weights,
)
from .config import AxisThermal, MotionHeat, TravelProfile


class TravelHistory:
    """The swept travel of one axis along its screw, and the Δa it implies per place."""

    def __init__(self, thermal: AxisThermal, profile: TravelProfile,
                 travel_mm: tuple[float, float],
                 clock: Callable[[], float] = time.monotonic) -> None:  # fmt: skip
        self.profile = profile
        self.clock = clock
        self.at_s = clock()
        self.stage = ThermalStage(thermal.length_mm, thermal.origin_mm)
        self.travel_mm = tuple(travel_mm)
        lo, hi = travel_mm
        self.toward = 1 if (lo + hi) / 2 >= thermal.origin_mm else -1
        a_point = thermal.origin_mm + self.toward * thermal.length_mm
        margin = 3.0 * profile.spread_mm + profile.bin_mm
        start = min(lo, hi, thermal.origin_mm, a_point) - margin
        stop = max(lo, hi, thermal.origin_mm, a_point) + margin
        n = math.ceil((stop - start) / profile.bin_mm) + 1
        self.centres_mm = start + profile.bin_mm * np.arange(n)
        self.swept = np.zeros(n)
        self._fold = (None if profile.screw_mm is None else
                      EndFold.of(self.centres_mm, profile.screw_mm))  # fmt: skip
        self.last_mm: float | None = None
        self._integral: np.ndarray | None = None  # W(x), made again after each move

    def same_screw(self, thermal: AxisThermal, travel_mm: tuple[float, float]) -> bool:
        """Whether a reloaded config describes the screw this history counts for."""
        return (thermal.profile == self.profile and tuple(travel_mm) == self.travel_mm
                and self.stage == ThermalStage(thermal.length_mm, thermal.origin_mm))

    def move_to(self, x_mm: float) -> None:
        """The axis goes to ``x_mm``: the stretch from where it was is swept once (one
        move in scalars: the gateway's path on every target write, about 10 µs)."""
        last, self.last_mm = self.last_mm, x_mm
        if last is None or x_mm == last:
            return
        now = self.clock()
        since_s, self.at_s = now - self.at_s, now
        fade = abs(x_mm - last) / self.profile.memory_mm
        if self.profile.memory_s is not None:  # a pause cools the old zones too
            fade = max(fade, since_s / self.profile.memory_s)
        self.swept *= math.exp(-fade)
        self.swept += travel_swept(self.centres_mm, self.profile.bin_mm, last, x_mm)
        self._integral = None

    def moves_to(self, xs_mm: Sequence[float]) -> None:
        """The axis goes to each of ``xs_mm`` in turn, all at this clock reading: as many
        :meth:`move_to` calls, summed at once (tests/test_thermal_travel.py holds the two
        equal)."""
        self.replay(xs_mm, ())

    def replay(self, xs_mm: Sequence[float], stops: Sequence[int]) -> NDArray[np.float64]:
        """:meth:`moves_to` ``xs_mm``, returning the swept travel (one row a stop) as it
        stood after each move of ``stops`` (indices into ``xs_mm``, increasing): a fit
        replays a warm-up's thousands of moves and reads every stop, for each of a hundred
        profiles (tests/test_thermal_travel.py holds it to the moves one by one)."""
        xs = np.asarray(xs_mm, dtype=np.float64)
        at = np.asarray(stops, dtype=np.int64)
        if not xs.size:
            return np.zeros((0, self.swept.size))
        if at.size and (np.any(np.diff(at) <= 0) or at[0] < 0 or at[-1] >= xs.size):
            raise ValueError("replay: stops must be increasing indices into the moves")
        came = np.concatenate([[xs[0] if self.last_mm is None else self.last_mm], xs[:-1]])
        self.last_mm = float(xs[-1])
        fade = np.abs(xs - came) / self.profile.memory_mm
        moved = np.flatnonzero(xs != came)
        if moved.size:
            now = self.clock()
            since_s, self.at_s = now - self.at_s, now
            if self.profile.memory_s is not None:  # a pause cools the old zones too
                fade[moved[0]] = max(fade[moved[0]], since_s / self.profile.memory_s)
        # blocks of moves, each ending at a stop (and one more to the last move)
        ends = at if at.size and at[-1] == xs.size - 1 else np.append(at, xs.size - 1)
        faded = np.cumsum(fade)  # fade from the start to after each move
        block = np.searchsorted(ends, np.arange(xs.size))
        # only the bins the moves reach are swept: 30-odd of a history's hundreds
        half = self.profile.bin_mm / 2.0
        reach = np.flatnonzero((self.centres_mm + half > min(xs.min(), came.min())) &
                               (self.centres_mm - half < max(xs.max(), came.max())))
        cols = slice(reach[0], reach[-1] + 1) if reach.size else slice(0, 0)
        stretch = travel_swept(self.centres_mm[None, cols], self.profile.bin_mm,
                               came[:, None], xs[:, None])  # fmt: skip
        stretch *= np.exp(-(faded[ends][block] - faded))[:, None]
        added = np.add.reduceat(stretch, np.concatenate([[0], ends[:-1] + 1]), axis=0)
        rows = np.empty((ends.size, self.swept.size))
        state, before = self.swept, 0.0
        for k, end in enumerate(ends):
            state = state * math.exp(-(faded[end] - before))
            state[cols] += added[k]
            rows[k], before = state, faded[end]
        self.swept = state
        self._integral = None
        return rows[:at.size]

    def integral_rows(self, at_mm: ArrayLike) -> NDArray[np.float64]:
        """Rows that read W at each of ``at_mm`` off a swept-travel row (see
        :func:`~gateway.compensation.thermal.travel_integral_rows`)."""
        return travel_integral_rows(self.centres_mm, self.profile.bin_mm,
                                    self.profile.spread_mm, self._fold, at_mm)  # fmt: skip

    def delta_a_mm(self, delta_a_mm: float, at_mm: float) -> float:
        """The Δa for the linear stage at ``at_mm`` (see travel_delta_a_mm)."""
        if self._integral is None:
            weights = travel_weights(self.swept, self.profile.bin_mm, self.profile.spread_mm)
            if self._fold is not None:
                weights = self._fold(weights)
            self._integral = travel_integral(self.centres_mm, weights)
        return travel_delta_a_mm(delta_a_mm, at_mm, self.centres_mm, self._integral,
                                 self.stage, self.toward)  # fmt: skip


class MoveLog:
    """Every target the gateway sent on since it started (the last ``capacity``): the heat
    a ``thermal.motion`` model loaded later starts from (:meth:`HeatFromMotion.from_log`).
    Commissioning loads one after hours of its own runs; begun cold, the gateway left the
    whole of that heat in the after-run (random machine 3: X E 10.4 µm as read, 0.7 with
    the drift taken off). 2^18 moves: days of a machine's work, 4.5 MB."""

    def __init__(self, clock: Callable[[], float] = time.monotonic,
                 capacity: int = 1 << 18) -> None:  # fmt: skip
        self.clock = clock
        self.codes: dict[str, int] = {}
        self._axis = np.zeros(capacity, dtype=np.int16)
        self._travel_mm = np.zeros(capacity)
        self._at_s = np.zeros(capacity)
        self.count = 0  # moves logged, the overwritten ones too
        self.last_mm: dict[str, float] = {}

    def moved(self, axis: str, x_mm: float) -> None:
        """``axis`` is sent to ``x_mm``."""
        last = self.last_mm.get(axis)
        self.last_mm[axis] = x_mm
        i = self.count % self._at_s.size
        self._axis[i] = self.codes.setdefault(axis, len(self.codes))
        self._travel_mm[i] = 0.0 if last is None else abs(x_mm - last)
        self._at_s[i] = self.clock()
        self.count += 1

    def heat_m(self, axis: str, motion: MotionHeat) -> tuple[float, float]:
        """The heat (m of travel) ``axis``'s moves left in its screw as ``motion`` counts it
        (each move lasting its travel over ``speeds_mm_s`` or the clock since the move
        before, whichever is longer: :meth:`HeatFromMotion.moved`), and the clock (s) of
        the last move; (0, now) before any."""
        n = min(self.count, self._at_s.size)
        if n == 0 or axis not in self.codes:
            return 0.0, self.clock()
        order = (np.arange(n) + self.count - n) % self._at_s.size
        code, travel, at = self._axis[order], self._travel_mm[order], self._at_s[order]
        speed = np.array([motion.speeds_mm_s.get(a, 0.0) for a in self.codes])[code]
        moving = np.divide(travel, speed, out=np.zeros(n), where=speed > 0)
        elapsed = np.maximum(moving, np.diff(at, prepend=at[0]))
        own_m = np.where(code == self.codes[axis], travel / 1000.0, 0.0)
        return motion_heat_after_m(own_m, elapsed, motion.tau_s), float(at[-1])


class HeatFromMotion:
    """The heat one axis's moves have put into its screw, and the Δa it makes (no sensor).

    Told of every target the gateway sends on (any axis): the axis's own travel heats the
    screw, and each move of an axis in ``speeds_mm_s`` lasts at least its travel over that
    speed, the time the screw cools by; the monotonic clock counts pauses. With a
    ``state_file`` the heat is kept across a restart (cooled for the time the gateway was
    down); without one the screw is taken as cold."""

    def __init__(self, axis: str, motion: MotionHeat,
                 clock: Callable[[], float] = time.monotonic) -> None:  # fmt: skip
        self.axis = axis
        self.motion = motion
        self.clock = clock
        self.heat_m = 0.0
        self.last_mm: dict[str, float] = {}
        self.at_s = clock()

    @classmethod
    def from_log(cls, axis: str, motion: MotionHeat, log: MoveLog) -> HeatFromMotion:
        """A model loaded while the gateway runs: from the heat the moves it relayed since
        it started already put in (``log``), not from a cold screw."""
        heat = cls(axis, motion, log.clock)
        heat.heat_m, heat.at_s = log.heat_m(axis, motion)
        heat.last_mm = dict(log.last_mm)
        return heat

    def moved(self, axis: str, x_mm: float) -> None:
        """``axis`` is sent to ``x_mm``: heat from this screw's travel, cooling for the time
        the move takes (or the wall clock, whichever is longer)."""
        now = self.clock()
        last = self.last_mm.get(axis)
        self.last_mm[axis] = x_mm
        travel_mm = 0.0 if last is None else abs(x_mm - last)
        speed = self.motion.speeds_mm_s.get(axis)
        moving_s = travel_mm / speed if speed else 0.0
        own_m = travel_mm / 1000.0 if axis == self.axis else 0.0
        self.heat_m = motion_heat_one_m(self.heat_m, own_m, max(moving_s, now - self.at_s),
                                        self.motion.tau_s)  # fmt: skip
        self.at_s = now

    def heat_now_m(self) -> float:
        """The heat now (m of travel), cooled for the time since the last move."""
        idle = max(0.0, self.clock() - self.at_s)
        return motion_heat_one_m(self.heat_m, 0.0, idle, self.motion.tau_s)

    def delta_a_mm(self) -> float:
        """Δa now (mm)."""
        return self.motion.delta_a_um_per_m * self.heat_now_m() / 1000.0

    def carry_on(self, heat_m: float, age_s: float) -> None:
        """Take back the heat an earlier process saved ``age_s`` ago (it cooled since)."""
        self.heat_m = motion_heat_one_m(max(0.0, heat_m), 0.0, max(0.0, age_s),
                                        self.motion.tau_s)  # fmt: skip
        self.at_s = self.clock()
