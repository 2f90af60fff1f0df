"""`compgw export`: LinuxCNC (types 0 and 1) and CSV round trips, FANUC-style parameters."""

from __future__ import annotations

import numpy as np
import pytest

from gateway.calibration.reporting.export import fanuc_pitch
from gateway.cli import main
from gateway.compensation import PitchTable
from gateway.formats import read_linuxcnc, read_pitch_csv, write_pitch_csv

LINUXCNC_1 = """\
0.0 0.0012 -0.0031
50.0 -0.0025 -0.0068
100.0 0.0101 0.0047
150.0 0.0003 -0.00405
200.0 -0.0112 -0.0154
"""


def numbers(path):
    return [[float(v) for v in line.split()] for line in path.read_text().splitlines()]


@pytest.mark.parametrize("comp_type", [0, 1])
def test_linuxcnc_file_to_compgw_table_and_back_is_identical_in_values(tmp_path, comp_type):
    src = tmp_path / f"x.comp{comp_type}"
    if comp_type == 1:
        src.write_text(LINUXCNC_1)
    else:  # type 0: nominal, actual going +, actual going −
        rows = [[float(v) for v in ln.split()] for ln in LINUXCNC_1.splitlines()]
        src.write_text("".join(f"{n} {n - f} {n - r}\n" for n, f, r in rows))
    table_csv = tmp_path / "x.csv"
    back = tmp_path / f"back.comp{comp_type}"
    assert main(["export", str(src), "--from", f"linuxcnc{comp_type}", "--to", "csv",
                 "-o", str(table_csv)]) == 0  # fmt: skip
    assert main(["export", str(table_csv), "--to", f"linuxcnc{comp_type}", "-o", str(back)]) == 0
    np.testing.assert_allclose(numbers(back), numbers(src), rtol=0, atol=1e-12)
    table = read_pitch_csv(table_csv)
    assert table.bidirectional and table.position_mm.size == 5


def test_linuxcnc_type_0_and_1_describe_the_same_table(tmp_path):
    src = tmp_path / "x.comp1"
    src.write_text(LINUXCNC_1)
    t1 = read_linuxcnc(src, 1)
    out0 = tmp_path / "x.comp0"
    assert main(["export", str(src), "--from", "linuxcnc1", "--to", "linuxcnc0",
                 "-o", str(out0)]) == 0  # fmt: skip
    t0 = read_linuxcnc(out0, 0)
    np.testing.assert_allclose(t0.forward_mm, t1.forward_mm, atol=1e-12)
    np.testing.assert_allclose(t0.reverse_mm, t1.reverse_mm, atol=1e-12)
    # type 1 holds trims (nominal − actual): the opposite of compgw's deviation
    assert t1.forward_mm[0] == pytest.approx(-0.0012)


def test_linuxcnc_needs_its_type(tmp_path, capsys):
    src = tmp_path / "x.comp"
    src.write_text(LINUXCNC_1)
    assert main(["export", str(src), "--to", "csv", "-o", str(tmp_path / "o.csv")]) == 1
    assert "--from" in capsys.readouterr().err


def smooth_table() -> PitchTable:
    x = np.linspace(0.0, 800.0, 33)
    dev = 0.03 * np.sin(x / 130.0) + 2.5e-5 * x
    return PitchTable(x, dev, dev + 0.012 + 4e-6 * x)


def test_fanuc_increments_rebuild_the_correction_within_half_a_step():
    table = smooth_table()
    fp = fanuc_pitch(table, interval_mm=25.0, reference_mm=0.0, reference_number=0)
    assert fp.interval_units == 25_000 and fp.negative_end == 0 and fp.positive_end == 32
    assert all(isinstance(v, int) for v in fp.increments) and fp.increments[0] == 0
    assert max(abs(v) for v in fp.increments) <= 7
    want = -(np.interp(fp.position_mm(), table.position_mm, table.forward_mm) - table.forward_mm[0])
    step = fp.magnification * fp.unit_mm
    assert np.abs(fp.correction_mm() - want).max() <= 0.5 * step + 1e-12
    assert fp.backlash_units == round(np.mean(table.reverse_mm - table.forward_mm) * 1000)


def test_fanuc_reference_in_the_middle_and_fixed_magnification():
    table = smooth_table()
    fp = fanuc_pitch(table, 50.0, reference_mm=400.0, reference_number=100, magnification=2,
                     max_increment=127)  # fmt: skip
    assert (fp.negative_end, fp.reference_number, fp.positive_end) == (92, 100, 108)
    assert fp.magnification == 2
    corr = fp.correction_mm()
    assert corr[fp.reference_number - fp.negative_end] == 0.0
    want = -(np.interp(fp.position_mm(), table.position_mm, table.forward_mm)
             - np.interp(400.0, table.position_mm, table.forward_mm))  # fmt: skip
    assert np.abs(corr - want).max() <= 0.5 * 2 * 0.001 + 1e-12


def test_fanuc_export_file(tmp_path):
    src = tmp_path / "x.csv"
    write_pitch_csv(src, smooth_table())
    out = tmp_path / "x.fanuc"
    assert main(["export", str(src), "--to", "fanuc", "-o", str(out), "--interval-mm", "25"]) == 0
    text = out.read_text()
    for param in ("3620,0", "3621,0", "3622,32", "3624,25000", "point,value", "\n32,"):
        assert param in text
