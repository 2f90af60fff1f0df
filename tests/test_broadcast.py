"""Broadcasts (unit 0) from an RTU master on a pty and from a TCP master: a broadcast
trigger moves every axis to its *corrected* target, a broadcast target write reaches each
drive corrected (never the nominal value), and an RTU master gets no reply."""

from __future__ import annotations

import asyncio
import time
from pathlib import Path

import serial

from gateway.compensation import AxisInput
from gateway.modbus.frames import (
    build_read_request,
    build_write_multiple_registers,
    build_write_single_register,
    find_rtu_frame,
    pack_int32,
    rtu_encode,
    rtu_response_length,
)
from tests.gateway_rig import FEEDBACK, TARGET, TRIGGER, rig
from tests.helpers_modbus import RawTcpMaster, run, wait_for_condition
from tests.test_gateway_e2e import PITCH_X, read32, with_pitch


def edit(data: dict) -> None:
    with_pitch(data)  # X: pitch table, Y: backlash: both corrections differ from nominal
    data["buses"]["line1"]["turnaround_s"] = 0.02


class RawRtuMaster:
    """An RTU master writing raw frames on its end of a pty."""

    def __init__(self, path: str) -> None:
        self.port = serial.Serial(path, timeout=0)
        self.buf = b""

    def send(self, unit: int, pdu: bytes) -> None:
        self.port.write(rtu_encode(unit, pdu))

    async def next_frame(self, timeout_s: float = 3.0) -> bytes:
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            self.buf += self.port.read(4096)
            scan = find_rtu_frame(self.buf, rtu_response_length)
            if scan.frame is not None:
                self.buf = b""
                return scan.frame
            await asyncio.sleep(0.002)
        raise TimeoutError(f"no RTU reply, got {self.buf.hex()}")

    async def request(self, unit: int, pdu: bytes) -> bytes:
        self.send(unit, pdu)
        frame = await self.next_frame()
        assert frame[0] == unit, f"a reply for unit {frame[0]}: {frame.hex()}"
        return frame[1:-2]

    def close(self) -> None:
        self.port.close()


def corrected(chain, name: str, nominal: int, direction: int = 1) -> int:
    return chain.command_pulses(name, {name: AxisInput(nominal, direction)})


async def drive_at(direct, unit: int) -> tuple[int, int]:
    """(target register, feedback) of a drive, asked directly."""
    return await read32(direct, unit, TARGET), await read32(direct, unit, FEEDBACK)


READ_FEEDBACK = build_read_request(3, FEEDBACK, 2)
fc16, fc06 = build_write_multiple_registers, build_write_single_register


def test_rtu_broadcasts_move_every_axis_corrected_and_get_no_reply(tmp_path: Path) -> None:
    async def body() -> None:
        async with rig(tmp_path, edit, {"x.csv": PITCH_X}, drives="rtu", upstream="rtu") as r:
            r["master"].close()
            master = RawRtuMaster(r["upstream_line"].b)
            direct, chain, app = r["direct"], r["chain"], r["app"]
            try:
                # unicast targets, one broadcast trigger starts both axes
                assert await master.request(1, fc16(TARGET, list(pack_int32(300_000))))
                assert await master.request(2, fc16(TARGET, list(pack_int32(200_000))))
                bus = app.buses["line1"]
                master.send(0, fc06(TRIGGER, 0x10))
                await wait_for_condition(lambda: bus.counters.broadcasts == 1)
                # the next frame on the line answers the next request: none for the broadcast
                reply = await master.request(1, READ_FEEDBACK)
                assert reply[:2] == b"\x03\x04"
                x_cmd, y_cmd = corrected(chain, "X", 300_000), corrected(chain, "Y", 200_000)
                assert x_cmd != 300_000 and y_cmd != 200_000
                assert await drive_at(direct, 1) == (x_cmd, x_cmd)  # moved, corrected
                assert await drive_at(direct, 2) == (y_cmd, y_cmd)
                assert int.from_bytes(reply[2:6], "big") == 300_000  # feedback reads nominal
                # a broadcast target write: each drive gets its own corrected target
                master.send(0, fc16(TARGET, list(pack_int32(400_000))))
                await wait_for_condition(lambda: app.gateway.counters.broadcasts == 2)
                master.send(0, fc06(TRIGGER, 0x10))
                await wait_for_condition(lambda: bus.counters.broadcasts == 2)
                assert (await master.request(2, READ_FEEDBACK))[:2] == b"\x03\x04"
                x_cmd, y_cmd = corrected(chain, "X", 400_000), corrected(chain, "Y", 400_000)
                assert 400_000 not in (x_cmd, y_cmd)
                assert await drive_at(direct, 1) == (x_cmd, x_cmd)
                assert await drive_at(direct, 2) == (y_cmd, y_cmd)
                gw = app.gateway.counters
                assert (gw.broadcasts, gw.broadcasts_expanded) == (3, 1)
                assert bus.counters.broadcasts == 2  # the target went unicast
            finally:
                master.close()

    run(body())


def test_tcp_broadcasts_reach_every_drive_corrected(tmp_path: Path) -> None:
    async def body() -> None:
        async with rig(tmp_path, edit, {"x.csv": PITCH_X}) as r:
            direct, chain, app = r["direct"], r["chain"], r["app"]
            master = await RawTcpMaster.connect(app.tcp_port)
            try:
                pdu = fc16(TARGET, list(pack_int32(250_000)))
                assert await master.request(0, pdu) == pdu[:5]  # the normal write response
                x_cmd, y_cmd = corrected(chain, "X", 250_000), corrected(chain, "Y", 250_000)
                assert 250_000 not in (x_cmd, y_cmd)
                assert (await drive_at(direct, 1))[0] == x_cmd  # held until the trigger
                assert (await drive_at(direct, 2))[0] == y_cmd
                before = app.buses["line1"].counters.transactions
                assert await master.request(0, fc06(TRIGGER, 0x10)) == fc06(TRIGGER, 0x10)
                assert await drive_at(direct, 1) == (x_cmd, x_cmd)
                assert await drive_at(direct, 2) == (y_cmd, y_cmd)
                # a TCP bus has no broadcast: one unicast per known drive (X, Y, the laser)
                assert app.buses["line1"].counters.transactions - before == 3
                # a broadcast read is refused: only writes can be broadcast
                assert await master.request(0, READ_FEEDBACK) == b"\x83\x01"
            finally:
                await master.close()

    run(body())
