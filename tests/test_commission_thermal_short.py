"""A short budget on a machine with a thermal sensor (issue 54): the plain calibration's
steps first, the zone warm-up after them (sim, gateway and the command as real processes,
time_scale 0). Its own file: the suite's files are spread over the workers whole."""

from __future__ import annotations

import json
from pathlib import Path

import yaml

from tests.commission_rig import random_machine, running, small_machine
from tests.test_service_helpers import Proc


def test_a_short_budget_with_a_thermal_sensor_takes_the_plain_steps_first(
        tmp_path: Path) -> None:  # fmt: skip
    """Issue 54: with a Δa sensor given, a short budget warmed X first (45 minutes of a
    0.9 h budget) and stopped with no table. Now the ISO runs of every axis come first,
    and the warm-up only where the budget left holds it."""
    directory = tmp_path / "machine"
    machine = small_machine(directory, seed=7)
    original = yaml.safe_load((tmp_path / "machine" / "gateway.yaml").read_text())
    fresh = tmp_path / "fresh"
    random_machine(fresh, seed=7)  # as `compgw sim --random-machine 7` writes it
    written = yaml.safe_load((fresh / "gateway.yaml").read_text())
    original["thermal_sources"] = written["thermal_sources"]  # the Δa sensor back, X on it
    original["axes"]["X"]["compensation"]["thermal"] = written["axes"]["X"]["compensation"][
        "thermal"]  # (small_machine drops both)  # fmt: skip
    delta_a = machine["instruments"]["delta_a"]
    (directory / "gateway.yaml").write_text(yaml.safe_dump(original, sort_keys=False))
    with running(directory, tmp_path / "m") as rig:
        proc = rig.commission("--budget-h", "0.2", "--delta-a",
                              f"127.0.0.1:{rig.sim_port}:{delta_a['unit']}:1")
        assert proc.popen.wait(timeout=300) in (0, 1), proc.text()
        state = json.loads((rig.dir / "commission" / "commission.json").read_text())
        done = list(state["steps"])
        assert state["short"], proc.text()
        assert "iso-X" in done and "iso-Y" in done, done
        assert "warmup-X" not in done or done.index("iso-X") < done.index("warmup-X"), done
        summary = json.loads((rig.dir / "commission" / "summary.json").read_text())
        assert all(e.get("table_points", 0) > 0 for e in summary["axes"].values()), summary



def test_a_short_budget_reads_no_drift_references_where_every_axis_keeps_its_sensor(
        tmp_path: Path) -> None:  # fmt: skip
    """X alone, on its Δa sensor, on a short budget that holds a plain calibration's steps
    with the drift references: its readings are levelled by the sensor's compensation and
    the references' drift is never taken off them, so none are read; said so, and X gets
    its table."""
    directory = tmp_path / "machine"
    machine = small_machine(directory, seed=7)
    original = yaml.safe_load((directory / "gateway.yaml").read_text())
    fresh = tmp_path / "fresh"
    random_machine(fresh, seed=7)
    written = yaml.safe_load((fresh / "gateway.yaml").read_text())
    original["thermal_sources"] = written["thermal_sources"]
    original["axes"]["X"]["compensation"]["thermal"] = written["axes"]["X"]["compensation"][
        "thermal"]  # fmt: skip
    delta_a = machine["instruments"]["delta_a"]
    (directory / "gateway.yaml").write_text(yaml.safe_dump(original, sort_keys=False))
    with running(directory, tmp_path / "m") as rig:
        args = rig.commission_args("--axes", "X", "--budget-h", "0.3", "--delta-a",
                                   f"127.0.0.1:{rig.sim_port}:{delta_a['unit']}:1")
        at = args.index("--xy-device")  # (the plane is not commissioned: X alone)
        args = args[:at] + args[at + 2:]
        args[args.index("--lead-mm") + 1] = f"X={machine['axes']['X']['lead_mm']:g}"
        proc = Proc(args)
        assert proc.popen.wait(timeout=300) in (0, 1), proc.text()
        state = json.loads((rig.dir / "commission" / "commission.json").read_text())
        assert state["short"] and state["refs_off"], proc.text()
        assert "no drift references: every axis keeps its own sensor" in proc.text()
        assert not state.get("drift_log"), state.get("drift_log")
        summary = json.loads((rig.dir / "commission" / "summary.json").read_text())
        assert summary["axes"]["X"].get("table_points", 0) > 0, summary
