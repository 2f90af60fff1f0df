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
products. A pitch table is one line of points, not evenly spaced (:func:`smooth_line`:
second divided differences in mean steps, the points moved by no more than their own
scatter allows). Pure: arrays in, arrays out.
"""

from __future__ import annotations

import math
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


def _penalty_eig(n: int, x: NDArray[np.float64] | None = None
                 ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:  # fmt: skip
    """Eigenvalues and eigenvectors of DᵀD, D the second differences of ``n`` values (at
    positions ``x``: :func:`divided_differences`); no penalty, identity vectors, for fewer
    than MIN_LINES."""
    if n < MIN_LINES:
        return np.zeros(n), np.eye(n)
    d = np.diff(np.eye(n), n=2, axis=0) if x is None else divided_differences(x, 2)
    e, u = np.linalg.eigh(d.T @ d)
    return np.clip(e, 0.0, None), u


def divided_differences(x: NDArray[np.float64], order: int) -> NDArray[np.float64]:
    """D: the ``order``-th divided differences at positions ``x`` times order! and the mean
    step to the order (dimensionless; evenly spaced points: the plain differences, and a
    polynomial of degree order − 1 costs nothing)."""
    h = float(np.mean(np.diff(x)))
    d = np.zeros((x.size - order, x.size))
    for i in range(x.size - order):
        xs = x[i : i + order + 1]
        for j in range(order + 1):
            d[i, i + j] = math.factorial(order) * h**order / np.prod(
                [xs[j] - xs[k] for k in range(order + 1) if k != j])  # fmt: skip
    return d


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
    # every pair of weights at once: (ly, lx, ny, nx)
    w = 1.0 / (1.0 + lam_x[None, :, None, None] * ex[None, None, None, :]
               + lam_y[:, None, None, None] * ey[None, None, :, None])  # fmt: skip
    fit = uy @ (w * zt) @ ux.T
    loo = (z - fit) / np.maximum(1.0 - uy2 @ w @ ux2.T, 1e-9)
    score = np.mean(loo**2, axis=(2, 3))
    score[(lam_y[:, None] == 0.0) & (lam_x[None, :] == 0.0)] = np.inf  # the interpolant:
    if not np.isfinite(score).any():  # nothing left out can be judged (one node each way)
        return SmoothedGrid(z.copy(), 0.0, 0.0, np.full_like(z, np.nan))
    iy, ix = np.unravel_index(int(np.argmin(score)), score.shape)  # the first, as searched
    return SmoothedGrid(fit[iy, ix], float(lam_x[ix]), float(lam_y[iy]), loo[iy, ix])


@dataclass(frozen=True)
class SmoothedLine:
    """Values along one line of points, smoothed (``values``, same units as given), the
    weight chosen (0: the points kept as they are) and the RMS change of the points."""

    values: NDArray[np.float64]
    lam: float
    change_rms: float


def smooth_line(x: ArrayLike, values: ArrayLike, max_change_rms: float) -> SmoothedLine:
    """``values`` at strictly increasing positions ``x`` smoothed by the weight whose
    leave-one-out residuals have the least mean square, moving the points by no more than
    ``max_change_rms`` (RMS, the units of the values: what the scatter of a point's own
    readings could have put it off by). Leave-one-out alone takes a line too sparse for
    what changes along it (a wave of a few points a period) for noise and flattens it;
    its points differ by more than their scatter, so the cap keeps them (the heaviest
    weight up to the one chosen that moves them no further). Fewer than MIN_LINES points,
    or a cap of 0: returned as they are."""
    pos = np.asarray(x, dtype=np.float64)
    z = np.asarray(values, dtype=np.float64)
    if z.ndim != 1 or pos.shape != z.shape:
        raise ValueError("smooth_line: x and values must be 1-D and the same length")
    if z.size < MIN_LINES or not max_change_rms > 0:
        return SmoothedLine(z.copy(), 0.0, 0.0)
    if not np.all(np.diff(pos) > 0):
        raise ValueError("smooth_line: positions must be strictly increasing")
    e, u = _penalty_eig(z.size, pos)
    zt, u2 = u.T @ z, u**2
    fits = []
    for lam in LAMBDAS[1:]:
        w = 1.0 / (1.0 + lam * e)
        fit = u @ (w * zt)
        loo = (z - fit) / np.maximum(1.0 - u2 @ w, 1e-9)
        fits.append((float(np.mean(loo**2)), float(lam), fit))
    chosen = min(range(len(fits)), key=lambda i: fits[i][0])
    for i in range(chosen, -1, -1):  # lighter weights, until within the cap
        change = float(np.sqrt(np.mean((fits[i][2] - z) ** 2)))
        if change <= max_change_rms:
            return SmoothedLine(fits[i][2], fits[i][1], change)
    return SmoothedLine(z.copy(), 0.0, 0.0)
