"""Commissioning's scans of the once-per-lead term (`planner.cyclic_scans`): seven one-way
stations reaching one lead from each end where the travel holds them (else a plain
calibration's three two-way scans), fewer readings than three two-way scans, and a
term that changes along the screw read closer."""

from __future__ import annotations

import numpy as np

from gateway.calibration.commissioning.planner import SCAN_STATIONS, cyclic_scans
from gateway.calibration.fitting.cyclic_fit import StationScan, fit_cyclic
from gateway.calibration.fitting.plans_scans import cyclic_plan
from gateway.calibration.plans.plans import Plan

LEAD_MM = 5.0
TRAVEL_MM = (0.0, 700.0)


def stations_mm(plan: Plan) -> list[float]:
    return [float(s) for s in dict(plan.meta)["stations_mm"].split()]


def test_seven_one_way_stations_reach_the_ends_in_fewer_readings_than_three_two_way():
    plan = cyclic_scans("X", TRAVEL_MM, LEAD_MM)
    assert stations_mm(plan) == [6.5, 121.0, 235.5, 350.0, 464.5, 579.0, 693.5]
    moves = [m for m in plan.moves if m.run in (1, 7)]
    assert min(min(m.target_mm) for m in moves) == 0.5  # a take-up move 0.5 mm inside
    assert max(max(m.target_mm) for m in moves) == 698.5  # (one way: none above a scan)
    measured = [m for m in plan.moves if m.role == "measure"]
    assert {m.direction for m in measured} == {1}
    plain = [m for m in cyclic_plan("X", TRAVEL_MM, LEAD_MM).moves if m.role == "measure"]
    assert len(measured) < len(plain)  # 175 against 198: no time from a plain calibration's


def test_a_travel_short_of_seven_scans_keeps_the_plain_calibrations_scans():
    # a scan with its take-up moves: 34 mm at a 16 mm lead, seven of them 238 mm
    assert cyclic_scans("Y", (0.0, 237.0), 16.0) == cyclic_plan("Y", (0.0, 237.0), 16.0)
    seven = cyclic_scans("Y", (0.0, 238.0), 16.0)
    assert len(stations_mm(seven)) == SCAN_STATIONS
    assert {m.direction for m in seven.moves if m.role == "measure"} == {1}


def true_term_um(x_mm: np.ndarray) -> np.ndarray:
    """A once-per-lead term whose amplitude and phase wander along the screw (as a worn or
    ground screw's do), not linearly between any three stations."""
    amp = 1.6 + 0.6 * np.sin(x_mm / 90.0)
    phase = np.radians(25.0) * np.cos(x_mm / 130.0)
    return amp * np.sin(2 * np.pi * x_mm / LEAD_MM + phase)


def fitted_miss_um(plan: Plan, seed: int) -> float:
    """RMS (µm) over the travel of the fitted term against the truth, the scans read with
    0.25 µm of noise, a local slope and 6 µm of lost motion."""
    rng = np.random.default_rng(seed)
    stations = stations_mm(plan)
    scans = []
    for j in range(1, len(stations) + 1):
        moves = [m for m in plan.moves if m.run == j and m.role == "measure"]
        x = np.array([m.target_mm[0] for m in moves])
        d = np.array([m.direction for m in moves])
        dev_um = true_term_um(x) + 0.02 * x - 3.0 * d + rng.normal(0.0, 0.25, x.size)
        scans.append(StationScan(x, dev_um * 1e-3, d.astype(np.int64)))
    fit = fit_cyclic(stations, scans, LEAD_MM)
    assert fit.model is not None
    x = np.linspace(0.0, 700.0, 4001)
    return float(np.sqrt(np.mean((fit.model.error_mm(x) * 1e3 - true_term_um(x)) ** 2)))


def test_a_term_that_changes_along_the_screw_is_read_closer_by_seven_one_way_scans():
    seven = [fitted_miss_um(cyclic_scans("X", TRAVEL_MM, LEAD_MM), s) for s in range(5)]
    three = [fitted_miss_um(cyclic_plan("X", TRAVEL_MM, LEAD_MM), s) for s in range(5)]
    assert max(seven) < 0.5 * min(three), (seven, three)  # 0.06-0.10 µm against 0.24-0.25
