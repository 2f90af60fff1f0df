"""Calibration in degrees (issue 16): `compgw fit` of a swing axis (the linkage by least
squares, the table for the rest, interpolation by cross-validation), `compgw report` in
arcseconds and degrees, `compgw export` to LinuxCNC and FANUC rotary forms."""

from __future__ import annotations

import contextlib
import io
import json
import subprocess
from pathlib import Path

import numpy as np
import pytest
import yaml

from gateway.calibration.plans.rawdata import RawWriter
from gateway.cli import build_parser
from gateway.compensation import LinkageModel, PitchTable
from gateway.demos.seed003 import axis_data, gateway_data
from gateway.formats import read_linkage, read_linuxcnc, read_pitch_csv, write_linkage
from gateway.formats.pitch_csv import write_pitch_csv

TRUE = LinkageModel(arm_mm=150.0, base_mm=450.0, phi0_deg=74.4, mm_per_deg=2.59144,
                    offset_mm=10.0, zero_deg=0.0)  # fmt: skip
DRAWING = TRUE.with_values(base_mm=451.0, phi0_deg=75.0, mm_per_deg=2.59)


def compgw(*args: str) -> subprocess.CompletedProcess[str]:
    """``compgw ARGS`` in this process (the parser and the command a user runs), its exit
    code and output as a finished process's."""
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        parsed = build_parser().parse_args(list(args))
        code = int(parsed.func(parsed))
    return subprocess.CompletedProcess(list(args), code, out.getvalue(), err.getvalue())


def swing_raw(path: Path, runs: int = 2) -> None:
    """An identification run of a swing axis: the linkage, a screw ripple, 0.0008 deg of
    play, 0.1" of noise; targets every 0.5 deg, ISO cycle order."""
    rng = np.random.default_rng(5)
    targets = np.arange(-14.0, 13.01, 0.5)
    path.write_text("# kind: iso230-linear\n# axis: A\n# unit: deg\n# compensation: off\n")
    with RawWriter(path) as raw:
        for run in range(1, runs + 1):
            for sign, order in ((1, targets), (-1, targets[::-1])):
                for t in order:
                    actual = TRUE.actual_deg(t) + 2e-4 * np.sin(t) + (sign < 0) * 8e-4
                    raw.append("A", run, sign, float(t), float(actual + rng.normal(0, 3e-5)))


def test_fit_a_swing_axis_writes_the_linkage_and_the_table_for_the_rest(tmp_path: Path):
    write_linkage(tmp_path / "a_linkage.yaml", DRAWING, "the drawing")
    comp = {"pitch": {"file": "a_pitch.csv", "interpolation": "linear"},
            "linkage": "a_linkage.yaml"}
    (tmp_path / "gw.yaml").write_text(yaml.safe_dump(
        gateway_data(5021, {"A": axis_data(1, (-14.5, 13.5), False, comp)})))
    swing_raw(tmp_path / "a.csv")
    result = compgw("fit", str(tmp_path / "a.csv"), "-c", str(tmp_path / "gw.yaml"))
    assert result.returncode == 0, result.stderr
    out = result.stdout
    assert "(linkage: base_mm" in out and "the table holds the rest" in out
    assert "interpolation by leave-one-out: smooth" in out
    assert "set axes.A.compensation.pitch.interpolation: smooth" in out
    fitted = read_linkage(tmp_path / "a_linkage.yaml")
    grid = np.linspace(-14.5, 13.5, 200)
    mean = TRUE.actual_deg(grid) + 4e-4  # the model follows both directions' mean
    assert np.abs(fitted.actual_deg(grid) - mean).max() < 2.5e-4  # the ripple is the table's
    table = read_pitch_csv(tmp_path / "a_pitch.csv")
    assert table.rotary and table.position_mm.min() < -13.9  # the model's angles, deg
    assert np.abs(table.forward_mm).max() < 7e-4  # what the linkage left: ripple, half the play
    mean_reversal = np.mean(table.reverse_mm - table.forward_mm)
    assert abs(mean_reversal - 8e-4) < 1e-4


def test_report_of_a_rotary_axis_is_in_arcseconds_and_degrees(tmp_path: Path):
    swing_raw(tmp_path / "a.csv")
    result = compgw("report", str(tmp_path / "a.csv"), "--json")
    assert result.returncode == 0, result.stderr
    figures = json.loads(result.stdout)["A"]
    assert figures["unit"] == "deg" and "A_um" not in figures
    assert abs(figures["E_arcsec"] - figures["E_deg"] * 3600) < 1e-9
    assert 300 < figures["E_arcsec"] < 450  # the linkage's 0.095 deg and the play
    assert abs(figures["B_arcsec"] - 2.88) < 0.3  # 0.0008 deg of play
    result = compgw("report", str(tmp_path / "a.csv"), "--out", str(tmp_path / "rep"))
    assert result.returncode == 0, result.stderr
    page = (tmp_path / "rep" / "report.html").read_text()
    assert "axis A (arcsec)" in page and "target deg" in page and "°)" in page
    assert "in arcseconds (and degrees) over targets in degrees" in page
    linear = compgw("report", str(tmp_path / "a.csv"), "--json", "--unit", "mm")
    assert "E_um" in json.loads(linear.stdout)["A"]


