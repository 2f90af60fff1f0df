"""RTU over TCP: an RS-485 line behind a serial device server in transparent mode.

The server passes bytes between a TCP connection and its serial port as they come: plain
RTU frames with their CRC, no MBAP header, no transaction id. So the bus is an RTU line in
every respect but the cable: one transaction at a time, replies checked (unit, function,
byte count, echoed address and quantity), the line's t3.5 kept before each request, the
late-reply guard after a timeout (:class:`gateway.modbus.downstream.RtuBus`, whose hooks this
transport reuses) and frames cut by length and CRC from the byte stream
(:class:`gateway.modbus.serialline.RtuStream`, whose reading and timing it reuses). Only opening
differs: a TCP connect, re-tried with the bus's backoff after a refusal or a loss.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import socket

from .downstream import RtuBus
from .serialline import RtuStream, T35Mode

log = logging.getLogger(__name__)


class TcpRtuLine(RtuStream):
    """The TCP connection to a serial device server, read as an RTU byte stream. The line
    settings are those of the server's RS-485 side (they time t3.5 and wire time)."""

    kind = "rtu over tcp"

    def __init__(self, host: str, port: int, *, baudrate: int = 19200, bytesize: int = 8,
                 parity: str = "E", stopbits: float = 1, silence_s: float | None = None,
                 stale_s: float = 0.1, t35: T35Mode = "spec") -> None:
        super().__init__(f"{host}:{port}", baudrate=baudrate, bytesize=bytesize,
                         parity=parity, stopbits=stopbits, silence_s=silence_s,
                         stale_s=stale_s, t35=t35)
        self.host = host
        self.tcp_port = port
        self._sock: socket.socket | None = None

    async def connect(self, timeout_s: float) -> None:
        """Connect (closing an earlier connection first); OSError or TimeoutError if the
        server cannot be reached."""
        self.close()
        loop = asyncio.get_running_loop()
        infos = await loop.getaddrinfo(self.host, self.tcp_port, type=socket.SOCK_STREAM)
        family, kind, proto, _, address = infos[0]
        sock = socket.socket(family, kind, proto)
        try:
            sock.setblocking(False)
            await asyncio.wait_for(loop.sock_connect(sock, address), timeout_s)
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_KEEPALIVE, 1)
        except BaseException:
            sock.close()
            raise
        self._sock = sock
        self._attach(sock.fileno())

    def _release(self) -> None:
        if self._sock is not None:
            with contextlib.suppress(OSError):
                self._sock.close()
        self._sock = None

    def _empty_read(self) -> None:
        log.warning("%s %s lost: closed by the server", self.kind, self.port)
        self.close()


class RtuOverTcpBus(RtuBus):
    """A drive bus on an RS-485 line behind a serial device server (transparent mode).

    Everything an :class:`RtuBus` does (t3.5 and ``min_silence_s`` before each request,
    the late-reply guard, unit 0 as a broadcast with ``turnaround_s``), over a TCP
    connection that is opened on first use and reopened with exponential backoff
    (``reconnect_min_s``..``reconnect_max_s``) after a refusal or a loss.
    """

    def __init__(self, host: str, port: int = 502, *, baudrate: int = 19200,
                 bytesize: int = 8, parity: str = "E", stopbits: float = 1,
                 silence_s: float | None = None, late_guard_s: float | None = None,
                 t35: T35Mode = "spec", connect_timeout_s: float | None = None,
                 **bus_kwargs: object) -> None:
        bus_kwargs.setdefault("name", f"{host}:{port}")
        super(RtuBus, self).__init__(**bus_kwargs)  # type: ignore[arg-type]  (Bus's)
        self.connect_timeout_s = connect_timeout_s or max(self.timeout_s, 1.0)
        self._use_line(TcpRtuLine(host, port, baudrate=baudrate, bytesize=bytesize,
                                  parity=parity, stopbits=stopbits, silence_s=silence_s,
                                  t35=t35), late_guard_s)

    async def _open(self) -> None:
        line = self.line
        assert isinstance(line, TcpRtuLine)
        await line.connect(self.connect_timeout_s)
        self._opened()
