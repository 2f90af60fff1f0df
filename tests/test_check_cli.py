"""`compgw check`: a valid config prints the resolved setup; bad ones exit 1 with one line."""

from __future__ import annotations

import contextlib
import copy
import io
import json
import socket
import subprocess
import sys
from pathlib import Path

import yaml

from gateway.cli import main as cli_main
from gateway.config import json_schema
from tests.test_config import BASE

ROOT = Path(__file__).resolve().parent.parent

def _config() -> dict:
    """The bad-config table's base, plus a pitch table, a planar model and no sources."""
    config = copy.deepcopy(BASE)
    del config["thermal_sources"], config["axes"]["X"]["registers"]["status"]
    config["axes"]["X"]["compensation"] = {
        "pitch": {"file": "tables/x.csv", "interpolation": "smooth"},
        "max_correction_mm": 0.2,
    }
    config["axes"]["Y"]["compensation"] = {"backlash_mm": 0.008}
    config["planar"] = {"axes": ["X", "Y"], "model": "tables/xy.yaml"}
    return config


CONFIG = _config()


def _compgw(*args: object) -> subprocess.CompletedProcess:  # type: ignore[type-arg]
    """``compgw ARGS`` in this process (no interpreter to start per call, as a process's
    would): its exit code (a parser's SystemExit too), stdout and stderr."""
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            rc = cli_main([str(a) for a in args])
        except SystemExit as exc:
            rc = int(exc.code or 0)
    return subprocess.CompletedProcess(list(args), rc, out.getvalue(), err.getvalue())


def _write(tmp_path: Path, x_csv: str, config=CONFIG) -> Path:
    (tmp_path / "tables").mkdir(exist_ok=True)
    (tmp_path / "tables" / "x.csv").write_text(x_csv)
    rows = "".join(
        f"{x},{y},{0.145 * y / 1000 * 1000:.3f},{0.02 * x:.3f}\n"
        for x in (0, 200, 400, 600, 800)
        for y in (0, 300, 600)
    )
    (tmp_path / "tables" / "xy.csv").write_text("x_mm,y_mm,dx_um,dy_um\n" + rows)
    (tmp_path / "tables" / "xy.yaml").write_text("points: xy.csv\nmodel: poly\n")
    path = tmp_path / "gw.yaml"
    path.write_text(yaml.safe_dump(config))
    return path


def _check(path: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "gateway.cli", "check", "-c", str(path)],
        capture_output=True,
        text=True,
        timeout=60,
        cwd=ROOT,
    )


GOOD_X = "position_mm,forward_um,reverse_um\n0,0,10\n400,12,22\n800,25,35\n"


def test_check_prints_the_resolved_setup(tmp_path: Path):
    result = _check(_write(tmp_path, GOOD_X))
    assert result.returncode == 0, result.stderr
    out = result.stdout
    assert "X: upstream unit 1 -> line1 unit 1" in out
    assert "trigger 0x6002 on value 0x10" in out
    assert "3 points, bidirectional, smooth" in out
    assert "backlash 8.0 µm (mean)" in out
    assert "planar: X/Y poly degree 1" in out
    assert "metrics: off" in out and "state file: none (a restart starts every" in out
    config = copy.deepcopy(CONFIG)
    config["passthrough"] = {20: {"bus": "line1", "unit": 20}}
    config["metrics"] = {"port": 9108}
    config["state_file"] = "run/state.json"
    out = _check(_write(tmp_path, GOOD_X, config)).stdout
    assert "passthrough: upstream unit 20 -> line1 unit 20" in out
    assert "metrics: 127.0.0.1:9108" in out and "state file: run/state.json" in out


def test_check_refuses_a_bad_table_naming_file_and_line(tmp_path: Path):
    bad = "position_mm,forward_um,reverse_um\n0,0,10\n400,12\n800,25,35\n"
    result = _check(_write(tmp_path, bad))
    assert result.returncode == 1
    assert result.stderr.count("\n") == 1
    assert "x.csv: line 3: expected 3 comma-separated fields" in result.stderr


