"""Commissioning and calibration with the instruments a technician owns, end to end with
real processes: the sim's laser on the bridge protocol (as a vendor SDK wrapped in a short
script would answer), and a gauge typed at the prompt (scripted through stdin)."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path
from typing import IO

import numpy as np
import pytest
import yaml

from gateway.calibration.plans.plans import Move, Plan, write_plan
from gateway.calibration.plans.rawdata import read_raw_csv
from sim.technician import attend
from tests.commission_rig import running, small_machine

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def template(tmp_path_factory: pytest.TempPathFactory) -> Path:
    directory = tmp_path_factory.mktemp("machine") / "m"
    small_machine(directory, seed=7)
    sim = yaml.safe_load((directory / "sim.yaml").read_text())
    sim["sim"]["instruments"]["laser"]["bridge"] = {"host": "127.0.0.1", "port": 0}
    sim["sim"]["instruments"]["delta_a"] = {"unit": 22, "axis": "X", "a_mm": 0.0,
                                            "resolution_um": 0.1}  # fmt: skip
    (directory / "sim.yaml").write_text(yaml.safe_dump(sim, sort_keys=False))
    return directory


#: a Δa sensor behind a technician's own bridge (docs/instruments-bridge.md): the sim's, read
#: over Modbus (int32 nm at registers 1-2 of unit 22), answered on channel delta_a
DELTA_A_BRIDGE = """
import sys
from pymodbus.client import ModbusTcpClient
client = ModbusTcpClient("127.0.0.1", port=int(sys.argv[1]))
client.connect()
for line in sys.stdin:
    words = line.split()
    if words[0] == "HELLO":
        print("OK sim-delta-a channels=delta_a unit=um", flush=True)
    elif words[0] == "READ" and words[1:] == ["delta_a"]:
        hi, lo = client.read_holding_registers(1, count=2, device_id=22).registers
        nm = (hi << 16 | lo) - (1 << 32 if hi & 0x8000 else 0)
        print(f"OK {nm / 1000:.4f} um STABLE", flush=True)
    elif words[0] == "BYE":
        print("OK", flush=True)
        break
    else:
        print("ERR not a request of this bridge", flush=True)
