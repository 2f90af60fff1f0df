"""A faded planar model re-expressed when the tables it was read with change
(gateway/calibration/fitting/plane_frame.py)."""

from __future__ import annotations

import numpy as np
import yaml

from gateway.calibration.fitting.models import choose_planar_model, pinned_measurement
from gateway.calibration.fitting.plane_frame import (
    frame_of,
    read_frame,
    reframed,
    table_deviation_mm,
    write_frame,
)
from gateway.compensation import GridModel, PlanarMeasurement
from gateway.config import load_config

AXIS = {"bus": "line1", "pulse_mm": 0.001, "travel_mm": [0, 450],
        "registers": {"target": {"address": 0x6201}, "feedback": {"address": 0x602A}}}  # fmt: skip


def _config(tmp_path, bow_um):
    """X and Y with pitch tables (X's a bow of ``bow_um`` over its travel, Y's flat) and a
    plane (``tables/xy_model.yaml``, its points beside it)."""
    (tmp_path / "tables").mkdir(exist_ok=True)
    x = np.linspace(0, 450, 46)
    for name, values in (("x", bow_um * np.sin(np.pi * x / 450)), ("y", 0.0 * x)):
        rows = "\n".join(f"{p:g},{v:.4f}" for p, v in zip(x, values))
        (tmp_path / "tables" / f"{name}.csv").write_text(f"position_mm,error_um\n{rows}\n")
    axes = {n: {**AXIS, "unit": k + 1,
                "compensation": {"pitch": f"tables/{n.lower()}.csv", "max_correction_mm": 0.1}}
            for k, n in enumerate("XY")}  # fmt: skip
    data = {"upstream": {"tcp": {"port": 0}}, "axes": axes,
            "buses": {"line1": {"tcp": {"host": "127.0.0.1", "port": 1}}},
            "planar": {"axes": ["X", "Y"], "model": "tables/xy_model.yaml"}}  # fmt: skip
    path = tmp_path / "gw.yaml"
    path.write_text(yaml.safe_dump(data))
    return load_config(path)


def test_table_deviation_is_what_the_tables_take_off(tmp_path):
    config = _config(tmp_path, 3.0)
    x = np.array([0.0, 112.5, 225.0, 450.0])
    got_um = table_deviation_mm(config, tmp_path, "X", x) * 1e3
    np.testing.assert_allclose(got_um, 3.0 * np.sin(np.pi * x / 450), atol=2e-3)


