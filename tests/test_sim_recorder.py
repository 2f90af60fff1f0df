"""The sim laser's continuous recording (sim/recorder.py): .rtx and CSV files as a laser's
dynamic capture writes them, read back here with a reader of the test's own (never the
gateway's). Dwells are idle wall time on an injected wall clock (deterministic): at
time_scale 0 a wall second is 1 / idle_time_scale seconds of standstill in the recording.
Expected sample counts come from the YAML numbers (travel / speed + dwells)."""

from __future__ import annotations

import math
import re
import struct
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from sim.config import SimConfigError, parse_config
from sim.server import SimServer
from tests.test_sim_support import EXAMPLE, Master, example_dict, run, tcp_client

LASER_UNIT = 20
SPEED_MM_S = 100.0  # the example's axes (speed register 0)
DWELL_WALL_S = 0.04  # x 1/0.02 = 2 s of standstill in the recording


class FakeWall:
    """A wall clock the test moves by hand."""

    def __init__(self) -> None:
        self.now_s = 1000.0

    def __call__(self) -> float:
        return self.now_s


def recording_dict(**recording: Any) -> dict[str, Any]:
    """The example machine (time_scale 0, 1 µm pulses) with the laser recording axis X."""
    data = example_dict()
    data["sim"]["tcp"]["port"] = 0
    data["sim"]["instruments"]["laser"]["recording"] = {"axis": "X", **recording}
    return data


def read_rtx(path: Path) -> tuple[dict[str, str], np.ndarray]:
    """A minimal .rtx reader: HEADER::, Key: value lines, Data:, float64 LE, EOF::."""
    raw = path.read_bytes()
    assert raw.startswith(b"HEADER::\r\n") and raw.endswith(b"EOF::\r\n")
    head, _, rest = raw.partition(b"Data:\r\n")
    fields: dict[str, str] = {}
    for line in head.decode("ascii").split("\r\n")[1:]:
        if line:
            key, sep, value = line.partition(": ")
            assert sep, line
            fields[key] = value
    data = rest[: -len(b"EOF::\r\n")]
    assert len(data) % 8 == 0
    return fields, np.array(struct.unpack(f"<{len(data) // 8}d", data))


def plateaus(values: np.ndarray, step: float, min_len: int) -> list[tuple[int, int, float]]:
    """Runs of at least ``min_len`` samples whose neighbours differ by less than ``step``:
    (first index, length, median)."""
    out: list[tuple[int, int, float]] = []
    start = 0
    for i in range(1, values.size + 1):
        if i == values.size or abs(values[i] - values[i - 1]) >= step:
            if i - start >= min_len:
                out.append((start, i - start, float(np.median(values[start:i]))))
            start = i
    return out


async def moves_with_dwells(master: Master, wall: FakeWall, targets_mm: list[float]) -> list[float]:
    """Move X to each target and dwell there; the Modbus laser's reading at each stop (µm)."""
    readings = []
    for target in targets_mm:
        await master.move_mm("X", target)
        wall.now_s += DWELL_WALL_S
        readings.append(await master.laser_um("X"))
    return readings


def expected_samples(targets_mm: list[float], rate_hz: float, idle_scale: float = 0.02) -> int:
    """Samples over the moves (travel / speed) and the dwells, one at t = 0 included."""
    here, move_s = 0.0, 0.0
    for target in targets_mm:
        move_s += abs(target - here) / SPEED_MM_S
        here = target
    total_s = move_s + len(targets_mm) * DWELL_WALL_S / idle_scale
    return math.floor(total_s * rate_hz + 1e-9) + 1


