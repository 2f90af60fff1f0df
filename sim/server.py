"""The simulator's Modbus server (TCP, RTU serial and/or RTU over TCP) and ``compgw sim``.

Frame-level on purpose, using pymodbus's framers (``FramerSocket``, ``FramerRTU``) only to
split and build frames: the faults need the unit id of every request and control over
whether, when and how a reply leaves (silence, delay, garbage bytes), and each request must
reach its unit exactly once with its own transaction id. pymodbus's SimDevice action hook
gets no unit id, runs twice for FC06 and answers pipelined TCP requests with the wrong
transaction id (see PYMODBUS.md), so the sim answers frames itself.

In-process use (tests, demo)::

    cfg = load_config("config/example-sim.yaml")
    async with SimServer(cfg, tcp_port=0) as server:
        port = server.tcp_port              # the bound port
        server.sim.machine ...              # the truth, for assertions
        server.laser_bridge_port            # with instruments.laser.bridge (sim/bridge.py)
        server.sim.recorder                 # with instruments.laser.recording (sim/recorder.py)

Unknown unit ids: no reply on RTU (another device's address on a shared line); exception
0x0B (gateway target failed to respond) on TCP, as a TCP-to-RS-485 gateway answers.

RTU over TCP (``rtu_over_tcp``): RTU frames with CRC inside TCP, no MBAP header, as a
serial device server in transparent mode passes them; each connection is served as an RTU
line of its own (unknown units unanswered, broadcasts acted on, replies in order).
"""

from __future__ import annotations

import asyncio
import contextlib
import os
import signal
import sys
import time
import tty
from collections.abc import Callable, Coroutine
from pathlib import Path
from typing import Any

import serial
from pymodbus.framer import FramerRTU, FramerSocket
from pymodbus.pdu import DecodePDU

from sim.bridge import LaserBridge
from sim.config import PTY_PORT, RtuConfig, SimConfig, SimConfigError, TcpConfig, load_config
from sim.instruments import Laser
from sim.pdu import GATEWAY_NO_RESPONSE, exception_pdu
from sim.simulation import Reply, Simulation

EXIT_OK, EXIT_BAD_CONFIG, EXIT_RUNTIME = 0, 1, 3
RTU_GAP_S = 0.05  # an incomplete RTU frame older than this is dropped (line silence)
_PARITY = {"N": serial.PARITY_NONE, "E": serial.PARITY_EVEN, "O": serial.PARITY_ODD}


