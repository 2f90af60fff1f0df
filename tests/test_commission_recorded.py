"""Commissioning from the laser software's own recordings, end to end with real processes:
a scripted technician starts and saves the sim's recordings as compgw asks (apart from
tests/test_commission_instruments.py: this one waits on the laser's real-time dwells, and
the suite's workers share the long files)."""

from __future__ import annotations

import re
import sys
from pathlib import Path

import numpy as np
import yaml

from gateway.calibration.plans.rawdata import read_raw_csv
from tests.commission_rig import recording_machine, running

ROOT = Path(__file__).resolve().parents[1]


def test_commission_one_axis_from_the_laser_software_s_own_recordings(tmp_path: Path) -> None:
    """`compgw commission --axes X --laser recording:DIR`: a scripted technician
    (sim/technician.py) starts the sim's recording when compgw says so and presses Enter,
    stops it after the moves and saves it under the name compgw waits for. A step is one
    recording, the drift references read in it before and after its runs, at the laser's
    one zero (the first recording's); a short one of their own across a config switch. A
    short budget (the suite's time; the bench compares the kinds at full length): the ISO
    runs, then the table fitted from them. Then the laser set up on Y, in a folder of its
    own, and the plane commissioned with it (the XY device read live)."""
    import json

    from sim.technician import Technician

    directory = tmp_path / "t"
    recording_machine(directory, "csv", 250)
    with running(directory, tmp_path / "m") as rig:
        laser_dir = tmp_path / "laser"
        laser_dir.mkdir()
        argv = [sys.executable, "-m", "gateway.cli", "commission", "-c", str(rig.config),
                "--gateway", f"127.0.0.1:{rig.gw_port}", "--axes", "X",
                "--laser", f"recording:{laser_dir}:um", "--no-lead-search", "--budget-h",
                "0.3", "--dwell-s", "0.08", "--wait-start", "--no-progress",
                "--delta-a", f"127.0.0.1:{rig.sim_port}:22"]  # fmt: skip
        with Technician("127.0.0.1", rig.sim_port, 20, rig.dir / "recordings", "csv") as tech:
            done_run = tech.attend(argv, ROOT, 200.0)
            assert done_run.returncode == 1, done_run.stdout + done_run.stderr  # budget spent
            # then the laser moved to Y, and the plane with it (the XY device read live)
            tech.set_up_on(1)
            argv_y = [*argv[:argv.index("--axes")], "--axes", "Y", "--xy-device",
                      f"127.0.0.1:{rig.sim_port}:21", "--out", str(rig.config.parent / "y"),
                      *argv[argv.index("--axes") + 2:]]  # fmt: skip
            argv_y[argv_y.index("--budget-h") + 1] = "0.15"
            # X's folder, an iso-Y left there by an earlier try: never read as this one's
            (laser_dir / "iso-Y.csv").write_bytes((laser_dir / "iso-X.csv").read_bytes())
            stale = tech.attend(argv_y, ROOT, 60.0)
            assert stale.returncode == 3 and re.search(  # (or its references' recording)
                rf"{re.escape(str(laser_dir))}/(iso-Y|refs-001)\.csv: there before the moves it "
                "is to record", stale.stderr), (stale.stdout + stale.stderr,
                                                "X's run before:", done_run.stdout[-3000:],
                                                done_run.stderr[-2000:])  # fmt: skip
            laser_y = tmp_path / "laser-Y"
            laser_y.mkdir()
            argv_y[argv_y.index("--laser") + 1] = f"recording:{laser_y}:um"
            plane_run = tech.attend(argv_y, ROOT, 200.0)
        text = done_run.stdout + done_run.stderr
        assert done_run.returncode == 1, text  # the budget spent: not verified
        assert "plane" not in text.split("commissioning X:")[1], text  # none is commissioned
        assert [p.name for p in tech.saved][:2] == ["refs-001.csv", "iso-X.csv"], tech.saved
        done = rig.config.parent / "commission"
        state = json.loads((done / "commission.json").read_text())
        assert "laser_datum_mm" in state and state["refs_recordings"] >= 1
        # the references read in iso-X's own recording: before and after each of its runs
        parts = state["steps"]["iso-X"]["parts"]
        assert len(parts) == 3 and all("drift" in part for part in parts), parts
        assert len(state["drift_log"]) >= 1 + len(parts) + 1, state["drift_log"]
        summary = json.loads((done / "summary.json").read_text())
        assert summary["outcome"] == "budget" and "X" in state["tables"]["pitch"], text
        table = read_raw_csv(done / "raw" / "iso-X.part1.csv")
        assert np.abs(table.deviation_mm).max() < 0.2  # positions, not the laser's own zero
        # a sensor compgw read at each stop stays beside the run's readings
        assert len(table.extra["delta_a_mm"]) == table.target_mm.size, table.extra
        # the laser was zeroed at its first stop, anywhere: the table is zero at the
        # machine's zero, and the laser's zero moved with it
        from gateway.formats import read_pitch_csv

        pitch = read_pitch_csv(done.parent / state["tables"]["pitch"]["X"])
        assert pitch.forward_mm[0] == 0.0 and pitch.position_mm[0] <= 1.0, pitch
        assert "X" in state["zero_moved_mm"], state
        # Y with the plane: X keeps its table, the plane is fitted over both, the XY
        # device's steps read live; the budget holds a plain calibration's steps, not the
        # plane's verdict after them (said)
        text = plane_run.stdout + plane_run.stderr
        assert plane_run.returncode == 1, text
        assert "the plane: no random points before and after on this budget" in text, text
        config = yaml.safe_load(rig.config.read_text())
        assert config["axes"]["X"]["compensation"]["pitch"]["file"] == \
            state["tables"]["pitch"]["X"]  # fmt: skip
        assert config["planar"]["axes"] == ["X", "Y"], config.get("planar")
        saved = [p.name for p in tech.saved if p.parent == laser_y]
        assert "iso-Y.csv" in saved and not any("xy" in n for n in saved), saved
        grids = sorted((rig.config.parent / "y" / "raw").glob("xy-grid*.csv"))
        assert grids and set(read_raw_csv(grids[0]).axis) == {"X", "Y"}, grids
