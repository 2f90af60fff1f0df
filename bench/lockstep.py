"""The bench's machine in lock-step: compgw on the simulated machine's clock, the gateway's
thermal sources read at the machine's instants. What makes two runs of bench/accuracy.py
print the same figures.

The sim runs at ``time_scale: 0``: its clock moves with each move, reading and explicit
advance, not with the wall clock. compgw is written for a machine whose clock is the wall
clock, and at three places the wall clock reached the figures:

* the gateway's heat from motion (``thermal.motion``: the screw cools for the wall time
  between two moves when longer than the move) and its travel profile's ``memory_s``;
* `compgw commission`'s drift log (``wall_s``: the time a heat-from-motion fit cools by);
* the gateway polls its thermal sources every ``poll_s`` of wall time: whether it had read
  a sensor since the last move when the next target came depended on timing (one to a few
  moves stale), and every poll drew the sensor's noise from the sim's generator, so the
  readings commissioning took itself (and the heat profile's time steps) shifted with the
  number of polls before them.

``clock`` runs one compgw command with the machine's clock (``time.time()`` and the
gateway's heat-from-motion, travel-profile and move-log clocks, each a read of the sim's control
block 0x0802-0x0803, ms): ``python bench/lockstep.py clock HOST:PORT -- run -c gw.yaml``.
compgw's code is not changed: a real machine's clock and its computer's agree, and here
the computer gets the machine's.

``wire`` sits between the sim and everyone else (the gateway's bus, the instruments'
readers, the gateway's masters) on a machine with thermal sources:

* requests reach the sim one at a time; after each that may move the clock (all but the
  reads of drives and of the control block) the wire reads the clock and every thermal
  sensor, and when the clock moved (a new *instant*) that reading is what every reader of a
  sensor gets until the next instant: the sensors' noise is drawn as often in every run,
  whoever reads and how often;
* a write through the gateway (a target, a trigger) waits until the gateway has polled each
  thermal source at the current instant and polled it again after (its filter has taken
  that reading) and its status unit says every source is ok: the correction is made with
  the sensor as it reads now, as on a real machine whose moves last far longer than a
  poll. Reads through the gateway do not wait: status words pass through, and feedback at
  rest reports the nominal target the master wrote (gateway/axis.py, reported_feedback);
* while no master's request waits here or is in the gateway, a poll of a source the
  gateway has already read at this instant is held (at most ``PARK_S``) until the next
  instant or a master's request: the gateway reads its sensors about once per instant
  instead of every ``poll_s``. (Its bus takes one request at a time: a held poll holds
  the other sources' polls and the drives' requests too, so none is held while a write
  waits for the sources or a request is in the gateway.)

    python bench/lockstep.py wire --sim 127.0.0.1:5021 --sensor 23:3 --source 23:0:1 \
        --status-unit 247    # prints its ports; then give it "gateway PORT" on stdin
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import signal
import socket
import struct
import sys
import threading
import time
from collections.abc import Callable, Mapping, Sequence

FAULTS_UNIT, CLOCK_MS, ADVANCE_MS = 250, 0x0802, 0x0801
READS = (0x03, 0x04)
#: function codes that write (the gateway corrects what they carry, or starts a move)
WRITES = (0x05, 0x06, 0x0F, 0x10, 0x16, 0x17)
#: how long a write waits for the gateway's sensors before going on unsynced (counted)
SYNC_TIMEOUT_S = 30.0
#: how long the gateway's poll of a sensor it has read at this instant is held at most (s;
#: well inside its bus timeout, bench/workflows.py BUS_TIMEOUT_S)
PARK_S = 1.0


# -- the machine's clock for compgw ------------------------------------------------------------
def _recv_exactly(sock: socket.socket, n: int) -> bytes:
    out = b""
    while len(out) < n:
        chunk = sock.recv(n - len(out))
        if not chunk:
            raise ConnectionError("the sim closed the connection")
        out += chunk
    return out


class SimClock:
    """The sim's machine clock (s) from its control block, over a socket of its own
    (blocking, thread-safe; the socket's timeouts are the kernel's, not ``time.time``)."""

    def __init__(self, host: str, port: int) -> None:
        self.address = (host, port)
        self._sock: socket.socket | None = None
        self._tid = 0
        self._lock = threading.Lock()

    def _read_ms(self) -> int:
        if self._sock is None:
            self._sock = socket.create_connection(self.address, timeout=10.0)
            self._sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self._tid = (self._tid + 1) & 0xFFFF
        self._sock.sendall(struct.pack(">HHHBBHH", self._tid, 0, 6, FAULTS_UNIT, 0x03,
                                       CLOCK_MS, 2))  # fmt: skip
        tid, _, length = struct.unpack(">HHH", _recv_exactly(self._sock, 6))
        body = _recv_exactly(self._sock, length)
        if tid != self._tid or body[1] != 0x03 or body[2] != 4:
            raise ConnectionError(f"the sim's clock read answered {body.hex()}")
        hi, lo = struct.unpack(">HH", body[3:7])
        return (hi << 16) | lo

    def advance(self, seconds: float) -> None:
        """Move the machine's clock on by ``seconds`` (the control block's 0x0801, ms)."""
        with self._lock:
            if self._sock is None:
                self._read_ms()
            assert self._sock is not None
            self._tid = (self._tid + 1) & 0xFFFF
            self._sock.sendall(struct.pack(">HHHBBHH", self._tid, 0, 6, FAULTS_UNIT, 0x06,
                                           ADVANCE_MS, round(seconds * 1000.0)))  # fmt: skip
            tid, _, length = struct.unpack(">HHH", _recv_exactly(self._sock, 6))
            body = _recv_exactly(self._sock, length)
            if tid != self._tid or body[1] != 0x06:
                raise ConnectionError(f"the sim's clock advance answered {body.hex()}")

    def __call__(self) -> float:
        with self._lock:
            try:
                return self._read_ms() / 1000.0
            except OSError:
                if self._sock is not None:
                    self._sock.close()
                self._sock = None
                return self._read_ms() / 1000.0


def install(clock: Callable[[], float]) -> None:
    """Make ``clock`` compgw's time: ``time.time`` (commissioning's drift log, the raw
    files' ``time_s``) and the default clock of the gateway's heat from motion, travel
    profile and move log (gateway/thermal_travel.py); a recording's stand at each stop advances the
    machine's clock instead of sleeping. asyncio, bus timeouts and the thermal sources'
    filter keep the wall clock: every poll at one instant reads the same (``wire``), and
    with ``smoothing: 1`` (the generated machines' sources) the filter's value is that
    reading however often it polled (a smoothing below 1 would count the polls)."""
    real = time.monotonic
    time.time = clock
    advance = getattr(clock, "advance", None)
    if advance is not None:  # a recording's stand at each stop: machine time, not wall time
        from gateway.calibration.measuring import from_file

        async def stand(seconds: float) -> None:
            await asyncio.to_thread(advance, seconds)

        from_file.stand = stand
        _stops_on_clock(clock, advance)
    from gateway import thermal_travel

    for cls in (thermal_travel.HeatFromMotion, thermal_travel.TravelHistory,
                thermal_travel.MoveLog):
        defaults = cls.__init__.__defaults__ or ()
        if real not in defaults:
            raise RuntimeError(f"{cls.__name__}: no time.monotonic default clock to replace")
        cls.__init__.__defaults__ = tuple(clock if d is real else d for d in defaults)


#: machine time (s) of a live reading at a stop: settling and the instrument's averaging,
#: what compgw's estimates count (``plan_time_s``'s ``stop_s``) and a recording's stand
STOP_S = 2.0


def _stops_on_clock(clock: Callable[[], float], advance: Callable[[float], None]) -> None:
    """A live instrument's reading at a stop (a laser, an XY device, an angle instrument;
    not the Δa sensor read at the same stop) lasts ``STOP_S`` of the machine's clock, as a
    recording's stand does: the sim's settling is over in a few reads of its clock, and
    the machine would not cool while a Modbus laser or a bridge is read (smooth-0's X
    commissioning spanned 259 s of the machine's clock through the Modbus laser and 2122 s
    through a recording, for 0.52 and 0.55 h of estimated machine time)."""
    from gateway.calibration.measuring.devices import DELTA_A_CHANNEL
    from gateway.instruments.base import Instrument

    plain = Instrument.read_mm

    async def read_mm(self: Instrument, axes: Sequence[str],
                      near_mm: Mapping[str, float] | None = None) -> dict[str, float]:
        began_s = clock()
        values = await plain(self, axes, near_mm)
        left_s = STOP_S - (clock() - began_s)
        if DELTA_A_CHANNEL not in axes and left_s > 0:  # (a Δa sensor: read at the stop)
            await asyncio.to_thread(advance, left_s)
        return values

    Instrument.read_mm = read_mm  # type: ignore[method-assign]


# -- the wire ------------------------------------------------------------------------------------
#: a connection's end, or the wire's own (its tasks cancelled as it stops)
_GONE = (asyncio.IncompleteReadError, ConnectionError, asyncio.CancelledError)


def _exception(fc: int, code: int) -> bytes:
    return bytes([(fc | 0x80) & 0xFF, code])


async def _read_frame(reader: asyncio.StreamReader) -> tuple[int, int, bytes]:
    """(transaction id, unit, PDU) of one MBAP frame."""
    tid, _, length = struct.unpack(">HHH", await reader.readexactly(6))
    body = await reader.readexactly(length)
    return tid, body[0], body[1:]


def _frame(tid: int, unit: int, pdu: bytes) -> bytes:
    return struct.pack(">HHHB", tid, 0, len(pdu) + 1, unit) + pdu


class Wire:
    """The sim's only client: serialises requests, keeps the sensors' reading per instant,
    holds writes through the gateway until its thermal sources have read the instant."""

    def __init__(self, sim: tuple[str, int], sensors: dict[int, int],
                 sources: list[tuple[int, int, int]], status_unit: int,
                 drives: set[int]) -> None:  # fmt: skip
        self.sim_address = sim
        self.sensors = sensors  # unit -> registers read from 0
        self.sources = sources  # (unit, address, count) the gateway polls
        self.status_unit = status_unit
        self.drives = drives  # units whose reads never move the clock
        self.instant = 0
        self.clock_ms = -1
        self.cache: dict[int, list[int]] = {}
        self.answered: dict[tuple[int, int, int], int] = {}  # instant of the last answer
        self.proof: dict[tuple[int, int, int], int | None] = {}  # polled again after it
        self.synced = -1
        self.in_flight = 0  # masters' requests waiting here or in the gateway
        self.unsynced = 0
        self.holds = 0
        self.held_s = 0.0  # wall time writes waited
        self.held_max_s = 0.0
        self.rounds = 0  # polls asked again for a source not ok
        self.polls = 0
        self.polled = asyncio.Condition()
        self._wake = asyncio.Event()
        self._lock = asyncio.Lock()
        self._status_lock = asyncio.Lock()
        self._tid = 0
        self._sim: tuple[asyncio.StreamReader, asyncio.StreamWriter] | None = None
        self.gateway: tuple[str, int] | None = None
        self._status: tuple[asyncio.StreamReader, asyncio.StreamWriter] | None = None

    # the sim, one request at a time
    async def _ask(self, requests: list[tuple[int, bytes]]) -> list[bytes]:
        """The sim's replies to ``requests`` (unit, PDU), sent back to back."""
        if self._sim is None:
            self._sim = await asyncio.open_connection(*self.sim_address)
        reader, writer = self._sim
        tids = []
        for unit, pdu in requests:
            self._tid = (self._tid + 1) & 0xFFFF
            tids.append(self._tid)
            writer.write(_frame(self._tid, unit, pdu))
        await writer.drain()
        replies: dict[int, bytes] = {}
        while len(replies) < len(tids):
            tid, _, reply = await _read_frame(reader)
            if tid in tids:
                replies[tid] = reply
        return [replies[t] for t in tids]

    async def ask(self, unit: int, pdu: bytes, tick: bool = True) -> bytes:
        """The sim's reply to one request (under ``_lock``); with ``tick`` the clock and
        every sensor are read right after it, and when the clock moved (a new instant)
        that reading is what every reader of a sensor gets until the next instant. The
        sensors are read after every such request, moved or not (their noise drawn as
        many times in every run), so all of it goes to the sim at once."""
        if not tick:
            return (await self._ask([(unit, pdu)]))[0]
        units = list(self.sensors)
        reads = [(u, struct.pack(">BHH", 0x04, 0, self.sensors[u])) for u in units]
        clock = (FAULTS_UNIT, struct.pack(">BHH", 0x03, CLOCK_MS, 2))
        reply, clock_reply, *sensor_replies = await self._ask([(unit, pdu), clock, *reads])
        hi, lo = struct.unpack(">HH", clock_reply[2:6])
        ms = (hi << 16) | lo
        if ms != self.clock_ms:
            cache = {}
            for u, r in zip(units, sensor_replies, strict=True):
                n = self.sensors[u]
                if r[0] != 0x04:
                    raise RuntimeError(f"sensor unit {u} answered {r.hex()}")
                cache[u] = list(struct.unpack(f">{n}H", r[2:2 + 2 * n]))
            self.clock_ms, self.cache, self.instant = ms, cache, self.instant + 1  # at once
            self.wake()
        return reply

    def wake(self) -> None:
        """Answer the gateway's parked polls (a new instant, or it needs its bus)."""
        self._wake.set()
        self._wake = asyncio.Event()

    async def forward(self, unit: int, pdu: bytes, gateway_bus: bool) -> bytes:
        """The sim's reply to one request (a sensor's from this instant's reading)."""
        fc = pdu[0] if pdu else 0
        if unit in self.sensors and fc in READS:
            if len(pdu) != 5:
                return _exception(fc, 0x03)
            address, count = struct.unpack(">HH", pdu[1:5])
            if not 1 <= count <= 125 or address + count > self.sensors[unit]:
                return _exception(fc, 0x02)
            if gateway_bus:
                await self._polled((unit, address, count))
            data = self.cache[unit][address:address + count]
            return bytes([fc, 2 * count]) + struct.pack(f">{count}H", *data)
        quiet = fc in READS and (unit in self.drives or unit == FAULTS_UNIT)
        async with self._lock:  # not quiet: a move, a reading that takes time, an advance
            return await self.ask(unit, pdu, tick=not quiet)

    async def _polled(self, key: tuple[int, int, int]) -> None:
        """The gateway polls source ``key``. Asked again at the instant it was answered,
        the answer it had is in its filter (the proof a held write waits for); that poll
        is then parked until a new instant or a master's request (the gateway's bus is
        one request at a time), so the gateway polls once per instant, not every poll_s."""
        self.polls += 1
        if self.answered.get(key) == self.instant:
            self.proof[key] = self.instant
            async with self.polled:
                self.polled.notify_all()
            if not self.in_flight:
                with contextlib.suppress(TimeoutError):
                    await asyncio.wait_for(self._wake.wait(), PARK_S)
        self.answered[key] = self.instant

    # the gateway's masters
    async def _source_states(self) -> list[int]:
        """Each thermal source's state on the gateway's status unit (1: ok)."""
        assert self.gateway is not None
        n = len(self.sources)
        request = _frame(1, self.status_unit, struct.pack(">BHH", 0x04, 80, 4 * n))
        async with self._status_lock:
            for attempt in (0, 1):  # a connection the gateway closed: once more on a new one
                try:
                    if self._status is None:
                        self._status = await asyncio.open_connection(*self.gateway)
                    reader, writer = self._status
                    writer.write(request)
                    await writer.drain()
                    _, _, reply = await _read_frame(reader)
                    break
                except (asyncio.IncompleteReadError, ConnectionError):
                    self._status = None
                    if attempt:
                        raise
        if reply[0] != 0x04:
            raise RuntimeError(f"the gateway's status unit answered {reply.hex()}")
        regs = struct.unpack(f">{4 * n}H", reply[2:2 + 8 * n])
        return [regs[4 * s] for s in range(n)]

    async def sync(self) -> None:
        """Until the gateway's thermal sources have read the current instant (see above)."""
        if not self.sources or self.synced == self.instant:
            return
        self.holds += 1
        loop = asyncio.get_running_loop()
        t0 = loop.time()
        try:
            await self._sync(loop, t0 + SYNC_TIMEOUT_S)
        finally:
            held = loop.time() - t0
            self.held_s += held
            self.held_max_s = max(self.held_max_s, held)
            if held > 0.5:
                print(f"lockstep wire: a write waited {held:.2f} s for instant {self.instant}",
                      file=sys.stderr, flush=True)

    async def _sync(self, loop: asyncio.AbstractEventLoop, deadline: float) -> None:
        while self.synced != self.instant:
            k = self.instant

            def fresh(k: int = k) -> bool:
                return self.instant != k or all(self.proof.get(s) == k for s in self.sources)

            try:
                async with self.polled:
                    await asyncio.wait_for(self.polled.wait_for(fresh),
                                           max(0.0, deadline - loop.time()))  # fmt: skip
            except TimeoutError:
                self.unsynced += 1
                print(f"lockstep wire: sources not read at instant {k} in "
                      f"{SYNC_TIMEOUT_S:g} s: a write went on unsynced", file=sys.stderr)
                self.synced = self.instant
                return
            if self.instant != k:
                continue
            states = await self._source_states()
            if all(state == 1 for state in states) and self.instant == k:
                self.synced = k
            else:  # a reading refused (or none yet): another round of polls
                self.rounds += 1
                for s in self.sources:
                    self.proof[s] = None
                self.wake()

    async def serve_sim(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter,
                        gateway_bus: bool) -> None:  # fmt: skip
        with contextlib.suppress(*_GONE):
            while True:
                tid, unit, pdu = await _read_frame(reader)
                writer.write(_frame(tid, unit, await self.forward(unit, pdu, gateway_bus)))
                await writer.drain()
        writer.close()

    async def serve_masters(self, reader: asyncio.StreamReader,
                            writer: asyncio.StreamWriter) -> None:  # fmt: skip
        assert self.gateway is not None
        gw_reader, gw_writer = await asyncio.open_connection(*self.gateway)
        with contextlib.suppress(*_GONE):
            while True:
                tid, unit, pdu = await _read_frame(reader)
                self.in_flight += 1  # from here no poll is parked: the sources (one bus)
                self.wake()  # poll in turn while this waits, the gateway may need its bus
                try:
                    if unit != self.status_unit and pdu[:1] and pdu[0] in WRITES:
                        await self.sync()
                    gw_writer.write(_frame(tid, unit, pdu))
                    await gw_writer.drain()
                    while True:
                        r_tid, r_unit, reply = await _read_frame(gw_reader)
                        if r_tid == tid:
                            break
                finally:
                    self.in_flight -= 1
                writer.write(_frame(r_tid, r_unit, reply))
                await writer.drain()
        gw_writer.close()
        writer.close()


