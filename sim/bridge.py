"""The sim's laser on the instrument bridge line protocol, version 1 (docs/instruments-bridge.md).

Why: a technician's laser is often reached through a bridge (a script around the vendor's
SDK), not Modbus; compgw's bridge client is tested against this server, which reads the
same truth as the Modbus laser (:meth:`sim.instruments.Laser.reading`: noise, resolution,
the stable band, and ``sample_s`` of machine time per reading at time_scale 0, so a master
asking until ``STABLE`` lets the axis settle).

Lines (UTF-8, ``\\n``; ``\\r\\n`` accepted), one answer per request:

* ``HELLO 1`` → ``OK sim-laser channels=X,Y unit=um`` (the laser's channels);
* ``READ CH [CH ...]`` → ``OK V [V ...] um STABLE|MOVING`` (one reading for all channels
  asked, in µm to 1 nm; ``STABLE`` when every channel asked is stable);
* ``BYE`` → ``OK``, then the connection closes;
* anything else, an unknown channel, a bad version → ``ERR text``.

Faults (``instruments.laser.bridge``), counted over the server's life: ``hang_after: N``:
from request N+1 on, nothing is answered (the connection stays open); ``garbage_after: N``:
from request N+1 on, every answer is ``OK banana``.
"""

from __future__ import annotations

import asyncio
import contextlib

from sim.config import LaserBridgeConfig
from sim.instruments import Laser

NAME = "sim-laser"
PROTOCOL_VERSION = "1"
MAX_LINE_BYTES = 4096
_SHOWN_CHARS = 40


def _shown(text: str) -> str:
    """A piece of a request fit to quote in a one-line answer (printable, short)."""
    clean = "".join(ch if ch.isprintable() else "?" for ch in text)
    return clean if len(clean) <= _SHOWN_CHARS else clean[: _SHOWN_CHARS - 3] + "..."


class LaserBridge:
    """An asyncio TCP server answering the bridge protocol from a :class:`Laser`."""

    def __init__(self, cfg: LaserBridgeConfig, laser: Laser) -> None:
        self.cfg = cfg
        self.laser = laser
        self.port: int | None = None
        self.requests = 0  # requests received over the server's life (the faults count them)
        self._server: asyncio.Server | None = None
        self._tasks: set[asyncio.Task] = set()

    async def start(self, port: int | None = None) -> int:
        """Listen (``port`` overrides the config's; 0: a free one); return the bound port."""
        self._server = await asyncio.start_server(
            self._serve, self.cfg.host, self.cfg.port if port is None else port,
            limit=MAX_LINE_BYTES)  # fmt: skip
        self.port = self._server.sockets[0].getsockname()[1]
        return self.port

    async def stop(self) -> None:
        """Stop listening and drop every connection."""
        if self._server is None:
            return
        self._server.close()
        for task in list(self._tasks):
            task.cancel()
        await asyncio.gather(*self._tasks, return_exceptions=True)
        await self._server.wait_closed()
        self._server = None

    # ------------------------------------------------------------ lines
    def answer(self, raw: bytes) -> tuple[str, bool]:
        """The answer to one request line (without its newline), and whether to close."""
        try:
            line = raw.decode("utf-8").rstrip("\r\n")
        except UnicodeDecodeError:
            return "ERR request is not UTF-8", False
        if not line.strip():
            return "ERR empty request", False
        fields = line.split(" ")
        command, args = fields[0], fields[1:]
        if "" in fields:
            return "ERR fields must be separated by single spaces", False
        if command == "HELLO":
            if args != [PROTOCOL_VERSION]:
                got = " ".join(args) or "none"
                return f"ERR protocol version {_shown(got)} not supported (1)", False
            return f"OK {NAME} channels={','.join(self.laser.axes)} unit=um", False
        if command == "READ":
            return self._read(args), False
        if command == "BYE":
            return ("OK", True) if not args else ("ERR BYE takes no arguments", False)
        return f"ERR unknown request {_shown(command)} (HELLO, READ, BYE)", False

    def _read(self, channels: list[str]) -> str:
        if not channels:
            return "ERR READ needs at least one channel"
        unknown = [ch for ch in channels if ch not in self.laser.axes]
        if unknown:
            return (f"ERR unknown channel {_shown(unknown[0])} "
                    f"(channels {','.join(self.laser.axes)})")  # fmt: skip
        nm, stable = self.laser.reading(channels)
        values = " ".join(f"{v / 1000:.3f}" for v in nm)
        return f"OK {values} um {'STABLE' if all(stable) else 'MOVING'}"

    # ------------------------------------------------------------ connections
    async def _serve(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        """One connection: a line in, a line out, in order; faults as configured."""
        task = asyncio.current_task()
        if task is not None:
            self._tasks.add(task)
        try:
            while True:
                try:
                    raw = await reader.readuntil(b"\n")
                except asyncio.IncompleteReadError as err:
                    if not err.partial:
                        return
                    raw = err.partial  # the last line without its newline, then EOF
                except asyncio.LimitOverrunError:
                    writer.write(f"ERR request longer than {MAX_LINE_BYTES} bytes\n".encode())
                    await writer.drain()
                    return
                self.requests += 1
                hang, garbage = self.cfg.hang_after, self.cfg.garbage_after
                if hang is not None and self.requests > hang:
                    continue  # a hung bridge: reads on, answers nothing
                if garbage is not None and self.requests > garbage:
                    text, close = "OK banana", False
                else:
                    text, close = self.answer(raw)
                writer.write(f"{text}\n".encode())
                await writer.drain()
                if close or reader.at_eof():
                    return
        except (ConnectionError, asyncio.CancelledError):
            pass
        finally:
            if task is not None:
                self._tasks.discard(task)
            writer.close()
            with contextlib.suppress(Exception):
                await writer.wait_closed()
