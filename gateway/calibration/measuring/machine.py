"""The machine driver of a calibration run: moves through the gateway, reads instruments.

This is the I/O side of calibration (the math lives in :mod:`..fitting.fit`,
:mod:`..fitting.iso230`, :mod:`..fitting.models`). It acts as an upper computer: it writes
nominal targets to the gateway the way any master would, triggers the move, and waits for
in-position. The laser, XY device and angle instrument are read through
:mod:`gateway.instruments` (any kind: :mod:`.devices`); the Modbus sensors read here as the
config's thermal sources read them:

- Δa sensor (``--delta-a HOST:PORT:UNIT[:ADDRESS]``): input registers ADDRESS (default 1),
  ADDRESS+1, int32 nm (the sim's displacement sensor at reference point A);
- screw temperature (``--temperature HOST:PORT:UNIT``): the config's temperature source's
  register and scale;
- a turntable's angle reading (modulo 360) is taken in the turn of its target
  (:func:`nearest_turn_deg`).

Any instrument behind the gateway's ``passthrough`` can be reached through the gateway's
own address, e.g. ``--laser 127.0.0.1:5020:20``.
"""

from __future__ import annotations

import asyncio
import time
from collections.abc import Awaitable, Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from pymodbus.client import AsyncModbusTcpClient

from ...config import Axis, GatewayConfig, SourceRegister, ThermalSource
from ...machine_clock import WrappingCount
from ...modbus.frames import (
    GATEWAY_PATH_UNAVAILABLE,
    GATEWAY_TARGET_NO_RESPONSE,
    SERVER_DEVICE_BUSY,
    exception_words,
    pack_int32,
    unpack_int32,
)
from ...status import MACHINE_CLOCK_REGISTER
from ..cli_common import FROM_CONFIG

#: Status bits of the sim's default (Leadshine-like) profile; override per run.
DEFAULT_IN_POSITION_BIT = 4
DEFAULT_MOVING_BIT = 2
DEFAULT_ALARM_BIT = 0
NM_PER_MM = 1e6


class MachineError(RuntimeError):
    """The machine or an instrument did not do what was asked (Modbus error, alarm, timeout);
    ``code``: the Modbus exception code a device answered, where one did."""

    def __init__(self, message: str, code: int | None = None) -> None:
        super().__init__(message)
        self.code = code


class SetupError(MachineError):
    """What the command line says does not match the machine (the gateway runs another
    config file than ``-c``; a laser channel does not follow its axis): fixed by the
    command line, not by resuming."""


class ConfigMismatch(SetupError):
    """The gateway reloaded, but another file than the one written for it (``-c``)."""


@dataclass(frozen=True)
class Endpoint:
    """A Modbus TCP device: host, port, unit id and (optional) first register address."""

    host: str
    port: int
    unit: int
    address: int | None = None

    @classmethod
    def parse(cls, text: str) -> Endpoint:
        """``HOST:PORT[:UNIT[:ADDRESS]]``; ValueError with the rule if malformed."""
        parts = text.split(":")
        if not 2 <= len(parts) <= 4 or not parts[0]:
            raise ValueError(f"{text!r} is not HOST:PORT[:UNIT[:ADDRESS]]")
        try:
            numbers = [int(p, 0) for p in parts[1:]]
        except ValueError:
            raise ValueError(f"{text!r}: port, unit and address must be integers") from None
        port = numbers[0]
        unit = numbers[1] if len(numbers) > 1 else 1
        address = numbers[2] if len(numbers) > 2 else None
        if not (0 < port < 65536 and 0 <= unit <= 247):
            raise ValueError(f"{text!r}: port must be 1..65535 and unit 0..247")
        return cls(parts[0], port, unit, address)

    @classmethod
    def device(cls, option: str, text: str | None) -> Endpoint | None:
        """An instrument's ``HOST:PORT:UNIT[:ADDRESS]`` given as ``option`` (None: not
        given), its unit required: the default unit 1 is a drive on most lines."""
        if text is None:
            return None
        if text.count(":") < 2:
            raise ValueError(f"{option} {text!r}: give HOST:PORT:UNIT (the instrument's unit id)")
        try:
            return cls.parse(text)
        except ValueError as exc:
            raise ValueError(f"{option} {exc}") from None

    @property
    def key(self) -> tuple[str, int]:
        return self.host, self.port


