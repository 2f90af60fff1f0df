"""RTU over TCP (``buses.NAME.rtu_over_tcp``): the gateway's drives behind a serial device
server in transparent mode, played by the sim's RTU-over-TCP server (a real TCP socket,
RTU frames with CRC, no MBAP). Byte-exact pass-through, corrected moves and broadcasts,
late replies dropped after a timeout, and a server killed and restarted is reconnected.
"""

from __future__ import annotations

import asyncio
import os
import re
import signal
import subprocess
import sys
from pathlib import Path

import yaml

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
from tests.gateway_rig import FEEDBACK, ROOT, TARGET, TRIGGER, rig
from tests.helpers_modbus import RawTcpMaster, wait_for_condition
from tests.test_gateway_e2e import PITCH_X, read32, run, with_pitch
from tests.test_sim_support import example_dict

CONTROL_UNIT = 250


class RawRtuOverTcp:
    """A master writing RTU frames into a TCP connection (what a PC does with a serial
    device server), one request at a time."""

    def __init__(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        self.reader, self.writer = reader, writer

    @classmethod
    async def connect(cls, port: int) -> RawRtuOverTcp:
        return cls(*await asyncio.open_connection("127.0.0.1", port))

    async def request(self, unit: int, pdu: bytes) -> bytes:
        self.writer.write(rtu_encode(unit, pdu))
        buf = b""
        while True:
            buf += await asyncio.wait_for(self.reader.read(256), 3.0)
            scan = find_rtu_frame(buf, rtu_response_length)
            if scan.frame is not None:
                assert scan.frame[0] == unit
                return scan.frame[1:-2]

    async def close(self) -> None:
        self.writer.close()


REQUESTS = [  # not intercepted: the drive's (or the laser's) own answers, byte for byte
    (20, build_read_request(3, 0x7000, 2)),  # the laser (pass-through unit): its 0x02
    (1, build_write_single_register(0x6204, 0x1234)),
    (1, build_write_multiple_registers(0x6204, [7, 8, 9])),
    (1, build_read_request(3, 0x6204, 3)),
    (2, build_read_request(3, 0x7000, 1)),  # the drive's exception 0x02
    (1, bytes([0x2B, 0x0E, 0x01, 0x00])),  # a function the drive does not know: 0x01
    (2, build_read_request(4, 0x1003, 1)),  # no input registers: 0x02
]


def test_pass_through_is_byte_exact_and_moves_land_corrected(tmp_path: Path) -> None:
    async def body() -> None:
        async with rig(tmp_path, with_pitch, {"x.csv": PITCH_X}, drives="rtu_over_tcp") as r:
            sim, app, chain = r["sim"], r["app"], r["chain"]
            gateway = await RawTcpMaster.connect(app.tcp_port)
            direct = await RawRtuOverTcp.connect(sim.rtu_over_tcp_port)
            try:
                for unit, pdu in REQUESTS:
                    expected = await direct.request(unit, pdu)
                    assert await gateway.request(unit, pdu) == expected, pdu.hex()
                # a compensated move on an RTU-over-TCP bus
                pdu = build_write_multiple_registers(TARGET, list(pack_int32(300_000)))
                assert await gateway.request(1, pdu) == pdu[:5]
                assert await gateway.request(1, build_write_single_register(TRIGGER, 0x10))
                corrected = chain.command_pulses("X", {"X": AxisInput(300_000, 1)})
                assert corrected != 300_000
                assert await read32(r["direct"], 1, FEEDBACK) == corrected
                assert await read32(r["master"], 1, FEEDBACK) == 300_000
                # a broadcast: one unit-0 frame on the line, every drive acts on it
                pdu = build_write_single_register(0x6204, 0x0BAD)
                assert await gateway.request(0, pdu) == pdu
                await wait_for_condition(lambda: all(
                    d._store[0x6204] == 0x0BAD for d in sim.sim.drives.values()))
                assert app.buses["line1"].counters.broadcasts == 1
            finally:
                await gateway.close()
                await direct.close()

    run(body())


def test_late_reply_after_a_timeout_is_dropped(tmp_path: Path) -> None:
    """A reply that comes after the timeout has the very shape of the next request's:
    without the guard it would be taken as that answer (the old value)."""

    async def body() -> None:
        async with rig(tmp_path, drives="rtu_over_tcp") as r:
            direct, master = r["direct"], r["master"]
            bus = r["app"].buses["line1"]
            assert not (await direct.write_register(0x6204, 111, device_id=1)).isError()
            # the drive answers 0.3 s late; the bus gives up after 0.2 s
            rr = await direct.write_registers(1 * 8, [0, 300], device_id=CONTROL_UNIT)
            assert not rr.isError()
            rr = await master.read_holding_registers(0x6204, count=1, device_id=1)
            assert rr.isError() and rr.exception_code == 0x0B
            # at once: the drive prompt again and the register changed
            rr = await direct.write_registers(1 * 8, [0, 0], device_id=CONTROL_UNIT)
            assert not rr.isError()
            assert not (await direct.write_register(0x6204, 222, device_id=1)).isError()
            dropped = bus.counters.dropped
            rr = await master.read_holding_registers(0x6204, count=1, device_id=1)
            assert not rr.isError() and rr.registers == [222]  # never the late 111
            assert bus.counters.dropped > dropped  # the late reply was seen and dropped

    run(body())


def test_server_killed_and_restarted_is_reconnected(tmp_path: Path) -> None:
    async def body() -> None:
        async with rig(tmp_path, drives="rtu_over_tcp") as r:
            sim, master = r["sim"], r["master"]
            bus = r["app"].buses["line1"]
            port = sim.rtu_over_tcp_port
            rr = await master.read_holding_registers(0x6204, count=1, device_id=1)
            assert not rr.isError()
            await sim.stop_rtu_over_tcp()  # the device server goes away
            rr = await master.read_holding_registers(0x6204, count=1, device_id=1)
            assert rr.isError() and rr.exception_code in (0x0A, 0x0B)
            await wait_for_condition(lambda: not bus.connected)
            rr = await master.read_holding_registers(0x6204, count=1, device_id=1)
            assert rr.isError() and rr.exception_code == 0x0A  # down: at once, no hang
            assert await sim.start_rtu_over_tcp(port) == port  # back, same address
            for _ in range(100):  # the bus reconnects on its backoff (0.1 s doubling)
                rr = await master.read_holding_registers(0x6204, count=1, device_id=1)
                if not rr.isError():
                    break
                await asyncio.sleep(0.05)
            assert not rr.isError() and bus.connected
            assert bus.counters.reconnects == 2

    run(body())


def test_compgw_sim_serves_rtu_over_tcp_on_the_port_it_prints(tmp_path: Path) -> None:
    data = example_dict()
    data["sim"].pop("tcp")
    data["sim"]["rtu_over_tcp"] = {"host": "127.0.0.1", "port": 0}
    config = tmp_path / "sim.yaml"
    config.write_text(yaml.safe_dump(data))
    proc = subprocess.Popen([sys.executable, "-m", "gateway.cli", "sim", "-c", str(config)],
                            cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env={**os.environ, "PYTHONUNBUFFERED": "1"})
    try:
        assert proc.stdout is not None
        line = proc.stdout.readline()  # blocks until the server prints its bound port
        match = re.search(r"modbus rtu over tcp on 127\.0\.0\.1:(\d+)", line)
        assert match, line

        async def ask() -> bytes:
            master = await RawRtuOverTcp.connect(int(match[1]))
            try:
                return await master.request(1, build_read_request(3, TARGET, 2))
            finally:
                await master.close()

        assert run(ask())[:2] == b"\x03\x04"
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(timeout=30) == 0
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
