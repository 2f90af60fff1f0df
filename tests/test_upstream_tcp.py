"""Upstream Modbus TCP server: pipelining, concurrency, malformed frames, security options,
handler errors, graceful close."""

from __future__ import annotations

import asyncio
import struct
import time

import pytest

from gateway.modbus import frames as f
from gateway.modbus.downstream import TcpBus
from gateway.modbus.upstream import TcpServer
from tests.helpers_modbus import (
    DRIVE_UNIT,
    RawTcpMaster,
    mbap,
    read_mbap,
    run,
    tcp_drive,
    wait_for_condition,
)


async def address_echo(unit_id: int, pdu: bytes) -> bytes | None:
    """FC03 answers each register with its own address (+ unit); identifies the request."""
    req = f.parse_request(pdu)
    assert req.read_address is not None
    return f.build_read_registers_response(3, [req.read_address + i + unit_id
                                               for i in range(req.read_count)])


async def assert_closed_by_server(reader: asyncio.StreamReader) -> None:
    assert await asyncio.wait_for(reader.read(100), 2.0) == b""


@pytest.mark.parametrize("mode", ["one-segment", "back-to-back"])
def test_pipelining_through_the_drive(mode: str) -> None:
    """Several requests without waiting: each reply in order with its own tid and data."""

    async def main() -> None:
        async with tcp_drive() as port:
            bus = TcpBus("127.0.0.1", port, timeout_s=0.5, retries=0)

            async def handler(unit_id: int, pdu: bytes) -> bytes | None:
                return await bus.transact(unit_id, pdu)

            async with TcpServer(handler, "127.0.0.1", 0) as server:
                master = await RawTcpMaster.connect(server.port)
                values = [1000 + 7 * i for i in range(40)]
                await master.request(DRIVE_UNIT, f.build_write_multiple_registers(100, values))
                tids = [7, 3, 65535, 1, 0, 40000, 2, 9, 11, 12] * 3
                frames = [mbap(tid, DRIVE_UNIT, f.build_read_request(3, 100 + i, 1))
                          for i, tid in enumerate(tids)]
                if mode == "one-segment":
                    master.writer.write(b"".join(frames))
                else:
                    for frame in frames:
                        master.writer.write(frame)
                        await master.writer.drain()
                await master.writer.drain()
                for i, tid in enumerate(tids):
                    r_tid, r_unit, pdu = await read_mbap(master.reader)
                    assert (r_tid, r_unit) == (tid, DRIVE_UNIT)
                    assert f.parse_read_registers_response(pdu) == [values[i]]
                await master.close()
            await bus.close()

    run(main())


def test_connections_run_concurrently_requests_of_one_in_order() -> None:
    async def main() -> None:
        started: list[int] = []

        async def slow(unit_id: int, pdu: bytes) -> bytes | None:
            started.append(unit_id)
            await asyncio.sleep(0.1)
            return await address_echo(unit_id, pdu)

        async with TcpServer(slow, "127.0.0.1", 0) as server:
            a = await RawTcpMaster.connect(server.port)
            b = await RawTcpMaster.connect(server.port)
            t0 = time.monotonic()
            ra, rb = await asyncio.gather(a.request(1, f.build_read_request(3, 5, 1)),
                                          b.request(2, f.build_read_request(3, 5, 1)))
            assert time.monotonic() - t0 < 0.18  # concurrent, not 0.2 s
            assert (ra, rb) == (f.build_read_registers_response(3, [6]),
                                f.build_read_registers_response(3, [7]))
            # One connection, 3 pipelined requests: processed one after the other.
            a.writer.write(b"".join(mbap(t, 1, f.build_read_request(3, t, 1)) for t in (1, 2, 3)))
            t0 = time.monotonic()
            for t in (1, 2, 3):
                assert (await read_mbap(a.reader))[0] == t
            assert time.monotonic() - t0 >= 0.29
            await a.close()
            await b.close()

    run(main())


