"""The cyclic (once-per-lead) stage: exact forward/inverse, chain integration, its file."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st
from scipy.optimize import brentq

from gateway.compensation import (
    AxisChain,
    AxisInput,
    Chain,
    CyclicModel,
    CyclicStage,
    PitchStage,
    PitchTable,
    TableError,
)
from gateway.formats import read_cyclic, write_cyclic

PULSE_MM = 0.001


@st.composite
def cyclic_models(draw):
    lead = draw(st.sampled_from([4.0, 5.0, 10.0, 16.0, 20.0, 40.0]))
    k = draw(st.integers(1, 3))
    n = draw(st.integers(1, 4))
    stations = np.sort(np.array(draw(st.lists(st.floats(0, 800), min_size=n, max_size=n,
                                              unique=True))))
    assume(np.all(np.diff(stations) >= lead))  # a model that loads: a lead apart at least
    amp = st.lists(st.lists(st.floats(-0.003, 0.003), min_size=k, max_size=k),
                   min_size=n, max_size=n)
    origin = draw(st.floats(-5, 5))
    return CyclicModel(lead, stations, np.array(draw(amp)), np.array(draw(amp)), origin)


@settings(max_examples=80, deadline=None)
@given(model=cyclic_models(), data=st.data())
def test_round_trip_within_half_pulse_both_directions(model, data):
    table = PitchTable(np.linspace(0, 800, 17), np.linspace(0, 0.02, 17),
                       np.linspace(0.01, 0.03, 17))
    axis = AxisChain("X", PULSE_MM, pitch=PitchStage(table), cyclic=CyclicStage(model, (0, 800)),
                     travel_mm=(0, 800))
    chain = Chain({"X": axis})
    for _ in range(10):
        nominal = data.draw(st.integers(0, 800_000))
        direction = data.draw(st.sampled_from([1, -1]))
        command = chain.command_pulses("X", {"X": AxisInput(nominal, direction)})
        back = chain.nominal_pulses("X", {"X": AxisInput(command, direction)})
        assert abs(back - nominal) <= 0.51
        exact = axis.actual_mm(axis.command_mm(nominal * PULSE_MM, direction), direction)
        assert abs(float(exact) - nominal * PULSE_MM) < 1e-9


def test_stations_closer_than_one_lead_are_refused():
    """A dense scan spans two leads or more: amplitudes that change within one turn of the
    screw are a broken file (they would make the correction steeper than the pulse grid)."""
    with pytest.raises(TableError, match=r"x.yaml: stations 0 and 0.03125 mm are closer "
                                         r"than one lead \(4 mm\)"):
        CyclicModel(4.0, np.array([0.0, 0.03125, 100.0]), np.full((3, 1), 0.001),
                    np.zeros((3, 1)), source="x.yaml")
    CyclicModel(4.0, np.array([0.0, 4.0]), np.full((2, 1), 0.001), np.zeros((2, 1)))


def test_forward_matches_root_finding_on_the_model():
    model = CyclicModel(10.0, np.array([100.0, 700.0]), np.array([[0.0015, 0.0003], [0.001, 0.0]]),
                        np.array([[0.0005, 0.0], [0.0012, -0.0002]]), origin_mm=2.5)
    stage = CyclicStage(model, (0.0, 800.0))
    for target in np.linspace(0.5, 799.5, 157):
        expected = brentq(lambda c, p=target: c + float(model.error_mm(c)) - p,
                          target - 1, target + 1, xtol=1e-12)
        assert stage.forward_scalar(target) == pytest.approx(expected, abs=5e-6)
        assert float(stage.forward(target)) == pytest.approx(expected, abs=5e-6)


def test_the_model_is_a_once_per_lead_sinusoid():
    model = CyclicModel(10.0, np.array([0.0]), np.array([[0.002]]), np.array([[0.0]]))
    x = np.array([0.0, 2.5, 5.0, 7.5, 10.0, 12.5])
    np.testing.assert_allclose(model.error_mm(x), [0, 0.002, 0, -0.002, 0, 0.002], atol=1e-15)
    assert model.peak_mm() == pytest.approx(0.002)


def test_amplitudes_interpolate_between_stations_and_hold_beyond():
    model = CyclicModel(10.0, np.array([100.0, 300.0]), np.array([[0.001], [0.003]]),
                        np.array([[0.0], [0.0]]))
    a, _ = model.amplitudes_mm(np.array([0.0, 100.0, 200.0, 300.0, 800.0]))
    np.testing.assert_allclose(a[:, 0], [0.001, 0.001, 0.002, 0.003, 0.003])


def test_file_round_trip_and_bad_files(tmp_path: Path):
    model = CyclicModel(10.0, np.array([100.0, 400.0]), np.array([[0.00075, 5e-5], [0.0007, 4e-5]]),
                        np.array([[0.0013, -2e-5], [0.00125, -1e-5]]), origin_mm=1.0)
    write_cyclic(tmp_path / "c.yaml", model, extra={"fitted": "test"})
    back = read_cyclic(tmp_path / "c.yaml")
    np.testing.assert_allclose(back.sin_mm, model.sin_mm, atol=1e-10)
    np.testing.assert_allclose(back.cos_mm, model.cos_mm, atol=1e-10)
    assert back.lead_mm == 10.0 and back.origin_mm == 1.0
    (tmp_path / "bad.yaml").write_text(
        "lead_mm: 10\nstations:\n  - {position_mm: 1, sin_um: [1]}\n")
    with pytest.raises(TableError, match=r"bad\.yaml: stations\.0: needs position_mm, sin_um"):
        read_cyclic(tmp_path / "bad.yaml")
    (tmp_path / "bad2.yaml").write_text(
        "lead_mm: 0\nstations:\n  - {position_mm: 1, sin_um: [1], cos_um: [0]}\n")
    with pytest.raises(TableError, match=r"bad2\.yaml: lead_mm 0\.0 must be > 0"):
        read_cyclic(tmp_path / "bad2.yaml")
    # amplitudes in mm by mistake: the axis would run backwards
    huge = CyclicModel(1.0, np.array([0.0]), np.array([[0.5]]), np.array([[0.0]]), source="x")
    with pytest.raises(TableError, match="run backwards"):
        CyclicStage(huge, (0.0, 10.0))
