"""Planar (XY) measurement points and the model file that references them.

Points CSV (deviations actual − commanded, µm, at commanded positions, mm)::

    x_mm,y_mm,dx_um,dy_um
    0,0,0.0,0.0
    100,0,1.2,-0.4

Model file (YAML), paths relative to the model file::

    points: xy_points.csv
    model: grid          # grid | poly
    method: cubic        # grid only: cubic | linear
    degree: auto         # poly only: auto (leave-one-out CV) or 0..6
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from ..compensation.errors import TableError
from ..compensation.planar import GridModel, PlanarMeasurement, PlanarModel, PolyModel
from ..config_types import read_yaml
from .atomic import atomic_write_text
from .lines import DEVIATION_DECIMALS as DEV
from .lines import POSITION_DECIMALS as POS
from .lines import csv_header, data_lines, fmt, parse_numbers

_HEADER = ("x_mm", "y_mm", "dx_um", "dy_um")
_MODEL_KEYS = {"points", "model", "method", "degree"}


def read_planar_csv(path: str | os.PathLike[str]) -> PlanarMeasurement:
    rows = data_lines(path)
    header_line, header = csv_header(path, rows)
    if header != _HEADER:
        raise TableError(f"{path}: line {header_line}: header must be {','.join(_HEADER)}")
    lines: list[int] = []
    values: list[tuple[float, ...]] = []
    for number, text in rows:
        cells = text.split(",")
        if len(cells) != 4:
            raise TableError(
                f"{path}: line {number}: expected 4 comma-separated numbers, got {len(cells)}"
            )
        values.append(parse_numbers(path, number, _HEADER, cells))
        lines.append(number)
    if not values:
        raise TableError(f"{path}: no points after the header")
    data = np.array(values)
    cmd = data[:, :2]
    return PlanarMeasurement(cmd, cmd + data[:, 2:] * 1e-3, source=str(path), lines=tuple(lines))


def planar_csv_text(meas: PlanarMeasurement) -> str:
    """The points CSV's text (what :func:`write_planar_csv` writes)."""
    dev = (meas.error_mm * 1e3).tolist()  # plain floats: the same values, read faster
    body = "".join(
        f"{fmt(x, POS)},{fmt(y, POS)},{fmt(dx, DEV)},{fmt(dy, DEV)}\n"
        for (x, y), (dx, dy) in zip(meas.command_mm.tolist(), dev)
    )
    return "# deviation actual - commanded (um)\n" + ",".join(_HEADER) + "\n" + body


def write_planar_csv(path: str | os.PathLike[str], meas: PlanarMeasurement) -> None:
    atomic_write_text(path, planar_csv_text(meas))


def load_planar_model(path: str | os.PathLike[str]) -> PlanarModel:
    """Build the planar model a model file describes (errors name the file and key)."""
    spec = read_yaml(path, TableError)
    if not isinstance(spec, dict):
        raise TableError(f"{path}: expected a mapping with keys {', '.join(sorted(_MODEL_KEYS))}")
    unknown = set(spec) - _MODEL_KEYS
    if unknown:
        raise TableError(f"{path}: unknown key {sorted(unknown)[0]!r}")
    if "points" not in spec:
        raise TableError(f"{path}: points: missing (the CSV of measured points)")
    points = Path(path).parent / str(spec["points"])
    meas = read_planar_csv(points)
    kind = spec.get("model", "grid")
    if kind == "grid":
        method = spec.get("method", "cubic")
        if method not in ("cubic", "linear"):
            raise TableError(f"{path}: method: {method!r} is not cubic or linear")
        return GridModel.from_measurement(meas, method)
    if kind == "poly":
        degree = spec.get("degree", "auto")
        if degree != "auto" and not (isinstance(degree, int) and 0 <= degree <= 6):
            raise TableError(f"{path}: degree: {degree!r} is not auto or an integer 0..6")
        return PolyModel.fit(meas, None if degree == "auto" else degree)
    raise TableError(f"{path}: model: {kind!r} is not grid or poly")
