"""Every fault mode as a real Modbus client sees it, switched at run time via the control block."""

from __future__ import annotations

import asyncio
import time

import pytest
from pymodbus.exceptions import ModbusIOException
from pymodbus.framer import FramerRTU, FramerSocket
from pymodbus.pdu import DecodePDU

from sim.server import SimServer
from tests.conftest import PtyPair
from tests.test_sim_support import (
    FAULTS_UNIT,
    Master,
    config_from,
    example_dict,
    rtu_client,
    run,
    tcp_client,
    with_rtu,
)

MODE, DELAY, CODE, ALARM = 0, 1, 2, 3


def fault_address(unit: int, field: int) -> int:
    """Documented control block layout: unit u at u*8 + field."""
    return unit * 8 + field


def test_silent_drive_times_out_then_recovers() -> None:
    data = example_dict()

    async def script() -> None:
        async with SimServer(config_from(data), tcp_port=0) as server:
            client = await tcp_client(server.tcp_port, timeout_s=0.2)
            m = Master(client, data)
            await m.control(fault_address(1, MODE), [1])
            t0 = time.monotonic()
            with pytest.raises(ModbusIOException):
                await client.read_holding_registers(0x1003, device_id=1)
            assert time.monotonic() - t0 >= 0.19
            # the other drive is unaffected
            assert not (await client.read_holding_registers(0x1003, device_id=2)).isError()
            client.close()
            # a new connection (the old one has an unanswered request) clears all faults
            client = await tcp_client(server.tcp_port, timeout_s=0.5)
            m = Master(client, data)
            await m.control(0x0804, [1])
            assert not (await client.read_holding_registers(0x1003, device_id=1)).isError()
            client.close()

    run(script())


def test_slow_replies_arrive_after_the_delay() -> None:
    data = example_dict()

    async def script() -> float:
        async with SimServer(config_from(data), tcp_port=0) as server:
            client = await tcp_client(server.tcp_port, timeout_s=2.0)
            await Master(client, data).control(fault_address(2, DELAY), [300])
            t0 = time.monotonic()
            rr = await client.read_holding_registers(0x602A, count=2, device_id=2)
            elapsed = time.monotonic() - t0
            assert not rr.isError()
            client.close()
            return elapsed

    elapsed = run(script())
    assert 0.3 <= elapsed < 1.5, elapsed


def test_exception_mode_answers_every_request_with_the_code() -> None:
    data = example_dict()

    async def script() -> None:
        async with SimServer(config_from(data), tcp_port=0) as server:
            client = await tcp_client(server.tcp_port)
            m = Master(client, data)
            await m.control(fault_address(1, MODE), [2, 0, 0x06])
            rr = await client.read_holding_registers(0x1003, device_id=1)
            assert rr.isError() and rr.exception_code == 0x06
            rr = await client.write_register(0x6002, 0x10, device_id=1)
            assert rr.isError() and rr.exception_code == 0x06
            # code 0 means 0x04 (device failure): a dead sensor that still answers
            await m.control(fault_address(20, MODE), [2, 0, 0])
            rr = await client.read_input_registers(0, count=2, device_id=20)
            assert rr.isError() and rr.exception_code == 0x04
            client.close()

    run(script())


def test_dead_sensor_is_silent() -> None:
    data = example_dict()

    async def script() -> None:
        async with SimServer(config_from(data), tcp_port=0) as server:
            client = await tcp_client(server.tcp_port, timeout_s=0.2)
            await Master(client, data).control(fault_address(10, MODE), [1])
            with pytest.raises(ModbusIOException):
                await client.read_input_registers(0, count=1, device_id=10)
            client.close()

    run(script())


def test_forced_alarm_blocks_moves() -> None:
    data = example_dict()

    async def script() -> None:
        async with SimServer(config_from(data), tcp_port=0) as server:
            m = Master(await tcp_client(server.tcp_port), data)
            await m.control(fault_address(1, ALARM), [1])
            assert await m.status("X") & 0x01  # alarm bit 0
            await m.move_pulses("X", 100_000)
            assert await m.feedback("X") == 0
            await m.control(fault_address(1, ALARM), [0])
            await m.move_pulses("X", 100_000)
            assert await m.feedback("X") == 100_000
            assert not await m.status("X") & 0x01
            m.client.close()

    run(script())


