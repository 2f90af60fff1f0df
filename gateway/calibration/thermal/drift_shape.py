"""Where commissioning's own moves have warmed a screw: the shape of its thermal drift
between the two drift references (pure).

The drift references read how far an axis has grown at two places; between them the drift
is taken as linear in position. A screw grows from its fixed end by the integral of its
temperature, and a ball screw is warm where its nut has worked: random targets warm the
middle of the travel most, a sweep piece or a warm-up the zone it worked, and a straight
line through the two references leaves that bow in every reading it corrects (1-2 µm on
the bench's rough screws, into the table).

Commissioning sees every target it commands, so it counts the travel swept over each
stretch of the screw (:class:`SweptHeat`, older travel fading with machine time, spread
along the screw by conduction as the gateway's travel profile spreads it:
:func:`~gateway.compensation.thermal.travel_weights`). The growth is then c·(W(x) − W(o)),
W the integral of the heat weights and o the fixed end, so through the two references

    d(x) = d₁ + (d₂ − d₁) · (W(x) − W(x₁)) / (W(x₂) − W(x₁)),

exactly the straight line when the screw was worked evenly. It holds for the growth itself
(no thermal compensation on: a linear correction would be mistaken for heat), on a screw
known to be warm where it works (an evenly warm one grows linearly whatever W says).
Positions in mm, times in s.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ...compensation.thermal import travel_integral, travel_swept, travel_weights

#: bins of the swept travel (mm)
BIN_MM = 5.0
#: the widest spread a shape is asked for (mm): the margin kept beyond the travel
MAX_SPREAD_MM = 300.0
#: places a shape is kept at (the axis's travel, ends included)
SAMPLES = 41


@dataclass
class SweptHeat:
    """The travel an axis has swept over each stretch of its screw, fading with machine
    time by ``memory_s`` (mutable: it follows the moves). ``swept`` per bin of ``BIN_MM``
    from ``start_mm``."""

    start_mm: float
    swept: NDArray[np.float64]
    travel_mm: tuple[float, float]
    memory_s: float
    last_mm: float | None = None

    @classmethod
    def for_travel(cls, travel_mm: tuple[float, float], memory_s: float) -> SweptHeat:
        lo, hi = sorted(travel_mm)
        margin = 3.0 * MAX_SPREAD_MM + BIN_MM
        n = math.ceil((hi - lo + 2 * margin) / BIN_MM) + 1
        return cls(lo - margin, np.zeros(n), (lo, hi), memory_s)

    @property
    def centres_mm(self) -> NDArray[np.float64]:
        return self.start_mm + BIN_MM * np.arange(self.swept.size)

    def elapse(self, seconds: float) -> None:
        """Machine time passes (a move of any axis, a stop): the heat fades."""
        if seconds > 0.0:
            self.swept *= math.exp(-seconds / self.memory_s)

    def move_to(self, x_mm: float) -> None:
        """The axis goes to ``x_mm``: the stretch from where it was is swept once."""
        last, self.last_mm = self.last_mm, float(x_mm)
        if last is None or x_mm == last:
            return
        self.swept += travel_swept(self.centres_mm, BIN_MM, last, float(x_mm))

    def shape(self, spread_mm: float) -> list[float]:
        """W (the integral of the heat weights, any scale) at the ``SAMPLES`` places."""
        spread = min(max(spread_mm, BIN_MM), MAX_SPREAD_MM)
        w = travel_integral(self.centres_mm, travel_weights(self.swept, BIN_MM, spread))
        return [float(v) for v in np.interp(sample_mm(self.travel_mm), self.centres_mm, w)]

    def to_json(self) -> dict[str, Any]:
        return {"start_mm": self.start_mm, "swept": [round(float(v), 4) for v in self.swept],
                "travel_mm": list(self.travel_mm), "memory_s": self.memory_s,
                "last_mm": self.last_mm}  # fmt: skip

    @classmethod
    def from_json(cls, v: dict[str, Any]) -> SweptHeat:
        return cls(float(v["start_mm"]), np.asarray(v["swept"], dtype=np.float64),
                   (float(v["travel_mm"][0]), float(v["travel_mm"][1])),
                   float(v["memory_s"]), v.get("last_mm"))  # fmt: skip


def sample_mm(travel_mm: tuple[float, float]) -> NDArray[np.float64]:
    """The places a shape is kept at."""
    return np.linspace(travel_mm[0], travel_mm[1], SAMPLES)


def shaped_drift_mm(x_mm: ArrayLike, refs_mm: tuple[float, float],
                    drift_mm: tuple[float, float], travel_mm: tuple[float, float],
                    shape: ArrayLike) -> NDArray[np.float64]:  # fmt: skip
    """Drift (mm) at ``x_mm`` from the drift at the two references and the heat shape W
    (at :func:`sample_mm` of ``travel_mm``); a shape that cannot tell the references apart
    (no travel between them yet) gives the straight line."""
    x = np.asarray(x_mm, dtype=np.float64)
    xs, w = sample_mm(travel_mm), np.asarray(shape, dtype=np.float64)
    w0, w1 = np.interp(refs_mm, xs, w)
    d0, d1 = drift_mm
    span = w1 - w0
    if not abs(span) > 1e-6 * max(1e-12, float(np.abs(w).max())):
        return d0 + (d1 - d0) * (x - refs_mm[0]) / (refs_mm[1] - refs_mm[0])
    return d0 + (d1 - d0) * (np.interp(x, xs, w) - w0) / span
