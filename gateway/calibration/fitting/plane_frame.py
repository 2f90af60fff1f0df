"""The tables a faded planar model was fitted against, and the model re-expressed when they
change.

An XY grid is read with the pitch tables on, so a grid model holds what the tables left:
M = T − A_fit (per component: X's error less X's table, which depends on x only). Pinned
with a fade (:func:`.models.pinned_measurement`), the model keeps M far from the pitch
lines, the tables' own error at the grid's resolution included, and its level along the
line everywhere (where the instruments were zeroed: no step at the line). When a table changes
afterwards by Δ = A_now − A_fit (a sweep, a refinement, a table put back), the model far
from the line would undo the change there; pinned without a fade (a polynomial) Δ cancels
and nothing is needed. So the tables' values at the grid's nodes are kept beside the
model (the *frame*, ``xy_frame.json``, with the points as fitted, ``xy_points_fitted.csv``),
and before the model runs with other tables it is re-expressed: the fitted points, each
component less (1 − fade) · (S(Δ) − L(Δ)) + fade · mean(Δ), S(Δ) the cubic through Δ at
the grid's nodes (what the grid would have read of it), L(Δ) its straight part less its
mean, the fade the pin's own: far from the line table and plane still add up to what the
grid read but for the straight part, which the pin takes off the whole plane and which so
follows the table everywhere, and on the line the table's level change is given back too
(a table's level moves the whole plane, never a step). Always from the
fitted points, never from the last re-expression: an interrupted write is simply done
again.

Pure functions on arrays and one small file; the tables' values come from the gateway's
own chain (:func:`table_deviation_mm`).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray
from scipy.interpolate import CubicSpline

from ...compensation import PlanarMeasurement
from ...config import GatewayConfig
from ...formats import atomic_write_text, read_planar_csv
from ...formats.planar_file import planar_csv_text
from ...tables import build_axis
from .models import line_part, node_step_mm, pin_fade, pin_fades
from .outputs import planar_paths

#: the frame's file, and the points as fitted, beside the model's points
FRAME_FILE = "xy_frame.json"
FITTED_FILE = "xy_points_fitted.csv"


@dataclass(frozen=True)
class PlaneFrame:
    """Per plane axis (mm): where the other axis stood for its table (``line_mm``), the
    grid's nodes along the axis (``nodes_mm``) and the deviation the tables applied there
    when the grid was read (``table_mm``)."""

    line_mm: dict[str, float]
    nodes_mm: dict[str, NDArray[np.float64]]
    table_mm: dict[str, NDArray[np.float64]]

    def step_mm(self, axis: str) -> float:
        """The grid's node step away from ``axis``'s line (the fade's scale): the other
        axis's."""
        other = next(a for a in self.nodes_mm if a != axis)
        return node_step_mm(self.nodes_mm[other])

    def to_json(self) -> str:
        return json.dumps({
            "line_mm": self.line_mm,
            "nodes_mm": {a: v.tolist() for a, v in self.nodes_mm.items()},
            "table_mm": {a: v.tolist() for a, v in self.table_mm.items()},
        }, indent=1)  # fmt: skip

    @classmethod
    def from_json(cls, text: str) -> PlaneFrame:
        d = json.loads(text)
        arrays = {k: {a: np.asarray(v, dtype=np.float64) for a, v in d[k].items()}
                  for k in ("nodes_mm", "table_mm")}  # fmt: skip
        return cls(dict(d["line_mm"]), arrays["nodes_mm"], arrays["table_mm"])


def table_deviation_mm(config: GatewayConfig, config_dir: Path, axis: str,
                       positions_mm: NDArray[np.float64]) -> NDArray[np.float64]:  # fmt: skip
    """The deviation (mm, actual − commanded) ``config``'s own stages of ``axis`` take off
    at ``positions_mm`` approached in + (pitch, cyclic, backlash; no plane, no heat)."""
    chain = build_axis(axis, config.axes[axis], config_dir)
    x = np.asarray(positions_mm, dtype=np.float64)
    return x - chain.command_mm(x, 1, 0.0)


def frame_of(config: GatewayConfig, config_dir: Path, axes: tuple[str, str],
             nodes_mm: tuple[NDArray[np.float64], NDArray[np.float64]],
             lines_mm: dict[str, float]) -> PlaneFrame:  # fmt: skip
    """The frame of a grid read on ``nodes_mm`` (x, y) with ``config``'s tables on."""
    nodes = {axes[0]: np.asarray(nodes_mm[0], np.float64),
             axes[1]: np.asarray(nodes_mm[1], np.float64)}  # fmt: skip
    table = {a: table_deviation_mm(config, config_dir, a, nodes[a]) for a in axes}
    return PlaneFrame({a: float(lines_mm[a]) for a in axes}, nodes, table)


def fitted_frame(pinned: str | None, meas: PlanarMeasurement, config: GatewayConfig,
                 config_dir: Path, axes: tuple[str, str],
                 lines_mm: dict[str, float] | None) -> PlaneFrame | None:  # fmt: skip
    """The frame of a plane just fitted from ``meas`` (read with ``config``'s tables as
    they are on disk), or None when it needs none: not pinned, or pinned without a fade
    (``pinned``: the family pinned, :attr:`.models.PlanarChoice.pinned`)."""
    if not lines_mm or pinned is None or not pin_fades(pinned.split()[0]):
        return None
    nodes = (np.unique(meas.command_mm[:, 0]), np.unique(meas.command_mm[:, 1]))
    return frame_of(config, config_dir, axes, nodes, lines_mm)


def save_frame(points_path: Path, frame: PlaneFrame | None) -> None:
    """The frame and a copy of the points just fitted beside them, or neither there (stale
    ones removed)."""
    path, fitted = points_path.parent / FRAME_FILE, points_path.parent / FITTED_FILE
    if frame is None:
        path.unlink(missing_ok=True)
        fitted.unlink(missing_ok=True)
    else:
        atomic_write_text(fitted, points_path.read_text())
        write_frame(path, frame)


def reframed(points: PlanarMeasurement, frame: PlaneFrame, axes: tuple[str, str],
             table_now_mm: dict[str, NDArray[np.float64]]) -> PlanarMeasurement:  # fmt: skip
    """A faded model's points re-expressed against tables that now take off
    ``table_now_mm`` at the frame's nodes: each component less (1 − fade) · (S(Δ) − L(Δ))
    + fade · mean(Δ), L(Δ) the straight part of Δ less its mean (:func:`.models.line_part`):
    what the pin takes off the whole plane follows the table everywhere, a level is held on
    the line as off it (:func:`.models.pinned_measurement`)."""
    err = points.error_mm.copy()
    for k, a in enumerate(axes):
        delta = np.asarray(table_now_mm[a], np.float64) - frame.table_mm[a]
        nodes = frame.nodes_mm[a]
        if nodes.size < 2 or not np.any(delta):
            continue
        smooth = CubicSpline(nodes, delta) if nodes.size > 2 else (
            lambda x, n=nodes, d=delta: np.interp(x, n, d))  # fmt: skip
        along = np.clip(points.command_mm[:, k], nodes[0], nodes[-1])
        away = points.command_mm[:, 1 - k] - frame.line_mm[a]
        fade = pin_fade("grid", away, frame.step_mm(a))
        tilt = line_part(nodes, delta)  # (the plane holds none of the line's tilt: followed)
        err[:, k] -= ((1.0 - fade) * (smooth(along) - tilt(along))
                      + fade * float(np.mean(delta)))  # fmt: skip
    return PlanarMeasurement(points.command_mm, points.command_mm + err, points.source)


def reframe_plane(config: GatewayConfig, config_dir: Path) -> bool:
    """``config``'s plane made its fitted points re-expressed against the tables
    ``config`` names as they are on disk now (what every writer of a table calls after
    it); False when the config has no plane, the plane no frame, or its points are that
    already."""
    if config.planar is None:
        return False
    points_path = planar_paths(config, config_dir)[1]
    frame = read_frame(points_path.parent / FRAME_FILE)
    fitted = points_path.parent / FITTED_FILE
    if frame is None or not fitted.exists():
        return False
    axes: tuple[str, str] = tuple(config.planar.axes)  # type: ignore[assignment]
    now = {a: table_deviation_mm(config, config_dir, a, frame.nodes_mm[a]) for a in axes}
    text = planar_csv_text(reframed(read_planar_csv(fitted), frame, axes, now))
    if points_path.exists() and points_path.read_text() == text:
        return False
    atomic_write_text(points_path, text)
    return True


def write_frame(path: Path, frame: PlaneFrame) -> None:
    atomic_write_text(path, frame.to_json() + "\n")


def read_frame(path: Path) -> PlaneFrame | None:
    return PlaneFrame.from_json(path.read_text()) if path.exists() else None
