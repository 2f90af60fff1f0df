"""Fitting tables from raw data of planned runs, and folding residuals (seed 001).

The machine here is a small numpy function written in this file (not the sim, not the
engine): true deviation e(x) plus lost motion L, landing at ``c + e(c) − d·L/2`` when
commanded to c approaching in direction d. The engine (PitchStage, BacklashStage) is what
the fitted tables are judged through.
"""

from __future__ import annotations

import numpy as np
import pytest

from gateway.calibration.fitting.fit import (
    bidirectional_table,
    fold_backlash,
    fold_residual,
    planar_measurement,
    unidirectional_table,
)
from gateway.calibration.fitting.iso230 import iso230_axis
from gateway.calibration.plans.plans import iso230_linear_plan, resume_index
from gateway.calibration.plans.rawdata import RawData, RawWriter, axis_deviations, read_raw_csv
from gateway.calibration.plans.xy import xy_grid_plan, xy_verification_plan
from gateway.compensation import BacklashStage, GridModel, PitchStage, PitchTable
from gateway.compensation.errors import TableError

TRAVEL = (0.0, 600.0)
LOST_MM = 0.012


def e_true(x):
    x = np.asarray(x, dtype=np.float64)
    return 0.02 * np.sin(2 * np.pi * x / 700.0) + 2e-5 * x + 0.002 * np.cos(x / 37.0)


def land(command_mm, direction):
    """Where the machine is after commanding ``command_mm`` approaching in ``direction``."""
    return command_mm + e_true(command_mm) - np.asarray(direction) * LOST_MM / 2


def run_plan(path, plan, command=lambda p, d: p, noise_um=0.3, seed=0):
    """Execute the measured moves of a 1-axis plan on the machine, writing raw data."""
    rng = np.random.default_rng(seed)
    with RawWriter(path, ["time_s"]) as w:
        for k, m in enumerate(plan.moves):
            if m.measured:
                p = m.target_mm[0]
                actual = land(command(p, m.direction), m.direction) + rng.normal(0, noise_um * 1e-3)
                w.append(plan.axes[0], m.run, m.direction, p, float(actual), time_s=float(k))
    return read_raw_csv(path)


def pitch_command(table, backlash_mm=None):
    stage = PitchStage(table)
    lash = BacklashStage(backlash_mm) if backlash_mm is not None else None

    def command(p, d):
        c = float(stage.forward(p, d))
        return lash.forward(c, d) if lash is not None else c

    return command


def test_bidirectional_fit_compensates_between_points(tmp_path) -> None:
    plan = iso230_linear_plan("X", TRAVEL, step_mm=20, seed=1, lead_mm=5)
    raw = run_plan(tmp_path / "cal.csv", plan)
    table = bidirectional_table(axis_deviations(raw, "X"))
    t = table.position_mm
    np.testing.assert_allclose(t, np.unique(plan.targets_mm()))
    np.testing.assert_allclose(table.forward_mm, e_true(t) - LOST_MM / 2, atol=1e-3 * 0.5)
    np.testing.assert_allclose(table.reverse_mm, e_true(t) + LOST_MM / 2, atol=1e-3 * 0.5)
    before = iso230_axis(axis_deviations(raw, "X"))
    ver = iso230_linear_plan("X", TRAVEL, step_mm=20, seed=1, lead_mm=5, verification=True)
    verified = run_plan(tmp_path / "v.csv", ver, pitch_command(table))
    after = iso230_axis(axis_deviations(verified, "X"))
    assert after.E_um <= 0.1 * before.E_um and after.A_um <= 0.1 * before.A_um


