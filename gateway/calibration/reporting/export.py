"""`compgw export`: pitch tables between compgw CSV, LinuxCNC comp files, and FANUC style.

``compgw export IN -o OUT --to csv|linuxcnc0|linuxcnc1|fanuc [--from ...]``

- ``--from`` defaults to ``csv`` for ``*.csv`` files; LinuxCNC files need ``--from linuxcnc0``
  or ``linuxcnc1`` (the types are indistinguishable by content). Importing is the same
  command the other way round (``--from linuxcnc1 --to csv``). LinuxCNC → compgw → LinuxCNC
  gives the same numbers (shortest round-trip float text).
- ``--to fanuc`` writes FANUC-style pitch error compensation parameters (see
  :func:`fanuc_pitch` for the conventions) as a text file of ``parameter,value`` and
  ``point,value`` rows to type into the controller.

FANUC conventions (as in the 0i/30i parameter manuals, no. 3620-3624; check your control):

- points are equally spaced by the *interval* (no. 3624, in detection units); the table is
  resampled there by linear interpolation of the deviation;
- the *reference point number* (no. 3620) is the point at the reference (home) position;
  the extreme negative and positive point numbers (no. 3621, 3622) follow from the travel;
- the compensation at a position is the opposite of the deviation (command correction),
  counted from the reference position, where it is 0;
- each point n carries the *increment* of that correction from point n−1 to point n, as an
  integer number of detection units × *magnification* (no. 3623); the extreme negative point
  carries 0. Rounding is done on the running sum, so errors do not accumulate (each point is
  within half a unit·magnification of the exact correction);
- the magnification is the smallest integer that keeps every increment within
  ``--max-increment`` (7 on older controls, 127 on newer ones) unless given;
- a bidirectional table is exported in one direction (``--direction forward``, default, the
  approach FANUC tables describe; ``reverse``; or ``mean``); FANUC's backlash parameter (no.
  1851) then holds the reversal, printed as a comment.

Rotary axes (issue 16): a compgw CSV in ``position_deg`` is in degrees; a LinuxCNC file has
no unit, ``--unit deg`` says it is one. A swing axis's table is exported like a linear one,
in degrees (FANUC: detection units of ``--unit-mm`` degrees, 0.001 by default). A
turntable's (``--turn``) covers one turn: LinuxCNC gets it over 0…360°, the same value at
both ends, so the table closes across 360→0; FANUC gets points every interval over one turn
from the reference position (the interval must divide 360), the last one turn after the
first, so the increments over a turn sum to zero, the reference point taking the last
one's value (the parameter manual's rotary example), and no. 3625, the movement per
rotation in detection units (the rotary-axis type of pitch error compensation).
"""

from __future__ import annotations

import argparse
import math
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from ...compensation import PitchTable
from ...compensation.errors import TableError
from ...formats import (
    atomic_write_text,
    read_linuxcnc,
    read_pitch_csv,
    write_linuxcnc,
    write_pitch_csv,
)

FORMATS = ("csv", "linuxcnc0", "linuxcnc1")


@dataclass(frozen=True)
class FanucPitch:
    """FANUC-style pitch compensation of one axis (integers as the control takes them)."""

    reference_number: int  # no. 3620
    negative_end: int  # no. 3621
    positive_end: int  # no. 3622
    magnification: int  # no. 3623
    interval_units: int  # no. 3624 (detection units)
    increments: tuple[int, ...]  # point negative_end … positive_end
    unit_mm: float
    reference_mm: float
    backlash_units: int | None
    unit: str = "mm"  # or "deg"
    per_turn_units: int | None = None  # a turntable: no. 3625

    @property
    def interval_mm(self) -> float:
        return self.interval_units * self.unit_mm

    def position_mm(self) -> NDArray[np.float64]:
        n = np.arange(self.negative_end, self.positive_end + 1) - self.reference_number
        return self.reference_mm + n * self.interval_mm

    def correction_mm(self) -> NDArray[np.float64]:
        """Correction at each point (relative to the reference), from the increments."""
        total = np.cumsum(self.increments) * self.magnification * self.unit_mm
        ref = self.reference_number - self.negative_end
        return total - total[ref]


def _direction_values(table: PitchTable, direction: str) -> NDArray[np.float64]:
    if table.reverse_mm is None or direction == "forward":
        return table.forward_mm
    if direction == "reverse":
        return table.reverse_mm
    if direction == "mean":
        return 0.5 * (table.forward_mm + table.reverse_mm)
    raise TableError(f"direction {direction!r} is not forward, reverse or mean")


