"""A bridge: the line protocol of ``docs/instruments-bridge.md`` over TCP or a child process.

A vendor's SDK is wrapped in a short script (``examples/bridge_template.py``) that answers
``READ CH`` with ``OK VALUE UNIT STABLE|MOVING``; this kind asks it. Every answer is
checked field by field: a line that does not read as the protocol says, silence past the
timeout, an ``ERR`` or a bridge that exits is an error naming the bridge, the request and
what came back.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import math
import os
import signal
from collections.abc import Mapping, Sequence

from .base import UNITS, Instrument, InstrumentError, Sample, TransientError

log = logging.getLogger(__name__)

PROTOCOL_VERSION = 1
#: how long one answer may take (s); MOVING answers are answers
DEFAULT_TIMEOUT_S = 5.0


def parse_read_answer(line: str, channels: Sequence[str]) -> Sample:
    """``OK V [V ...] UNIT STABLE|MOVING`` for ``channels``; InstrumentError saying what is
    wrong with it otherwise (``ERR TEXT`` as the bridge's own words)."""
    words = line.split()
    if words[:1] == ["ERR"]:
        raise InstrumentError(f"READ {' '.join(channels)}: the bridge says: "
                              f"{line[3:].strip() or '(no reason given)'}")
    expected = len(channels) + 3
    if words[:1] != ["OK"] or len(words) != expected:
        raise InstrumentError(f"READ {' '.join(channels)}: answer {line!r} is not 'OK "
                              f"{' '.join('V' for _ in channels)} UNIT STABLE|MOVING'")
    *texts, unit, state = words[1:]
    values = []
    for text in texts:
        try:
            value = float(text)
        except ValueError:
            value = math.nan
        if not math.isfinite(value):
            raise InstrumentError(f"READ {' '.join(channels)}: {text!r} in {line!r} is not a "
                                  "number")
        values.append(value)
    if unit not in UNITS:
        raise InstrumentError(f"READ {' '.join(channels)}: unit {unit!r} in {line!r} is not "
                              f"one of {', '.join(UNITS)}")
    if state not in ("STABLE", "MOVING"):
        raise InstrumentError(f"READ {' '.join(channels)}: {state!r} in {line!r} is not "
                              "STABLE or MOVING")
    return Sample(tuple(values), unit, state == "STABLE")


class Bridge(Instrument):
    """The bridge kind; the transport (TCP or a child process) is a subclass's."""

    kind = "bridge"

    def __init__(self, role: str, where: str, channels: Mapping[str, str] | None = None,
                 *, timeout_s: float = DEFAULT_TIMEOUT_S, **kw) -> None:  # type: ignore[no-untyped-def]
        super().__init__(role, where, channels, **kw)
        self.timeout_s = timeout_s
        self.hello = ""
        self._reader: asyncio.StreamReader | None = None
        self._writer: asyncio.StreamWriter | None = None

    async def _ask(self, request: str) -> str:
        """Send one line, return the answer line (stripped)."""
        if self._reader is None or self._writer is None:
            raise TransientError(f"{request}: not connected")
        try:
            self._writer.write(request.encode() + b"\n")
            await self._writer.drain()
            raw = await asyncio.wait_for(self._reader.readline(), self.timeout_s)
        except asyncio.TimeoutError:
            await self._close()  # a late answer would be taken for the next request's
            raise InstrumentError(f"{request}: no answer within {self.timeout_s:g} s (the "
                                  "bridge hangs: stopped)") from None
        except (ConnectionError, OSError) as exc:
            raise TransientError(f"{request}: {exc}") from None
        if not raw:
            raise TransientError(f"{request}: {await self._gone()}")
        try:
            return raw.decode("utf-8").strip()
        except UnicodeDecodeError:
            raise InstrumentError(f"{request}: answer {raw[:40]!r} is not UTF-8 text") from None

    async def _gone(self) -> str:
        return "the bridge closed the connection"

    async def _greet(self) -> None:
        """HELLO once connected; a bridge that does not answer it is closed again."""
        try:
            answer = await self._ask(f"HELLO {PROTOCOL_VERSION}")
            if answer.split()[:1] != ["OK"] or len(answer.split()) < 2:
                raise InstrumentError(f"HELLO {PROTOCOL_VERSION}: answer {answer!r} is not "
                                      "'OK NAME ...': is this a compgw bridge?")
        except InstrumentError as exc:
            await self._close()
            raise InstrumentError(f"{self.name}: {exc}") from None
        self.hello = answer[3:]

    async def _sample(self, channels: list[str], axes: Sequence[str],
                      near_mm: Mapping[str, float]) -> Sample:
        request = "READ " + " ".join(channels)
        return parse_read_answer(await self._ask(request), channels)


class TcpBridge(Bridge):
    """A bridge listening on TCP (``bridge:tcp:HOST:PORT``)."""

    def __init__(self, role: str, host: str, port: int, channels: Mapping[str, str] | None
                 = None, **kw) -> None:  # type: ignore[no-untyped-def]  # fmt: skip
        super().__init__(role, f"tcp {host}:{port}", channels, **kw)
        self.host, self.port = host, port

    async def _open(self) -> None:
        try:
            self._reader, self._writer = await asyncio.wait_for(
                asyncio.open_connection(self.host, self.port), self.timeout_s)
        except (OSError, asyncio.TimeoutError) as exc:
            raise InstrumentError(f"{self.name}: cannot connect: {exc or 'timeout'}") from None
        await self._greet()

    async def _close(self) -> None:
        writer, self._reader, self._writer = self._writer, None, None
        if writer is not None:
            await self._say_bye_to(writer)
            writer.close()
            with contextlib.suppress(Exception):
                await writer.wait_closed()

    async def _say_bye_to(self, writer: asyncio.StreamWriter) -> None:
        with contextlib.suppress(Exception):
            writer.write(b"BYE\n")
            await asyncio.wait_for(writer.drain(), 1.0)


class CommandBridge(Bridge):
    """A bridge run as a child process (``bridge:cmd:COMMAND``): requests on its standard
    input, answers on its standard output, its standard error into compgw's log."""

    def __init__(self, role: str, command: str, channels: Mapping[str, str] | None = None,
                 **kw) -> None:  # type: ignore[no-untyped-def]
        super().__init__(role, f"cmd {command!r}", channels, **kw)
        self.command = command
        self._proc: asyncio.subprocess.Process | None = None
        self._stderr_tail: list[str] = []
        self._stderr_task: asyncio.Task[None] | None = None

    async def _open(self) -> None:
        try:
            self._proc = await asyncio.create_subprocess_shell(
                self.command, stdin=asyncio.subprocess.PIPE, stdout=asyncio.subprocess.PIPE,
                stderr=asyncio.subprocess.PIPE, start_new_session=True)  # its own group
        except OSError as exc:
            raise InstrumentError(f"{self.name}: cannot start: {exc}") from None
        assert self._proc.stdout is not None and self._proc.stdin is not None
        self._reader = self._proc.stdout
        self._writer = self._proc.stdin  # type: ignore[assignment]
        self._stderr_task = asyncio.create_task(self._drain_stderr())
        await self._greet()

    async def _drain_stderr(self) -> None:
        assert self._proc is not None and self._proc.stderr is not None
        while line := await self._proc.stderr.readline():
            text = line.decode("utf-8", "replace").rstrip()
            self._stderr_tail = [*self._stderr_tail[-4:], text]
            log.info("%s: %s", self.name, text)

    async def _gone(self) -> str:
        code = None
        if self._proc is not None:
            with contextlib.suppress(asyncio.TimeoutError):
                code = await asyncio.wait_for(self._proc.wait(), 2.0)
            if self._stderr_task is not None:  # its last words, read to the end
                with contextlib.suppress(asyncio.TimeoutError, asyncio.CancelledError):
                    await asyncio.wait_for(asyncio.shield(self._stderr_task), 1.0)
        tail = f"; its last words: {self._stderr_tail[-1]!r}" if self._stderr_tail else ""
        return f"the bridge exited (code {code}){tail}"

    async def _close(self) -> None:
        proc, self._proc = self._proc, None
        self._reader = self._writer = None
        if proc is None:
            return
        if proc.returncode is None and proc.stdin is not None:
            with contextlib.suppress(Exception):
                proc.stdin.write(b"BYE\n")
                await asyncio.wait_for(proc.stdin.drain(), 1.0)
                proc.stdin.close()
        try:
            await asyncio.wait_for(proc.wait(), 2.0)
        except asyncio.TimeoutError:  # a bridge that hangs is stopped, with what it started
            with contextlib.suppress(ProcessLookupError, PermissionError):
                os.killpg(proc.pid, signal.SIGKILL)
            await proc.wait()
        if self._stderr_task is not None:
            self._stderr_task.cancel()
            with contextlib.suppress(asyncio.CancelledError, Exception):
                await self._stderr_task
