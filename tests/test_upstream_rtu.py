"""Upstream RTU server on a pty: garbage, fragments, foreign units, broadcast, unknown FC,
bad CRC, a port that goes away."""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import AsyncIterator

import pytest

from gateway.modbus import frames as f
from gateway.modbus.upstream import RtuServer
from tests.helpers_modbus import PtyPair, rtu_request, run, wait_for_condition

UNIT = 3


class Recorder:
    """Handler that records what it gets and echoes FC06 / answers FC03 with zeros."""

    def __init__(self) -> None:
        self.seen: list[tuple[int, bytes]] = []

    async def __call__(self, unit_id: int, pdu: bytes) -> bytes | None:
        self.seen.append((unit_id, pdu))
        if pdu[0] == 3:
            return f.build_read_registers_response(3, [0] * f.parse_request(pdu).read_count)
        if pdu[0] == 0x41:
            return b"\x41\x99"
        return pdu


@contextlib.asynccontextmanager
async def server() -> AsyncIterator[tuple[RtuServer, PtyPair, Recorder]]:
    pair = PtyPair()
    rec = Recorder()
    srv = RtuServer(rec, pair.path, unit_ids={UNIT}, baudrate=115200, silence_s=0.005)
    await srv.start()
    try:
        yield srv, pair, rec
    finally:
        await srv.close()
        pair.close()


READ = f.build_read_request(3, 0, 2)
READ_REPLY = f.rtu_encode(UNIT, b"\x03\x04\x00\x00\x00\x00")


@pytest.mark.parametrize("garbage", [
    b"\xff\x00\x13",
    f.rtu_encode(UNIT, READ)[:5],  # a truncated frame right before a good one
    b"\x03\x10\x00\x00\x00\x7b\xf6",  # a bogus FC16 header announcing 246 bytes
    bytes(range(200)),
], ids=["noise", "truncated", "long-header", "noise-200"])
def test_garbage_then_valid_request_is_served(garbage: bytes) -> None:
    async def main() -> None:
        async with server() as (_srv, pair, rec):
            pair.write(garbage)
            assert await rtu_request(pair, UNIT, READ) == READ_REPLY
            assert rec.seen[-1] == (UNIT, READ)

    run(main())


def test_fragmented_frame_is_reassembled_and_stale_fragment_dropped() -> None:
    async def main() -> None:
        async with server() as (srv, pair, rec):
            frame = f.rtu_encode(UNIT, f.build_write_multiple_registers(7, [1, 2, 3]))
            for i in range(0, len(frame), 3):
                pair.write(frame[i:i + 3])
                await asyncio.sleep(0.002)  # gaps shorter than stale_s: one frame
            await wait_for_condition(lambda: len(rec.seen) == 1)
            pair.write(frame[:6])  # then the master gives up mid-frame
            await wait_for_condition(lambda: srv.line.garbage_bytes >= 6)
            assert await rtu_request(pair, UNIT, READ) == READ_REPLY
            assert len(rec.seen) == 2

    run(main())


def test_foreign_units_dropped_broadcast_handled_without_reply() -> None:
    async def main() -> None:
        async with server() as (_srv, pair, rec):
            with pytest.raises(TimeoutError):
                await rtu_request(pair, UNIT + 1, READ, timeout_s=0.1)
            write = f.build_write_single_register(1, 5)
            pair.write(f.rtu_encode(0, write))
            await wait_for_condition(lambda: (0, write) in rec.seen)
            assert await rtu_request(pair, UNIT, READ) == READ_REPLY
            assert pair.read_available() == b""  # nothing for the foreign unit nor broadcast
            assert [u for u, _ in rec.seen] == [0, UNIT]

    run(main())


def test_unknown_function_framed_by_silence_bad_crc_ignored() -> None:
    async def main() -> None:
        async with server() as (_srv, pair, rec):
            bad = bytearray(f.rtu_encode(UNIT, READ))
            bad[-1] ^= 0xFF
            pair.write(bytes(bad))
            pair.write(f.rtu_encode(UNIT, b"\x41\x01\x02\x03"))
            want = f.rtu_encode(UNIT, b"\x41\x99")  # unknown FC: the test cannot frame it
            got = bytearray()

            def complete() -> bool:
                got.extend(pair.read_available())
                return len(got) >= len(want)

            await wait_for_condition(complete)
            assert bytes(got) == want
            assert rec.seen == [(UNIT, b"\x41\x01\x02\x03")]

    run(main())


def test_handler_exception_answered_with_crc() -> None:
    async def main() -> None:
        async def failing(unit_id: int, pdu: bytes) -> bytes | None:
            raise f.ModbusError("bus down", code=f.GATEWAY_PATH_UNAVAILABLE)

        pair = PtyPair()
        srv = RtuServer(failing, pair.path, unit_ids={UNIT}, baudrate=115200)
        await srv.start()
        try:
            assert await rtu_request(pair, UNIT, READ) == f.rtu_encode(UNIT, b"\x83\x0a")
        finally:
            await srv.close()
            pair.close()

    run(main())


def test_port_going_away_does_not_crash_or_spin() -> None:
    async def main() -> None:
        pair = PtyPair()
        rec = Recorder()
        srv = RtuServer(rec, pair.path, unit_ids={UNIT}, baudrate=115200, reopen_max_s=0.2)
        await srv.start()
        pair.close()
        await wait_for_condition(lambda: not srv.line.is_open)
        await asyncio.sleep(0.3)  # the reopen loop backs off meanwhile (no busy loop)
        await asyncio.wait_for(srv.close(), 2.0)

    run(main())