def test_a_table_change_is_kept_off_the_line_and_the_grid_reading_kept(tmp_path):
    """A grid read with X's table bowed 3 µm holds the bow's miss (the truth has none); the
    table is then made flat (Δ = −3 µm bow). Re-expressed, the model far from X's pitch
    line takes the change off again: table + plane there is what the grid read (at its
    nodes, exactly), and on the line the table alone rules, as before."""
    xs, ys = np.linspace(2, 448, 25), np.linspace(2, 448, 17)
    gx, gy = np.meshgrid(xs, ys)
    cmd = np.column_stack([gx.ravel(), gy.ravel()])
    squareness = 2e-5 * cmd[:, 1]  # X error growing with Y (mm)
    bow_then = 3e-3 * np.sin(np.pi * cmd[:, 0] / 450)
    read = np.column_stack([squareness - bow_then, np.zeros(len(cmd))])  # truth − table
    choice = choose_planar_model(PlanarMeasurement(cmd, cmd + read), "grid")
    lines = {"X": 0.0, "Y": 0.0}
    points = pinned_measurement(choice.model, ("X", "Y"), lines, nodes=(xs, ys))
    (tmp_path / "then").mkdir()
    then = _config(tmp_path / "then", 3.0)
    frame = frame_of(then, tmp_path / "then", ("X", "Y"), (xs, ys), lines)
    write_frame(tmp_path / "xy_frame.json", frame)
    frame = read_frame(tmp_path / "xy_frame.json")
    (tmp_path / "now").mkdir()
    now_config = _config(tmp_path / "now", 0.0)
    now = {a: table_deviation_mm(now_config, tmp_path / "now", a, frame.nodes_mm[a])
           for a in "XY"}  # fmt: skip
    after = GridModel.from_measurement(reframed(points, frame, ("X", "Y"), now))
    before = GridModel.from_measurement(points)
    far = np.column_stack([xs, np.full(xs.size, ys[-1])])
    bow_nodes = 3e-3 * np.sin(np.pi * xs / 450)
    # then: table (bow) + plane; now: table (flat) + re-expressed plane: the same there
    # (the bow as X's 10 mm table interpolates it: within 2 nm of the sine at the nodes)
    np.testing.assert_allclose(after.error_mm(far)[:, 0], before.error_mm(far)[:, 0]
                               + bow_nodes, atol=5e-6)  # fmt: skip
    # ... which is the squareness the grid read, the bow's miss gone with the bow
    np.testing.assert_allclose(after.error_mm(far)[:, 0], 2e-5 * ys[-1], atol=2e-5)
    # on the line the table rules, but for its level: the plane moves with that (no step)
    on_line = np.column_stack([xs, np.zeros(xs.size)])
    np.testing.assert_allclose(after.error_mm(on_line)[:, 0],
                               before.error_mm(on_line)[:, 0] + np.mean(bow_nodes), atol=1e-6)
    np.testing.assert_allclose(after.error_mm(on_line)[:, 1], before.error_mm(on_line)[:, 1],
                               atol=1e-12)  # fmt: skip
    # no change, no re-expression
    same = reframed(points, frame, ("X", "Y"), frame.table_mm)
    np.testing.assert_array_equal(same.error_mm, points.error_mm)


def test_reframe_plane_rewrites_the_points_once_per_change(tmp_path):
    """What `compgw fit`, the iteration's fold and the commissioning call after a table is
    written: the points re-expressed against the new tables; nothing when the points are
    that already or there is no frame (a plane pinned without a fade)."""
    from gateway.calibration.fitting.plane_frame import reframe_plane, save_frame
    from gateway.formats import read_planar_csv, write_planar_csv

    xs, ys = np.linspace(2, 448, 13), np.linspace(2, 448, 9)
    gx, gy = np.meshgrid(xs, ys)
    cmd = np.column_stack([gx.ravel(), gy.ravel()])
    points_path = tmp_path / "tables" / "xy_points.csv"
    config = _config(tmp_path, 3.0)
    write_planar_csv(points_path, PlanarMeasurement(cmd, cmd.copy()))
    assert not reframe_plane(config, tmp_path)  # no frame
    save_frame(points_path,
               frame_of(config, tmp_path, ("X", "Y"), (xs, ys), {"X": 0.0, "Y": 0.0}))
    assert not reframe_plane(config, tmp_path)  # same tables
    config = _config(tmp_path, 1.0)  # X's bow 3 → 1 µm, written over the same file
    assert reframe_plane(config, tmp_path)
    err_um = read_planar_csv(points_path).error_mm * 1e3
    far = cmd[:, 1] > 200
    np.testing.assert_allclose(err_um[far, 0], 2.0 * np.sin(np.pi * cmd[far, 0] / 450),
                               atol=2e-3)  # fmt: skip
    assert np.abs(err_um[:, 1]).max() < 1e-9  # Y's table did not change
    assert not reframe_plane(config, tmp_path)  # done once
    # always from the points as fitted: a table put back puts the plane back too, and an
    # interrupted re-expression is simply done again
    config = _config(tmp_path, 3.0)
    assert reframe_plane(config, tmp_path)
    np.testing.assert_allclose(read_planar_csv(points_path).error_mm, 0.0, atol=1e-12)


