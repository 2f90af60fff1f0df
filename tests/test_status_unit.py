"""The gateway's status unit: live state and counters; control only when allowed."""

from __future__ import annotations

import asyncio
import subprocess
import sys
import zlib
from pathlib import Path

import yaml

from gateway.compensation import AxisInput
from gateway.modbus.frames import unpack_int32
from gateway.status import format_status
from tests.gateway_rig import TARGET, rig
from tests.test_gateway_e2e import PITCH_X, move, read32, run, with_pitch

STATUS_UNIT = 247


def with_thermal(data):
    with_pitch(data)
    data["thermal_sources"] = {
        "x_ref": {"bus": "line1", "unit": 10, "register": {"address": 1, "words": 2},
                  "scale_mm": 1e-6, "poll_s": 0.05, "noise_mm": 0.0015}
    }
    data["axes"]["X"]["compensation"]["thermal"] = {"source": "x_ref", "length_mm": 800}


def test_status_reports_state_counters_and_sources(tmp_path: Path):
    async def body():
        async with rig(tmp_path, with_thermal, {"x.csv": PITCH_X}) as r:
            master, chain = r["master"], r["chain"]
            await move(master, 1, 300_000)
            await move(master, 2, 100_000)
            await move(master, 2, 50_000)
            rr = await master.read_input_registers(0, count=120, device_id=STATUS_UNIT)
            assert not rr.isError()
            regs = rr.registers
            assert regs[0] == 4 and regs[1] == 2
            assert regs[2] & 0b100 == 0  # every drive answers
            assert unpack_int32(regs[3:5], "hi_lo", signed=False) == 3  # commits
            x = regs[16:24]
            assert x[0] & 0b111011 == 0b1011  # enabled, corrected, thermal; answers; corrects
            expected = chain.command_pulses("X", {"X": AxisInput(300_000, 1)}) - 300_000
            assert unpack_int32(x[1:3], "hi_lo") == expected * 10  # 0.1 µm units
            y = regs[24:32]
            assert y[0] & 0b111 == 0b111  # enabled, corrected, last move was −
            assert unpack_int32(y[1:3], "hi_lo") == -50  # −B/2 = −5 µm
            assert regs[80] in (0, 1)  # the source is starting or ok
            text = format_status(["X", "Y"], ["x_ref"], regs)
            assert "axis Y: compensation on" in text and "direction -" in text
            assert "last correction -5.0 µm, Δa" in text
            # a rotary axis's registers hold 0.1 millidegrees: said in arcseconds
            turned = format_status(["X", "Y"], ["x_ref"], regs, rotary=frozenset({"Y"}))
            assert "axis Y: compensation on" in turned and "last correction -18.0″" in turned
            assert turned.split("axis Y")[1].split("\n")[0].count("µm") == 0
            # the loaded file's CRC-32: `compgw status -c FILE` says whether FILE is running
            path = r["config_path"]
            crc = zlib.crc32(path.read_bytes())
            assert unpack_int32(regs[14:16], "hi_lo", signed=False) == crc
            assert f"config: {path} is what it loaded" in format_status(
                ["X", "Y"], ["x_ref"], regs, (str(path), crc))  # fmt: skip
            assert f"config: NOT {path}" in format_status(
                ["X", "Y"], ["x_ref"], regs, (str(path), crc ^ 1))  # fmt: skip
            # holding registers: the switches; writing them is refused by default
            rr = await master.read_holding_registers(0, count=2, device_id=STATUS_UNIT)
            assert rr.registers == [1, 1]
            rr = await master.write_register(0, 0, device_id=STATUS_UNIT)
            assert rr.isError() and rr.exception_code == 0x01
            rr = await master.read_input_registers(120, count=20, device_id=STATUS_UNIT)
            assert rr.isError() and rr.exception_code == 0x02

    run(body())


def test_status_names_a_silent_drive_and_an_axis_given_nothing(tmp_path: Path):
    """A drive that stops answering on a bus that is up (cut wire, power, wrong unit id):
    the status unit says which axis and how many requests in a row, and forgets it at the
    drive's next reply; an axis whose config corrects nothing is said to be so (trial 7:
    "bus down: no" and "compensation on" while Y's drive was silent and had no table)."""
    def only_x(data):
        with_pitch(data)
        data["axes"]["Y"]["compensation"] = {}

    async def body():
        async with rig(tmp_path, only_x, {"x.csv": PITCH_X}) as r:
            master, direct = r["master"], r["direct"]
            assert not (await direct.write_register(2 * 8, 1, device_id=250)).isError()
            for _ in range(2):
                rr = await master.read_holding_registers(TARGET, count=2, device_id=2)
                assert rr.isError() and rr.exception_code == 0x0B
            regs = (await master.read_input_registers(0, count=120,
                                                      device_id=STATUS_UNIT)).registers
            assert regs[2] & 0b110 == 0b100  # the bus is up, a drive is silent
            assert regs[16] & 0b110000 == 0  # X answers and corrects
            assert regs[24] & 0b110000 == 0b110000 and regs[31] == 2
            text = format_status(["X", "Y"], [], regs)
            assert "bus down: no; drive not answering: YES" in text
            assert "axis Y: its DRIVE IS NOT ANSWERING: the last 2 request(s)" in text
            assert "axis Y: compensation on (the config gives it nothing to correct)" in text
            assert "axis X: compensation on, " in text
            assert not (await direct.write_register(0x0804, 1, device_id=250)).isError()
            assert not (await master.read_holding_registers(TARGET, count=2,
                                                            device_id=2)).isError()
            regs = (await master.read_input_registers(0, count=120,
                                                      device_id=STATUS_UNIT)).registers
            assert regs[2] & 0b100 == 0 and regs[24] & 0b10000 == 0 and regs[31] == 0
            assert "NOT ANSWERING" not in format_status(["X", "Y"], [], regs)
            # `compgw status` asking at a unit the gateway does not serve: its exception in
            # words, one line (it was pymodbus's repr)
            other = yaml.safe_load(r["config_path"].read_text())
            other["status"] = {"upstream_unit": 246}
            copy = tmp_path / "other.yaml"
            copy.write_text(yaml.safe_dump(other))
            out = await asyncio.to_thread(
                subprocess.run, [sys.executable, "-m", "gateway.cli", "status", "-c", str(copy),
                                 "--port", str(r["app"].tcp_port)],
                capture_output=True, text=True, timeout=60)  # fmt: skip
            assert out.returncode == 3 and out.stderr.splitlines() == [
                f"compgw status: 127.0.0.1:{r['app'].tcp_port} answered exception 0x0a "
                f"(gateway path unavailable) at unit 246: is it a compgw gateway, running "
                f"{copy}'s status.upstream_unit?"], out.stderr  # fmt: skip

    run(body())


def test_remote_control_switches_compensation_when_allowed(tmp_path: Path):
    def allow(data):
        with_pitch(data)
        data["status"] = {"upstream_unit": STATUS_UNIT, "remote_control": True}

    async def body():
        async with rig(tmp_path, allow, {"x.csv": PITCH_X}) as r:
            master, direct = r["master"], r["direct"]
            assert not (await master.write_register(0, 0, device_id=STATUS_UNIT)).isError()
            await move(master, 1, 300_000)
            assert await read32(direct, 1, TARGET) == 300_000  # sent as written
            assert not (await master.write_register(0, 1, device_id=STATUS_UNIT)).isError()
            await move(master, 1, 310_000)
            assert await read32(direct, 1, TARGET) != 310_000
            rr = await master.write_register(0, 2, device_id=STATUS_UNIT)
            assert rr.isError() and rr.exception_code == 0x03

    run(body())