class SimServer:
    """The simulation served over Modbus TCP and/or RTU; an async context manager.

    Keyword overrides replace the config's values (``tcp_port=0`` binds a free port,
    ``rtu_port`` names a serial device, e.g. a pty); ``tcp_port`` given without a ``tcp``
    section listens on 127.0.0.1.
    """

    def __init__(
        self,
        config: SimConfig,
        *,
        tcp_port: int | None = None,
        rtu_port: str | None = None,
        rtu_over_tcp_port: int | None = None,
        time_scale: float | None = None,
        seed: int | None = None,
        wall_s: Callable[[], float] = time.monotonic,
    ) -> None:
        section = config.sim
        updates: dict[str, object] = {}
        if tcp_port is not None:
            updates["tcp"] = (section.tcp or TcpConfig()).model_copy(update={"port": tcp_port})
        if rtu_port is not None:
            updates["rtu"] = (section.rtu or RtuConfig(port=rtu_port)).model_copy(
                update={"port": rtu_port}
            )
        if rtu_over_tcp_port is not None:
            updates["rtu_over_tcp"] = (section.rtu_over_tcp or TcpConfig()).model_copy(
                update={"port": rtu_over_tcp_port})
        if time_scale is not None:
            updates["time_scale"] = time_scale
        if seed is not None:
            updates["seed"] = seed
        self.config = config.model_copy(update={"sim": section.model_copy(update=updates)})
        self.sim = Simulation(self.config, wall_s)
        self.tcp_port: int | None = None
        self.rtu_port: str | None = None
        self.rtu_over_tcp_port: int | None = None
        #: the laser on the bridge line protocol (``instruments.laser.bridge``), bound port
        self.laser_bridge_port: int | None = None
        self.laser_bridge: LaserBridge | None = None
        self._tcp_server: asyncio.Server | None = None
        self._rot_server: asyncio.Server | None = None
        self._rot_lines: set[_RtuOverTcpLine] = set()
        self._rtu: _RtuLine | None = None
        self._tasks: set[asyncio.Task] = set()

    async def start(self) -> None:
        """Open the configured listeners; raises OSError/SerialException if one fails."""
        cfg = self.config.sim
        try:
            if cfg.tcp is not None:
                self._tcp_server = await asyncio.start_server(
                    self._serve_tcp_client, cfg.tcp.host, cfg.tcp.port
                )
                self.tcp_port = self._tcp_server.sockets[0].getsockname()[1]
            if cfg.rtu is not None:
                self._rtu = _RtuLine(cfg.rtu, self.sim)
                self.rtu_port = self._rtu.open()
            if cfg.rtu_over_tcp is not None:
                await self.start_rtu_over_tcp(cfg.rtu_over_tcp.port)
            laser = self.sim.instruments.get("laser")
            bridge_cfg = cfg.instruments.laser.bridge if cfg.instruments.laser else None
            if bridge_cfg is not None and isinstance(laser, Laser):
                self.laser_bridge = LaserBridge(bridge_cfg, laser)
                self.laser_bridge_port = await self.laser_bridge.start()
        except BaseException:
            await self.stop()
            raise

    async def start_rtu_over_tcp(self, port: int) -> int:
        """Listen for RTU over TCP on ``port`` (0: a free one); returns the bound port.
        With :meth:`stop_rtu_over_tcp`, a test kills and restarts this server alone."""
        cfg = self.config.sim.rtu_over_tcp or TcpConfig()
        line_cfg = RtuConfig(port=f"tcp:{cfg.host}")
        self._rot_server = await asyncio.get_running_loop().create_server(
            lambda: _RtuOverTcpLine(line_cfg, self.sim, self._rot_lines), cfg.host, port)
        self.rtu_over_tcp_port = self._rot_server.sockets[0].getsockname()[1]
        return self.rtu_over_tcp_port

    async def stop_rtu_over_tcp(self) -> None:
        """Stop listening for RTU over TCP and drop its connections."""
        if self._rot_server is not None:
            self._rot_server.close()
            for line in list(self._rot_lines):
                line.abort()
            await self._rot_server.wait_closed()
            self._rot_server = None

    async def stop(self) -> None:
        """Close listeners and connections."""
        if self.laser_bridge is not None:
            await self.laser_bridge.stop()
            self.laser_bridge = None
        await self.stop_rtu_over_tcp()
        if self._rtu is not None:
            await self._rtu.close()
            self._rtu = None
        if self._tcp_server is not None:
            self._tcp_server.close()
            for task in list(self._tasks):
                task.cancel()
            await asyncio.gather(*self._tasks, return_exceptions=True)
            await self._tcp_server.wait_closed()
            self._tcp_server = None

    async def __aenter__(self) -> SimServer:
        await self.start()
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.stop()

    # ------------------------------------------------------------ TCP
    async def _serve_tcp_client(
        self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter
    ) -> None:
        """One connection: requests answered in order, each with its own transaction id."""
        task = asyncio.current_task()
        if task is not None:
            self._tasks.add(task)
        framer = FramerSocket(DecodePDU(is_server=True))
        buffer = b""
        try:
            while True:
                chunk = await reader.read(4096)
                if not chunk:
                    return
                buffer += chunk
                while len(buffer) >= framer.MIN_SIZE:
                    if buffer[2:4] != b"\x00\x00":
                        return  # not Modbus: drop the connection
                    used, unit, tid, pdu = framer.decode(buffer)
                    if not used:
                        break
                    buffer = buffer[used:]
                    await self._answer_tcp(writer, framer, unit, tid, pdu)
        except (ConnectionError, asyncio.CancelledError):
            pass
        finally:
            if task is not None:
                self._tasks.discard(task)
            writer.close()
            with contextlib.suppress(Exception):
                await writer.wait_closed()

    async def _answer_tcp(
        self, writer: asyncio.StreamWriter, framer: FramerSocket, unit: int, tid: int, pdu: bytes
    ) -> None:
        reply = self.sim.respond(unit, pdu)
        if reply.unknown_unit and pdu:
            reply = Reply(exception_pdu(pdu[0], GATEWAY_NO_RESPONSE))
        if reply.pdu is None:
            return
        if reply.delay_s > 0:
            await asyncio.sleep(reply.delay_s)
        body = self.sim.scramble(reply.pdu) if reply.garbage else reply.pdu
        writer.write(framer.encode(body, unit, tid))
        await writer.drain()


class _PtyPort:
    """The drives' end of a new pseudo-terminal (``rtu.port: pty``): the masters open
    :attr:`path` as their serial port, with no bridge process or thread in between. The
    sim keeps the terminal's own end open too, so a master closing it does not hang it up."""

    def __init__(self) -> None:
        self._fd, self._keep = os.openpty()
        tty.setraw(self._keep)
        os.set_blocking(self._fd, False)
        self.path = os.ttyname(self._keep)

    def fileno(self) -> int:
        return self._fd

    def read(self, size: int) -> bytes:
        try:
            return os.read(self._fd, size)
        except BlockingIOError:
            return b""

    def write(self, data: bytes) -> None:
        view = memoryview(data)
        while view:
            try:
                view = view[os.write(self._fd, view):]
            except BlockingIOError:  # the master is not reading: its input queue is full
                return

    def close(self) -> None:
        for fd in (self._fd, self._keep):
            with contextlib.suppress(OSError):
                os.close(fd)


