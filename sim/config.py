"""The simulator's YAML config: pydantic models and a loader with one-line error messages.

Every key is validated (``extra="forbid"``); a bad file raises :class:`SimConfigError` whose
message names the YAML path, the value and the rule, e.g.
``sim.axes.X.registers.target.address: 70000 is not in 0..65535``.
Register vocabulary (``target``, ``feedback``, ``status``, ``trigger``) matches the gateway's
config so a gateway config can point at the simulated drives unchanged.
"""

from __future__ import annotations

import csv
import re
from pathlib import Path
from typing import Annotated, Literal

import numpy as np
import yaml
from pydantic import (
    AfterValidator,
    BaseModel,
    ConfigDict,
    Field,
    ValidationError,
    model_validator,
)

from sim.config_rotary import AngleConfig, SwingConfig, TurntableConfig
from sim.config_truth import (
    CyclicScrew,
    DeviationTable,
    LostMotionConfig,
    PlaneField,
    ScrewHeat,
    Settling,
    StickSlip,
)
from sim.profiles import DRIVE_PROFILES, TRIGGER_STYLES, profile_registers
from sim.truth import XYField, load_screw


class SimConfigError(ValueError):
    """A bad simulator config; ``str(err)`` is one line naming the YAML path."""


def _in_range(lo: int, hi: int):
    def check(value: int) -> int:
        if not lo <= value <= hi:
            raise ValueError(f"is not in {lo}..{hi}")
        return value

    return AfterValidator(check)


Address = Annotated[int, _in_range(0, 0xFFFF)]
UnitId = Annotated[int, _in_range(1, 247)]
Bit = Annotated[int, _in_range(0, 15)]
Word = Annotated[int, _in_range(0, 0xFFFF)]
PositiveFloat = Annotated[float, Field(gt=0)]
NonNegFloat = Annotated[float, Field(ge=0)]


