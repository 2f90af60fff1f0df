"""Pitch-error tables and the pitch stage of the chain.

Sign convention (compgw's own CSV and every table object): values are the measured
**deviation** of the axis, ``actual − commanded``, at each commanded position, as a laser
interferometer shows it (ISO 230-2 sign). compgw corrects by commanding ``c`` such that
``c + e(c)`` is the nominal target: the correction is the opposite of the deviation, found
exactly (not the first-order ``p − e(p)`` a CNC table applies).

Unidirectional tables have one deviation per point; bidirectional tables have a forward
(approached in +) and a reverse (approached in −) value and so already contain backlash.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .errors import TableError, where
from .monotone_map import MonotoneMap

Interpolation = Literal["linear", "smooth", "pchip"]
Outside = Literal["hold", "taper"]

MAX_POINTS = 4096
MIN_SPACING_MM = 1e-3
ROTARY_PERIOD_DEG = 360.0
#: Resampling tolerance for spline tables: the piecewise-linear twin of the spline may
#: differ from it by at most this much (mm). 1e-7 mm is 1/10000 of a 1 µm pulse.
SPLINE_TOLERANCE_MM = 1e-7
_MAX_DENSE_POINTS = 1 << 21


@dataclass(frozen=True, eq=False)
class PitchTable:
    """Measured deviation of one axis (mm, or degrees when ``rotary``) at table points.

    ``lines`` are the source-file line numbers of the points, so errors can name them.
    """

    position_mm: NDArray[np.float64]
    forward_mm: NDArray[np.float64]
    reverse_mm: NDArray[np.float64] | None = None
    rotary: bool = False
    source: str = "<table>"
    lines: tuple[int, ...] | None = None

    def __post_init__(self) -> None:
        pos = np.asarray(self.position_mm, dtype=np.float64).reshape(-1)
        fwd = np.asarray(self.forward_mm, dtype=np.float64).reshape(-1)
        rev = None if self.reverse_mm is None else np.asarray(self.reverse_mm, np.float64)
        for name, value in (("position_mm", pos), ("forward_mm", fwd), ("reverse_mm", rev)):
            if value is not None:
                value = value.reshape(-1)
                value.setflags(write=False)
                object.__setattr__(self, name, value)
        self._validate_shape()

    @property
    def bidirectional(self) -> bool:
        return self.reverse_mm is not None

    @property
    def unit(self) -> str:
        return "deg" if self.rotary else "mm"

    def point(self, i: int) -> str:
        """Where point ``i`` comes from, for error messages."""
        line = self.lines[i] if self.lines is not None else None
        text = where(self.source, line, float(self.position_mm[i]), self.unit)
        return text if line is not None else f"{text} [point {i}]"

    def _validate_shape(self) -> None:
        pos, fwd, rev = self.position_mm, self.forward_mm, self.reverse_mm
        n = pos.size
        if n < 2:
            raise TableError(f"{self.source}: a pitch table needs at least 2 points, got {n}")
        if n > MAX_POINTS:
            raise TableError(f"{self.source}: {n} points, more than the {MAX_POINTS} allowed")
        if fwd.size != n or (rev is not None and rev.size != n):
            raise TableError(f"{self.source}: positions and values differ in length")
        if self.lines is not None and len(self.lines) != n:
            raise TableError(f"{self.source}: line numbers and points differ in length")
        for name, values in (("position", pos), ("forward", fwd), ("reverse", rev)):
            if values is None:
                continue
            bad = np.flatnonzero(~np.isfinite(values))
            if bad.size:
                raise TableError(f"{self.point(int(bad[0]))}: {name} value is not a finite number")
        steps = np.diff(pos)
        bad = np.flatnonzero(steps < MIN_SPACING_MM)
        if bad.size:
            i = int(bad[0]) + 1
            raise TableError(
                f"{self.point(i)}: positions must increase by at least {MIN_SPACING_MM} "
                f"{self.unit} (previous point {pos[i - 1]:g})"
            )
        if self.rotary and (pos[0] < -ROTARY_PERIOD_DEG or pos[-1] > ROTARY_PERIOD_DEG):
            i = 0 if pos[0] < -ROTARY_PERIOD_DEG else n - 1
            raise TableError(f"{self.point(i)}: rotary table positions must lie in "
                             "-360..360 deg")  # fmt: skip


@dataclass(frozen=True, eq=False)
class PitchStage:
    """Pitch correction of one axis, from a :class:`PitchTable`.

    ``wrap`` (default: the table's ``rotary``): positions modulo 360° with interpolation
    across 360→0, a turntable's table (points in 0..360); a swing axis's rotary table (its
    angle stays within its travel) has ``wrap=False`` and is interpolated like a linear one.
    ``interpolation``: ``linear`` (as LinuxCNC and SINUMERIK), ``smooth`` (C2 cubic spline)
    or ``pchip`` (monotone cubic, no overshoot). ``outside``: ``hold`` keeps the end value
    beyond the table; ``taper`` ramps it linearly to zero over ``taper_mm``.
    Splines are resampled at build time into an exact-inverse piecewise-linear map whose
    deviation from the spline is below :data:`SPLINE_TOLERANCE_MM`.
    """

    table: PitchTable
    interpolation: Interpolation = "linear"
    outside: Outside = "hold"
    taper_mm: float = 0.0
    wrap: bool | None = None
    forward_map: MonotoneMap = field(init=False)
    reverse_map: MonotoneMap = field(init=False)

    def __post_init__(self) -> None:
        if self.interpolation not in ("linear", "smooth", "pchip"):
            raise TableError(f"{self.table.source}: unknown interpolation {self.interpolation!r}")
        if self.outside not in ("hold", "taper"):
            raise TableError(f"{self.table.source}: unknown outside rule {self.outside!r}")
        if self.outside == "taper" and not self.taper_mm > 0:
            raise TableError(f"{self.table.source}: taper_mm must be > 0 with outside: taper")
        wrap = self.table.rotary if self.wrap is None else bool(self.wrap)
        if wrap and not self.table.rotary:
            raise TableError(f"{self.table.source}: a linear table cannot wrap at 360 deg")
        object.__setattr__(self, "wrap", wrap)
        pos = self.table.position_mm
        if wrap and (pos[0] < 0 or pos[-1] > ROTARY_PERIOD_DEG):
            i = 0 if pos[0] < 0 else pos.size - 1
            raise TableError(f"{self.table.point(i)}: a turntable's table (positions modulo "
                             "360) must lie in 0..360 deg")  # fmt: skip
        fwd = self._build(self.table.forward_mm, "forward")
        rev = fwd
        if self.table.reverse_mm is not None:
            rev = self._build(self.table.reverse_mm, "reverse")
        object.__setattr__(self, "forward_map", fwd)
        object.__setattr__(self, "reverse_map", rev)

    @property
    def bidirectional(self) -> bool:
        return self.table.bidirectional

    def _build(self, values: NDArray[np.float64], name: str) -> MonotoneMap:
        table = self.table
        pos = table.position_mm
        self._check_monotone(pos, values, name)
        period = ROTARY_PERIOD_DEG if self.wrap else None
        if self.wrap:
            pos, values = _close_period(table, values, name)
        x, e = pos, values
        if self.interpolation != "linear":
            x, e = _resample_spline(pos, values, self.interpolation, periodic=bool(self.wrap))
        if not self.wrap and self.outside == "taper":
            x = np.concatenate([[x[0] - self.taper_mm], x, [x[-1] + self.taper_mm]])
            e = np.concatenate([[0.0], e, [0.0]])
        try:
            return MonotoneMap(x, e, period)
        except ValueError:
            # Points themselves were checked: the spline or the taper made it non-monotone.
            f = x + e
            i = int(np.flatnonzero(np.diff(f) <= 0)[0])
            raise TableError(
                f"{table.source}: {name} correction is not strictly increasing near "
                f"{x[i]:g} {table.unit} ({self.interpolation} interpolation"
                f"{', taper' if self.outside == 'taper' else ''}); refine the table"
            ) from None

    def _check_monotone(
        self, pos: NDArray[np.float64], values: NDArray[np.float64], name: str
    ) -> None:
        image = pos + values
        bad = np.flatnonzero(np.diff(image) <= 0)
        if bad.size:
            i = int(bad[0]) + 1
            raise TableError(
                f"{self.table.point(i)}: {name} deviation makes the axis run backwards "
                f"(commanded-to-actual map not strictly increasing after {pos[i - 1]:g})"
            )

    # -- stage interface ----------------------------------------------------------------
    def forward(self, target_mm: ArrayLike, direction: ArrayLike) -> NDArray[np.float64]:
        """Command (mm) that makes the axis land on ``target_mm`` approaching in ``direction``
        (between −1 and +1: a nut part way across its play, the two tables blended)."""
        p = np.asarray(target_mm, dtype=np.float64)
        e_fwd = self.forward_map.error_at_actual(p)
        if not self.bidirectional:
            return p - e_fwd
        e_rev = self.reverse_map.error_at_actual(p)
        w = _forward_weight(direction)
        c = p - (w * e_fwd + (1.0 - w) * e_rev)
        part = (w > 0.0) & (w < 1.0)
        if np.any(part):  # one step of c = p − E(c), E the blend at the command
            c = np.where(part, p - self._blend_at_command(c, w), c)
        return c

    def inverse(self, command_mm: ArrayLike, direction: ArrayLike) -> NDArray[np.float64]:
        """Where the axis is (mm) after commanding ``command_mm`` approaching in ``direction``."""
        c = np.asarray(command_mm, dtype=np.float64)
        if not self.bidirectional:
            return c + self.forward_map.error_at_command(c)
        return c + self._blend_at_command(c, _forward_weight(direction))

    def _blend_at_command(self, c: NDArray[np.float64], w: NDArray[np.float64]
                          ) -> NDArray[np.float64]:  # fmt: skip
        """Deviation (mm) at command ``c``, the forward table weighted ``w``."""
        e_fwd = self.forward_map.error_at_command(c)
        e_rev = self.reverse_map.error_at_command(c)
        return w * e_fwd + (1.0 - w) * e_rev

    def forward_scalar(self, target_mm: float, direction: float) -> float:
        if direction >= 1.0 or not self.bidirectional:
            return target_mm - self.forward_map.error_at_actual_scalar(target_mm)
        if direction <= -1.0:
            return target_mm - self.reverse_map.error_at_actual_scalar(target_mm)
        w = 0.5 * (1.0 + direction)
        c = target_mm - (w * self.forward_map.error_at_actual_scalar(target_mm)
                         + (1.0 - w) * self.reverse_map.error_at_actual_scalar(target_mm))
        return target_mm - self._blend_scalar(c, w)

    def inverse_scalar(self, command_mm: float, direction: float) -> float:
        if direction >= 1.0 or not self.bidirectional:
            return command_mm + self.forward_map.error_at_command_scalar(command_mm)
        if direction <= -1.0:
            return command_mm + self.reverse_map.error_at_command_scalar(command_mm)
        return command_mm + self._blend_scalar(command_mm, 0.5 * (1.0 + direction))

    def _blend_scalar(self, c_mm: float, w: float) -> float:
        return (w * self.forward_map.error_at_command_scalar(c_mm)
                + (1.0 - w) * self.reverse_map.error_at_command_scalar(c_mm))

    def max_abs_correction_mm(self) -> float:
        """Largest |correction| anywhere (linear pieces: reached at a breakpoint)."""
        return float(max(np.abs(self.forward_map.e_mm).max(), np.abs(self.reverse_map.e_mm).max()))

    def check_cap(self, max_correction_mm: float) -> None:
        """Refuse the table if any point needs a correction above ``max_correction_mm``."""
        table = self.table
        for name, values in (("forward", table.forward_mm), ("reverse", table.reverse_mm)):
            if values is None:
                continue
            over = np.flatnonzero(np.abs(values) > max_correction_mm)
            if over.size:
                i = int(over[np.argmax(np.abs(values[over]))])
                raise TableError(
                    f"{table.point(i)}: {name} correction {abs(values[i]):.6g} {table.unit} "
                    f"exceeds max_correction_mm {max_correction_mm:g}"
                )
        worst = self.max_abs_correction_mm()
        if worst > max_correction_mm * (1 + 1e-12):
            raise TableError(
                f"{table.source}: {self.interpolation} interpolation overshoots to "
                f"{worst:.6g} {table.unit}, above max_correction_mm {max_correction_mm:g}"
            )


def _forward_weight(direction: ArrayLike) -> NDArray[np.float64]:
    """Weight of the forward table for a direction (+1: 1, −1: 0; between: a nut part way
    across its play, :mod:`.takeup`)."""
    return np.clip(0.5 * (1.0 + np.asarray(direction, dtype=np.float64)), 0.0, 1.0)


def _close_period(
    table: PitchTable, values: NDArray[np.float64], name: str
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Rotary table over exactly one turn: the first point repeated one turn later."""
    pos = table.position_mm
    if pos[-1] - pos[0] == ROTARY_PERIOD_DEG:
        if not np.isclose(values[-1], values[0], rtol=0.0, atol=1e-12):
            raise TableError(
                f"{table.point(pos.size - 1)}: {name} value one turn after the first point "
                f"must equal the first point's value on a rotary table"
            )
        values = values.copy()
        values[-1] = values[0]
        return pos, values
    return (
        np.concatenate([pos, [pos[0] + ROTARY_PERIOD_DEG]]),
        np.concatenate([values, values[:1]]),
    )


def _resample_spline(
    x: NDArray[np.float64], e: NDArray[np.float64], kind: str, periodic: bool
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Dense piecewise-linear twin of the spline through (x, e), within the tolerance."""
    # scipy.interpolate is half a second of every process's start (check, status, the
    # gateway on linear tables): imported where a spline table is loaded
    from scipy.interpolate import CubicSpline, PchipInterpolator

    if kind == "smooth":
        spline = CubicSpline(x, e, bc_type="periodic" if periodic else "not-a-knot")
    else:
        spline = PchipInterpolator(x, e)
    sub = 8
    while True:
        t = np.linspace(0.0, 1.0, sub + 1)[:-1]
        dense = (x[:-1, None] + np.diff(x)[:, None] * t[None, :]).reshape(-1)
        dense = np.concatenate([dense, x[-1:]])
        values = spline(dense)
        mid = 0.5 * (dense[1:] + dense[:-1])
        gap = np.abs(spline(mid) - 0.5 * (values[1:] + values[:-1])).max()
        if gap <= SPLINE_TOLERANCE_MM or dense.size * 2 > _MAX_DENSE_POINTS:
            break
        sub *= 2
    values[:: sub] = e  # exact at the table points
    return dense, values
