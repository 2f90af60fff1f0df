"""The gateway's YAML config: pydantic models, the single source of truth of what a user sets.

Every error is one line naming the YAML path, the value and the rule, e.g.
``axes.X.registers.target.address: 70000 is not in 0..65535``. Unknown keys are errors.
Table paths are relative to the config file.
"""

from __future__ import annotations

import ipaddress
import math
import os
import re
import zlib
from pathlib import Path
from typing import Annotated, Any, Literal

from pydantic import Discriminator, Field, Tag, ValidationError, field_validator, model_validator

from .config_registers import (
    Registers,
)
from .config_types import (
    Address,
    Interval,
    Port,
    Positive,
    UnitId,
    WordOrder,
    in_range,
    read_yaml,
    validation_lines,
)
from .config_types import StrictModel as Model
from .config_types import path_error as _path_error
from .profiles import PROFILES, merge_defaults, profile_names


class ConfigError(ValueError):
    """A config that must not run; the message is one line naming the YAML path.
    ``lines``: every mistake found, one line each (``compgw check`` prints them all)."""

    def __init__(self, message: str, lines: list[str] | None = None) -> None:
        super().__init__(message)
        self.lines = lines or [message]


# -- upstream -------------------------------------------------------------------------------
class TcpListen(Model):
    """Modbus TCP server for the upper computer."""

    host: str = "127.0.0.1"
    port: Port = 502
    allow: list[str] = Field(default_factory=lambda: ["127.0.0.0/8", "::1/128"])
    max_connections: Annotated[int, in_range(1, 1024)] = 16
    #: a connection with no request for this long is closed (0: never)
    idle_timeout_s: float = Field(default=60.0, ge=0.0)
    #: a frame must be complete this long after its first byte, or its connection closes
    frame_timeout_s: float = Field(default=2.0, gt=0.0)

    @field_validator("allow")
    @classmethod
    def _networks(cls, value: list[str]) -> list[str]:
        for net in value:
            try:
                ipaddress.ip_network(net, strict=False)
            except ValueError:
                raise ValueError(f"{net!r} is not an IP network (like 127.0.0.0/8)") from None
        return value


# which member of a "word or list" union a value is for: errors then name the key, not
# pydantic's member type (the tags are in _UNION_TAGS)
def _units_tag(value: Any) -> str:
    return "<all>" if isinstance(value, str) else "<units>"


def _write_tag(value: Any) -> str:
    return "<ranges>" if isinstance(value, list) else "<flag>"


class TlsRole(Model):
    """What a client certificate's role may do (Modbus/TCP Security).

    ``units``: ``all`` (and broadcasts) or a list of upstream units. ``read``: FC01-04 and
    the other read-only functions. ``write``: ``true`` every write and every other function,
    ``false`` none, or ``[[first, last], ...]``: FC05/06/15/16/22/23 whose written addresses
    (holding registers or coils) all lie in these inclusive ranges.
    """

    units: Annotated[Annotated[Literal["all"], Tag("<all>")]
                     | Annotated[list[UnitId], Tag("<units>")], Discriminator(_units_tag)] = "all"
    read: bool = True
    write: Annotated[Annotated[bool, Tag("<flag>")]
                     | Annotated[list[tuple[Address, Address]], Tag("<ranges>")],
                     Discriminator(_write_tag)] = False

    @field_validator("write")
    @classmethod
    def _ranges(cls, value: bool | list[tuple[int, int]]) -> bool | list[tuple[int, int]]:
        if not isinstance(value, bool):
            for first, last in value:
                if first > last:
                    raise ValueError(f"[{first}, {last}] must be [first, last] with first <= last")
        return value


class TlsListen(TcpListen):
    """Modbus/TCP Security (MB-TCP-Security): the TCP listener's settings, over TLS >= 1.2
    with a client certificate verified against ``ca``; each request authorised by the
    certificate's role (``roles``; ``no_role`` for a certificate without one). Paths are
    relative to the config file."""

    port: Port = 802
    cert: str
    key: str
    ca: str
    roles: dict[str, TlsRole] = Field(default_factory=dict)
    no_role: Literal["refuse", "read_only"] = "refuse"