def fanuc_pitch(
    table: PitchTable,
    interval_mm: float | None = None,
    reference_mm: float | None = None,
    reference_number: int = 0,
    unit_mm: float = 0.001,
    magnification: int | None = None,
    max_increment: int = 7,
    direction: str = "forward",
    turn: bool = False,
) -> FanucPitch:
    """FANUC-style parameters from a deviation table (conventions: module docstring).

    Defaults: the interval is the table's mean spacing rounded to whole units, the
    reference position the first table point (a turntable's, ``turn``: 0°).
    """
    pos = table.position_mm
    unit = table.unit
    if unit_mm <= 0 or max_increment < 1:
        raise TableError("unit_mm must be > 0 and max_increment >= 1")
    if turn and not table.rotary:
        raise TableError(f"{table.source}: --turn needs a rotary table (degrees)")
    if interval_mm is None:
        interval_mm = float((pos[-1] - pos[0]) / (pos.size - 1))
    units = round(interval_mm / unit_mm)
    if units < 1:
        raise TableError(f"interval {interval_mm:g} {unit} is below one unit {unit_mm:g} {unit}")
    step = units * unit_mm
    per_turn = None
    if turn:
        per_turn = round(360.0 / unit_mm)
        if abs(per_turn * unit_mm - 360.0) > 1e-9 or per_turn % units:
            raise TableError(f"interval {step:g} deg does not divide a turn into whole "
                             f"detection units of {unit_mm:g} deg: give --interval-mm, a "
                             "divisor of 360 (e.g. 5 or 10, in degrees)")  # fmt: skip
        ref = 0.0 if reference_mm is None else float(reference_mm)
        below, above = 0, per_turn // units
    else:
        ref = float(pos[0]) if reference_mm is None else float(reference_mm)
        below = math.floor((ref - pos[0]) / step + 1e-9)
        above = math.floor((pos[-1] - ref) / step + 1e-9)
    positions = ref + step * np.arange(-below, above + 1)
    values = _direction_values(table, direction)
    correction = -(np.interp(positions, pos, values, period=360.0) if turn
                   else np.interp(positions, pos, values))  # fmt: skip
    correction -= correction[below]  # 0 at the reference position
    exact = correction / unit_mm  # detection units

    def integers(m: int) -> NDArray[np.int64]:
        running = np.round(exact / m).astype(np.int64)
        return np.diff(np.concatenate([[running[0]], running]))

    if magnification is None:
        magnification = 1
        while np.abs(integers(magnification)).max() > max_increment:
            magnification += 1
            if magnification > 100:
                raise TableError("no magnification up to 100 keeps the increments in range")
    inc = integers(magnification)
    if turn:  # the reference point takes the last point's value (FANUC's rotary type: the
        inc[0] = inc[-1]  # parameter manual, no. 3625's example; 1…last sum to zero)
    if np.abs(inc).max() > max_increment:
        raise TableError(
            f"increment {int(np.abs(inc).max())} exceeds {max_increment} at magnification "
            f"{magnification}: use a larger magnification or a smaller interval"
        )
    backlash = None
    if table.reverse_mm is not None:
        backlash = round(float(np.mean(table.reverse_mm - table.forward_mm)) / unit_mm)
    return FanucPitch(reference_number, reference_number - below, reference_number + above,
                      magnification, units, tuple(int(v) for v in inc), unit_mm, ref,
                      backlash, unit, per_turn)  # fmt: skip


def format_fanuc(fp: FanucPitch, source: str = "") -> str:
    lines = [
        f"# FANUC-style pitch error compensation from {source} (compgw export)",
        "# conventions: gateway/calibration/reporting/export.py; value of point n = increment"
        " of the",
        "# correction (opposite of the deviation) from point n-1 to n, in detection units",
        f"# ({fp.unit_mm:g} {fp.unit}) x magnification; 0 at the reference position "
        f"{fp.reference_mm:g} {fp.unit}",
    ]
    if fp.per_turn_units is not None:
        lines.append("# rotary axis type: one turn from the reference, increments summing to "
                     "0 over it; 3625 = movement per rotation")  # fmt: skip
    if fp.backlash_units is not None:
        lines.append(f"# mean reversal of the bidirectional table: {fp.backlash_units} units "
                     "(backlash parameter, no. 1851)")  # fmt: skip
    lines += ["parameter,value", f"3620,{fp.reference_number}", f"3621,{fp.negative_end}",
              f"3622,{fp.positive_end}", f"3623,{fp.magnification}", f"3624,{fp.interval_units}"]
    if fp.per_turn_units is not None:
        lines.append(f"3625,{fp.per_turn_units}")
    lines.append("point,value")
    lines += [f"{fp.negative_end + k},{v}" for k, v in enumerate(fp.increments)]
    return "\n".join(lines) + "\n"


