"""Modbus clients toward the drives: one :class:`Bus` per RS-485 line or TCP drive endpoint.

Shape after python-can's ``BusABC``: the base class :class:`Bus` does the fair queue, the
retry/timeout loop and the reply checks once (unit id, transaction id, function, byte
count, echoed address and quantity); each transport fills a few small hooks (``_open``,
``_prepare``, ``_send``, ``_recv_internal``, ``_after_timeout``, ``_close``).

Errors the gateway turns into Modbus exceptions upstream:
:class:`DriveTimeout` (0x0B, the drive stayed silent) and :class:`BusUnavailable` (0x0A,
the port or connection is down). A drive's own exception response is returned as is.
"""

from __future__ import annotations

import asyncio
import contextlib
import contextvars
import logging
import socket
import time
from abc import ABC, abstractmethod
from collections import OrderedDict, deque
from collections.abc import Callable, Hashable
from dataclasses import dataclass

from .frames import (
    GATEWAY_PATH_UNAVAILABLE,
    GATEWAY_TARGET_NO_RESPONSE,
    MAX_PDU_BYTES,
    READ_HOLDING_REGISTERS,
    READ_INPUT_REGISTERS,
    ModbusError,
    build_read_request,
    is_exception,
    parse_read_registers_response,
    response_matches,
    rtu_encode,
    rtu_response_length,
)
from .serialline import RtuStream, SerialLine, SerialLineLost, T35Mode

log = logging.getLogger(__name__)

#: Completion callback of :meth:`Bus.submit`: ``done(reply, None)`` with the drive's reply
#: PDU, or ``done(None, error)`` with the error :meth:`Bus.transact` would have raised.
Done = Callable[[bytes | None, BaseException | None], None]

#: Who is asking, for fair queuing: the upstream server sets it per master connection,
#: so each master gets its turn on a busy bus whatever the others have queued.
current_caller: contextvars.ContextVar[Hashable | None] = contextvars.ContextVar(
    "compgw_caller", default=None)


class BusError(ModbusError):
    """A transaction could not be completed on the bus."""


class DriveTimeout(BusError):
    """The drive did not answer within timeout_s × (retries + 1): upstream gets 0x0B."""

    code = GATEWAY_TARGET_NO_RESPONSE


class BusUnavailable(BusError):
    """The serial port or TCP connection is down: upstream gets 0x0A."""

    code = GATEWAY_PATH_UNAVAILABLE


@dataclass
class BusCounters:
    """Monotonic counters for metrics."""

    transactions: int = 0  # transact() calls that reached the bus
    replies: int = 0  # answered (normal or exception response)
    timeouts: int = 0  # attempts that timed out
    retries: int = 0  # attempts after the first
    dropped: int = 0  # late or mismatched replies discarded
    unavailable: int = 0  # transactions refused with BusUnavailable
    open_attempts: int = 0  # attempts to (re)open the port/connection
    broadcasts: int = 0  # broadcast() calls
    reconnects: int = 0  # successful (re)opens


class FairQueue:
    """Grants one holder at a time: round-robin between callers, FIFO within one caller.

    A master that pipelines many requests cannot starve another: after each transaction
    the turn passes to the next caller that is waiting.
    """

    def __init__(self) -> None:
        self._lanes: OrderedDict[Hashable | None, deque[asyncio.Future[None]]] = OrderedDict()
        self._busy = False

    @property
    def depth(self) -> int:
        """Requests waiting (not counting the one on the bus)."""
        return sum(len(lane) for lane in self._lanes.values())

    async def acquire(self, caller: Hashable | None) -> None:
        if not self._busy and not self._lanes:
            self._busy = True
            return
        fut: asyncio.Future[None] = asyncio.get_running_loop().create_future()
        self._lanes.setdefault(caller, deque()).append(fut)
        try:
            await fut
        except asyncio.CancelledError:
            if fut.done() and not fut.cancelled():
                self.release()  # granted just as we were cancelled: pass the turn on
            else:
                lane = self._lanes.get(caller)
                if lane is not None and fut in lane:
                    lane.remove(fut)
                    if not lane:
                        del self._lanes[caller]
            raise

    def release(self) -> None:
        while self._lanes:
            caller, lane = next(iter(self._lanes.items()))
            fut = lane.popleft()
            if lane:
                self._lanes.move_to_end(caller)
            else:
                del self._lanes[caller]
            if not fut.done():
                fut.set_result(None)
                return
        self._busy = False


