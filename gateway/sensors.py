"""Thermal sources: Δa from a displacement sensor or a screw temperature, polled over a bus.

Two layers, kept apart:

* :class:`ThermalFilter` is pure: it steps on ``(t_s, raw Δa mm or None)`` and decides what
  the correction may use (plausibility by range and rate, exponential smoothing, hold,
  alarm, fallback, recovery). No I/O, no clock of its own.
* :class:`ThermalSensor` reads one source over a :class:`~gateway.modbus.downstream.Bus` every
  ``poll_s`` and feeds the filter; :class:`SensorSet` runs all configured sources and
  answers "Δa for axis X" for the router.

States (:class:`ThermalState`):

* ``starting``: no trusted value yet. Δa = 0.0, the cold state, i.e. exactly no thermal
  correction: the machine moves as it would without the thermal stage, never with a
  guessed or stale growth.
* ``ok``: the last reading was accepted; Δa is the smoothed value.
* ``holding``: no accepted reading for less than ``hold_s``; the last smoothed value holds.
* ``alarm``: no accepted reading for ``hold_s`` or more (also from start-up: a sensor dead
  at boot raises the alarm after ``hold_s``). ``fallback`` applies: ``hold`` keeps the last
  good value (0.0 if there never was one), ``zero`` uses 0.0, ``disable`` turns thermal
  correction off (Δa is None).

Recovery: from ``holding`` one accepted reading suffices, because it passed the rate check
against the last good value (the value is continuous with what the axis was using). From
``starting`` or ``alarm`` there is no value to check against, so ``recover_count``
(default 3) consecutive in-range readings that agree with each other within the rate limit
are required: one stray reading after a dead stretch must not become the correction, and
a flapping sensor must not toggle the alarm bit at every poll. A reading that breaks the
rate limit there restarts the run from itself, so a source that really did change while it
was lost is accepted after ``recover_count`` polls instead of being locked out.

Rate limit: a reading is accepted when ``|x − x_ref| <= max_rate_mm_s·(t − t_ref) + noise_mm``
where ``x_ref`` is the last accepted reading and ``t_ref`` its time: after a long gap
proportionally more change is allowed. ``noise_mm`` covers quantisation and sensor noise
(default: two counts of the source register).

Temperature sources: the filter always works in millimetres of Δa. A temperature source
converts T to the Δa of a *reference length* ``L_ref`` (the longest axis fed by the
source; 1000 mm when no axis is given, then ``range_mm`` and ``max_rate_mm_s`` are per metre
of screw) with :func:`~gateway.compensation.delta_a_from_temperature`, so ``range_mm`` and
``max_rate_mm_s`` keep their meaning ("Δa of the screw must stay within"). Each axis then
converts the filtered temperature with its own ``length_mm``
(:meth:`ThermalSensor.delta_a_mm_for`); Δa is linear in T, so filtering at ``L_ref`` and
rescaling equals filtering each axis on its own. A displacement sensor measures Δa at its
point A, whose distance from the fixed end is by definition the axis's ``length_mm``
(seed 002): it is used unchanged.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from enum import IntEnum
from typing import Any, Literal

from .compensation import delta_a_from_temperature
from .config import Axis, AxisThermal, SourceRegister, ThermalSource
from .modbus.downstream import Bus
from .modbus.frames import (
    READ_HOLDING_REGISTERS,
    READ_INPUT_REGISTERS,
    ModbusError,
    build_read_request,
    exception_code,
    is_exception,
    parse_read_registers_response,
    unpack_int32,
)
from .thermal_travel import HeatFromMotion, MoveLog

log = logging.getLogger(__name__)

Fallback = Literal["hold", "zero", "disable"]
Verdict = Literal["accepted", "failed", "range", "rate"]

#: Reference length for a temperature source that no axis uses.
DEFAULT_REFERENCE_LENGTH_MM = 1000.0
DEFAULT_RECOVER_COUNT = 3


class ThermalState(IntEnum):
    """Source state; the integer is what the status unit reports."""

    STARTING = 0
    OK = 1
    HOLDING = 2
    ALARM = 3

    @property
    def label(self) -> str:
        return self.name.lower()


@dataclass(frozen=True)
class FilterSettings:
    """Plausibility, smoothing and loss handling of one source (mm of Δa, seconds)."""

    range_mm: tuple[float, float] = (-0.5, 0.5)
    max_rate_mm_s: float = 0.01
    smoothing: float = 0.3
    hold_s: float = 30.0
    fallback: Fallback = "hold"
    noise_mm: float = 0.0
    recover_count: int = DEFAULT_RECOVER_COUNT

    def __post_init__(self) -> None:
        lo, hi = self.range_mm
        if not lo < hi:
            raise ValueError(f"range_mm {self.range_mm} must be [low, high] with low < high")
        if not self.max_rate_mm_s > 0:
            raise ValueError(f"max_rate_mm_s {self.max_rate_mm_s} must be > 0")
        if not 0 < self.smoothing <= 1:
            raise ValueError(f"smoothing {self.smoothing} must be in (0, 1]")
        if self.hold_s < 0 or self.noise_mm < 0:
            raise ValueError("hold_s and noise_mm must be >= 0")
        if self.recover_count < 1:
            raise ValueError(f"recover_count {self.recover_count} must be >= 1")
        if self.fallback not in ("hold", "zero", "disable"):
            raise ValueError(f"fallback {self.fallback!r} must be hold, zero or disable")

    @classmethod
    def from_source(cls, source: ThermalSource, *, noise_mm: float = 0.0,
                    recover_count: int = DEFAULT_RECOVER_COUNT) -> FilterSettings:
        return cls(range_mm=tuple(source.range_mm),  # type: ignore[arg-type]
                   max_rate_mm_s=source.max_rate_mm_s, smoothing=source.smoothing,
                   hold_s=source.hold_s, fallback=source.fallback, noise_mm=noise_mm,
                   recover_count=recover_count)


@dataclass
class SensorCounters:
    """Monotonic counters for metrics and the status unit."""

    reads: int = 0  # steps (poll attempts)
    failures: int = 0  # no reading (bus down, timeout, device exception, bad reply)
    rejected_range: int = 0  # reading outside range_mm
    rejected_rate: int = 0  # reading changing faster than max_rate_mm_s
    accepted: int = 0  # readings that passed both checks

    @property
    def rejected(self) -> int:
        return self.rejected_range + self.rejected_rate


class ThermalFilter:
    """Pure decision logic of one thermal source; see the module docstring for the rules."""

    def __init__(self, settings: FilterSettings) -> None:
        self.settings = settings
        self.counters = SensorCounters()
        self._state = ThermalState.STARTING
        self._t0_s: float | None = None  # first step
        self._smoothed_mm: float | None = None  # published (smoothed) Δa
        self._last_good_t_s: float | None = None  # last accepted reading in trusted states
        self._ref_mm: float | None = None  # rate-check reference reading
        self._ref_t_s: float = 0.0
        self._run = 0  # consistent readings in the recovery run (starting/alarm)
        self._run_mm = 0.0  # smoothed value of the recovery run
        self.last_raw_mm: float | None = None  # last reading seen (diagnostics)

    # ------------------------------------------------------------------ outputs

    @property
    def state(self) -> ThermalState:
        return self._state

    @property
    def alarm(self) -> bool:
        return self._state is ThermalState.ALARM

    @property
    def smoothed_mm(self) -> float | None:
        """The last published smoothed Δa, whatever the state (None before the first)."""
        return self._smoothed_mm

    @property
    def delta_a_mm(self) -> float | None:
        """Δa the correction uses now; None = thermal correction off (fallback disable)."""
        if self._state in (ThermalState.OK, ThermalState.HOLDING):
            return self._smoothed_mm
        if self._state is ThermalState.STARTING:
            return 0.0
        fallback = self.settings.fallback
        if fallback == "disable":
            return None
        if fallback == "hold" and self._smoothed_mm is not None:
            return self._smoothed_mm
        return 0.0

    def alarm_due_s(self, t_s: float) -> float | None:
        """Seconds from ``t_s`` until a step with no accepted reading raises the alarm (0
        when due now); None in alarm already, or before the first step."""
        hold_s = self.settings.hold_s
        if self._state in (ThermalState.OK, ThermalState.HOLDING) and \
                self._last_good_t_s is not None:
            return max(0.0, self._last_good_t_s + hold_s - t_s)
        if self._state is ThermalState.STARTING and self._t0_s is not None:
            return max(0.0, self._t0_s + hold_s - t_s)
        return None

    # ------------------------------------------------------------------ stepping

    def step(self, t_s: float, raw_delta_a_mm: float | None) -> Verdict:
        """Feed one poll at time ``t_s``: a reading in mm, or None when the read failed."""
        s = self.settings
        self.counters.reads += 1
        if self._t0_s is None:
            self._t0_s = t_s
        self.last_raw_mm = raw_delta_a_mm
        verdict = self._classify(t_s, raw_delta_a_mm)
        if self._state in (ThermalState.OK, ThermalState.HOLDING):
            if verdict == "accepted":
                assert raw_delta_a_mm is not None and self._smoothed_mm is not None
                self._smoothed_mm += s.smoothing * (raw_delta_a_mm - self._smoothed_mm)
                self._trust(t_s, raw_delta_a_mm)
            else:
                assert self._last_good_t_s is not None
                if t_s - self._last_good_t_s >= s.hold_s:
                    self._enter_alarm()
                else:
                    self._state = ThermalState.HOLDING
        else:
            self._recovery_step(t_s, raw_delta_a_mm, verdict)
            if self._state is ThermalState.STARTING and t_s - self._t0_s >= s.hold_s:
                self._state = ThermalState.ALARM
        self._count(verdict)
        return verdict

    def _classify(self, t_s: float, raw_mm: float | None) -> Verdict:
        s = self.settings
        if raw_mm is None:
            return "failed"
        lo, hi = s.range_mm
        if not lo <= raw_mm <= hi:  # also rejects NaN
            return "range"
        if self._ref_mm is not None:
            allowed_mm = s.max_rate_mm_s * max(0.0, t_s - self._ref_t_s) + s.noise_mm
            if abs(raw_mm - self._ref_mm) > allowed_mm:
                return "rate"
        return "accepted"

    def _recovery_step(self, t_s: float, raw_mm: float | None, verdict: Verdict) -> None:
        """Starting/alarm: collect ``recover_count`` mutually consistent readings."""
        if raw_mm is None or verdict == "range":
            self._run = 0
            self._ref_mm = None
            return
        if verdict == "rate" or self._run == 0:  # (re)start the run from this reading
            self._run, self._run_mm = 1, raw_mm
        else:
            self._run += 1
            self._run_mm += self.settings.smoothing * (raw_mm - self._run_mm)
        self._ref_mm, self._ref_t_s = raw_mm, t_s
        if self._run >= self.settings.recover_count:
            self._smoothed_mm = self._run_mm
            self._trust(t_s, raw_mm)

    def _trust(self, t_s: float, raw_mm: float) -> None:
        self._state = ThermalState.OK
        self._last_good_t_s = t_s
        self._ref_mm, self._ref_t_s = raw_mm, t_s
        self._run = 0

    def _enter_alarm(self) -> None:
        self._state = ThermalState.ALARM
        self._ref_mm = None  # a new value must prove itself by a consistent run
        self._run = 0

    def _count(self, verdict: Verdict) -> None:
        c = self.counters
        if verdict == "accepted":
            c.accepted += 1
        elif verdict == "failed":
            c.failures += 1
        elif verdict == "range":
            c.rejected_range += 1
        else:
            c.rejected_rate += 1


# ---------------------------------------------------------------------- register decoding


class SensorReadError(ModbusError):
    """The source answered, but not with a usable value (exception, wrong length)."""


def read_request(register: SourceRegister) -> bytes:
    """FC03 (holding) or FC04 (input) request PDU for the source register."""
    fc = READ_HOLDING_REGISTERS if register.table == "holding" else READ_INPUT_REGISTERS
    return build_read_request(fc, register.address, register.words)


def decode_counts(words: Sequence[int], register: SourceRegister) -> int:
    """Raw integer of one or two register words (signedness, word order)."""
    if len(words) != register.words:
        raise SensorReadError(f"expected {register.words} register(s), got {len(words)}")
    if register.words == 2:
        return unpack_int32(words, register.order, signed=register.signed)
    value = words[0] & 0xFFFF
    if register.signed and value & 0x8000:
        value -= 0x10000
    return value


def decode_response(pdu: bytes, register: SourceRegister) -> int:
    """Raw integer of a read response PDU; :class:`SensorReadError` for an exception."""
    if is_exception(pdu):
        raise SensorReadError(f"device exception 0x{exception_code(pdu) or 0:02X}")
    return decode_counts(parse_read_registers_response(pdu), register)


# ---------------------------------------------------------------------- one source (I/O)


class ThermalSensor:
    """Polls one thermal source over a bus and filters it.

    ``reference_length_mm`` (temperature sources only): the screw length whose Δa the
    filter checks and smooths; see the module docstring. ``clock`` gives the filter's time
    (monotonic seconds); the poll interval itself is waited on the event loop.
    """

    def __init__(self, name: str, source: ThermalSource, bus: Bus, *,
                 reference_length_mm: float | None = None,
                 clock: Callable[[], float] = time.monotonic,
                 noise_mm: float | None = None,
                 recover_count: int = DEFAULT_RECOVER_COUNT) -> None:
        self.name = name
        self.source = source
        self.bus = bus
        self.clock = clock
        if source.kind == "temperature":
            if not source.alpha_per_k > 0:
                raise ValueError(f"thermal_sources.{name}.alpha_per_k must be > 0")
            length = reference_length_mm or DEFAULT_REFERENCE_LENGTH_MM
            if not length > 0:
                raise ValueError(f"{name}: reference_length_mm must be > 0")
            self.reference_length_mm: float | None = length
            count_mm = abs(source.scale_c) * source.alpha_per_k * length
        else:
            self.reference_length_mm = None
            count_mm = abs(source.scale_mm)
        if noise_mm is None:
            noise_mm = 2.0 * count_mm  # one count either way of quantisation, plus one
        self.filter = ThermalFilter(FilterSettings.from_source(
            source, noise_mm=noise_mm, recover_count=recover_count))
        self.last_error: str | None = None
        self._request = read_request(source.source_register)

    # ------------------------------------------------------------------ outputs

    @property
    def state(self) -> ThermalState:
        return self.filter.state

    @property
    def alarm(self) -> bool:
        return self.filter.alarm

    @property
    def counters(self) -> SensorCounters:
        return self.filter.counters

    @property
    def delta_a_mm(self) -> float | None:
        """Δa in use (temperature sources: at ``reference_length_mm``); None = off."""
        return self.filter.delta_a_mm

    @property
    def temperature_c(self) -> float | None:
        """Temperature in use (temperature sources only; None otherwise or when off)."""
        d = self.filter.delta_a_mm
        if d is None or self.reference_length_mm is None:
            return None
        return self.source.reference_c + d / (self.source.alpha_per_k * self.reference_length_mm)

    def delta_a_mm_for(self, length_mm: float) -> float | None:
        """Δa for an axis whose thermal length is ``length_mm``; None = correction off."""
        if self.reference_length_mm is None:
            return self.filter.delta_a_mm
        t_c = self.temperature_c
        if t_c is None:
            return None
        return delta_a_from_temperature(self.source.alpha_per_k, length_mm, t_c,
                                        self.source.reference_c)

    def to_delta_a_mm(self, counts: int) -> float:
        """Raw register value → Δa in mm (temperature: at the reference length)."""
        src = self.source
        if self.reference_length_mm is None:
            return counts * src.scale_mm
        return delta_a_from_temperature(src.alpha_per_k, self.reference_length_mm,
                                        counts * src.scale_c, src.reference_c)

    # ------------------------------------------------------------------ I/O

    async def read_delta_a_mm(self) -> float:
        """One read of the source; raises on any failure (bus, device, reply)."""
        reply = await self.bus.transact(self.source.unit, self._request,
                                        caller=("thermal", self.name))
        return self.to_delta_a_mm(decode_response(reply, self.source.source_register))

    async def poll_once(self) -> Verdict:
        """Read once and step the filter; never raises for a failed read."""
        try:
            raw: float | None = await self.read_delta_a_mm()
            self.last_error = None
        except (ModbusError, ValueError, OSError) as err:
            raw = None
            self.last_error = f"{type(err).__name__}: {err}"
            log.debug("thermal %s: read failed: %s", self.name, self.last_error)
        except Exception as err:  # a bug must not stop the polling: a failed read, logged
            raw = None
            self.last_error = f"{type(err).__name__}: {err}"
            log.exception("thermal %s: unexpected error while reading", self.name)
        before = self.filter.state
        verdict = self.filter.step(self.clock(), raw)
        self._log_transition(before, self.filter.state, verdict)
        return verdict

    async def run(self, stop_event: asyncio.Event) -> None:
        """Poll every ``poll_s`` until ``stop_event`` is set.

        A failed read is followed by a wait at least as long as it took, doubling with each
        failure in a row up to ``MAX_BACKOFF_S`` (:func:`failed_wait_s`): a silent device
        on a shared line leaves the line to the masters' requests, which queued behind
        each poll's timeout (a master's 0x0B came 2-3 × later than its bus's timeout); a
        bus that is down fails at once and is retried the same way: never a busy loop.
        """
        loop = asyncio.get_running_loop()
        poll_s = self.source.poll_s
        next_s = loop.time()
        failures = 0
        while not stop_event.is_set():
            started_s = loop.time()
            verdict = await self.poll_once()
            now_s = loop.time()
            next_s += poll_s
            failures = failures + 1 if verdict == "failed" else 0
            if failures:
                wait_s = failed_wait_s(poll_s, now_s - started_s, failures)
                due_s = self.filter.alarm_due_s(self.clock())
                if due_s is not None:  # the read that raises the alarm is not put off
                    wait_s = min(wait_s, max(poll_s, due_s + 1e-3))
                next_s = max(next_s, now_s + wait_s)
            if next_s < now_s:  # overran: restart the grid instead of catching up
                next_s = now_s + poll_s
            with contextlib.suppress(asyncio.TimeoutError):
                await asyncio.wait_for(stop_event.wait(), next_s - now_s)

    def _log_transition(self, before: ThermalState, after: ThermalState,
                        verdict: Verdict) -> None:
        if before is after:
            return
        why = self.last_error if verdict == "failed" else f"last reading {verdict}"
        if after is ThermalState.ALARM:
            now = self.delta_a_mm
            log.warning("thermal %s: ALARM (%s); fallback %s, Δa now %s", self.name, why,
                        self.source.fallback, "off" if now is None else
                        f"{now * 1000.0:.1f} µm")  # fmt: skip
        elif after is ThermalState.HOLDING:
            log.info("thermal %s: holding last value (%s)", self.name, why)
        else:
            log.info("thermal %s: %s, Δa %.4f mm", self.name, after.label,
                     self.delta_a_mm or 0.0)


# ---------------------------------------------------------------------- all sources


#: the longest wait between reads of a device that keeps failing (s), unless its poll_s
#: is longer: a recovered sensor is read again within it
MAX_BACKOFF_S = 10.0


def failed_wait_s(poll_s: float, took_s: float, failures: int) -> float:
    """The wait (s) after the ``failures``-th failed read in a row, which took ``took_s``:
    as long as it took, at least ``poll_s``, doubling with each failure after the first,
    at most ``MAX_BACKOFF_S`` (or ``poll_s``, or ``took_s``, where longer)."""
    base = max(poll_s, took_s)
    return max(base, min(base * 2.0 ** (failures - 1), MAX_BACKOFF_S))


class SensorSet:
    """All thermal sources of a config, and Δa per axis for the router."""

    def __init__(self, sensors: Mapping[str, ThermalSensor],
                 axis_thermal: Mapping[str, AxisThermal] | None = None, *,
                 motion_clock: Callable[[], float] | None = None) -> None:  # fmt: skip
        self.sensors = dict(sensors)
        self.axis_thermal: dict[str, AxisThermal] = {}
        #: axes whose Δa comes from their own motion (thermal.motion): their screw's heat
        self.motion: dict[str, HeatFromMotion] = {}
        #: every target since the start: where a model loaded later begins
        # (None: MoveLog's own default clock, the computer's)
        self.moves = MoveLog() if motion_clock is None else MoveLog(motion_clock)
        self.set_axis_thermal(axis_thermal or {})

    def set_axis_thermal(self, axis_thermal: Mapping[str, AxisThermal]) -> None:
        """Replace the axis → (source, length) map (config reload); checked first."""
        for axis, thermal in axis_thermal.items():
            if thermal.source is not None and thermal.source not in self.sensors:
                raise ValueError(f"axes.{axis}.compensation.thermal.source: "
                                 f"{thermal.source!r} is not a thermal source")
        self.axis_thermal = dict(axis_thermal)
        motion = {}
        for axis, thermal in axis_thermal.items():
            if thermal.motion is not None:  # the screw's heat survives a reload
                kept = self.motion.get(axis)
                motion[axis] = (kept if kept is not None and kept.motion == thermal.motion
                                else HeatFromMotion.from_log(axis, thermal.motion, self.moves))
        self.motion = motion

    def saved_heat(self) -> dict[str, dict[str, float]]:
        """Heat from motion per axis and when (epoch s), for the state file."""
        return {axis: {"heat_m": heat.heat_now_m(), "at_epoch_s": time.time()}
                for axis, heat in self.motion.items()}  # fmt: skip

    def carry_on_heat(self, saved: Mapping[str, Any]) -> None:
        """Take back :meth:`saved_heat` of an earlier process, cooled for the time since."""
        for axis, entry in saved.items():
            heat = self.motion.get(axis)
            try:
                if heat is not None:
                    heat.carry_on(float(entry["heat_m"]),
                                  time.time() - float(entry["at_epoch_s"]))  # fmt: skip
            except (KeyError, TypeError, ValueError) as exc:
                log.warning("axis %s: saved heat not used: %s", axis, exc)

    def moved(self, axis: str, x_mm: float) -> None:
        """The gateway sent ``axis`` to ``x_mm``: axes heated by motion count it."""
        self.moves.moved(axis, x_mm)
        for heat in self.motion.values():
            heat.moved(axis, x_mm)

    def set_axes(self, axes: Mapping[str, Axis]) -> None:
        """:meth:`set_axis_thermal` from the config's axes (reload)."""
        self.set_axis_thermal({name: ax.compensation.thermal for name, ax in axes.items()
                               if ax.compensation.thermal is not None})

    @classmethod
    def from_config(cls, sources: Mapping[str, ThermalSource], buses: Mapping[str, Bus], *,
                    axes: Mapping[str, Axis] | None = None,
                    clock: Callable[[], float] = time.monotonic,
                    motion_clock: Callable[[], float] | None = None) -> SensorSet:
        """One sensor per source on the caller's buses; temperature sources take the
        longest axis length that uses them as reference length. ``motion_clock`` times
        heat from motion (the machine's clock, :mod:`gateway.machine_clock`)."""
        sensors: dict[str, ThermalSensor] = {}
        lengths = {name: [ax.compensation.thermal.length_mm for ax in (axes or {}).values()
                          if ax.compensation.thermal is not None
                          and ax.compensation.thermal.source == name] for name in sources}
        for name, src in sources.items():
            if src.bus not in buses:
                raise ValueError(f"thermal_sources.{name}.bus: {src.bus!r} has no Bus")
            sensors[name] = ThermalSensor(name, src, buses[src.bus], clock=clock,
                                          reference_length_mm=max(lengths[name], default=None),
                                          noise_mm=src.noise_mm)
        out = cls(sensors, motion_clock=motion_clock)
        out.set_axes(axes or {})
        return out

    def __getitem__(self, name: str) -> ThermalSensor:
        return self.sensors[name]

    def __iter__(self) -> Iterator[str]:
        return iter(self.sensors)

    def __len__(self) -> int:
        return len(self.sensors)

    @property
    def alarm(self) -> bool:
        """True while any source is in alarm."""
        return any(s.alarm for s in self.sensors.values())

    def delta_a_mm_for(self, thermal: AxisThermal) -> float | None:
        """Δa for an axis thermal setting (its source, length and gain)."""
        if thermal.source is None:
            return None
        d = self.sensors[thermal.source].delta_a_mm_for(thermal.length_mm)
        return None if d is None else d * thermal.gain

    def axis_delta_a_mm(self, axis: str) -> float | None:
        """Δa for axis ``axis``; None when it has no thermal source or it is off.

        Shaped as the router's ``delta_a_mm`` callable."""
        thermal = self.axis_thermal.get(axis)
        heat = self.motion.get(axis)
        if heat is not None and thermal is not None:
            return heat.delta_a_mm() * thermal.gain
        return None if thermal is None else self.delta_a_mm_for(thermal)

    async def run(self, stop_event: asyncio.Event) -> None:
        """Poll every source until ``stop_event`` is set."""
        await asyncio.gather(*(s.run(stop_event) for s in self.sensors.values()))
