"""XY plans (seed 001): the grid the planar model is fitted on and the verification points
judged off it, in serpentine order; :class:`.plans.Plan`'s file format."""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

from .plans import Move, Plan, _meta, _round, _travel


# -- XY grid (seed 001) ---------------------------------------------------------------------
def even_grid(x_travel_mm: float, y_travel_mm: float, lines: int = 7, least: int = 5
              ) -> tuple[int, int]:  # fmt: skip
    """A plane grid (nodes along x, along y) whose cells are about square: ``lines`` along
    the longer travel, along the shorter as many as keep that spacing, at least ``least``
    (a cubic grid needs 4): 7 x 5 on an 800 x 600 mm table, 7 x 7 on a square one. The
    judge's worse axis reads a line across the grid, and cells half again as long one way
    leave it the worse: the sdss plates' field interpolated noise-free from 15 x 10 nodes
    leaves that axis 3.54, 2.30 and 2.68 µm (median over 40 parks), from 12 x 12, fewer
    nodes, 2.60, 2.04 and 1.84 µm."""
    long_mm, short_mm = max(x_travel_mm, y_travel_mm), min(x_travel_mm, y_travel_mm)
    across = max(least, 1 + round((lines - 1) * short_mm / long_mm))
    return (lines, across) if x_travel_mm >= y_travel_mm else (across, lines)


def xy_grid_points_mm(
    x_range_mm: Sequence[float], y_range_mm: Sequence[float], nx: int, ny: int
) -> NDArray[np.float64]:
    """The nx × ny grid nodes in serpentine order: rows of constant y, x alternating."""
    if nx < 2 or ny < 2:
        raise ValueError("an XY grid needs nx >= 2 and ny >= 2")
    xs = _round(np.linspace(*_travel(x_range_mm), nx))
    ys = _round(np.linspace(*_travel(y_range_mm), ny))
    return _serpentine(xs, ys)


def _serpentine(xs: NDArray[np.float64], ys: NDArray[np.float64]) -> NDArray[np.float64]:
    rows = [np.column_stack([xs if j % 2 == 0 else xs[::-1], np.full(xs.size, y)])
            for j, y in enumerate(ys)]  # fmt: skip
    return np.vstack(rows)


def _xy_plan(
    kind: str, axes: Sequence[str], points: NDArray[np.float64], runs: int,
    meta: tuple[tuple[str, str], ...], speed_mm_s: float | None, dwell_s: float | None,
    approach_mm: float | None = None, lower_mm: Sequence[float] = (-math.inf, -math.inf),
    upper_mm: Sequence[float] | None = None,
) -> Plan:  # fmt: skip
    """Moves over ``points``; with ``approach_mm`` each point is approached in + on both axes
    from a ``takeup`` point ``approach_mm`` below it (clipped at ``lower_mm``), so every
    point is measured with the play taken up the same way (a small corrective move in −
    would otherwise be lost in the backlash). With ``upper_mm`` too, every second run
    approaches in − from ``approach_mm`` above (clipped there): the plane read from both
    sides, as a PLC going point to point reaches it."""
    moves: list[Move] = []
    for j in range(1, runs + 1):
        prev = None
        down = upper_mm is not None and j % 2 == 0
        for p in points:
            if approach_mm:
                start = (np.minimum(p + approach_mm, np.asarray(upper_mm, dtype=np.float64))
                         if down else
                         np.maximum(p - approach_mm, np.asarray(lower_mm, dtype=np.float64)))
                moves.append(Move(j, 0, "takeup", tuple(float(v) for v in _round(start)),
                                  speed_mm_s))  # fmt: skip
                d = -1 if down else 1
            else:
                d = 0 if prev is None or p[0] == prev[0] else (1 if p[0] > prev[0] else -1)
            moves.append(Move(j, d, "measure", (float(p[0]), float(p[1])), speed_mm_s, dwell_s))
            prev = p
    return Plan(kind, tuple(axes), tuple(moves), meta)