class Bus(ABC):
    """One transaction at a time toward the drives on one line or endpoint.

    ``timeout_s`` is per attempt; ``retries`` extra attempts follow a timeout (never an
    exception response, never a write that was answered). ``min_silence_s`` is extra line
    silence between frames for drives that need more than t3.5 (Delta: 0.01).
    ``reconnect_min_s``/``reconnect_max_s`` bound the exponential backoff between
    attempts to reopen a failed port/connection: meanwhile transactions fail at once
    with :class:`BusUnavailable` (no busy loop, no master left hanging).
    ``turnaround_s``: after a broadcast, how long the drives are given before the next
    request (RTU; the serial-line spec's turnaround delay).
    """

    def __init__(self, *, name: str = "bus", timeout_s: float = 0.1, retries: int = 1,
                 min_silence_s: float = 0.0, reconnect_min_s: float = 0.1,
                 reconnect_max_s: float = 5.0, turnaround_s: float = 0.1) -> None:
        if timeout_s <= 0 or retries < 0 or min_silence_s < 0 or turnaround_s < 0:
            raise ValueError("timeout_s must be > 0, retries, min_silence_s and turnaround_s "
                             ">= 0")
        self.name = name
        self.turnaround_s = turnaround_s
        self.timeout_s = timeout_s
        self.retries = retries
        self.min_silence_s = min_silence_s
        self.reconnect_min_s = reconnect_min_s
        self.reconnect_max_s = reconnect_max_s
        self.counters = BusCounters()
        self._queue = FairQueue()
        self._backoff_s = reconnect_min_s
        self._next_open_s = 0.0
        self._closed = False

    # ------------------------------------------------------------------ public

    @property
    def queue_depth(self) -> int:
        """Transactions waiting for the bus (metrics)."""
        return self._queue.depth

    @property
    @abstractmethod
    def connected(self) -> bool:
        """True while the port/connection is open."""

    async def transact(self, unit_id: int, pdu: bytes, *, caller: Hashable | None = None
                       ) -> bytes:
        """Send request ``pdu`` to ``unit_id`` and return the drive's response PDU.

        The response may be an exception PDU (relayed as is). Raises :class:`DriveTimeout`
        or :class:`BusUnavailable`; ``ValueError`` for a PDU that cannot be sent.
        """
        if not 1 <= len(pdu) <= MAX_PDU_BYTES or not 0 <= unit_id <= 255:
            raise ValueError(f"cannot send unit {unit_id} PDU of {len(pdu)} bytes")
        if caller is None:
            caller = current_caller.get()
        await self._queue.acquire(caller)
        try:
            return await self._transact_locked(unit_id, pdu)
        finally:
            self._queue.release()

    async def read_registers(self, unit_id: int, table: str, address: int, count: int
                             ) -> list[int]:
        """``count`` holding or input registers of a drive (the gateway's own reads).
        Raises :class:`ModbusError` when the drive answers an exception or the wrong
        number of words, besides what :meth:`transact` raises."""
        fc = READ_HOLDING_REGISTERS if table == "holding" else READ_INPUT_REGISTERS
        reply = await self.transact(unit_id, build_read_request(fc, address, count))
        if is_exception(reply):
            raise ModbusError(f"{self.name}: unit {unit_id} refused the read of "
                              f"0x{address:04X}", reply[1])  # fmt: skip
        words = parse_read_registers_response(reply)
        if len(words) != count:
            raise ModbusError(f"{self.name}: unit {unit_id} answered {len(words)} words, "
                              f"not {count}")  # fmt: skip
        return words

    async def broadcast(self, pdu: bytes, units: list[int]) -> None:
        """A write request for every drive on this bus at once. Here (a TCP endpoint has no
        broadcast): one unicast per unit in ``units``; as on a serial line, where nobody
        answers a broadcast, a drive's exception reply or silence is logged, not raised;
        :class:`BusUnavailable` (nothing could be sent) is raised. :class:`RtuBus` sends
        one unit-0 frame."""
        self.counters.broadcasts += 1
        for unit in units:
            try:
                reply = await self.transact(unit, pdu)
            except BusUnavailable:
                raise
            except ModbusError as exc:
                log.warning("%s: broadcast FC%02d to unit %d: %s", self.name, pdu[0], unit, exc)
                continue
            if is_exception(reply):
                log.debug("%s: unit %d answered the broadcast with exception 0x%02X",
                          self.name, unit, reply[1])

    def submit(self, unit_id: int, pdu: bytes, done: Done) -> bool:
        """Start ``transact(unit_id, pdu)`` without a task when the bus can send at once
        (free, connected, nothing queued): ``done`` gets the outcome later, exactly what
        ``transact`` would have returned or raised. False: nothing was done (the bus is
        busy or down, or this transport has no such path); call :meth:`transact`."""
        return False

    async def connect(self) -> bool:
        """Open the port/connection now (e.g. at start-up); False if it is down."""
        try:
            await self._ensure_open(force=True)
        except BusUnavailable:
            return False
        return True

    async def close(self) -> None:
        """Close for good; later transactions raise :class:`BusUnavailable`."""
        self._closed = True
        await self._close()

    # ------------------------------------------------------------------ the loop

    async def _transact_locked(self, unit_id: int, pdu: bytes, first_attempt: int = 0,
                               timed_out: bool = False) -> bytes:
        """The attempts of one transaction (``first_attempt`` > 0: the rest of one that
        :meth:`submit` started; ``timed_out``: an earlier attempt timed out)."""
        if not first_attempt:
            self.counters.transactions += 1
        for attempt in range(first_attempt, self.retries + 1):
            final = attempt == self.retries
            if attempt:
                self.counters.retries += 1
            await self._ensure_open()
            in_flight = False
            try:
                await self._prepare()
                tid = await self._send(unit_id, pdu)
                in_flight = True
                if self._no_reply_expected(unit_id):
                    in_flight = False
                    return b""
                reply = await self._await_reply(unit_id, tid, pdu)
                in_flight = False
            except (OSError, ConnectionError, EOFError) as err:
                in_flight = False
                await self._lost(err)
                if not final:
                    continue
                self.counters.unavailable += 1
                raise BusUnavailable(f"{self.name}: {err}") from err
            finally:
                if in_flight:  # cancelled with a request on the line: its reply may come
                    self._after_timeout(final=True)
            if reply is not None:
                self.counters.replies += 1
                if timed_out:  # an earlier attempt may still be answered: a duplicate
                    self._after_timeout(final=True)
                return reply
            timed_out = True
            self.counters.timeouts += 1
            self._after_timeout(final)
            log.debug("%s: unit %d FC%02d attempt %d timed out", self.name, unit_id, pdu[0],
                      attempt + 1)
        raise DriveTimeout(f"{self.name}: unit {unit_id} did not answer FC{pdu[0]:02d}")

    async def _await_reply(self, unit_id: int, tid: int | None, pdu: bytes) -> bytes | None:
        """Receive until a matching reply or the attempt's deadline; drop the others."""
        deadline = time.monotonic() + self.timeout_s + self._extra_wait_s(pdu)
        while True:
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                return None
            got = await self._recv_internal(remaining)
            if got is None:
                return None
            r_unit, r_tid, r_pdu = got
            if ((r_unit is None or r_unit == unit_id) and (tid is None or r_tid == tid)
                    and response_matches(pdu, r_pdu)):
                return r_pdu
            self.counters.dropped += 1
            log.debug("%s: dropped reply unit %d tid %s %s (waiting for unit %d tid %s)",
                      self.name, r_unit, r_tid, r_pdu.hex(), unit_id, tid)

    async def _ensure_open(self, force: bool = False) -> None:
        if self._closed:
            self.counters.unavailable += 1
            raise BusUnavailable(f"{self.name}: closed")
        if self.connected:
            return
        now = time.monotonic()
        if now < self._next_open_s and not force:
            self.counters.unavailable += 1
            raise BusUnavailable(f"{self.name}: down, next attempt in "
                                 f"{self._next_open_s - now:.2f} s")
        self.counters.open_attempts += 1
        try:
            await self._open()
        except (OSError, ConnectionError, asyncio.TimeoutError) as err:
            self._next_open_s = time.monotonic() + self._backoff_s
            self._backoff_s = min(self._backoff_s * 2, self.reconnect_max_s)
            log.warning("%s: cannot open: %s", self.name, err)
            self.counters.unavailable += 1
            raise BusUnavailable(f"{self.name}: {err}") from err
        self._backoff_s = self.reconnect_min_s
        self.counters.reconnects += 1
        log.info("%s: open", self.name)

    async def _lost(self, err: BaseException) -> None:
        log.warning("%s: connection lost: %s", self.name, err)
        await self._close()

    # ------------------------------------------------------------------ hooks

    @abstractmethod
    async def _open(self) -> None:
        """Open the port/connection; raise OSError if it cannot be."""

    @abstractmethod
    async def _close(self) -> None:
        """Close the port/connection (idempotent)."""

    async def _prepare(self) -> None:  # noqa: B027  (optional hook)
        """Before each request: let the line settle, drop stale input."""

    @abstractmethod
    async def _send(self, unit_id: int, pdu: bytes) -> int | None:
        """Send one request; return its transaction id (None where there is none)."""

    @abstractmethod
    async def _recv_internal(self, timeout_s: float) -> tuple[int | None, int | None, bytes] | None:
        """Next frame as (unit id, transaction id, PDU), or None on timeout (unit or tid
        None: not checked)."""

    def _after_timeout(self, final: bool) -> None:  # noqa: B027  (optional hook)
        """A request went unanswered, its reply may still come. ``final``: the next frame
        sent will be another request (not a retry of this one, whose late reply would be
        a valid answer)."""

    def _extra_wait_s(self, pdu: bytes) -> float:
        """Added to timeout_s for one attempt (wire time on serial lines)."""
        return 0.0

    def _no_reply_expected(self, unit_id: int) -> bool:
        return False