def test_compgw_fit_keeps_a_faded_plane_in_line_with_a_table_it_writes(tmp_path, capsys):
    """`compgw fit xy.csv --pitch-line …` writes a smoothed grid pinned with a fade and its
    frame; `compgw fit X_on.csv --residual` then folds a bow and a 1 µm tilt into X's
    table. The plane gives the bow back off X's pitch line (where the table alone rules,
    nothing moves but the bow's level); the tilt it follows everywhere (the pin takes a
    line's straight part off the whole plane: the plane held none of it), giving back its
    level alone. A level folded alone is given back everywhere, on the line too: a step
    there would be the laser's zero against the grid device's."""
    from gateway.calibration.fitting.plane_frame import FRAME_FILE
    from gateway.calibration.plans.rawdata import RawWriter
    from gateway.cli import main
    from gateway.formats import read_planar_csv

    _config(tmp_path, 3.0)
    xs, ys = np.linspace(2, 448, 25), np.linspace(2, 448, 17)
    rng = np.random.default_rng(3)
    with RawWriter(tmp_path / "xy.csv", ["x_mm", "y_mm"]) as w:
        for x, y in ((x, y) for y in ys for x in xs):
            wave = 3e-3 * np.array([np.sin(x / 25.0) * np.sin(y / 20.0),
                                    np.cos(x / 18.0) * np.sin(y / 26.0)])  # zero on the lines
            got = np.array([x, y]) + wave + rng.normal(0, 2e-4, 2)
            for axis, target, actual in (("X", x, got[0]), ("Y", y, got[1])):
                w.append(axis, 1, "+", target, float(actual), x_mm=float(x), y_mm=float(y))
    gw = str(tmp_path / "gw.yaml")
    assert main(["fit", str(tmp_path / "xy.csv"), "-c", gw, "--pitch-line", "X@Y=0",
                 "--pitch-line", "Y@X=0"]) == 0  # fmt: skip
    points = tmp_path / "tables" / "xy_points.csv"
    assert (tmp_path / "tables" / FRAME_FILE).exists(), capsys.readouterr().out
    before = read_planar_csv(points)
    def fold(name, miss_mm):  # X read with its table on, ``miss_mm(t)`` long, folded in
        with RawWriter(tmp_path / name) as w:
            for run in (1, 2):
                for sign, targets in (("+", np.arange(0, 451, 10.0)),
                                      ("-", np.arange(450, -1, -10.0))):  # fmt: skip
                    for t in targets:
                        w.append("X", run, sign, float(t), float(t) + miss_mm(t))
        capsys.readouterr()
        assert main(["fit", str(tmp_path / name), "-c", gw, "--residual"]) == 0
        return capsys.readouterr().out

    far = before.command_mm[:, 1] > 100.0
    on_line = before.command_mm[:, 1] == 0.0
    assert "re-expressed" in fold("x_level.csv", lambda t: 1e-3)  # a level: everywhere
    level_um = (read_planar_csv(points).error_mm - before.error_mm) * 1e3
    np.testing.assert_allclose(level_um[:, 0], -1.0, atol=1e-6)
    assert np.abs(level_um[:, 1]).max() < 1e-9  # Y's table did not change
    def bow(t):  # µm: a bow with no straight part over the grid's nodes
        return np.cos(2 * np.pi * (np.asarray(t) - 2.0) / 446.0)

    assert "re-expressed" in fold("x_bow.csv", lambda t: 1e-3 * (t / 450 + bow(t)))
    after = read_planar_csv(points)
    np.testing.assert_array_equal(after.command_mm, before.command_mm)
    shift_um = (after.error_mm - before.error_mm) * 1e3 - level_um
    x = np.clip(before.command_mm[:, 0], xs[0], xs[-1])  # (held past the nodes)
    level = np.mean(xs / 450 + bow(xs))
    np.testing.assert_allclose(shift_um[far, 0], -bow(x[far]) - np.mean(xs / 450) + level
                               - level, atol=2e-2)  # fmt: skip
    np.testing.assert_allclose(shift_um[on_line, 0], -level, atol=1e-9)
    assert np.abs(shift_um[:, 1]).max() < 1e-9
