"""Modbus servers for the upper computer: TCP (MBAP) and RTU (serial), frame level.

Both hand every request PDU to one handler, ``async (unit_id, pdu) -> bytes | None``
(None: no reply), and send back what it returns, byte for byte. A handler raising
:class:`gateway.modbus.frames.ModbusError` (``DriveTimeout``, ``BusUnavailable``, or one raised
by the interception layer) is answered with that exception code; any other error with
0x04 and a log line, so the master is never left hanging.

Pipelining (TCP): a master may send several requests without waiting, even in one
segment. Each connection is an :class:`asyncio.Protocol` that cuts frames as they arrive
and answers them one after the other, each reply with its own transaction id (no reader
task, no queue hop). Requests of one connection are processed in order, not concurrently:
a master that pipelines "write target, write trigger" must have the trigger reach the
drive after the target, and requests to one RS-485 bus are serialised anyway. Connections
run concurrently.

Fast path (TCP): the server may also get a *fast handler*, ``fast(unit_id, pdu, done) ->
bool``, tried first for each request: True means it took the request and will call
``done(reply, error)`` exactly once (maybe before returning), with what the handler would
have returned or raised; False means it did nothing. The gateway's fast handler takes the
requests that need one drive transaction on a free TCP bus and a synchronous look at the
reply (pass-through, reads, plain writes): no task, no coroutine, no future per request.
Everything else runs the handler coroutine in a task, as before.
"""

from __future__ import annotations

import asyncio
import contextlib
import ipaddress
import itertools
import logging
import socket
from collections import deque
from collections.abc import Awaitable, Callable, Collection, Iterable
from dataclasses import dataclass
from typing import TYPE_CHECKING

from .downstream import current_caller
from .frames import (
    MAX_PDU_BYTES,
    SERVER_DEVICE_FAILURE,
    ModbusError,
    exception_pdu,
    rtu_encode,
    rtu_request_length,
)
from .serialline import SerialLine, SerialLineLost, T35Mode

if TYPE_CHECKING:
    from .mbsecurity import Check, TlsGate, TlsServer

log = logging.getLogger(__name__)

Handler = Callable[[int, bytes], Awaitable[bytes | None]]
Done = Callable[[bytes | None, BaseException | None], None]
FastHandler = Callable[[int, bytes, Done], bool]
Network = ipaddress.IPv4Network | ipaddress.IPv6Network

_conn_ids = itertools.count(1)


@dataclass
class ServerCounters:
    """Monotonic counters for metrics."""

    connections: int = 0  # accepted
    refused: int = 0  # closed at accept: not allowed, or every connection busy
    evicted: int = 0  # closed to make room for a new connection (idle longest)
    slow_frames: int = 0  # closed: a frame not complete within frame_timeout_s
    idle_closed: int = 0  # closed: no request for idle_timeout_s
    requests: int = 0
    replies: int = 0
    handler_errors: int = 0  # handler raised something other than ModbusError
    malformed: int = 0  # frames that closed a connection or were skipped


class Listener:
    """What both servers share: the handler call and its error mapping."""

    def __init__(self, handler: Handler, fast: FastHandler | None = None) -> None:
        self.handler = handler
        self.fast = fast
        self.counters = ServerCounters()

    async def _call(self, unit_id: int, pdu: bytes) -> bytes | None:
        """Run the handler; map its errors to exception PDUs; check what it returns."""
        self.counters.requests += 1
        try:
            reply = await self.handler(unit_id, pdu)
        except Exception as err:
            return self._finish(unit_id, pdu, None, err)
        return self._finish(unit_id, pdu, reply, None)

    def _finish(self, unit_id: int, pdu: bytes, reply: bytes | None,
                exc: BaseException | None) -> bytes | None:
        """The reply to send for a handler outcome (its reply, or the error it raised)."""
        if exc is not None:
            if isinstance(exc, ModbusError):
                log.debug("unit %d FC%02d: exception 0x%02X: %s", unit_id, pdu[0], exc.code,
                          exc)
                reply = exception_pdu(pdu[0], exc.code)
            else:
                self.counters.handler_errors += 1
                log.error("handler failed on unit %d PDU %s", unit_id, pdu.hex(),
                          exc_info=exc)
                reply = exception_pdu(pdu[0], SERVER_DEVICE_FAILURE)
        if reply is not None and not 1 <= len(reply) <= MAX_PDU_BYTES:
            self.counters.handler_errors += 1
            log.error("handler returned a %d-byte PDU for unit %d: not sent", len(reply), unit_id)
            reply = exception_pdu(pdu[0], SERVER_DEVICE_FAILURE)
        if reply is not None:
            self.counters.replies += 1
        return reply