class SerialLine(Model):
    """An RS-485/RS-232 line: device path and serial settings."""

    port: str
    baudrate: Annotated[int, in_range(300, 4_000_000)] = 19200
    parity: Literal["N", "E", "O"] = "E"
    stopbits: Literal[1, 2] = 1
    bytesize: Literal[7, 8] = 8
    #: inter-frame silence: "spec" (Modbus: 3.5 characters, 1.75 ms above 19200 baud) or
    #: "exact" (3.5 characters at the real baud rate: 0.30 ms at 115200, if the drives cope)
    t35: Literal["spec", "exact"] = "spec"


class Upstream(Model):
    tcp: TcpListen | None = None
    tls: TlsListen | None = None
    rtu: SerialLine | None = None

    @model_validator(mode="after")
    def _one_at_least(self) -> Upstream:
        if self.tcp is None and self.tls is None and self.rtu is None:
            raise ValueError("needs tcp, tls, rtu or any of them together")
        if (self.tcp is not None and self.tls is not None and self.tls.port != 0
                and (self.tcp.host, self.tcp.port) == (self.tls.host, self.tls.port)):
            raise _path_error(("tls", "port"), self.tls.port, "is upstream.tcp's port too")
        return self


# -- downstream -----------------------------------------------------------------------------
class TcpEndpoint(Model):
    host: str
    port: Port = 502


class RtuOverTcp(Model):
    """RTU frames (with CRC, no MBAP header) inside a TCP connection: a serial device server
    in transparent mode. The serial settings are the RS-485 side's (set in the device
    server): they time the line's silence and the wire time of replies."""

    host: str
    port: Port = 502
    baudrate: Annotated[int, in_range(300, 4_000_000)] = 19200
    parity: Literal["N", "E", "O"] = "E"
    stopbits: Literal[1, 2] = 1
    bytesize: Literal[7, 8] = 8
    t35: Literal["spec", "exact"] = "spec"


class Bus(Model):
    """One drive-side bus: an RS-485 line (rtu), a Modbus TCP endpoint (tcp), or an RS-485
    line behind a serial device server (rtu_over_tcp)."""

    rtu: SerialLine | None = None
    tcp: TcpEndpoint | None = None
    rtu_over_tcp: RtuOverTcp | None = None
    timeout_s: float = Field(default=0.1, gt=0.0, le=10.0)
    retries: Annotated[int, in_range(0, 5)] = 1
    min_silence_s: float = Field(default=0.0, ge=0.0, le=1.0)
    #: after a broadcast on an RTU line, the time left to the drives before the next request
    #: (the serial-line spec's turnaround delay, typically 0.1-0.2 s)
    turnaround_s: float = Field(default=0.1, ge=0.0, le=2.0)

    @model_validator(mode="after")
    def _exactly_one(self) -> Bus:
        if sum(x is not None for x in (self.rtu, self.tcp, self.rtu_over_tcp)) != 1:
            raise ValueError("needs exactly one of rtu or tcp or rtu_over_tcp")
        return self


# -- axes -----------------------------------------------------------------------------------
class PitchFile(Model):
    """A pitch table file and how to interpolate it."""

    file: str
    format: Literal["csv", "linuxcnc0", "linuxcnc1"] = "csv"
    interpolation: Literal["linear", "smooth", "pchip"] = "linear"
    outside: Literal["hold", "taper"] = "hold"
    taper_mm: float = Field(default=0.0, ge=0.0)


class TravelProfile(Model):
    """Spread the Δa where the axis has been working instead of linearly from the fixed
    end (a screw warm only where the nut runs): the travel swept over each stretch, spread
    along the screw by ``spread_mm`` (about √(κτ): 100 mm for steel in air), older travel
    fading per ``memory_mm`` travelled since or per ``memory_s`` of the clock since (the
    screw's cooling time constant: after a pause the heat of old moves is gone), whichever
    fades it more. ``screw_mm``: the screw's two ends (axis mm), where its heat cannot go
    on and stays (a zone worked near an end warms that end); None: the heat spreads past
    the travel as if the screw ran on. Displacement (Δa) sources and ``motion`` only."""

    spread_mm: float = Field(default=100.0, gt=0.0, le=10_000.0)
    memory_mm: float = Field(default=100_000.0, gt=0.0)
    memory_s: float | None = Field(default=None, gt=0.0, le=1e6)
    bin_mm: float = Field(default=5.0, gt=0.0, le=100.0)
    screw_mm: tuple[float, float] | None = None

    @field_validator("screw_mm")
    @classmethod
    def _screw_ends(cls, v: tuple[float, float] | None) -> tuple[float, float] | None:
        if v is not None and not (math.isfinite(v[0]) and math.isfinite(v[1]) and v[0] < v[1]):
            raise ValueError(f"screw_mm: {list(v)} must be [low end, high end] in mm")
        return v