class _RtuLine:
    """Modbus RTU on one serial port: one request at a time, replies in order."""

    def __init__(self, cfg: RtuConfig, sim: Simulation) -> None:
        self.cfg = cfg
        self.sim = sim
        self.framer = FramerRTU(DecodePDU(is_server=True))
        self._port: serial.Serial | _PtyPort | None = None
        self._buffer = b""
        self._gap: asyncio.TimerHandle | None = None
        self._queue: asyncio.Queue[tuple[int, bytes, float]] = asyncio.Queue()
        self._line_idle_since_s = 0.0  # when the last frame on the line ended (monotonic)
        self._frame_start_s = 0.0  # when the frame being received began
        self._worker: asyncio.Task | None = None

    def open(self) -> str:
        """Open the port and start reading (raises serial.SerialException, OSError);
        returns the device path the masters open (for ``pty``: the new terminal's)."""
        if self.cfg.port == PTY_PORT:
            self._port = _PtyPort()
            path = self._port.path
        else:
            self._port = serial.Serial(
                port=self.cfg.port,
                baudrate=int(self.cfg.baudrate),
                parity=_PARITY[self.cfg.parity],
                stopbits=self.cfg.stopbits,
                bytesize=self.cfg.bytesize,
                timeout=0,
            )
            path = self.cfg.port
        loop = asyncio.get_running_loop()
        loop.add_reader(self._port.fileno(), self._on_readable)
        self._worker = loop.create_task(self._work())
        return path

    async def close(self) -> None:
        """Stop reading and close the port."""
        if self._gap is not None:
            self._gap.cancel()
        if self._worker is not None:
            self._worker.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self._worker
        if self._port is not None:
            with contextlib.suppress(Exception):
                asyncio.get_running_loop().remove_reader(self._port.fileno())
            self._port.close()
            self._port = None

    def _on_readable(self) -> None:
        assert self._port is not None
        try:
            chunk = self._port.read(4096)
        except (serial.SerialException, OSError):
            # the line is gone (adapter unplugged): stop watching it instead of spinning
            asyncio.get_running_loop().remove_reader(self._port.fileno())
            return
        if chunk:
            self._feed(chunk)

    def _feed(self, chunk: bytes) -> None:
        """Bytes from the line: cut frames (CRC) and queue each request."""
        now = time.monotonic()
        if not self._buffer:
            self._frame_start_s = now
        self._buffer += chunk
        used, unit, _tid, pdu = self.framer.decode(self._buffer)
        if used:
            self._buffer = b""  # a frame, or a bad CRC: either way the buffer is spent
            silence_s = self._frame_start_s - self._line_idle_since_s
            self._line_idle_since_s = now
            if pdu:
                self._queue.put_nowait((unit, pdu, silence_s))
        if self._gap is not None:
            self._gap.cancel()
            self._gap = None
        if self._buffer:
            self._gap = asyncio.get_running_loop().call_later(RTU_GAP_S, self._drop_partial)

    def _drop_partial(self) -> None:
        self._buffer = b""
        self._gap = None

    async def _work(self) -> None:
        while True:
            unit, pdu, silence_s = await self._queue.get()
            if unit == 0:  # broadcast: every unit on the line acts on it, none answers
                for each in list(self.sim.units):
                    if each != self.sim.config.sim.faults.unit:  # the harness's, no device
                        self.sim.respond(each, pdu)
                continue
            drive = self.sim.drives_by_unit.get(unit)
            if drive is not None and silence_s < drive.regs_cfg.min_silence_s:
                drive.silence_violations += 1  # the drive does not see a frame this close
                continue
            reply = self.sim.respond(unit, pdu)
            if reply.pdu is None:
                continue
            if reply.delay_s > 0:
                await asyncio.sleep(reply.delay_s)
            keep_s = self.cfg.reply_silence_s - (time.monotonic() - self._line_idle_since_s)
            if keep_s > 0:  # a slave that needs t3.5 of silence to see the request's end
                await asyncio.sleep(keep_s)
            frame = self.framer.encode(reply.pdu, unit, 0)
            if reply.garbage:
                frame = self.sim.scramble(frame)
                if FramerRTU.check_CRC(frame[:-2], int.from_bytes(frame[-2:], "big")):
                    frame = frame[:-1] + bytes([frame[-1] ^ 0xFF])
            self._write(frame)

    def _write(self, frame: bytes) -> None:
        if self._port is not None:
            self._port.write(frame)
            self._line_idle_since_s = time.monotonic()


