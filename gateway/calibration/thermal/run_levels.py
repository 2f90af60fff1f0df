"""The ISO runs' own levels: how far the screw grew from one run to the next.

A commissioning too short for drift references (a plain calibration's machine time) still
reads every target once per run, run after run, while its own moves warm the screw. What
a target reads differently from one run to the next (the mean of its ↑ and ↓, so the
reversal drops out) is the screw's growth between them, at every target for free; its
static error, the same in every run, is unknown, so only the changes count. A line over
the targets per run (the growth is linear from the screw's fixed end) gives each run's
level at the drift references, what :func:`..thermal.heat_fit.motion_heat_fit` takes
with ``offset``. Pure: arrays in, arrays out.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray


@dataclass(frozen=True)
class RunLevels:
    """The runs' levels at the references: ``runs`` (sorted labels), ``levels_um`` (runs,
    2: each up to a constant per group and reference), ``group`` (runs: the runs that read
    the same targets share one, and only their changes count), ``noise_um`` (one level's
    standard deviation, from the readings' scatter about the per-run lines)."""

    runs: NDArray[np.int64]
    levels_um: NDArray[np.float64]
    group: NDArray[np.int64]
    noise_um: float


def run_levels_um(run: ArrayLike, target_mm: ArrayLike, deviation_mm: ArrayLike,
                  refs_mm: tuple[float, float]) -> RunLevels:  # fmt: skip
    """Each run's level (µm) at the two references ``refs_mm`` from one axis's readings
    (``run`` a label per row: runs of several steps numbered apart; ``deviation_mm``
    actual − target). Runs over the same targets form a group (the ISO runs; the
    midpoints'): within it each target's mean over the runs is taken off, then a line per
    run through what is left gives its level."""
    r = np.asarray(run)
    x = np.asarray(target_mm, dtype=np.float64)
    dev = np.asarray(deviation_mm, dtype=np.float64) * 1000.0
    runs = np.unique(r)
    xs = np.unique(x)
    k = np.searchsorted(runs, r)
    i = np.searchsorted(xs, x)
    sums = np.zeros((runs.size, xs.size))
    counts = np.zeros((runs.size, xs.size))
    np.add.at(sums, (k, i), dev)
    np.add.at(counts, (k, i), 1.0)
    read = counts > 0
    group = np.unique(read, axis=0, return_inverse=True)[1].ravel()
    levels = np.zeros((runs.size, 2))
    refs = np.stack([np.ones(2), np.asarray(refs_mm, dtype=np.float64)], axis=1)
    squares, dof, lever = 0.0, 0, []
    for g in np.unique(group):
        rows = group == g
        on = read[rows][0]
        at = xs[on]
        if at.size < 3 or rows.sum() < 2:
            continue  # no line, or no change: the group's levels stay 0
        mean = sums[rows][:, on] / counts[rows][:, on]  # each run's ↑↓ mean per target
        change = mean - mean.mean(axis=0)  # the static error, the same in every run, off
        design = np.stack([np.ones_like(at), at], axis=1)
        coef = np.linalg.lstsq(design, change.T, rcond=None)[0]  # (2, runs)
        levels[rows] = (refs @ coef).T
        left = change.T - design @ coef
        squares += float((left**2).sum())
        dof += (at.size - 2) * (int(rows.sum()) - 1)
        # a level's variance over a reading's: the line's leverage at the references
        inv = np.linalg.inv(design.T @ design)
        lever.append(float(np.max(np.einsum("ri,ij,rj->r", refs, inv, refs))))
    noise = float(np.sqrt(squares / dof * max(lever))) if dof > 0 and lever else float("nan")
    return RunLevels(runs.astype(np.int64), levels, group.astype(np.int64), noise)


def row_odometer_mm(row_s: ArrayLike, span_s: tuple[float, float],
                    odometer_mm: tuple[dict[str, float], dict[str, float]]
                    ) -> dict[str, NDArray[np.float64]]:  # fmt: skip
    """Each axis's odometer (mm) at each row's time ``row_s``, taken as growing evenly in
    time over the step's span (``span_s``: its clock before and after; ``odometer_mm``:
    the odometers then)."""
    t = np.asarray(row_s, dtype=np.float64)
    t0, t1 = span_s
    share = np.clip((t - t0) / (t1 - t0), 0.0, 1.0) if t1 > t0 else np.full(t.size, 0.5)
    before, after = odometer_mm
    return {a: before.get(a, 0.0) + share * (after.get(a, 0.0) - before.get(a, 0.0))
            for a in after}  # fmt: skip


def means_by(label: ArrayLike, values: ArrayLike) -> NDArray[np.float64]:
    """The mean of ``values`` per label, labels sorted (as np.unique, and as
    :func:`run_levels_um` returns the runs)."""
    k = np.unique(np.asarray(label), return_inverse=True)[1].ravel()
    return np.bincount(k, weights=np.asarray(values, dtype=np.float64)) / np.bincount(k)


def on_the_way(at_s: ArrayLike, odometer_mm: dict[str, ArrayLike], way_s: ArrayLike,
               way_odometer_mm: dict[str, ArrayLike]
               ) -> tuple[NDArray[np.intp], NDArray[np.float64], dict[str, NDArray[np.float64]]]:
    """Readings (clock ``at_s``, each axis's odometer) and points on the way between them
    (``way_s``, ``way_odometer_mm``: the ends of other steps, where the travel of the moves
    between an axis's runs lies in time) in one timeline. Returns where each reading went
    (indices into it; the rest are points on the way), its clock (s) and odometers (mm).
    A reading comes before a point on the way at the same instant."""
    t = np.concatenate([np.asarray(at_s, dtype=np.float64),
                        np.asarray(way_s, dtype=np.float64)])  # fmt: skip
    n = np.size(at_s)
    order = np.lexsort((np.arange(t.size) >= n, t))
    odo = {a: np.concatenate([np.asarray(v, dtype=np.float64),
                              np.asarray(way_odometer_mm.get(a, np.zeros(t.size - n)),
                                         dtype=np.float64)])[order]
           for a, v in odometer_mm.items()}  # fmt: skip
    where = np.empty(n, dtype=np.intp)
    where[order[order < n]] = np.flatnonzero(order < n)
    return where, t[order], odo