def test_check_refuses_a_correction_above_the_cap(tmp_path: Path):
    big = "position_mm,forward_um,reverse_um\n0,0,10\n400,250,260\n800,25,35\n"
    result = _check(_write(tmp_path, big))
    assert result.returncode == 1
    assert "x.csv: line 3 (position 400 mm): forward correction 0.25 mm exceeds" in result.stderr


def test_check_refuses_pitch_plus_planar_above_the_cap(tmp_path: Path):
    config = json.loads(json.dumps(CONFIG))
    config["axes"]["X"]["compensation"]["max_correction_mm"] = 0.1
    result = _check(_write(tmp_path, GOOD_X, config))
    assert result.returncode == 1
    assert "axes.X.compensation: correction 112.0 µm at X=800, Y=600 mm" in result.stderr


def test_check_refuses_a_bad_config_naming_the_field(tmp_path: Path):
    config = json.loads(json.dumps(CONFIG))
    config["axes"]["X"]["registers"]["target"]["address"] = 70000
    result = _check(_write(tmp_path, GOOD_X, config))
    assert result.returncode == 1
    assert "axes.X.registers.target.address: 70000 is not in 0..65535" in result.stderr


def test_schema_file_is_generated_from_the_models():
    committed = json.loads((ROOT / "config" / "schema.json").read_text())
    assert committed == json_schema(), "run: make schema"


def test_status_with_no_gateway_says_so_in_one_line(tmp_path: Path):
    """No gateway listening: one line, compgw's own, not also the Modbus library's."""
    with socket.socket() as s:  # a loopback port just free: nobody listens there
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    out = subprocess.run([sys.executable, "-m", "gateway.cli", "status", "-c",
                          "config/example.yaml", "--port", str(port)],
                         capture_output=True, text=True, timeout=60, cwd=ROOT)  # fmt: skip
    assert out.returncode == 3
    assert out.stderr.splitlines() == [f"compgw status: no gateway at 127.0.0.1:{port}"], out.stderr


def test_a_reader_that_stops_reading_ends_no_traceback():
    """`compgw check … | head`: the pipe closed early is not an error to show."""
    root = Path(__file__).resolve().parent.parent
    proc = subprocess.Popen([sys.executable, "-m", "gateway.cli", "check", "-c",
                             str(root / "config" / "example.yaml")], cwd=root,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE)  # fmt: skip
    assert proc.stdout is not None and proc.stderr is not None
    proc.stdout.close()  # before it writes a line
    err = proc.stderr.read().decode()
    assert proc.wait(timeout=60) == 0 and "Traceback" not in err and "BrokenPipe" not in err, err
    proc.stderr.close()


def test_a_command_line_out_of_range_is_one_line_before_anything(tmp_path: Path):
    """Numbers out of range, and a --verify --iterate with no table to fold into: one line
    each naming the option, no usage text before it, no traceback, nothing moved (no
    gateway or instrument is listening: a run would have failed otherwise)."""
    no_pitch = yaml.safe_load((ROOT / "config" / "example.yaml").read_text())
    no_pitch["axes"]["X"]["compensation"].pop("pitch")
    (tmp_path / "gw.yaml").write_text(yaml.safe_dump(no_pitch))
    base = ["--laser", "127.0.0.1:1:20", "--raw", str(tmp_path / "x.csv"),
            "--gateway", "127.0.0.1:1"]  # fmt: skip
    cases = [
        (["status", "-c", ROOT / "config/example.yaml", "--port", "70000"], 2,
         "compgw status: argument --port: 70000 must be at most 65535 (TCP port)"),
        (["calibrate", "-c", ROOT / "config/example.yaml", "--iso", "X", "--step-mm", "0",
          *base], 2,
         "compgw calibrate: argument --step-mm: 0 must be above 0 (mm)"),
        (["calibrate", "-c", ROOT / "config/example.yaml", "--iso", "X", "--verify",
          "--tolerance-um", "-2", *base], 2,
         "compgw calibrate: argument --tolerance-um: -2 must be above 0 (µm)"),
        (["commission", "-c", ROOT / "config/example.yaml", "--laser", "127.0.0.1:1:20",
          "--budget-h", "nan"], 2, "compgw commission: argument --budget-h: nan must be above 0"),
        (["calibrate", "-c", str(tmp_path / "gw.yaml"), "--iso", "X", "--verify",
          "--iterate", "2", *base], 1,
         "compgw calibrate: --verify --iterate folds into axis X's pitch table, and "
         "axes.X.compensation.pitch names none"),
    ]  # fmt: skip
    for argv, code, line in cases:
        out = _compgw(*argv)
        assert out.returncode == code, (argv, out.stderr)
        lines = out.stderr.splitlines()
        assert len(lines) == 1 and lines[0].startswith(line), (argv, out.stderr)
    assert not (tmp_path / "x.csv").exists()


