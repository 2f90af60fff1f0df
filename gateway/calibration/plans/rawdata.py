"""Raw-data CSV of a calibration run: one row per measurement, appended as it arrives.

::

    # comments start with '#', anywhere on a line
    axis,run,direction,target_mm,actual_mm,time_s
    X,1,+,12.345,12.3391,0.52
    X,1,-,12.345,12.3512,9.81

Required columns (any order): ``axis`` (name as in the config), ``run`` (integer ≥ 1; the
ISO 230-2 run j, the backlash repeat, the warm-up cycle), ``direction`` (``+`` or ``-``: the
direction of approach to the target), ``target_mm`` (nominal commanded position) and
``actual_mm`` (measured position). Extra columns (``time_s``, ``delta_a_mm``, ``x_mm``,
``y_mm``, …) are allowed and kept as text. Deviations are ``actual − target`` (ISO 230-2
sign). XY grid runs write two rows per point, one per axis, and both carry ``x_mm`` and
``y_mm`` (the commanded point) so the rows of a point can be paired.

The writer appends and flushes each row, so a run killed at any moment keeps every row it
reported as written; the rows reach the disk within a second (a power cut loses at most
that); a torn last line (no newline) is cut off when the file is reopened.
"""

from __future__ import annotations

import math
import os
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from types import MappingProxyType

import numpy as np
from numpy.typing import NDArray

from ...compensation.errors import TableError
from ...formats.lines import POSITION_DECIMALS, csv_cells, csv_header, data_lines, fmt, parse_number

RAW_COLUMNS: tuple[str, ...] = ("axis", "run", "direction", "target_mm", "actual_mm")
#: Targets closer than this (mm) are the same ISO 230-2 target position.
TARGET_TOLERANCE_MM = 1e-6
_DIRECTIONS = {"+": 1, "-": -1}


@dataclass(frozen=True, eq=False)
class RawData:
    """The rows of a raw-data file as columns; ``extra`` keeps other columns as text."""

    axis: tuple[str, ...]
    run: NDArray[np.int64]
    direction: NDArray[np.int8]
    target_mm: NDArray[np.float64]
    actual_mm: NDArray[np.float64]
    extra: Mapping[str, tuple[str, ...]]
    lines: tuple[int, ...]
    source: str = "<raw>"

    @property
    def deviation_mm(self) -> NDArray[np.float64]:
        return self.actual_mm - self.target_mm

    @property
    def axes(self) -> tuple[str, ...]:
        """Axis names in order of first appearance."""
        return tuple(dict.fromkeys(self.axis))

    def __len__(self) -> int:
        return len(self.axis)

    def where(self, i: int) -> str:
        return f"{self.source}: line {self.lines[i]}"

    def column_mm(self, name: str) -> NDArray[np.float64]:
        """An extra column parsed as numbers (errors name file and line): millimetres for
        ``delta_a_mm``, whatever its name says for the others (``temperature_c``)."""
        if name not in self.extra:
            raise TableError(f"{self.source}: no column {name!r}")
        return np.array(
            [
                parse_number(self.source, line, name, text)
                for line, text in zip(self.lines, self.extra[name])
            ],
            dtype=np.float64,
        )


