"""A calibration session against a running gateway: plan run, and the seed-001 iteration.

Compensation off / on (decided here, documented in ``compgw calibrate --help``): the
runner does not switch the gateway. *Off* means the gateway it talks to runs an
identification config: the same config with the pitch tables, backlash, cyclic term, linkage
and planar model removed (``compgw calibrate --identify-config OUT.yaml -c CFG`` writes it;
thermal stays on when configured, so a long run's heating does not enter the tables). *On*
means the gateway runs the config whose tables are being verified. Iterating rewrites those
tables; the gateway must then reload them (SIGHUP: ``--reload-pid``, or ``--reload-cmd``, e.g.
``systemctl reload compgw``) before the next round. Talking straight to the drives (no
gateway) is also compensation off. The raw file records ``# compensation: off|on``.
"""

from __future__ import annotations

import copy
import time
from collections.abc import Awaitable, Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from ...config import GatewayConfig, ThermalSource
from ...config_types import read_yaml
from ...instruments.base import Instrument, InstrumentError
from ...instruments.spec import InstrumentSpec
from ..fitting.fit import planar_measurement
from ..fitting.outputs import (
    fit_pitch,
    fit_planar,
    residual_figures,
    save_pitch,
    save_planar,
)
from ..fitting.plane_frame import reframe_plane, save_frame
from ..plans.plans import Move, Plan
from ..plans.rawdata import RawData, read_raw_csv
from ..plans.runner import ProgressFn, RunSummary, run_plan
from .devices import DELTA_A_CHANNEL, open_device
from .from_file import enter_pressed, run_for_file
from .machine import (
    DeltaASensor,
    Endpoint,
    GatewayClock,
    Links,
    MachineDriver,
    MachineError,
    MotionSettings,
    TemperatureSensor,
    nearest_turn_deg,
)

ReloadFn = Callable[[], Awaitable[None]]


@dataclass
class Instruments:
    """Endpoints of the measuring devices (any may be None)."""

    laser: Endpoint | None = None
    laser_axes: Sequence[str] | None = None
    xy: Endpoint | None = None
    delta_a: Endpoint | None = None
    #: where the screw temperature sensors answer (registers and scale: the config's
    #: thermal sources); a warm-up records ``temperature_c`` of its axis's source
    temperature: Endpoint | None = None
    #: the angle instrument of rotary axes (the laser's layout in µdeg) and its channels
    angle: Endpoint | None = None
    angle_axes: Sequence[str] | None = None
    #: readings wait for the instrument's stable flag (see :class:`.machine.Laser`)
    wait_stable: bool = True
    #: instruments of another kind than Modbus, by role (laser, angle, xy, delta_a): a
    #: bridge, a gauge at the prompt (:mod:`.devices`)
    kinds: Mapping[str, InstrumentSpec] = field(default_factory=dict)
    #: how long compgw stands at each stop for a recording or a capture (s)
    dwell_s: float = 3.0
    #: before a recording's or capture's moves, wait for a line on stdin (Enter: the laser
    #: records); the CLI's ``--wait-start``, on by default at a terminal
    wait_start: bool = False

    def given(self, role: str) -> bool:
        """Whether an instrument of ``role`` was given, whatever its kind."""
        return getattr(self, role) is not None or role in self.kinds

    async def open(self, role: str, links: Links, *, order: Sequence[str], unit: str = "nm",
                   xy_axes: tuple[str, str] = ("X", "Y")) -> Instrument:  # fmt: skip
        """The instrument of ``role`` through the one interface (:mod:`.devices`)."""
        return await open_device(role, getattr(self, role), self.kinds.get(role), links,
                                 order=order, unit=unit, wait_stable=self.wait_stable,
                                 xy_axes=xy_axes)  # fmt: skip

    def laser_order(self, config: GatewayConfig) -> list[str]:
        """The laser's channels in order: ``laser_axes``, else the config's axes."""
        return list(self.laser_axes or config.axes)

    def angle_order(self, config: GatewayConfig) -> list[str]:
        """The angle instrument's channels: ``angle_axes``, else the config's rotary axes."""
        return list(self.angle_axes or [a for a, c in config.axes.items() if c.rotary])

    def __post_init__(self) -> None:
        """Two instruments given the same device (host, port, unit and first register) is
        a slip of the command line: the laser and the XY device of the simulator share one
        register layout, so a laser given the XY device's unit reads positions that follow
        the axes, and no later check can tell."""
        seen: dict[Endpoint, str] = {}
        for option, end in (("--laser", self.laser), ("--xy-device", self.xy),
                            ("--delta-a", self.delta_a), ("--temperature", self.temperature),
                            ("--angle", self.angle)):  # fmt: skip
            if end is None:
                continue
            if end in seen:
                raise ValueError(f"{seen[end]} and {option} name the same device "
                                 f"({end.host}:{end.port} unit {end.unit}): each instrument "
                                 "answers at its own unit id")  # fmt: skip
            seen[end] = option


