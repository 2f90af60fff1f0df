"""Planar (XY) error model and the planar stage of the chain (seed 001).

The model is the 2-D error field ``E(c) = actual − commanded`` of a pair of axes, identified
from commanded points and the measured actual positions. Two models:

- :class:`GridModel`: the measured rectilinear grid, interpolated bicubically (or bilinearly);
- :class:`PolyModel`: a least-squares 2-D polynomial (total degree d, Legendre basis on the
  normalised measured area), d chosen by leave-one-out cross-validation unless fixed.

Outside the measured area the field is clamped to the edge. The stage finds the command for a
desired position by the fixed-point iteration ``c ← p − E(c)``, bounded in count; feedback is
mapped back exactly by ``p = c + E(c)``. For speed, the stage evaluates a rectilinear bilinear
twin of the model resampled at build time within :data:`FIELD_TOLERANCE_MM`.
"""

from __future__ import annotations

from array import array
from bisect import bisect_right
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from numpy.polynomial import legendre
from numpy.typing import ArrayLike, NDArray

from .errors import ConvergenceError, TableError, where

GridMethod = Literal["cubic", "linear"]
#: Largest difference (mm) between the model and the bilinear twin the stage evaluates.
FIELD_TOLERANCE_MM = 1e-6
#: Largest slope of the error field allowed: beyond it the correction is not a small,
#: unique perturbation and the command iteration may not converge.
MAX_FIELD_SLOPE = 0.1
MAX_POLY_DEGREE = 6
#: a simpler model whose leave-one-out RMS is within this share of the best is preferred
PARSIMONY = 0.05
_MAX_FIELD_NODES = 1 << 21


