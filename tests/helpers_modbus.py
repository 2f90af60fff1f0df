"""Shared fixtures for the transport tests: real pymodbus drives, pty pairs, raw clients.

No mocks: the "drive" is a pymodbus server (TCP on 127.0.0.1 port 0, or RTU on a pty),
serial lines are pseudo-terminals (a pty ignores baud rate), and the masters speak raw
Modbus TCP / RTU bytes so every byte can be compared.
"""

from __future__ import annotations

import asyncio
import contextlib
import os
import select
import threading
import time
import tty
from collections.abc import AsyncIterator, Awaitable, Callable
from typing import TypeVar

from pymodbus.constants import ExcCodes
from pymodbus.pdu import ModbusPDU
from pymodbus.server import ModbusSerialServer, ModbusTcpServer
from pymodbus.simulator import DataType, SimData, SimDevice

from gateway.modbus.frames import rtu_encode

T = TypeVar("T")

DRIVE_UNIT = 1
SLOW_ADDRESS = 500  # reading/writing here makes the drive sleep SLOW_S before answering
SLOW_S = 0.15
EXC_ADDRESS = 600  # the drive answers 0x03 here
REGISTERS = 1000


def run(coro: Awaitable[T], timeout_s: float = 20.0) -> T:
    """Run one test coroutine with a hard time bound."""

    async def bounded() -> T:
        return await asyncio.wait_for(coro, timeout_s)

    return asyncio.run(bounded())


async def wait_for_condition(check: Callable[[], bool], timeout_s: float = 5.0) -> None:
    """Poll a cheap condition (on the loop) until true; fail after ``timeout_s``."""
    deadline = time.monotonic() + timeout_s
    while not check():
        if time.monotonic() > deadline:
            raise AssertionError("condition not met in time")
        await asyncio.sleep(0.002)


async def _action(function_code: int, start_address: int, address: int, count: int,
                  current_registers: list[int], set_values: list[int] | None
                  ) -> ExcCodes | None:
    if address <= SLOW_ADDRESS < address + count:
        await asyncio.sleep(SLOW_S)
    if address <= EXC_ADDRESS < address + count:
        return ExcCodes.ILLEGAL_VALUE
    return None


def _only_units(units: tuple[int, ...]) -> Callable[[bool, ModbusPDU], ModbusPDU | None]:
    """trace_pdu hook: requests for other units get no reply at all (a silent drive)."""

    def trace(sending: bool, pdu: ModbusPDU) -> ModbusPDU | None:
        if not sending and pdu.dev_id not in units:
            return None
        return pdu

    return trace


def drive_device(unit: int = DRIVE_UNIT) -> SimDevice:
    """A drive with REGISTERS holding registers (coils share them), slow and failing spots."""
    return SimDevice(unit, [SimData(0, count=REGISTERS, values=0, datatype=DataType.REGISTERS)],
                     action=_action)


@contextlib.asynccontextmanager
async def tcp_drive(units: tuple[int, ...] = (DRIVE_UNIT,), port: int = 0) -> AsyncIterator[int]:
    """A pymodbus TCP server on 127.0.0.1 (port 0: any); yields its port. Other units are
    silent."""
    server = ModbusTcpServer([drive_device(u) for u in units], address=("127.0.0.1", port),
                             trace_pdu=_only_units(units))  # type: ignore[arg-type]
    await server.serve_forever(background=True)
    try:
        yield server.transport.sockets[0].getsockname()[1]
    finally:
        await server.shutdown()


@contextlib.asynccontextmanager
async def rtu_drive(port: str, units: tuple[int, ...] = (DRIVE_UNIT,)
                    ) -> AsyncIterator[ModbusSerialServer]:
    """A pymodbus RTU server on serial ``port`` (a pty); other units are silent."""
    server = ModbusSerialServer([drive_device(u) for u in units], port=port, baudrate=115200,
                                trace_pdu=_only_units(units))  # type: ignore[arg-type]
    await server.serve_forever(background=True)
    try:
        yield server
    finally:
        await server.shutdown()


class PtyPair:
    """One pseudo-terminal: our code opens ``path``; the test reads/writes ``master``."""

    def __init__(self) -> None:
        self.master, self.slave = os.openpty()
        tty.setraw(self.slave)
        self.path = os.ttyname(self.slave)
        os.set_blocking(self.master, False)

    def write(self, data: bytes) -> None:
        os.write(self.master, data)

    def read_available(self) -> bytes:
        try:
            return os.read(self.master, 4096)
        except (BlockingIOError, OSError):
            return b""

    def close(self) -> None:
        for fd in (self.master, self.slave):
            with contextlib.suppress(OSError):
                os.close(fd)


