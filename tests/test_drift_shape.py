"""The thermal drift between the two drift references (gateway.calibration.drift_shape,
adaptive.Drift), checked against the sim's screw: heat where the nut works, conducted along
the steel and lost to the air (sim.heat), never the gateway's own travel counts."""

# the spread and memory commissioning takes from a zone warm-up's fit (warmup_heat)

from __future__ import annotations

import numpy as np
import pytest

from gateway.calibration.adaptive import Drift
from gateway.calibration.drift_shape import SweptHeat, sample_mm
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


def _probes(growth, swept: SweptHeat, screw: ScrewHeatModel, scatter_um: float,
            seed: int = 5) -> list:  # type: ignore[no-untyped-def]
    """Middle readings beside the references while zones of the travel are worked in turn
    (a config switch every third reading), each read with ``scatter_um`` of noise; the
    truth ``growth(x_mm, t_s)`` (mm), the moves told to ``screw`` and ``swept``."""
    from gateway.calibration.drift_shape import PROBE_SPREADS_MM, MidProbe

    rng = np.random.default_rng(seed)
    x3 = (*REFS, 0.5 * (REFS[0] + REFS[1]))
    zones = [(0.0, 600.0), (60.0, 250.0), (300.0, 580.0), (0.0, 600.0), (400.0, 600.0),
             (100.0, 300.0)] * 2  # fmt: skip
    out, t = [], 0.0
    for k, zone in enumerate(zones):
        t = _work(screw, swept, zone, t, 400.0)
        g = [growth(x, t) for x in x3]
        noise = rng.normal(0.0, scatter_um * 1e-3, 3) * (1.0, 1.0, 1.0)
        w = {s: tuple(float(v) for v in np.interp(x3, sample_mm(TRAVEL), swept.shape(s)))
             for s in PROBE_SPREADS_MM}  # fmt: skip
        # the tables differ from one config to the next: the middle's own offset changes
        offset = 0.01 * (k // 3)
        out.append(MidProbe(f"config{k // 3}", x3, (g[0] + noise[0] / 3**0.5,
                                                   g[1] + noise[1] / 3**0.5),
                            offset + g[2] + noise[2], w))  # fmt: skip
    return out


def test_middle_readings_tell_a_screw_warm_where_it_works_from_an_evenly_warm_one() -> None:
    """A screw warm where its nut works (the sim's): its middle readings beside the
    references choose a heat shape, which predicts the middle's drift several times better
    than the straight line. An evenly warm screw (growth linear from its fixed end) keeps
    the line, and so does one whose growth is within the readings' scatter."""
    from gateway.calibration.drift_shape import choose_spread

    screw = _screw()
    probes = _probes(screw.growth_mm, SweptHeat.for_travel(TRAVEL, MEMORY_S), screw, 0.3)
    chosen = choose_spread(probes, 0.3)
    assert chosen is not None and chosen.pairs == 8, chosen
    assert chosen.spread_mm is not None, chosen.summary()
    assert chosen.sse_um2[chosen.spread_mm] < 0.25 * chosen.sse_um2[None], chosen.summary()

    def even(x: float, t: float) -> float:  # one temperature, rising and levelling off
        return 2e-5 * (1 - np.exp(-t / 1500.0)) * (x + 40.0)

    # the same zones worked (the travel counted as uneven), the screw evenly warm
    line = choose_spread(_probes(even, SweptHeat.for_travel(TRAVEL, MEMORY_S), _screw(), 0.3),
                         0.3)  # fmt: skip
    assert line is not None and line.spread_mm is None, line.summary()
    quiet = choose_spread(_probes(lambda x, t: 1e-4 * even(x, t),
                                  SweptHeat.for_travel(TRAVEL, MEMORY_S), _screw(), 0.3), 0.3)
    assert quiet is not None and quiet.spread_mm is None, quiet.summary()
