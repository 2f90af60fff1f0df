"""The Modbus TCP bus: :class:`TcpBus`, one persistent connection to a drive or converter.

The transport hooks of :class:`gateway.modbus.bus.Bus` for MBAP framing, plus the
task-free :meth:`TcpBus.submit` hot path of the pass-through (``data_received`` resolves the
waiting transaction directly). Its own module because the connection protocol, the
transaction-id matching and the fast path are a concern of their own.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import socket

from .bus import Bus, BusUnavailable, Done, DriveTimeout
from .frames import MAX_PDU_BYTES, response_matches

# the logger of the module these buses were split from: log settings keep working
log = logging.getLogger("gateway.modbus.downstream")


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
            self.unanswered(unit_id)
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
                if self.silent:
                    self.silent.pop(f_unit, None)
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
