"""A strictly increasing piecewise-linear map and its exact inverse.

Every one-dimensional correction in compgw reduces to this: breakpoints ``x_mm`` in command
space with the axis error ``e_mm`` there (actual − commanded). The machine maps a command ``c``
to the actual position ``f(c) = c + e(c)``. With ``e`` linear between breakpoints, ``f`` is
linear between the images ``f_i = x_i + e_i``, so the inverse is again a linear interpolation:
``c = p − e`` with ``e`` interpolated over ``f_i``. Both directions are exact and O(log n).
Outside the breakpoints the error is held at the end value (callers add taper points).
"""

from __future__ import annotations

from array import array
from bisect import bisect_right
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray


@dataclass(frozen=True, eq=False)
class MonotoneMap:
    """Piecewise-linear ``f(c) = c + e(c)`` with ``f`` strictly increasing.

    ``period_mm`` (rotary axes) makes ``e`` periodic; positions are then taken modulo it.
    """

    x_mm: NDArray[np.float64]
    e_mm: NDArray[np.float64]
    period_mm: float | None = None
    f_mm: NDArray[np.float64] = field(init=False)
    _x_list: array = field(init=False, repr=False)
    _e_list: array = field(init=False, repr=False)
    _f_list: array = field(init=False, repr=False)

    def __post_init__(self) -> None:
        x = np.asarray(self.x_mm, dtype=np.float64)
        e = np.asarray(self.e_mm, dtype=np.float64)
        if self.period_mm is not None:
            x, e = _periodic_extension(x, e, self.period_mm)
        f = x + e
        if not np.all(np.diff(f) > 0):
            raise ValueError("map is not strictly increasing")
        for name, value in (("x_mm", x), ("e_mm", e), ("f_mm", f)):
            value.setflags(write=False)
            object.__setattr__(self, name, value)
        object.__setattr__(self, "_x_list", array("d", x.tolist()))
        object.__setattr__(self, "_e_list", array("d", e.tolist()))
        object.__setattr__(self, "_f_list", array("d", f.tolist()))

    # -- vectorised ---------------------------------------------------------------------
    def error_at_command(self, command_mm: ArrayLike) -> NDArray[np.float64]:
        """Axis error (actual − commanded, mm) when commanding ``command_mm``."""
        c = np.asarray(command_mm, dtype=np.float64)
        if self.period_mm is not None:
            c = np.mod(c, self.period_mm)
        return np.interp(c, self.x_mm, self.e_mm)

    def error_at_actual(self, actual_mm: ArrayLike) -> NDArray[np.float64]:
        """Axis error (mm) of the command that lands exactly on ``actual_mm``."""
        p = np.asarray(actual_mm, dtype=np.float64)
        if self.period_mm is not None:
            p = np.mod(p, self.period_mm)
        return np.interp(p, self.f_mm, self.e_mm)

    # -- scalar fast path (same breakpoints, pure Python) --------------------------------
    def error_at_command_scalar(self, command_mm: float) -> float:
        """Scalar twin of :meth:`error_at_command` for the per-transaction path."""
        if self.period_mm is not None:
            command_mm %= self.period_mm
        return _interp_scalar(command_mm, self._x_list, self._e_list)

    def error_at_actual_scalar(self, actual_mm: float) -> float:
        """Scalar twin of :meth:`error_at_actual`."""
        if self.period_mm is not None:
            actual_mm %= self.period_mm
        return _interp_scalar(actual_mm, self._f_list, self._e_list)


def _interp_scalar(x: float, xs: array, ys: array) -> float:
    n = len(xs)
    if x <= xs[0]:
        return ys[0]
    if x >= xs[n - 1]:
        return ys[n - 1]
    i = bisect_right(xs, x)
    x0 = xs[i - 1]
    y0 = ys[i - 1]
    return y0 + (ys[i] - y0) * (x - x0) / (xs[i] - x0)


def _periodic_extension(
    x: NDArray[np.float64], e: NDArray[np.float64], period: float
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Breakpoints over one period extended by one period on each side.

    ``x`` covers exactly one period, ``[x0, x0 + period]``, with ``e`` equal at both ends;
    the extension lets any position taken modulo the period interpolate across the wrap.
    """
    if not np.isclose(x[-1] - x[0], period) or e[-1] != e[0]:
        raise ValueError("periodic breakpoints must span one period with equal end values")
    core_x = x[:-1]
    core_e = e[:-1]
    ext_x = np.concatenate([core_x - period, core_x, core_x + period, [x[-1] + period]])
    ext_e = np.concatenate([core_e, core_e, core_e, [e[-1]]])
    return ext_x, ext_e