def test_many_masters_pipelining_no_lost_or_mismatched_reply() -> None:
    async def main() -> None:
        async with TcpServer(address_echo, "127.0.0.1", 0, max_pipeline=8) as server:

            async def master(unit: int, n: int) -> None:
                m = await RawTcpMaster.connect(server.port)
                for start in range(0, n, 50):  # bursts of 50 pipelined requests
                    burst = range(start, min(start + 50, n))
                    m.writer.write(b"".join(mbap(i + 1, unit, f.build_read_request(3, i, 1))
                                            for i in burst))
                    for i in burst:
                        tid, r_unit, pdu = await read_mbap(m.reader)
                        assert (tid, r_unit) == (i + 1, unit)
                        assert f.parse_read_registers_response(pdu) == [i + unit]
                await m.close()

            await asyncio.gather(*(master(unit, 400) for unit in range(1, 9)))
            assert server.counters.requests == 8 * 400 == server.counters.replies

    run(main())


@pytest.mark.parametrize("garbage", [
    mbap(1, 1, b"\x03\x00\x00\x00\x01")[:2] + b"\x00\x01" + b"\x00\x06\x01\x03\x00\x00\x00\x01",
    b"\x00\x01\x00\x00\xff\xff\x01\x03\x00\x00",
    b"\x00\x01\x00\x00\x00\x01\x01\x03",
    bytes(range(64)),
], ids=["protocol-id", "absurd-length", "length-1", "noise"])
def test_malformed_frame_closes_connection_server_survives(garbage: bytes) -> None:
    async def main() -> None:
        async with TcpServer(address_echo, "127.0.0.1", 0) as server:
            bad = await RawTcpMaster.connect(server.port)
            bad.writer.write(garbage)
            await assert_closed_by_server(bad.reader)
            assert server.counters.malformed == 1
            good = await RawTcpMaster.connect(server.port)
            assert await good.request(1, f.build_read_request(3, 1, 1)) == b"\x03\x02\x00\x02"
            await good.close()
            await bad.close()

    run(main())


def test_partial_frames_across_segments() -> None:
    async def main() -> None:
        async with TcpServer(address_echo, "127.0.0.1", 0) as server:
            m = await RawTcpMaster.connect(server.port)
            data = mbap(5, 1, f.build_read_request(3, 9, 2)) * 2
            for i in range(len(data)):  # one byte per segment
                m.writer.write(data[i:i + 1])
                await m.writer.drain()
            for _ in range(2):
                assert await read_mbap(m.reader) == (5, 1, f.build_read_registers_response(
                    3, [10, 11]))
            await m.close()

    run(main())


def test_handler_errors_become_exceptions_and_none_means_no_reply() -> None:
    async def handler(unit_id: int, pdu: bytes) -> bytes | None:
        if unit_id == 1:
            raise RuntimeError("bug in the layer above")
        if unit_id == 2:
            raise f.ModbusError("protected", code=f.ILLEGAL_DATA_ADDRESS)
        if unit_id == 3:
            return None
        if unit_id == 4:
            return b""
        return pdu

    async def main() -> None:
        async with TcpServer(handler, "127.0.0.1", 0) as server:
            m = await RawTcpMaster.connect(server.port)
            pdu = f.build_write_single_register(1, 2)
            assert await m.request(1, pdu) == b"\x86\x04"
            assert await m.request(2, pdu) == b"\x86\x02"
            assert await m.request(4, pdu) == b"\x86\x04"
            m.writer.write(mbap(100, 3, pdu) + mbap(101, 5, pdu))
            assert await read_mbap(m.reader) == (101, 5, pdu)  # 100 got no reply
            assert server.counters.handler_errors == 2
            await m.close()

    run(main())


