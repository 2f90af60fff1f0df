"""Table files: compgw CSV, LinuxCNC types 0 and 1, planar points and model files."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from gateway.compensation import PitchTable, PolyModel, TableError
from gateway.formats import (
    atomic_write_text,
    load_planar_model,
    read_linuxcnc,
    read_pitch_csv,
    read_planar_csv,
    write_linuxcnc,
    write_pitch_csv,
)
from gateway.formats.linuxcnc import format_linuxcnc

GOOD_CSV = """\
# X axis, laser run 2026-11-02
position_mm,forward_um,reverse_um
0,0.0,11.8
100,2.5,14.0   # a comment after the values

200,-3.25,9.0
"""


def test_csv_reads_units_lines_and_direction(tmp_path: Path):
    path = tmp_path / "x.csv"
    path.write_text(GOOD_CSV)
    table = read_pitch_csv(path)
    np.testing.assert_array_equal(table.position_mm, [0, 100, 200])
    np.testing.assert_allclose(table.forward_mm, [0, 0.0025, -0.00325])
    np.testing.assert_allclose(table.reverse_mm, [0.0118, 0.014, 0.009])
    assert table.lines == (3, 4, 6)
    assert table.bidirectional


def test_csv_unidirectional_and_rotary_forms(tmp_path: Path):
    (tmp_path / "u.csv").write_text("position_mm,error_um\n0,1\n10,2\n")
    assert not read_pitch_csv(tmp_path / "u.csv").bidirectional
    (tmp_path / "e.csv").write_text("position_mm,forward_um,reverse_um\n0,1,\n10,2,\n")
    assert not read_pitch_csv(tmp_path / "e.csv").bidirectional
    (tmp_path / "r.csv").write_text("position_deg,forward_mdeg\n0,1.5\n180,-2\n")
    rotary = read_pitch_csv(tmp_path / "r.csv")
    assert rotary.rotary
    np.testing.assert_allclose(rotary.forward_mm, [0.0015, -0.002])


@pytest.mark.parametrize(
    ("body", "message"),
    [
        ("position_mm,forward_um,reverse_um\n0,0,0\n100,abc,0\n", r"line 3: forward_um 'abc'"),
        ("position_mm,forward_um,reverse_um\n0,0,0\n100,1\n", r"line 3: expected 3 comma"),
        ("position_mm,forward_um,reverse_um\n0,0,0\n100,1,2,3\n", r"line 3: expected 3 comma"),
        ("position_mm,forward_um,reverse_um\n0,0,0\n100,nan,0\n", r"line 3: forward_um 'nan'"),
        ("position_mm,forward_um,reverse_um\n0,0,\n100,1,2\n", r"line 2: reverse_um is empty"),
        ("pos,err\n0,0\n", r"line 1: header 'pos,err'"),
        ("# only a comment\n", r"empty table"),
        ("position_mm,error_um\n", r"no points after the header"),
        ("position_mm,error_um\n0,1\n0,2\n", r"line 3 \(position 0 mm\).*increase by at least"),
    ],
)
def test_csv_bad_line_names_file_and_line(tmp_path: Path, body: str, message: str):
    path = tmp_path / "bad.csv"
    path.write_text(body)
    with pytest.raises(TableError, match=message) as info:
        read_pitch_csv(path)
    assert str(path) in str(info.value)
    assert "\n" not in str(info.value)


def test_csv_missing_and_binary_files(tmp_path: Path):
    with pytest.raises(TableError, match="file not found"):
        read_pitch_csv(tmp_path / "nope.csv")
    (tmp_path / "bin.csv").write_bytes(b"\xff\xfe\x00garbage")
    with pytest.raises(TableError, match="not a UTF-8 text file"):
        read_pitch_csv(tmp_path / "bin.csv")


def test_csv_write_read_round_trip_is_exact(tmp_path: Path):
    rng = np.random.default_rng(11)
    # positions to 1 nm and deviations to 0.1 nm, what is written: read back exactly
    pos = np.round(np.sort(rng.uniform(0, 800, 50)) + np.arange(50), 6)
    table = PitchTable(pos, np.round(rng.normal(0, 0.01, 50), 7),
                       np.round(rng.normal(0, 0.01, 50), 7))
    write_pitch_csv(tmp_path / "t.csv", table, comment="fitted by a test")
    back = read_pitch_csv(tmp_path / "t.csv")
    np.testing.assert_array_equal(back.position_mm, table.position_mm)
    np.testing.assert_allclose(back.forward_mm, table.forward_mm, rtol=0, atol=1e-15)
    np.testing.assert_allclose(back.reverse_mm, table.reverse_mm, rtol=0, atol=1e-15)


LINUXCNC_TYPE0 = """\
0.000000 0.000000 -0.001279
100.000000 100.001258 99.998742
200.000000 200.002100 199.999000
"""


def test_linuxcnc_type0_and_type1_mean_the_same_table(tmp_path: Path):
    (tmp_path / "t0.comp").write_text(LINUXCNC_TYPE0)
    t0 = read_linuxcnc(tmp_path / "t0.comp", 0)
    np.testing.assert_allclose(t0.forward_mm, [0.0, 0.001258, 0.0021], atol=1e-12)
    np.testing.assert_allclose(t0.reverse_mm, [-0.001279, -0.001258, -0.001], atol=1e-12)
    # type 1 stores trim = nominal - actual
    (tmp_path / "t1.comp").write_text(format_linuxcnc(t0, 1))
    t1 = read_linuxcnc(tmp_path / "t1.comp", 1)
    np.testing.assert_allclose(t1.forward_mm, t0.forward_mm, atol=1e-12)
    first = (tmp_path / "t1.comp").read_text().splitlines()[1].split()
    assert float(first[1]) == pytest.approx(-0.001258)


@pytest.mark.parametrize("comp_type", [0, 1])
def test_linuxcnc_round_trip_is_identical_in_values(tmp_path: Path, comp_type: int):
    rng = np.random.default_rng(comp_type)
    nominal = np.arange(0.0, 805.0, 12.5)
    fwd = rng.normal(0, 0.01, nominal.size).round(6)
    rev = rng.normal(0, 0.01, nominal.size).round(6)
    cols = (nominal, nominal + fwd, nominal + rev) if comp_type == 0 else (nominal, fwd, rev)
    text = "".join(f"{a:.6f} {b:.6f} {c:.6f}\n" for a, b, c in zip(*cols))
    (tmp_path / "in.comp").write_text(text)
    table = read_linuxcnc(tmp_path / "in.comp", comp_type)
    write_linuxcnc(tmp_path / "out.comp", table, comp_type)
    original = np.loadtxt(tmp_path / "in.comp")
    rewritten = np.loadtxt(tmp_path / "out.comp")
    np.testing.assert_allclose(rewritten, original, rtol=0, atol=1e-12)


def test_linuxcnc_malformed_line_is_an_error_not_a_short_table(tmp_path: Path):
    path = tmp_path / "x.comp"
    path.write_text("0 0 0\n10 10.001 9.999\n20 20.001\n30 30 30\n")
    with pytest.raises(TableError, match=r"x\.comp: line 3: expected 3 numbers"):
        read_linuxcnc(path, 0)


def test_write_is_atomic_and_leaves_no_partial_file(tmp_path: Path):
    path = tmp_path / "t.csv"
    path.write_text("old content\n")
    with pytest.raises(TypeError):
        atomic_write_text(path, 12345)  # type: ignore[arg-type]  # the write itself fails
    assert path.read_text() == "old content\n"
    assert [p.name for p in tmp_path.iterdir()] == ["t.csv"]
    atomic_write_text(path, "new\n")
    assert path.read_text() == "new\n"


def test_planar_points_and_model_file(tmp_path: Path):
    xs, ys = np.meshgrid(np.linspace(0, 800, 5), np.linspace(0, 600, 4))
    rows = "".join(
        f"{x},{y},{30 / 206.265 * y / 1000:.4f},{0.01 * x:.4f}\n"
        for x, y in zip(xs.ravel(), ys.ravel())
    )
    (tmp_path / "xy.csv").write_text("x_mm,y_mm,dx_um,dy_um\n" + rows)
    meas = read_planar_csv(tmp_path / "xy.csv")
    assert meas.command_mm.shape == (20, 2)
    (tmp_path / "m.yaml").write_text("points: xy.csv\nmodel: poly\ndegree: auto\n")
    assert isinstance(load_planar_model(tmp_path / "m.yaml"), PolyModel)
    (tmp_path / "g.yaml").write_text("points: xy.csv\nmodel: grid\nmethod: linear\n")
    assert load_planar_model(tmp_path / "g.yaml").kind == "grid"
    (tmp_path / "bad.yaml").write_text("points: xy.csv\nmodel: spline\n")
    with pytest.raises(TableError, match=r"bad\.yaml: model: 'spline'"):
        load_planar_model(tmp_path / "bad.yaml")
    (tmp_path / "bad2.yaml").write_text("points: xy.csv\nsmoothing: 3\n")
    with pytest.raises(TableError, match="unknown key 'smoothing'"):
        load_planar_model(tmp_path / "bad2.yaml")
    (tmp_path / "xy_bad.csv").write_text("x_mm,y_mm,dx_um,dy_um\n0,0,1,1\n1,2,x,1\n")
    with pytest.raises(TableError, match=r"xy_bad\.csv: line 3: dx_um 'x'"):
        read_planar_csv(tmp_path / "xy_bad.csv")


def test_written_tables_carry_no_float_noise(tmp_path: Path) -> None:
    """Positions on a 0.001 mm pulse grid (104570 × 0.001 = 104.56999999999998 in binary)
    are written as 104.57; deviations to 0.1 nm; what is read back is what was meant."""
    from gateway.compensation import PitchTable
    from gateway.formats import read_pitch_csv, write_pitch_csv

    pos = np.arange(104_570, 104_620, 10) * 0.001
    assert repr(float(pos[0])) != "104.57"  # binary float noise
    table = PitchTable(pos, np.full(5, 0.1 + 0.2) * 1e-3, np.full(5, -0.3) * 1e-3)
    write_pitch_csv(tmp_path / "t.csv", table)
    text = (tmp_path / "t.csv").read_text()
    assert "104.57,0.3,-0.3" in text and "104.6,0.3,-0.3" in text
    assert "9999" not in text and "0000000" not in text
    back = read_pitch_csv(tmp_path / "t.csv")
    assert np.allclose(back.position_mm, pos, atol=1e-9)
