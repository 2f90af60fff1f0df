"""RTU timing: t3.5 per the spec or exact for the baud rate, silences timed exactly (not
rounded up to whole milliseconds by the event loop) and never cut short."""

from __future__ import annotations

import asyncio
import statistics
import time

import pytest

from gateway.modbus import frames as f
from gateway.modbus.downstream import RtuBus
from gateway.modbus.serialline import ExactTimer, SerialLine, t35_s
from tests.helpers_modbus import DRIVE_UNIT, PtyBridge, PtyPair, rtu_drive, run

READ_ONE = f.build_read_request(3, 10, 1)


def test_t35_spec_and_exact() -> None:
    assert t35_s(115200) == 0.00175  # spec: fixed above 19200
    assert t35_s(115200, parity="N", mode="exact") == pytest.approx(3.5 * 10 / 115200)
    assert t35_s(115200, mode="exact") == pytest.approx(3.5 * 11 / 115200)
    assert t35_s(9600) == t35_s(9600, mode="exact") == pytest.approx(3.5 * 11 / 9600)
    with pytest.raises(ValueError):
        t35_s(9600, mode="fast")  # type: ignore[arg-type]
    assert SerialLine("/dev/null", baudrate=38400, t35="exact").silence_s == \
        pytest.approx(3.5 * 11 / 38400)
    assert SerialLine("/dev/null", baudrate=38400).silence_s == 0.00175
    assert SerialLine("/dev/null", baudrate=38400, silence_s=0.01, t35="exact").silence_s \
        == 0.01
    assert RtuBus("/dev/null", baudrate=57600, t35="exact").line.silence_s == \
        pytest.approx(3.5 * 11 / 57600)


def test_exact_timer_is_never_early_and_not_rounded_to_milliseconds() -> None:
    async def main() -> None:
        fired: list[float] = []
        done = asyncio.Event()

        def call() -> None:
            fired.append(time.monotonic())
            done.set()

        timer = ExactTimer(call)
        late: list[float] = []
        try:
            for _ in range(30):
                done.clear()
                when = time.monotonic() + 0.0003
                timer.arm(when)
                await done.wait()
                late.append(fired[-1] - when)
            # cancelled: never called; re-armed: only the new deadline counts
            timer.arm(time.monotonic() + 0.0005)
            timer.cancel()
            timer.arm(time.monotonic() + 0.002)
            n = len(fired)
            await asyncio.sleep(0.01)
            assert len(fired) == n + 1
        finally:
            timer.close()
        assert min(late) >= 0
        # epoll would round 0.3 ms up to 1 ms; allow for a loaded machine
        assert statistics.median(late) < 0.0006, late

    run(main())


def test_wait_data_wakes_on_bytes_and_times_out_exactly() -> None:
    async def main() -> None:
        pair = PtyPair()
        line = SerialLine(pair.path, baudrate=115200)
        line.open()
        try:
            waits = []
            for _ in range(20):
                t0 = time.monotonic()
                await line.wait_data(0.0004)
                waits.append(time.monotonic() - t0)
            assert min(waits) >= 0.0004
            assert statistics.median(waits) < 0.0009, waits
            asyncio.get_running_loop().call_later(0.01, pair.write, b"\x01")
            t0 = time.monotonic()
            await line.wait_data(1.0)
            assert time.monotonic() - t0 < 0.5 and line.pending_bytes == 1
        finally:
            line.close()
            pair.close()

    run(main())


@pytest.mark.parametrize("t35", ["spec", "exact"])
def test_rtu_bus_silence_before_each_request_is_never_short(t35: str) -> None:
    """Each request leaves at least t3.5 (+ min_silence_s) after the last byte received;
    measured from the reply's arrival, not from an estimated end of our own request."""

    async def main() -> None:
        bridge = PtyBridge()
        try:
            async with rtu_drive(bridge.b):
                bus = RtuBus(bridge.a, baudrate=115200, timeout_s=0.2, retries=0, t35=t35)
                gaps: list[float] = []
                write = bus.line.write

                async def timed_write(data: bytes) -> None:
                    if bus.line.last_rx_s:
                        gaps.append(time.monotonic() - bus.line.last_rx_s)
                    await write(data)

                bus.line.write = timed_write  # type: ignore[method-assign]
                for _ in range(40):
                    assert await bus.transact(DRIVE_UNIT, READ_ONE) == b"\x03\x02\x00\x00"
                silence = bus.line.silence_s
                assert min(gaps) >= silence
                assert statistics.median(gaps) < silence + 0.0007, (silence, gaps)
                await bus.close()
        finally:
            bridge.unplug()

    run(main())
