"""Raw-data CSV: reader errors, append-and-fsync writer, torn-line recovery, arrangement."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap

import numpy as np
import pytest

from gateway.calibration.plans.rawdata import (
    RawWriter,
    axis_deviations,
    deviations_by_axis,
    read_raw_csv,
)
from gateway.compensation.errors import TableError

HEADER = "axis,run,direction,target_mm,actual_mm,time_s\n"


def write(tmp_path, text: str):
    path = tmp_path / "raw.csv"
    path.write_text(text)
    return path


def test_read_keeps_extra_columns_and_lines(tmp_path) -> None:
    path = write(
        tmp_path,
        "# a run\n" + HEADER + "X,1,+,10,10.002,0.5\n\nX,1,-,10,10.004,1.5  # late\n",
    )
    raw = read_raw_csv(path)
    assert len(raw) == 2 and raw.lines == (3, 5)
    assert list(raw.direction) == [1, -1]
    assert raw.extra["time_s"] == ("0.5", "1.5")
    np.testing.assert_allclose(raw.column_mm("time_s"), [0.5, 1.5])
    np.testing.assert_allclose(raw.deviation_mm, [0.002, 0.004], atol=1e-12)


@pytest.mark.parametrize(
    ("body", "message"),
    [
        ("X,1,+,10,10.1,0\nX,1,*,10,10.1,0\n", r"line 3: direction '\*' is not \+ or -"),
        ("X,0,+,10,10.1,0\n", r"line 2: run '0' is not an integer >= 1"),
        ("X,1,+,ten,10.1,0\n", r"line 2: target_mm 'ten' is not a number"),
        ("X,1,+,10,nan,0\n", r"line 2: actual_mm 'nan' is not finite"),
        ("X,1,+,10,10.1\n", r"line 2: expected 6 comma-separated fields"),
        (",1,+,10,10.1,0\n", r"line 2: axis is empty"),
    ],
)
def test_malformed_lines_name_file_and_line(tmp_path, body: str, message: str) -> None:
    path = write(tmp_path, HEADER + body)
    with pytest.raises(TableError, match=message) as err:
        read_raw_csv(path)
    assert str(path) in str(err.value)


def test_missing_column_and_empty_file(tmp_path) -> None:
    with pytest.raises(TableError, match="lacks column"):
        read_raw_csv(write(tmp_path, "axis,run,target_mm,actual_mm\n"))
    with pytest.raises(TableError, match="empty"):
        read_raw_csv(write(tmp_path, "# nothing\n"))


def test_writer_appends_header_once_and_checks_it(tmp_path) -> None:
    path = tmp_path / "raw.csv"
    with RawWriter(path, ["time_s"]) as w:
        w.append("X", 1, +1, 10.0, 10.001, time_s=0.25)
    with RawWriter(path, ["time_s"]) as w:
        w.append("X", 1, "-", 10.0, 10.003)
    assert path.read_text().splitlines() == [
        "axis,run,direction,target_mm,actual_mm,time_s",
        "X,1,+,10.0,10.001,0.25",
        "X,1,-,10.0,10.003,",
    ]
    with pytest.raises(TableError, match="differs"):
        RawWriter(path)
    with RawWriter(path, ["time_s"]) as w, pytest.raises(ValueError, match="no column"):
        w.append("X", 1, 1, 1.0, 1.0, y_mm=3.0)


def test_writer_cuts_a_torn_last_line(tmp_path) -> None:
    path = tmp_path / "raw.csv"
    path.write_text("axis,run,direction,target_mm,actual_mm\nX,1,+,10.0,10.001\nX,1,-,10")
    with RawWriter(path) as w:
        w.append("X", 1, "-", 10.0, 10.004)
    raw = read_raw_csv(path)
    np.testing.assert_allclose(raw.actual_mm, [10.001, 10.004])


def test_killed_writer_loses_no_written_row(tmp_path) -> None:
    """A process killed (SIGKILL) right after append() returns has every row on disk."""
    path = tmp_path / "raw.csv"
    script = textwrap.dedent(
        f"""
        import os, signal
        from gateway.calibration.plans.rawdata import RawWriter
        w = RawWriter({str(path)!r})
        for k in range(25):
            w.append("X", 1 + k // 5, "+", float(k % 5), k % 5 + 0.001 * k)
        os.kill(os.getpid(), signal.SIGKILL)
        """
    )
    proc = subprocess.run([sys.executable, "-c", script], check=False)
    assert proc.returncode == -9
    raw = read_raw_csv(path)
    assert len(raw) == 25 and set(raw.run) == {1, 2, 3, 4, 5}
    assert os.path.getsize(path) == len(path.read_bytes())


def test_a_fast_writer_syncs_once_a_second_and_at_its_close(tmp_path, monkeypatch) -> None:
    """A simulated machine's readings come a hundred a second: the disk is asked once a
    second (and at the close), not at each; a machine's, seconds apart: at each."""
    import gateway.calibration.plans.rawdata as rawdata

    synced: list[int] = []
    real_fsync = os.fsync
    monkeypatch.setattr(rawdata.os, "fsync", lambda fd: (synced.append(fd), real_fsync(fd)))
    clock = [100.0]
    monkeypatch.setattr(rawdata.time, "monotonic", lambda: clock[0])
    with RawWriter(tmp_path / "raw.csv") as w:  # the header: synced
        for k in range(30):  # 10 ms apart: 0.3 s
            clock[0] += 0.01
            w.append("X", 1, "+", float(k), k + 0.001)
        assert len(synced) == 1
        clock[0] += 0.7  # a second after the header
        w.append("X", 2, "+", 0.0, 0.001)
        assert len(synced) == 2
        for k in range(3):  # a machine's: 2 s apart
            clock[0] += 2.0
            w.append("X", 3, "+", float(k), k + 0.001)
        assert len(synced) == 5
    assert len(synced) == 6 and len(read_raw_csv(tmp_path / "raw.csv")) == 34


def test_arrangement_per_target_run_direction(tmp_path) -> None:
    lines = [HEADER.strip()]
    rng = np.random.default_rng(3)
    truth_up = rng.normal(0, 0.01, (3, 2))
    truth_down = rng.normal(0, 0.01, (3, 2))
    targets = [5.0, 15.0, 25.0]
    for j in (1, 2):
        for i, t in enumerate(targets):
            lines.append(f"X,{j},+,{t + 1e-9 * j},{float(t + truth_up[i, j - 1])!r},0")
        for i in (2, 1, 0):
            lines.append(f"X,{j},-,{targets[i]},{float(targets[i] + truth_down[i, j - 1])!r},0")
        lines.append(f"Y,{j},+,1.0,1.5,0")
    raw = read_raw_csv(write(tmp_path, "\n".join(lines) + "\n"))
    dev = axis_deviations(raw, "X")
    np.testing.assert_allclose(dev.target_mm, targets, atol=1e-8)
    np.testing.assert_allclose(dev.up_mm, truth_up, atol=1e-8)
    np.testing.assert_allclose(dev.down_mm, truth_down, atol=1e-12)
    assert list(dev.runs) == [1, 2]
    both = deviations_by_axis(raw)
    assert list(both) == ["X", "Y"] and both["Y"].down_mm is None
    np.testing.assert_allclose(both["Y"].up_mm, [[0.5, 0.5]])


def test_duplicate_measurement_is_refused(tmp_path) -> None:
    path = write(tmp_path, HEADER + "X,1,+,10,10.1,0\nX,1,+,10,10.2,0\n")
    with pytest.raises(TableError, match="line 3: axis X run 1 target 10 mm direction \\+"):
        axis_deviations(read_raw_csv(path), "X")
