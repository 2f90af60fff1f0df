"""Lost motion taken up over a reversal, not at once: where the nut sits in its play.

Classic backlash compensation switches the whole lost motion on at a reversal: right for a
dead band (the table stands still while the motor crosses the play, then follows). A soft
engagement (a preloaded or worn nut, a belt, a long shaft winding up) lets the table follow
part of the way while the play is still being crossed, so a short reversal shows only part
of the lost motion and a full switch overshoots it by the rest (tens of µm on a reversal of
a few µm when the lost motion is taken up over 0.3 mm).

The *engagement* e ∈ [−1, 1] says where the nut is: +1 on the flank of a move in +, −1 on
the flank of a move in −, between on a reversal that has not taken the play up yet. The
chain's backlash and bidirectional pitch stages correct for e by blending their + and −
corrections (e = ±1: the classic switch).

:class:`TakeUpCurve` is measured (``compgw commission``, seed 000's backlash places): the
fraction of the lost motion shown after the **table** reversed by ``reversal_mm`` from a
nut fully on the other flank, nondecreasing to 1. Below the first point it holds the first
fraction (a dead band shows all of it at once). A reversal from part way follows the same
curve from the point where it stands (the nut remembers how far it has crossed: a
hysteresis, not a switch).
"""

from __future__ import annotations

import bisect
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .errors import CompensationError


@dataclass(frozen=True, eq=False)
class TakeUpCurve:
    """Fraction (0..1) of the lost motion shown after a table reversal of ``reversal_mm``."""

    reversal_mm: NDArray[np.float64]
    fraction: NDArray[np.float64]
    source: str = "takeup"
    _r: tuple[float, ...] = field(init=False, repr=False)
    _f: tuple[float, ...] = field(init=False, repr=False)

    def __init__(self, reversal_mm: ArrayLike, fraction: ArrayLike,
                 source: str = "takeup") -> None:  # fmt: skip
        r = np.array(reversal_mm, dtype=np.float64).reshape(-1)
        f = np.array(fraction, dtype=np.float64).reshape(-1)
        where = source
        if r.size < 2 or r.size != f.size:
            raise CompensationError(
                f"{where}: reversal and fraction need the same number of points, at least 2 "
                f"(got {r.size} and {f.size})")  # fmt: skip
        if not (np.all(np.isfinite(r)) and np.all(np.isfinite(f))):
            raise CompensationError(f"{where}: every reversal and fraction must be a number")
        if r[0] < 0 or np.any(np.diff(r) <= 0):
            raise CompensationError(f"{where}: reversals must be >= 0 and strictly increasing")
        if f[0] < 0 or np.any(np.diff(f) < 0) or f[-1] != 1.0:
            raise CompensationError(
                f"{where}: fractions must be >= 0, never decrease, and end at 1 (the play "
                "fully taken up by the last reversal)")  # fmt: skip
        r.setflags(write=False)
        f.setflags(write=False)
        object.__setattr__(self, "reversal_mm", r)
        object.__setattr__(self, "fraction", f)
        object.__setattr__(self, "source", source)
        object.__setattr__(self, "_r", tuple(float(v) for v in r))
        object.__setattr__(self, "_f", tuple(float(v) for v in f))

    def shown(self, reversal_mm: float) -> float:
        """Fraction shown after a reversal of ``reversal_mm`` from the other flank."""
        if reversal_mm <= 0.0:
            return 0.0
        r, f = self._r, self._f
        if reversal_mm <= r[0]:
            return f[0]
        if reversal_mm >= r[-1]:
            return 1.0
        i = bisect.bisect_right(r, reversal_mm)
        return f[i - 1] + (f[i] - f[i - 1]) * (reversal_mm - r[i - 1]) / (r[i] - r[i - 1])

    def reached(self, fraction: float) -> float:
        """The reversal (mm) from the other flank at which ``fraction`` is shown: the
        smallest one (0 for a fraction the first point already shows)."""
        r, f = self._r, self._f
        if fraction <= f[0]:
            return 0.0
        if fraction >= 1.0:
            i = f.index(1.0)
            return r[i]
        i = bisect.bisect_left(f, fraction)
        f0, f1 = f[i - 1], f[i]
        return r[i - 1] + (r[i] - r[i - 1]) * (fraction - f0) / (f1 - f0)

    def advance(self, engagement: float, direction: int, distance_mm: float) -> float:
        """Engagement after the table moved ``distance_mm`` (≥ 0) in ``direction`` (±1)
        from ``engagement``."""
        done = 0.5 * (1.0 + direction * max(-1.0, min(1.0, engagement)))  # toward direction
        after = self.shown(self.reached(done) + distance_mm) if distance_mm > 0 else done
        after = max(done, after)
        return direction * (2.0 * after - 1.0)