def read_raw_csv(path: str | os.PathLike[str]) -> RawData:
    """Read a raw-data CSV; a malformed line is a TableError naming file and line."""
    rows = data_lines(path)
    header_line, header = csv_header(path, rows)
    missing = [c for c in RAW_COLUMNS if c not in header]
    if missing:
        raise TableError(
            f"{path}: line {header_line}: header lacks column_mm(s) {', '.join(missing)} "
            f"(needs at least {','.join(RAW_COLUMNS)})"
        )
    if len(set(header)) != len(header) or "" in header:
        raise TableError(f"{path}: line {header_line}: empty or repeated column name")
    col = {name: k for k, name in enumerate(header)}
    extra_names = [c for c in header if c not in RAW_COLUMNS]
    axis: list[str] = []
    run: list[int] = []
    direction: list[int] = []
    target: list[float] = []
    actual: list[float] = []
    extra: dict[str, list[str]] = {name: [] for name in extra_names}
    lines: list[int] = []
    for number, text in rows:
        cells = csv_cells(path, number, text, header)
        name = cells[col["axis"]]
        if not name:
            raise TableError(f"{path}: line {number}: axis is empty")
        run_text = cells[col["run"]]
        if not run_text.isdigit() or int(run_text) < 1:
            raise TableError(f"{path}: line {number}: run {run_text!r} is not an integer >= 1")
        sign = _DIRECTIONS.get(cells[col["direction"]])
        if sign is None:
            raise TableError(
                f"{path}: line {number}: direction {cells[col['direction']]!r} is not + or -"
            )
        axis.append(name)
        run.append(int(run_text))
        direction.append(sign)
        target.append(parse_number(path, number, "target_mm", cells[col["target_mm"]]))
        actual.append(parse_number(path, number, "actual_mm", cells[col["actual_mm"]]))
        for extra_name in extra_names:
            extra[extra_name].append(cells[col[extra_name]])
        lines.append(number)
    return RawData(
        axis=tuple(axis),
        run=np.array(run, dtype=np.int64),
        direction=np.array(direction, dtype=np.int8),
        target_mm=np.array(target, dtype=np.float64),
        actual_mm=np.array(actual, dtype=np.float64),
        extra=MappingProxyType({k: tuple(v) for k, v in extra.items()}),
        lines=tuple(lines),
        source=str(path),
    )


#: a raw file reaches the disk at least this often (s): a power cut loses at most the
#: readings of the last second (on a machine, a reading takes seconds: one at most), while
#: a simulated machine's hundred readings a second do not wait on the disk for each
SYNC_EVERY_S = 1.0


class RawWriter:
    """Append rows to a raw-data CSV, each one flushed to the OS before ``append`` returns
    (a killed process loses none) and on the disk within :data:`SYNC_EVERY_S` (and at
    :meth:`close`).

    A new (or empty) file gets the header; an existing file must have the same header. Use as
    a context manager, or call :meth:`close`.
    """

    def __init__(
        self, path: str | os.PathLike[str], extra_columns: Sequence[str] = ()
    ) -> None:
        self.path = Path(path)
        self.columns: tuple[str, ...] = RAW_COLUMNS + tuple(extra_columns)
        if len(set(self.columns)) != len(self.columns):
            raise TableError(f"{self.path}: repeated column name in {self.columns}")
        existing = self._existing_header()
        self._file = open(self.path, "a", encoding="utf-8", newline="\n")  # noqa: SIM115
        self._synced_s = -math.inf
        if existing is None:
            self._write_line(",".join(self.columns))
        elif existing != self.columns:
            self._file.close()
            raise TableError(
                f"{self.path}: existing header {','.join(existing)!r} differs from "
                f"{','.join(self.columns)!r}; write to a new file"
            )

    def _existing_header(self) -> tuple[str, ...] | None:
        """Header of an existing file (after cutting a torn last line), or None if new."""
        if not self.path.exists() or self.path.stat().st_size == 0:
            return None
        data = self.path.read_bytes()
        if not data.endswith(b"\n"):
            keep = data.rfind(b"\n") + 1
            with open(self.path, "r+b") as handle:
                handle.truncate(keep)
                handle.flush()
                os.fsync(handle.fileno())
            if keep == 0:
                return None
        try:
            return csv_header(self.path, data_lines(self.path))[1]
        except TableError:
            return None

    def _write_line(self, text: str) -> None:
        self._file.write(text + "\n")
        self._file.flush()
        now_s = time.monotonic()
        if now_s - self._synced_s >= SYNC_EVERY_S:
            os.fsync(self._file.fileno())
            self._synced_s = now_s

    def append(
        self,
        axis: str,
        run: int,
        direction: int | str,
        target_mm: float,
        actual_mm: float,
        **extra: object,
    ) -> None:
        """Write one measurement (the class says when it is on the disk). ``direction``:
        +1/−1 or ``'+'``/``'-'``."""
        sign = direction if isinstance(direction, str) else ("+" if direction > 0 else "-")
        if sign not in _DIRECTIONS:
            raise ValueError(f"direction {direction!r} is not + or -")
        unknown = set(extra) - set(self.columns)
        if unknown:
            raise ValueError(f"{self.path}: no column_mm(s) {', '.join(sorted(unknown))}")
        values = {
            "axis": axis,
            "run": str(int(run)),
            "direction": sign,
            "target_mm": fmt(target_mm, POSITION_DECIMALS),
            "actual_mm": fmt(actual_mm),
        }
        for name, value in extra.items():
            values[name] = fmt(value) if isinstance(value, float) else str(value)
        cells = [values.get(name, "") for name in self.columns]
        if any("," in c or "\n" in c or "#" in c for c in cells):
            raise ValueError(f"{self.path}: a value contains ',', '#' or a newline: {cells}")
        self._write_line(",".join(cells))

    def close(self) -> None:
        if not self._file.closed:
            self._file.flush()
            os.fsync(self._file.fileno())
        self._file.close()

    def __enter__(self) -> RawWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


