"""The sim config: the example loads, bad files fail with one line naming the YAML path."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from sim.config import SimConfigError, load_config, parse_config
from sim.server import SimServer
from tests.test_sim_support import EXAMPLE, ROOT, Master, example_dict, run, tcp_client


def test_example_loads() -> None:
    cfg = load_config(EXAMPLE)
    assert list(cfg.sim.axes) == ["X", "Y"]
    assert cfg.sim.axes["X"].registers.target.address == 0x6201


@pytest.mark.parametrize(
    ("edit", "expected"),
    [
        (
            lambda d: d["sim"]["axes"]["X"]["registers"]["target"].update(address=70000),
            "sim.axes.X.registers.target.address: 70000 is not in 0..65535",
        ),
        (
            lambda d: d["sim"]["axes"]["X"].update(pulse_mm=-1),
            "sim.axes.X.pulse_mm: -1: input should be greater than 0",
        ),
        (
            lambda d: d["sim"]["axes"]["Y"].update(colour="red"),
            "sim.axes.Y.colour: unknown key",
        ),
        (
            lambda d: d["sim"]["axes"]["Y"].update(unit=1),
            "sim.axes.Y.unit: 1 is already used by axes.X",
        ),
        (
            lambda d: d["sim"]["axes"]["X"]["registers"]["speed"].update(address=0x6202),
            "sim.axes.X.registers: target (0x6201) overlaps speed (0x6202)",
        ),
        (
            lambda d: d["sim"]["machine"]["X"]["pitch"].update(table={"path": "nope.csv"}),
            "sim.machine.X.pitch.table:",
        ),
    ],
)
def test_bad_config_names_the_path(edit, expected: str) -> None:
    data = example_dict()
    edit(data)
    with pytest.raises(SimConfigError) as err:
        parse_config(data, EXAMPLE.parent)
    message = str(err.value)
    assert "\n" not in message
    assert expected in message, message


def test_pitch_table_from_real_data(tmp_path: Path) -> None:
    """A measured curve (one of ../shared/data/real) is accepted as a pitch table."""
    csv = tmp_path / "pitch.csv"
    csv.write_text("target_mm,dev_fwd_um\n0,0\n400,,\n400,-10\n800,5\n")
    data = example_dict()
    data["sim"]["machine"]["X"]["pitch"] = {
        "table": {"path": str(csv), "position_column": "target_mm", "error_column": "dev_fwd_um"}
    }
    data["sim"]["machine"]["X"]["repeatability_um"] = 0.0
    data["sim"]["machine"]["X"].pop("thermal")
    data["sim"]["instruments"].pop("delta_a")
    data["sim"]["instruments"]["laser"]["noise_um"] = 0.0
    cfg = parse_config(data, tmp_path)

    async def script() -> list[float]:
        async with SimServer(cfg, tcp_port=0) as server:
            m = Master(await tcp_client(server.tcp_port), data)
            out = []
            for x_mm in (200.0, 600.0):
                await m.move_mm("X", x_mm)
                out.append(await m.laser_um("X") - x_mm * 1000)
            m.client.close()
            return out

    # linear between the table points (blank rows skipped): -5 um at 200, -2.5 um at 600
    assert run(script()) == pytest.approx([-5.0, -2.5], abs=0.06)


def test_sim_never_imports_the_correction() -> None:
    """Truth and correction are written independently."""
    for path in (ROOT / "sim").glob("*.py"):
        text = path.read_text()
        assert "gateway.compensation" not in text.replace("``gateway.compensation``", "")
        assert "import gateway" not in text and "from gateway" not in text, path


def test_cli_runtime_fault_exits_3(tmp_path: Path) -> None:
    data = example_dict()
    data["sim"]["tcp"]["port"] = 0
    data["sim"]["rtu"] = {"port": str(tmp_path / "no-such-tty")}
    cfg = tmp_path / "sim.yaml"
    cfg.write_text(yaml.safe_dump(data))
    proc = _cli(cfg)
    _out, err = proc.communicate(timeout=30)
    assert proc.returncode == 3
    assert len(err.strip().splitlines()) == 1, err


def _cli(config: Path, *extra: str) -> subprocess.Popen:
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    return subprocess.Popen(
        [sys.executable, "-m", "gateway.cli", "sim", "-c", str(config), *extra],
        cwd=ROOT,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
    )


def test_cli_bad_config_exits_1_with_one_line(tmp_path: Path) -> None:
    data = example_dict()
    data["sim"]["axes"]["X"]["registers"]["target"]["address"] = 70000
    bad = tmp_path / "bad.yaml"
    bad.write_text(yaml.safe_dump(data))
    proc = _cli(bad)
    _out, err = proc.communicate(timeout=30)
    assert proc.returncode == 1
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert "sim.axes.X.registers.target.address: 70000 is not in 0..65535" in lines[0]


def test_cli_runs_and_stops_on_sigterm(tmp_path: Path) -> None:
    data = example_dict()
    data["sim"]["tcp"]["port"] = 0
    good = tmp_path / "sim.yaml"
    good.write_text(yaml.safe_dump(data))
    proc = _cli(good)
    try:
        assert proc.stdout is not None
        line = proc.stdout.readline()  # blocks until the server prints its bound port
        assert "modbus tcp on 127.0.0.1:" in line, line
        assert int(line.rsplit(":", 1)[1]) > 0
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(timeout=30) == 0
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
