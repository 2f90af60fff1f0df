"""LinuxCNC compensation files (``COMP_FILE_TYPE`` 0 and 1), read and written.

Each line holds three numbers separated by white space, in machine units (mm):

- type 0: ``nominal forward_actual reverse_actual`` (where the axis really was when
  commanded to ``nominal`` approaching in + and in −);
- type 1: ``nominal forward_trim reverse_trim`` with ``trim = nominal − actual``.

LinuxCNC stops reading at the first line that is not a triplet; compgw refuses such a file
instead, naming the line, so a table is never silently shortened. Lines starting with ``#``
and blank lines are skipped.
"""

from __future__ import annotations

import os

import numpy as np

from ..compensation.errors import TableError
from ..compensation.pitch import PitchTable
from .atomic import atomic_write_text
from .lines import POSITION_DECIMALS as POS
from .lines import data_lines, fmt, parse_number

VALUE = 7  # decimals of the actual / trim values (mm): 0.1 nm


def read_linuxcnc(path: str | os.PathLike[str], comp_type: int) -> PitchTable:
    """Read a LinuxCNC comp file as a bidirectional deviation table (mm)."""
    if comp_type not in (0, 1):
        raise TableError(f"{path}: LinuxCNC comp file type must be 0 or 1, got {comp_type!r}")
    lines: list[int] = []
    rows: list[tuple[float, float, float]] = []
    for number, text in data_lines(path):
        cells = text.split()
        if len(cells) != 3:
            raise TableError(
                f"{path}: line {number}: expected 3 numbers (nominal forward reverse), "
                f"got {len(cells)}: {text!r}"
            )
        nominal, forward, reverse = (
            parse_number(path, number, name, cell)
            for name, cell in zip(("nominal", "forward", "reverse"), cells)
        )
        rows.append((nominal, forward, reverse))
        lines.append(number)
    if not rows:
        raise TableError(f"{path}: no compensation points")
    data = np.array(rows, dtype=np.float64)
    nominal = data[:, 0]
    if comp_type == 0:
        forward, reverse = data[:, 1] - nominal, data[:, 2] - nominal
    else:
        forward, reverse = -data[:, 1], -data[:, 2]
    return PitchTable(nominal, forward, reverse, source=str(path), lines=tuple(lines))


def format_linuxcnc(table: PitchTable, comp_type: int) -> str:
    if comp_type not in (0, 1):
        raise TableError(f"LinuxCNC comp file type must be 0 or 1, got {comp_type!r}")
    fwd = table.forward_mm
    rev = table.reverse_mm if table.reverse_mm is not None else table.forward_mm
    nominal = table.position_mm
    cols = (nominal, nominal + fwd, nominal + rev) if comp_type == 0 else (nominal, -fwd, -rev)
    return "".join(f"{fmt(a, POS)} {fmt(b, VALUE)} {fmt(c, VALUE)}\n" for a, b, c in zip(*cols))


def write_linuxcnc(path: str | os.PathLike[str], table: PitchTable, comp_type: int) -> None:
    """Write ``table`` as a LinuxCNC comp file of ``comp_type``, atomically.

    No comment lines are written: LinuxCNC itself would stop reading at them.
    """
    atomic_write_text(path, format_linuxcnc(table, comp_type))