def reraise_cancel() -> None:
    """A cancellation (Ctrl-C, SIGTERM) that pymodbus swallowed is raised again, or the
    interrupt would be lost: pymodbus turns a cancelled request into ModbusIOException,
    and on Python 3.11 ``asyncio.wait_for`` returns the reply when the cancel and the reply
    arrive together. Call it after every pymodbus await, answered or not."""
    task = asyncio.current_task()
    cancelling = getattr(task, "cancelling", None)  # Python 3.11+
    if task is not None and cancelling is not None and cancelling():
        raise asyncio.CancelledError


#: exception codes a request is tried again on: 0x06 "server device busy" and 0x0B "gateway
#: target device failed to respond" (a drive or instrument slow to answer: under CPU load
#: the sim behind a gateway with a 0.2 s bus timeout answered late and a commissioning
#: aborted on one reply). Reads and register writes are idempotent, so a second try is safe:
#: a target written twice is the same target, a trigger bit set twice is one rising edge.
TRANSIENT_CODES = frozenset({SERVER_DEVICE_BUSY, GATEWAY_TARGET_NO_RESPONSE})
#: tries after the first, and the pause before each (s, growing linearly)
TRANSIENT_RETRIES = 3
TRANSIENT_PAUSE_S = 0.05


#: what a gateway's exception says to check
_EXCEPTION_HINTS = {GATEWAY_PATH_UNAVAILABLE: "the gateway's line to that device is down",
                    GATEWAY_TARGET_NO_RESPONSE: "no answer from that device on its line: its "
                    "wiring, baud rate and unit id"}  # fmt: skip


def exception_text(reply: Any) -> str:
    """A Modbus reply in words: "exception 0x0b (gateway target device failed to respond:
    …)" for an exception response (pymodbus's repr otherwise)."""
    code = getattr(reply, "exception_code", None)
    if not isinstance(code, int) or not code:
        return str(reply)
    return exception_words(code, _EXCEPTION_HINTS.get(code, ""))


class Link:
    """One Modbus TCP connection, shared by every device at that host and port."""

    def __init__(self, host: str, port: int, timeout_s: float = 2.0) -> None:
        self.host, self.port = host, port
        self.client = AsyncModbusTcpClient(host, port=port, timeout=timeout_s, retries=1)
        #: requests answered only on a later try (:data:`TRANSIENT_CODES`)
        self.retried = 0

    async def connect(self) -> None:
        connected = await self.client.connect()
        reraise_cancel()
        if not connected:
            raise MachineError(f"cannot connect to {self.host}:{self.port}")

    def close(self) -> None:
        self.client.close()

    async def _ok(self, call: Callable[[], Awaitable[Any]], what: str) -> Any:
        """The reply of ``call()``; tried again on a transient exception
        (:data:`TRANSIENT_CODES`), a MachineError naming the request otherwise."""
        for attempt in range(TRANSIENT_RETRIES + 1):
            try:
                reply = await call()
            except Exception as exc:  # pymodbus raises ModbusIOException and friends
                reraise_cancel()
                raise MachineError(f"{self.host}:{self.port}: {what}: {exc}") from exc
            reraise_cancel()
            if not reply.isError():
                if attempt:
                    self.retried += 1
                return reply
            if getattr(reply, "exception_code", None) not in TRANSIENT_CODES:
                break
            if attempt < TRANSIENT_RETRIES:
                await asyncio.sleep(TRANSIENT_PAUSE_S * (attempt + 1))
        tries = f" ({attempt + 1} tries)" if attempt else ""
        raise MachineError(f"{self.host}:{self.port}: {what}: {exception_text(reply)}{tries}",
                           getattr(reply, "exception_code", None))

    async def read(self, unit: int, address: int, count: int, table: str) -> list[int]:
        fn = self.client.read_input_registers if table == "input" else (
            self.client.read_holding_registers
        )
        what = f"unit {unit} read {table} {address:#06x}+{count}"
        reply = await self._ok(lambda: fn(address, count=count, device_id=unit), what)
        return list(reply.registers)

    async def write_coil(self, unit: int, address: int, on: bool) -> None:
        await self._ok(lambda: self.client.write_coil(address, on, device_id=unit),
                       f"unit {unit} write coil {address:#06x}")  # fmt: skip

    async def write(self, unit: int, address: int, values: Sequence[int]) -> None:
        what = f"unit {unit} write {address:#06x}"
        if len(values) == 1:
            await self._ok(
                lambda: self.client.write_register(address, values[0], device_id=unit), what)
        else:
            await self._ok(
                lambda: self.client.write_registers(address, list(values), device_id=unit), what)


