"""`compgw demo`, and the example configs running as they are, as separate processes."""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import yaml
from pymodbus.client import ModbusTcpClient

from gateway.modbus.frames import pack_int32, unpack_int32

ROOT = Path(__file__).resolve().parent.parent
CONFIG = ROOT / "config"


def compgw(*args: str, **kwargs) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "gateway.cli", *args],
        capture_output=True, text=True, timeout=120, cwd=ROOT, **kwargs,
    )


def test_demo_json_shows_compensation_cutting_the_systematic_error():
    result = compgw("demo", "--json")
    assert result.returncode == 0, result.stderr
    data = json.loads(result.stdout)
    for axis in ("X", "Y"):
        before, after = data["axes"][axis]["before"], data["axes"][axis]["after"]
        assert set(before) >= {"B_um", "E_um", "A_um"}
        assert before["E_um"] > 15.0  # the example machine has tens of µm of error
        assert after["E_um"] <= 0.1 * before["E_um"], (axis, before, after)
        assert after["A_um"] < 0.25 * before["A_um"]
        assert after["B_um"] < 0.2 * before["B_um"]
    xy = data["xy"]
    assert xy["before_max_um"] > 50.0  # 30" of squareness over 600 mm
    assert xy["after_max_um"] <= 0.1 * xy["before_max_um"]


def test_demo_prints_a_table():
    result = compgw("demo")
    assert result.returncode == 0, result.stderr
    assert re.search(r"^X\s+before\s+[\d.]+\s+[\d.]+", result.stdout, re.M)
    assert "XY max vector error" in result.stdout


def test_example_config_checks():
    result = compgw("check", "-c", str(CONFIG / "example.yaml"))
    assert result.returncode == 0, result.stderr
    assert re.search(r"planar: X/Y (grid|poly)", result.stdout), result.stdout


def _read_port(proc: subprocess.Popen[str], pattern: str, timeout_s: float = 20.0) -> int:
    """The port a process reports on stdout/stderr (it binds port 0)."""
    deadline = time.monotonic() + timeout_s
    assert proc.stdout is not None
    while time.monotonic() < deadline:
        line = proc.stdout.readline()
        if not line:
            if proc.poll() is not None:
                raise AssertionError(f"process ended: {proc.returncode}")
            continue
        match = re.search(pattern, line)
        if match:
            return int(match.group(1))
    raise AssertionError(f"no line matching {pattern!r}")


def test_example_configs_run_as_processes(tmp_path: Path):
    """`compgw sim` and `compgw run` with the example configs (ports moved to 0)."""
    sim_cfg = yaml.safe_load((CONFIG / "example-sim.yaml").read_text())
    sim_cfg["sim"]["tcp"]["port"] = 0
    sim_cfg["sim"]["time_scale"] = 0  # instant moves: the feedback is read right after
    (tmp_path / "sim.yaml").write_text(yaml.safe_dump(sim_cfg))
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    sim = subprocess.Popen(
        [sys.executable, "-m", "gateway.cli", "sim", "-c", str(tmp_path / "sim.yaml")],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, cwd=ROOT, env=env,
    )
    gw = None
    try:
        sim_port = _read_port(sim, r"modbus tcp on 127\.0\.0\.1:(\d+)")
        gw_cfg = yaml.safe_load((CONFIG / "example.yaml").read_text())
        gw_cfg["upstream"]["tcp"]["port"] = 0
        gw_cfg["buses"]["line1"]["tcp"]["port"] = sim_port
        for axis in gw_cfg["axes"].values():
            pitch = axis["compensation"]["pitch"]
            pitch["file"] = str(CONFIG / pitch["file"])
        gw_cfg["planar"]["model"] = str(CONFIG / gw_cfg["planar"]["model"])
        (tmp_path / "gw.yaml").write_text(yaml.safe_dump(gw_cfg))
        gw = subprocess.Popen(
            [sys.executable, "-m", "gateway.cli", "run", "-c", str(tmp_path / "gw.yaml")],
            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, cwd=ROOT, env=env,
        )
        port = _read_port(gw, r"listening on 127\.0\.0\.1:(\d+)")
        master = ModbusTcpClient("127.0.0.1", port=port, timeout=2)
        assert master.connect()
        try:
            target = list(pack_int32(250_000))
            assert not master.write_registers(0x6201, target, device_id=1).isError()
            assert not master.write_register(0x6002, 0x10, device_id=1).isError()
            rr = master.read_holding_registers(0x602A, count=2, device_id=1)
            assert unpack_int32(rr.registers, "hi_lo") == 250_000
        finally:
            master.close()
        status = compgw("status", "-c", str(tmp_path / "gw.yaml"))  # port 0 in the file
        assert status.returncode == 1 and "upstream.tcp.port is 0" in status.stderr
        assert "--port" in status.stderr
        status = compgw("status", "-c", str(tmp_path / "gw.yaml"), "--port", str(port))
        assert status.returncode == 0, status.stderr
        assert "axis X: compensation on, last target corrected" in status.stdout
        assert "targets committed 1" in status.stdout
        gw.send_signal(signal.SIGTERM)
        assert gw.wait(timeout=20) == 0
    finally:
        for proc in (gw, sim):
            if proc is not None and proc.poll() is None:
                proc.send_signal(signal.SIGTERM)
                proc.wait(timeout=20)


def test_demo_commission_runs_live_and_the_saved_run_is_shown() -> None:
    """`compgw demo --commission` commissions a random machine live (in seconds); plain
    `compgw demo` shows the saved run of it after the before/after table."""
    out = compgw("demo", "--commission")
    assert out.returncode == 0, out.stderr
    cuts = re.findall(r"^([XY]): E ([\d.]+) → ([\d.]+) µm as read", out.stdout, re.MULTILINE)
    assert len(cuts) == 2, out.stdout
    # the tables cut E (the drift-corrected figures where the machine's heat while
    # measuring made the as-read ones differ: the diagnosis beside them)
    for axis, before, after in cuts:
        off = re.search(rf"^{axis}: .*taken off \(diagnosis: heat\): E ([\d.]+) → ([\d.]+)",
                        out.stdout, re.MULTILINE)
        if off is not None:
            before, after = off.groups()
        assert float(after) < 0.35 * float(before), out.stdout
    assert re.search(r"XY max vector error [\d.]+ → [\d.]+ µm", out.stdout)
    assert "outcome: " in out.stdout
    saved = (ROOT / "config" / "commission-demo.txt").read_text()
    assert "outcome: " in saved and "round 1" in saved
