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

from dataclasses import replace

import numpy as np
from numpy.typing import NDArray
from scipy.interpolate import CubicSpline, PchipInterpolator

from ...compensation import PitchTable
from ...compensation.cyclic import CyclicModel
from ..plans.rawdata import (
    TARGET_TOLERANCE_MM,
    AxisDeviations,
    RawData,
    axis_deviations,
    pooled_variance,
)

METHODS = ("linear", "smooth", "pchip")
#: standard errors by which a levelling line's slope must stand out of its readings' scatter
SLOPE_SIGNIFICANCE = 2.0
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
            misses += _left_out(xx, yy, inner, method)
        out[method] = float(np.sqrt(np.mean(np.square(misses))))
    return out


def _left_out(x: NDArray[np.float64], y: NDArray[np.float64], at: range, method: str
              ) -> list[float]:  # fmt: skip
    """Each point ``at`` predicted by ``method`` through every other point, less itself."""
    out = []
    for i in at:
        keep = np.arange(x.size) != i
        out.append(_predict(x[keep], y[keep], float(x[i]), method) - float(y[i]))
    return out


def choose_interpolation(table: PitchTable, wrap: bool = False) -> tuple[str, dict[str, float]]:
    """The method with the smallest leave-one-out RMS (ties: the simpler), and the scores."""
    scores = loo_rms(table, wrap)
    best = min(scores, key=lambda m: (scores[m], METHODS.index(m)))
    return best, scores


def _cyclic_mm(cyclic: CyclicModel | None, x_mm: NDArray[np.float64]) -> NDArray[np.float64]:
    """The once-per-lead term at ``x_mm`` (mm; zero without one)."""
    return np.zeros_like(x_mm) if cyclic is None else cyclic.error_mm(x_mm)


def between_points(dev: AxisDeviations, cyclic: CyclicModel | None = None,
                   curves: bool = False) -> tuple[float, float] | None:  # fmt: skip
    """(ratio, miss RMS in mm): how much more a table through the ISO runs' means misses
    between its points than their scatter explains: each inner mean predicted by the
    straight line through its two neighbours (per direction of approach), the RMS of those
    misses over the RMS the means' own standard errors give them
    (s²(1/nᵢ + (1−w)²/nᵢ₋₁ + w²/nᵢ₊₁), s pooled over the runs).
    About 1 where the table follows the screw as closely as its points allow; the real-data
    slits' first tables read 7-39 (slit-11358's Y, 38: a dip of 3.5 µm over 2 mm between
    points 3.5 mm apart), the sdss plates' 1.0-2.0. With ``cyclic``, of the deviations net
    of that once-per-lead term (a table every few leads reads it at one phase, its
    midpoints at another); the miss RMS is what midpoints may win. With ``curves``, each
    inner mean predicted along whichever interpolation (:data:`METHODS`, through every other
    mean) misses least, as the table will be read (:func:`choose_interpolation`): a curve
    that a spline follows is not a miss more points would buy (slit-11358's Y, its minimum
    read at the first table's midpoints: straight lines missed the truth by 0.55 µm RMS,
    the spline 0.15; its quarter points left 0.16). None with fewer than 3 targets or 2
    runs."""
    x = dev.target_mm
    cyc = _cyclic_mm(cyclic, x)
    series = [d - cyc[:, None] for d in (dev.up_mm, dev.down_mm) if d is not None]
    if x.size < 3 or not series:
        return None
    n = [np.sum(np.isfinite(d), axis=1) for d in series]
    if min(int(k.min()) for k in n) < 2:
        return None
    means = [np.nanmean(d, axis=1) for d in series]
    s2, _ = pooled_variance(dev)
    w = (x[1:-1] - x[:-2]) / (x[2:] - x[:-2])
    miss2 = var = 0.0
    for m, k in zip(means, n):
        miss2 += float(np.sum((m[1:-1] - ((1 - w) * m[:-2] + w * m[2:])) ** 2))
        var += float(np.sum(s2 * (1 / k[1:-1] + (1 - w) ** 2 / k[:-2] + w**2 / k[2:])))
    if curves and x.size >= 5:
        miss2 = min(miss2, *(float(np.sum(np.square(
            [d for m in means for d in _left_out(x, m, range(1, x.size - 1), method)])))
            for method in METHODS[1:]))  # fmt: skip
    count = sum(m.size - 2 for m in means)
    return (float(np.sqrt(miss2 / var)), float(np.sqrt(miss2 / count))) if var > 0 else None