class MotionHeat(Model):
    """Δa without a sensor: from the heat the axis's own motion puts into its screw
    (:func:`~gateway.compensation.thermal.motion_heat_m`). ``delta_a_um_per_m``: Δa at
    ``length_mm`` per metre of travel whose heat is still in the screw; ``tau_s``: how fast
    that heat goes to the air; ``speeds_mm_s``: the axes whose moves take machine time and
    their speed (a move lasts at least travel/speed, so time passes with the moves even
    where the clock cannot see it; the wall clock counts pauses). Fitted by ``compgw
    commission`` from its drift references on an axis with no sensor; the screw is taken
    as cold when the gateway starts."""

    delta_a_um_per_m: float = Field(gt=0.0, le=1000.0)
    tau_s: float = Field(gt=0.0, le=1e6)
    speeds_mm_s: dict[str, Positive] = Field(default_factory=dict)


class AxisThermal(Model):
    """Thermal growth: Δa from a ``source`` in thermal_sources, or from ``motion``."""

    source: str | None = None
    motion: MotionHeat | None = None
    length_mm: Positive
    origin_mm: float = 0.0
    #: Δa used = gain × the source's Δa: the screw is not at the sensor's temperature (a
    #: temperature sensor on the nut housing, heat uneven along the screw); fitted by
    #: ``compgw commission --temperature`` from a warm-up
    gain: float = Field(default=1.0, gt=0.0, le=10.0)
    #: where the heat is, from the axis's own travel (see TravelProfile); off: linear
    profile: TravelProfile | None = None

    @model_validator(mode="after")
    def _one_source(self) -> AxisThermal:
        if (self.source is None) == (self.motion is None):
            raise ValueError("thermal: give either source (a sensor in thermal_sources) or "
                             "motion (Δa from the axis's own travel), not both or neither")
        return self


class TakeUp(Model):
    """How a reversal takes up the lost motion (gateway/compensation/takeup.py): the fraction
    of it shown after the table reversed by each of ``reversal_um`` from the other flank,
    nondecreasing and ending at 1. Fitted by ``compgw commission``; without it the whole
    lost motion is switched at a reversal (a dead band)."""

    reversal_um: list[float] = Field(min_length=2, max_length=64)
    fraction: list[float] = Field(min_length=2, max_length=64)


class Compensation(Model):
    pitch: str | PitchFile | None = None
    backlash_mm: float = Field(default=0.0, ge=0.0, le=1.0)
    backlash_table_direction: Literal["mean", "forward", "reverse"] = "mean"
    allow_backlash_with_bidirectional: bool = False
    takeup: TakeUp | None = None
    thermal: AxisThermal | None = None
    cyclic: str | None = None  # the cyclic-error file (lead, harmonics at stations)
    #: a swing axis's linkage file (rocking-block geometry, the control's scale): the
    #: kinematic stage after the pitch table (gateway/compensation/linkage.py)
    linkage: str | None = None
    max_correction_mm: float = Field(default=0.2, gt=0.0, le=5.0)
    enabled: bool = True

    @property
    def pitch_file(self) -> PitchFile | None:
        return PitchFile(file=self.pitch) if isinstance(self.pitch, str) else self.pitch