class RtuBus(Bus):
    """An RS-485 line (or pty) with Modbus RTU framing, one transaction at a time.

    Before each request the line must have been quiet for t3.5 + ``min_silence_s``.
    After a request that may still be answered (it timed out, its transaction was cancelled,
    or it was a retry whose first attempt may answer twice), the next *different* request
    waits until ``timeout_s + late_guard_s`` (default guard: ``timeout_s``) after that
    request was sent, discarding whatever arrives, then for a quiet line: a late reply
    inside that window is dropped. One arriving even later is still checked against the
    new request (unit, function, byte count, echoed address and quantity) and dropped if
    it does not fit; a late reply of the very same shape after the guard is the one case
    RTU cannot tell, hence the guard. Retries of the same request are sent without the
    guard (a late answer to the first attempt is a correct answer to the retry). Unit 0 is
    broadcast: sent, no reply awaited, ``b""`` returned, and the next request waits
    ``turnaround_s`` (input meanwhile discarded) while the drives act on it.

    t3.5 is ``silence_s`` if given, else per ``t35`` (``"spec"``: 1.75 ms above 19200 baud;
    ``"exact"``: 3.5 characters at the baud rate). Silences are timed exactly (no rounding
    up to whole milliseconds, see :mod:`gateway.modbus.serialline`), and bytes arriving during
    one restart it.
    """

    def __init__(self, port: str, *, baudrate: int = 19200, bytesize: int = 8,
                 parity: str = "E", stopbits: float = 1, silence_s: float | None = None,
                 late_guard_s: float | None = None, t35: T35Mode = "spec",
                 serial_kwargs: dict[str, object] | None = None, **bus_kwargs: object) -> None:
        bus_kwargs.setdefault("name", port)
        super().__init__(**bus_kwargs)  # type: ignore[arg-type]
        self._use_line(SerialLine(port, baudrate=baudrate, bytesize=bytesize, parity=parity,
                                  stopbits=stopbits, silence_s=silence_s, t35=t35,
                                  **(serial_kwargs or {})), late_guard_s)

    def _use_line(self, line: RtuStream, late_guard_s: float | None) -> None:
        """Serve transactions on ``line`` (a serial port here; another byte stream in
        :class:`gateway.modbus.rtu_over_tcp.RtuOverTcpBus`)."""
        self.line = line
        self.late_guard_s = self.timeout_s if late_guard_s is None else late_guard_s
        self._hold_until_s = 0.0  # no new request before this (monotonic)
        self._last_send_s = 0.0

    @property
    def connected(self) -> bool:
        return self.line.is_open

    async def _open(self) -> None:
        line = self.line
        assert isinstance(line, SerialLine)
        try:
            line.open()
        except SerialLineLost as err:
            raise OSError(str(err)) from err
        self._opened()

    def _opened(self) -> None:
        self._hold_until_s = time.monotonic() + self.line.silence_s  # drop what was there

    async def _close(self) -> None:
        self.line.close()

    async def _prepare(self) -> None:
        gap_s = self.line.silence_s + self.min_silence_s
        dropped = self.line.discard()
        hold_s = self._hold_until_s - time.monotonic()
        if hold_s > 0:  # a late reply may still come: listen and drop it
            while hold_s > 0 and self.line.is_open:
                await self.line.wait_data(hold_s)
                dropped += self.line.discard()
                hold_s = self._hold_until_s - time.monotonic()
            dropped += await self.line.wait_quiet(gap_s, max_wait_s=self.timeout_s)
        elif gap_s > self.line.quiet_for_s():  # exact wait; noise restarts the silence
            dropped += await self.line.wait_quiet(gap_s, max_wait_s=max(self.timeout_s,
                                                                        2 * gap_s))
        if dropped:
            self.counters.dropped += 1
            self.line.garbage_bytes += dropped

    async def broadcast(self, pdu: bytes, units: list[int]) -> None:
        """One unit-0 frame on the line, no reply (every drive acts on it)."""
        self.counters.broadcasts += 1
        await self.transact(0, pdu)

    async def _send(self, unit_id: int, pdu: bytes) -> int | None:
        await self.line.write(rtu_encode(unit_id, pdu))
        self._last_send_s = time.monotonic()
        if unit_id == 0:  # the drives' turnaround: no request (nor reply) meanwhile
            self._hold_until_s = max(self._hold_until_s, self._last_send_s + self.turnaround_s)
        return None

    async def _recv_internal(self, timeout_s: float
                             ) -> tuple[int | None, int | None, bytes] | None:
        frame = await self.line.read_frame(rtu_response_length, timeout_s)
        if frame is None:
            return None
        return frame[0], None, frame[1:-2]

    def _after_timeout(self, final: bool) -> None:
        if final:  # the last request sent may still be answered until well after its timeout
            self._hold_until_s = self._last_send_s + self.timeout_s + self.late_guard_s

    def _extra_wait_s(self, pdu: bytes) -> float:
        return self.line.wire_time_s(len(pdu) + 3)

    def _no_reply_expected(self, unit_id: int) -> bool:
        return unit_id == 0