def read_table(path: str | Path, fmt: str | None, unit: str | None = None) -> PitchTable:
    """A table from a compgw CSV (its header gives the unit) or a LinuxCNC file (``unit``:
    ``deg`` for a rotary axis's, default mm)."""
    fmt = fmt or ("csv" if str(path).lower().endswith(".csv") else None)
    if fmt is None:
        raise TableError(f"{path}: give --from linuxcnc0|linuxcnc1|csv")
    if fmt == "csv":
        table = read_pitch_csv(path)
        if unit is not None and table.unit != unit:
            raise TableError(f"{path}: the table is in {table.unit}, not {unit} (--unit)")
        return table
    table = read_linuxcnc(path, int(fmt[-1]))
    if unit == "deg":
        table = PitchTable(table.position_mm, table.forward_mm, table.reverse_mm, True,
                           table.source, table.lines)  # fmt: skip
    return table


def closed_turn(table: PitchTable) -> PitchTable:
    """A turntable's table over 0…360°, its values at both ends the same (LinuxCNC then
    interpolates across 360→0): its points taken modulo 360, the value at 0° read around
    the circle where 0° is no point of it (a table fitted from runs that began at 3° ran
    3…363°, and LinuxCNC had nothing for 0…3°)."""
    if not table.rotary:
        return table
    pos = np.mod(table.position_mm, 360.0)
    order = np.argsort(pos, kind="stable")
    pos = pos[order]

    def closed(values: NDArray[np.float64]) -> NDArray[np.float64]:
        v = values[order]
        start = float(np.interp(0.0, pos, v, period=360.0))
        inner = v[pos > 1e-9]
        return np.concatenate([[start], inner, [start]])

    inner_pos = pos[pos > 1e-9]
    rev = None if table.reverse_mm is None else closed(table.reverse_mm)
    # a plain table for the writer: its last point 360, one turn after 0
    return PitchTable(np.concatenate([[0.0], inner_pos, [360.0]]), closed(table.forward_mm),
                      rev, False, table.source)  # fmt: skip


def export(args: argparse.Namespace) -> str:
    table = read_table(args.input, args.from_format, args.unit)
    turn = getattr(args, "turn", False)
    if turn and not table.rotary:
        raise TableError(f"{args.input}: --turn needs a table in degrees (position_deg, or "
                         "--unit deg for a LinuxCNC file)")  # fmt: skip
    lo, hi = float(table.position_mm[0]), float(table.position_mm[-1])
    if turn and (lo < -1e-9 or hi > 360.0 + 1e-9):
        raise TableError(f"{args.input}: --turn is for a turntable's table, within one turn "
                         f"0…360° (this one runs {lo:g}…{hi:g}°: a swing axis's is exported "
                         "without --turn, and its linkage stays with compgw)")  # fmt: skip
    if args.to == "csv":
        write_pitch_csv(args.output, table, f"exported from {args.input}")
    elif args.to in ("linuxcnc0", "linuxcnc1"):
        write_linuxcnc(args.output, closed_turn(table) if turn else table, int(args.to[-1]))
    else:
        fp = fanuc_pitch(table, args.interval_mm, args.reference_mm, args.reference_number,
                         args.unit_mm, args.magnification, args.max_increment, args.direction,
                         turn)  # fmt: skip
        atomic_write_text(args.output, format_fanuc(fp, str(args.input)))
    return f"{args.input} → {args.output} ({args.to})"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("input", help="a pitch table (compgw CSV or LinuxCNC comp file)")
    p.add_argument("-o", "--output", required=True)
    p.add_argument("--to", required=True, choices=[*FORMATS, "fanuc"])
    p.add_argument("--from", dest="from_format", choices=FORMATS, help="input format")
    p.add_argument("--unit", choices=["mm", "deg"],
                   help="a LinuxCNC file's unit (mm; deg: a rotary axis's table)")
    p.add_argument("--turn", action="store_true",
                   help="a turntable's table: one full turn (LinuxCNC: closed at 360; FANUC: "
                        "rotary type, no. 3625)")  # fmt: skip
    f = p.add_argument_group("fanuc")
    f.add_argument("--interval-mm", type=float, help="point interval (table's mean spacing)")
    f.add_argument("--reference-mm", type=float, help="reference position (first point)")
    f.add_argument("--reference-number", type=int, default=0, help="its point number (0)")
    f.add_argument("--unit-mm", type=float, default=0.001,
                   help="detection unit, mm or deg (0.001)")
    f.add_argument("--magnification", type=int, help="fixed magnification (auto)")
    f.add_argument("--max-increment", type=int, default=7, help="per-point limit (7)")
    f.add_argument("--direction", choices=["forward", "reverse", "mean"], default="forward")


def main(args: argparse.Namespace) -> int:
    try:
        print(export(args))
    except TableError as exc:
        print(f"compgw export: {exc}", file=sys.stderr)
        return 1
    return 0