def test_unidirectional_fit_and_backlash_sign(tmp_path) -> None:
    plan = iso230_linear_plan("X", TRAVEL, step_mm=20, seed=2)
    dev = axis_deviations(run_plan(tmp_path / "cal.csv", plan), "X")
    fit = unidirectional_table(dev)
    assert fit.table_direction == "mean" and not fit.table.bidirectional
    assert fit.reversal_mean_mm == pytest.approx(-LOST_MM, abs=3e-4)  # ISO B̄ < 0
    assert fit.backlash_mm == pytest.approx(LOST_MM, abs=3e-4)
    np.testing.assert_allclose(fit.table.forward_mm, e_true(fit.table.position_mm), atol=5e-4)
    ver = iso230_linear_plan("X", TRAVEL, step_mm=20, seed=2, verification=True)
    cmd = pitch_command(fit.table, fit.backlash_mm)
    res = iso230_axis(axis_deviations(run_plan(tmp_path / "v.csv", ver, cmd), "X"))
    assert res.E_um < 2.0 and abs(res.Bmean_um) < 0.6
    up_only = read_raw_csv(tmp_path / "cal.csv")
    keep = up_only.direction > 0
    sub = RawData(
        tuple(np.array(up_only.axis)[keep]), up_only.run[keep], up_only.direction[keep],
        up_only.target_mm[keep], up_only.actual_mm[keep], {}, tuple(np.array(up_only.lines)[keep]),
    )  # fmt: skip
    fwd = unidirectional_table(axis_deviations(sub, "X"))
    assert fwd.backlash_mm is None and fwd.table_direction == "forward"


def residual_at(table, targets, backlash_mm=None):
    """Residual (mm) measured at ``targets`` in + and − with ``table`` applied, no noise."""
    cmd = pitch_command(table, backlash_mm)
    up = np.array([land(cmd(p, 1), 1) - p for p in targets])
    down = np.array([land(cmd(p, -1), -1) - p for p in targets])
    return up, down


def test_fold_residual_bidirectional_cuts_residual_by_90_percent() -> None:
    targets = np.unique(iso230_linear_plan("X", TRAVEL, step_mm=20, seed=5).targets_mm())
    wrong = PitchTable(targets, 0.3 * e_true(targets) + 0.005, 0.5 * e_true(targets))
    up, down = residual_at(wrong, targets)
    before = max(np.abs(up).max(), np.abs(down).max())
    assert before > 0.01
    new = fold_residual(wrong, PitchTable(targets, up, down))
    mids = 0.5 * (targets[1:] + targets[:-1])
    for where in (targets, mids):
        up2, down2 = residual_at(new, where)
        after = max(np.abs(up2).max(), np.abs(down2).max())
        assert after <= 0.1 * before, (after, before)
    # the sign matters: subtracting the residual instead makes things worse
    bad = PitchTable(targets, wrong.forward_mm - up, wrong.reverse_mm - down)
    assert np.abs(residual_at(bad, targets)[0]).max() > before


def test_fold_residual_unidirectional_with_backlash() -> None:
    targets = np.linspace(5, 595, 31)
    wrong = PitchTable(targets, -0.5 * e_true(targets))
    up, down = residual_at(wrong, targets, backlash_mm=0.0)
    before = max(np.abs(up).max(), np.abs(down).max())
    residual = PitchTable(targets, up, down)
    new = fold_residual(wrong, residual)
    assert not new.bidirectional
    b_new = fold_backlash(0.0, float(np.mean(up - down)))
    assert b_new == pytest.approx(LOST_MM, abs=1e-6)
    up2, down2 = residual_at(new, targets, backlash_mm=b_new)
    assert max(np.abs(up2).max(), np.abs(down2).max()) <= 0.1 * before
    assert fold_backlash(0.004, 0.01) == 0.0


def test_fold_uses_residual_at_the_landing_target() -> None:
    """Exactness of the fold: with e linear, one fold makes the table exact at its points."""
    x = np.linspace(0, 100, 11)
    table = PitchTable(x, np.zeros_like(x))
    residual = PitchTable(x, 0.05 + 1e-3 * x)  # machine e(c) = 0.05 + 0.001 c
    new = fold_residual(table, residual)
    np.testing.assert_allclose(new.forward_mm, 0.05 + 1e-3 * x, atol=1e-12)
    shifted = fold_residual(PitchTable(x, np.full_like(x, 0.01)), residual)
    # e_t = 0.01 everywhere: the point x_k is reached at p = x_k + 0.01 → r read there
    np.testing.assert_allclose(shifted.forward_mm[1:-1], 0.01 + 0.05 + 1e-3 * (x[1:-1] + 0.01))