class Axis(Model):
    """One servo axis: its drive on a bus, its registers, its compensation.

    ``profile`` names a real drive's register defaults (``gateway.profiles``) that the other
    keys override one by one. ``fc16_max_words`` caps register blocks sent to the drive
    (longer ones are split, never inside the target pair); ``min_silence_s`` is extra line
    silence the drive needs around frames (applied to its whole bus);
    ``ram_setting_applied`` declares that the drive's keep-writes-in-RAM parameter is set.
    ``command_scale`` (k): the drive's electronic gear is set k times finer than the upper
    computer's pulse, so targets go to the drive in units of ``pulse_mm``/k and corrections
    land to a k-th of a pulse while the master keeps its own units.
    ``rotary``: positions in degrees (``pulse_mm``, ``travel_mm``, ``max_correction_mm``
    too); a turntable by default (tables modulo 360°, targets of any turn), or with
    ``wrap: false`` a swing axis whose angle stays within its travel.
    """

    bus: str
    unit: UnitId
    upstream_unit: UnitId | None = None
    profile: str | None = None
    pulse_mm: Positive
    rotary: bool = False
    wrap: bool | None = None
    travel_mm: Interval
    home_direction: Literal[1, -1] = 1
    registers: Registers
    fc16_max_words: Annotated[int, in_range(2, 123)] = 123
    min_silence_s: float = Field(default=0.0, ge=0.0, le=1.0)
    ram_setting_applied: bool = False
    command_scale: Annotated[int, in_range(1, 1000)] = 1
    compensation: Compensation = Field(default_factory=Compensation)

    @model_validator(mode="before")
    @classmethod
    def _profile_defaults(cls, data: Any) -> Any:
        if not isinstance(data, dict) or data.get("profile") is None:
            return data
        name = data["profile"]
        if name not in PROFILES:
            raise ValueError(f"profile: {name!r} is not one of {profile_names()}")
        return merge_defaults(PROFILES[name].defaults(), data)

    @model_validator(mode="after")
    def _fits_int32(self) -> Axis:
        farthest = max(abs(self.travel_mm[0]), abs(self.travel_mm[1]))
        units = farthest / self.pulse_mm * self.command_scale
        if units > 2**31 - 1 - 2**20:  # room for corrections on top
            raise ValueError(
                f"travel_mm {farthest:g} is {units:.3g} drive units at pulse_mm "
                f"{self.pulse_mm:g} and command_scale {self.command_scale}: more than a "
                "signed 32-bit target holds"
            )
        return self

    @model_validator(mode="after")
    def _rotary_kind(self) -> Axis:
        if self.wrap is not None and not self.rotary:
            raise _path_error(("wrap",), self.wrap, "needs rotary: true (a linear axis "
                              "never wraps)")  # fmt: skip
        comp = self.compensation
        if comp.linkage is not None and not (self.rotary and self.wrap is False):
            raise _path_error(("compensation", "linkage"), comp.linkage, "needs a swing axis "
                              "(rotary: true, wrap: false)")  # fmt: skip
        return self

    @property
    def wraps(self) -> bool:
        """A turntable: positions modulo 360° (rotary and not ``wrap: false``)."""
        return self.rotary and self.wrap is not False

    @model_validator(mode="after")
    def _feedback_scale_is_explicit(self) -> Axis:
        # no default is right for both kinds of feedback register once the gear changes,
        # and a wrong feedback scale would send the master after a position it is not at
        if self.command_scale > 1 and self.registers.feedback.upstream_counts_per_pulse is None:
            raise ValueError(
                f"command_scale {self.command_scale} needs "
                "registers.feedback.upstream_counts_per_pulse (the counts per pulse the upper "
                "computer reads: 1 if the register counts command units, else the encoder "
                "counts per upper-computer pulse)"
            )
        return self

    @property
    def upstream(self) -> int:
        return self.upstream_unit if self.upstream_unit is not None else self.unit

    @property
    def upstream_counts_per_pulse(self) -> float:
        """Feedback counts per upper-computer pulse, as reported to the master."""
        feedback = self.registers.feedback
        if feedback.upstream_counts_per_pulse is not None:
            return feedback.upstream_counts_per_pulse
        return feedback.counts_per_pulse


class Planar(Model):
    axes: tuple[str, str]
    model: str
    commit: Literal["on_trigger", "immediate"] = "on_trigger"


class SourceRegister(Model):
    address: Address
    table: Literal["holding", "input"] = "input"
    words: Literal[1, 2] = 1
    order: WordOrder = "hi_lo"
    signed: bool = True


