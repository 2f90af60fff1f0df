"""A carried-on commissioning's after-run against the run before's
(:mod:`gateway.calibration.commissioning.carried`): tables this run left as they were keep
the run before's reading; tables it changed are put back as the run before left them, with
their reading. On the commissioning's own record, files and state on disk."""

from __future__ import annotations

import json
from pathlib import Path

from gateway.calibration.commissioning.carried import RunBefore
from gateway.calibration.commissioning.record import Record
from gateway.calibration.fitting.plane_frame import FRAME_FILE

AFTER = ("after-X", "after-Y", "after-xy")


def _record(tmp_path: Path) -> Record:
    """A finished run's record: X's and Y's tables, the plane's model, its after-run."""
    record = Record(tmp_path / "commission", tmp_path)
    (tmp_path / "tables" / "plane").mkdir(parents=True)
    for a in ("X", "Y"):
        (tmp_path / "tables" / f"{a}.csv").write_text(f"position_mm,{a}\n0,0.0\n100,1.0\n")
        record.tables.pitch[a] = f"tables/{a}.csv"
    (tmp_path / "tables" / "plane" / "model.yaml").write_text("kind: poly\n")
    record.tables.planar_model, record.tables.planar_axes = "tables/plane/model.yaml", ("X", "Y")
    record.state["best"] = {"X": {"score": 1.1, "round": 1}}
    for k, step in enumerate(AFTER):
        record.raw_path(step).parent.mkdir(parents=True, exist_ok=True)
        record.raw_path(step).write_text(f"readings of {step}\n")
        record.state["steps"][step] = {"machine_s": 280.0 + k}
    figures = {"X": 1.10, "Y": 1.86, "XY": 0.95}
    record.state["run_before"] = {n: {"read": v, "tables": record.tables.digest(n, tmp_path)}
                                  for n, v in figures.items()}  # fmt: skip
    for n, a in (("X", 3.73), ("Y", 3.76)):  # their A as read (the plane has none)
        record.state["run_before"][n]["read_A"] = a
    return record


def test_tables_left_as_they_were_keep_their_reading_and_changed_ones_go_back(
        tmp_path: Path) -> None:  # fmt: skip
    record = _record(tmp_path)
    x_table = (tmp_path / "tables" / "X.csv").read_text()
    run_before = RunBefore(record)
    run_before.keep(list(AFTER))
    # the after-run is to be read again; the run before's readings aside
    assert not any(record.done(s) for s in AFTER)
    superseded = record.dir / "raw" / "superseded"
    assert sorted(p.name for p in superseded.iterdir()) == sorted(f"{s}.csv" for s in AFTER)
    # this run refines X: a new table, read otherwise
    (tmp_path / "tables" / "X.csv").write_text("position_mm,X\n0,0.0\n50,0.4\n100,1.2\n")
    record.tables.interpolation["X"] = "pchip"
    record.state["best"]["X"] = {"score": 0.8, "round": 2}
    assert run_before.same("Y") and not run_before.same("X")
    # the plane's model is as it was, but it is read with X's table
    assert run_before.same_one("XY") and not run_before.same("XY")
    # Y: not read again, its reading the run before's (its machine time was the run before's)
    assert run_before.carry("after-Y", "Y")
    assert record.raw_path("after-Y").read_text() == "readings of after-Y\n"
    assert record.state["steps"]["after-Y"] == {"machine_s": 0.0, "carried": True}
    assert not run_before.carry("after-X", "X") and not run_before.carry("after-xy", "XY")
    # X read worse, to the hundredth printed: put back, with its reading and its best
    assert not run_before.reads_worse("X", 1.104) and run_before.reads_worse("X", 1.106)
    # ... or its A, the acceptance figure (random machine 7's X: E 1.44 → 1.43, A 3.73 →
    # 5.32); the plane has only its maximum
    assert not run_before.reads_worse("X", 1.09, 3.734) and run_before.reads_worse("X", 1.09, 5.32)
    assert not run_before.reads_worse("XY", 0.95, 9.0)
    record.raw_path("after-X").write_text("this run's readings of after-X\n")
    record.state["steps"]["after-X"] = {"machine_s": 281.0}
    run_before.set_aside("after-X")
    assert (record.dir / "raw" / "put-back" / "after-X.csv").exists()
    run_before.put_back("X")
    assert (tmp_path / "tables" / "X.csv").read_text() == x_table
    assert "X" not in record.tables.interpolation and record.state["best"]["X"]["score"] == 1.1
    assert record.state["put_back"] == ["X"]
    assert run_before.same("X") and run_before.same("XY")
    assert run_before.carry("after-X", "X") and run_before.carry("after-xy", "XY")
    assert record.raw_path("after-X").read_text() == "readings of after-X\n"
    # all of it on disk: a resume reads the same
    again = json.loads(record.state_path.read_text())
    assert {s for s in AFTER if again["steps"][s].get("carried")} == set(AFTER)
    assert again["tables"]["pitch"] == record.tables.pitch


def test_a_plane_model_this_run_fitted_anew_is_put_back_whole(tmp_path: Path) -> None:
    """A plane the run before had no frame for: this run's frame goes with its model."""
    record = _record(tmp_path)
    run_before = RunBefore(record)
    run_before.keep(list(AFTER))
    plane = tmp_path / "tables" / "plane"
    (plane / "model.yaml").write_text("kind: grid\n")
    (plane / FRAME_FILE).write_text("pinned: true\n")
    assert not run_before.same_one("XY")
    run_before.put_back("XY")
    assert (plane / "model.yaml").read_text() == "kind: poly\n"
    assert not (plane / FRAME_FILE).exists()
    assert run_before.same("XY") and run_before.carry("after-xy", "XY")