def test_export_turntable_and_swing_tables_to_rotary_forms(tmp_path: Path):
    pos = np.arange(0.0, 360.0, 30.0)
    dev = 1e-3 * (np.sin(np.radians(pos)) + 0.5)  # deg
    write_pitch_csv(tmp_path / "c.csv", PitchTable(pos, dev, dev + 3e-3, rotary=True))
    result = compgw("export", str(tmp_path / "c.csv"), "-o", str(tmp_path / "c.comp"),
                    "--to", "linuxcnc0", "--turn")
    assert result.returncode == 0, result.stderr
    lines = (tmp_path / "c.comp").read_text().split("\n")
    assert float(lines[-2].split()[0]) == 360.0  # closed: the first point one turn later
    back = read_linuxcnc(tmp_path / "c.comp", 0)
    np.testing.assert_allclose(back.forward_mm[:-1], dev, atol=1e-7)  # the CSV's decimals
    assert abs(back.forward_mm[-1] - back.forward_mm[0]) < 1e-12
    result = compgw("export", str(tmp_path / "c.comp"), "--from", "linuxcnc0", "--unit", "deg",
                    "-o", str(tmp_path / "back.csv"), "--to", "csv")
    assert result.returncode == 0, result.stderr
    assert "position_deg,forward_mdeg,reverse_mdeg" in (tmp_path / "back.csv").read_text()

    result = compgw("export", str(tmp_path / "c.csv"), "-o", str(tmp_path / "c.fanuc"),
                    "--to", "fanuc", "--turn", "--interval-mm", "15", "--max-increment", "127")
    assert result.returncode == 0, result.stderr
    text = (tmp_path / "c.fanuc").read_text()
    params = dict(line.split(",") for line in text.split("point,value")[0].splitlines()
                  if line and not line.startswith("#") and line != "parameter,value")
    assert params["3625"] == "360000" and params["3624"] == "15000"
    assert int(params["3622"]) - int(params["3621"]) == 24  # 0..360 every 15 deg
    points = [int(v.split(",")[1]) for v in text.split("point,value\n")[1].splitlines()]
    assert len(points) == 25 and sum(points[1:]) == 0  # one turn: back to where it started
    assert points[0] == points[-1]  # the reference point takes the last one's value
    assert "0.001 deg" in text and "rotary axis type" in text

    swing = compgw("export", str(tmp_path / "c.csv"), "-o", str(tmp_path / "s.fanuc"),
                   "--to", "fanuc", "--max-increment", "127")
    assert swing.returncode == 0 and "3625" not in (tmp_path / "s.fanuc").read_text()
    bad = compgw("export", str(tmp_path / "c.comp"), "--from", "linuxcnc0", "--turn",
                 "-o", str(tmp_path / "x.csv"), "--to", "csv")
    assert bad.returncode == 1 and "--turn needs a table in degrees" in bad.stderr
    # a table fitted from runs that began at 3° (3…357°): LinuxCNC still gets 0…360°, the
    # value at 0° read around the circle, the same at both ends
    late = pos + 3.0
    write_pitch_csv(tmp_path / "late.csv", PitchTable(late, dev, dev + 3e-3, rotary=True))
    result = compgw("export", str(tmp_path / "late.csv"), "-o", str(tmp_path / "late.comp"),
                    "--to", "linuxcnc0", "--turn")
    assert result.returncode == 0, result.stderr
    back = read_linuxcnc(tmp_path / "late.comp", 0)
    assert back.position_mm[0] == 0.0 and back.position_mm[-1] == 360.0
    at_zero = np.interp(0.0, late, dev, period=360.0)
    assert back.forward_mm[0] == pytest.approx(at_zero, abs=1e-7)
    assert back.forward_mm[-1] == pytest.approx(at_zero, abs=1e-7)
    # a swing axis's table (−14…13°) is no turn
    write_pitch_csv(tmp_path / "a.csv", PitchTable(np.linspace(-14, 13, 10), dev[:10],
                                                   None, rotary=True))  # fmt: skip
    bad = compgw("export", str(tmp_path / "a.csv"), "-o", str(tmp_path / "a.comp"),
                 "--to", "linuxcnc0", "--turn")
    assert bad.returncode == 1 and "--turn is for a turntable's table" in bad.stderr
