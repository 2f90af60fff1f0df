"""Commissioning and calibration with the instruments a technician owns, end to end with
real processes: the sim's laser on the bridge protocol (as a vendor SDK wrapped in a short
script would answer), and a gauge typed at the prompt (scripted through stdin)."""

from __future__ import annotations

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
from tests.commission_rig import recording_machine, running, small_machine

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
    recording_machine(directory, "rtx", 1000)
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
