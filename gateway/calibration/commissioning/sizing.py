"""What a short budget's first table and the plane's first grid come to: pure functions
of machine-time costs (:mod:`.short` decides with them)."""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass

from ..fitting import adaptive

#: the fewest runs per target a short budget reads a plain calibration's table at (else the
#: coarse table at up to its runs; :meth:`.identify.IdentifySteps._iso_runs_that_fit`)
DENSE_LEAST_RUNS = 2


@dataclass(frozen=True)
class TableReading:
    """How densely and how often a short budget reads each axis's first table."""

    points: Mapping[str, int]  # targets per axis; empty: the coarse table's
    runs: int  # runs per target
    dense: bool  # a plain calibration's table
    fits: bool  # whether the budget holds it (else the least there is)


def first_table_reading(axes: list[str], runs: int, dense: Mapping[str, int],
                        cost_s: Callable[[int, Mapping[str, int | None]], float],
                        room_s: float, scans_s: float) -> TableReading:  # fmt: skip
    """The first table's reading on a short budget, whose rounds will not sweep between its
    points: a plain calibration's table (``dense``, per axis; empty where the coarse one
    is as dense) at ``runs`` down to DENSE_LEAST_RUNS where it fits in ``room_s`` beside
    the cyclic scans (``scans_s``); else the coarse table at the runs that fit (down to 2,
    the fewest that show a scatter), then fewer targets down to the ISO 230-2 least.
    ``cost_s(runs, points)`` is every axis's ISO runs' machine time (s; a point count of
    None: the coarse table's)."""
    if dense:
        for r in range(runs, DENSE_LEAST_RUNS - 1, -1):
            if cost_s(r, dense) + scans_s <= room_s:
                return TableReading(dict(dense), r, True, True)
    coarse: dict[str, int | None] = dict.fromkeys(axes)
    while runs > 2 and cost_s(runs, coarse) > room_s:
        runs -= 1
    if cost_s(runs, coarse) <= room_s:
        return TableReading({}, runs, False, True)
    for n in range(adaptive.COARSE_POINTS - 1, adaptive.ISO_LEAST_POINTS - 1, -1):
        if cost_s(runs, dict.fromkeys(axes, n)) <= room_s:
            return TableReading(dict.fromkeys(axes, n), runs, False, True)
    return TableReading(dict.fromkeys(axes, adaptive.ISO_LEAST_POINTS), runs, False, False)


#: the most nodes a grid takes along an axis (as :func:`..fitting.adaptive.denser_grid`)
MAX_NODES = 33


def hold_each(held_s: float, needs_s: list[float], left_s: float) -> float:
    """Machine time (s) held: ``held_s`` and each of ``needs_s`` in turn where it fits
    in ``left_s`` beside those held before it (one that does not fit holds nothing)."""
    for need_s in needs_s:
        if held_s + need_s <= left_s:
            held_s += need_s
    return held_s


def grid_of_shape(grid: tuple[int, int], nodes_x: int) -> tuple[int, int]:
    """``nodes_x`` nodes along x, along y in the proportion of ``grid``'s cells."""
    nx, ny = grid
    return nodes_x, min(MAX_NODES, max(2, 1 + round((ny - 1) * (nodes_x - 1) / max(1, nx - 1))))


def fitting_grid(grid: tuple[int, int], cost_s: Callable[[tuple[int, int]], float],
                 left_s: float) -> tuple[int, int] | None:
    """The densest grid of ``grid``'s shape, at most as dense, whose ``cost_s`` is within
    ``left_s`` (at least 3 nodes along x); None where none is."""
    for kx in range(grid[0], 2, -1):
        cand = grid if kx == grid[0] else grid_of_shape(grid, kx)
        if cost_s(cand) <= left_s:
            return cand
    return None


def max_grid_in(grid: tuple[int, int], cost_s: Callable[[tuple[int, int]], float],
                left_s: float) -> tuple[int, int]:
    """The densest grid of ``grid``'s shape (nodes along x from its own up, along y in the
    same proportion of cells) whose ``cost_s`` is within ``left_s``; ``grid`` itself if
    none denser is. Every size between, not only the configured grid split in two each
    way: a budget that holds 13 x 9 and not 25 x 17 is spent on 17 x 12."""
    best = grid
    for kx in range(grid[0] + 1, MAX_NODES + 1):
        cand = grid_of_shape(grid, kx)
        if cost_s(cand) > left_s:
            break
        best = cand
    return best
