"""The downstream bus interface: :class:`Bus`, its errors, its fair queue and counters.

Shape after python-can's ``BusABC``: the base class :class:`Bus` does the fair queue, the
retry/timeout loop and the reply checks once (unit id, transaction id, function, byte
count, echoed address and quantity); each transport fills a few small hooks (``_open``,
``_prepare``, ``_send``, ``_recv_internal``, ``_after_timeout``, ``_close``): Modbus TCP in
:mod:`gateway.modbus.tcp_bus`, RTU in :mod:`gateway.modbus.rtu_bus`. Kept apart from them
so that each transport imports this module and nothing imports back (no cycle); the public
names are re-exported by :mod:`gateway.modbus.downstream`.

Errors the gateway turns into Modbus exceptions upstream:
:class:`DriveTimeout` (0x0B, the drive stayed silent) and :class:`BusUnavailable` (0x0A,
the port or connection is down). A drive's own exception response is returned as is.
"""

from __future__ import annotations

import asyncio
import contextvars
import logging
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
)

# the logger of the module these buses were split from: log settings keep working
log = logging.getLogger("gateway.modbus.downstream")

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
        #: unit id → transactions in a row it left unanswered (DriveTimeout); a unit leaves
        #: at its next reply: a silent drive on a bus that is up (the status unit says so)
        self.silent: dict[int, int] = {}
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
                if self.silent:
                    self.silent.pop(unit_id, None)
                if timed_out:  # an earlier attempt may still be answered: a duplicate
                    self._after_timeout(final=True)
                return reply
            timed_out = True
            self.counters.timeouts += 1
            self._after_timeout(final)
            log.debug("%s: unit %d FC%02d attempt %d timed out", self.name, unit_id, pdu[0],
                      attempt + 1)
        self.unanswered(unit_id)
        raise DriveTimeout(f"{self.name}: unit {unit_id} did not answer FC{pdu[0]:02d}")

    def unanswered(self, unit_id: int) -> None:
        """Count a transaction ``unit_id`` left unanswered (every attempt timed out)."""
        self.silent[unit_id] = self.silent.get(unit_id, 0) + 1

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