def test_a_config_commissioning_left_behind_is_named(tmp_path: Path):
    """A commissioning killed mid-run leaves its identification config loaded (tables
    off): `check` (and `status`, `run`'s log) say so. And a config naming tables that are
    gone (commission/ removed to start over) is refused before commissioning begins: an
    abort would put it back, and the gateway would refuse it."""
    text = (ROOT / "config" / "example.yaml").read_text()
    tables = ROOT / "config" / "tables"
    (tmp_path / "tables").symlink_to(tables)
    left = tmp_path / "gw.yaml"
    left.write_text("# written by compgw commission (identification config): your own config "
                    "is kept in commission/original.yaml\n" + text)  # fmt: skip
    out = _compgw("check", "-c", left)
    assert out.returncode == 0, out.stderr
    assert (f"compgw check: warning: {left}: compgw commission's identification config, left "
            "by a commissioning that did not finish") in out.stderr, out.stderr
    assert "put your own config back (commission/original.yaml)" in out.stderr
    final = tmp_path / "final.yaml"
    final.write_text("# written by compgw commission (full config): your own config is kept "
                     "in x.yaml\n" + text)  # fmt: skip
    out = _compgw("check", "-c", final)
    assert "did not finish" not in out.stderr, out.stderr

    gone = yaml.safe_load(text)
    gone["axes"]["X"]["compensation"]["pitch"]["file"] = "commission/tables/x_pitch.csv"
    (tmp_path / "gone.yaml").write_text(yaml.safe_dump(gone))
    out = _compgw("commission", "-c", tmp_path / "gone.yaml", "--laser", "127.0.0.1:1:20")
    assert out.returncode == 1, out.stderr
    assert out.stderr.splitlines() == [out.stderr.strip()], out.stderr
    assert "gone.yaml does not load as it is (axes.X.compensation.pitch.file:" in out.stderr
    assert "commission/tables/x_pitch.csv: file not found" in out.stderr
    assert not (tmp_path / "commission").exists()


def _check_example_with(tmp_path: Path, change) -> subprocess.CompletedProcess:  # type: ignore[no-untyped-def,type-arg]
    """``compgw check`` of config/example.yaml changed by ``change(data)`` (its tables
    beside it); it must load."""
    data = yaml.safe_load((ROOT / "config" / "example.yaml").read_text())
    change(data)
    (tmp_path / "tables").symlink_to(ROOT / "config" / "tables")
    (tmp_path / "gw.yaml").write_text(yaml.safe_dump(data))
    out = _compgw("check", "-c", tmp_path / "gw.yaml")
    assert out.returncode == 0, out.stderr
    return out


def test_check_shows_a_take_up_curve(tmp_path: Path):
    """A take-up curve (as commissioning fits it) is in the axis's compensation line."""
    out = _check_example_with(tmp_path, lambda d: d["axes"]["X"]["compensation"].update(
        takeup={"reversal_um": [0.0, 3.0, 8.0], "fraction": [0.0, 0.6, 1.0]}))
    assert "take-up curve (3 points, all of the lost motion by 8.0 µm of reversal)" in out.stdout