def test_allowlist_refuses_at_accept() -> None:
    async def main() -> None:
        async with TcpServer(address_echo, "127.0.0.1", 0, allow=["10.0.0.0/8"]) as server:
            m = await RawTcpMaster.connect(server.port)
            await assert_closed_by_server(m.reader)
            await m.close()
            assert server.counters.refused == 1 and server.counters.requests == 0
        async with TcpServer(address_echo, "127.0.0.1", 0, allow=["127.0.0.1"]) as server:
            m = await RawTcpMaster.connect(server.port)
            assert await m.request(1, f.build_read_request(3, 0, 1)) == b"\x03\x02\x00\x01"
            await m.close()

    run(main())


def test_max_connections_makes_room_and_idle_timeout() -> None:
    """At max_connections a new client closes the one idle longest; idle ones time out."""

    async def main() -> None:
        async with TcpServer(address_echo, "127.0.0.1", 0, max_connections=1,
                             idle_timeout_s=0.3) as server:
            first = await RawTcpMaster.connect(server.port)
            assert await first.request(1, f.build_read_request(3, 0, 1)) == b"\x03\x02\x00\x01"
            second = await RawTcpMaster.connect(server.port)
            await assert_closed_by_server(first.reader)  # made room for the second
            assert server.counters.evicted == 1 and server.counters.refused == 0
            assert await second.request(1, f.build_read_request(3, 0, 1)) == b"\x03\x02\x00\x01"
            t0 = time.monotonic()
            await assert_closed_by_server(second.reader)  # idle
            assert 0.25 < time.monotonic() - t0 < 1.0
            assert server.counters.idle_closed == 1
            await wait_for_condition(lambda: server.connection_count == 0)
            for m in (first, second):
                await m.close()

    run(main())


def test_connection_busy_everywhere_refuses_the_newcomer() -> None:
    """Only when every connection has a request in flight is a new one refused."""

    async def main() -> None:
        release = asyncio.Event()

        async def held(unit_id: int, pdu: bytes) -> bytes | None:
            await release.wait()
            return await address_echo(unit_id, pdu)

        async with TcpServer(held, "127.0.0.1", 0, max_connections=1) as server:
            busy = await RawTcpMaster.connect(server.port)
            busy.writer.write(mbap(5, 1, f.build_read_request(3, 0, 1)))
            await wait_for_condition(lambda: server.counters.requests == 1)
            newcomer = await RawTcpMaster.connect(server.port)
            await assert_closed_by_server(newcomer.reader)
            assert server.counters.refused == 1 and server.counters.evicted == 0
            release.set()
            assert (await read_mbap(busy.reader))[0] == 5  # the busy one was not touched
            for m in (busy, newcomer):
                await m.close()

    run(main())


def test_graceful_close_finishes_request_in_flight() -> None:
    async def main() -> None:
        release = asyncio.Event()
        entered = asyncio.Event()

        async def held(unit_id: int, pdu: bytes) -> bytes | None:
            entered.set()
            await release.wait()
            return pdu

        server = TcpServer(held, "127.0.0.1", 0)
        await server.start()
        m = await RawTcpMaster.connect(server.port)
        pdu = f.build_write_single_register(3, 4)
        m.writer.write(mbap(1, 1, pdu) + mbap(2, 1, pdu))  # second one is refused
        await entered.wait()
        closing = asyncio.create_task(server.close())
        await asyncio.sleep(0.05)
        assert not closing.done()
        with pytest.raises(OSError):
            await asyncio.open_connection("127.0.0.1", server.port)
        release.set()
        assert await read_mbap(m.reader) == (1, 1, pdu)
        await assert_closed_by_server(m.reader)
        await asyncio.wait_for(closing, 2.0)
        assert server.counters.requests == 1
        await m.close()

    run(main())


def test_port_zero_and_bind_error() -> None:
    async def main() -> None:
        async with TcpServer(address_echo, "127.0.0.1", 0) as server:
            assert server.port > 0
            other = TcpServer(address_echo, "127.0.0.1", server.port)
            with pytest.raises(OSError):
                await other.start()

    run(main())