class PtyBridge:
    """A null-modem cable: two pty pairs whose masters are copied to each other by a thread.

    Open ``a`` at one end, ``b`` at the other. ``inject_to_b`` writes raw bytes as if they
    came down the cable (garbage, fragments). ``unplug()`` closes everything.
    """

    def __init__(self) -> None:
        self._a = PtyPair()
        self._b = PtyPair()
        self.a = self._a.path
        self.b = self._b.path
        self._stop_r, self._stop_w = os.pipe()
        self._lock = threading.Lock()
        self._thread = threading.Thread(target=self._copy, daemon=True)
        self._thread.start()

    def _copy(self) -> None:
        pair = {self._a.master: self._b.master, self._b.master: self._a.master}
        while True:
            readable, _, _ = select.select([*pair, self._stop_r], [], [], 1.0)
            if self._stop_r in readable:
                return
            for fd in readable:
                try:
                    data = os.read(fd, 4096)
                except (BlockingIOError, OSError):
                    continue
                with self._lock:
                    _write_all(pair[fd], data)

    def inject_to_b(self, data: bytes) -> None:
        with self._lock:
            _write_all(self._b.master, data)

    def inject_to_a(self, data: bytes) -> None:
        with self._lock:
            _write_all(self._a.master, data)

    def unplug(self) -> None:
        os.write(self._stop_w, b"x")
        self._thread.join(2.0)
        self._a.close()
        self._b.close()
        for fd in (self._stop_r, self._stop_w):
            with contextlib.suppress(OSError):
                os.close(fd)


def _write_all(fd: int, data: bytes) -> None:
    view = memoryview(data)
    deadline = time.monotonic() + 2.0
    while view and time.monotonic() < deadline:
        try:
            view = view[os.write(fd, view):]
        except BlockingIOError:
            time.sleep(0.0005)


# ---------------------------------------------------------------- raw masters


def mbap(tid: int, unit: int, pdu: bytes) -> bytes:
    """A Modbus TCP frame."""
    return tid.to_bytes(2, "big") + b"\x00\x00" + (len(pdu) + 1).to_bytes(2, "big") \
        + bytes((unit,)) + pdu


async def read_mbap(reader: asyncio.StreamReader, timeout_s: float = 3.0
                    ) -> tuple[int, int, bytes]:
    """Next (tid, unit, pdu) from a Modbus TCP stream."""
    header = await asyncio.wait_for(reader.readexactly(7), timeout_s)
    body = await asyncio.wait_for(reader.readexactly(int.from_bytes(header[4:6], "big") - 1),
                                  timeout_s)
    return int.from_bytes(header[:2], "big"), header[6], body


class RawTcpMaster:
    """A Modbus TCP master speaking raw frames over one connection."""

    def __init__(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        self.reader, self.writer = reader, writer
        self._tid = 0

    @classmethod
    async def connect(cls, port: int, host: str = "127.0.0.1") -> RawTcpMaster:
        reader, writer = await asyncio.open_connection(host, port)
        return cls(reader, writer)

    async def request(self, unit: int, pdu: bytes, timeout_s: float = 3.0) -> bytes:
        self._tid = self._tid % 0xFFFF + 1
        self.writer.write(mbap(self._tid, unit, pdu))
        await self.writer.drain()
        tid, r_unit, r_pdu = await read_mbap(self.reader, timeout_s)
        assert (tid, r_unit) == (self._tid, unit)
        return r_pdu

    async def close(self) -> None:
        self.writer.close()
        with contextlib.suppress(Exception):
            await self.writer.wait_closed()


async def rtu_request(pair: PtyPair, unit: int, pdu: bytes, timeout_s: float = 3.0) -> bytes:
    """Send an RTU request on a pty master and collect one reply frame (unit+PDU+CRC)."""
    from gateway.modbus.frames import find_rtu_frame, rtu_response_length

    pair.write(rtu_encode(unit, pdu))
    buf = b""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        buf += pair.read_available()
        scan = find_rtu_frame(buf, rtu_response_length)
        if scan.frame is not None:
            return scan.frame
        await asyncio.sleep(0.001)
    raise TimeoutError(f"no RTU reply, got {buf.hex()}")