@dataclass
class Session:
    """Gateway connection, motion settings and instruments of one calibration session."""

    config: GatewayConfig
    config_dir: Path
    gateway: Endpoint
    instruments: Instruments
    motion: MotionSettings = field(default_factory=MotionSettings)
    park: Mapping[str, float] = field(default_factory=dict)
    progress: ProgressFn | None = None
    dwell: Callable[[float], Awaitable[None]] | None = None
    #: told of every target written (axis, mm)
    on_move: Callable[[str, float], None] | None = None
    #: requests answered only on a later try (:data:`.machine.TRANSIENT_CODES`), all runs
    retried: int = 0
    #: a recording's readings less this (mm): the laser's zero kept across a commissioning's
    #: recordings (:func:`.from_file.run_for_file`); None: each recording's first stop
    datum_mm: float | None = None
    #: the machine's clock as the gateway shows it, read after each move: what the
    #: readings' ``time_s`` counts (None: the computer's)
    clock: GatewayClock | None = None
    #: the instruments a run opened (closed when it ends: a bridge's connection or child)
    _opened: list[Instrument] = field(default_factory=list, repr=False)

    async def run(self, plan: Plan, raw_path: Path, compensation: str) -> RunSummary:
        """Run ``plan`` into ``raw_path`` (resuming), measuring with the right instrument."""
        links = Links(self.motion.request_timeout_s)
        clock = time.time if self.clock is None else self.clock.now_s  # the readings' time
        try:
            link = await links.get(self.gateway.host, self.gateway.port)
            driver = MachineDriver(link, self.config, self.motion, self.clock)
            driver.on_move = self.on_move
            extra, names = None, ()
            if plan.kind == "warmup" and dict(plan.meta).get("sensor") == "none":
                pass  # heat from motion: the laser's readings alone
            elif plan.kind == "warmup" and self._warmup_reads_temperature(plan):
                extra, names = await self._temperature_fn(plan, links)
            elif plan.kind == "warmup" or self.instruments.given("delta_a"):
                extra, names = await self._delta_a_fn(links)
            elif self._stops_read_temperature(plan):
                extra, names = await self._temperature_fn(plan, links)
            later = self.instruments.kinds.get(self._role(plan))
            if later is not None and later.reads_later:  # from a recording or a capture
                if self.park:
                    await driver.move(dict(self.park))
                return await run_for_file(
                    plan, raw_path, later, driver.move, self.instruments.dwell_s,
                    {"compensation": compensation},
                    ready=enter_pressed if self.instruments.wait_start else None,
                    datum_mm=self.datum_mm, extra=extra, extra_names=names,
                    clock=clock)
            read = await self._measure_fn(plan, links)

            async def measure(move: Move) -> Mapping[str, float]:
                values = await read(move)  # then the axes still where they were sent:
                await driver.still_at(dict(zip(plan.axes, move.target_mm)))  # else not kept
                return values

            if self.park:
                await driver.move(dict(self.park))
            return await run_plan(
                plan, raw_path, driver.move, measure, extra=extra, extra_names=names,
                meta={"compensation": compensation}, progress=self.progress, dwell=self.dwell,
                clock=clock,
            )  # fmt: skip
        finally:
            self.retried += links.retried
            for dev in self._opened:
                await dev.close()
            self._opened.clear()
            links.close()

    def _role(self, plan: Plan) -> str:
        """Which instrument reads ``plan``: the angle instrument for rotary axes, the XY
        device for the plane, else the laser (the XY device when there is no laser)."""
        ins = self.instruments
        rotary = [a for a in plan.axes if a in self.config.axes and self.config.axes[a].rotary]
        if rotary and ins.given("angle"):
            return "angle"
        if len(plan.axes) == 2 and ins.given("xy"):
            return "xy"
        if ins.given("laser"):
            return "laser"
        if ins.given("xy"):
            return "xy"
        raise MachineError("no instrument: give --laser, --angle or --xy-device (or "
                           "--join FILE)")  # fmt: skip

    async def _measure_fn(self, plan: Plan, links: Links):  # type: ignore[no-untyped-def]
        ins = self.instruments
        planar = tuple(self.config.planar.axes) if self.config.planar else ("X", "Y")
        role = self._role(plan)
        if role == "angle":
            dev = await ins.open("angle", links, order=ins.angle_order(self.config),
                                 unit="udeg")  # fmt: skip
        elif role == "xy" and len(plan.axes) == 2:
            dev = await ins.open("xy", links, order=plan.axes, xy_axes=tuple(plan.axes))  # type: ignore[arg-type]
        elif role == "laser":
            dev = await ins.open("laser", links, order=ins.laser_order(self.config))
        else:
            dev = await ins.open("xy", links, order=planar, xy_axes=planar)  # type: ignore[arg-type]
        self._opened.append(dev)
        wraps = {a for a in plan.axes if a in self.config.axes and self.config.axes[a].wraps}

        async def measure(move: Move) -> Mapping[str, float]:
            try:
                values = dict(await dev.read_mm(plan.axes, dict(zip(plan.axes, move.target_mm))))
            except InstrumentError as exc:
                raise MachineError(str(exc)) from None
            for a, target in zip(plan.axes, move.target_mm):
                if a in wraps:
                    values[a] = nearest_turn_deg(values[a], target)
            return values

        return measure

    def _warmup_reads_temperature(self, plan: Plan) -> bool:
        """Whether a warm-up records its axis's screw temperature: its thermal source is a
        temperature sensor and one is given, or no Δa sensor is (with both sensors given,
        an axis warmed by temperature recorded the Δa column and its fit failed: 46 minutes
        of machine time lost, trial of issue 54)."""
        ins = self.instruments
        if ins.temperature is None:
            return False
        source = self._thermal_source(plan.axes[0])
        if source is not None:
            return source.kind == "temperature"
        return not ins.given("delta_a")

    def _thermal_source(self, axis: str) -> ThermalSource | None:
        """The thermal source ``axis``'s compensation reads, None without one (no thermal
        setting, heat from motion, or an axis not in the config)."""
        entry = self.config.axes.get(axis)
        thermal = None if entry is None else entry.compensation.thermal
        if thermal is None or not thermal.source:
            return None
        return self.config.thermal_sources.get(thermal.source)

    def _stops_read_temperature(self, plan: Plan) -> bool:
        """Whether a run of one axis records its screw's temperature at every stop (as ISO
        230-2 asks): a temperature sensor is given and the axis's thermal source is one.
        What the sensor's compensation took off each reading can then be given back, where
        heat from motion replaces the sensor later (rough-9's X at 1.5 x: its table read
        under a sensor that explained its growth to 3.5 µm RMS, the reversal 0.5-0.9 µm
        short mid-travel)."""
        if self.instruments.temperature is None or len(plan.axes) != 1:
            return False
        source = self._thermal_source(plan.axes[0])
        return source is not None and source.kind == "temperature"

    async def _temperature_fn(self, plan: Plan, links: Links):  # type: ignore[no-untyped-def]
        ep = self.instruments.temperature
        assert ep is not None
        thermal = self.config.axes[plan.axes[0]].compensation.thermal
        if thermal is None:
            raise MachineError(f"axis {plan.axes[0]}: no thermal source to warm up with")
        src = self.config.thermal_sources[thermal.source]
        sensor = TemperatureSensor.of_source(await links.get(*ep.key), ep.unit, src)

        async def extra(_: Move) -> Mapping[str, float]:
            return {"temperature_c": await sensor.read_c()}

        return extra, ("temperature_c",)

    async def _delta_a_fn(self, links: Links):  # type: ignore[no-untyped-def]
        ins = self.instruments
        if not ins.given("delta_a"):
            raise MachineError("a warm-up run needs the Δa sensor: --delta-a HOST:PORT:UNIT")
        if ins.delta_a is not None:  # Modbus: int32 nm at its address
            ep = ins.delta_a
            sensor = DeltaASensor(await links.get(*ep.key), ep.unit, ep.address or 1)
            read = sensor.read_mm
        else:  # any other kind: its channel "delta_a"
            dev = await ins.open("delta_a", links, order=(DELTA_A_CHANNEL,))
            self._opened.append(dev)

            async def read() -> float:
                try:
                    return (await dev.read_mm([DELTA_A_CHANNEL]))[DELTA_A_CHANNEL]
                except InstrumentError as exc:
                    raise MachineError(str(exc)) from None

        async def extra(_: Move) -> Mapping[str, float]:
            return {"delta_a_mm": await read()}

        return extra, ("delta_a_mm",)


