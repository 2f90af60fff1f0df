"""The callback fast path (``TcpServer(fast=...)``, ``Bus.submit``, ``Gateway.handle_fast``):
the same bytes, order, errors and counters as the handler coroutine, with real pymodbus
drives and masters over loopback (port 0)."""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import AsyncIterator, Awaitable, Callable
from pathlib import Path

import pytest
from pymodbus.client import AsyncModbusTcpClient

from gateway.modbus import frames as f
from gateway.modbus.downstream import Bus, Done, TcpBus
from gateway.modbus.upstream import TcpServer
from tests.gateway_rig import FEEDBACK, SPEED, STATUS, TARGET, TRIGGER, rig
from tests.helpers_modbus import (
    DRIVE_UNIT,
    SLOW_ADDRESS,
    RawTcpMaster,
    mbap,
    read_mbap,
    run,
    tcp_drive,
    wait_for_condition,
)
from tests.test_upstream_passthrough import SCRIPT, direct_script

SILENT_UNIT = 5  # no drive answers this unit

Handler = Callable[[int, bytes], Awaitable[bytes | None]]


class Counted:
    """A fast handler forwarding to ``bus.submit`` (or declining every ``decline``-th
    request), counting what it took."""

    def __init__(self, bus: Bus, decline: int = 0) -> None:
        self.bus = bus
        self.decline = decline
        self.calls = 0
        self.taken = 0

    def __call__(self, unit_id: int, pdu: bytes, done: Done) -> bool:
        self.calls += 1
        if self.decline and self.calls % self.decline == 0:
            return False
        taken = self.bus.submit(unit_id, pdu, done)
        self.taken += taken
        return taken


def forward_to(bus: Bus) -> Handler:
    async def handler(unit_id: int, pdu: bytes) -> bytes | None:
        return await bus.transact(unit_id, pdu)

    return handler


@contextlib.asynccontextmanager
async def served(bus: Bus, fast: Counted, **kwargs: object) -> AsyncIterator[TcpServer]:
    async with TcpServer(forward_to(bus), "127.0.0.1", 0, fast=fast, **kwargs) as server:
        yield server


def test_fast_passthrough_is_byte_exact() -> None:
    async def main() -> None:
        expected = await direct_script()
        async with tcp_drive() as port:
            bus = TcpBus("127.0.0.1", port, timeout_s=0.5, retries=1)
            fast = Counted(bus)
            async with served(bus, fast) as server:
                master = await RawTcpMaster.connect(server.port)
                assert await bus.connect()  # else the first request opens it (coroutine)
                got = [await master.request(DRIVE_UNIT, pdu) for pdu in SCRIPT]
                await master.close()
                assert server.counters.requests == server.counters.replies == len(SCRIPT)
            await bus.close()
        for pdu, want, have in zip(SCRIPT, expected, got, strict=True):
            assert have == want, f"FC{pdu[0]:02d} {pdu.hex()}: {have.hex()} != {want.hex()}"
        assert fast.taken == len(SCRIPT)
        c = bus.counters
        assert (c.transactions, c.replies, c.timeouts, c.retries) == (len(SCRIPT),) * 2 + (0, 0)

    run(main())


@pytest.mark.parametrize("decline", [0, 3])
def test_pipelined_in_order_two_masters_one_bus(decline: int) -> None:
    """Two masters pipelining on one bus: the fast path when the bus is free, the
    coroutine (fair queue) when not or when declined; every reply in order, its own tid,
    its own data."""

    async def main() -> None:
        async with tcp_drive() as port:
            bus = TcpBus("127.0.0.1", port, timeout_s=1.0, retries=0)
            fast = Counted(bus, decline)
            async with served(bus, fast) as server:
                setup = await RawTcpMaster.connect(server.port)
                values = list(range(3000, 3100))
                await setup.request(DRIVE_UNIT, f.build_write_multiple_registers(100, values))

                async def master(offset: int) -> None:
                    m = await RawTcpMaster.connect(server.port)
                    tids = [(offset + 7 * i) % 0xFFFF + 1 for i in range(60)]
                    m.writer.write(b"".join(
                        mbap(tid, DRIVE_UNIT, f.build_read_request(3, 100 + i % 100, 1))
                        for i, tid in enumerate(tids)))
                    for i, tid in enumerate(tids):
                        r_tid, unit, pdu = await read_mbap(m.reader)
                        assert (r_tid, unit) == (tid, DRIVE_UNIT)
                        assert f.parse_read_registers_response(pdu) == [values[i % 100]]
                    await m.close()

                await asyncio.gather(master(0), master(5000))
                await setup.close()
                assert server.counters.requests == server.counters.replies == 121
            await bus.close()
        assert 0 < fast.taken < fast.calls if decline else fast.taken > 0
        assert bus.counters.transactions == bus.counters.replies == 121
        assert bus.counters.dropped == 0

    run(main())