def test_rtx_recording_over_moves_and_dwells(tmp_path: Path) -> None:
    data = recording_dict(format="rtx", rate_hz=200, unit="um")
    targets = [100.0, 250.0, 180.0]
    wall = FakeWall()

    async def body() -> list[float]:
        cfg = parse_config(data, EXAMPLE.parent)
        async with SimServer(cfg, wall_s=wall) as server:
            client = await tcp_client(server.tcp_port)
            recorder = server.sim.recorder
            assert recorder is not None
            recorder.start()
            readings = await moves_with_dwells(Master(client, data), wall, targets)
            assert recorder.stop(tmp_path / "run.rtx") == tmp_path / "run.rtx"
            client.close()
            return readings

    readings = run(body())
    fields, values = read_rtx(tmp_path / "run.rtx")
    assert list(fields)[:3] == ["Owner", "Version no", "File Type"]
    assert fields["Owner"] == "CARTO-Dynamic" and fields["File Type"] == "Dynamic"
    assert fields["Sample rate"] == "200" and fields["Actual sample rate"] == "200.0"
    assert fields["Axis"] == "X" and fields["Flags"] == "0 0 0"
    assert re.fullmatch(r"\d\d/\d\d/\d{4} \d\d:\d\d:\d\d", fields["Date"])
    assert int(fields["Sample no"]) == values.size == expected_samples(targets, 200)
    # three stops of 2 s each, where the Modbus laser read them (its noise 0.05 µm, 0.1 µm
    # resolution; the recording's 0.02 µm)
    stops = plateaus(values, step=0.5, min_len=300)
    assert [round(n / 200) for _i, n, _m in stops] == [2, 2, 2], stops
    for (_i, _n, median_um), laser_um in zip(stops, readings, strict=True):
        assert abs(median_um - laser_um) <= 0.3
    # moving between them at 100 mm/s: 500 µm per sample; the ringing right after a stop
    assert np.abs(np.diff(values)).max() > 400
    first_stop_end = stops[0][0]
    assert np.abs(values[first_stop_end - 8 : first_stop_end] - stops[0][2]).max() > 0.5


def test_csv_columns_clock_offset_and_drop(tmp_path: Path) -> None:
    data = recording_dict(format="csv", unit="mm", rate_hz=100, csv_columns=["value", "time"],
                          clock_offset_s=12.5, drop_s=[1.0, 1.5])  # fmt: skip
    targets = [50.0, 20.0]
    wall = FakeWall()

    async def body() -> list[float]:
        async with SimServer(parse_config(data, EXAMPLE.parent), wall_s=wall) as server:
            client = await tcp_client(server.tcp_port)
            recorder = server.sim.recorder
            assert recorder is not None
            recorder.start()
            readings = await moves_with_dwells(Master(client, data), wall, targets)
            recorder.stop(tmp_path / "run.csv")
            client.close()
            return readings

    readings = run(body())
    lines = (tmp_path / "run.csv").read_text().splitlines()
    assert lines[0] == "position_mm,time_s"
    rows = [line.split(",") for line in lines[1:]]
    values_mm = np.array([float(v) for v, _t in rows])
    times_s = np.array([float(t) for _v, t in rows])
    assert rows[0][1] == "12.500000" and all(len(t.split(".")[1]) == 6 for _v, t in rows)
    # 100 Hz over 0.5 + 0.3 s of moves and 2 × 2 s of dwells, less the 0.5 s dropped
    assert len(rows) == expected_samples(targets, 100) - 50
    assert not np.any((times_s >= 12.5 + 1.0 - 1e-6) & (times_s < 12.5 + 1.5 - 1e-6))
    gaps = np.diff(times_s)
    assert np.allclose(np.delete(gaps, np.argmax(gaps)), 0.01, atol=1e-6)
    assert gaps.max() == pytest.approx(0.51, abs=1e-6)
    assert abs(values_mm[-1] * 1000 - readings[-1]) <= 0.5  # mm, where the laser read it


