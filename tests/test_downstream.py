"""Downstream buses against real pymodbus drives: late replies, timeouts, unavailability,
reconnection, fairness, cancellation, garbage on the line."""

from __future__ import annotations

import asyncio
import contextlib
import dataclasses
import os
import tempfile
import time
from collections.abc import AsyncIterator
from typing import Any

import pytest

from gateway.modbus import frames as f
from gateway.modbus.downstream import (
    BusCounters,
    BusUnavailable,
    DriveTimeout,
    RtuBus,
    TcpBus,
)
from tests.helpers_modbus import (
    DRIVE_UNIT,
    EXC_ADDRESS,
    SLOW_ADDRESS,
    PtyBridge,
    rtu_drive,
    run,
    tcp_drive,
    wait_for_condition,
)

READ_ONE = f.build_read_request(3, 10, 1)


@contextlib.asynccontextmanager
async def rtu_bus_to_drive(**bus_kwargs: Any) -> AsyncIterator[tuple[RtuBus, PtyBridge]]:
    """An RtuBus at 115200 on a null-modem cable to a pymodbus RTU drive; the bus is closed
    and the cable unplugged afterwards."""
    bridge = PtyBridge()
    try:
        async with rtu_drive(bridge.b):
            bus = RtuBus(bridge.a, baudrate=115200, **bus_kwargs)
            try:
                yield bus, bridge
            finally:
                await bus.close()
    finally:
        bridge.unplug()


async def seed(bus: TcpBus | RtuBus) -> None:
    """The drive's first registers written. A drive whose server has just started may
    answer later than the bus's timeout on a loaded machine (the full suite beside a
    bench: FC16 timed out at 0.1 s): asked again until it answers (within 3 s), and the
    counters then read as if it had answered the first time."""
    start = dataclasses.replace(bus.counters)
    deadline = time.monotonic() + 3.0
    while True:
        try:
            await bus.transact(DRIVE_UNIT, f.build_write_multiple_registers(10, [111, 222]))
            break
        except DriveTimeout:
            assert time.monotonic() < deadline
    c = bus.counters
    c.transactions, c.replies = start.transactions + 1, start.replies + 1
    c.timeouts, c.retries, c.dropped = start.timeouts, start.retries, start.dropped
    bus.silent.pop(DRIVE_UNIT, None)


def opens_allowed_by_backoff(bus: TcpBus | RtuBus, elapsed_s: float) -> int:
    """The most (re)open attempts the bus's backoff permits within ``elapsed_s``: the first
    at once, each next one a backoff later (reconnect_min_s, doubling up to
    reconnect_max_s). A slow (loaded) run is allowed the few more it has time for."""
    assert bus.reconnect_min_s > 0
    attempts, at_s, backoff_s = 1, 0.0, bus.reconnect_min_s
    while at_s + backoff_s <= elapsed_s:
        at_s += backoff_s
        backoff_s = min(2 * backoff_s, bus.reconnect_max_s)
        attempts += 1
    return attempts


def assert_refused_without_storm(bus: TcpBus | RtuBus, before: BusCounters, requests: int,
                                 elapsed_s: float) -> None:
    """The ``requests`` made on a dead bus since ``before`` (they took ``elapsed_s``) were
    each refused as unavailable (0x0A) without a request sent and waited for (no timeout),
    and with no connection storm: no more opens than the backoff allows in that time. A
    bound on the opens, not on the clock: load makes the requests slower, not wrong."""
    counters = bus.counters
    assert counters.unavailable - before.unavailable == requests
    assert (counters.timeouts, counters.replies) == (before.timeouts, before.replies)
    opens = counters.open_attempts - before.open_attempts
    assert opens <= opens_allowed_by_backoff(bus, elapsed_s), (opens, elapsed_s)


def test_tcp_late_reply_is_dropped_by_transaction_id_and_shape() -> None:
    async def main() -> None:
        async with tcp_drive() as port:
            bus = TcpBus("127.0.0.1", port, timeout_s=0.1, retries=0)
            await seed(bus)
            t0 = time.monotonic()
            with pytest.raises(DriveTimeout):
                await bus.transact(DRIVE_UNIT, f.build_read_request(3, SLOW_ADDRESS, 2))
            assert time.monotonic() - t0 >= bus.timeout_s  # not before the timeout
            # Raised by the timeout, not after the reply (SLOW_S > timeout_s): the drive had
            # not answered yet. Load cannot reorder this: the drive sleeps on this event loop,
            # its timer is due after the bus's, and its reply needs further loop turns.
            assert bus.counters.dropped == 0
            assert (bus.counters.timeouts, bus.counters.retries, bus.counters.replies) == (1, 0, 1)
            # Keep asking while the late reply arrives: never the wrong answer.
            deadline = time.monotonic() + 2.0
            while bus.counters.dropped == 0 and time.monotonic() < deadline:
                assert await bus.transact(DRIVE_UNIT, READ_ONE) == b"\x03\x02\x00\x6f"
                await asyncio.sleep(0.01)
            assert bus.counters.dropped >= 1
            assert await bus.transact(DRIVE_UNIT, READ_ONE) == b"\x03\x02\x00\x6f"
            await bus.close()

    run(main())