class _MbapClient(asyncio.Protocol):
    """The TCP connection of one :class:`TcpBus`: cuts MBAP frames in ``data_received``
    and hands each to the bus, which resolves the waiting transaction's future (no reader
    task, no queue: a reply wakes the transaction directly)."""

    def __init__(self, bus: TcpBus) -> None:
        self.bus = bus
        self.transport: asyncio.Transport | None = None
        self.buf = bytearray()
        self.lost = False
        self.paused = False
        self._drain: asyncio.Future[None] | None = None

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        self.transport = transport  # type: ignore[assignment]
        sock = transport.get_extra_info("socket")
        if sock is not None:
            with contextlib.suppress(OSError):
                sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
                sock.setsockopt(socket.SOL_SOCKET, socket.SO_KEEPALIVE, 1)

    def data_received(self, data: bytes) -> None:
        buf = self.buf
        buf += data
        while len(buf) >= 8:
            length = (buf[4] << 8) | buf[5]
            if buf[2] or buf[3] or not 2 <= length <= MAX_PDU_BYTES + 1:
                log.warning("%s: bad MBAP header %s: closing", self.bus.name, bytes(buf[:8]).hex())
                buf.clear()
                self.close()
                return
            size = 6 + length
            if len(buf) < size:
                return
            tid = (buf[0] << 8) | buf[1]
            unit = buf[6]
            pdu = bytes(buf[7:size])
            del buf[:size]
            self.bus._on_frame(self, unit, tid, pdu)

    def eof_received(self) -> bool:
        return False  # the drive closed: close our side too (connection_lost follows)

    def connection_lost(self, exc: Exception | None) -> None:
        self.close()

    def pause_writing(self) -> None:
        self.paused = True

    def resume_writing(self) -> None:
        self.paused = False
        if self._drain is not None and not self._drain.done():
            self._drain.set_result(None)
        self._drain = None

    async def drain(self) -> None:
        """Wait until the write buffer is below the low-water mark (only when paused)."""
        if self.lost:
            raise ConnectionError("connection closed")
        if self._drain is None or self._drain.done():
            self._drain = asyncio.get_running_loop().create_future()
        await self._drain

    def close(self) -> None:
        """Close (idempotent); a transaction waiting on this connection fails at once."""
        if not self.lost:
            self.lost = True
            if self.transport is not None:
                self.transport.close()
            if self._drain is not None and not self._drain.done():
                self._drain.set_exception(ConnectionError("connection closed"))
            self.bus._on_lost(self)