class _Model(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


# ---------------------------------------------------------------- transports
class TcpConfig(_Model):
    """Modbus TCP listener; port 0 binds a free port (printed at start)."""

    host: str = "127.0.0.1"
    port: Annotated[int, _in_range(0, 65535)] = 5021


#: ``rtu.port`` value: the sim opens a new pseudo-terminal and prints its path
PTY_PORT = "pty"


class RtuConfig(_Model):
    """Modbus RTU on a serial port (a pty in tests; a pty ignores the baud rate)."""

    #: a serial device, or ``pty``: a new pseudo-terminal whose path ``compgw sim`` prints
    #: ("modbus rtu on /dev/pts/N"), for a master (the gateway) to open as its port
    port: str
    baudrate: PositiveFloat = 115200
    parity: Literal["N", "E", "O"] = "E"
    stopbits: Literal[1, 2] = 1
    bytesize: Literal[7, 8] = 8
    #: line silence the drives keep after a request before they reply, in s. 0: at once,
    #: faster than any real drive; 0.00175: a Modbus slave that finds the end of a request by
    #: t3.5 of silence (1.75 ms above 19200 baud), as the spec describes.
    reply_silence_s: Annotated[float, _in_range(0, 1)] = 0.0


# ---------------------------------------------------------------- drive registers
class TargetRegister(_Model):
    """Signed 32-bit target position in command pulses (holding registers)."""

    address: Address = 0x6201
    words: Literal[2] = 2
    order: Literal["hi_lo", "lo_hi"] = "hi_lo"


class FeedbackRegister(_Model):
    """Signed 32-bit motor-side position (semi-closed loop) = pulses x counts_per_pulse."""

    address: Address = 0x602A
    table: Literal["holding", "input"] = "holding"
    words: Literal[2] = 2
    order: Literal["hi_lo", "lo_hi"] = "hi_lo"
    counts_per_pulse: Annotated[int, Field(ge=1)] = 1


class StatusRegister(_Model):
    """Status word; each bit is optional (None = not reported)."""

    address: Address = 0x1003
    alarm_bit: Bit | None = 0
    enabled_bit: Bit | None = 1
    moving_bit: Bit | None = 2
    in_position_bit: Bit | None = 4
    homed_bit: Bit | None = 6


class TriggerRegister(_Model):
    """How a move starts: write of ``value``, any write (no value), or a rising ``rising_bit``.

    ``home_value`` (value-style only) starts homing instead of a move. ``table: coils``: the
    trigger is a coil (FC05/FC15); ``words: 2``: a 32-bit field, high word first. ``style``
    names a drive family's own start rules (sim/profiles.py, :data:`TRIGGER_STYLES`).
    """

    address: Address = 0x6002
    value: Word | None = 0x10
    rising_bit: Bit | None = None
    home_value: Word | None = 0x20
    table: Literal["holding", "coils"] = "holding"
    words: Literal[1, 2] = 1
    style: Literal[TRIGGER_STYLES] = "plain"  # type: ignore[valid-type]

    @model_validator(mode="after")
    def _one_style(self) -> TriggerRegister:
        if self.value is not None and self.rising_bit is not None:
            raise ValueError("give either value or rising_bit, not both")
        return self


class SpeedRegister(_Model):
    """Unsigned 16-bit speed; speed_mm_s = register x scale_mm_s (0 = the axis default)."""

    address: Address = 0x6203
    scale_mm_s: PositiveFloat = 1.0


class MemoryBlock(_Model):
    """Plain read/write holding registers (parameters the sim stores but does not act on)."""

    address: Address
    count: Annotated[int, Field(ge=1, le=0x10000)]


class EepromConfig(_Model):
    """EEPROM wear model: a counter of target writes that went to EEPROM.

    ``counter`` (uint32, high word first) counts target writes unless ``ram_only`` is set;
    writing ``ram_only_param.value`` to ``ram_only_param.address`` switches to RAM at run time
    (as Inovance H0C.13 = 0 does).
    """

    counter: MemoryBlock | None = None
    ram_only: bool = False
    ram_only_param: RamOnlyParam | None = None


class RamOnlyParam(_Model):
    """A parameter register; writing ``value`` keeps writes in RAM, anything else EEPROM."""

    address: Address
    value: Word = 0


EepromConfig.model_rebuild()


class DriveRegisters(_Model):
    """Register layout of one drive (default: Leadshine-like PR mode, see sim/README.md)."""

    target: TargetRegister = TargetRegister()
    feedback: FeedbackRegister = FeedbackRegister()
    status: StatusRegister = StatusRegister()
    trigger: TriggerRegister | None = TriggerRegister()
    speed: SpeedRegister | None = SpeedRegister()
    memory: tuple[MemoryBlock, ...] = (MemoryBlock(address=0x6200, count=8),)
    eeprom: EepromConfig = EepromConfig(counter=MemoryBlock(address=0x7F00, count=2))
    fc16_max_words: Annotated[int, Field(ge=1, le=123)] | None = None
    #: RTU: a request arriving less than this after the previous frame on the line is not
    #: seen (counted in the control block), as a drive that needs long silence behaves
    min_silence_s: NonNegFloat = 0.0

    @model_validator(mode="after")
    def _no_overlap(self) -> DriveRegisters:
        spans: list[tuple[str, int, int]] = [
            ("target", self.target.address, 2),
            ("status", self.status.address, 1),
        ]
        if self.feedback.table == "holding":
            spans.append(("feedback", self.feedback.address, 2))
        if self.trigger is not None and self.trigger.table == "holding":
            spans.append(("trigger", self.trigger.address, self.trigger.words))
        if self.speed is not None:
            spans.append(("speed", self.speed.address, 1))
        if self.eeprom.counter is not None:
            spans.append(("eeprom.counter", self.eeprom.counter.address, 2))
        for i, (name_a, a0, na) in enumerate(spans):
            if a0 + na - 1 > 0xFFFF:
                raise ValueError(f"{name_a} at {a0:#06x} runs past 0xFFFF")
            for name_b, b0, nb in spans[i + 1 :]:
                if a0 < b0 + nb and b0 < a0 + na:
                    raise ValueError(f"{name_a} ({a0:#06x}) overlaps {name_b} ({b0:#06x})")
        return self


class AxisConfig(_Model):
    """One simulated drive + axis."""

    unit: UnitId
    pulse_mm: PositiveFloat = 0.001
    travel_mm: tuple[float, float] = (0.0, 800.0)
    overtravel_mm: NonNegFloat = 1.0
    speed_mm_s: PositiveFloat = 100.0
    homed_at_start: bool = True
    profile: Literal[tuple(DRIVE_PROFILES)] | None = None  # type: ignore[valid-type]
    registers: DriveRegisters = DriveRegisters()

    @model_validator(mode="before")
    @classmethod
    def _profile_layout(cls, data: object) -> object:
        if isinstance(data, dict) and data.get("profile") in DRIVE_PROFILES:
            data = {**data, "registers": profile_registers(data["profile"], data.get("registers"))}
        return data

    @model_validator(mode="after")
    def _travel_order(self) -> AxisConfig:
        if not self.travel_mm[0] < self.travel_mm[1]:
            raise ValueError(f"travel_mm: {list(self.travel_mm)} must be [min, max], min < max")
        return self


# ---------------------------------------------------------------- the true machine
class PeriodicTerm(_Model):
    """amplitude * sin(2 pi x / period + phase): e.g. once-per-lead screw error."""

    amplitude_um: float
    period_mm: PositiveFloat
    phase_deg: float = 0.0


class PitchTable(_Model):
    """A measured error curve from CSV: columns position (mm) and error (um); blanks skipped."""

    path: str
    position_column: str = "position_mm"
    error_column: str = "error_um"
    scale: float = 1.0


class PitchConfig(_Model):
    """Pitch error (true - commanded, um) as a sum of the given terms.

    slope over travel, ``poly_um[k] * t**k`` with t = (x - travel_min)/travel_length in 0..1,
    periodic terms, and an interpolated table (constant beyond its ends).
    """

    slope_um_per_m: float = 0.0
    poly_um: tuple[float, ...] = ()
    periodic: tuple[PeriodicTerm, ...] = ()
    table: PitchTable | None = None


class ThermalConfig(_Model):
    """Screw heating: per metre travelled at ref speed; Newton cooling to ambient.

    Heat of a move = heat_K_per_m * distance_m * speed/ref_speed; spread over the move.
    Growth = alpha * (T - ambient) * (x - origin_mm): proportional from the fixed end.
    """

    alpha_per_K: float = 11.5e-6
    origin_mm: float = 0.0
    heat_K_per_m: NonNegFloat = 0.0
    ref_speed_mm_s: PositiveFloat = 100.0
    tau_s: PositiveFloat = 600.0
    ambient_C: float = 20.0


class AxisErrors(_Model):
    """The true errors of one axis (all optional; absent = perfect).

    The parametric terms (``pitch``, ``backlash_um``, ``thermal``) and the data-driven ones
    of :mod:`sim.config_truth` (``deviation``, ``lost_motion``, ``cyclic``, ``heat``) add
    up; ``stick_slip`` and ``settling`` act on every stop.
    """

    pitch: PitchConfig = PitchConfig()
    backlash_um: NonNegFloat = 0.0
    backlash_um_per_m: float = 0.0
    repeatability_um: NonNegFloat = 0.0
    thermal: ThermalConfig | None = None
    deviation: DeviationTable | None = None
    lost_motion: LostMotionConfig | None = None
    cyclic: CyclicScrew | None = None
    stick_slip: StickSlip | None = None
    settling: Settling | None = None
    heat: ScrewHeat | None = None
    #: rotary truths (sim/config_rotary.py): a swing axis through a linkage, a turntable
    swing: SwingConfig | None = None
    turntable: TurntableConfig | None = None

    @model_validator(mode="after")
    def _one_of_each(self) -> AxisErrors:
        if self.thermal is not None and self.heat is not None:
            raise ValueError("heat: give either thermal (one screw temperature) or heat "
                             "(a temperature profile), not both")  # fmt: skip
        if self.lost_motion is not None and (self.backlash_um or self.backlash_um_per_m):
            raise ValueError("lost_motion: give the play either as backlash_um or as "
                             "lost_motion, not both")  # fmt: skip
        if self.swing is not None or self.turntable is not None:
            kind = "swing" if self.swing is not None else "turntable"
            linear = ("deviation", "lost_motion", "cyclic", "thermal", "heat")
            if ((self.swing is not None and self.turntable is not None)
                    or any(getattr(self, k) is not None for k in linear)
                    or self.pitch != PitchConfig() or self.backlash_um
                    or self.backlash_um_per_m or self.repeatability_um):
                raise ValueError(f"{kind}: a rotary truth carries its own errors, play and "
                                 "repeatability: no pitch, backlash_um, repeatability_um, "
                                 "deviation, lost_motion, cyclic, thermal or heat beside it, "
                                 "and not both swing and turntable")  # fmt: skip
        dev, lm = self.deviation, self.lost_motion
        if dev is not None and dev.reverse_column and lm is not None and (lm.um or lm.table):
            raise ValueError("lost_motion: the deviation table's reverse column already "
                             "holds the lost motion (keep only lost_motion.takeup)")  # fmt: skip
        return self

    @property
    def data_driven(self) -> bool:
        """True when the axis' play and deviation come from data (the screw path)."""
        return any(v is not None for v in (self.deviation, self.lost_motion, self.cyclic))


class PlaneConfig(_Model):
    """XY plane errors between two axes (first = X, second = Y).

    squareness: X_true += (y - y_min) * tan(angle): positive = the Y axis leans towards +X.
    straightness_x_um: Y deviation bow over X travel (peak at mid travel, 0 at the ends).
    straightness_y_um: X deviation bow over Y travel.
    cross_um: X error = cross_um * tx * ty (tx, ty = normalised positions 0..1).
    """

    axes: tuple[str, str]
    squareness_arcsec: float = 0.0
    straightness_x_um: float = 0.0
    straightness_y_um: float = 0.0
    cross_um: float = 0.0
    #: a measured (ex, ey) field on grid nodes, added to the terms above (sim.config_truth)
    field: PlaneField | None = None


# ---------------------------------------------------------------- instruments
class LaserBridgeConfig(_Model):
    """The laser on the bridge line protocol (docs/instruments-bridge.md) over TCP.

    ``hang_after`` / ``garbage_after``: faults for tests, counted over the server's life:
    after N requests it stops answering (the connection stays open) / answers ``OK banana``.
    """

    host: str = "127.0.0.1"
    port: Annotated[int, _in_range(0, 65535)] = 0
    hang_after: Annotated[int, Field(ge=0)] | None = None
    garbage_after: Annotated[int, Field(ge=0)] | None = None


class LaserRecordingConfig(_Model):
    """The laser recording continuously, as CARTO's Dynamic capture does (sim/recorder.py)."""

    #: where ``rec-NNN.rtx|csv`` files go (relative to the sim config file)
    dir: str = "recordings"
    format: Literal["rtx", "csv"] = "rtx"
    #: the laser channel recorded (default: the laser's first channel)
    axis: str | None = None
    rate_hz: PositiveFloat = 200.0
    unit: Literal["um", "mm"] = "um"
    noise_um: NonNegFloat = 0.02
    #: while the axis moves: a sine of this amplitude at ``vibration_hz`` plus normal noise
    #: of half of it
    vibration_um: NonNegFloat = 0.3
    vibration_hz: PositiveFloat = 40.0
    #: after each stop: amplitude · e^(−t/ringing_s) · sin(2π · vibration_hz · t), ahead in
    #: the move's direction
    ringing_um: NonNegFloat = 3.0
    ringing_s: PositiveFloat = 0.05
    #: added to the CSV time column (the laser's clock is not the machine's)
    clock_offset_s: float = 0.0
    #: [start_s, end_s] of recording time left out of the file (a lost beam)
    drop_s: tuple[NonNegFloat, NonNegFloat] | None = None
    #: at time_scale 0, wall time while nothing moves is recorded as wall_s / idle_time_scale
    #: seconds of standstill (how a master's dwell shows in the recording)
    idle_time_scale: PositiveFloat = 0.02
    csv_columns: tuple[Literal["time", "value"], Literal["time", "value"]] = ("time", "value")
    #: the recording stops taking samples beyond this many (a capture's memory is finite)
    max_samples: Annotated[int, Field(ge=1)] = 5_000_000

    @model_validator(mode="after")
    def _checks(self) -> LaserRecordingConfig:
        if self.drop_s is not None and not self.drop_s[0] < self.drop_s[1]:
            raise ValueError(f"drop_s: {list(self.drop_s)} must be [start_s, end_s], start < end")
        if set(self.csv_columns) != {"time", "value"}:
            raise ValueError(f"csv_columns: {list(self.csv_columns)} must be [time, value] or "
                             "[value, time]")  # fmt: skip
        return self


class LaserConfig(_Model):
    """Laser interferometer: one int32 (nm) per axis, true table position."""

    unit: UnitId = 20
    axes: tuple[str, ...] | None = None
    resolution_um: PositiveFloat = 0.1
    noise_um: NonNegFloat = 0.0
    #: machine time one reading takes (averaging); at time_scale 0 each read advances the
    #: clock by it, so a master reading until stable lets a settling axis settle
    sample_s: NonNegFloat = 0.0
    #: a channel's stable flag (registers after the readings) is 1 once the axis is at
    #: rest and its ringing is within this band
    stable_band_um: PositiveFloat = 0.1
    #: the laser on the bridge line protocol over TCP (absent: no bridge server)
    bridge: LaserBridgeConfig | None = None
    #: continuous recording to .rtx / CSV files (absent: none)
    recording: LaserRecordingConfig | None = None


class XYConfig(_Model):
    """2-D measuring device (e.g. grid encoder): true X and Y, int32 nm each."""

    unit: UnitId = 21
    resolution_um: PositiveFloat = 0.1
    noise_um: NonNegFloat = 0.0
    sample_s: NonNegFloat = 0.0
    stable_band_um: PositiveFloat = 0.1


class DeltaAConfig(_Model):
    """Displacement sensor at reference point A (seed 002): reads the screw growth there."""

    unit: UnitId = 22
    axis: str
    a_mm: float
    resolution_um: PositiveFloat = 1.0
    noise_um: NonNegFloat = 0.0
    #: how it is mounted: 1 reads + when point A moves +; -1 when it moves − (a sensor at
    #: the low free end of a screw held at its high end reads elongation positive so)
    direction: Literal[1, -1] = 1


class TemperatureConfig(_Model):
    """Temperature sensors: one int16 per channel, 0.01 degC; channels = axis names or 'ambient'."""

    unit: UnitId = 23
    channels: tuple[str, ...] | None = None
    noise_C: NonNegFloat = 0.0
    #: where a screw channel sits along its screw (mm, axis coordinates); matters for a
    #: ``heat`` profile (default: the middle of the travel)
    positions_mm: dict[str, float] = Field(default_factory=dict)


class InstrumentsConfig(_Model):
    """Measuring instruments, each on its own unit id (absent = not simulated)."""

    laser: LaserConfig | None = None
    xy: XYConfig | None = None
    delta_a: DeltaAConfig | None = None
    temperature: TemperatureConfig | None = None
    angle: AngleConfig | None = None


class FaultsConfig(_Model):
    """The fault/control unit (holding registers; map in sim/faults.py)."""

    unit: Annotated[int, _in_range(1, 255)] = 250


# ---------------------------------------------------------------- root
class SimSection(_Model):
    """Everything under the top-level ``sim:`` key."""

    seed: int = 1
    time_scale: NonNegFloat = 0.0
    tcp: TcpConfig | None = None
    rtu: RtuConfig | None = None
    #: RTU frames (with CRC) inside TCP, as behind a serial device server in transparent
    #: mode; each connection is a line of its own; port 0 binds a free port (printed)
    rtu_over_tcp: TcpConfig | None = None
    axes: dict[str, AxisConfig]
    machine: dict[str, AxisErrors] = Field(default_factory=dict)
    plane: PlaneConfig | None = None
    instruments: InstrumentsConfig = InstrumentsConfig()
    faults: FaultsConfig = FaultsConfig()

    @model_validator(mode="after")
    def _cross_refs(self) -> SimSection:
        if not self.axes:
            raise ValueError("axes: at least one axis is needed")
        for name in self.machine:
            if name not in self.axes:
                raise ValueError(f"machine.{name}: no such axis (axes: {list(self.axes)})")
        if self.plane is not None:
            for name in self.plane.axes:
                if name not in self.axes:
                    raise ValueError(f"plane.axes: {name!r} is not an axis")
            if self.plane.axes[0] == self.plane.axes[1]:
                raise ValueError("plane.axes: the two axes must differ")
        units: dict[int, str] = {}

        def claim(unit: int, who: str) -> None:
            if unit in units:
                raise ValueError(f"{who}.unit: {unit} is already used by {units[unit]}")
            units[unit] = who

        for name, axis in self.axes.items():
            claim(axis.unit, f"axes.{name}")
        ins = self.instruments
        for key in ("laser", "xy", "delta_a", "temperature", "angle"):
            item = getattr(ins, key)
            if item is not None:
                claim(item.unit, f"instruments.{key}")
        claim(self.faults.unit, "faults")
        if ins.laser is not None and ins.laser.axes is not None:
            for name in ins.laser.axes:
                if name not in self.axes:
                    raise ValueError(f"instruments.laser.axes: {name!r} is not an axis")
        if ins.laser is not None and ins.laser.recording is not None:
            channels = ins.laser.axes if ins.laser.axes is not None else tuple(self.axes)
            rec_axis = ins.laser.recording.axis
            if rec_axis is not None and rec_axis not in channels:
                raise ValueError(f"instruments.laser.recording.axis: {rec_axis!r} is not a "
                                 f"laser channel ({', '.join(channels)})")  # fmt: skip
        if ins.angle is not None:
            for name in ins.angle.axes:
                if name not in self.axes:
                    raise ValueError(f"instruments.angle.axes: {name!r} is not an axis")
        if ins.xy is not None and self.plane is None:
            raise ValueError("instruments.xy: needs a plane (which axes are X and Y)")
        if ins.delta_a is not None:
            if ins.delta_a.axis not in self.axes:
                raise ValueError(f"instruments.delta_a.axis: {ins.delta_a.axis!r} is not an axis")
            errs = self.machine.get(ins.delta_a.axis)
            if errs is None or (errs.thermal is None and errs.heat is None):
                raise ValueError("instruments.delta_a: its axis has no machine thermal model")
        if ins.temperature is not None and ins.temperature.channels is not None:
            for ch in ins.temperature.channels:
                if ch != "ambient" and ch not in self.axes:
                    raise ValueError(f"instruments.temperature.channels: {ch!r} is not an axis")
        return self


class SimConfig(_Model):
    """The whole file; ``base_dir`` resolves relative paths (pitch tables)."""

    sim: SimSection
    base_dir: str = "."


# ---------------------------------------------------------------- loading
def _format_error(err: ValidationError) -> str:
    """First validation error as ``yaml.path: value rule``."""
    first = err.errors(include_url=False)[0]
    loc = ".".join(str(p) for p in first["loc"])
    msg = first["msg"].removeprefix("Value error, ")
    if first["type"] == "missing":
        return f"{loc}: missing (required)"
    if first["type"] == "extra_forbidden":
        return f"{loc}: unknown key"
    value = first.get("input")
    if isinstance(value, dict | list | tuple):
        # a model-level rule may name the key it is about: "axes.Y.unit: 1 is ..."
        head, sep, rest = msg.partition(": ")
        if sep and re.fullmatch(r"[\w.]+", head):
            return f"{loc}.{head}: {rest}"
        return f"{loc}: {msg}"
    if msg.startswith("is "):
        return f"{loc}: {value!r} {msg}"
    return f"{loc}: {value!r}: {msg[:1].lower()}{msg[1:]}"


def parse_config(data: object, base_dir: str | Path = ".") -> SimConfig:
    """Validate already-parsed YAML data; raise :class:`SimConfigError` on any problem."""
    if not isinstance(data, dict) or "sim" not in data:
        raise SimConfigError("sim: missing (the file needs a top-level 'sim:' key)")
    try:
        cfg = SimConfig.model_validate({**data, "base_dir": str(base_dir)})
    except ValidationError as err:
        raise SimConfigError(_format_error(err)) from None
    for name, errs in cfg.sim.machine.items():
        if errs.pitch.table is not None:
            try:
                load_pitch_table(errs.pitch.table, cfg.base_dir)
            except (OSError, ValueError, KeyError) as err:
                raise SimConfigError(f"sim.machine.{name}.pitch.table: {err}") from None
    try:
        check_truth_data(cfg.sim, cfg.base_dir)
    except ValueError as err:
        raise SimConfigError(str(err)) from None
    return cfg


def load_config(path: str | Path) -> SimConfig:
    """Read and validate a sim YAML file; raise :class:`SimConfigError` with one line."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as err:
        raise SimConfigError(f"{path}: cannot read ({err.strerror})") from None
    try:
        data = yaml.load(text, Loader=getattr(yaml, "CSafeLoader", yaml.SafeLoader))  # C if built
    except yaml.YAMLError as err:
        mark = getattr(err, "problem_mark", None)
        where = f" line {mark.line + 1}" if mark is not None else ""
        raise SimConfigError(f"{path}:{where} not valid YAML") from None
    return parse_config(data, path.parent)


def load_pitch_table(table: PitchTable, base_dir: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """Read (position_mm, error_um) sorted by position; rows with a blank cell are skipped."""
    path = Path(table.path)
    if not path.is_absolute():
        path = Path(base_dir) / path
    xs: list[float] = []
    es: list[float] = []
    with path.open(newline="", encoding="utf-8") as fh:
        reader = csv.DictReader(fh)
        for col in (table.position_column, table.error_column):
            if reader.fieldnames is None or col not in reader.fieldnames:
                raise ValueError(f"{path}: no column {col!r}")
        for row in reader:
            x, e = row[table.position_column].strip(), row[table.error_column].strip()
            if x and e:
                xs.append(float(x))
                es.append(float(e) * table.scale)
    if len(xs) < 2:
        raise ValueError(f"{path}: needs at least 2 rows with both values")
    order = np.argsort(xs)
    return np.asarray(xs)[order], np.asarray(es)[order]


def check_truth_data(sim: SimSection, base_dir: str | Path) -> None:
    """Load-time checks of the data-driven truth: every file readable, every rule that needs
    the data (a take-up distance against the largest play, a heated screw covering the
    travel). Raise ValueError (one line, with the YAML path) if a data file or rule fails."""
    for name, errs in sim.machine.items():
        where = f"sim.machine.{name}"
        lo, hi = sim.axes[name].travel_mm
        if errs.data_driven:
            key = "deviation" if errs.deviation else "lost_motion" if errs.lost_motion else "cyclic"
            try:
                screw = load_screw(errs.deviation, errs.lost_motion, errs.cyclic,
                                   errs.backlash_um, base_dir)  # fmt: skip
            except (OSError, ValueError, KeyError) as err:
                raise ValueError(f"{where}.{key}: {err}") from None
            if errs.backlash_um_per_m:
                raise ValueError(f"{where}.backlash_um_per_m: not with data-driven lost motion "
                                 "(give lost_motion.table)")  # fmt: skip
            takeup = screw.takeup
            if takeup.distance_mm is not None:
                need_mm = takeup.factor * screw.largest_play_mm(lo, hi)
                if takeup.distance_mm < need_mm - 1e-9:
                    raise ValueError(
                        f"{where}.lost_motion.takeup.distance_um: {takeup.distance_mm * 1e3:g} "
                        f"is less than {takeup.factor:g} x the largest play "
                        f"({need_mm * 1e3 / takeup.factor:.2f} um): the table would move "
                        "against the motor")  # fmt: skip
        if errs.heat is not None and errs.heat.screw_mm is not None:
            s0, s1 = errs.heat.screw_mm
            if lo < s0 or hi > s1:
                raise ValueError(f"{where}.heat.screw_mm: {[s0, s1]} does not cover the travel "
                                 f"{[lo, hi]}")  # fmt: skip
    if sim.plane is not None and sim.plane.field is not None:
        try:
            XYField(sim.plane.field, base_dir)
        except (OSError, ValueError, KeyError) as err:
            raise ValueError(f"sim.plane.field: {err}") from None
    temp = sim.instruments.temperature
    if temp is not None:
        channels = temp.channels or (*sim.axes, "ambient")
        for ch in temp.positions_mm:
            if ch not in channels or ch == "ambient":
                raise ValueError(f"sim.instruments.temperature.positions_mm: {ch!r} is not a "
                                 "screw channel")  # fmt: skip