@dataclass(frozen=True, eq=False)
class PlanarMeasurement:
    """Commanded points and the measured actual positions of both axes (mm), shape (N, 2)."""

    command_mm: NDArray[np.float64]
    actual_mm: NDArray[np.float64]
    source: str = "<points>"
    lines: tuple[int, ...] | None = None

    def __post_init__(self) -> None:
        cmd = np.asarray(self.command_mm, dtype=np.float64).reshape(-1, 2)
        act = np.asarray(self.actual_mm, dtype=np.float64).reshape(-1, 2)
        if cmd.shape != act.shape:
            raise TableError(f"{self.source}: commanded and actual points differ in count")
        if cmd.shape[0] < 4:
            raise TableError(f"{self.source}: a planar model needs at least 4 points")
        for name, values in (("commanded", cmd), ("actual", act)):
            bad = np.flatnonzero(~np.all(np.isfinite(values), axis=1))
            if bad.size:
                raise TableError(f"{self.point(int(bad[0]))}: {name} position is not finite")
        cmd.setflags(write=False)
        act.setflags(write=False)
        object.__setattr__(self, "command_mm", cmd)
        object.__setattr__(self, "actual_mm", act)

    @property
    def error_mm(self) -> NDArray[np.float64]:
        return self.actual_mm - self.command_mm

    def point(self, i: int) -> str:
        line = self.lines[i] if self.lines is not None else None
        x, y = np.asarray(self.command_mm, dtype=np.float64).reshape(-1, 2)[i]
        return where(self.source, line, None) + f" (point {x:g}, {y:g} mm)"

    @property
    def bounds_mm(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        return self.command_mm.min(axis=0), self.command_mm.max(axis=0)


class PlanarModel:
    """Interface of an XY error model: ``error_mm(points (..., 2)) -> (..., 2)``."""

    lower_mm: NDArray[np.float64]
    upper_mm: NDArray[np.float64]
    kind: str

    def error_mm(self, points_mm: ArrayLike) -> NDArray[np.float64]:  # pragma: no cover
        raise NotImplementedError

    def clamp(self, points_mm: ArrayLike) -> NDArray[np.float64]:
        return np.clip(np.asarray(points_mm, dtype=np.float64), self.lower_mm, self.upper_mm)

    def error_on_grid_mm(self, gx_mm: NDArray[np.float64], gy_mm: NDArray[np.float64]
                         ) -> NDArray[np.float64]:  # fmt: skip
        """The error (mm) at every node of the rectilinear grid ``gx_mm`` × ``gy_mm``
        (increasing), shape (len(gy_mm), len(gx_mm), 2): what :meth:`error_mm` gives on
        their mesh."""
        return self.error_mm(np.stack(np.meshgrid(gx_mm, gy_mm), axis=-1))

    def nodes_hint_mm(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Lines the resampled field must contain (measured grid lines, or the bounds)."""
        return (
            np.array([self.lower_mm[0], self.upper_mm[0]]),
            np.array([self.lower_mm[1], self.upper_mm[1]]),
        )


@dataclass(frozen=True, eq=False)
class GridModel(PlanarModel):
    """Error field on a rectilinear grid: ``ex_mm[j, i]`` at ``(x_mm[i], y_mm[j])``."""

    x_mm: NDArray[np.float64]
    y_mm: NDArray[np.float64]
    ex_mm: NDArray[np.float64]
    ey_mm: NDArray[np.float64]
    method: GridMethod = "cubic"
    source: str = "<grid>"
    kind: str = field(default="grid", init=False)
    lower_mm: NDArray[np.float64] = field(init=False)
    upper_mm: NDArray[np.float64] = field(init=False)
    _splines: tuple = field(init=False, repr=False)

    def __post_init__(self) -> None:
        if self.method not in ("cubic", "linear"):
            raise TableError(f"{self.source}: grid method {self.method!r} is not cubic or linear")
        x, y = np.asarray(self.x_mm, np.float64), np.asarray(self.y_mm, np.float64)
        if x.size < 2 or y.size < 2:
            raise TableError(f"{self.source}: a grid needs at least 2 lines in X and in Y")
        if np.any(np.diff(x) <= 0) or np.any(np.diff(y) <= 0):
            raise TableError(f"{self.source}: grid lines must be strictly increasing")
        object.__setattr__(self, "lower_mm", np.array([x[0], y[0]]))
        object.__setattr__(self, "upper_mm", np.array([x[-1], y[-1]]))
        kx = 3 if (self.method == "cubic" and x.size >= 4) else 1
        ky = 3 if (self.method == "cubic" and y.size >= 4) else 1
        from scipy.interpolate import RectBivariateSpline  # (its start: pitch.py says why)

        splines = tuple(
            RectBivariateSpline(x, y, np.asarray(values, np.float64).T, kx=kx, ky=ky, s=0)
            for values in (self.ex_mm, self.ey_mm)
        )
        object.__setattr__(self, "_splines", splines)

    @classmethod
    def from_measurement(cls, meas: PlanarMeasurement, method: GridMethod = "cubic") -> GridModel:
        """Grid model from a full rectilinear grid; scattered points are first gridded.

        Scattered sets are interpolated (Clough–Tocher, C1) onto the grid of their distinct
        coordinates; grid nodes outside the points' convex hull take the nearest point's error.
        """
        cmd, err = meas.command_mm, meas.error_mm
        xs, ys = np.unique(cmd[:, 0]), np.unique(cmd[:, 1])
        ix = np.searchsorted(xs, cmd[:, 0])
        iy = np.searchsorted(ys, cmd[:, 1])
        count = np.zeros((ys.size, xs.size))
        np.add.at(count, (iy, ix), 1)
        if np.all(count >= 1) and xs.size * ys.size <= cmd.shape[0]:
            ex = np.zeros_like(count)
            ey = np.zeros_like(count)
            np.add.at(ex, (iy, ix), err[:, 0])
            np.add.at(ey, (iy, ix), err[:, 1])
            return cls(xs, ys, ex / count, ey / count, method, meas.source)
        if xs.size > 64 or ys.size > 64:
            xs = np.linspace(xs[0], xs[-1], 33)
            ys = np.linspace(ys[0], ys[-1], 33)
        gx, gy = np.meshgrid(xs, ys)
        nodes = np.column_stack([gx.ravel(), gy.ravel()])
        from scipy.interpolate import CloughTocher2DInterpolator  # (pitch.py says why)

        inside = CloughTocher2DInterpolator(cmd, err)(nodes)
        nearest = np.argmin(((nodes[:, None, :] - cmd[None, :, :]) ** 2).sum(axis=2), axis=1)
        filled = np.where(np.isfinite(inside), inside, err[nearest])
        return cls(
            xs,
            ys,
            filled[:, 0].reshape(gx.shape),
            filled[:, 1].reshape(gx.shape),
            method,
            meas.source,
        )

    def error_mm(self, points_mm: ArrayLike) -> NDArray[np.float64]:
        p = self.clamp(points_mm)
        flat = p.reshape(-1, 2)
        out = np.column_stack([s.ev(flat[:, 0], flat[:, 1]) for s in self._splines])
        return out.reshape(p.shape)

    def error_on_grid_mm(self, gx_mm: NDArray[np.float64], gy_mm: NDArray[np.float64]
                         ) -> NDArray[np.float64]:  # fmt: skip
        """As :meth:`PlanarModel.error_on_grid_mm`, the splines evaluated on the grid's
        lines rather than node by node (a plate's 15 × 10 grid, resampled to 961 × 641
        nodes: its build 1.49 → 0.37 s)."""
        x = np.clip(np.asarray(gx_mm, np.float64), self.lower_mm[0], self.upper_mm[0])
        y = np.clip(np.asarray(gy_mm, np.float64), self.lower_mm[1], self.upper_mm[1])
        return np.stack([s(x, y, grid=True).T for s in self._splines], axis=-1)

    def nodes_hint_mm(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        return np.asarray(self.x_mm, np.float64), np.asarray(self.y_mm, np.float64)


@dataclass(frozen=True, eq=False)
class PolyModel(PlanarModel):
    """2-D polynomial error field of total degree ``degree`` (Legendre basis, normalised)."""

    degree: int
    lower_mm: NDArray[np.float64]
    upper_mm: NDArray[np.float64]
    coef_mm: NDArray[np.float64]  # shape (terms, 2)
    loo_rms_mm: dict[int, float] = field(default_factory=dict)
    kind: str = field(default="poly", init=False)

    @staticmethod
    def terms(degree: int) -> list[tuple[int, int]]:
        return [(i, total - i) for total in range(degree + 1) for i in range(total + 1)]

    def _design(self, points_mm: NDArray[np.float64]) -> NDArray[np.float64]:
        return _design_matrix(points_mm, self.lower_mm, self.upper_mm, self.degree)

    def error_mm(self, points_mm: ArrayLike) -> NDArray[np.float64]:
        p = self.clamp(points_mm)
        flat = p.reshape(-1, 2)
        return (self._design(flat) @ self.coef_mm).reshape(p.shape)

    @classmethod
    def fit(
        cls, meas: PlanarMeasurement, degree: int | None = None, max_degree: int = MAX_POLY_DEGREE
    ) -> PolyModel:
        """Least-squares fit; ``degree=None`` picks the lowest degree whose LOO RMS is
        within :data:`PARSIMONY` of the lowest (a higher degree that predicts no better
        than that only follows the points' scatter)."""
        lower, upper = meas.bounds_mm
        if np.any(upper - lower <= 0):
            raise TableError(f"{meas.source}: planar points must span an area, not a line")
        cmd, err = meas.command_mm, meas.error_mm
        n = cmd.shape[0]
        candidates = [degree] if degree is not None else list(range(1, max_degree + 1))
        scores: dict[int, float] = {}
        fits: dict[int, NDArray[np.float64]] = {}
        for d in candidates:
            if d < 0 or d > max(max_degree, MAX_POLY_DEGREE):
                raise TableError(f"{meas.source}: polynomial degree {d} is not in 0..{max_degree}")
            a = _design_matrix(cmd, lower, upper, d)
            if a.shape[1] >= n:
                if degree is not None:
                    raise TableError(
                        f"{meas.source}: degree {d} needs more than {a.shape[1]} points, got {n}"
                    )
                break
            q, r = np.linalg.qr(a)
            if np.min(np.abs(np.diag(r))) < 1e-10 * np.max(np.abs(np.diag(r))):
                if degree is not None:
                    raise TableError(f"{meas.source}: points do not determine a degree-{d} fit")
                continue
            coef, loo = _fit_loo(q, r, err)
            scores[d] = float(np.sqrt(np.mean(np.sum(loo**2, axis=1))))
            fits[d] = coef
        if not fits:
            raise TableError(f"{meas.source}: too few points for a polynomial model ({n})")
        least = min(scores[d] for d in fits)
        best = min(d for d in fits if scores[d] <= least * (1.0 + PARSIMONY))
        return cls(best, lower, upper, fits[best], scores)


def _fit_loo(q: NDArray[np.float64], r: NDArray[np.float64], err: NDArray[np.float64]
             ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:  # fmt: skip
    """Least-squares coefficients from the QR of the design, and each point's leave-one-out
    error (its residual over one less its leverage; inf where it alone fixes a term)."""
    coef = np.linalg.solve(r, q.T @ err)
    leverage = np.sum(q**2, axis=1)
    resid = err - (q @ r) @ coef
    with np.errstate(divide="ignore", invalid="ignore"):
        loo = np.where((leverage > 1 - 1e-9)[:, None], np.inf,
                       resid / (1 - leverage)[:, None])  # fmt: skip
    return coef, loo


def poly_loo_mm(meas: PlanarMeasurement, degree: int) -> NDArray[np.float64]:
    """Each point's leave-one-out error (x, y; mm) of the degree-``degree`` polynomial fitted
    to ``meas``: what it predicts there without that point, less what was read."""
    lower, upper = meas.bounds_mm
    q, r = np.linalg.qr(_design_matrix(meas.command_mm, lower, upper, degree))
    return _fit_loo(q, r, meas.error_mm)[1]


def _design_matrix(
    points_mm: NDArray[np.float64],
    lower: NDArray[np.float64],
    upper: NDArray[np.float64],
    degree: int,
) -> NDArray[np.float64]:
    span = np.where(upper > lower, upper - lower, 1.0)
    u = 2.0 * (points_mm - lower) / span - 1.0
    vx = legendre.legvander(u[:, 0], degree)
    vy = legendre.legvander(u[:, 1], degree)
    return np.column_stack([vx[:, i] * vy[:, j] for i, j in PolyModel.terms(degree)])


@dataclass(frozen=True, eq=False)
class _BilinearField:
    """Rectilinear bilinear field (mm) with edge clamping; vector and scalar evaluation."""

    gx: NDArray[np.float64]
    gy: NDArray[np.float64]
    values: NDArray[np.float64]  # shape (ny, nx, 2)
    _gx: array = field(init=False, repr=False)
    _gy: array = field(init=False, repr=False)
    _vx: array = field(init=False, repr=False)
    _vy: array = field(init=False, repr=False)

    def __post_init__(self) -> None:
        for name, values in (("_gx", self.gx), ("_gy", self.gy), ("_vx", self.values[:, :, 0]),
                             ("_vy", self.values[:, :, 1])):  # fmt: skip
            plain = array("d")  # C doubles, as numpy's: copied whole, not element by element
            plain.frombytes(np.ascontiguousarray(values, dtype=np.float64).tobytes())
            object.__setattr__(self, name, plain)

    def __call__(self, points_mm: NDArray[np.float64]) -> NDArray[np.float64]:
        gx, gy, v = self.gx, self.gy, self.values
        x = np.clip(points_mm[..., 0], gx[0], gx[-1])
        y = np.clip(points_mm[..., 1], gy[0], gy[-1])
        i = np.clip(np.searchsorted(gx, x, side="right") - 1, 0, gx.size - 2)
        j = np.clip(np.searchsorted(gy, y, side="right") - 1, 0, gy.size - 2)
        tx = ((x - gx[i]) / (gx[i + 1] - gx[i]))[..., None]
        ty = ((y - gy[j]) / (gy[j + 1] - gy[j]))[..., None]
        low = v[j, i] * (1 - tx) + v[j, i + 1] * tx
        high = v[j + 1, i] * (1 - tx) + v[j + 1, i + 1] * tx
        return low * (1 - ty) + high * ty

    def scalar(self, x: float, y: float) -> tuple[float, float]:
        gx, gy = self._gx, self._gy
        nx, ny = len(gx), len(gy)
        x = min(max(x, gx[0]), gx[nx - 1])
        y = min(max(y, gy[0]), gy[ny - 1])
        i = min(max(bisect_right(gx, x) - 1, 0), nx - 2)
        j = min(max(bisect_right(gy, y) - 1, 0), ny - 2)
        tx = (x - gx[i]) / (gx[i + 1] - gx[i])
        ty = (y - gy[j]) / (gy[j + 1] - gy[j])
        k = j * nx + i
        w00 = (1 - tx) * (1 - ty)
        w01 = tx * (1 - ty)
        w10 = (1 - tx) * ty
        w11 = tx * ty
        vx, vy = self._vx, self._vy
        return (
            w00 * vx[k] + w01 * vx[k + 1] + w10 * vx[k + nx] + w11 * vx[k + nx + 1],
            w00 * vy[k] + w01 * vy[k + 1] + w10 * vy[k + nx] + w11 * vy[k + nx + 1],
        )


def _resample(model: PlanarModel) -> _BilinearField:
    """Bilinear twin of ``model`` within :data:`FIELD_TOLERANCE_MM` (exact for linear grids)."""
    hx, hy = model.nodes_hint_mm()
    if isinstance(model, GridModel) and model.method == "linear":
        gx, gy = hx, hy
        values = np.stack([model.ex_mm, model.ey_mm], axis=-1).astype(np.float64)
        return _BilinearField(gx, gy, values)
    sub = 4
    while True:
        gx = _subdivide(hx, sub)
        gy = _subdivide(hy, sub)
        values = model.error_on_grid_mm(gx, gy)
        # checked at the cells' centres, where the bilinear twin is its corners' mean
        centre = 0.25 * (values[:-1, :-1] + values[:-1, 1:] + values[1:, :-1] + values[1:, 1:])
        mx = 0.5 * (gx[1:] + gx[:-1])
        my = 0.5 * (gy[1:] + gy[:-1])
        gap = np.abs(model.error_on_grid_mm(mx, my) - centre).max()
        if gap <= FIELD_TOLERANCE_MM or gx.size * gy.size * 4 > _MAX_FIELD_NODES:
            return _BilinearField(gx, gy, values)
        sub *= 2


def _subdivide(lines: NDArray[np.float64], sub: int) -> NDArray[np.float64]:
    t = np.linspace(0.0, 1.0, sub + 1)[:-1]
    inner = (lines[:-1, None] + np.diff(lines)[:, None] * t[None, :]).reshape(-1)
    return np.concatenate([inner, lines[-1:]])


@dataclass(frozen=True, eq=False)
class PlanarStage:
    """Joint XY correction of two axes named ``axes`` (first = X role, second = Y role)."""

    model: PlanarModel
    axes: tuple[str, str] = ("X", "Y")
    max_iterations: int = 20
    source: str = "<planar>"
    field_: _BilinearField = field(init=False, repr=False)

    def __post_init__(self) -> None:
        twin = _resample(self.model)
        slope = max(
            np.abs(np.diff(twin.values, axis=1) / np.diff(twin.gx)[None, :, None]).max(),
            np.abs(np.diff(twin.values, axis=0) / np.diff(twin.gy)[:, None, None]).max(),
        )
        if not np.all(np.isfinite(twin.values)):
            raise TableError(f"{self.source}: planar model gives non-finite errors")
        if slope > MAX_FIELD_SLOPE:
            raise TableError(
                f"{self.source}: planar error field changes by {slope:.3g} mm per mm, more than "
                f"{MAX_FIELD_SLOPE}: not a small correction (check units and points)"
            )
        object.__setattr__(self, "field_", twin)

    def max_abs_correction_mm(self) -> float:
        return float(np.abs(self.field_.values).max())

    def error_mm(self, command_mm: ArrayLike) -> NDArray[np.float64]:
        return self.field_(np.asarray(command_mm, dtype=np.float64))

    def inverse(self, command_mm: ArrayLike) -> NDArray[np.float64]:
        """Actual XY position (mm) reached by commanding ``command_mm`` (..., 2)."""
        c = np.asarray(command_mm, dtype=np.float64)
        return c + self.field_(c)

    def forward(self, target_mm: ArrayLike, tolerance_mm: float) -> NDArray[np.float64]:
        """Command (..., 2) whose actual position is ``target_mm`` within ``tolerance_mm``."""
        p = np.asarray(target_mm, dtype=np.float64)
        c = p - self.field_(p)
        for _ in range(self.max_iterations):
            e = self.field_(c)
            residual = np.abs(c + e - p).max() if c.size else 0.0
            if residual <= tolerance_mm:
                return c
            c = p - e
        raise ConvergenceError(
            f"{self.source}: XY command iteration did not converge to {tolerance_mm:g} mm in "
            f"{self.max_iterations} steps"
        )

    def forward_scalar(self, x_mm: float, y_mm: float, tolerance_mm: float) -> tuple[float, float]:
        ex, ey = self.field_.scalar(x_mm, y_mm)
        cx, cy = x_mm - ex, y_mm - ey
        for _ in range(self.max_iterations):
            ex, ey = self.field_.scalar(cx, cy)
            rx, ry = cx + ex - x_mm, cy + ey - y_mm
            if abs(rx) <= tolerance_mm and abs(ry) <= tolerance_mm:
                return cx, cy
            cx, cy = x_mm - ex, y_mm - ey
        raise ConvergenceError(
            f"{self.source}: XY command iteration did not converge to {tolerance_mm:g} mm in "
            f"{self.max_iterations} steps at ({x_mm:g}, {y_mm:g}) mm"
        )

    def inverse_scalar(self, x_mm: float, y_mm: float) -> tuple[float, float]:
        ex, ey = self.field_.scalar(x_mm, y_mm)
        return x_mm + ex, y_mm + ey