"""


def test_a_bridge_named_before_anything_moves_and_read_as_the_modbus_laser(
        template: Path, tmp_path: Path) -> None:  # fmt: skip
    """A bridge that does not answer is named before commissioning moves anything; the
    sim's laser on the bridge protocol reads as its Modbus laser, and a Δa sensor behind a
    bridge of its own as over Modbus."""
    with running(template, tmp_path / "m") as rig:
        hangs = [a if not a.startswith(f"127.0.0.1:{rig.sim_port}:20") else
                 "bridge:cmd:" + f"{sys.executable} -c 'import time; time.sleep(30)'"
                 for a in rig.commission_args()]  # fmt: skip
        proc = subprocess.run([sys.executable, *hangs], cwd=ROOT, capture_output=True,
                              text=True, timeout=120)  # fmt: skip
        assert proc.returncode == 1, proc.stdout + proc.stderr
        assert "--laser bridge:cmd:" in proc.stderr and "HELLO 1: no answer within 5 s" \
            in proc.stderr, proc.stderr  # fmt: skip
        assert not (rig.dir / "commission").exists()
        port = int(rig.sim.wait_line(r"laser bridge on 127\.0\.0\.1:(\d+)").group(1))
        # the sim's laser on the bridge protocol reads as its Modbus laser (a short plan:
        # commissioning through it end to end is the bench's)
        plan = tmp_path / "x.plan"
        write_plan(plan, Plan("iso", ("X",), tuple(Move(1, +1, "measure", (x,))
                                                   for x in (10.0, 40.0, 70.0))))  # fmt: skip
        (tmp_path / "delta_a_bridge.py").write_text(DELTA_A_BRIDGE)
        raws = {}
        for name, laser, delta_a in (
                ("bridge", f"bridge:tcp:127.0.0.1:{port}",
                 f"bridge:cmd:{sys.executable} {tmp_path / 'delta_a_bridge.py'} {rig.sim_port}"),
                ("modbus", f"127.0.0.1:{rig.sim_port}:20", f"127.0.0.1:{rig.sim_port}:22")):
            raws[name] = tmp_path / f"{name}.csv"
            done = subprocess.run([sys.executable, "-m", "gateway.cli", "calibrate", "-c",
                                   str(rig.config), "--gateway", f"127.0.0.1:{rig.gw_port}",
                                   "--plan", str(plan), "--no-progress", "--laser", laser,
                                   "--delta-a", delta_a, "--raw", str(raws[name])], cwd=ROOT,
                                  capture_output=True, text=True, timeout=60)  # fmt: skip
            assert done.returncode == 0, done.stdout + done.stderr
        bridge, modbus = read_raw_csv(raws["bridge"]), read_raw_csv(raws["modbus"])
        assert np.allclose(bridge.target_mm, modbus.target_mm)
        # two visits of each stop: the machine's repeatability (0.3-0.5 µm here) apart
        assert np.max(np.abs(bridge.deviation_mm - modbus.deviation_mm)) * 1000 < 2.0
        # the screw's growth at point A, a cold machine's: the same through either
        da = {n: np.asarray(d.extra["delta_a_mm"], float) for n, d in (("bridge", bridge),
                                                               ("modbus", modbus))}  # fmt: skip
        assert da["bridge"].size == 3 and np.allclose(da["bridge"], da["modbus"], atol=2e-4), da


def test_calibrate_with_a_gauge_typed_at_the_prompt(template: Path, tmp_path: Path) -> None:
    """Four targets on X read from a dial gauge: deviations typed, one typo, one read
    again; the raw file holds the targets plus the deviations."""
    with running(template, tmp_path / "m") as rig:
        plan = tmp_path / "x.plan"
        write_plan(plan, Plan("gauge", ("X",), tuple(Move(1, +1, "measure", (x,))
                                                     for x in (10.0, 30.0, 50.0, 70.0))))
        typed = "3.1\n\n-2,5\n\nnot\n1.0\nr\n1.5\n\n0\n\n"
        proc = subprocess.run([sys.executable, "-m", "gateway.cli", "calibrate", "-c",
                               str(rig.config), "--gateway", f"127.0.0.1:{rig.gw_port}",
                               "--plan", str(plan), "--no-progress",
                               "--laser", "manual:deviation", "--raw",
                               str(tmp_path / "gauge.csv")],
                              cwd=ROOT, input=typed, capture_output=True, text=True,
                              timeout=120)  # fmt: skip
        assert proc.returncode == 0, proc.stdout + proc.stderr
        assert "'not' is not a number" in proc.stdout
        raw = read_raw_csv(tmp_path / "gauge.csv")
        assert np.allclose(raw.target_mm, [10.0, 30.0, 50.0, 70.0])
        assert np.allclose(raw.deviation_mm * 1000, [3.1, -2.5, 1.5, 0.0], atol=1e-6), raw


def test_calibrate_from_the_laser_software_s_own_recording(tmp_path: Path) -> None:
    """The laser software records while compgw stands 0.3 s at each stop (the technician
    starts it before and stops it after, on the sim's laser over Modbus); compgw waits for
    the file, finds the stops, and its readings are the Modbus laser's within the machine's
    repeatability. A recording cut short is refused naming the file, nothing joined, and
    the same command carries on once the whole file is there. The same plan captured on
    stationary by the laser software (sim/capture.py, against the targets compgw writes),
    exported as config/capture-generic.yaml has it: an export one row short is refused
    naming the file and the missing reading; the whole export carries on, no moves, the
    Δa sensor compgw read at each stop beside the export's readings."""
    from pymodbus.client import ModbusTcpClient

    from tests.test_service_helpers import Proc

    directory = tmp_path / "t"
    small_machine(directory, seed=7)
    sim = yaml.safe_load((directory / "sim.yaml").read_text())
    sim["sim"]["instruments"]["laser"]["recording"] = {
        "dir": "recordings", "format": "rtx", "axis": "X", "rate_hz": 1000, "unit": "um",
        "idle_time_scale": 1.0}  # fmt: skip
    sim["sim"]["instruments"]["delta_a"] = {"unit": 22, "axis": "X", "a_mm": 0.0}
    (directory / "sim.yaml").write_text(yaml.safe_dump(sim, sort_keys=False))
    with running(directory, tmp_path / "m") as rig:
        plan = tmp_path / "x.plan"
        write_plan(plan, Plan("iso", ("X",), tuple(
            Move(1, d, "measure", (x,)) for x, d in ((10.0, 1), (30.0, 1), (50.0, 1),
                                                     (70.0, 1), (50.0, -1), (30.0, -1)))))
        laser_dir = tmp_path / "laser"
        laser_dir.mkdir()
        saved = rig.dir / "recordings"
        args = ["-m", "gateway.cli", "calibrate", "-c", str(rig.config), "--gateway",
                f"127.0.0.1:{rig.gw_port}", "--plan", str(plan), "--no-progress",
                "--dwell-s", "0.3"]  # fmt: skip
        laser = ModbusTcpClient("127.0.0.1", port=rig.sim_port)
        assert laser.connect()
        try:
            raw = tmp_path / "rec.csv"
            assert not laser.write_register(0x0100, 1, device_id=20).isError()  # start
            recording = [*args, "--laser", f"recording:{laser_dir}:um", "--raw", str(raw)]
            proc = Proc(recording)
            proc.wait_line(r"waiting for rec\.rtx in ", timeout_s=60)
            assert not laser.write_register(0x0100, 2, device_id=20).isError()  # stop, save
            number = laser.read_holding_registers(0x0101, count=1, device_id=20).registers[0]
            made = (saved / f"rec-{number:03d}.rtx").read_bytes()
            (laser_dir / "rec.rtx").write_bytes(made[: len(made) // 2])  # a copy cut short
            assert proc.popen.wait(timeout=60) == 3, proc.text()
            assert "rec.rtx: truncated" in proc.text() and "nothing fitted" in proc.text()
            assert not raw.exists() or not read_raw_csv(raw).target_mm.size
            (laser_dir / "rec.rtx").write_bytes(made)  # the whole file: carries on, no moves
            again = subprocess.run([sys.executable, *recording], cwd=ROOT, capture_output=True,
                                   text=True, timeout=60)  # fmt: skip
            assert again.returncode == 0, again.stdout + again.stderr
            assert "start the laser's recording" not in again.stdout
        finally:
            laser.close()
        reference = tmp_path / "modbus.csv"
        done = subprocess.run([sys.executable, *args, "--laser", f"127.0.0.1:{rig.sim_port}:20",
                               "--raw", str(reference)], cwd=ROOT, capture_output=True,
                              text=True, timeout=60)  # fmt: skip
        assert done.returncode == 0, done.stdout + done.stderr
        got, want = read_raw_csv(raw), read_raw_csv(reference)
        assert np.allclose(got.target_mm, want.target_mm)
        # the recording reads from its first stop (the laser zeroed there): deviations
        # relative to the first one's
        rec = (got.deviation_mm - got.deviation_mm[0]) * 1000
        mod = (want.deviation_mm - want.deviation_mm[0]) * 1000
        # two visits of each stop: each reading scatters by the machine's repeatability
        # (0.3-0.5 µm here) and the first stop's too, so a few µm between single readings
        assert np.max(np.abs(rec - mod)) < 3.0 and abs(np.mean(rec - mod)) < 1.5, (rec, mod)

        from sim.technician import WAITING, Technician

        export = laser_dir / "cap.csv"
        capture = [sys.executable, *args[:-1], "0.5", "--laser",
                   f"capture:{ROOT / 'config' / 'capture-generic.yaml'}:{laser_dir}",
                   "--raw", str(tmp_path / "cap.csv"), "--wait-start",
                   "--delta-a", f"127.0.0.1:{rig.sim_port}:22"]  # fmt: skip
        with Technician("127.0.0.1", rig.sim_port, 20, saved, "capture", source="rtx",
                        still_s=0.2) as tech:  # fmt: skip

            def loses_the_last_row(line: str, stdin: IO[str] | None) -> None:
                tech.hear(line, stdin)
                if WAITING.search(line):
                    whole = export.read_text()
                    export.write_text(whole[: whole.rstrip("\n").rfind("\n") + 1])
                    export.with_suffix(".whole").write_text(whole)

            cut = attend(capture, ROOT, 60.0, loses_the_last_row)
        assert cut.returncode == 3, cut.stdout + cut.stderr
        assert f"{export}: 5 readings, the plan has 6: the plan's reading 6 at 30.0000 mm " \
            "(run 1) is missing; nothing fitted" in cut.stderr, cut.stderr  # fmt: skip
        export.with_suffix(".whole").replace(export)
        again = subprocess.run(capture, cwd=ROOT, input="", capture_output=True, text=True,
                               timeout=60)  # the same command: no moves, the file read
        assert again.returncode == 0 and "start the laser's" not in again.stdout, again.stdout
        cap = read_raw_csv(tmp_path / "cap.csv")
        assert np.allclose(cap.target_mm, want.target_mm)
        # the Δa sensor read by compgw at each stop, kept through the refusal
        assert len(cap.extra["delta_a_mm"]) == 6, cap.extra
        # the laser zeroed once, at the first target: deviations from the first one's
        cap_rel = (cap.deviation_mm - cap.deviation_mm[0]) * 1000
        assert np.max(np.abs(cap_rel - mod)) < 3.0 and abs(np.mean(cap_rel - mod)) < 1.5, \
            (cap_rel, mod)  # fmt: skip


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
    small_machine(directory, seed=7)
    sim = yaml.safe_load((directory / "sim.yaml").read_text())
    sim["sim"]["instruments"]["laser"]["recording"] = {
        "dir": "recordings", "format": "csv", "axis": "X", "rate_hz": 250, "unit": "um",
        "idle_time_scale": 1.0}  # fmt: skip
    sim["sim"]["instruments"]["delta_a"] = {"unit": 22, "axis": "X", "a_mm": 0.0}
    (directory / "sim.yaml").write_text(yaml.safe_dump(sim, sort_keys=False))
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
                "is to record", stale.stderr), stale.stdout + stale.stderr  # fmt: skip
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


def test_a_recording_commissions_one_linear_axis(template: Path, tmp_path: Path) -> None:
    """A recording reads the one axis the laser is set up on: two axes or the plane are
    refused in one line, before anything is asked or moved."""
    args = [sys.executable, "-m", "gateway.cli", "commission", "-c",
            str(template / "gateway.yaml"), "--laser", f"recording:{tmp_path}", "--dry-run"]
    for extra in ([], ["--axes", "X,Y", "--xy-device", "127.0.0.1:1:21"]):
        out = subprocess.run([*args, *extra], cwd=ROOT, capture_output=True, text=True,
                             timeout=60)  # fmt: skip
        assert out.returncode == 1, out.stdout + out.stderr  # as any other bad option
        assert "a recording or capture reads one linear axis" in out.stderr
        assert "--axes X, then --axes Y" in out.stderr