def _tilt(x: NDArray[np.float64], miss: NDArray[np.float64]) -> float:
    """The slope (per mm) of the straight line through ``miss`` at ``x`` where it stands out
    of what scatters about it by more than SLOPE_SIGNIFICANCE standard errors, else 0: what
    a table misses between its points scatters the midpoints about the first table's level
    too, and a line through few of them takes some of it for a tilt (on the quiet machine,
    rough-0's X read 4.28 µm levelled by every line, 3.72 by the offset alone)."""
    dx = x - x.mean()
    sxx = float(np.sum(dx**2))
    if x.size < 3 or sxx <= 0.0:
        return 0.0
    slope = float(np.sum(dx * (miss - miss.mean())) / sxx)
    rest = miss - miss.mean() - slope * dx
    se = float(np.sqrt(np.sum(rest**2) / (x.size - 2) / sxx))
    return slope if abs(slope) > SLOPE_SIGNIFICANCE * se else 0.0


def denser_miss(dev: AxisDeviations, first_mm: NDArray[np.float64],
                cyclic: CyclicModel | None = None) -> tuple[float, float] | None:  # fmt: skip
    """(ratio, miss RMS in mm): what a table read at its first points (``first_mm``) and at
    their midpoints (the rest of ``dev``, put on their level) is expected to miss between its
    points, over what the midpoints' scatter explains. The first table's miss at its
    midpoints as they read (along whichever interpolation misses least), times how much it
    fell from the first table's miss at twice the spacing (:func:`between_points` along
    curves), at most 1: a smooth error that a spline follows falls fast as points are added
    (slit-11358's Y: 4.84 → 0.91 µm RMS, its table through both then missed the truth by
    0.15), a rough screw's hardly (rough-9's Y: 6.10 → 4.39 µm). With ``cyclic``, net of
    that once-per-lead term. None where either cannot be said."""
    near = np.abs(dev.target_mm[:, None] - np.asarray(first_mm)[None, :])
    at_first = np.min(near, axis=1) <= TARGET_TOLERANCE_MM  # (as grouped: their mean)
    sub = [None if d is None else d[at_first] for d in (dev.up_mm, dev.down_mm)]
    first = replace(dev, target_mm=dev.target_mm[at_first], up_mm=sub[0], down_mm=sub[1])
    coarse = between_points(first, cyclic, curves=True)
    mid_x = dev.target_mm[~at_first]
    if coarse is None or coarse[1] <= 0.0 or mid_x.size == 0:
        return None
    s2, _ = pooled_variance(dev)
    cyc, cyc_mid = _cyclic_mm(cyclic, first.target_mm), _cyclic_mm(cyclic, mid_x)
    misses: dict[str, list[float]] = {m: [] for m in METHODS}
    var = []
    for d_first, d in zip(sub, (dev.up_mm, dev.down_mm)):
        if d_first is None or d is None:
            continue
        y = np.nanmean(d_first, axis=1) - cyc
        k_first = float(np.mean(np.sum(np.isfinite(d_first), axis=1)))
        d_mid = d[~at_first]
        k_mid = np.sum(np.isfinite(d_mid), axis=1)
        ok = k_mid > 0
        got = np.nanmean(np.where(ok[:, None], d_mid, 0.0), axis=1) - cyc_mid
        for method in METHODS:
            if first.target_mm.size < (3 if method == "linear" else 5):
                continue
            misses[method] += [_predict(first.target_mm, y, float(at), method) - g
                               for at, g in zip(mid_x[ok], got[ok])]  # fmt: skip
        var += list(s2 * (1 / k_mid[ok] + 0.5 / k_first))
    rms = [float(np.sqrt(np.mean(np.square(v)))) for v in misses.values() if v]
    if not rms or not var:
        return None
    fine = min(rms)
    expected = fine * min(1.0, fine / coarse[1])
    return expected / float(np.sqrt(np.mean(var))), expected