@pytest.mark.parametrize("guard", ["default-guard", "no-guard-shape-check"])
def test_rtu_late_reply_never_reaches_next_request(guard: str) -> None:
    async def main() -> None:
        kwargs = {} if guard == "default-guard" else {"late_guard_s": 0.0}
        async with rtu_bus_to_drive(timeout_s=0.1, retries=0, **kwargs) as (bus, _):
            await seed(bus)
            # Same shape as the next request with the guard; a different one without.
            count = 1 if guard == "default-guard" else 2
            # The slow register reads 0: its late reply is told from READ_ONE's (111) by
            # value, whatever its shape.
            late_reply = b"\x03" + bytes((2 * count,)) + bytes(2 * count)
            own_reply = b"\x03\x02\x00\x6f"
            with pytest.raises(DriveTimeout):
                await bus.transact(DRIVE_UNIT, f.build_read_request(3, SLOW_ADDRESS, count))
            try:
                reply = await bus.transact(DRIVE_UNIT, READ_ONE)
            except DriveTimeout:
                # Without a guard the drive may still be busy: a timeout is fine, a
                # wrong answer is not.
                assert guard != "default-guard"
            else:
                assert reply != late_reply, "the late reply reached the next request"
                assert reply == own_reply
                if guard == "default-guard":
                    # The guard held the next request until the late reply had come and
                    # been discarded; the next request was answered on its first attempt.
                    assert bus.counters.dropped >= 1
                    assert (bus.counters.timeouts, bus.counters.replies) == (1, 2)
            # The late reply is dropped either during the guard or before the next request.
            await wait_for_condition(lambda: bus.counters.dropped >= 1
                                     or bus.line.pending_bytes > 0, 2.0)
            assert await bus.transact(DRIVE_UNIT, READ_ONE) == b"\x03\x02\x00\x6f"
            assert bus.counters.dropped >= 1

    run(main())


def test_rtu_retry_then_answer_and_exception_relayed() -> None:
    async def main() -> None:
        async with rtu_bus_to_drive(timeout_s=0.14, retries=1) as (bus, _):
            # The drive takes 0.15 s: attempt 1 times out, its late answer serves the retry
            # (it may come up to 0.13 s late on a loaded machine: a slow one only delays it).
            reply = await bus.transact(DRIVE_UNIT, f.build_read_request(3, SLOW_ADDRESS, 1))
            assert reply == b"\x03\x02\x00\x00"
            assert (bus.counters.timeouts, bus.counters.retries) == (1, 1)
            assert await bus.transact(DRIVE_UNIT, f.build_read_request(3, EXC_ADDRESS, 1)) \
                == b"\x83\x03"
            assert await bus.transact(DRIVE_UNIT, READ_ONE) == b"\x03\x02\x00\x00"

    run(main())


def test_rtu_garbage_on_the_line_is_skipped() -> None:
    async def main() -> None:
        async with rtu_bus_to_drive(timeout_s=0.2, retries=0) as (bus, bridge):
            await seed(bus)
            bridge.inject_to_a(b"\x01\x03\x02\xff")  # a stale fragment before the request
            assert await bus.transact(DRIVE_UNIT, READ_ONE) == b"\x03\x02\x00\x6f"
            assert bus.counters.timeouts == 0

    run(main())


def test_tcp_drive_down_unavailable_with_backoff_then_reconnects() -> None:
    async def main() -> None:
        async with tcp_drive() as port:
            bus = TcpBus("127.0.0.1", port, timeout_s=0.1, retries=0, reconnect_min_s=0.2)
            assert await bus.connect()
            await seed(bus)
        # The drive is gone: 0x0A at once, and no connection storm.
        before = dataclasses.replace(bus.counters)
        t0 = time.monotonic()
        for _ in range(50):
            with pytest.raises(BusUnavailable):
                await bus.transact(DRIVE_UNIT, READ_ONE)
        assert_refused_without_storm(bus, before, 50, time.monotonic() - t0)
        assert not bus.connected
        # It comes back on the same port: the bus reconnects by itself after the backoff.
        async with tcp_drive(port=port):
            deadline = time.monotonic() + 3.0
            while True:
                try:
                    reply = await bus.transact(DRIVE_UNIT, READ_ONE)
                    break
                except BusUnavailable:
                    assert time.monotonic() < deadline
                    await asyncio.sleep(0.05)
            assert reply == b"\x03\x02\x00\x00"  # a fresh drive
            assert bus.counters.reconnects == 2
        await bus.close()

    run(main())


