"""A pitch table's interpolation chosen by cross-validation (pure).

Leave-one-out over the table's own points: each point is predicted from the others with
``linear`` (straight lines, as LinuxCNC and SINUMERIK), ``smooth`` (C2 cubic spline) and
``pchip`` (monotone cubic), as :class:`~gateway.compensation.PitchStage` interpolates; the
RMS of the misses, over both directions, scores each. The end points count too, predicted as
the stage predicts beyond a table (the end value held): commands run past the last measured
point wherever the correction is large there, so a table whose error still changes at its
ends scores badly, one that leaves little beyond a model well. A smooth error sampled densely (seed
003's linkage at every degree) favours the spline; a rough one (real screws measured
coarsely) straight lines. A turntable's table (``wrap``) is scored around the circle.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray
from scipy.interpolate import CubicSpline, PchipInterpolator

from ..compensation import PitchTable

METHODS = ("linear", "smooth", "pchip")
TURN_DEG = 360.0


def _predict(x: NDArray[np.float64], y: NDArray[np.float64], at: float, method: str) -> float:
    if at < x[0] or at > x[-1]:  # beyond the table: the end value held (outside: hold)
        return float(y[0] if at < x[0] else y[-1])
    if method == "linear":
        return float(np.interp(at, x, y))
    if method == "smooth":
        return float(CubicSpline(x, y, bc_type="not-a-knot")(at))
    return float(PchipInterpolator(x, y)(at))


def loo_rms(table: PitchTable, wrap: bool = False) -> dict[str, float]:
    """Leave-one-out RMS (table units) of each interpolation method."""
    x = table.position_mm
    series = [table.forward_mm] + ([table.reverse_mm] if table.reverse_mm is not None else [])
    n = x.size
    out: dict[str, float] = {}
    for method in METHODS:
        if n < (3 if method == "linear" else 5) and not wrap:
            continue
        misses: list[float] = []
        for y in series:
            xx, yy, inner = x, y, range(n)
            if wrap:  # three points of the neighbouring turns on each side
                xx = np.concatenate([x[-3:] - TURN_DEG, x, x[:3] + TURN_DEG])
                yy = np.concatenate([y[-3:], y, y[:3]])
                inner = range(3, n + 3)
            for i in inner:
                keep = np.ones(xx.size, dtype=bool)
                keep[i] = False
                misses.append(_predict(xx[keep], yy[keep], float(xx[i]), method) - yy[i])
        out[method] = float(np.sqrt(np.mean(np.square(misses))))
    return out


def choose_interpolation(table: PitchTable, wrap: bool = False) -> tuple[str, dict[str, float]]:
    """The method with the smallest leave-one-out RMS (ties: the simpler), and the scores."""
    scores = loo_rms(table, wrap)
    best = min(scores, key=lambda m: (scores[m], METHODS.index(m)))
    return best, scores