# -- identification config ----------------------------------------------------------------------
def identify_config(path: Path) -> dict[str, Any]:
    """The config at ``path`` without pitch tables, backlash, cyclic term, linkage and planar
    model (thermal kept).

    Table paths are not needed by it; other relative paths stay valid when the result is
    written next to the original.
    """
    data = copy.deepcopy(read_yaml(path, ValueError))
    for axis in (data.get("axes") or {}).values():
        comp = axis.get("compensation") or {}
        comp.pop("pitch", None)
        comp.pop("backlash_mm", None)
        comp.pop("cyclic", None)
        comp.pop("linkage", None)
        axis["compensation"] = comp
    data.pop("planar", None)
    return data


def identify_config_text(path: Path) -> str:
    head = f"# identification config made from {path.name} by compgw calibrate: no pitch,\n"
    head += "# backlash, cyclic, linkage or planar compensation (thermal kept)\n"
    return head + yaml.safe_dump(identify_config(path), sort_keys=False)


# -- iteration (seed 001) -------------------------------------------------------------------------
@dataclass
class Round:
    number: int
    raw_path: Path
    figures: dict[str, dict[str, float | None]]  # axis → ISO figures; "XY" → max/rms vector
    #: the same on the verification plan (targets between the calibration targets)
    verify_path: Path | None = None
    verify_figures: dict[str, dict[str, float | None]] | None = None

    @property
    def judged(self) -> dict[str, dict[str, float | None]]:
        """What the tolerance is judged on: the verification targets when measured."""
        return self.figures if self.verify_figures is None else self.verify_figures