class ThermalSource(Model):
    """A Δa source: a displacement sensor (scale_mm per count) or a temperature sensor.

    Readings are checked for plausibility (``range_mm``; a change faster than
    ``max_rate_mm_s`` plus ``noise_mm``, default two register counts, is rejected),
    smoothed, held for ``hold_s`` when lost, then ``fallback`` applies and the alarm is set.
    """

    bus: str
    unit: UnitId
    source_register: SourceRegister = Field(alias="register")
    kind: Literal["displacement", "temperature"] = "displacement"
    scale_mm: float = 0.001
    scale_c: float = 0.01
    alpha_per_k: float = 11.5e-6
    reference_c: float = 20.0
    poll_s: float = Field(default=1.0, gt=0.0, le=3600.0)
    smoothing: float = Field(default=0.3, gt=0.0, le=1.0)
    range_mm: Interval = (-0.5, 0.5)
    max_rate_mm_s: float = Field(default=0.01, gt=0.0)
    noise_mm: float | None = Field(default=None, ge=0.0)
    hold_s: float = Field(default=30.0, ge=0.0)
    fallback: Literal["hold", "zero", "disable"] = "hold"

    @model_validator(mode="after")
    def _scales(self) -> ThermalSource:
        if self.kind == "temperature" and not (self.alpha_per_k > 0 and self.scale_c != 0):
            raise ValueError("a temperature source needs alpha_per_k > 0 and scale_c != 0")
        if self.kind == "displacement" and self.scale_mm == 0:
            raise ValueError("scale_mm must not be 0")
        return self


class MachineClockSource(Model):
    """The machine's clock where it is not the computer's: a simulator's (``compgw sim``
    at ``time_scale: 0``, control unit 250, 0x0802-0x0803, ms). The gateway counts heat
    from motion and the travel profile's time by it (:mod:`gateway.machine_clock`)."""

    bus: str
    unit: Annotated[int, in_range(1, 255)]  # the sim's control unit is 250, above 247
    source_register: SourceRegister = Field(alias="register")
    scale_s: float = Field(default=0.001, gt=0.0)


class Status(Model):
    upstream_unit: UnitId = 247
    remote_control: bool = False


class Metrics(Model):
    """Prometheus endpoint: off unless ``port`` is set; loopback unless ``host`` says else."""

    host: str = "127.0.0.1"
    port: Port | None = None


class WriteProtect(Model):
    """Registers no master may write on an upstream unit: writes get exception 0x02."""

    unit: UnitId
    address: Address = 0
    count: Annotated[int, in_range(1, 65536)] = 65536
    table: Literal["holding", "coils"] = "holding"


class Passthrough(Model):
    """An upstream unit forwarded untouched to a unit on a bus."""

    bus: str
    unit: UnitId


class GatewayConfig(Model):
    upstream: Upstream
    buses: dict[str, Bus]
    axes: dict[str, Axis] = Field(default_factory=dict)
    planar: Planar | None = None
    thermal_sources: dict[str, ThermalSource] = Field(default_factory=dict)
    status: Status = Field(default_factory=Status)
    passthrough: dict[UnitId, Passthrough] = Field(default_factory=dict)
    metrics: Metrics = Field(default_factory=Metrics)
    write_protect: list[WriteProtect] = Field(default_factory=list)
    #: the machine's clock where it is not the computer's (a simulator): none, the computer's
    machine_clock: MachineClockSource | None = None
    #: where each axis's last target, command and direction are kept, so a restarted
    #: gateway (a crash, an update) carries on where the drives are; relative to the config
    #: file; best on tmpfs (``/run/compgw/state.json``); none: a restart starts afresh
    state_file: str | None = None

    @model_validator(mode="after")
    def _references(self) -> GatewayConfig:
        for name, axis in self.axes.items():
            _require(self.buses, axis.bus, ("axes", name, "bus"), "buses")
            thermal = axis.compensation.thermal
            if thermal is not None and thermal.motion is not None:
                for other in thermal.motion.speeds_mm_s:
                    _require(self.axes, other, ("axes", name, "compensation", "thermal",
                                                "motion", "speeds_mm_s", other), "axes")
            if thermal is not None and thermal.source is not None:
                path = ("axes", name, "compensation", "thermal", "source")
                _require(self.thermal_sources, thermal.source, path, "thermal_sources")
                if thermal.profile is not None and \
                        self.thermal_sources[thermal.source].kind != "displacement":
                    raise ValueError(f"axes.{name}.compensation.thermal.profile: needs a "
                                     "displacement (Δa) source; a temperature at one spot "
                                     "does not say how much the screw grew")  # fmt: skip
        for name, src in self.thermal_sources.items():
            _require(self.buses, src.bus, ("thermal_sources", name, "bus"), "buses")
        if self.machine_clock is not None:
            _require(self.buses, self.machine_clock.bus, ("machine_clock", "bus"), "buses")
        seen: dict[int, str] = {self.status.upstream_unit: "status.upstream_unit"}
        for name, axis in self.axes.items():
            _claim(seen, axis.upstream, f"axes.{name}")
        for unit, route in self.passthrough.items():
            _require(self.buses, route.bus, ("passthrough", unit, "bus"), "buses")
            _claim(seen, unit, f"passthrough.{unit}")
        if self.planar is not None:
            for i, name in enumerate(self.planar.axes):
                _require(self.axes, name, ("planar", "axes", i), "axes")
                if self.axes[name].rotary:
                    raise _path_error(("planar", "axes", i), name, "is a rotary axis")
            if self.planar.axes[0] == self.planar.axes[1]:
                raise _path_error(("planar", "axes"), list(self.planar.axes), "must differ")
        return self


