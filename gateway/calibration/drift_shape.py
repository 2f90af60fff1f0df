"""Where commissioning's own moves have warmed each screw: the shape of the thermal drift
between the two drift references (pure).

The drift references read how far an axis has grown at two places; between them the drift
was taken as linear in position. A screw grows from its fixed end by the integral of its
temperature, and a ball screw is warm where its nut has worked: after a sweep piece, a
verification or a warm-up in one zone the growth is steeper there, and a straight line
through the two references leaves a bow in every reading it corrects (up to 0.3 µm RMS on
the rough machines' longer axes, mostly longer than 200 mm: it goes into the table).

Commissioning sees every target it commands, so it counts the travel swept over each
stretch of the screw (:class:`SweptHeat`, older travel fading per mm travelled since,
spread along the screw by conduction) exactly as the gateway's travel profile does
(:func:`~gateway.compensation.thermal.travel_weights`). The drift at x is then

    d(x) = d₁ + (d₂ − d₁) · (W(x) − W(x₁)) / (W(x₂) − W(x₁))

with W the integral of the heat weights: right for a screw fixed anywhere (growth is
c·(W(x) − W(o))) and exactly the straight line when the screw was swept evenly. Positions
in mm.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..compensation.thermal import travel_integral, travel_weights

#: bins of the swept travel (mm)
BIN_MM = 5.0
#: conduction along the screw over its cooling time: √(κτ) for steel and τ ≈ 700 s
SPREAD_MM = 100.0
#: travel over which old heat fades (mm): τ ≈ 1000 s at 100 mm/s
MEMORY_MM = 100_000.0
#: places the shape is kept at (the axis's travel, ends included)
SAMPLES = 41


@dataclass
class SweptHeat:
    """The travel an axis has swept over each stretch of its screw (mutable: it follows
    the moves). ``swept`` per bin of ``BIN_MM`` from ``start_mm``."""

    start_mm: float
    swept: NDArray[np.float64]
    last_mm: float | None = None
    travel_mm: tuple[float, float] = field(default=(0.0, 1.0))

    @classmethod
    def for_travel(cls, travel_mm: tuple[float, float]) -> SweptHeat:
        lo, hi = sorted(travel_mm)
        margin = 3.0 * SPREAD_MM + BIN_MM
        n = math.ceil((hi - lo + 2 * margin) / BIN_MM) + 1
        return cls(lo - margin, np.zeros(n), None, (lo, hi))

    @property
    def centres_mm(self) -> NDArray[np.float64]:
        return self.start_mm + BIN_MM * np.arange(self.swept.size)

    def move_to(self, x_mm: float) -> None:
        """The axis goes to ``x_mm``: the stretch from where it was is swept once."""
        last, self.last_mm = self.last_mm, float(x_mm)
        if last is None or x_mm == last:
            return
        lo, hi = sorted((last, float(x_mm)))
        self.swept *= math.exp(-(hi - lo) / MEMORY_MM)
        c = self.centres_mm
        half = BIN_MM / 2.0
        self.swept += np.clip(np.minimum(c + half, hi) - np.maximum(c - half, lo), 0.0,
                              None) / BIN_MM  # fmt: skip

    def shape(self) -> list[float]:
        """W (the integral of the heat weights, any scale) at the ``SAMPLES`` places."""
        w = travel_integral(self.centres_mm, travel_weights(self.swept, BIN_MM, SPREAD_MM))
        return [float(v) for v in np.interp(sample_mm(self.travel_mm), self.centres_mm, w)]

    def to_json(self) -> dict[str, Any]:
        return {"start_mm": self.start_mm, "swept": [round(float(v), 4) for v in self.swept],
                "last_mm": self.last_mm, "travel_mm": list(self.travel_mm)}

    @classmethod
    def from_json(cls, v: dict[str, Any]) -> SweptHeat:
        return cls(float(v["start_mm"]), np.asarray(v["swept"], dtype=np.float64),
                   v.get("last_mm"), (float(v["travel_mm"][0]), float(v["travel_mm"][1])))


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
    if not abs(span) > 1e-9 * max(1.0, float(np.abs(w).max())):
        return d0 + (d1 - d0) * (x - refs_mm[0]) / (refs_mm[1] - refs_mm[0])
    # beyond the references the shape is followed too, to the ends of the travel
    return d0 + (d1 - d0) * (np.interp(x, xs, w) - w0) / span