def test_mbap_length_struct() -> None:
    frame = mbap(0x1234, 7, b"\x03\x00\x01\x00\x02")
    assert struct.unpack(">HHHB", frame[:7]) == (0x1234, 0, 6, 7)


@pytest.mark.parametrize("max_pipeline", [1, 3])
def test_pipeline_reads_ahead_at_most_max_pipeline(max_pipeline: int) -> None:
    """200 requests in one segment: all answered in order, never more than max_pipeline
    of them read and unanswered (then reading pauses: TCP backpressure)."""

    async def main() -> None:
        peak = 0

        async def handler(unit_id: int, pdu: bytes) -> bytes | None:
            nonlocal peak
            conn = next(iter(server._connections))
            peak = max(peak, len(conn.pending) + conn.busy)
            await asyncio.sleep(0.0005)
            return await address_echo(unit_id, pdu)

        async with TcpServer(handler, "127.0.0.1", 0, max_pipeline=max_pipeline) as server:
            m = await RawTcpMaster.connect(server.port)
            m.writer.write(b"".join(mbap(i + 1, 1, f.build_read_request(3, i, 1))
                                    for i in range(200)))
            for i in range(200):
                tid, unit, pdu = await read_mbap(m.reader)
                assert (tid, unit) == (i + 1, 1)
                assert f.parse_read_registers_response(pdu) == [i + 1]
            assert 1 <= peak <= max_pipeline
            await m.close()

    run(main())


def test_idle_timeout_spares_a_connection_whose_request_is_in_flight() -> None:
    async def main() -> None:
        async def slow(unit_id: int, pdu: bytes) -> bytes | None:
            await asyncio.sleep(0.5)
            return await address_echo(unit_id, pdu)

        async with TcpServer(slow, "127.0.0.1", 0, idle_timeout_s=0.2) as server:
            m = await RawTcpMaster.connect(server.port)
            assert await m.request(1, f.build_read_request(3, 0, 1)) == b"\x03\x02\x00\x01"
            t0 = time.monotonic()
            await assert_closed_by_server(m.reader)  # idle from the reply on
            assert 0.15 < time.monotonic() - t0 < 0.6
            await m.close()

    run(main())


def test_eof_after_pipelined_requests_answers_them_then_closes() -> None:
    async def main() -> None:
        async with TcpServer(address_echo, "127.0.0.1", 0) as server:
            m = await RawTcpMaster.connect(server.port)
            m.writer.write(b"".join(mbap(t, 1, f.build_read_request(3, t, 1)) for t in (1, 2, 3)))
            m.writer.write_eof()
            for t in (1, 2, 3):
                assert (await read_mbap(m.reader))[0] == t
            await assert_closed_by_server(m.reader)
            await wait_for_condition(lambda: server.connection_count == 0)
            await m.close()

    run(main())


def test_frame_must_complete_within_frame_timeout() -> None:
    """A frame in two segments a little apart is served; one left incomplete closes its
    connection frame_timeout_s after its first byte, counted; a later byte does not
    restart the clock."""

    async def main() -> None:
        async with TcpServer(address_echo, "127.0.0.1", 0, frame_timeout_s=0.4) as server:
            m = await RawTcpMaster.connect(server.port)
            frame = mbap(9, 1, f.build_read_request(3, 10, 1))
            m.writer.write(frame[:5])
            await asyncio.sleep(0.1)  # well inside the frame timeout
            m.writer.write(frame[5:])
            assert (await read_mbap(m.reader))[2] == b"\x03\x02\x00\x0b"
            loop = asyncio.get_running_loop()
            t0 = loop.time()
            m.writer.write(frame[:9])
            await asyncio.sleep(0.2)
            m.writer.write(frame[9:10])  # still one byte short
            await assert_closed_by_server(m.reader)
            assert 0.35 < loop.time() - t0 < 1.5
            assert server.counters.slow_frames == 1
            await m.close()

    run(main())