def parse_networks(allow: Iterable[str | Network] | None) -> list[Network] | None:
    """Allowlist entries as networks ("10.0.0.0/8", "127.0.0.1"); None = everyone."""
    if allow is None:
        return None
    return [ipaddress.ip_network(a, strict=False) if isinstance(a, str) else a for a in allow]


def _allowed(host: str, networks: list[Network] | None) -> bool:
    if networks is None:
        return True
    try:
        addr = ipaddress.ip_address(host.split("%", 1)[0])
    except ValueError:
        return False
    if isinstance(addr, ipaddress.IPv6Address) and addr.ipv4_mapped is not None:
        addr = addr.ipv4_mapped
    return any(addr in net for net in networks)


class _Connection(asyncio.Protocol):
    """One master's TCP connection, callback-driven (an :class:`asyncio.Protocol`).

    ``data_received`` cuts MBAP frames into a FIFO and, when the connection has nothing in
    flight, starts answering it at once: strictly in order, one request at a time, each
    reply with its own transaction id. A request goes to the server's fast handler when it
    takes it (its completion callback writes the reply and starts the next request), else
    to a task running the handler coroutine. At most ``max_pipeline`` requests are read
    ahead (in flight included): then reading pauses (TCP backpressure) until one is
    answered. End of input (EOF, idle timeout, malformed frame): what was received is
    answered, then the connection closes. Server stopping: the request in flight is
    answered, the rest dropped, nothing more is read.

    Activity (``last_active``, for the idle timeout and for eviction) is a complete request
    received or a reply sent, never a lone byte: a client dripping a frame byte by byte is
    idle, and is closed when its frame is not complete ``frame_timeout_s`` after its first
    byte.
    """

    def __init__(self, server: TcpServer) -> None:
        self.server = server
        self.loop = asyncio.get_running_loop()
        self.transport: asyncio.Transport | None = None
        self.peer = "?"
        self.id = next(_conn_ids)
        self.buf = bytearray()
        self.pending: deque[tuple[int, int, bytes]] = deque()  # (tid, unit, PDU), not started
        self.task: asyncio.Task[None] | None = None  # a request in the handler coroutine
        self.working = False  # answering ``pending`` (a request in flight or a reply draining)
        self.busy = False  # a request is in the handler
        self.current: tuple[int, int, bytes] | None = None  # that request
        self.accepted = False
        self.eof = False  # no more input: answer what was received, then close
        self.stopping = False  # graceful close: finish the request in flight, no more
        self.lost = False  # connection_lost seen
        self.read_paused = False
        self.write_paused = False
        self._draining = False  # a reply is written, waiting for resume_writing
        self._advancing = False  # _advance() is on the stack
        self._done_cb = self._fast_done  # one bound method for every fast request
        self.last_active = self.loop.time()
        self.requested = False  # a complete request has arrived on this connection
        self._idle: asyncio.TimerHandle | None = None
        self._frame_timer: asyncio.TimerHandle | None = None  # a frame is incomplete
        self.authorise: Check | None = None  # TLS: what the client's role may ask
        self.done: asyncio.Future[None] = self.loop.create_future()  # closed and idle

    # ------------------------------------------------------------------ protocol

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        self.transport = transport  # type: ignore[assignment]
        server = self.server
        peername = transport.get_extra_info("peername") or ("?", 0)
        self.peer = f"{peername[0]}:{peername[1]}"
        # one log template per cause: the log filter limits repeats per template
        if not _allowed(str(peername[0]), server.allow):
            self._refuse("refused Modbus TCP client %s: not in the allowlist", self.peer)
            return
        if server._server is None:
            self._refuse("refused Modbus TCP client %s: server closing", self.peer)
            return
        if server.open_count() >= server.max_connections and not server.make_room(self):
            self._refuse("refused Modbus TCP client %s: all %d connections have a request "
                         "in flight (max_connections)", self.peer, server.max_connections)
            return
        sock = transport.get_extra_info("socket")
        if sock is not None:
            with contextlib.suppress(OSError):
                sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self.accepted = True
        if server.tls is not None:  # after the handshake: the certificate's role
            self.authorise = server.tls.authoriser(transport, self.peer)
        server.counters.connections += 1
        server._connections[self] = None
        self.last_active = self.loop.time()
        if server.idle_timeout_s:
            self._idle = self.loop.call_later(server.idle_timeout_s, self._idle_check)
        log.debug("client %s connected", self.peer)

    def _refuse(self, template: str, *args: object) -> None:
        """Close at accept, counted and logged (``template``: one per cause)."""
        self.server.counters.refused += 1
        log.warning(template, *args)
        assert self.transport is not None
        self.transport.close()

    def data_received(self, data: bytes) -> None:
        if self.eof or self.stopping or not self.accepted:
            return
        self.buf += data
        self._cut()

    def eof_received(self) -> bool:
        self._end_input()
        # keep our side open to answer what was received; closed when done (TLS cannot:
        # asyncio closes it anyway, and warns when asked to keep it open)
        return self.server.tls is None

    def connection_lost(self, exc: Exception | None) -> None:
        if exc is not None:
            log.debug("%s: %s", self.peer, exc)
        self.lost = True
        self.eof = True
        self.pending.clear()  # nobody to answer; the request in flight still finishes
        if self._idle is not None:
            self._idle.cancel()
            self._idle = None
        self._stop_frame_timer()
        if self._draining:
            self._draining = False
            self._next()
        self._maybe_done()

    def pause_writing(self) -> None:
        self.write_paused = True

    def resume_writing(self) -> None:
        self.write_paused = False
        if self._draining:
            self._draining = False
            self._next()

    # ------------------------------------------------------------------ requests

    def _cut(self) -> None:
        """Cut complete frames from the buffer into ``pending`` (up to max_pipeline) and
        start answering them if the connection is idle."""
        buf = self.buf
        limit = self.server.max_pipeline
        cut = limited = False
        while len(buf) >= 8 and not self.eof and not self.stopping:
            if len(self.pending) + self.busy >= limit:
                limited = True
                if not self.read_paused and self.transport is not None:
                    self.read_paused = True  # backpressure: stop reading when too far ahead
                    self.transport.pause_reading()
                break
            length = (buf[4] << 8) | buf[5]
            if buf[2] or buf[3] or not 2 <= length <= MAX_PDU_BYTES + 1:
                self.server.counters.malformed += 1
                log.warning("%s: bad MBAP header %s: closing", self.peer, bytes(buf[:8]).hex())
                self._end_input()
                break
            size = 6 + length
            if len(buf) < size:
                break
            self.pending.append(((buf[0] << 8) | buf[1], buf[6], bytes(buf[7:size])))
            del buf[:size]
            cut = True
        if cut:
            self.requested = True
            self.last_active = self.loop.time()
        if buf and not limited and not self.eof and not self.stopping:
            if cut or self._frame_timer is None:  # a new frame began: its clock starts
                self._start_frame_timer()
        else:
            self._stop_frame_timer()
        if self.pending and not self.working:
            self._advance()

    def _start_frame_timer(self) -> None:
        self._stop_frame_timer()
        timeout_s = self.server.frame_timeout_s
        if timeout_s:
            self._frame_timer = self.loop.call_later(timeout_s, self._frame_expired)

    def _stop_frame_timer(self) -> None:
        if self._frame_timer is not None:
            self._frame_timer.cancel()
            self._frame_timer = None

    def _frame_expired(self) -> None:
        """A frame begun ``frame_timeout_s`` ago is still incomplete: a slow or stuck
        sender, closed (what was received complete is answered first)."""
        self._frame_timer = None
        if self.eof or self.stopping or self.lost or not self.buf:
            return
        self.server.counters.slow_frames += 1
        log.warning("Modbus TCP client %s: frame incomplete %.1f s after its first byte: "
                    "closing", self.peer, self.server.frame_timeout_s)
        self._end_input()

    def _advance(self) -> None:
        """Start the next requests of ``pending`` in order, as long as they are answered
        at once (a fast request whose callback already ran); stop at one in flight. With
        nothing left, the connection is idle (and closes if its input has ended)."""
        if self._advancing:
            return  # the loop below is on the stack: it goes on when the callback returns
        self._advancing = True
        pending = self.pending
        server = self.server
        try:
            while not self.busy and not self._draining:
                if not pending or self.stopping:
                    self.working = False
                    if self.eof or self.stopping:
                        pending.clear()
                        self._close_transport()
                    self._maybe_done()
                    return
                self.working = True
                self.busy = True
                self.current = request = pending.popleft()
                server.counters.requests += 1
                if self.authorise is not None:
                    refusal = self.authorise(request[1], request[2])
                    if refusal is not None:  # not this client's role: 0x01, nothing forwarded
                        self._fast_done(None, refusal)
                        continue
                fast = server.fast
                if fast is not None:
                    try:
                        taken = fast(request[1], request[2], self._done_cb)
                    except Exception as exc:  # a bug in the fast handler: answered 0x04
                        self._fast_done(None, exc)
                        continue
                    if taken:
                        continue
                self.task = self.loop.create_task(self._work(request),
                                                  name=f"compgw-up-{self.id}")
        finally:
            self._advancing = False

    def _fast_done(self, reply: bytes | None, exc: BaseException | None) -> None:
        request = self.current
        if request is None or not self.busy:
            log.error("%s: a reply without a request in flight: dropped", self.peer)
            return
        if exc is None and reply and len(reply) <= MAX_PDU_BYTES:
            self.server.counters.replies += 1  # what _finish does with a good reply
        else:
            reply = self.server._finish(request[1], request[2], reply, exc)
        self._replied(request, reply)

    async def _work(self, request: tuple[int, int, bytes]) -> None:
        """One request through the handler coroutine (the fast handler did not take it)."""
        current_caller.set(("tcp", self.id))
        server = self.server
        reply = None
        try:
            try:
                reply = await server.handler(request[1], request[2])
            except Exception as err:
                reply = server._finish(request[1], request[2], None, err)
            else:
                reply = server._finish(request[1], request[2], reply, None)
        except BaseException:  # cancelled (server closing timed out): nothing is sent
            self.task = None
            self.busy = False
            self.current = None
            self.working = False
            self.pending.clear()
            self._close_transport()
            self._maybe_done()
            raise
        self.task = None
        self._replied(request, reply)

    def _replied(self, request: tuple[int, int, bytes], reply: bytes | None) -> None:
        """Write the reply of the request in flight, then go on with the next one."""
        self.busy = False
        self.current = None
        transport = self.transport
        if reply is not None and not self.lost and transport is not None:
            tid, unit = request[0], request[1]
            n = len(reply) + 1
            transport.write(bytes((tid >> 8, tid & 0xFF, 0, 0, n >> 8, n & 0xFF, unit)) + reply)
            if self.write_paused and not self.lost:
                self._draining = True  # resume_writing (or connection_lost) goes on
                return
        self._next()

    def _next(self) -> None:
        self.last_active = self.loop.time()
        if self.read_paused and not (self.eof or self.stopping or self.lost):
            self._cut()  # frames already received, up to the limit again
            if len(self.pending) < self.server.max_pipeline and self.transport is not None:
                self.read_paused = False
                self.transport.resume_reading()
        self._advance()

    def _end_input(self) -> None:
        """No more requests on this connection (EOF, idle, malformed): answer what was
        received, then close."""
        if self.eof:
            return
        self.eof = True
        self._stop_frame_timer()
        self._stop_reading()

    def stop(self) -> None:
        """Graceful close: no more reading, the request in flight is answered, the rest
        dropped, then the connection closes."""
        self.stopping = True
        self.pending.clear()
        self._stop_frame_timer()
        self._stop_reading()

    def _stop_reading(self) -> None:
        """Drop unparsed input, read no more, close now if nothing is in flight."""
        self.buf.clear()
        if not self.lost and self.transport is not None and not self.read_paused:
            self.read_paused = True
            with contextlib.suppress(Exception):
                self.transport.pause_reading()
        if not self.working:
            self._close_transport()

    def _close_transport(self) -> None:
        if self.transport is not None and not self.transport.is_closing():
            self.transport.close()

    def _maybe_done(self) -> None:
        if self.lost and not self.working and not self.done.done():
            if self.server._connections.pop(self, False) is None:
                log.debug("client %s disconnected", self.peer)
            self.done.set_result(None)

    def _idle_check(self) -> None:
        """One timer per connection: closes it when no request arrived for idle_timeout_s
        (a request being answered counts as activity)."""
        self._idle = None
        idle_s = self.server.idle_timeout_s
        if self.eof or self.stopping or self.lost or not idle_s:
            return
        now = self.loop.time()
        if self.working or self.pending:
            self.last_active = now
        due = self.last_active + idle_s
        if now >= due:
            self.server.counters.idle_closed += 1
            log.info("Modbus TCP client %s: no request for %.0f s (idle_timeout_s): closing",
                     self.peer, idle_s)
            self._end_input()
            return
        self._idle = self.loop.call_at(due, self._idle_check)