def denser_pays(miss_mm: float, s2_mm2: float, denser_runs: int, first_runs: int,
                all_runs: int) -> bool:
    """Whether a table's denser points (its quarter or eighth points), read at
    ``denser_runs`` runs, take more of its error off per reading than its more runs on the
    same targets (``first_runs`` up to ``all_runs``): the variance each takes off per
    target and per run read, the miss expected between its points (``miss_mm``,
    :func:`denser_miss`) less the denser points' own noise, against what the more runs
    take off the means' noise (``s2_mm2``: the runs' variance). (At 1.5 x a plain
    calibration's time rough-0's X was expected to miss 1.5 µm RMS between its points, its
    scatter 0.27 µm: the 4th and 5th runs took 0.005 µm² off per reading, the quarter
    points at one run 2.2.)"""
    denser = (miss_mm**2 - s2_mm2 / denser_runs) / denser_runs
    more = all_runs - first_runs
    runs = s2_mm2 * (1 / first_runs - 1 / all_runs) / more if more > 0 else 0.0
    return denser > runs


def _through(x: NDArray[np.float64], y: NDArray[np.float64], at: NDArray[np.float64]
             ) -> NDArray[np.float64]:  # fmt: skip
    """The first table's means at ``at``: along a spline through them where there are 4 or
    more (a line through few midpoints would take the straight lines' miss of a curved
    error for heat: smooth-2's Y, 7 points over 150 mm rising 10 µm in its last 20 mm,
    read 0.48 µm RMS levelled along straight lines, 0.27 along the spline, 0.57 without
    its midpoints), else straight lines."""
    if x.size >= 4:
        return np.asarray(CubicSpline(x, y, bc_type="not-a-knot")(at), dtype=np.float64)
    return np.interp(at, x, y)


def levelled_midpoints(first: RawData, mid: RawData, axis: str,
                       cyclic: CyclicModel | None = None, tilt: bool = True) -> RawData:
    """The midpoints' readings of ``axis`` (``mid``; or more runs on the same targets) put
    onto the level of the first table's (``first``): per run, their deviations minus the
    first table's means there (per direction of approach, :func:`_through`), their mean
    taken off, and with ``tilt`` the straight line in position through them where its
    slope stands out (:func:`_tilt`).
    The midpoints are read later, on a machine that has warmed or cooled meanwhile; a line
    in position is what a screw's growth puts between the two sets (not what they read
    between the points, which a line through many midpoints leaves). With ``cyclic``, both
    compared net of that once-per-lead term (the midpoints read it at another phase, and
    its amplitude changes along the travel). No ``tilt`` where the axis's own sensor
    follows its heat while both sets are read: a line between them is then what the table
    misses between its points, not heat (rough-8's X, Δa 1 → 4.8 µm while read, every set
    within 0.5 µm/m of the cold screw: the line taken off its midpoints tilted them
    2.5 µm/m, and the quiet machine's E at random parks read 4.53 µm against 3.11
    without it, a perfect table's 1.82)."""
    dev = axis_deviations(first, axis)
    cyc_first = _cyclic_mm(cyclic, dev.target_mm)
    means = {s: None if d is None else np.nanmean(d, axis=1) - cyc_first
             for s, d in ((1, dev.up_mm), (-1, dev.down_mm))}  # fmt: skip
    cyc_mid = _cyclic_mm(cyclic, mid.target_mm)
    actual = mid.actual_mm.copy()
    rows = np.flatnonzero(np.array(mid.axis) == axis)
    for run in np.unique(mid.run[rows]):
        sel = rows[mid.run[rows] == run]
        miss, keep = np.zeros(sel.size), np.zeros(sel.size, dtype=bool)
        for sign, m in means.items():
            here = mid.direction[sel] == sign
            if m is None or not here.any():
                continue
            ok = np.isfinite(m)
            miss[here] = mid.deviation_mm[sel[here]] - cyc_mid[sel[here]] - _through(
                dev.target_mm[ok], m[ok], mid.target_mm[sel[here]])
            keep[here] = True
        if keep.sum() < 2:
            continue
        x = mid.target_mm[sel][keep]
        slope = _tilt(x, miss[keep]) if tilt else 0.0
        line = float(np.mean(miss[keep])) + slope * (mid.target_mm[sel] - x.mean())
        actual[sel] = np.where(keep, actual[sel] - line, actual[sel])
    return replace(mid, actual_mm=actual)
