"""compgw's pitch-table CSV.

::

    # comments start with '#', anywhere on a line
    position_mm,forward_um,reverse_um
    0,0.0,11.8
    50,2.1,13.4

Values are the measured deviation, actual − commanded, in µm (ISO 230-2 sign; compgw
corrects by the opposite). Column sets accepted after the header:
``position_mm,error_um`` (unidirectional), ``position_mm,forward_um`` (unidirectional),
``position_mm,forward_um,reverse_um`` (bidirectional; a reverse column left empty on every
row means unidirectional). Rotary axes use ``position_deg`` with deviations in millidegrees
(``error_mdeg``, ``forward_mdeg``, ``reverse_mdeg``).
"""

from __future__ import annotations

import os

import numpy as np

from ..compensation.errors import TableError
from ..compensation.pitch import PitchTable
from .atomic import atomic_write_text
from .lines import DEVIATION_DECIMALS as DEV
from .lines import POSITION_DECIMALS as POS
from .lines import csv_cells, csv_header, data_lines, fmt, parse_number

_LINEAR_HEADERS = {
    ("position_mm", "error_um"): False,
    ("position_mm", "forward_um"): False,
    ("position_mm", "forward_um", "reverse_um"): True,
}
_ROTARY_HEADERS = {
    ("position_deg", "error_mdeg"): False,
    ("position_deg", "forward_mdeg"): False,
    ("position_deg", "forward_mdeg", "reverse_mdeg"): True,
}
#: Table value unit → mm (or deg): µm and mdeg are both 1e-3 of the position unit.
_VALUE_SCALE = 1e-3


def read_pitch_csv(path: str | os.PathLike[str]) -> PitchTable:
    """Read a compgw pitch CSV; every malformed line is an error naming file and line."""
    rows = data_lines(path)
    header_line, header = csv_header(path, rows)
    if header in _LINEAR_HEADERS:
        rotary, has_reverse = False, _LINEAR_HEADERS[header]
    elif header in _ROTARY_HEADERS:
        rotary, has_reverse = True, _ROTARY_HEADERS[header]
    else:
        raise TableError(
            f"{path}: line {header_line}: header {','.join(header)!r} is not one of "
            f"'position_mm,forward_um,reverse_um', 'position_mm,error_um' "
            f"(or the position_deg/..._mdeg forms for rotary axes)"
        )
    lines: list[int] = []
    positions: list[float] = []
    forward: list[float] = []
    reverse: list[float | None] = []
    for number, text in rows:
        cells = csv_cells(path, number, text, header)
        lines.append(number)
        positions.append(parse_number(path, number, header[0], cells[0]))
        forward.append(parse_number(path, number, header[1], cells[1]))
        if has_reverse:
            reverse.append(
                None if cells[2] == "" else parse_number(path, number, header[2], cells[2])
            )
    if not lines:
        raise TableError(f"{path}: no points after the header")
    rev_values: np.ndarray | None = None
    if has_reverse:
        missing = [n for n, v in zip(lines, reverse) if v is None]
        if len(missing) not in (0, len(lines)):
            raise TableError(f"{path}: line {missing[0]}: {header[2]} is empty on some rows only")
        if not missing:
            rev_values = np.array(reverse, dtype=np.float64) * _VALUE_SCALE
    return PitchTable(
        np.array(positions),
        np.array(forward) * _VALUE_SCALE,
        rev_values,
        rotary=rotary,
        source=str(path),
        lines=tuple(lines),
    )


def format_pitch_csv(table: PitchTable, comment: str = "") -> str:
    """The CSV text of ``table`` (values in µm, or mdeg for rotary axes)."""
    pos, dev = ("position_deg", "mdeg") if table.rotary else ("position_mm", "um")
    out = [
        "# compgw pitch table: deviation actual - commanded at each commanded position",
        "# (ISO 230-2 sign); compgw commands the opposite correction",
    ]
    out += [f"# {line}" for line in comment.splitlines()]
    fwd = table.forward_mm / _VALUE_SCALE
    if table.reverse_mm is None:
        out.append(f"{pos},forward_{dev}")
        out += [f"{fmt(p, POS)},{fmt(f, DEV)}" for p, f in zip(table.position_mm, fwd)]
    else:
        rev = table.reverse_mm / _VALUE_SCALE
        out.append(f"{pos},forward_{dev},reverse_{dev}")
        out += [f"{fmt(p, POS)},{fmt(f, DEV)},{fmt(r, DEV)}"
                for p, f, r in zip(table.position_mm, fwd, rev)]
    return "\n".join(out) + "\n"


def write_pitch_csv(path: str | os.PathLike[str], table: PitchTable, comment: str = "") -> None:
    """Write ``table`` atomically."""
    atomic_write_text(path, format_pitch_csv(table, comment))