class TcpServer(Listener):
    """Modbus TCP server: MBAP framing, pipelining, allowlist, connection management.

    ``allow``: client networks accepted (None: all); others are closed at accept and
    logged. ``max_connections``: when that many are open, an allowed new connection closes
    the one idle longest to make room — first among those that never sent a complete
    request, then by time since their last request or reply — as the Modbus TCP
    implementation guide advises, so leaked or silent connections can never lock a working
    master out; only when every connection has a request in flight is the new one refused.
    ``idle_timeout_s``: a connection with no request for that long is closed (None: never).
    ``frame_timeout_s``: a frame not complete that long after its first byte closes its
    connection (None: never). ``max_pipeline``: requests read ahead per connection before
    reading pauses. ``fast``: the fast handler tried first for each request (see the
    module's docstring). ``tls``: Modbus/TCP Security (:mod:`gateway.modbus.mbsecurity`): each
    connection's TLS handshake comes before ``connection_made``, and each request is
    authorised by the client certificate's role before it reaches a handler.
    """

    def __init__(self, handler: Handler, host: str = "127.0.0.1", port: int = 502, *,
                 allow: Iterable[str | Network] | None = None, max_connections: int = 16,
                 idle_timeout_s: float | None = None, frame_timeout_s: float | None = 2.0,
                 max_pipeline: int = 16, fast: FastHandler | None = None,
                 tls: TlsGate | None = None) -> None:
        super().__init__(handler, fast)
        if max_pipeline < 1:
            raise ValueError("max_pipeline must be >= 1")
        self.host = host
        self._port = port
        self.allow = parse_networks(allow)
        self.max_connections = max_connections
        self.idle_timeout_s = idle_timeout_s
        self.frame_timeout_s = frame_timeout_s
        self.max_pipeline = max_pipeline
        self.tls = tls
        self._server: asyncio.Server | TlsServer | None = None
        self._connections: dict[_Connection, None] = {}

    @property
    def port(self) -> int:
        """The bound port (the real one when constructed with port 0)."""
        return self._port

    @property
    def connection_count(self) -> int:
        return len(self._connections)

    def open_count(self) -> int:
        """Connections that count against ``max_connections``: accepted and not closing."""
        return sum(1 for c in self._connections if not (c.eof or c.stopping))

    def make_room(self, newcomer: _Connection) -> bool:
        """Close the connection idle longest (nothing in flight; one that never sent a
        complete request first) for ``newcomer``; False when every one is busy."""
        idle = [c for c in self._connections
                if not (c.eof or c.stopping or c.working or c.pending)]
        if not idle:
            return False
        victim = min(idle, key=lambda c: (c.requested, c.last_active))
        self.counters.evicted += 1
        log.warning("Modbus TCP client %s closed to make room for %s (max_connections %d): "
                    "idle longest, %.1f s%s", victim.peer, newcomer.peer, self.max_connections,
                    victim.loop.time() - victim.last_active,
                    "" if victim.requested else ", no request yet")
        victim._end_input()
        return True

    async def start(self) -> None:
        """Bind and listen; raises OSError if the address cannot be bound."""
        loop = asyncio.get_running_loop()
        if self.tls is not None:
            self._server = await self.tls.serve(lambda: _Connection(self), self.host,
                                                self._port, lambda h: _allowed(h, self.allow))
        else:
            self._server = await loop.create_server(lambda: _Connection(self), self.host,
                                                    self._port)
        self._port = self._server.sockets[0].getsockname()[1]
        log.info("Modbus %s server listening on %s:%d", "TCP" if self.tls is None
                 else "TCP Security (TLS)", self.host, self._port)

    async def __aenter__(self) -> TcpServer:
        await self.start()
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.close()

    async def close(self, timeout_s: float = 5.0) -> None:
        """Stop accepting, let each connection finish its request in flight, close all."""
        server, self._server = self._server, None
        if server is not None:
            server.close()
        conns = list(self._connections)
        for conn in conns:
            conn.stop()  # no more reading (before any EOF), nothing new is started
        if conns:
            _, pending = await asyncio.wait([c.done for c in conns], timeout=timeout_s)
            if pending:
                for conn in conns:
                    if not conn.done.done():
                        if conn.task is not None:
                            conn.task.cancel()
                        if conn.transport is not None:
                            conn.transport.abort()
                await asyncio.wait(pending, timeout=1.0)
        if server is not None:
            with contextlib.suppress(Exception):
                await asyncio.wait_for(server.wait_closed(), 1.0)