def _require(mapping: dict[Any, Any], key: Any, path: tuple[Any, ...], what: str) -> None:
    if key not in mapping:
        names = ", ".join(map(str, mapping)) or "(none)"
        raise _path_error(path, key, f"is not one of {what}: {names}")


def _claim(seen: dict[int, str], unit: int, owner: str) -> None:
    if unit in seen:
        raise _path_error((owner,), unit, f"upstream unit already used by {seen[unit]}")
    seen[unit] = owner


_UNION_TAGS = frozenset({"str", "PitchFile", "<all>", "<units>", "<flag>", "<ranges>"})


def bus_silence_s(config: GatewayConfig, bus: str) -> float:
    """Line silence a bus needs: its own, or the longest any of its drives needs."""
    needs = [a.min_silence_s for a in config.axes.values() if a.bus == bus]
    return max([config.buses[bus].min_silence_s, *needs])


#: a drive unit above this (mm) leaves a rounding error worth a warning on a corrected axis
COARSE_UNIT_MM = 0.0005


def _loopback(host: str) -> bool:
    """Whether a listener's host is on loopback only (an address; "localhost")."""
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


#: how the first line of every config ``compgw commission`` makes the gateway run begins
COMMISSION_WRITTEN = "# written by compgw commission"
_COMMISSION_LINE = re.compile(re.escape(COMMISSION_WRITTEN)
                              + r" \((?P<phase>[\w ,-]+) config\): "
                              r"your own config is kept in (?P<original>.+)$")


def file_warnings(path: str | os.PathLike[str]) -> list[str]:
    """What the file itself says a user should know: a config ``compgw commission`` wrote
    for one of its phases (identification: compensation off on the axes it measures), left
    behind by a commissioning that stopped without putting the user's own back (a power
    loss, a kill)."""
    try:
        with open(path, encoding="utf-8") as f:
            first = f.readline().strip()
    except (OSError, UnicodeDecodeError):
        return []
    m = _COMMISSION_LINE.match(first)
    if m is None or m["phase"] == "full":
        return []
    return [f"{path}: compgw commission's {m['phase']} config, left by a commissioning that "
            f"did not finish (tables off or not yet verified): the same commission command "
            f"carries it on, or put your own config back ({m['original']})"]


#: the baud rates serial Modbus devices offer; anything else is most likely a typo
STANDARD_BAUDS = frozenset({1200, 2400, 4800, 9600, 14400, 19200, 38400, 57600, 76800, 115200,
                            128000, 230400, 250000, 460800, 500000, 921600, 1000000})


def corrects(config: GatewayConfig, name: str) -> bool:
    """Whether ``config`` gives axis ``name`` anything to correct (a table, backlash, take-up,
    heat, a cyclic term, a linkage, the plane): compensation "on" with none of them moves
    nothing."""
    comp = config.axes[name].compensation
    return (comp.pitch is not None or comp.backlash_mm > 0 or comp.takeup is not None
            or comp.thermal is not None or comp.cyclic is not None or comp.linkage is not None
            or (config.planar is not None and name in config.planar.axes))


