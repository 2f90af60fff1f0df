"""Heat from motion, fitted from drift references: an axis with no thermal sensor.

While commissioning, the drift references (two places per axis, read before and after every
run) record how far the screw has grown, and the odometer how far the axis has travelled
and when. A screw warms by its nut's friction, the same energy per metre at any speed, and
cools in proportion to how warm it is, so its growth at x is

    growth(x) = c · (x − x_fixed) · H,    H = heat in metres of travel (motion_heat_m)

with three unknowns: c, the screw's fixed end x_fixed, and the time constant τ of its
cooling. Time is what the moves of every commissioned axis take at ``speed_mm_s`` (or the
wall clock, if longer): the gateway counts it the same way. For each τ on a grid, the two
references' growth is a linear least-squares fit in H; the τ with the least residual
wins. The result is the config's ``thermal: {origin_mm, length_mm, motion: {...}}``.
Pure: arrays in, numbers out.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from ..compensation.errors import TableError
from ..compensation.thermal import motion_heat_series_m

#: the time constants tried (s): from a thin screw in a draught to a thick one in still air
TAU_GRID_S = np.geomspace(20.0, 50_000.0, 100)
#: growth (µm) below which there is nothing worth a model
MIN_GROWTH_UM = 3.0
#: the model must explain this much of the drift (residual RMS over drift RMS at most)
MAX_RESIDUAL_SHARE = 0.5
#: a fixed end farther than this many travels off the travel is not a screw's growth (a
#: drift that is the same everywhere: the air at the laser, a base that moves)
FAR_ENDS = 20.0


@dataclass(frozen=True)
class MotionHeatFit:
    """The fitted thermal setting of one axis, and how well it explains the drift."""

    axis: str
    origin_mm: float  # the screw's fixed end, axis coordinates
    length_mm: float  # from the fixed end to the farther reference
    delta_a_um_per_m: float  # Δa at length_mm per metre of heat
    tau_s: float
    speeds_mm_s: dict[str, float]
    growth_max_um: float
    residual_rms_um: float
    points: int

    def config(self) -> dict[str, object]:
        """The axis's ``compensation.thermal`` section."""
        return {"origin_mm": round(float(self.origin_mm), 2),
                "length_mm": round(float(self.length_mm), 2),
                "motion": {"delta_a_um_per_m": float(f"{self.delta_a_um_per_m:.5g}"),
                           "tau_s": round(float(self.tau_s), 1),
                           "speeds_mm_s": {a: float(v) for a, v
                                           in self.speeds_mm_s.items()}}}  # fmt: skip


def motion_heat_fit(axis: str, odometer_m: dict[str, ArrayLike], wall_s: ArrayLike,
                    growth_um: ArrayLike, refs_mm: tuple[float, float],
                    speeds_mm_s: dict[str, float], travel_mm: tuple[float, float]
                    ) -> MotionHeatFit:  # fmt: skip
    """Fit heat from motion to the growth (µm, shape (k, 2): both references) of ``axis``
    read at the odometers ``odometer_m`` (each commissioned axis's travel since the first
    reading, m) and wall clock ``wall_s``. Raises TableError (naming the axis) when the
    drift is too small or the model does not hold."""
    wall = np.asarray(wall_s, dtype=np.float64)
    odo = {a: np.asarray(v, dtype=np.float64) for a, v in odometer_m.items()}
    g = np.asarray(growth_um, dtype=np.float64).reshape(-1, 2)
    n = g.shape[0]
    if n < 6 or wall.size != n or any(v.size != n for v in odo.values()):
        raise TableError(f"axis {axis}: {n} drift readings, too few to fit heat from "
                         "motion (6 needed)")  # fmt: skip
    peak = float(np.abs(g).max())
    if peak < MIN_GROWTH_UM:
        raise TableError(f"axis {axis}: the screw grew {peak:.1f} µm at most while "
                         f"commissioning (under {MIN_GROWTH_UM:g}): no heat to model")
    travel = np.diff(odo[axis], prepend=0.0).clip(min=0.0)
    moving = sum(np.diff(odo[a], prepend=0.0).clip(min=0.0) * 1000.0 / speeds_mm_s[a]
                 for a in odo)  # fmt: skip
    elapsed = np.maximum(moving, np.diff(wall, prepend=wall[0]).clip(min=0.0))
    best: tuple[float, float, np.ndarray] | None = None
    for tau in TAU_GRID_S:
        heat = motion_heat_series_m(travel, elapsed, float(tau))
        hh = float(heat @ heat)
        if hh <= 0:
            continue
        slopes = heat @ g / hh  # growth per metre of heat at each reference
        sse = float(((g - np.outer(heat, slopes)) ** 2).sum())
        if best is None or sse < best[0]:
            best = (sse, float(tau), slopes)
    if best is None:
        raise TableError(f"axis {axis}: it never moved between the drift readings")
    sse, tau, slopes = best
    rms = float(np.sqrt(sse / g.size))
    spread = float(np.sqrt((g**2).mean()))
    if tau >= TAU_GRID_S[-1] or rms > MAX_RESIDUAL_SHARE * spread:
        why = ("the heat never levelled off (a longer commissioning would show where)"
               if tau >= TAU_GRID_S[-1] else
               f"it leaves {rms:.1f} µm RMS of {spread:.1f} µm")  # fmt: skip
        raise TableError(f"axis {axis}: heat from motion does not explain the drift: {why}")
    (x0, x1), (s0, s1) = refs_mm, slopes
    per_mm = (s1 - s0) / (x1 - x0)  # growth per mm of lever per metre of heat
    if per_mm <= 0:
        raise TableError(f"axis {axis}: the references drift as a screw that shrinks with "
                         "use: is the machine still cooling from before?")  # fmt: skip
    origin = x0 - s0 / per_mm
    lo, hi = travel_mm
    length = max(abs(x0 - origin), abs(x1 - origin))
    if not lo - FAR_ENDS * (hi - lo) <= origin <= hi + FAR_ENDS * (hi - lo):
        raise TableError(f"axis {axis}: the drift puts the screw's fixed end at "
                         f"{origin:.0f} mm, far off the travel: not the screw's growth")
    return MotionHeatFit(axis, origin, length, per_mm * length, tau, dict(speeds_mm_s),
                         peak, rms, n)  # fmt: skip
