"""Swing axes and turntables in the compensation engine (issue 16): the linkage stage, its
fit by least squares, tables that do not wrap, the worm term modulo 360, tables in degrees
from raw data, and interpolation chosen by cross-validation."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from gateway.calibration.fitting.fit import as_axis_table
from gateway.calibration.fitting.linkage_fit import fit_linkage, residual_deviations
from gateway.calibration.fitting.table_cv import choose_interpolation
from gateway.calibration.plans.rawdata import AxisDeviations
from gateway.compensation import (
    AxisChain,
    CyclicModel,
    CyclicStage,
    LinkageModel,
    LinkageStage,
    PitchStage,
    PitchTable,
    TableError,
)
from gateway.config import ConfigError, parse_config
from gateway.demos.seed003 import axis_data, gateway_data
from gateway.formats import read_linkage, write_linkage

TRUE = LinkageModel(arm_mm=150.0, base_mm=450.0, phi0_deg=74.4, mm_per_deg=2.59144,
                    offset_mm=10.0, zero_deg=0.0)  # fmt: skip
DRAWING = LinkageModel(arm_mm=150.0, base_mm=451.0, phi0_deg=75.2, mm_per_deg=2.59,
                       offset_mm=10.0, zero_deg=0.0)  # fmt: skip
TRAVEL = (-14.5, 13.5)


def test_linkage_stage_is_exact_both_ways_scalar_and_vector():
    stage = LinkageStage(TRUE, TRAVEL)
    theta = np.linspace(*TRAVEL, 271)
    cmd = stage.forward(theta)
    np.testing.assert_allclose(stage.inverse(cmd), theta, rtol=0, atol=1e-10)
    for t, c in zip(theta[::27], cmd[::27]):
        assert abs(stage.forward_scalar(float(t)) - c) < 1e-10
        assert abs(stage.inverse_scalar(float(c)) - t) < 1e-10
    # the law of cosines by hand at one angle
    a, b, e, phi = 150.0, 450.0, 10.0, math.radians(74.4 + 5.0)
    nut = math.sqrt(a * a + b * b - 2 * a * b * math.cos(phi) - e * e)
    nut0 = math.sqrt(a * a + b * b - 2 * a * b * math.cos(math.radians(74.4)) - e * e)
    assert abs(stage.forward_scalar(5.0) - (nut - nut0) / 2.59144) < 1e-12
    assert 0.05 < stage.max_abs_correction_mm() < 0.15


def test_linkage_refuses_a_geometry_that_does_not_close_or_run_steadily():
    with pytest.raises(TableError, match=r"angle MAN leaves 0\.\.180"):
        LinkageStage(TRUE.with_values(phi0_deg=175.0), TRAVEL)
    with pytest.raises(TableError, match="offset_mm 400 must be >= 0 and below"):
        TRUE.with_values(offset_mm=400.0)
    with pytest.raises(TableError, match="mm_per_deg must be > 0"):
        TRUE.with_values(mm_per_deg=-1.0)


def test_fit_recovers_the_linkage_from_measured_angles():
    """From the drawing's values (base +1 mm, phi0 +0.8 deg, scale 0.06 % off), angles measured
    with 0.1" noise: the fitted model predicts the true one to 0.05" everywhere."""
    rng = np.random.default_rng(7)
    c = np.arange(-14.0, 13.01, 0.25)
    measured = TRUE.actual_deg(c) + rng.normal(0, 0.1 / 3600, c.size)
    fit = fit_linkage(c, measured, DRAWING)
    assert fit.start_rms_deg > 20 * fit.rms_deg
    grid = np.linspace(-14.5, 13.5, 500)
    assert np.abs(fit.model.actual_deg(grid) - TRUE.actual_deg(grid)).max() < 0.05 / 3600
    assert fit.model.arm_mm == 150.0 and fit.model.offset_mm == 10.0  # not fitted


def test_table_before_the_linkage_reproduces_the_readings_at_the_points():
    """Chain: target → residual table (at the model's angles) → linkage → command; at each
    measured command the chain's inverse gives the measured angle, per direction."""
    c = np.arange(-14.0, 13.01, 0.5)
    screw = 2e-4 * np.sin(c)  # what the kinematics leave
    lash = 4e-4
    up = (TRUE.actual_deg(c) + screw - c)[:, None]
    down = up + lash
    dev = AxisDeviations("A", c, np.array([1]), up, down)
    model = fit_linkage(c, c + up[:, 0] + lash / 2, DRAWING).model
    rest = residual_deviations(dev, model)
    table = PitchTable(rest.target_mm, rest.up_mm[:, 0], rest.down_mm[:, 0], rotary=True)
    chain = AxisChain("A", 1e-4, pitch=PitchStage(table, "smooth", wrap=False), rotary=True,
                      linkage=LinkageStage(model, TRAVEL))  # fmt: skip
    for direction, values in ((1, up[:, 0]), (-1, down[:, 0])):
        np.testing.assert_allclose(chain.actual_mm(c, direction), c + values, atol=1e-12)
        back = chain.command_mm(c + values, direction)
        np.testing.assert_allclose(back, c, atol=1e-9)


def test_swing_tables_do_not_wrap_and_turntable_tables_do():
    pos = np.array([-14.0, -7.0, 0.0, 6.5, 13.0])
    swing = PitchStage(PitchTable(pos, np.array([1, 2, 0, -1, 3]) * 1e-3, rotary=True),
                       wrap=False)  # fmt: skip
    assert swing.forward_scalar(-20.0, 1) == pytest.approx(-20.0 - 1e-3)  # held, no wrap
    with pytest.raises(TableError, match=r"a turntable's table .* must lie in 0\.\.360"):
        PitchStage(PitchTable(pos, np.zeros(5), rotary=True))
    with pytest.raises(TableError, match=r"rotary table positions must lie in -360\.\.360"):
        PitchTable(np.array([0.0, 400.0]), np.zeros(2), rotary=True)
    table = PitchTable(np.array([0.0, 90.0, 180.0, 270.0]), np.array([1, 2, 3, 4]) * 1e-3,
                       rotary=True)  # fmt: skip
    turn = PitchStage(table)
    for angle in (45.0, 315.0, 359.5):
        for k in (-3, 1, 2):
            assert turn.forward_scalar(angle + 360 * k, 1) == pytest.approx(
                turn.forward_scalar(angle, 1) + 360 * k, abs=1e-12)


def test_worm_term_modulo_360_is_continuous_across_the_wrap():
    model = CyclicModel(5.0, np.array([54.0, 180.0, 306.0]), np.array([[3.0], [2.0], [3.5]]) / 3600,
                        np.array([[0.5], [0.0], [-0.5]]) / 3600)  # fmt: skip
    stage = CyclicStage(model, (-1080.0, 1080.0), 360.0)
    for angle in (0.0, 1.3, 359.99):
        assert stage.forward_scalar(angle + 720.0) == pytest.approx(
            stage.forward_scalar(angle) + 720.0, abs=1e-12)
    ends = [stage.inverse_scalar(v) - v for v in (359.9999999, 360.0000001)]
    assert abs(ends[0] - ends[1]) < 1e-9  # no step at 360
    with pytest.raises(TableError, match="not a whole fraction of a turn"):
        CyclicStage(CyclicModel(7.0, np.array([0.0]), np.array([[1e-4]]), np.array([[0.0]])),
                    (0.0, 360.0), 360.0)  # fmt: skip


def test_turntable_readings_of_several_turns_make_one_table():
    raw = PitchTable(np.array([0.0, 90.0, 360.0, 450.0, 700.0]),
                     np.array([1.0, 2.0, 3.0, 4.0, 5.0]), np.array([2.0, 3, 4, 5, 6]))
    table = as_axis_table(raw, rotary=True, wrap=True)
    np.testing.assert_allclose(table.position_mm, [0.0, 90.0, 340.0])
    np.testing.assert_allclose(table.forward_mm, [2.0, 3.0, 5.0])
    np.testing.assert_allclose(table.reverse_mm, [3.0, 4.0, 6.0])
    assert table.rotary


def test_cross_validation_prefers_a_spline_on_a_smooth_map_only():
    x = np.arange(-14.0, 13.01, 1.0)
    smooth = PitchTable(x, 1e-3 * np.cos(x / 5.0), rotary=True)
    assert choose_interpolation(smooth)[0] == "smooth"
    rng = np.random.default_rng(3)
    rough = PitchTable(x, 1e-3 * rng.normal(size=x.size), rotary=True)
    best, scores = choose_interpolation(rough)
    assert best != "smooth" and scores["smooth"] > scores["linear"]


def test_config_swing_axis_and_linkage_file(tmp_path: Path):
    write_linkage(tmp_path / "a.yaml", DRAWING, "from the drawing")
    assert read_linkage(tmp_path / "a.yaml").values() == DRAWING.values()
    ok = gateway_data(5021, {"A": axis_data(1, TRAVEL, False, {"linkage": "a.yaml"})})
    config = parse_config(ok, "x.yaml")
    assert config.axes["A"].rotary and not config.axes["A"].wraps
    bad = gateway_data(5021, {"A": axis_data(1, TRAVEL, True, {"linkage": "a.yaml"})})
    with pytest.raises(ConfigError, match=r"axes\.A\.compensation\.linkage: 'a\.yaml' needs a "
                                          r"swing axis \(rotary: true, wrap: false\)"):
        parse_config(bad, "x.yaml")
    linear = gateway_data(5021, {"A": {**axis_data(1, TRAVEL, False), "rotary": False}})
    with pytest.raises(ConfigError, match=r"axes\.A\.wrap: False needs rotary: true"):
        parse_config(linear, "x.yaml")
    (tmp_path / "b.yaml").write_text("arm_mm: 150\nbase_mm: 450\nphi0_deg: x\nmm_per_deg: 2\n")
    with pytest.raises(TableError, match=r"b\.yaml: phi0_deg: 'x' is not a number"):
        read_linkage(tmp_path / "b.yaml")
