"""The thermal drift between the two drift references (gateway.calibration.thermal.drift_shape,
adaptive.Drift), checked against the sim's screw: heat where the nut works, conducted along
the steel and lost to the air (sim.heat), never the gateway's own travel counts."""

# the spread and memory commissioning takes from a zone warm-up's fit (warmup_heat)

from __future__ import annotations

import numpy as np
import pytest

from gateway.calibration.fitting.adaptive import Drift
from gateway.calibration.thermal.drift_shape import SweptHeat, sample_mm
from sim.config_truth import ScrewHeat
from sim.heat import ScrewHeatModel

TRAVEL, SPEED = (0.0, 600.0), 100.0
SPREAD_MM, MEMORY_S = 100.0, 1000.0
REFS = (31.0, 570.0)  # where commissioning reads them: 5 % in from each end


def _screw() -> ScrewHeatModel:
    return ScrewHeatModel(ScrewHeat(lead_mm=5.0, drag_torque_Nm=0.06, diameter_mm=16.0,
                                    nut_length_mm=40.0, h_W_m2K=15.0, screw_mm=(-40.0, 640.0),
                                    fixed_end_mm=-40.0), TRAVEL)  # fmt: skip


def _work(screw: ScrewHeatModel, swept: SweptHeat, zone: tuple[float, float], t0: float,
          duration_s: float) -> float:  # fmt: skip
    """Cycle ``zone`` for ``duration_s`` from ``t0``, every move told to both; the end time."""
    t, pos = t0, zone[0]
    swept.move_to(pos)
    while t < t0 + duration_s:
        x = zone[1] if pos == zone[0] else zone[0]
        dt = abs(x - pos) / SPEED
        screw.add_move(t, t + dt, pos, x, SPEED)
        swept.elapse(dt + 0.5)
        swept.move_to(x)
        t, pos = t + dt + 0.5, x
    return t


@pytest.mark.parametrize("zone", [(60.0, 220.0), (380.0, 560.0)])
def test_the_drift_follows_where_the_screw_was_worked(zone: tuple[float, float]) -> None:
    """A verification run worked one zone for 20 minutes: the screw grew steeply there.
    Read at the two references before and after, the drift taken along the heat shape
    misses the true growth by under an eighth of what a straight line misses (0.9 against
    21.6-21.9 µm here), at every place of the travel, at the end of the run and halfway."""
    screw = _screw()
    swept = SweptHeat.for_travel(TRAVEL, MEMORY_S)
    t0 = _work(screw, swept, (0.0, 600.0), 0.0, 300.0) + 60.0  # the whole travel, a pause
    swept.elapse(60.0)
    before = tuple(screw.growth_mm(r, t0) for r in REFS)
    shape_before = tuple(swept.shape(SPREAD_MM))
    half = _work(screw, swept, zone, t0, 600.0)
    shape_half = tuple(swept.shape(SPREAD_MM))
    mid = {x: screw.growth_mm(x, half) for x in sample_mm(TRAVEL)}
    at_half = tuple(screw.growth_mm(r, half) for r in REFS)
    t1 = _work(screw, swept, zone, half, 600.0)
    after = tuple(screw.growth_mm(r, t1) for r in REFS)
    x = sample_mm(TRAVEL)
    truth = np.array([screw.growth_mm(v, t1) for v in x])
    shaped = Drift(REFS, before, after, TRAVEL, shape_before, tuple(swept.shape(SPREAD_MM)))
    linear = Drift(REFS, before, after)
    err_shaped = np.abs(shaped.at(x, np.ones(x.size)) - truth).max()
    err_linear = np.abs(linear.at(x, np.ones(x.size)) - truth).max()
    assert err_linear > 2e-3  # a bow of micrometres: what a line through the refs leaves
    assert err_shaped < err_linear / 8, (err_shaped, err_linear)
    # halfway: the shapes read before and after, interpolated in the run's progress
    mid_truth = np.array([mid[v] for v in x])
    half_drift = Drift(REFS, before, at_half, TRAVEL, shape_before, shape_half)
    assert np.abs(half_drift.at(x, np.ones(x.size)) - mid_truth).max() < err_linear / 3
    # kept in the state file and read back the same
    again = Drift.from_json(shaped.to_json())
    halfway = np.full(x.size, 0.5)
    np.testing.assert_allclose(again.at(x, halfway), shaped.at(x, halfway))
    kept = SweptHeat.from_json(swept.to_json())
    assert kept.shape(SPREAD_MM) == pytest.approx(swept.shape(SPREAD_MM), rel=1e-4)


def test_a_drift_without_shapes_is_the_straight_line() -> None:
    """A Drift read from an older state file (no shapes), or before the axis moved, is the
    straight line through the references."""
    x = np.linspace(0.0, 600.0, 61)
    line = Drift(REFS, (0.0, 0.0), (1e-3, 5e-3))
    expected = 1e-3 + 4e-3 * (x - REFS[0]) / (REFS[1] - REFS[0])
    np.testing.assert_allclose(line.at(x, np.ones(x.size)), expected)
    assert Drift.from_json(line.to_json()) == line
    cold = SweptHeat.for_travel(TRAVEL, MEMORY_S)  # nothing swept yet: W flat, no shape
    w = tuple(cold.shape(SPREAD_MM))
    flat = Drift(REFS, (0.0, 0.0), (1e-3, 5e-3), TRAVEL, w, w)
    np.testing.assert_allclose(flat.at(x, np.ones(x.size)), expected)