def test_modbus_control_writes_rec_files(tmp_path: Path) -> None:
    data = recording_dict(dir="recs", format="rtx")  # relative to the config file
    wall = FakeWall()

    async def body() -> None:
        async with SimServer(parse_config(data, tmp_path), wall_s=wall) as server:
            client = await tcp_client(server.tcp_port)
            master = Master(client, data)

            async def control() -> list[int]:
                rr = await client.read_holding_registers(0x0100, count=2, device_id=LASER_UNIT)
                assert not rr.isError(), rr
                return rr.registers

            assert await control() == [0, 0]
            stop = await client.write_register(0x0100, 2, device_id=LASER_UNIT)
            assert stop.isError() and stop.exception_code == 0x04  # not recording
            assert not (await client.write_register(0x0100, 1, device_id=LASER_UNIT)).isError()
            assert await control() == [1, 0]
            again = await client.write_register(0x0100, 1, device_id=LASER_UNIT)
            assert again.isError() and again.exception_code == 0x04  # already recording
            await moves_with_dwells(master, wall, [30.0])
            assert not (await client.write_register(0x0100, 2, device_id=LASER_UNIT)).isError()
            assert await control() == [0, 1]
            fields, values = read_rtx(tmp_path / "recs" / "rec-001.rtx")
            assert int(fields["Sample no"]) == values.size == expected_samples([30.0], 200)
            # a second recording, as FC16 of one register: rec-002
            assert not (await client.write_registers(0x0100, [1], device_id=LASER_UNIT)).isError()
            assert not (await client.write_registers(0x0100, [2], device_id=LASER_UNIT)).isError()
            assert (tmp_path / "recs" / "rec-002.rtx").is_file()
            assert (await control())[1] == 2
            # everything else stays read-only
            for address, value, code in ((0x0100, 3, 0x03), (0x0101, 1, 0x02), (0, 1, 0x02)):
                rr = await client.write_register(address, value, device_id=LASER_UNIT)
                assert rr.isError() and rr.exception_code == code, (address, value, rr)
            names = sorted(p.name for p in (tmp_path / "recs").iterdir())
            assert names == ["rec-001.rtx", "rec-002.rtx"]  # no temporary file left behind
            client.close()

    run(body())


def test_time_scale_above_0_records_wall_time_as_machine_time(tmp_path: Path) -> None:
    data = recording_dict(format="rtx", rate_hz=100, ringing_um=0.0, vibration_um=0.0)
    data["sim"]["time_scale"] = 1.0
    wall = FakeWall()

    async def body() -> float:
        async with SimServer(parse_config(data, EXAMPLE.parent), wall_s=wall) as server:
            client = await tcp_client(server.tcp_port)
            master = Master(client, data)
            recorder = server.sim.recorder
            assert recorder is not None
            recorder.start()
            await master.move_mm("X", 50.0)  # 0.5 s of machine time = of wall time
            wall.now_s += 2.0
            reading = await master.laser_um("X")
            recorder.stop(tmp_path / "run.rtx")
            client.close()
            return reading

    reading = run(body())
    fields, values = read_rtx(tmp_path / "run.rtx")
    assert values.size == int(fields["Sample no"]) == 201  # 2 s at 100 Hz, no idle added
    assert abs(values[-1] - reading) <= 0.3
    assert abs(values[40] - values[-1]) > 1000  # 0.4 s in, still on the way (40 mm of 50)


def test_recording_leaves_the_truth_alone() -> None:
    """The same moves read the same on the Modbus laser with and without a recording."""

    async def readings(with_recording: bool) -> list[float]:
        data = recording_dict() if with_recording else example_dict()
        data["sim"]["tcp"]["port"] = 0
        wall = FakeWall()
        async with SimServer(parse_config(data, EXAMPLE.parent), wall_s=wall) as server:
            client = await tcp_client(server.tcp_port)
            if server.sim.recorder is not None:
                server.sim.recorder.start()
            out = await moves_with_dwells(Master(client, data), wall, [120.0, 80.0, 300.0])
            client.close()
            return out

    assert run(readings(True)) == run(readings(False))


@pytest.mark.parametrize(
    ("recording", "expected"),
    [
        ({"axis": "Z"}, "recording.axis: 'Z' is not a laser channel"),
        ({"drop_s": [2.0, 1.0]}, "drop_s: [2.0, 1.0] must be [start_s, end_s]"),
        ({"csv_columns": ["time", "time"]}, "csv_columns"),
        ({"format": "txt"}, "recording.format"),
    ],
)
def test_bad_recording_config_is_one_line(recording: dict, expected: str) -> None:
    data = example_dict()
    data["sim"]["instruments"]["laser"]["recording"] = recording
    with pytest.raises(SimConfigError) as err:
        parse_config(data, EXAMPLE.parent)
    assert expected in str(err.value), str(err.value)