class _RtuOverTcpLine(_RtuLine, asyncio.Protocol):
    """One TCP connection carrying RTU frames (CRC, no MBAP), as a serial device server in
    transparent mode passes them: each connection is a line of its own (its own framing,
    silence and reply order), served by the :class:`_RtuLine` machinery."""

    def __init__(self, cfg: RtuConfig, sim: Simulation, lines: set[_RtuOverTcpLine]) -> None:
        super().__init__(cfg, sim)
        self._lines = lines
        self._transport: asyncio.Transport | None = None

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        self._transport = transport  # type: ignore[assignment]
        self._lines.add(self)
        self._worker = asyncio.get_running_loop().create_task(self._work())

    def data_received(self, data: bytes) -> None:
        self._feed(data)

    def connection_lost(self, exc: Exception | None) -> None:
        self._lines.discard(self)
        self._transport = None
        if self._gap is not None:
            self._gap.cancel()
        if self._worker is not None:
            self._worker.cancel()

    def _write(self, frame: bytes) -> None:
        if self._transport is not None and not self._transport.is_closing():
            self._transport.write(frame)
            self._line_idle_since_s = time.monotonic()

    def abort(self) -> None:
        """Close the connection at once (the server stops)."""
        if self._transport is not None:
            self._transport.abort()


# ---------------------------------------------------------------- command line
async def _serve(config: SimConfig) -> int:
    """Run until SIGINT/SIGTERM."""
    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    for sig in (signal.SIGINT, signal.SIGTERM):
        loop.add_signal_handler(sig, stop.set)
    server = SimServer(config)
    try:
        await server.start()
    except (OSError, serial.SerialException) as err:
        print(f"compgw sim: cannot listen: {err}", file=sys.stderr)
        return EXIT_RUNTIME
    cfg = server.config.sim
    if server.tcp_port is not None and cfg.tcp is not None:
        print(f"compgw sim: modbus tcp on {cfg.tcp.host}:{server.tcp_port}", flush=True)
    if server.rtu_port is not None:
        print(f"compgw sim: modbus rtu on {server.rtu_port}", flush=True)
    if server.rtu_over_tcp_port is not None and cfg.rtu_over_tcp is not None:
        print(f"compgw sim: modbus rtu over tcp on {cfg.rtu_over_tcp.host}:"
              f"{server.rtu_over_tcp_port}", flush=True)
    laser = cfg.instruments.laser
    if server.laser_bridge_port is not None and laser is not None and laser.bridge is not None:
        print(f"compgw sim: laser bridge on {laser.bridge.host}:{server.laser_bridge_port}",
              flush=True)
    recorder = server.sim.recorder
    if recorder is not None and laser is not None:
        print(f"compgw sim: laser recording {recorder.axis} to {recorder.dir} (unit "
              f"{laser.unit} register 0x0100: 1 starts, 2 stops and saves)", flush=True)
    units = ", ".join(f"{n}={a.unit}" for n, a in cfg.axes.items())
    print(f"compgw sim: drives {units}; faults unit {cfg.faults.unit}", flush=True)
    try:
        await stop.wait()
    finally:
        await server.stop()
    return EXIT_OK


def _run(main: Coroutine[Any, Any, int]) -> int:
    """On uvloop where it is installed, as the gateway runs: the suite's and the benches'
    commissionings send the sim tens of thousands of requests."""
    try:
        import uvloop
    except ImportError:  # pragma: no cover - a pinned dependency on Linux
        return asyncio.run(main)
    return uvloop.run(main)


def main(config_path: str) -> int:
    """``compgw sim -c FILE``: 0 ok, 1 bad config (one line naming the YAML path), 3 fault."""
    try:
        config = load_config(config_path)
    except SimConfigError as err:
        print(f"compgw sim: {Path(config_path)}: {err}", file=sys.stderr)
        return EXIT_BAD_CONFIG
    if config.sim.tcp is None and config.sim.rtu is None and config.sim.rtu_over_tcp is None:
        print(f"compgw sim: {config_path}: sim: give tcp, rtu and/or rtu_over_tcp",
              file=sys.stderr)
        return EXIT_BAD_CONFIG
    try:
        return _run(_serve(config))
    except KeyboardInterrupt:
        return EXIT_OK
    except Exception as err:  # a runtime fault, reported in one line
        print(f"compgw sim: runtime fault: {type(err).__name__}: {err}", file=sys.stderr)
        return EXIT_RUNTIME
