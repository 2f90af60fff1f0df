"""The log's repeat filter: a flood of one warning becomes a few lines and a count."""

from __future__ import annotations

import asyncio
import io
import ipaddress
import logging

from gateway.modbus.upstream import TcpServer
from gateway.service import EVERY, RepeatFilter, configure_logging
from tests.helpers_modbus import run, wait_for_condition


class Clock:
    def __init__(self) -> None:
        self.t_s = 100.0

    def __call__(self) -> float:
        return self.t_s


def capture(clock: Clock) -> tuple[logging.Logger, io.StringIO]:
    out = io.StringIO()
    handler = logging.StreamHandler(out)
    handler.setFormatter(logging.Formatter("%(levelname)s %(message)s"))
    handler.addFilter(RepeatFilter(burst=3, window_s=60.0, clock=clock))
    logger = logging.getLogger(f"test.repeats.{id(out)}")
    logger.handlers[:] = [handler]
    logger.propagate = False
    logger.setLevel(logging.DEBUG)
    return logger, out


def test_a_flood_of_one_warning_is_held_back_and_counted() -> None:
    clock = Clock()
    log, out = capture(clock)
    for i in range(50):
        log.warning("refused Modbus TCP client %s: %s", f"127.0.9.{i}", "not allowed")
        log.warning("write to unit %d refused", 1)  # another kind: its own budget
        log.info("idle for %d s", i)  # below WARNING: never held back
    lines = out.getvalue().splitlines()
    assert sum("refused Modbus TCP client" in ln for ln in lines) == 3
    assert sum("write to unit 1 refused" in ln for ln in lines) == 3
    assert sum(ln.startswith("INFO") for ln in lines) == 50
    clock.t_s += 59.9
    log.warning("refused Modbus TCP client %s: %s", "127.0.9.99", "not allowed")
    assert "127.0.9.99" not in out.getvalue()  # still the same window
    clock.t_s += 0.2
    log.warning("refused Modbus TCP client %s: %s", "127.0.9.98", "not allowed")
    last = out.getvalue().splitlines()[-1]
    assert last == ("WARNING refused Modbus TCP client 127.0.9.98: not allowed "
                    "(48 more like this held back)")
    log.warning("refused Modbus TCP client %s: %s", "127.0.9.97", "not allowed")
    assert out.getvalue().splitlines()[-1].endswith("127.0.9.97: not allowed")  # count reset


def test_the_daemons_log_handler_holds_repeats_back() -> None:
    root = logging.getLogger()
    saved = root.handlers[:], root.level
    try:
        configure_logging("info", environ={})
        assert any(isinstance(f, RepeatFilter) for f in root.handlers[0].filters)
    finally:
        root.handlers[:], level = saved
        root.setLevel(level)


def test_refusals_of_different_causes_are_held_back_separately() -> None:
    """A flood of allowlist refusals must not swallow (or count) a refusal of another
    cause: each cause of the TCP server's refusals is its own kind."""
    out = io.StringIO()
    handler = logging.StreamHandler(out)
    handler.setFormatter(logging.Formatter("%(message)s"))
    handler.addFilter(RepeatFilter(burst=1, window_s=60.0, clock=Clock()))
    logger = logging.getLogger("gateway.modbus.upstream")
    saved = logger.handlers[:], logger.level
    logger.handlers[:] = [handler]
    logger.setLevel(logging.WARNING)

    async def held(unit_id: int, pdu: bytes) -> bytes | None:
        await asyncio.sleep(10)
        return None

    async def main() -> None:
        async with TcpServer(held, "127.0.0.1", 0, allow=["127.0.0.0/8"],
                             max_connections=1) as server:
            server.allow = [ipaddress.ip_network("127.0.0.2/32")]
            for _ in range(3):  # not in the allowlist
                _, w = await asyncio.open_connection("127.0.0.1", server.port)
                w.close()
            await wait_for_condition(lambda: server.counters.refused == 3)
            server.allow = None
            _, busy = await asyncio.open_connection("127.0.0.1", server.port)
            busy.write(bytes((0, 1, 0, 0, 0, 6, 1, 3, 0, 0, 0, 1)))
            await wait_for_condition(lambda: server.counters.requests == 1)
            _, w = await asyncio.open_connection("127.0.0.1", server.port)  # all busy
            await wait_for_condition(lambda: server.counters.refused == 4)
            w.close()
            busy.close()
            await server.close(timeout_s=0.1)

    try:
        run(main())
    finally:
        logger.handlers[:], logger.level = saved
    lines = out.getvalue().splitlines()
    assert sum("not in the allowlist" in ln for ln in lines) == 1  # 2 held back
    assert [ln for ln in lines if "max_connections" in ln] != []  # not held, not counted
    assert "held back" not in out.getvalue()


def test_a_record_marked_every_is_never_held_back() -> None:
    """A refused reload is an operator's own action: each gets its line and its reason."""
    clock = Clock()
    log, out = capture(clock)
    for i in range(10):
        log.error("reload refused, old config kept: %s", f"reason {i}", extra=EVERY)
    lines = out.getvalue().splitlines()
    assert lines == [f"ERROR reload refused, old config kept: reason {i}" for i in range(10)]
