"""Modbus servers for the upper computer: TCP (MBAP) and RTU (serial), frame level.

Both hand every request PDU to one handler, ``async (unit_id, pdu) -> bytes | None``
(None: no reply), and send back what it returns, byte for byte. A handler raising
:class:`gateway.frames.ModbusError` (``DriveTimeout``, ``BusUnavailable``, or one raised
by the interception layer) is answered with that exception code; any other error with
0x04 and a log line, so the master is never left hanging.

Pipelining (TCP): a master may send several requests without waiting, even in one
segment. Each connection has a reader that cuts frames as they arrive and a worker that
runs them one after the other and writes each reply with its own transaction id. Requests
of one connection are processed in order, not concurrently: a master that pipelines
"write target, write trigger" must have the trigger reach the drive after the target, and
requests to one RS-485 bus are serialised anyway. Connections run concurrently.
"""

from __future__ import annotations

import asyncio
import contextlib
import ipaddress
import itertools
import logging
import socket
from collections.abc import Awaitable, Callable, Collection, Iterable
from dataclasses import dataclass

from pymodbus.framer import FramerSocket
from pymodbus.pdu import DecodePDU

from .downstream import current_caller
from .frames import (
    MAX_PDU_BYTES,
    SERVER_DEVICE_FAILURE,
    ModbusError,
    exception_pdu,
    rtu_encode,
    rtu_request_length,
)
from .serialline import SerialLine, SerialLineLost

log = logging.getLogger(__name__)

Handler = Callable[[int, bytes], Awaitable[bytes | None]]
Network = ipaddress.IPv4Network | ipaddress.IPv6Network

_conn_ids = itertools.count(1)


@dataclass
class ServerCounters:
    """Monotonic counters for metrics."""

    connections: int = 0  # accepted
    refused: int = 0  # closed at accept: not allowed, or too many
    requests: int = 0
    replies: int = 0
    handler_errors: int = 0  # handler raised something other than ModbusError
    malformed: int = 0  # frames that closed a connection or were skipped


class Listener:
    """What both servers share: the handler call and its error mapping."""

    def __init__(self, handler: Handler) -> None:
        self.handler = handler
        self.counters = ServerCounters()

    async def _call(self, unit_id: int, pdu: bytes) -> bytes | None:
        """Run the handler; map its errors to exception PDUs; check what it returns."""
        self.counters.requests += 1
        try:
            reply = await self.handler(unit_id, pdu)
        except ModbusError as err:
            log.debug("unit %d FC%02d: exception 0x%02X: %s", unit_id, pdu[0], err.code, err)
            reply = exception_pdu(pdu[0], err.code)
        except Exception:
            self.counters.handler_errors += 1
            log.exception("handler failed on unit %d PDU %s", unit_id, pdu.hex())
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


class _Connection:
    """One master's TCP connection: a reader cutting MBAP frames, a worker answering.

    The reader reads ahead at most ``max_pipeline`` requests (then stops reading: TCP
    backpressure); the worker answers them strictly in order.
    """

    def __init__(self, server: TcpServer, reader: asyncio.StreamReader,
                 writer: asyncio.StreamWriter, peer: str) -> None:
        self.server = server
        self.reader = reader
        self.writer = writer
        self.peer = peer
        self.id = next(_conn_ids)
        self.queue: asyncio.Queue[tuple[int, int, bytes] | None] = asyncio.Queue()
        self.room = asyncio.Semaphore(server.max_pipeline)
        self.busy = False
        self.stopping = False  # graceful close: finish the request in flight, no more

    async def run(self) -> None:
        worker = asyncio.create_task(self._work(), name=f"compgw-up-work-{self.id}")
        reader = asyncio.create_task(self._read(), name=f"compgw-up-read-{self.id}")
        try:
            done, _ = await asyncio.wait({reader, worker}, return_when=asyncio.FIRST_COMPLETED)
            if reader in done:
                # End of input (EOF, idle, malformed, close): answer what was received,
                # unless the server is stopping.
                if self.stopping:
                    self._drop_queued()
                self.queue.put_nowait(None)
                await worker
            else:  # the worker stopped (peer gone, or server stopping)
                reader.cancel()
                with contextlib.suppress(asyncio.CancelledError):
                    await reader
        finally:
            for task in (reader, worker):
                task.cancel()
            await asyncio.gather(reader, worker, return_exceptions=True)
            self.writer.close()
            with contextlib.suppress(Exception):
                await asyncio.wait_for(self.writer.wait_closed(), 1.0)

    def _drop_queued(self) -> None:
        while not self.queue.empty():
            self.queue.get_nowait()

    async def _read(self) -> None:
        buf = bytearray()
        framer = self.server.framer
        idle_s = self.server.idle_timeout_s
        while not self.stopping:
            try:
                data = await asyncio.wait_for(self.reader.read(4096), idle_s)
            except asyncio.TimeoutError:
                if self.busy or not self.queue.empty():
                    continue
                log.info("%s: idle for %.0f s: closing", self.peer, idle_s)
                return
            except (ConnectionError, OSError) as err:
                log.debug("%s: %s", self.peer, err)
                return
            if not data:
                return
            buf += data
            while len(buf) >= 8 and not self.stopping:
                length = int.from_bytes(buf[4:6], "big")
                if buf[2:4] != b"\x00\x00" or not 2 <= length <= MAX_PDU_BYTES + 1:
                    self.server.counters.malformed += 1
                    log.warning("%s: bad MBAP header %s: closing", self.peer, bytes(buf[:8]).hex())
                    return
                size = 6 + length
                if len(buf) < size:
                    break
                # Exactly one frame is given to the framer (see FramerSocket.decode quirks).
                _, unit, tid, pdu = framer.decode(bytes(buf[:size]))
                del buf[:size]
                await self.room.acquire()  # backpressure: stop reading when too far ahead
                self.queue.put_nowait((tid, unit, pdu))

    async def _work(self) -> None:
        current_caller.set(("tcp", self.id))
        framer = self.server.framer
        while True:
            item = await self.queue.get()
            if item is None:
                return
            tid, unit, pdu = item
            self.busy = True
            try:
                reply = await self.server._call(unit, pdu)
                if reply is not None:
                    self.writer.write(framer.encode(reply, unit, tid))
                    await self.writer.drain()
            except (ConnectionError, OSError) as err:
                log.debug("%s: %s", self.peer, err)
                return
            finally:
                self.busy = False
                self.room.release()
            if self.stopping:
                return