class Links:
    """Connections by (host, port), opened on first use, closed together."""

    def __init__(self, timeout_s: float = 2.0) -> None:
        self._links: dict[tuple[str, int], Link] = {}
        self.timeout_s = timeout_s  # per request

    async def get(self, host: str, port: int) -> Link:
        link = self._links.get((host, port))
        if link is None:
            link = Link(host, port, self.timeout_s)
            await link.connect()
            self._links[(host, port)] = link
        return link

    @property
    def retried(self) -> int:
        """Requests answered only on a later try, over every link."""
        return sum(link.retried for link in self._links.values())

    def close(self) -> None:
        for link in self._links.values():
            link.close()
        self._links.clear()


class GatewayClock:
    """The machine's clock as the gateway's status unit shows it (``machine_clock``: a
    simulator running hours in minutes), read after each move; the computer's clock
    (``time.time``) where the gateway shows none. What a commissioning's drift log and its
    readings' ``time_s`` count heat by: the screw heats and cools on the machine's clock."""

    def __init__(self) -> None:
        self._ms = WrappingCount(1 << 32)  # the status unit's uint32 ms
        self.shown: bool | None = None  # None: not asked yet

    def now_s(self) -> float:
        """The machine's clock (s) as last read, else the computer's."""
        return (self._ms.total or 0) / 1000.0 if self.shown else time.time()

    def kind(self) -> str:
        """Which clock :meth:`now_s` reads: ``"machine"`` or ``"computer"``."""
        return "machine" if self.shown else "computer"

    async def refresh(self, link: Link, unit: int) -> None:
        """Read the gateway's status unit ``unit`` (registers 120-122); a gateway that
        shows no machine clock (older than map v4, or none configured) is asked once."""
        if self.shown is False:
            return
        try:
            regs = await link.read(unit, MACHINE_CLOCK_REGISTER, 3, "input")
        except MachineError as exc:
            if exc.code is None:  # no reply at all: not an answer about the clock
                raise
            regs = [0, 0, 0]
        self.shown = bool(regs[0])
        if self.shown:
            self._ms.update(unpack_int32(regs[1:3], "hi_lo", signed=False))


@dataclass(frozen=True)
class MotionSettings:
    """How in-position is recognised: status bits of the drive, feedback tolerance, timeout.
    A bit left at :data:`FROM_CONFIG` comes from the axis's ``registers.status``
    (:meth:`MachineDriver.status_bits`); None: the drive has no such bit."""

    in_position_bit: int | None = FROM_CONFIG
    moving_bit: int | None = FROM_CONFIG
    alarm_bit: int | None = FROM_CONFIG
    in_position_pulses: float = 2.0
    timeout_s: float = 120.0
    poll_s: float = 0.005
    #: how long one request waits for its answer (s): a gateway on a slow serial line,
    #: or one a busy computer runs, answers a write after its drive has
    request_timeout_s: float = 2.0


