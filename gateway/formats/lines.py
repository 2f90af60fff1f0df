"""Line-oriented reading shared by the table formats: comments, blanks, line numbers."""

from __future__ import annotations

import math
import os
from collections.abc import Iterator

from ..compensation.errors import TableError
from ..config_types import read_text


def data_lines(path: str | os.PathLike[str]) -> Iterator[tuple[int, str]]:
    """Yield ``(line_number, text)`` of non-blank lines with ``#`` comments removed."""
    text = read_text(path, TableError)
    for number, raw in enumerate(text.splitlines(), start=1):
        line = raw.split("#", 1)[0].strip()
        if line:
            yield number, line


def csv_header(
    path: str | os.PathLike[str], rows: Iterator[tuple[int, str]]
) -> tuple[int, tuple[str, ...]]:
    """The first data line of a CSV as a tuple of column names, with its line number."""
    try:
        number, text = next(rows)
    except StopIteration:
        raise TableError(f"{path}: empty table (no header, no points)") from None
    return number, tuple(cell.strip() for cell in text.split(","))


def csv_cells(
    path: str | os.PathLike[str], number: int, text: str, header: tuple[str, ...]
) -> list[str]:
    """The stripped fields of a CSV data line, exactly one per header column."""
    cells = [c.strip() for c in text.split(",")]
    if len(cells) != len(header):
        raise TableError(
            f"{path}: line {number}: expected {len(header)} comma-separated fields "
            f"({','.join(header)}), got {len(cells)}: {text!r}"
        )
    return cells


def parse_number(path: str | os.PathLike[str], number: int, field: str, text: str) -> float:
    """A finite float, or a TableError naming file, line and field."""
    try:
        value = float(text)
    except ValueError:
        raise TableError(
            f"{path}: line {number}: {field} {text.strip()!r} is not a number"
        ) from None
    if value != value or value in (float("inf"), float("-inf")):
        raise TableError(f"{path}: line {number}: {field} {text.strip()!r} is not finite")
    return value


def parse_numbers(path: str | os.PathLike[str], number: int, fields: tuple[str, ...],
                  cells: list[str]) -> tuple[float, ...]:
    """Each of a row's ``cells`` a finite float (:func:`parse_number`), all read at once and
    cell by cell only where one is not (to name it): a file of thousands of rows, such as a
    plane's points read at every reload, is read without a call per cell."""
    try:
        values = tuple(map(float, cells))
    except ValueError:
        values = ()
    if not values or not math.isfinite(sum(values)):  # (a sum that overflows: each looked at)
        values = tuple(parse_number(path, number, f, c) for f, c in zip(fields, cells))
    return values


#: decimals written for positions (mm or deg: 1 nm) and deviations (µm or mdeg: 0.1 nm)
POSITION_DECIMALS = 6
DEVIATION_DECIMALS = 4


def fmt(value: float, decimals: int | None = None) -> str:
    """Shortest text that reads back as the same float; rounded to ``decimals`` first, so
    float noise (``104.56999999999998`` for 104570 pulses of 0.001 mm) is not written."""
    value = float(value)
    if decimals is not None:
        value = round(value, decimals) + 0.0  # + 0.0: no "-0.0"
    return repr(value)