def planar_error(p):
    x, y = p[..., 0], p[..., 1]
    ex = 0.01 * np.sin(x / 90.0) + 2e-5 * y  # squareness-like cross term
    ey = 0.008 * np.cos(y / 70.0) - 1e-5 * x
    return np.stack([ex, ey], axis=-1)


def run_xy(path, plan):
    pts = plan.measured_points_mm()
    with RawWriter(path, ["x_mm", "y_mm"]) as w:
        for run in (1, 2):
            for p in pts:
                act = p + planar_error(p)
                w.append("X", run, 1, p[0], float(act[0]), x_mm=p[0], y_mm=p[1])
                w.append("Y", run, 1, p[1], float(act[1]), x_mm=p[0], y_mm=p[1])
    return read_raw_csv(path)


def test_planar_measurement_from_grid_run(tmp_path) -> None:
    plan = xy_grid_plan((0, 300), (0, 200), 7, 5)
    meas = planar_measurement(run_xy(tmp_path / "xy.csv", plan))
    assert meas.command_mm.shape == (70, 2)
    np.testing.assert_allclose(meas.error_mm, planar_error(meas.command_mm), atol=1e-12)
    model = GridModel.from_measurement(meas)
    check = xy_verification_plan((0, 300), (0, 200), 7, 5).measured_points_mm()
    err = np.abs(model.error_mm(check) - planar_error(check)).max()
    assert err < 0.05 * np.abs(planar_error(check)).max()


def test_planar_measurement_refuses_unpaired_rows(tmp_path) -> None:
    path = tmp_path / "xy.csv"
    with RawWriter(path, ["x_mm", "y_mm"]) as w:
        w.append("X", 1, 1, 0.0, 0.001, x_mm=0.0, y_mm=0.0)
    with pytest.raises(TableError, match="line 2: point has no reading of the other axis"):
        planar_measurement(read_raw_csv(path))
    with RawWriter(path, ["x_mm", "y_mm"]) as w:
        w.append("Y", 1, 1, 5.0, 0.001, x_mm=0.0, y_mm=0.0)
    with pytest.raises(TableError, match="line 3: target_mm differs from y_mm"):
        planar_measurement(read_raw_csv(path))


def test_interrupted_run_resumes_to_the_same_table(tmp_path) -> None:
    """Kill after 37 measurements, resume at resume_index: same raw rows, same table."""
    plan = iso230_linear_plan("X", TRAVEL, step_mm=50, seed=3)
    whole = run_plan(tmp_path / "whole.csv", plan, noise_um=0.0)
    measured = [k for k, m in enumerate(plan.moves) if m.measured]
    path = tmp_path / "part.csv"
    with RawWriter(path, ["time_s"]) as w:
        for k in measured[:37]:
            m = plan.moves[k]
            p = m.target_mm[0]
            w.append("X", m.run, m.direction, p, float(land(p, m.direction)), time_s=float(k))
    start = resume_index(plan, read_raw_csv(path))
    assert start == measured[37]
    assert plan.moves[start - 1].target_mm != plan.moves[start].target_mm  # re-approach
    with RawWriter(path, ["time_s"]) as w:
        for k in measured[measured.index(start):]:
            m = plan.moves[k]
            p = m.target_mm[0]
            w.append("X", m.run, m.direction, p, float(land(p, m.direction)), time_s=float(k))
    resumed = read_raw_csv(path)
    assert resume_index(plan, resumed) == len(plan.moves)
    a = bidirectional_table(axis_deviations(whole, "X"))
    b = bidirectional_table(axis_deviations(resumed, "X"))
    np.testing.assert_array_equal(a.forward_mm, b.forward_mm)
    np.testing.assert_array_equal(a.reverse_mm, b.reverse_mm)
    other = iso230_linear_plan("X", TRAVEL, step_mm=50, seed=4)
    with pytest.raises(TableError, match="line 3: row does not match plan move 3"):
        resume_index(other, resumed)