def planar_figures(raw: Path | RawData, axes: Sequence[str]) -> dict[str, float]:
    """Max and RMS vector error (µm) of an XY run (its file, or its data)."""
    import numpy as np

    data = read_raw_csv(raw) if isinstance(raw, Path) else raw
    meas = planar_measurement(data, tuple(axes))  # type: ignore[arg-type]
    norm = np.hypot(*meas.error_mm.T) * 1e3
    return {"max_um": float(norm.max()), "rms_um": float(np.sqrt(np.mean(norm**2)))}


def round_figures(plan: Plan, raw_path: Path) -> dict[str, dict[str, float | None]]:
    if len(plan.axes) == 2:
        return {"XY": dict(planar_figures(raw_path, plan.axes))}
    raw = read_raw_csv(raw_path)
    return {a: residual_figures(raw, a) for a in plan.axes}


def within(figures: dict[str, dict[str, float | None]], tolerance_um: float) -> bool:
    """Systematic error within tolerance: E of every axis (max vector error for XY)."""
    for name, f in figures.items():
        value = f.get("max_um") if name == "XY" else f.get("E_um")
        if value is None or value > tolerance_um:
            return False
    return True


def fold_round(session: Session, plan: Plan, raw_path: Path, comment: str) -> list[str]:
    """Fold a compensation-on run of the calibration plan into the tables; lines to print."""
    raw = read_raw_csv(raw_path)
    out: list[str] = []
    if len(plan.axes) == 2:
        meas = planar_measurement(raw, tuple(plan.axes))  # type: ignore[arg-type]
        res = fit_planar(meas, session.config, session.config_dir, residual=True)
        save_planar(res, comment)
        save_frame(res.points_path, None)  # folded unpinned: no fade to keep in line
        out.append(f"planar model {res.choice.kind} written to {res.model_path}")
        return out
    for a in plan.axes:
        res = fit_pitch(raw, session.config, session.config_dir, a, residual=True)
        save_pitch(res, comment)
        line = f"{a}: table folded into {res.path}"
        if res.backlash_mm is not None:
            line += f"; set axes.{a}.compensation.backlash_mm: {res.backlash_mm:.6g}"
        out.append(line)
    if reframe_plane(session.config, session.config_dir):
        out.append("planar model re-expressed against the folded tables")
    return out