def test_tcp_idle_close_by_drive_is_transparent() -> None:
    async def main() -> None:
        async with tcp_drive() as port:
            bus = TcpBus("127.0.0.1", port, timeout_s=0.2, retries=1)
            await seed(bus)
            assert bus._transport is not None
            bus._transport.close()  # as if the drive dropped an idle connection
            await wait_for_condition(lambda: not bus.connected)
            assert await bus.transact(DRIVE_UNIT, READ_ONE) == b"\x03\x02\x00\x6f"
            await bus.close()

    run(main())


def test_rtu_port_disappears_and_comes_back() -> None:
    async def main() -> None:
        with tempfile.TemporaryDirectory() as tmp:
            link = os.path.join(tmp, "ttyBUS")
            bridge = PtyBridge()
            os.symlink(bridge.a, link)
            bus = RtuBus(link, baudrate=115200, timeout_s=0.1, retries=0, reconnect_min_s=0.1)
            async with rtu_drive(bridge.b):
                await seed(bus)
                bridge.unplug()
                # The hang-up is seen at once (no reply timeout), then the backoff refuses.
                before = dataclasses.replace(bus.counters)
                t0 = time.monotonic()
                for _ in range(30):
                    with pytest.raises(BusUnavailable):
                        await bus.transact(DRIVE_UNIT, READ_ONE)
                assert_refused_without_storm(bus, before, 30, time.monotonic() - t0)
            bridge2 = PtyBridge()
            os.unlink(link)
            os.symlink(bridge2.a, link)
            try:
                async with rtu_drive(bridge2.b):
                    deadline = time.monotonic() + 3.0
                    while True:
                        try:
                            reply = await bus.transact(DRIVE_UNIT, READ_ONE)
                            break
                        # (a first reply over 0.1 s late: a loaded machine's, asked again)
                        except (BusUnavailable, DriveTimeout):
                            assert time.monotonic() < deadline
                            await asyncio.sleep(0.05)
                    assert reply == b"\x03\x02\x00\x00"
                    await bus.close()
            finally:
                bridge2.unplug()

    run(main())


def test_fair_queue_between_callers_and_depth() -> None:
    async def main() -> None:
        async with tcp_drive() as port:
            bus = TcpBus("127.0.0.1", port, timeout_s=0.5, retries=0)
            await seed(bus)
            order: list[str] = []
            depths: list[int] = []

            async def one(caller: str, i: int) -> None:
                await bus.transact(DRIVE_UNIT, READ_ONE, caller=caller)
                order.append(f"{caller}{i}")
                depths.append(bus.queue_depth)

            greedy = [asyncio.create_task(one("A", i)) for i in range(20)]
            await asyncio.sleep(0)  # A's 20 are queued first
            polite = [asyncio.create_task(one("B", i)) for i in range(3)]
            await asyncio.gather(*greedy, *polite)
            # B is served every other turn, not after all of A.
            assert max(order.index(f"B{i}") for i in range(3)) <= 7, order
            assert [o for o in order if o[0] == "A"] == [f"A{i}" for i in range(20)]
            assert max(depths) >= 15 and bus.queue_depth == 0
            await bus.close()

    run(main())


def test_cancelled_waiter_leaves_the_queue() -> None:
    async def main() -> None:
        async with tcp_drive() as port:
            bus = TcpBus("127.0.0.1", port, timeout_s=0.5, retries=0)
            await seed(bus)
            slow = asyncio.create_task(bus.transact(DRIVE_UNIT,
                                                    f.build_read_request(3, SLOW_ADDRESS, 1)))
            await asyncio.sleep(0.01)
            waiting = asyncio.create_task(bus.transact(DRIVE_UNIT, READ_ONE))
            await wait_for_condition(lambda: bus.queue_depth == 1)
            waiting.cancel()
            await wait_for_condition(lambda: bus.queue_depth == 0)
            assert await slow == b"\x03\x02\x00\x00"
            assert await bus.transact(DRIVE_UNIT, READ_ONE) == b"\x03\x02\x00\x6f"
            await bus.close()
            with pytest.raises(BusUnavailable):
                await bus.transact(DRIVE_UNIT, READ_ONE)

    run(main())


def test_bad_requests_rejected_before_the_bus() -> None:
    async def main() -> None:
        bus = TcpBus("127.0.0.1", 1, timeout_s=0.1)
        with pytest.raises(ValueError):
            await bus.transact(1, b"")
        with pytest.raises(ValueError):
            await bus.transact(256, READ_ONE)
        assert bus.counters.open_attempts == 0

    run(main())


def test_min_silence_between_frames() -> None:
    async def main() -> None:
        # the timeout bounds a reply, not the silence: a loaded machine (two bench jobs on
        # two cores) once took over 0.2 s to answer through the pseudo-terminal
        async with rtu_bus_to_drive(timeout_s=2.0, retries=0, min_silence_s=0.02) as (bus, _):
            await seed(bus)
            t0 = time.monotonic()
            for _ in range(5):
                await bus.transact(DRIVE_UNIT, READ_ONE)
            assert time.monotonic() - t0 >= 5 * 0.02

    run(main())