def _deliver(done: Done, reply: bytes | None, exc: BaseException | None) -> None:
    """Call a :meth:`Bus.submit` completion callback; its errors are logged, never raised
    into the connection's ``data_received`` or the timer."""
    try:
        done(reply, exc)
    except Exception:
        log.exception("completion callback failed")


def _expire(fut: asyncio.Future[bytes | None]) -> None:
    if not fut.done():
        fut.set_result(None)


class TcpBus(Bus):
    """A Modbus TCP drive (or TCP-to-RTU converter): one persistent connection.

    Replies are matched by MBAP transaction id, so a late reply to a timed-out request is
    recognised and dropped. The connection is opened on first use and reopened after a
    failure with exponential backoff; a peer that closes an idle connection is reconnected
    transparently on the next request.

    The connection is an :class:`asyncio.Protocol`: ``data_received`` cuts frames and
    resolves the future of the transaction waiting for that transaction id (its timeout
    is one ``loop.call_later``); anything else is a late or foreign reply, dropped and
    counted. Writes wait only when the transport's buffer is above its high-water mark.
    """

    def __init__(self, host: str, port: int = 502, *, connect_timeout_s: float | None = None,
                 check_unit: bool = True, **bus_kwargs: object) -> None:
        bus_kwargs.setdefault("name", f"{host}:{port}")
        super().__init__(**bus_kwargs)  # type: ignore[arg-type]
        self.host = host
        self.port = port
        self.connect_timeout_s = connect_timeout_s or max(self.timeout_s, 1.0)
        self.check_unit = check_unit
        self._proto: _MbapClient | None = None
        # the transaction waiting for a reply: (connection, tid, unit or None, request, future)
        self._waiter: tuple[_MbapClient, int, int | None, bytes,
                            asyncio.Future[bytes | None]] | None = None
        # the transaction started by submit(): (connection, tid, unit, request, done)
        self._fast: tuple[_MbapClient, int, int, bytes, Done] | None = None
        self._fast_timer: asyncio.TimerHandle | None = None  # armed at or before the deadline
        self._fast_deadline = 0.0  # loop time
        self._loop: asyncio.AbstractEventLoop | None = None
        self._tasks: set[asyncio.Task[None]] = set()  # _remaining() tasks (kept referenced)
        self._tid = 0

    @property
    def connected(self) -> bool:
        return self._proto is not None and not self._proto.lost

    @property
    def _transport(self) -> asyncio.Transport | None:
        """The open connection's transport (tests close it to simulate a drive's close)."""
        return self._proto.transport if self._proto is not None else None

    async def _open(self) -> None:
        await self._close()
        self._loop = loop = asyncio.get_running_loop()
        _, proto = await asyncio.wait_for(
            loop.create_connection(lambda: _MbapClient(self), self.host, self.port),
            self.connect_timeout_s)
        self._proto = proto

    async def _close(self) -> None:
        proto, self._proto = self._proto, None
        if proto is not None:
            proto.close()

    def submit(self, unit_id: int, pdu: bytes, done: Done) -> bool:
        """Send now and return; ``done`` is called from ``data_received`` with the reply
        (or from the timeout timer). No task, no future: the pass-through hot path. A
        timeout or a lost connection continues in a task with the remaining attempts of
        :meth:`Bus._transact_locked`, so retries and errors are the same as ``transact``'s.
        """
        queue = self._queue
        proto = self._proto
        if (queue._busy or queue._lanes or proto is None or proto.lost or proto.paused
                or self.min_silence_s or self._closed or not 1 <= len(pdu) <= MAX_PDU_BYTES
                or not 0 <= unit_id <= 255):
            return False
        transport = proto.transport
        loop = self._loop
        if transport is None or loop is None:
            return False
        queue._busy = True
        self.counters.transactions += 1
        self._tid = tid = self._tid % 0xFFFF + 1
        n = len(pdu) + 1
        self._fast = (proto, tid, unit_id, pdu, done)
        # One timer per bus, not per request: a timer armed for an earlier transaction
        # fires no later than this one's deadline and is then re-armed for what is left.
        self._fast_deadline = loop.time() + self.timeout_s
        if self._fast_timer is None:
            self._fast_timer = loop.call_at(self._fast_deadline, self._fast_expired)
        transport.write(bytes((tid >> 8, tid & 0xFF, 0, 0, n >> 8, n & 0xFF, unit_id)) + pdu)
        return True

    def _fast_end(self) -> None:
        self._fast = None  # the timer stays armed: the next transaction may use it

    def _fast_expired(self) -> None:
        self._fast_timer = None
        fast = self._fast
        if fast is None:
            return
        assert self._loop is not None
        left = self._fast_deadline - self._loop.time()
        if left > 0:  # armed for an earlier transaction (at least 1 ms: no busy loop
            # on an event loop whose timers are rounded to milliseconds)
            self._fast_timer = self._loop.call_later(max(left, 0.001), self._fast_expired)
            return
        self._fast_end()
        _, _, unit_id, pdu, done = fast
        self.counters.timeouts += 1
        final = not self.retries
        self._after_timeout(final)
        log.debug("%s: unit %s FC%02d attempt 1 timed out", self.name, unit_id, pdu[0])
        if final:
            self._queue.release()
            _deliver(done, None, DriveTimeout(
                f"{self.name}: unit {unit_id} did not answer FC{pdu[0]:02d}"))
        else:
            self._continue(fast, None)

    def _continue(self, fast: tuple[_MbapClient, int, int, bytes, Done],
                  err: BaseException | None) -> None:
        """The first attempt of a submitted transaction got no reply (``err``: the
        connection was lost, else a timeout): the other attempts run in a task."""
        loop = self._loop or asyncio.get_running_loop()
        task = loop.create_task(self._remaining(fast[2], fast[3], fast[4], err))
        self._tasks.add(task)
        task.add_done_callback(self._tasks.discard)

    async def _remaining(self, unit_id: int, pdu: bytes, done: Done,
                         err: BaseException | None) -> None:
        try:
            try:
                if err is not None:
                    await self._lost(err)
                    if not self.retries:
                        self.counters.unavailable += 1
                        raise BusUnavailable(f"{self.name}: {err}") from err
                reply = await self._transact_locked(unit_id, pdu, 1, timed_out=err is None)
            finally:
                self._queue.release()
        except BaseException as exc:
            _deliver(done, None, exc)
            if not isinstance(exc, Exception):
                raise
        else:
            _deliver(done, reply, None)

    def _on_frame(self, proto: _MbapClient, unit: int, tid: int, pdu: bytes) -> None:
        fast = self._fast
        if fast is not None:
            f_proto, f_tid, f_unit, f_pdu, done = fast
            if tid == f_tid and proto is f_proto and (unit == f_unit or not self.check_unit) \
                    and response_matches(f_pdu, pdu):
                self._fast = None
                self.counters.replies += 1
                queue = self._queue
                if queue._lanes:
                    queue.release()  # the next transaction waiting in transact()
                else:
                    queue._busy = False
                try:
                    done(pdu, None)
                except Exception:
                    log.exception("completion callback failed")
                return
        waiter = self._waiter
        if waiter is not None:
            w_proto, w_tid, w_unit, w_pdu, fut = waiter
            if tid == w_tid and proto is w_proto and (w_unit is None or unit == w_unit) \
                    and response_matches(w_pdu, pdu) and not fut.done():
                fut.set_result(pdu)
                return
        self.counters.dropped += 1
        log.debug("%s: dropped reply unit %d tid %d %s (waiting for %s)", self.name, unit, tid,
                  pdu.hex(), None if waiter is None else f"unit {waiter[2]} tid {waiter[1]}")

    def _on_lost(self, proto: _MbapClient) -> None:
        fast = self._fast
        if fast is not None and fast[0] is proto:
            self._fast_end()
            self._continue(fast, ConnectionError("connection closed by drive"))
        waiter = self._waiter
        if waiter is not None and waiter[0] is proto and not waiter[4].done():
            waiter[4].set_exception(ConnectionError("connection closed by drive"))

    async def _prepare(self) -> None:
        if self.min_silence_s:
            await asyncio.sleep(self.min_silence_s)

    async def _send(self, unit_id: int, pdu: bytes) -> int | None:
        proto = self._proto
        if proto is None or proto.lost or proto.transport is None:
            raise ConnectionError("connection closed by drive")
        self._tid = tid = self._tid % 0xFFFF + 1
        proto.transport.write(
            bytes((tid >> 8, tid & 0xFF, 0, 0, (len(pdu) + 1) >> 8, (len(pdu) + 1) & 0xFF,
                   unit_id)) + pdu)
        if proto.paused:
            await proto.drain()
        return tid

    async def _await_reply(self, unit_id: int, tid: int | None, pdu: bytes) -> bytes | None:
        assert tid is not None and self._proto is not None
        loop = self._loop or asyncio.get_running_loop()
        fut: asyncio.Future[bytes | None] = loop.create_future()
        self._waiter = (self._proto, tid, unit_id if self.check_unit else None, pdu, fut)
        timer = loop.call_later(self.timeout_s, _expire, fut)
        try:
            return await fut
        finally:
            timer.cancel()
            self._waiter = None

    async def _recv_internal(self, timeout_s: float
                             ) -> tuple[int | None, int | None, bytes] | None:
        raise NotImplementedError("TcpBus matches replies as they arrive (_await_reply)")
