"""The full chain: pitch + backlash + planar + thermal, forward and inverse, both paths."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from gateway.compensation import (
    AxisChain,
    AxisInput,
    BacklashStage,
    Chain,
    CompensationError,
    CorrectionLimitError,
    GridModel,
    PitchStage,
    PitchTable,
    PlanarMeasurement,
    PlanarStage,
    PolyModel,
    TableError,
    ThermalStage,
    TravelError,
    delta_a_from_temperature,
    pulse_equivalent_mm,
    pulses_for_travel,
)

PULSE_MM = 0.001
X_TRAVEL = (0.0, 800.0)
Y_TRAVEL = (0.0, 600.0)


@st.composite
def realistic_pitch(draw, travel, bidirectional):
    """A random-walk deviation table with slopes a real screw has (≤ 2e-4)."""
    n = draw(st.integers(3, 60))
    pos = np.linspace(travel[0], travel[1], n)
    step = np.diff(pos)[0]
    walk = np.array(draw(st.lists(st.floats(-2e-4, 2e-4), min_size=n, max_size=n))) * step
    fwd = np.cumsum(walk) - walk[0]
    rev = None
    if bidirectional:
        rev = fwd + draw(st.floats(0.0, 0.02))
    return PitchTable(pos, fwd, rev)


@st.composite
def planar_models(draw):
    gx, gy = np.meshgrid(np.linspace(0, 800, 9), np.linspace(0, 600, 7))
    cmd = np.column_stack([gx.ravel(), gy.ravel()])
    squareness = draw(st.floats(-50, 50)) / 206265.0
    coeff = np.array(draw(st.lists(st.floats(-3e-5, 3e-5), min_size=4, max_size=4)))
    wave = draw(st.floats(0, 0.005))
    err = np.column_stack(
        [
            squareness * cmd[:, 1] + coeff[0] * cmd[:, 0] + wave * np.sin(cmd[:, 1] / 97.0),
            coeff[1] * cmd[:, 1] + coeff[2] * cmd[:, 0] + 1e-8 * cmd[:, 0] * cmd[:, 1] * coeff[3],
        ]
    )
    meas = PlanarMeasurement(cmd, cmd + err)
    kind = draw(st.sampled_from(["grid-cubic", "grid-linear", "poly"]))
    if kind == "poly":
        return PolyModel.fit(meas)
    return GridModel.from_measurement(meas, kind.split("-")[1])


def _machine(x_table, y_table, model, backlash_mm, bidirectional):
    def axis(name, table, travel):
        return AxisChain(
            name,
            PULSE_MM,
            pitch=PitchStage(table, "smooth"),
            backlash=None if bidirectional else BacklashStage(backlash_mm),
            thermal=ThermalStage(length_mm=travel[1], origin_mm=0.0),
            travel_mm=travel,
            max_correction_mm=0.5,
        )

    return Chain(
        {"X": axis("X", x_table, X_TRAVEL), "Y": axis("Y", y_table, Y_TRAVEL)},
        PlanarStage(model),
    )


@settings(max_examples=80, deadline=None)
@given(
    bidirectional=st.booleans(),
    data=st.data(),
    model=planar_models(),
    backlash_mm=st.floats(0.0, 0.02),
    delta_a_mm=st.floats(0.0, 0.03),
)
def test_full_chain_round_trip_within_half_pulse(bidirectional, data, model, backlash_mm,
                                                 delta_a_mm):
    x_table = data.draw(realistic_pitch(X_TRAVEL, bidirectional))
    y_table = data.draw(realistic_pitch(Y_TRAVEL, bidirectional))
    chain = _machine(x_table, y_table, model, backlash_mm, bidirectional)
    for _ in range(5):
        x = data.draw(st.integers(0, 800_000))
        y = data.draw(st.integers(0, 600_000))
        dx, dy = data.draw(st.sampled_from([1, -1])), data.draw(st.sampled_from([1, -1]))
        nominal = {"X": AxisInput(x, dx, delta_a_mm), "Y": AxisInput(y, dy, delta_a_mm)}
        cx = chain.command_pulses("X", nominal)
        cy = chain.command_pulses("Y", nominal)
        drive = {"X": AxisInput(cx, dx, delta_a_mm), "Y": AxisInput(cy, dy, delta_a_mm)}
        assert abs(chain.nominal_pulses("X", drive) - x) <= 0.502
        assert abs(chain.nominal_pulses("Y", drive) - y) <= 0.502
        # the batch path agrees with the scalar path to the pulse
        batch = chain.command_pulses_batch(
            {"X": [x], "Y": [y]}, {"X": [dx], "Y": [dy]}, {"X": delta_a_mm, "Y": delta_a_mm}
        )
        assert (int(batch["X"][0]), int(batch["Y"][0])) == (cx, cy)


def test_backlash_convention_by_direction():
    mean = BacklashStage(0.012)
    fwd = BacklashStage(0.012, "forward")
    rev = BacklashStage(0.012, "reverse")
    assert mean.forward_scalar(100.0, 1) == pytest.approx(100.006)
    assert mean.forward_scalar(100.0, -1) == pytest.approx(99.994)
    assert fwd.forward_scalar(100.0, 1) == pytest.approx(100.0)
    assert fwd.forward_scalar(100.0, -1) == pytest.approx(99.988)
    assert rev.forward_scalar(100.0, 1) == pytest.approx(100.012)
    assert rev.forward_scalar(100.0, -1) == pytest.approx(100.0)
    np.testing.assert_allclose(mean.forward([1.0, 1.0], [1, -1]), [1.006, 0.994])
    with pytest.raises(CompensationError, match="backlash_mm"):
        BacklashStage(-0.001)


def test_bidirectional_table_with_backlash_is_a_config_error_unless_allowed():
    table = PitchTable(np.array([0.0, 100.0]), np.zeros(2), np.full(2, 0.01))
    with pytest.raises(CompensationError, match="already contains backlash"):
        AxisChain("X", PULSE_MM, pitch=PitchStage(table), backlash=BacklashStage(0.01))
    AxisChain(
        "X",
        PULSE_MM,
        pitch=PitchStage(table),
        backlash=BacklashStage(0.01),
        allow_backlash_with_bidirectional=True,
    )


def test_thermal_pulse_equivalent_matches_seed_002():
    # C = 0.001 mm/pulse, reference length a = 500 mm grew by Δa = 0.02 mm
    c1 = pulse_equivalent_mm(0.001, 500.0, 0.02)
    assert c1 == pytest.approx(0.001 * 500.02 / 500.0, rel=1e-15)
    assert float(pulses_for_travel(300.0, c1)) == pytest.approx(300.0 / c1)
    # the stage with origin 0 gives exactly n1 = y / C1
    stage = ThermalStage(length_mm=500.0)
    command_mm = float(stage.forward(300.0, 0.02))
    assert command_mm / 0.001 == pytest.approx(300.0 / c1, rel=1e-12)
    # growth proportional from the fixed end: a point at the origin does not move
    shifted = ThermalStage(length_mm=500.0, origin_mm=100.0)
    assert float(shifted.forward(100.0, 0.02)) == pytest.approx(100.0)
    assert delta_a_from_temperature(11.5e-6, 500.0, 25.0, 20.0) == pytest.approx(0.02875)


def test_travel_and_correction_limits_refuse_the_command():
    table = PitchTable(np.array([0.0, 800.0]), np.array([0.0, 0.05]))
    axis = AxisChain("X", PULSE_MM, pitch=PitchStage(table), travel_mm=X_TRAVEL,
                     max_correction_mm=0.2)
    chain = Chain({"X": axis})
    with pytest.raises(TravelError, match=r"axis X: target 800.001 mm is outside travel_mm"):
        chain.command_pulses("X", {"X": AxisInput(800_001)})
    with pytest.raises(CorrectionLimitError, match="exceeds max_correction_mm"):
        # a Δa that is absurd for the screw gives a correction above the cap
        chain_hot = Chain({"X": AxisChain("X", PULSE_MM, thermal=ThermalStage(800.0),
                                          max_correction_mm=0.2)})
        chain_hot.command_pulses("X", {"X": AxisInput(700_000, 1, 0.5)})


def test_check_limits_names_axis_and_position():
    table = PitchTable(np.array([0.0, 400.0, 800.0]), np.array([0.0, 0.1, 0.0]))
    axis = AxisChain("X", PULSE_MM, pitch=PitchStage(table), backlash=BacklashStage(0.2),
                     travel_mm=X_TRAVEL, max_correction_mm=0.15)
    with pytest.raises(TableError, match=r"axes\.X\.compensation: correction 200\.0 µm at X=400"):
        Chain({"X": axis}).check_limits()


def test_planar_forward_iteration_reaches_a_hundredth_of_a_pulse():
    gx, gy = np.meshgrid(np.linspace(0, 800, 5), np.linspace(0, 600, 4))
    cmd = np.column_stack([gx.ravel(), gy.ravel()])
    sq = 30.0 / 206265.0
    meas = PlanarMeasurement(cmd, cmd + np.column_stack([sq * cmd[:, 1], 2e-5 * cmd[:, 1]]))
    stage = PlanarStage(GridModel.from_measurement(meas, "linear"))
    target = np.array([[400.0, 300.0], [10.0, 590.0], [900.0, -20.0]])  # last: outside, clamped
    command = stage.forward(target, tolerance_mm=1e-5)
    # reference by hand for this linear field: actual = c + (sq·cy, 2e-5·cy), cy clamped
    expected_y = target[:, 1] - 2e-5 * np.clip(target[:, 1] / (1 + 2e-5), 0, 600)
    np.testing.assert_allclose(command[:, 1], expected_y, atol=1e-5)
    np.testing.assert_allclose(
        command[:, 0], target[:, 0] - sq * np.clip(command[:, 1], 0, 600), atol=1e-5
    )


def test_poly_degree_chosen_by_cross_validation_and_exact_on_polynomials():
    rng = np.random.default_rng(3)
    cmd = rng.uniform([0, 0], [800, 600], size=(60, 2))
    truth = np.column_stack(
        [1e-5 * cmd[:, 0] + 4e-8 * cmd[:, 1] ** 2, -2e-5 * cmd[:, 0] + 1e-8 * cmd[:, 0] * cmd[:, 1]]
    )
    noisy = truth + rng.normal(0, 2e-4, truth.shape)
    model = PolyModel.fit(PlanarMeasurement(cmd, cmd + noisy))
    assert model.degree == 2, model.loo_rms_mm
    probe = rng.uniform(model.lower_mm, model.upper_mm, size=(200, 2))  # inside: no clamping
    expected = np.column_stack(
        [
            1e-5 * probe[:, 0] + 4e-8 * probe[:, 1] ** 2,
            -2e-5 * probe[:, 0] + 1e-8 * probe[:, 0] * probe[:, 1],
        ]
    )
    assert np.abs(model.error_mm(probe) - expected).max() < 2e-4


def test_planar_scattered_points_and_clamping():
    rng = np.random.default_rng(5)
    cmd = rng.uniform([0, 0], [800, 600], size=(40, 2))
    err = np.column_stack([1e-5 * cmd[:, 1], 1e-5 * cmd[:, 0]])
    model = GridModel.from_measurement(PlanarMeasurement(cmd, cmd + err))
    lo, hi = model.lower_mm, model.upper_mm
    inside = model.error_mm(np.array([0.5 * (lo + hi)]))
    assert np.abs(inside - 1e-5 * (0.5 * (lo + hi))[::-1]).max() < 1e-4
    edge = model.error_mm(np.array([[hi[0], hi[1]], [hi[0] + 500, hi[1] + 500]]))
    np.testing.assert_allclose(edge[0], edge[1])


def test_planar_field_too_steep_is_refused():
    gx, gy = np.meshgrid(np.linspace(0, 100, 3), np.linspace(0, 100, 3))
    cmd = np.column_stack([gx.ravel(), gy.ravel()])
    meas = PlanarMeasurement(cmd, cmd * 1.5, source="xy.csv")  # 50 % scale error: not a table
    with pytest.raises(TableError, match=r"xy\.csv: planar error field changes by 0\.5"):
        PlanarStage(GridModel.from_measurement(meas, "linear"), source="xy.csv")


def test_direction_follows_targets_and_starts_from_home_direction():
    from gateway.compensation import MotionState

    state = MotionState(-1)
    state = state.approach(1000)  # first target after homing: homing decided the flank
    assert state.direction == -1
    state = state.approach(2000)
    assert state.direction == 1
    state = state.approach(2000)  # same target: no reversal
    assert state.direction == 1
    assert state.approach(1500).direction == -1
    with pytest.raises(CompensationError, match="home_direction"):
        MotionState(0)


def test_a_target_on_the_travel_end_is_not_refused_for_float_rounding() -> None:
    """55800 pulses of 0.001 mm is 55.800000000000004 in floating point: still the end of
    travel [0, 55.8]; one pulse past it is refused."""
    axis = AxisChain("X", 0.001, travel_mm=(0.0, 55.8))
    assert 55800 * 0.001 > 55.8
    axis.check_travel(55800 * 0.001)
    axis.check_travel(0 * 0.001)
    with pytest.raises(TravelError):
        axis.check_travel(55801 * 0.001)