class RtuServer(Listener):
    """Modbus RTU server on a serial port, answering for ``unit_ids`` only.

    Requests for other units are dropped silently (a shared line); unit 0 (broadcast) is
    handled without a reply. Frames are cut by length and CRC, unknown function codes by
    line silence; garbage and fragments are skipped. The port is reopened with backoff if it
    disappears. A reply leaves after t3.5 of line silence (``silence_s``, else per ``t35``
    as :class:`gateway.modbus.downstream.RtuBus`), timed exactly.
    """

    def __init__(self, handler: Handler, port: str, *, unit_ids: Collection[int],
                 baudrate: int = 19200, bytesize: int = 8, parity: str = "E",
                 stopbits: float = 1, silence_s: float | None = None,
                 broadcast: bool = True, reopen_max_s: float = 5.0, t35: T35Mode = "spec",
                 serial_kwargs: dict[str, object] | None = None) -> None:
        super().__init__(handler)
        self.unit_ids = frozenset(unit_ids)
        self.broadcast = broadcast
        self.reopen_max_s = reopen_max_s
        self.line = SerialLine(port, baudrate=baudrate, bytesize=bytesize, parity=parity,
                               stopbits=stopbits, silence_s=silence_s, t35=t35,
                               **(serial_kwargs or {}))
        self._task: asyncio.Task[None] | None = None
        self._stopping = False
        self._busy = False
        self._opened = asyncio.Event()

    async def start(self) -> None:
        """Open the port (raises SerialLineLost if it cannot be opened) and serve."""
        self.line.open()
        self._task = asyncio.create_task(self._run(), name=f"compgw-rtu-{self.line.port}")
        log.info("Modbus RTU server on %s for units %s", self.line.port, sorted(self.unit_ids))

    async def __aenter__(self) -> RtuServer:
        await self.start()
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.close()

    async def _run(self) -> None:
        backoff_s = 0.1
        while not self._stopping:
            if not self.line.is_open:
                try:
                    self.line.open()
                    backoff_s = 0.1
                    log.info("serial %s reopened", self.line.port)
                except SerialLineLost as err:
                    log.debug("serial %s: %s", self.line.port, err)
                    await asyncio.sleep(backoff_s)
                    backoff_s = min(backoff_s * 2, self.reopen_max_s)
                    continue
            try:
                await self._serve()
            except SerialLineLost as err:
                log.warning("serial %s lost: %s", self.line.port, err)

    async def _serve(self) -> None:
        while not self._stopping:
            frame = await self.line.read_frame(rtu_request_length)
            if frame is None:
                continue
            unit, pdu = frame[0], frame[1:-2]
            if unit == 0 and self.broadcast:
                self._busy = True
                try:
                    await self._call(0, pdu)
                finally:
                    self._busy = False
                continue
            if unit not in self.unit_ids:
                continue
            self._busy = True
            try:
                reply = await self._call(unit, pdu)
                if reply is not None:
                    if self.line.quiet_for_s() < self.line.silence_s:
                        await self.line.wait_quiet(self.line.silence_s, 0.1, discard=False)
                    await self.line.write(rtu_encode(unit, reply))
            finally:
                self._busy = False

    async def close(self, timeout_s: float = 5.0) -> None:
        """Finish the request in flight, then close the port."""
        self._stopping = True
        task, self._task = self._task, None
        if task is not None:
            if not self._busy:
                task.cancel()
            done, _ = await asyncio.wait([task], timeout=timeout_s)
            if not done:
                task.cancel()
                await asyncio.wait([task], timeout=1.0)
        self.line.close()