async def _wire_main(args: argparse.Namespace) -> int:
    host, port = args.sim.rsplit(":", 1)
    sensors = {int(u): int(c) for u, c in (s.split(":") for s in args.sensor)}
    sources = [(int(u), int(a), int(c)) for u, a, c in (s.split(":") for s in args.source)]
    wire = Wire((host, int(port)), sensors, sources, args.status_unit, set(args.drive))
    async with wire._lock:  # the first instant
        await wire.ask(FAULTS_UNIT, struct.pack(">BHH", 0x03, CLOCK_MS, 2))
    sim_srv = await asyncio.start_server(lambda r, w: wire.serve_sim(r, w, False), "127.0.0.1", 0)
    bus_srv = await asyncio.start_server(lambda r, w: wire.serve_sim(r, w, True), "127.0.0.1", 0)
    print(f"lockstep wire: sim {sim_srv.sockets[0].getsockname()[1]} "
          f"bus {bus_srv.sockets[0].getsockname()[1]}", flush=True)
    loop = asyncio.get_running_loop()
    stop = asyncio.Event()
    for sig in (signal.SIGTERM, signal.SIGINT):
        loop.add_signal_handler(sig, stop.set)

    lines: asyncio.Queue[str] = asyncio.Queue()

    def read_stdin() -> None:  # a daemon thread: its blocked read never holds up the exit
        for line in sys.stdin:
            loop.call_soon_threadsafe(lines.put_nowait, line)
        loop.call_soon_threadsafe(lines.put_nowait, "")

    threading.Thread(target=read_stdin, daemon=True).start()

    async def control() -> None:  # "gateway PORT" on stdin; its end stops the wire
        masters = None
        while line := await lines.get():
            words = line.split()
            if words[:1] == ["gateway"] and masters is None:
                wire.gateway = ("127.0.0.1", int(words[1]))
                masters = await asyncio.start_server(wire.serve_masters, "127.0.0.1", 0)
                print(f"lockstep wire: gateway {masters.sockets[0].getsockname()[1]}",
                      flush=True)
        stop.set()

    ctl = asyncio.create_task(control())
    await stop.wait()
    done = (f"lockstep wire: instants {wire.instant} polls {wire.polls} holds {wire.holds} "
            f"waited {wire.held_s:.1f} s (at most {wire.held_max_s:.2f}) rounds {wire.rounds} "
            f"unsynced {wire.unsynced}")  # fmt: skip
    print(done, flush=True)
    print(done, file=sys.stderr, flush=True)
    ctl.cancel()
    return 0


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter,
                                     epilog=__doc__.split("\n\n", 1)[1])  # fmt: skip
    sub = parser.add_subparsers(dest="what", required=True)
    c = sub.add_parser("clock", help="run a compgw command on the sim's machine clock")
    c.add_argument("sim", metavar="HOST:PORT", help="the sim (its control block: unit 250)")
    c.add_argument("compgw", nargs=argparse.REMAINDER, help="-- and compgw's arguments")
    w = sub.add_parser("wire", help="the lock-step wire in front of the sim")
    w.add_argument("--sim", required=True, metavar="HOST:PORT")
    w.add_argument("--sensor", action="append", default=[], metavar="UNIT:COUNT",
                   help="a thermal sensor unit and how many registers it has")
    w.add_argument("--source", action="append", default=[], metavar="UNIT:ADDRESS:COUNT",
                   help="a thermal source the gateway polls (config order)")
    w.add_argument("--status-unit", type=int, default=247)
    w.add_argument("--drive", type=int, action="append", default=[], metavar="UNIT",
                   help="a drive's unit (its reads never move the machine's clock)")
    args = parser.parse_args()
    if args.what == "wire":
        return asyncio.run(_wire_main(args))
    host, port = args.sim.rsplit(":", 1)
    install(SimClock(host, int(port)))
    from gateway.cli import main as compgw

    argv = args.compgw[1:] if args.compgw[:1] == ["--"] else args.compgw
    sys.argv = ["compgw", *argv]
    return compgw(argv)


if __name__ == "__main__":
    sys.exit(main())