async def iterate(
    session: Session,
    plan: Plan,
    raw_stem: Path,
    rounds: int,
    tolerance_um: float,
    reload: ReloadFn,
    say: Callable[[str], None] = print,
    verification: Plan | None = None,
) -> list[Round]:
    """Seed 001: re-run ``plan`` with compensation on, fold, reload, until within tolerance.

    The tolerance is judged where the machine will be used: on ``verification`` (targets
    between the calibration targets, never used for fitting), measured every round into
    ``<stem>.round<r>.verify.csv``; only without one on the calibration targets (said so).
    Round r's calibration data goes to ``<stem>.round<r>.csv`` (resumable like any run) and
    is what is folded. At most ``rounds`` folds; the last round is a measurement only.
    """
    done: list[Round] = []
    if verification is None:
        say("no verification plan: the tolerance is judged at the calibration targets only")
    for r in range(rounds + 1):
        path = raw_stem.with_name(f"{raw_stem.stem}.round{r}.csv")
        await session.run(plan, path, "on")
        this = Round(r, path, round_figures(plan, path))
        say(f"round {r} at the calibration targets: " + format_figures(this.figures))
        if verification is not None:
            this.verify_path = path.with_name(f"{path.stem}.verify.csv")
            await session.run(verification, this.verify_path, "on")
            this.verify_figures = round_figures(verification, this.verify_path)
            say(f"round {r} between them (verification): "
                + format_figures(this.verify_figures))  # fmt: skip
        done.append(this)
        if within(this.judged, tolerance_um):
            say(f"round {r}: within {tolerance_um:g} µm: done")
            break
        if verification is not None and within(this.figures, tolerance_um):
            say(f"round {r}: within {tolerance_um:g} µm at the calibration targets but not "
                "between them: the table is too coarse for this screw; folding cannot help. "
                "Measure denser (smaller --step-mm) or add the cyclic stage (--cyclic)")
            break
        if r == rounds:
            say(f"round {r}: not within {tolerance_um:g} µm after {rounds} folds")
            break
        for line in fold_round(session, plan, path, f"folded with {path.name} (seed 001)"):
            say(f"round {r}: {line}")
        await reload()
    return done


def format_figures(figures: dict[str, dict[str, float | None]]) -> str:
    parts = []
    for name, f in figures.items():
        text = "  ".join(f"{k[:-3]} {v:.2f}" for k, v in f.items() if v is not None)
        parts.append(f"{name}: {text} µm")
    return "; ".join(parts)