def test_fast_timeout_retry_0x0b_and_late_reply_dropped() -> None:
    async def main() -> None:
        async with tcp_drive() as port:
            bus = TcpBus("127.0.0.1", port, timeout_s=0.1, retries=1)
            fast = Counted(bus)
            async with served(bus, fast) as server:
                m = await RawTcpMaster.connect(server.port)
                assert await bus.connect()
                for i in range(20):  # answered: the one bus timer never expires them
                    assert await m.request(DRIVE_UNIT, f.build_read_request(3, i, 1)) \
                        == b"\x03\x02\x00\x00"
                assert bus.counters.timeouts == 0
                # a silent unit: two attempts (the retry in a task), then 0x0B
                reply = await m.request(SILENT_UNIT, f.build_read_request(3, 0, 1))
                assert reply == f.exception_pdu(3, f.GATEWAY_TARGET_NO_RESPONSE)
                c = bus.counters
                assert (c.transactions, c.timeouts, c.retries) == (21, 2, 1)
                assert fast.taken == 21
                # a drive slower than the timeout: its late replies are dropped by tid
                slow = Counted(bus)
                server.fast = slow
                bus.retries = 0
                reply = await m.request(DRIVE_UNIT, f.build_read_request(3, SLOW_ADDRESS, 1))
                assert reply == f.exception_pdu(3, f.GATEWAY_TARGET_NO_RESPONSE)
                assert await m.request(DRIVE_UNIT, f.build_read_request(3, 7, 1)) \
                    == b"\x03\x02\x00\x00"
                await wait_for_condition(lambda: bus.counters.dropped == 1)
                assert slow.taken == 2
                await m.close()
            await bus.close()

    run(main())


