"""The serial line tells a tty's empty wake-up from a hang-up: an empty read on a port that
is still there keeps the line (closing it would flush a request in flight), a closed
other end or a port that is ready forever with nothing to read is a loss."""

from __future__ import annotations

import contextlib
import os
from collections.abc import Iterator

import pytest

from gateway.modbus.frames import rtu_encode, rtu_request_length
from gateway.modbus.serialline import MAX_EMPTY_READS, SerialLine, SerialLineLost
from tests.helpers_modbus import PtyPair, run, wait_for_condition


@contextlib.contextmanager
def open_line() -> Iterator[tuple[PtyPair, SerialLine]]:
    """A SerialLine opened on a pty; the test holds the other end (``pair.master``)."""
    pair = PtyPair()
    line = SerialLine(pair.path, baudrate=115200)
    line.open()
    try:
        yield pair, line
    finally:
        line.close()
        pair.close()


def test_empty_wakeup_keeps_the_line_and_its_bytes() -> None:
    async def main() -> None:
        with open_line() as (pair, line):
            frame = rtu_encode(1, bytes.fromhex("0300000001"))
            pair.write(frame[:3])  # half a request is buffered ...
            await wait_for_condition(lambda: line.pending_bytes == 3)
            line._on_readable()  # ... when the tty wakes us with nothing more to read
            assert line.is_open and line.spurious_wakeups == 1
            assert line.pending_bytes == 3
            pair.write(frame[3:])
            got = await line.read_frame(rtu_request_length, timeout_s=2.0)
            assert got == frame

    run(main())


def test_other_end_closed_is_a_loss() -> None:
    async def main() -> None:
        with open_line() as (pair, line):
            os.close(pair.master)  # the adapter goes away
            await wait_for_condition(lambda: not line.is_open)
            assert line.lost

    run(main())


def test_ready_forever_with_nothing_to_read_is_a_loss() -> None:
    async def main() -> None:
        with open_line() as (_, line):
            for _ in range(MAX_EMPTY_READS - 1):
                line._on_readable()
            assert line.is_open
            line._on_readable()
            assert line.lost and line.spurious_wakeups == MAX_EMPTY_READS - 1

    run(main())


def test_a_port_that_refuses_a_setting_is_one_line_naming_it(monkeypatch) -> None:
    """An adapter (or a pty) refusing a setting makes pyserial's tcsetattr raise
    ``termios.error``, which is no OSError: it crashed the gateway with a traceback. Now
    it is a lost line naming the port and the settings, as a missing port is. (The
    refusal itself cannot be had from a pty on every kernel: pyserial's call is made to
    raise what such an adapter raises.)"""
    import termios

    import serial

    def refuse(*args: object, **kwargs: object) -> None:
        raise termios.error(22, "Invalid argument")

    monkeypatch.setattr(serial, "Serial", refuse)
    line = SerialLine("/dev/ttyUSB7", baudrate=57600, parity="E", stopbits=1)
    with pytest.raises(SerialLineLost) as info:
        line.open()
    assert str(info.value) == "/dev/ttyUSB7: refuses 57600 baud, 8E1: Invalid argument"
    assert isinstance(info.value, OSError)  # the bus logs it and retries; run exits 3