def test_unknown_unit_tcp_gets_0x0b() -> None:
    data = example_dict()

    async def script() -> None:
        async with SimServer(config_from(data), tcp_port=0) as server:
            client = await tcp_client(server.tcp_port)
            rr = await client.read_holding_registers(0, device_id=99)
            assert rr.isError() and rr.exception_code == 0x0B
            client.close()

    run(script())


def test_garbage_on_rtu_is_a_corrupted_frame(pty_pair: PtyPair) -> None:
    """Garbage mode: bytes come back, of the reply's length, but the CRC is wrong.

    The client's raw receive hook records the bytes; pymodbus drops the frame and times out.
    """
    data = with_rtu(example_dict())
    received: list[bytes] = []

    def trace_packet(sending: bool, packet: bytes) -> bytes:
        if not sending:
            received.append(packet)
        return packet

    async def script() -> None:
        async with SimServer(config_from(data), tcp_port=0, rtu_port=pty_pair.a) as server:
            client = await rtu_client(pty_pair.b, timeout_s=0.3, trace_packet=trace_packet)
            server.sim.faults.set_fault(1, mode=3)
            with pytest.raises(ModbusIOException):
                await client.read_holding_registers(0x1003, device_id=1)
            got = b"".join(received)
            assert len(got) == 7  # 01 03 02 hi lo crc crc, scrambled
            assert not FramerRTU.check_CRC(got[:-2], int.from_bytes(got[-2:], "big"))
            server.sim.faults.clear()
            assert not (await client.read_holding_registers(0x1003, device_id=1)).isError()
            # unknown units are silent on RTU (another device's address)
            with pytest.raises(ModbusIOException):
                await client.read_holding_registers(0, device_id=99)
            client.close()

    run(script())


def test_control_block_rejects_bad_values() -> None:
    data = example_dict()

    async def script() -> None:
        async with SimServer(config_from(data), tcp_port=0) as server:
            client = await tcp_client(server.tcp_port)
            rr = await client.write_register(fault_address(1, MODE), 9, device_id=FAULTS_UNIT)
            assert rr.isError() and rr.exception_code == 0x03
            rr = await client.write_register(0x0802, 1, device_id=FAULTS_UNIT)
            assert rr.isError() and rr.exception_code == 0x02
            await client.write_register(0x0801, 1500, device_id=FAULTS_UNIT)
            rr = await client.read_holding_registers(0x0802, count=2, device_id=FAULTS_UNIT)
            assert (rr.registers[0] << 16 | rr.registers[1]) == 1500
            client.close()

    run(script())


def test_garbage_and_pipelining_on_tcp() -> None:
    """Two pipelined requests in one segment: each answered with its own transaction id;
    in garbage mode the MBAP header stays valid and the PDU is scrambled."""
    data = example_dict()
    mbap = FramerSocket(DecodePDU(is_server=False))
    req = b"\x03\x10\x03\x00\x01"

    async def script() -> tuple[bytes, bytes]:
        async with SimServer(config_from(data), tcp_port=0) as server:
            reader, writer = await asyncio.open_connection("127.0.0.1", server.tcp_port)
            writer.write(mbap.encode(req, 1, 7) + mbap.encode(req, 2, 8))
            clean = await reader.readexactly(2 * 11)
            server.sim.faults.set_fault(1, mode=3)
            writer.write(mbap.encode(req, 1, 9))
            dirty = await reader.readexactly(11)
            writer.close()
            return clean, dirty

    clean, dirty = run(script())
    assert clean[0:2] == (7).to_bytes(2, "big") and clean[11:13] == (8).to_bytes(2, "big")
    assert clean[7:9] == b"\x03\x02" and clean[18:20] == b"\x03\x02"
    assert dirty[:7] == (9).to_bytes(2, "big") + b"\x00\x00\x00\x05\x01"
    assert dirty[7:] != clean[7:11]
