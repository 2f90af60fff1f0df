"""A measured error grid (or a pitch table's line of points), smoothed as much as its own
scatter says: penalised least squares with the smoothing chosen by exact leave-one-out.

Every node of an XY grid is one stop of two axes, read once or twice: it holds the
positioning scatter of that stop (0.3-1 µm on a rough machine) as well as the field. A
cubic grid through those values follows the scatter, and along a line of the grid (what one
axis sees with the other parked) the differences between neighbouring nodes add up to a
peak-to-peak error of several scatters. Smoothed, the grid keeps the field and drops the
scatter; how much is decided by the data, per component, as in the sweep (:mod:`.sweep`).

For values Z on ny × nx nodes the smoothed F minimises

    ‖Z − F‖² + λx ‖F Dxᵀ‖² + λy ‖Dy F‖²

(D second differences along the grid lines, in node steps). The penalty is separable, so
in the eigenvectors of the two 1-D penalties the fit is a division, and the diagonal of
its hat matrix (hence every leave-one-out residual, r / (1 − h)) is two small matrix
products. A pitch table is one line of points, not evenly spaced, each a mean whose
standard error is known (:func:`smooth_line`: second divided differences in mean steps,
the weight chosen by the expected error at the points). Pure: arrays in, arrays out.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

#: the smoothing weights tried along each direction (dimensionless: node steps)
LAMBDAS = np.concatenate([[0.0], np.geomspace(1e-3, 1e5, 33)])
#: lines a direction needs before it is smoothed along (a second difference needs three)
MIN_LINES = 4


@dataclass(frozen=True)
class SmoothedGrid:
    """One error component on a grid, smoothed (``values``, same shape and units as given),
    the weights chosen, and each node's leave-one-out residual (what the fit without it
    misses there)."""

    values: NDArray[np.float64]
    lambda_x: float
    lambda_y: float
    loo: NDArray[np.float64]


def _penalty_eig(n: int) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Eigenvalues and eigenvectors of DᵀD, D the second differences of ``n`` values
    (no penalty, identity vectors, for fewer than MIN_LINES)."""
    if n < MIN_LINES:
        return np.zeros(n), np.eye(n)
    d = np.diff(np.eye(n), n=2, axis=0)
    e, u = np.linalg.eigh(d.T @ d)
    return np.clip(e, 0.0, None), u


def _second_differences(x: NDArray[np.float64]) -> NDArray[np.float64]:
    """D: the second divided differences at positions ``x`` times the mean step squared
    (evenly spaced points: the plain second differences)."""
    h = np.diff(x)
    a, b = h[:-1], h[1:]
    rows = np.arange(x.size - 2)
    d = np.zeros((x.size - 2, x.size))
    d[rows, rows] = 2.0 / (a * (a + b))
    d[rows, rows + 1] = -2.0 / (a * b)
    d[rows, rows + 2] = 2.0 / (b * (a + b))
    return d * float(np.mean(h)) ** 2


def smooth_grid(values: ArrayLike) -> SmoothedGrid:
    """``values`` (ny × nx, one component at the nodes) smoothed by the weights whose
    leave-one-out residuals have the least mean square."""
    z = np.asarray(values, dtype=np.float64)
    if z.ndim != 2:
        raise ValueError("smooth_grid: values must be a 2-D grid (ny × nx)")
    ey, uy = _penalty_eig(z.shape[0])
    ex, ux = _penalty_eig(z.shape[1])
    zt = uy.T @ z @ ux
    uy2, ux2 = uy**2, ux**2
    lam_y = LAMBDAS if z.shape[0] >= MIN_LINES else LAMBDAS[:1]
    lam_x = LAMBDAS if z.shape[1] >= MIN_LINES else LAMBDAS[:1]
    best: tuple[float, float, float, NDArray[np.float64], NDArray[np.float64]] | None = None
    for ly in lam_y:
        for lx in lam_x:
            if lx == 0.0 and ly == 0.0:
                continue  # the interpolant: nothing left out can be judged
            w = 1.0 / (1.0 + lx * ex[None, :] + ly * ey[:, None])
            fit = uy @ (w * zt) @ ux.T
            hat = uy2 @ w @ ux2.T
            loo = (z - fit) / np.maximum(1.0 - hat, 1e-9)
            score = float(np.mean(loo**2))
            if best is None or score < best[0]:
                best = (score, float(lx), float(ly), fit, loo)
    if best is None:  # a grid of one node each way
        return SmoothedGrid(z.copy(), 0.0, 0.0, np.full_like(z, np.nan))
    _, lx, ly, fit, loo = best
    return SmoothedGrid(fit, lx, ly, loo)



@dataclass(frozen=True)
class SmoothedLine:
    """Values along one line of points, smoothed (``values``, same units as given) and the
    weight chosen (0: the points kept as they are)."""

    values: NDArray[np.float64]
    lam: float


def smooth_line(x: ArrayLike, values: ArrayLike, sigma: ArrayLike) -> SmoothedLine:
    """``values`` at strictly increasing positions ``x``, each with the standard error
    ``sigma`` (same units; 0 for a point to be kept as it is), smoothed by the weight with
    the least expected error at the points: Stein's unbiased risk estimate (Mallows' Cp)
    Σ (y − f)²/σ² + 2 tr H − n, with the penalised fit weighted by 1/σ². A line whose
    points differ by more than their errors is kept (nothing says their differences are
    noise, even where they are too far apart to say what lies between); points that
    scatter by their errors around a smooth curve are pulled to it. Fewer than MIN_LINES
    points, or none with an error: returned as they are."""
    pos = np.asarray(x, dtype=np.float64)
    z = np.asarray(values, dtype=np.float64)
    err = np.broadcast_to(np.asarray(sigma, dtype=np.float64), z.shape)
    if z.ndim != 1 or pos.shape != z.shape:
        raise ValueError("smooth_line: x and values must be 1-D and the same length")
    if not np.all(err >= 0):
        raise ValueError("smooth_line: sigma must be ≥ 0")
    if z.size < MIN_LINES or not np.any(err > 0):
        return SmoothedLine(z.copy(), 0.0)
    if not np.all(np.diff(pos) > 0):
        raise ValueError("smooth_line: positions must be strictly increasing")
    # in units of the mean error; a point without one weighs a million times more
    scale = float(np.mean(err[err > 0]))
    inv_sqrt_w = np.maximum(err / scale, 1e-3)  # σ_i / scale = w_i^(−1/2)
    d = _second_differences(pos)
    k = d.T @ d * inv_sqrt_w[:, None] * inv_sqrt_w[None, :]
    e, u = np.linalg.eigh(k)
    e = np.clip(e, 0.0, None)
    zt = u.T @ (z / inv_sqrt_w)
    resid = (z / inv_sqrt_w) / scale
    best = (float(z.size), 0.0, z.copy())  # λ = 0: the points, SURE = n
    for lam in LAMBDAS[1:]:
        w = 1.0 / (1.0 + lam * e)
        g = u @ (w * zt)  # the fit in whitened units
        sure = float(np.sum((resid - g / scale) ** 2)) + 2.0 * float(w.sum()) - z.size
        if sure < best[0]:
            best = (sure, float(lam), g * inv_sqrt_w)
    return SmoothedLine(best[2], best[1])
