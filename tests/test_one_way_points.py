"""Points put between a table's others, read going up only: their reversal is the table's
(the nut's lost motion, slow along the travel), their short waves their own (the screw's,
the same both ways)."""

from __future__ import annotations

import numpy as np
import pytest

from gateway.calibration.commissioning.steps import concat_raw
from gateway.calibration.fitting.fit import (
    bidirectional_table,
    one_way_split,
    with_one_way_points,
)
from gateway.calibration.plans.plans import targets_plan
from gateway.calibration.plans.rawdata import RawData, axis_deviations
from gateway.compensation import PitchStage, PitchTable
from gateway.compensation.errors import TableError


def _waves_um(x: np.ndarray) -> np.ndarray:
    """A rough screw's waves of 15-40 mm (both directions)."""
    return 3.0 * np.sin(2 * np.pi * x / 21.0) + 1.5 * np.sin(2 * np.pi * x / 37.0 + 1.0)


def _lost_um(x: np.ndarray) -> np.ndarray:
    """Lost motion growing along the travel, worn at 150 mm."""
    return 12.0 + 0.02 * x + 4.0 * np.exp(-(((x - 150.0) / 40.0) ** 2))


def _raw(x_mm: np.ndarray, runs: int, ways: tuple[int, ...], seed: int) -> RawData:
    rng = np.random.default_rng(seed)
    rows = [(r, s, x) for r in range(1, runs + 1) for s in ways for x in x_mm]
    run = np.array([r[0] for r in rows])
    sign = np.array([r[1] for r in rows], dtype=np.int8)
    x = np.array([r[2] for r in rows])
    dev_um = _waves_um(x) + _lost_um(x) * (sign < 0) + rng.normal(0, 0.15, x.size)
    return RawData(("X",) * x.size, run, sign, x, x + dev_um * 1e-3, {},
                   tuple(range(x.size)))  # fmt: skip


def test_points_read_one_way_take_the_table_s_reversal_and_their_own_waves() -> None:
    """A table every 25 mm at 3 runs and its midpoints at 2, both ways; its quarter points
    going up only, one run. The table through all of them follows the waves between the
    points both ways as closely as one whose quarter points were read both ways (for twice
    the readings); the one without them misses twice as much."""
    first = np.arange(0.0, 300.01, 25.0)
    mid = (first[1:] + first[:-1]) / 2
    both_x = np.sort(np.concatenate([first, mid]))
    quarters = (both_x[1:] + both_x[:-1]) / 2
    raw = concat_raw([_raw(first, 3, (1, -1), 1), _raw(mid, 2, (1, -1), 2),
                      _raw(quarters, 1, (1,), 3)])  # fmt: skip
    dev = axis_deviations(raw, "X")
    both, one = one_way_split(dev)
    assert one is not None and np.allclose(one.target_mm, quarters)
    assert np.allclose(both.target_mm, both_x)
    table = with_one_way_points(bidirectional_table(both), one)
    assert np.allclose(table.position_mm, np.sort(np.concatenate([both_x, quarters])))

    x = np.linspace(2.0, 298.0, 600)
    truth_up, truth_down = _waves_um(x), _waves_um(x) + _lost_um(x)

    def misses_um(t: PitchTable) -> float:
        stage = PitchStage(t, "linear")
        up = (stage.inverse(x, np.ones(x.size)) - x) * 1e3
        down = (stage.inverse(x, -np.ones(x.size)) - x) * 1e3
        return float(max(np.abs(up - truth_up).max(), np.abs(down - truth_down).max()))

    both_ways = bidirectional_table(axis_deviations(concat_raw([
        _raw(first, 3, (1, -1), 1), _raw(mid, 2, (1, -1), 2), _raw(quarters, 1, (1, -1), 3)]),
        "X"))  # fmt: skip
    with_quarters, without = misses_um(table), misses_um(bidirectional_table(both))
    assert with_quarters < misses_um(both_ways) + 0.2, (with_quarters, misses_um(both_ways))
    assert without > 2.0 * with_quarters, (without, with_quarters)
    i = np.searchsorted(table.position_mm, quarters)
    assert np.allclose((table.reverse_mm - table.forward_mm)[i] * 1e3, _lost_um(quarters),
                       atol=0.5)  # fmt: skip


def test_a_table_read_both_ways_everywhere_is_not_split_and_one_way_needs_a_reversal() -> None:
    dev = axis_deviations(_raw(np.arange(0.0, 100.1, 25.0), 2, (1, -1), 4), "X")
    assert one_way_split(dev)[1] is None
    up_only = axis_deviations(_raw(np.array([12.5, 37.5]), 1, (1,), 5), "X")
    flat = PitchTable(np.array([0.0, 100.0]), np.zeros(2))  # one direction: no reversal
    with pytest.raises(TableError, match=r"axis X.*bidirectional table"):
        with_one_way_points(flat, up_only)


def test_a_raw_file_read_one_way_is_refused_as_bidirectional_naming_file_and_axis() -> None:
    """Its reversal cannot be known: before, the error said only that a table needs 2
    points."""
    x = np.arange(0.0, 100.1, 25.0)
    raw = concat_raw([_raw(x, 2, (1,), 6), _raw(x[:1], 1, (-1,), 7)])
    with pytest.raises(TableError, match=r"axis X: 1 target\(s\) read both ways.*--mode "
                                         r"unidirectional"):  # fmt: skip
        one_way_split(axis_deviations(raw, "X"))


def test_a_one_way_plan_reads_each_run_going_up_after_an_overrun_below() -> None:
    plan = targets_plan("X", (0.0, 100.0), [10.0, 20.0, 30.0], 2, kind="iso230-linear",
                        one_way=True)  # fmt: skip
    assert dict(plan.meta)["one_way"] == "+"
    moves = [(m.run, m.direction, m.role, m.target_mm[0]) for m in plan.moves]
    assert moves == [(r, d, role, x) for r in (1, 2) for d, role, x in
                     ((-1, "overrun", 9.0), (1, "measure", 10.0), (1, "measure", 20.0),
                      (1, "measure", 30.0))]  # fmt: skip
    both = targets_plan("X", (0.0, 100.0), [10.0, 20.0, 30.0], 2, kind="iso230-linear")
    assert sum(m.measured for m in both.moves) == 2 * sum(m.measured for m in plan.moves)
