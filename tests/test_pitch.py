"""Pitch tables: exactness, interpolation, outside rules, rotary wrap, safety checks.

Expected values are computed another way (root finding on the raw table with scipy), never by
calling the stage under test twice.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.interpolate import CubicSpline
from scipy.optimize import brentq

from gateway.compensation import (
    AxisChain,
    AxisInput,
    Chain,
    PitchStage,
    PitchTable,
    TableError,
)

PULSE_MM = 0.001


def _solve_command(error_fn, target_mm: float) -> float:
    """Reference: the command c with c + e(c) = target, by bracketing root finding."""
    return brentq(lambda c: c + error_fn(c) - target_mm, target_mm - 1.0, target_mm + 1.0,
                  xtol=1e-13)


@st.composite
def linear_tables(draw, rotary: bool = False):
    n = draw(st.integers(min_value=2, max_value=40))
    span = 360.0 if rotary else draw(st.floats(min_value=10.0, max_value=2000.0))
    gaps = np.array(draw(st.lists(st.floats(0.2, 5.0), min_size=n - 1, max_size=n - 1)))
    pos = np.concatenate([[0.0], np.cumsum(gaps)])
    pos = pos / pos[-1] * (span * (0.999 if rotary else 1.0))
    start = 0.0 if rotary else draw(st.floats(min_value=-500.0, max_value=500.0))
    values = lambda: np.array(  # noqa: E731
        draw(st.lists(st.floats(-0.08, 0.08), min_size=n, max_size=n))
    )
    fwd = values()
    rev = values() if draw(st.booleans()) else None
    return PitchTable(pos + start, fwd, rev, rotary=rotary)


def _max_slope(stage: PitchStage) -> float:
    return max(
        float(np.abs(np.diff(m.e_mm) / np.diff(m.x_mm)).max())
        for m in (stage.forward_map, stage.reverse_map)
    )


@pytest.mark.filterwarnings("ignore::RuntimeWarning")
@settings(max_examples=150, deadline=None)
@given(
    table=linear_tables(),
    interpolation=st.sampled_from(["linear", "smooth", "pchip"]),
    outside=st.sampled_from(["hold", "taper"]),
    fraction=st.floats(-0.2, 1.2),
    direction=st.sampled_from([1, -1]),
)
def test_round_trip_within_half_pulse(table, interpolation, outside, fraction, direction):
    """inverse(forward(n)) = n: exactly before rounding, within half a pulse after it.

    Rounding the command to a whole pulse moves the reported nominal by at most half a
    pulse times the local scale 1/(1 + de/dx), which differs from 1 by the table's slope.
    """
    try:
        stage = PitchStage(table, interpolation, outside, taper_mm=25.0)
    except TableError:
        return  # a random spline may overshoot into a non-monotone map: refusing is right
    pos = table.position_mm
    nominal_mm = pos[0] + fraction * (pos[-1] - pos[0])
    nominal = round(nominal_mm / PULSE_MM)
    axis = AxisChain("X", PULSE_MM, pitch=stage)
    chain = Chain({"X": axis})
    command = chain.command_pulses("X", {"X": AxisInput(nominal, direction)})
    back = chain.nominal_pulses("X", {"X": AxisInput(command, direction)})
    slope = _max_slope(stage)
    assert abs(back - nominal) <= 0.5 / (1 - min(slope, 0.99)) + 1e-9
    if slope < 1e-3:  # every real screw: the bound is half a pulse to 1 part in 1000
        assert abs(back - nominal) <= 0.5005
    exact = axis.actual_mm(axis.command_mm(nominal_mm, direction), direction)
    assert abs(float(exact) - nominal_mm) < 1e-9


@settings(max_examples=60, deadline=None)
@given(
    table=linear_tables(rotary=True),
    turns=st.integers(-3, 3),
    angle=st.floats(0.0, 360.0, exclude_max=True),
    direction=st.sampled_from([1, -1]),
    interpolation=st.sampled_from(["linear", "smooth"]),
)
def test_rotary_round_trip_across_wrap(table, turns, angle, direction, interpolation):
    pulse_deg = 0.001
    fwd = table.forward_mm.copy()
    rev = None if table.reverse_mm is None else table.reverse_mm.copy()
    if table.position_mm[-1] == 360.0:
        fwd[-1] = fwd[0]
        if rev is not None:
            rev[-1] = rev[0]
    table = PitchTable(table.position_mm, fwd, rev, rotary=True)
    try:
        stage = PitchStage(table, interpolation)
    except TableError:
        return
    chain = Chain({"C": AxisChain("C", pulse_deg, pitch=stage, rotary=True)})
    nominal = round((turns * 360.0 + angle) / pulse_deg)
    command = chain.command_pulses("C", {"C": AxisInput(nominal, direction)})
    back = chain.nominal_pulses("C", {"C": AxisInput(command, direction)})
    assert abs(back - nominal) <= 0.5 / (1 - min(_max_slope(stage), 0.99)) + 1e-9
    exact = chain.axes["C"].actual_mm(chain.axes["C"].command_mm(nominal * pulse_deg, direction),
                                      direction)
    assert abs(float(exact) - nominal * pulse_deg) < 1e-9


def test_rotary_is_periodic_and_continuous_across_360():
    pos = np.array([0.0, 90.0, 180.0, 270.0])
    dev = np.array([0.004, -0.002, 0.001, -0.003])  # degrees
    stage = PitchStage(PitchTable(pos, dev, rotary=True))
    # the error between 270 and 360 interpolates towards the value at 0 (= 360)
    e = stage.inverse(np.array([315.0, 359.999, 360.0, 720.0, -45.0]), 1) - np.array(
        [315.0, 359.999, 360.0, 720.0, -45.0]
    )
    assert e[0] == pytest.approx(0.5 * (-0.003 + 0.004), abs=1e-12)
    assert e[1] == pytest.approx(0.004, abs=1e-6)
    assert e[2] == pytest.approx(0.004, abs=1e-12)
    assert e[3] == pytest.approx(0.004, abs=1e-12)
    assert e[4] == pytest.approx(e[0], abs=1e-12)


def test_linear_matches_reference_root_finding():
    rng = np.random.default_rng(7)
    pos = np.linspace(0, 800, 17)
    fwd = rng.normal(0, 0.01, pos.size)
    rev = fwd + 0.012
    stage = PitchStage(PitchTable(pos, fwd, rev))
    for target in rng.uniform(-50, 850, 200):
        for direction, values in ((1, fwd), (-1, rev)):
            expected = _solve_command(lambda c, v=values: np.interp(c, pos, v), target)
            assert stage.forward_scalar(target, direction) == pytest.approx(expected, abs=1e-9)
            assert float(stage.forward(target, direction)) == pytest.approx(expected, abs=1e-9)


def test_smooth_matches_scipy_spline_reference():
    pos = np.linspace(0, 600, 13)
    dev = 0.02 * np.sin(pos / 90.0) + 1e-5 * pos
    stage = PitchStage(PitchTable(pos, dev), "smooth")
    spline = CubicSpline(pos, dev)
    for target in np.linspace(1, 599, 97):
        expected = _solve_command(lambda c: float(spline(np.clip(c, 0, 600))), target)
        assert stage.forward_scalar(target, 1) == pytest.approx(expected, abs=2e-7)


def test_smooth_beats_linear_off_grid_and_both_exact_at_points():
    """A known smooth error sampled at N points: off-grid, the spline predicts better."""
    truth = lambda x: 0.015 * np.sin(2 * np.pi * x / 700) + 0.004 * np.cos(2 * np.pi * x / 260)  # noqa: E731
    pos = np.linspace(0, 800, 21)
    table = PitchTable(pos, truth(pos))
    off = np.linspace(0, 800, 2001)
    off = off[~np.isin(off, pos)]
    rms = {}
    for kind in ("linear", "smooth", "pchip"):
        stage = PitchStage(table, kind)
        predicted = stage.inverse(off, 1) - off
        rms[kind] = float(np.sqrt(np.mean((predicted - truth(off)) ** 2)))
        at_points = stage.inverse(pos, 1) - pos
        np.testing.assert_allclose(at_points, truth(pos), atol=1e-12)
    assert rms["smooth"] < 0.5 * rms["linear"], rms


def test_outside_hold_and_taper():
    table = PitchTable(np.array([100.0, 200.0]), np.array([0.01, 0.02]))
    hold = PitchStage(table)
    taper = PitchStage(table, outside="taper", taper_mm=50.0)
    assert float(hold.inverse(0.0, 1)) == pytest.approx(0.01)
    assert float(hold.inverse(300.0, 1)) == pytest.approx(300.02)
    assert float(taper.inverse(75.0, 1)) == pytest.approx(75.005)
    assert float(taper.inverse(40.0, 1)) == pytest.approx(40.0)
    assert float(taper.inverse(225.0, 1)) == pytest.approx(225.01)
    assert float(taper.inverse(400.0, 1)) == pytest.approx(400.0)


def test_up_to_4096_points_and_not_more():
    pos = np.arange(4096) * 0.2
    PitchStage(PitchTable(pos, np.zeros(4096)))
    with pytest.raises(TableError, match="4097 points"):
        PitchTable(np.arange(4097) * 0.2, np.zeros(4097), source="big.csv")


def test_non_monotone_table_is_refused_naming_the_point():
    pos = np.array([0.0, 10.0, 20.0, 30.0])
    dev = np.array([0.0, 0.0, 15.0, 0.0])  # 15 mm "error" in 10 mm: the axis would reverse
    table = PitchTable(pos, dev, source="x.csv", lines=(3, 4, 5, 6))
    with pytest.raises(TableError, match=r"x\.csv: line 6 \(position 30 mm\).*not strictly"):
        PitchStage(table)


def test_cap_is_checked_naming_the_point():
    table = PitchTable(
        np.array([0.0, 100.0, 200.0]), np.array([0.0, 0.25, 0.0]), source="x.csv", lines=(2, 3, 4)
    )
    with pytest.raises(TableError, match=r"x\.csv: line 3 \(position 100 mm\).*max_correction_mm"):
        PitchStage(table).check_cap(0.2)


@pytest.mark.parametrize(
    ("positions", "values", "message"),
    [
        ([0.0, 0.0, 1.0], [0, 0, 0], "increase by at least"),
        ([0.0, 2.0, 1.0], [0, 0, 0], "increase by at least"),
        ([0.0, np.nan, 1.0], [0, 0, 0], "position value is not a finite"),
        ([0.0, 1.0, 2.0], [0, np.inf, 0], "forward value is not a finite"),
        ([0.0], [0], "at least 2 points"),
    ],
)
def test_bad_tables_are_refused(positions, values, message):
    with pytest.raises(TableError, match=message):
        PitchTable(np.array(positions, dtype=float), np.array(values, dtype=float))