def xy_grid_plan(
    x_range_mm: Sequence[float],
    y_range_mm: Sequence[float],
    nx: int,
    ny: int,
    axes: Sequence[str] = ("X", "Y"),
    runs: int = 1,
    speed_mm_s: float | None = None,
    dwell_s: float | None = None,
    approach_mm: float | None = None,
    lower_mm: Sequence[float] = (-math.inf, -math.inf),
) -> Plan:
    """Planar identification grid, serpentine order (direction = X approach direction).

    ``approach_mm``: approach every point in + on both axes from that far below (a
    ``takeup`` move, clipped at ``lower_mm``, the travel's lower ends).
    """
    points = xy_grid_points_mm(x_range_mm, y_range_mm, nx, ny)
    meta = _meta(kind="xy-grid", axes=tuple(axes), x_range_mm=tuple(x_range_mm),
                 y_range_mm=tuple(y_range_mm), nx=nx, ny=ny, runs=runs,
                 approach_mm=approach_mm)  # fmt: skip
    return _xy_plan("xy-grid", axes, points, runs, meta, speed_mm_s, dwell_s, approach_mm,
                    lower_mm)  # fmt: skip


def xy_verification_points_mm(
    x_range_mm: Sequence[float],
    y_range_mm: Sequence[float],
    nx: int,
    ny: int,
    mode: str = "centres",
    count: int = 20,
    seed: int = 0,
    min_distance_fraction: float = 0.25,
) -> NDArray[np.float64]:
    """Off-grid points: cell centres (serpentine) or ``count`` seeded random points inside.

    Random points closer than ``min_distance_fraction`` of the smaller cell size to any
    grid line crossing are re-drawn, so they probe the model between nodes.
    """
    grid = xy_grid_points_mm(x_range_mm, y_range_mm, nx, ny)
    xs, ys = np.unique(grid[:, 0]), np.unique(grid[:, 1])
    if mode == "centres":
        return _serpentine(_round(0.5 * (xs[1:] + xs[:-1])), _round(0.5 * (ys[1:] + ys[:-1])))
    if mode != "random":
        raise ValueError(f"mode {mode!r} is not centres or random")
    rng = np.random.default_rng(seed)
    cell = min(np.diff(xs).min(), np.diff(ys).min())
    out: list[NDArray[np.float64]] = []
    while len(out) < count:
        p = _round(np.array([rng.uniform(xs[0], xs[-1]), rng.uniform(ys[0], ys[-1])]))
        if np.min(np.hypot(*(grid - p).T)) >= min_distance_fraction * cell:
            out.append(p)
    return np.array(out)


def xy_verification_plan(
    x_range_mm: Sequence[float],
    y_range_mm: Sequence[float],
    nx: int,
    ny: int,
    axes: Sequence[str] = ("X", "Y"),
    mode: str = "centres",
    count: int = 20,
    seed: int = 0,
    speed_mm_s: float | None = None,
    dwell_s: float | None = None,
    approach_mm: float | None = None,
    lower_mm: Sequence[float] = (-math.inf, -math.inf),
    upper_mm: Sequence[float] | None = None,
) -> Plan:
    """Verification points of the grid plan with the same parameters (never on a node).

    ``upper_mm`` (with ``approach_mm``): the points read twice, in + from below, then in −
    from above (:func:`_xy_plan`)."""
    points = xy_verification_points_mm(x_range_mm, y_range_mm, nx, ny, mode, count, seed)
    runs = 1 if upper_mm is None or not approach_mm else 2
    meta = _meta(kind="xy-verification", axes=tuple(axes), x_range_mm=tuple(x_range_mm),
                 y_range_mm=tuple(y_range_mm), nx=nx, ny=ny, mode=mode,
                 count=count if mode == "random" else None, seed=seed,
                 approach_mm=approach_mm, both_ways=runs == 2 or None)  # fmt: skip
    return _xy_plan("xy-verification", axes, points, runs, meta, speed_mm_s, dwell_s,
                    approach_mm, lower_mm, upper_mm)  # fmt: skip