class ClosingDrive:
    """A raw Modbus TCP drive that closes its first ``close_first`` connections when a
    request arrives, then echoes FC06 requests."""

    def __init__(self, close_first: int) -> None:
        self.close_first = close_first
        self.connections = 0
        self.server: asyncio.Server | None = None

    async def _serve(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        self.connections += 1
        number = self.connections
        try:
            while True:
                tid, unit, pdu = await read_mbap(reader, 10.0)
                if number <= self.close_first:
                    return
                writer.write(mbap(tid, unit, pdu))
        except (asyncio.IncompleteReadError, ConnectionError, asyncio.TimeoutError):
            pass
        finally:
            writer.close()

    async def __aenter__(self) -> int:
        self.server = await asyncio.start_server(self._serve, "127.0.0.1", 0)
        return self.server.sockets[0].getsockname()[1]

    async def __aexit__(self, *exc: object) -> None:
        assert self.server is not None
        self.server.close()


@pytest.mark.parametrize("retries", [0, 1])
def test_fast_connection_lost_retried_or_0x0a(retries: int) -> None:
    async def main() -> None:
        drive = ClosingDrive(close_first=1)
        async with drive as port:
            bus = TcpBus("127.0.0.1", port, timeout_s=1.0, retries=retries,
                         reconnect_min_s=0.01)
            fast = Counted(bus)
            async with served(bus, fast) as server:
                m = await RawTcpMaster.connect(server.port)
                write = f.build_write_single_register(3, 42)
                assert await bus.connect()  # connected: the request goes the fast way
                reply = await m.request(DRIVE_UNIT, write)
                if retries:
                    assert reply == write  # attempt 2 on a new connection
                    assert (bus.counters.retries, bus.counters.reconnects) == (1, 2)
                else:
                    assert reply == f.exception_pdu(6, f.GATEWAY_PATH_UNAVAILABLE)
                    assert bus.counters.unavailable == 1
                    # the bus reconnects on the next request (a coroutine: it is down)
                    assert not bus.connected
                    assert await m.request(DRIVE_UNIT, write) == write
                assert fast.taken == 1
                await m.close()
            await bus.close()

    run(main())


# ------------------------------------------------------------------ the gateway


def _script(passthrough_unit: int) -> list[tuple[int, bytes]]:
    return [
        (1, f.build_read_request(3, TARGET, 2)),  # the shadow
        (1, f.build_read_request(3, TARGET - 1, 10)),  # the shadow inside a block
        (1, f.build_read_request(3, TARGET + 1, 1)),  # half the pair: widened
        (1, f.build_read_request(3, FEEDBACK, 2)),  # inverse chain
        (1, f.build_read_request(3, FEEDBACK + 1, 3)),  # half the feedback pair
        (1, f.build_read_request(3, STATUS, 1)),  # status word recorded
        (1, f.build_write_single_register(SPEED, 1234)),  # plain write
        (1, f.build_write_multiple_registers(SPEED, [5, 6])),
        (1, f.build_read_request(3, SPEED, 2)),
        (1, b"\x03\x00\x01"),  # malformed read: refused (0x03), never forwarded
        (1, f.build_read_request(3, 0, 0)),  # quantity 0: refused (0x03)
        (2, f.build_read_request(3, TARGET, 2)),
        (passthrough_unit, f.build_read_request(3, 0x6200, 4)),  # pass-through
        (1, f.build_write_multiple_registers(TARGET, [0, 1000])),  # target: coroutine
        (1, f.build_write_single_register(TRIGGER, 0x10)),  # trigger: coroutine
        (1, f.build_read_request(3, TARGET, 2)),
        (99, f.build_read_request(3, 0, 1)),  # not routed: 0x0A
    ]


PITCH = "position_mm,error_um\n0,0\n200,12\n400,20\n600,8\n800,-15\n"


def test_gateway_fast_and_coroutine_paths_answer_the_same(tmp_path: Path) -> None:
    """The same script through the gateway with and without its fast handler, after the
    same compensated move: the same bytes; the fast path took the reads and plain
    writes."""

    def edit(data: dict) -> None:
        data["axes"]["X"]["compensation"]["pitch"] = "x.csv"

    async def body() -> None:
        async with rig(tmp_path, edit, {"x.csv": PITCH}) as r:
            app, master = r["app"], r["master"]
            assert isinstance(master, AsyncModbusTcpClient)
            gw = app.gateway
            taken: list[tuple[int, bytes]] = []
            inner = app.tcp.fast

            def spy(unit_id: int, pdu: bytes, done: Done) -> bool:
                ok = inner(unit_id, pdu, done)
                if ok:
                    taken.append((unit_id, pdu))
                return ok

            raw = await RawTcpMaster.connect(app.tcp_port)
            answers: dict[str, list[bytes]] = {}
            for mode in ("fast", "coroutine"):
                app.tcp.fast = spy if mode == "fast" else None
                # the same state before each run: a compensated move to 300 mm
                await raw.request(1, f.build_write_multiple_registers(TARGET, [4, 0x93E0]))
                await raw.request(1, f.build_write_single_register(TRIGGER, 0x10))
                answers[mode] = [await raw.request(u, pdu) for u, pdu in _script(20)]
            await raw.close()
            assert answers["fast"] == answers["coroutine"]
            fast_answers = dict(zip(_script(20), answers["fast"], strict=True))
            assert f.parse_read_registers_response(
                fast_answers[(1, f.build_read_request(3, TARGET, 2))]) == [0, 1000]
            assert fast_answers[(99, f.build_read_request(3, 0, 1))] == \
                f.exception_pdu(3, f.GATEWAY_PATH_UNAVAILABLE)
            assert gw.axis_state("X").applied
            # reads, plain writes and pass-through went the fast way; target, trigger and
            # unrouted units did not
            kinds = {(u, pdu[0], int.from_bytes(pdu[1:3], "big")) for u, pdu in taken}
            assert (1, 3, TARGET) in kinds and (1, 3, FEEDBACK) in kinds
            assert (1, 6, SPEED) in kinds and (1, 16, SPEED) in kinds and (20, 3, 0x6200) in kinds
            assert not any(a in (TARGET, TRIGGER) and fc in (6, 16) for _, fc, a in kinds)
            assert not any(u == 99 for u, _, _ in kinds)

    run(body())


def test_gateway_fast_path_keeps_write_protect(tmp_path: Path) -> None:
    def edit(data: dict) -> None:
        data["write_protect"] = [{"unit": 1, "address": SPEED, "count": 1}]

    async def body() -> None:
        async with rig(tmp_path, edit) as r:
            app = r["app"]
            raw = await RawTcpMaster.connect(app.tcp_port)
            assert await raw.request(1, f.build_write_single_register(SPEED, 1)) == \
                f.exception_pdu(6, f.ILLEGAL_DATA_ADDRESS)
            assert await raw.request(1, f.build_write_single_register(SPEED + 1, 1)) == \
                f.build_write_single_register(SPEED + 1, 1)
            assert app.write_guard.refused == 1
            await raw.close()

    run(body())