@dataclass(frozen=True, eq=False)
class AxisDeviations:
    """Deviations of one axis (mm) arranged ``[target i, run j]`` per direction of approach.

    ``up_mm`` (approached in +) and ``down_mm`` (in −) have shape (targets, runs), NaN where
    a run did not measure a target; a direction never measured is ``None``.
    """

    axis: str
    target_mm: NDArray[np.float64]
    runs: NDArray[np.int64]
    up_mm: NDArray[np.float64] | None
    down_mm: NDArray[np.float64] | None
    source: str = "<raw>"


def pooled_variance(dev: AxisDeviations) -> tuple[float, int]:
    """The readings' variance about their target's mean per direction (mm², pooled over
    the targets and both directions) and its degrees of freedom (0: no repeat to pool)."""
    squares, dof = 0.0, 0
    for x in (dev.up_mm, dev.down_mm):
        if x is None:
            continue
        n = np.sum(np.isfinite(x), axis=1)
        mean = np.nansum(x, axis=1) / np.maximum(n, 1)
        squares += float(np.nansum((x - mean[:, None]) ** 2))
        dof += int(np.sum(np.maximum(n - 1, 0)))
    return (squares / dof if dof else float("nan")), dof


def _group_targets(target_mm: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.intp]]:
    """Distinct targets (within the tolerance) and each row's index into them."""
    order = np.argsort(target_mm, kind="stable")
    sorted_t = target_mm[order]
    new = np.concatenate([[True], np.diff(sorted_t) > TARGET_TOLERANCE_MM])
    group_sorted = np.cumsum(new) - 1
    index = np.empty_like(group_sorted)
    index[order] = group_sorted
    centres = np.array([sorted_t[group_sorted == g].mean() for g in range(group_sorted[-1] + 1)])
    return centres, index


def axis_deviations(raw: RawData, axis: str) -> AxisDeviations:
    """Arrange one axis's deviations per target i, run j and direction (ISO 230-2 x_ij)."""
    rows = np.flatnonzero(np.array(raw.axis) == axis)
    if rows.size == 0:
        raise TableError(f"{raw.source}: no rows for axis {axis!r}")
    targets, ti = _group_targets(raw.target_mm[rows])
    runs, rj = np.unique(raw.run[rows], return_inverse=True)
    out: dict[int, NDArray[np.float64]] = {}
    for sign in (1, -1):
        sel = raw.direction[rows] == sign
        if not sel.any():
            continue
        grid = np.full((targets.size, runs.size), np.nan)
        for k in np.flatnonzero(sel):
            i, j = ti[k], rj[k]
            if not np.isnan(grid[i, j]):
                raise TableError(
                    f"{raw.where(int(rows[k]))}: axis {axis} run {runs[j]} target "
                    f"{targets[i]:g} mm direction {'+' if sign > 0 else '-'} measured twice"
                )
            grid[i, j] = raw.actual_mm[rows[k]] - raw.target_mm[rows[k]]
        out[sign] = grid
    return AxisDeviations(axis, targets, runs, out.get(1), out.get(-1), raw.source)


def deviations_by_axis(raw: RawData) -> dict[str, AxisDeviations]:
    """:func:`axis_deviations` for every axis in the file, in order of appearance."""
    return {name: axis_deviations(raw, name) for name in raw.axes}