class MachineDriver:
    """Moves the axes of a gateway config through the gateway, as an upper computer does."""

    def __init__(
        self, link: Link, config: GatewayConfig, settings: MotionSettings | None = None,
        clock: GatewayClock | None = None,
    ) -> None:
        self.link = link
        self.config = config
        self.settings = settings or MotionSettings()
        #: read after each move (the machine's clock, where the gateway shows one)
        self.clock = clock
        #: told of every target written (axis, mm): commissioning's odometer
        self.on_move: Callable[[str, float], None] | None = None

    def axis(self, name: str) -> Axis:
        if name not in self.config.axes:
            raise MachineError(f"axis {name!r} is not in the gateway config")
        return self.config.axes[name]

    def pulses(self, name: str, position_mm: float) -> int:
        return round(position_mm / self.axis(name).pulse_mm)

    async def write_target(self, name: str, position_mm: float) -> None:
        axis = self.axis(name)
        lo, hi = axis.travel_mm
        if not lo <= position_mm <= hi:
            raise MachineError(
                f"axis {name}: target {position_mm:g} mm outside travel {lo:g}..{hi:g}"
            )
        reg = axis.registers.target
        words = pack_int32(self.pulses(name, position_mm), reg.order)
        await self.link.write(axis.upstream, reg.address, list(words))
        if self.on_move is not None:
            self.on_move(name, position_mm)

    async def trigger(self, name: str) -> None:
        """Start the move as the drive's trigger says: a coil switched on, a 32-bit field
        written, a value written, or an edge of one bit of a control word whose other bits
        are kept as they read (a servo-on input, a CiA 402 drive's enable bits: writing 0
        then the bit alone switched those off, and a Kinco drive never moved)."""
        axis = self.axis(name)
        trig = axis.registers.trigger
        if trig is None:
            return  # the target write itself starts the move
        unit = axis.upstream
        if trig.table == "coils":
            await self.link.write_coil(unit, trig.address, trig.value != 0)
        elif trig.words == 2:
            value = 1 if trig.value is None else trig.value
            await self.link.write(unit, trig.address, list(pack_int32(value, trig.order)))
        elif trig.rising_bit is not None:
            word = (await self.link.read(unit, trig.address, 1, "holding"))[0]
            bit = 1 << trig.rising_bit
            await self.link.write(unit, trig.address, [word & ~bit & 0xFFFF])
            await self.link.write(unit, trig.address, [word | bit])
        else:
            await self.link.write(unit, trig.address, [(trig.value or 0) & 0xFFFF])

    def status_bits(self, name: str) -> tuple[int | None, int | None, int | None]:
        """In-position, moving and alarm bits of axis ``name``'s status word: the command
        line's where it gave them, else its config's ``registers.status`` where that gives
        any (the others unset: the drive has none), else Leadshine's (4, 2, 0) without a
        drive ``profile`` and none with one (the feedback alone says the move ended)."""
        axis = self.axis(name)
        status = axis.registers.status
        given = (None if status is None else
                 (status.in_position_bit, status.moving_bit, status.alarm_bit))  # fmt: skip
        if given is None or given == (None, None, None):
            given = ((DEFAULT_IN_POSITION_BIT, DEFAULT_MOVING_BIT, DEFAULT_ALARM_BIT)
                     if axis.profile is None else (None, None, None))  # fmt: skip
        s = self.settings
        asked = (s.in_position_bit, s.moving_bit, s.alarm_bit)
        return tuple(g if a == FROM_CONFIG else a for a, g in zip(asked, given))  # type: ignore[return-value]

    async def feedback_pulses(self, name: str) -> float:
        axis = self.axis(name)
        reg = axis.registers.feedback
        words = await self.link.read(axis.upstream, reg.address, 2, reg.table)
        return unpack_int32(words, reg.order) / axis.upstream_counts_per_pulse  # as reported

    async def wait_in_position(self, name: str, position_mm: float) -> None:
        """Until the status says in position (not moving) and feedback is at the target."""
        axis, s = self.axis(name), self.settings
        want = self.pulses(name, position_mm)
        loop = asyncio.get_running_loop()
        deadline = loop.time() + s.timeout_s
        in_position, moving, alarm = self.status_bits(name)
        word: int | None = None
        while True:
            done = True
            status = axis.registers.status
            if status is not None:
                word = (await self.link.read(axis.upstream, status.address, 1, status.table))[0]
                if alarm is not None and word >> alarm & 1:
                    raise MachineError(f"axis {name}: drive alarm (status {word:#06x}, bit "
                                       f"{alarm}: registers.status.alarm_bit)")  # fmt: skip
                if in_position is not None and not word >> in_position & 1:
                    done = False
                if moving is not None and word >> moving & 1:
                    done = False
            if done and abs(await self.feedback_pulses(name) - want) <= s.in_position_pulses:
                return
            if loop.time() > deadline:
                at = await self.feedback_pulses(name)
                unit = "°" if axis.rotary else " mm"
                bits = [(f"{what} bit {b} {'set' if word >> b & 1 else 'clear'}")
                        for what, b in (("in-position", in_position), ("moving", moving))
                        if b is not None and word is not None]  # fmt: skip
                seen = "" if word is None else f", status {word:#06x}" + "".join(
                    f", {b}" for b in bits)  # fmt: skip
                ready = ("the drive switched on (servo on, enable bits) and its "
                         "registers.trigger as it starts")  # fmt: skip
                if axis.profile is not None:
                    from ...profiles import PROFILES

                    ready = f"a {axis.profile} drive needs {PROFILES[axis.profile].before_moves}"
                raise MachineError(
                    f"axis {name}: not in position at {position_mm:g}{unit} after "
                    f"{s.timeout_s:g} s (feedback at {at * axis.pulse_mm:g}{unit}{seen}): "
                    f"never moved? {ready}; at the target? registers.status's "
                    "in_position_bit and moving_bit (or --in-position-bit, --moving-bit)")
            await asyncio.sleep(s.poll_s)

    async def still_at(self, targets_mm: Mapping[str, float]) -> None:
        """After a reading: each axis's feedback still at its target (within the
        in-position window). Else a MachineError, the reading not kept: something else
        moved the axis (a PLC or HMI on the gateway's other port wrote a target; a reading
        70 mm off its target was kept, and the fit refused the tables on every resume)."""
        for name, position in targets_mm.items():
            got = await self.feedback_pulses(name)
            want = self.pulses(name, position)
            if abs(got - want) > self.settings.in_position_pulses:
                axis = self.axis(name)
                unit = "°" if axis.rotary else " mm"
                raise MachineError(
                    f"axis {name}: at {got * axis.pulse_mm:g}{unit} when read, not at "
                    f"{position:g}{unit} where it was sent: another master (a PLC, an HMI) "
                    "moved it? Commissioning needs the machine to itself; that reading is not "
                    "kept")  # fmt: skip

    async def move(self, targets_mm: Mapping[str, float]) -> None:
        """All targets first, then each trigger (``on_trigger`` planar commit sees both)."""
        for name, position in targets_mm.items():
            await self.write_target(name, position)
        for name, position in targets_mm.items():
            await self.trigger(name)
            await self.wait_in_position(name, position)
        if self.clock is not None:
            await self.clock.refresh(self.link, self.config.status.upstream_unit)


