"""A capture export: one reading per stop, as a laser's software exports it.

Layouts differ by vendor and version, and compgw does not guess them: a small mapping file
says once which column holds the target, which the reading (a position or a deviation),
their units, the sign, and the run and direction columns where there are any
(``config/capture-generic.yaml`` is one for a plain layout). The readings are then matched
with the plan row by row: a missing or an extra reading, a target that is not the plan's,
another run or direction, is refused with one line naming the file and the first row that
disagrees, never shifted into the next target's place.
"""

from __future__ import annotations

import csv
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Literal

import numpy as np
import yaml
from pydantic import Field, ValidationError

from ..config_types import StrictModel
from .base import InstrumentError, to_mm, unit_of

#: a row's target and the plan's agree within this (mm): both are nominal
TARGET_TOLERANCE_MM = 0.001


class CaptureError(InstrumentError):
    """An export or mapping that cannot be used; the message names the file and row."""


class CaptureLayout(StrictModel):
    """The mapping file: how one laser software's capture export is laid out."""

    delimiter: str | None = None  # sniffed when not given
    skip_rows: Annotated[int, Field(ge=0)] = 0  # lines before the header row
    target_column: str
    target_unit: str = "mm"
    reading_column: str
    reading_is: Literal["position", "deviation"] = "deviation"
    reading_unit: str = "um"
    sign: Literal[1, -1] = 1
    run_column: str | None = None
    direction_column: str | None = None


@dataclass(frozen=True)
class PlanStop:
    """A stop the plan measures: its nominal target (mm), run and direction (+1 / -1)."""

    target_mm: float
    run: int
    direction: int


def load_layout(path: str | Path) -> CaptureLayout:
    """The mapping file; CaptureError naming the file and key when it is not right."""
    try:
        data = yaml.safe_load(Path(path).read_text(encoding="utf-8"))
        layout = CaptureLayout.model_validate(data)
    except (OSError, yaml.YAMLError) as exc:
        raise CaptureError(f"{path}: {exc}") from None
    except ValidationError as exc:
        first = exc.errors()[0]
        where = ".".join(str(p) for p in first["loc"]) or "(the file)"
        raise CaptureError(f"{path}: {where}: {first['msg']}") from None
    for key in ("target_unit", "reading_unit"):
        try:
            unit_of(getattr(layout, key), f"{path}: {key}")
        except ValueError as exc:
            raise CaptureError(str(exc)) from None
    return layout


_DIRECTIONS = {"+": 1, "-": -1, "−": -1, "up": 1, "down": -1, "forward": 1, "backward": -1,
               "fwd": 1, "bwd": -1, "pos": 1, "neg": -1, "1": 1, "-1": -1}


def read_export(path: str | Path, layout: CaptureLayout,
                plan: Sequence[PlanStop]) -> np.ndarray:  # fmt: skip
    """The position (mm) read at each of the plan's stops, in the plan's order; refuses
    (CaptureError, one line) an export that does not hold exactly the plan's stops."""
    name = str(path)
    try:
        text = Path(path).read_text(encoding="utf-8-sig")
    except OSError as exc:
        raise CaptureError(f"{name}: {exc}") from None
    lines = text.splitlines()[layout.skip_rows :]
    if not lines:
        raise CaptureError(f"{name}: empty after {layout.skip_rows} skipped lines")
    delimiter = layout.delimiter or _sniff(lines[0])
    rows = list(csv.reader(lines, delimiter=delimiter))
    head = [h.strip() for h in rows[0]]
    cols = {}
    for key in ("target_column", "reading_column", "run_column", "direction_column"):
        want = getattr(layout, key)
        if want is None:
            continue
        if want not in head:
            raise CaptureError(f"{name}: no column {want!r} ({key} in the mapping); the "
                               f"header is {head}")
        cols[key] = head.index(want)
    taken = [(n, r) for n, r in enumerate(rows[1:], start=layout.skip_rows + 2)
             if any(c.strip() for c in r)]
    out = np.empty(len(plan))
    for i, (line_no, row) in enumerate(taken):
        if i >= len(plan):
            raise CaptureError(f"{name}: {len(taken)} readings, the plan has {len(plan)}: "
                               f"line {line_no} is one more than the plan's stops")
        stop = plan[i]
        try:
            target = to_mm(float(row[cols["target_column"]]), layout.target_unit)
            reading = to_mm(float(row[cols["reading_column"]]), layout.reading_unit)
        except (ValueError, IndexError):
            raise CaptureError(f"{name}: line {line_no}: {row!r}: the target or reading is "
                               "not a number") from None
        where = (f"{name}: {len(taken)} readings, the plan has {len(plan)}: line {line_no} "
                 f"(reading {i + 1})")
        if abs(target - stop.target_mm) > TARGET_TOLERANCE_MM:
            raise CaptureError(f"{where} is at {target:.4f} mm where the plan's reading "
                               f"{i + 1} is at {stop.target_mm:.4f} mm (run {stop.run}, "
                               f"{'+' if stop.direction > 0 else '-'})")
        if "run_column" in cols:
            run = row[cols["run_column"]].strip()
            if run != str(stop.run):
                raise CaptureError(f"{where} is run {run}, the plan's is run {stop.run}")
        if "direction_column" in cols:
            text_dir = row[cols["direction_column"]].strip().lower()
            direction = _DIRECTIONS.get(text_dir)
            if direction is None:
                raise CaptureError(f"{where}: direction {text_dir!r} is not one of "
                                   f"{', '.join(_DIRECTIONS)}")
            if direction != stop.direction:
                raise CaptureError(f"{where} was approached {text_dir}, the plan's from the "
                                   f"{'+' if stop.direction > 0 else '-'} side")
        value = layout.sign * reading
        out[i] = stop.target_mm + value if layout.reading_is == "deviation" else value
    if len(taken) < len(plan):
        missing = plan[len(taken)]
        raise CaptureError(f"{name}: {len(taken)} readings, the plan has {len(plan)}: the "
                           f"plan's reading {len(taken) + 1} at {missing.target_mm:.4f} mm "
                           f"(run {missing.run}) is missing")
    return out


def _sniff(header: str) -> str:
    for candidate in (",", ";", "\t"):
        if candidate in header:
            return candidate
    return ","