def warnings(config: GatewayConfig) -> list[str]:
    """Things that load but a user should act on (EEPROM wear, unverified profiles, a
    plain port open beside Modbus/TCP Security, a baud rate no device offers)."""
    out = []
    up = config.upstream
    lines = [("upstream.rtu", up.rtu)] + [
        (f"buses.{n}.{kind}", getattr(b, kind)) for n, b in config.buses.items()
        for kind in ("rtu", "rtu_over_tcp")]  # fmt: skip
    for where, line in lines:
        if line is not None and line.baudrate not in STANDARD_BAUDS:
            out.append(f"{where}.baudrate: {line.baudrate} is no standard rate (9600, 19200, "
                       "38400, 57600, 115200, …): a typo? A line at the wrong rate answers "
                       "nothing, or garbage")  # fmt: skip
    if up.tls is not None and up.tcp is not None and not _loopback(up.tcp.host):
        out.append(f"upstream.tcp: plain Modbus/TCP on {up.tcp.host}:{up.tcp.port} beside "
                   "upstream.tls: anyone the allowlist lets in writes without a certificate; "
                   "leave it off or on loopback (docs/service-and-security.md, \"Securing "
                   "the gateway\")")  # fmt: skip
    moving = [n for n, a in config.axes.items()
              if a.compensation.thermal is not None and a.compensation.thermal.motion is not None]
    if moving and config.state_file is None:
        out.append(f"axes.{moving[0]}.compensation.thermal.motion without a state_file: a "
                   "restart of the gateway forgets the heat in the screw and corrects a warm "
                   "machine as a cold one until it has cooled; set state_file "
                   "(docs/configuration.md)")  # fmt: skip
    for name, axis in config.axes.items():
        unit_mm = axis.pulse_mm / axis.command_scale
        if corrects(config, name) and not axis.rotary and unit_mm > COARSE_UNIT_MM:
            out.append(
                f"axes.{name}: corrections land to whole drive units of {unit_mm * 1000:g} µm "
                f"(up to ±{unit_mm * 500:g} µm of rounding); gear the drive finer and set "
                "command_scale (docs/retrofit.md, \"Resolution first\")"
            )
        if axis.profile is None:
            continue
        profile = PROFILES[axis.profile]
        if profile.eeprom.writes_eeprom_by_default and not axis.ram_setting_applied:
            out.append(
                f"axes.{name}: a {axis.profile} drive writes every bus write to EEPROM by "
                f"default and compgw writes a target on every move: set "
                f"{profile.eeprom.ram_setting}, then ram_setting_applied: true"
            )
        if not profile.verified:
            out.append(f"axes.{name}: profile {axis.profile} is unverified: check {profile.check}")
        mine = axis.registers
        for key in ("target", "feedback", "trigger"):
            theirs = profile.axis["registers"].get(key) or {}
            have = getattr(mine, key)
            if have is not None and "address" in theirs and have.address != theirs["address"]:
                out.append(f"axes.{name}.registers.{key}: address {have.address:#06x} where "
                           f"the {axis.profile} profile has {theirs['address']:#06x}: a "
                           "registers block left from another drive beside the profile? "
                           "Remove it to take the profile's whole (docs/retrofit.md, \"A profile "
                           "replaces the registers\")")  # fmt: skip
    return out


def parse_config(data: Any, source: str = "<config>") -> GatewayConfig:
    """Validate already-parsed YAML data."""
    if not isinstance(data, dict):
        raise ConfigError(f"{source}: the top level must be a mapping (upstream, buses, axes…)")
    try:
        return GatewayConfig.model_validate(data)
    except ValidationError as exc:
        lines = [f"{source}: {line}" for line in validation_lines(exc, _UNION_TAGS,
                                                                    GatewayConfig)]
        more = f" (and {len(lines) - 1} more: compgw check lists them)" if len(lines) > 1 else ""
        raise ConfigError(lines[0] + more, lines) from None


def config_crc(path: str | Path) -> int:
    """CRC-32 of a config file's bytes (the status unit shows the loaded one's; 0 when it
    cannot be read)."""
    try:
        return zlib.crc32(Path(path).read_bytes())
    except OSError:
        return 0


def load_config(path: str | Path) -> GatewayConfig:
    """Read and validate a gateway config file; raises ConfigError with one line."""
    return parse_config(read_yaml(path, ConfigError), str(path))


def json_schema() -> dict[str, Any]:
    """The JSON schema of the config, generated from the models."""
    return GatewayConfig.model_json_schema()