class TcpServer(Listener):
    """Modbus TCP server: MBAP framing, pipelining, allowlist, connection limits.

    ``allow``: client networks accepted (None: all); others are closed at accept and
    logged. ``max_connections``: further connections are closed at accept.
    ``idle_timeout_s``: a connection with no request for that long is closed (None: never).
    ``max_pipeline``: requests read ahead per connection before reading pauses.
    """

    def __init__(self, handler: Handler, host: str = "127.0.0.1", port: int = 502, *,
                 allow: Iterable[str | Network] | None = None, max_connections: int = 16,
                 idle_timeout_s: float | None = None, max_pipeline: int = 16) -> None:
        super().__init__(handler)
        self.host = host
        self._port = port
        self.allow = parse_networks(allow)
        self.max_connections = max_connections
        self.idle_timeout_s = idle_timeout_s
        self.max_pipeline = max_pipeline
        self.framer = FramerSocket(DecodePDU(is_server=True))
        self._server: asyncio.Server | None = None
        self._connections: dict[_Connection, asyncio.Task[None]] = {}

    @property
    def port(self) -> int:
        """The bound port (the real one when constructed with port 0)."""
        return self._port

    @property
    def connection_count(self) -> int:
        return len(self._connections)

    async def start(self) -> None:
        """Bind and listen; raises OSError if the address cannot be bound."""
        self._server = await asyncio.start_server(self._accept, self.host, self._port)
        self._port = self._server.sockets[0].getsockname()[1]
        log.info("Modbus TCP server listening on %s:%d", self.host, self._port)

    async def __aenter__(self) -> TcpServer:
        await self.start()
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.close()

    async def _accept(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        peername = writer.get_extra_info("peername") or ("?", 0)
        peer = f"{peername[0]}:{peername[1]}"
        reason = None
        if not _allowed(str(peername[0]), self.allow):
            reason = "not in the allowlist"
        elif len(self._connections) >= self.max_connections:
            reason = f"more than {self.max_connections} connections"
        elif self._server is None:
            reason = "server closing"
        if reason:
            self.counters.refused += 1
            log.warning("refused Modbus TCP client %s: %s", peer, reason)
            writer.close()
            return
        sock = writer.get_extra_info("socket")
        if sock is not None:
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self.counters.connections += 1
        conn = _Connection(self, reader, writer, peer)
        task = asyncio.current_task()
        assert task is not None
        self._connections[conn] = task
        log.debug("client %s connected", peer)
        try:
            await conn.run()
        finally:
            self._connections.pop(conn, None)
            log.debug("client %s disconnected", peer)

    async def close(self, timeout_s: float = 5.0) -> None:
        """Stop accepting, let each connection finish its request in flight, close all."""
        server, self._server = self._server, None
        if server is not None:
            server.close()
        for conn in list(self._connections):
            conn.stopping = True
            # no more data_received (it would assert "feed_data after feed_eof" and kill
            # the transport before the reply in flight is written)
            with contextlib.suppress(Exception):
                conn.writer.transport.pause_reading()
            conn.reader.feed_eof()
        tasks = list(self._connections.values())
        if tasks:
            _, pending = await asyncio.wait(tasks, timeout=timeout_s)
            for task in pending:
                task.cancel()
            if pending:
                await asyncio.wait(pending, timeout=1.0)
        if server is not None:
            with contextlib.suppress(Exception):
                await asyncio.wait_for(server.wait_closed(), 1.0)


class RtuServer(Listener):
    """Modbus RTU server on a serial port, answering for ``unit_ids`` only.

    Requests for other units are dropped silently (a shared line); unit 0 (broadcast) is
    handled without a reply. Frames are cut by length and CRC, unknown function codes by
    line silence; garbage and fragments are skipped. The port is reopened with backoff if it
    disappears.
    """

    def __init__(self, handler: Handler, port: str, *, unit_ids: Collection[int],
                 baudrate: int = 19200, bytesize: int = 8, parity: str = "E",
                 stopbits: float = 1, silence_s: float | None = None,
                 broadcast: bool = True, reopen_max_s: float = 5.0,
                 serial_kwargs: dict[str, object] | None = None) -> None:
        super().__init__(handler)
        self.unit_ids = frozenset(unit_ids)
        self.broadcast = broadcast
        self.reopen_max_s = reopen_max_s
        self.line = SerialLine(port, baudrate=baudrate, bytesize=bytesize, parity=parity,
                               stopbits=stopbits, silence_s=silence_s, **(serial_kwargs or {}))
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
                    gap = self.line.silence_s - self.line.quiet_for_s()
                    if gap > 0:
                        await asyncio.sleep(gap)
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