def test_check_warns_of_a_baud_rate_no_device_offers(tmp_path: Path):
    """baudrate: 11520 (a digit short) loads, and is said to be no standard rate."""
    out = _check_example_with(tmp_path, lambda d: d["upstream"].update(
        rtu={"port": "/dev/ttyUSB9", "baudrate": 11520}))
    assert ("compgw check: warning: upstream.rtu.baudrate: 11520 is no standard rate "
            "(9600, 19200, 38400, 57600, 115200, …): a typo?") in out.stderr, out.stderr
    assert "buses." not in out.stderr  # the example's TCP buses have no baud rate


def test_commission_refuses_a_drive_that_writes_its_eeprom_on_every_bus_write(tmp_path: Path):
    """Trial 9: an Inovance drive left writing EEPROM took 1849 and 2014 writes in one
    commissioning. Refused in one line, before anything is asked or moved."""
    data = copy.deepcopy(BASE)
    x = data["axes"]["X"]
    x.pop("registers", None)
    x["profile"] = "inovance-sv660p"
    path = tmp_path / "gw.yaml"
    path.write_text(yaml.safe_dump(data))
    out = _compgw("commission", "-c", path, "--gateway", "127.0.0.1:1",
                  "--laser", "127.0.0.1:1:20")  # fmt: skip
    assert out.returncode == 1, out
    assert out.stderr.splitlines() == [
        "compgw commission: axes.X: the inovance-sv660p drive writes every bus write to EEPROM "
        "by default, and commissioning writes thousands of targets: keep them in RAM on the "
        "drive (H0C.13 = 0 (address 0x0C0D): bus writes to RAM only), then set "
        "ram_setting_applied: true in the config"], out.stderr  # fmt: skip
    assert not (tmp_path / "commission").exists()
    out = _compgw("calibrate", "-c", path, "--iso", "X", "--gateway", "127.0.0.1:1",
                  "--laser", "127.0.0.1:1:20", "--raw", tmp_path / "raw.csv")  # fmt: skip
    assert out.returncode != 0 and "axes.X: the inovance-sv660p drive writes every bus write " \
        "to EEPROM by default, and a calibration writes thousands" in out.stderr, out
    assert not (tmp_path / "raw.csv").exists()


def test_check_lists_every_mistake_and_guesses_a_misspelt_key(tmp_path: Path):
    config = json.loads(json.dumps(CONFIG))
    config["axes"]["X"]["home_directon"] = 1  # trial: a typo stopped at the first error
    config["axes"]["X"]["registers"]["target"]["address"] = 70000
    config["axes"]["Y"]["pulse_mm"] = -1
    result = _check(_write(tmp_path, GOOD_X, config))
    assert result.returncode == 1
    lines = result.stderr.splitlines()
    assert "axes.X.home_directon: unknown key (did you mean 'home_direction'?)" in lines[1]
    assert any("axes.X.registers.target.address: 70000 is not in 0..65535" in x for x in lines)
    assert any("axes.Y.pulse_mm: -1 must be > 0" in x for x in lines)
    assert len(lines) == 3


def test_status_reaches_the_live_gateway_past_a_typo_in_an_axis(tmp_path: Path):
    import asyncio

    import yaml

    from tests.gateway_rig import rig

    async def body() -> subprocess.CompletedProcess[str]:
        async with rig(tmp_path) as r:
            data = yaml.safe_load(r["config_path"].read_text())
            data["axes"]["X"]["home_directon"] = 1
            data["upstream"]["tcp"]["port"] = r["app"].tcp_port
            broken = tmp_path / "typo.yaml"
            broken.write_text(yaml.safe_dump(data))
            return await asyncio.to_thread(subprocess.run, [
                sys.executable, "-m", "gateway.cli", "status", "-c", str(broken)],
                capture_output=True, text=True, timeout=60, cwd=ROOT)

    out = asyncio.run(body())
    assert out.returncode == 0, out.stderr
    assert "axes.X.home_directon: unknown key (did you mean 'home_direction'?)" in out.stderr
    assert "the gateway is asked all the same" in out.stderr
    assert "X" in out.stdout and "Y" in out.stdout