# -- instruments ----------------------------------------------------------------------------
async def read_int32_mm(link: Link, unit: int, address: int, table: str = "input") -> float:
    return unpack_int32(await link.read(unit, address, 2, table), "hi_lo") / NM_PER_MM


def nearest_turn_deg(reading_deg: float, target_deg: float) -> float:
    """A turntable's angle read modulo 360, in the turn of ``target_deg`` (the reading
    within ±180° of it): the instrument counts within a turn, the drive counts turns."""
    return target_deg + ((reading_deg - target_deg + 180.0) % 360.0 - 180.0)


@dataclass
class TemperatureSensor:
    """A screw temperature sensor read as the config's thermal source reads it: its
    register (decoded by the gateway's own :func:`~gateway.sensors.decode_counts`) times
    ``scale_c`` (°C per count)."""

    link: Link
    unit: int
    register: SourceRegister
    scale_c: float = 0.01

    @classmethod
    def of_source(cls, link: Link, unit: int, source: ThermalSource) -> TemperatureSensor:
        """The sensor of a config's temperature source (its register and scale)."""
        return cls(link, unit, source.source_register, source.scale_c)

    async def read_c(self) -> float:
        from ...sensors import decode_counts

        reg = self.register
        return decode_counts(await self.link.read(self.unit, reg.address, reg.words, reg.table),
                             reg) * self.scale_c  # fmt: skip


@dataclass
class DeltaASensor:
    """Displacement sensor at the screw's reference point A: Δa in mm (int32 nm)."""

    link: Link
    unit: int
    address: int = 1

    async def read_mm(self) -> float:
        return await read_int32_mm(self.link, self.unit, self.address)
