"""Commissioning's drift references: where the machine's thermal state is read between runs.

Two places per linear axis, read before and after each run (and across every config switch,
:meth:`.stager.Stager.use`), give each run's drift, which
:meth:`.steps.StepRunner.raw` takes off the readings; logged with the odometer, they
are what heat from motion is fitted to on an axis with no sensor
(:meth:`DriftRefs.fit_motion_heat`). A rotary axis has none: the laser sees no angle, and
its readings are taken as they are.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ...compensation import Chain, PitchTable
from ...compensation.errors import TableError
from ...config import GatewayConfig
from ..fitting.adaptive import thermal_mm
from ..fitting.fit import zeroed_at_origin
from ..measuring.from_file import STOP_TIME
from ..measuring.machine import GatewayClock
from ..measuring.session import Session
from ..plans.plans import Move, Plan
from ..plans.runner import read_raw_meta
from ..thermal.drift_shape import SweptHeat
from ..thermal.heat_fit import (
    MAX_RESIDUAL_SHARE,
    drift_left_um,
    heat_at_readings_m,
    least_growth_um,
    modelled_growth_um,
    motion_heat_fit,
)
from ..thermal.thermal_shape import NOISE_UM

#: how far (a factor) a zone warm-up's τ may lie from the drift references' own before
#: theirs stands (:meth:`DriftRefs.adopt_warmed_motion`)
TAU_AGREE = 2.0

if TYPE_CHECKING:
    from .axes import Axes
    from .record import Record

Say = Callable[[str], None]

#: readings of each drift reference per reading (their mean is the reference)
REF_REPEATS = 3
#: the drift is taken off an axis whose references vary by more than this many times what
#: their own scatter gives (see :meth:`DriftRefs.drift_stands_out`)
DRIFT_RATIO = 2.0
#: degrees of freedom the drift references' own scatter needs before it is used (one
#: reading of an axis's two references, REF_REPEATS each, gives 2 · (REF_REPEATS − 1))
MIN_REF_DOF = 4
#: how fast the swept travel behind a drift shape fades (s of machine time): a screw's
#: thermal time constant (the bench's warm-ups fit 960-1130 s)
MEMORY_S = 1000.0
#: heat from motion is fitted to a growth SEEN_X_SCATTER times the references' scatter,
#: and at least this (µm): see :meth:`DriftRefs.least_growth_um`
MIN_SEEN_UM = 1.0


class DriftRefs:
    """The drift references of a commissioning: read, logged in the record, and what they
    say about the machine's thermal state."""

    def __init__(self, axes: Axes, record: Record, say: Say) -> None:
        self.s = axes.s
        self.config = axes.config
        self.axes = axes
        self.record = record
        self.say = say
        self.read_here = False  # the references read by this process yet
        #: the machine's clock (the gateway's status unit shows it on a simulator), read
        #: after each move; the computer's clock where none is shown
        self.clock = GatewayClock()
        kept = record.state.get("swept_heat", {})
        record.swept.update({
            a: SweptHeat.from_json(kept[a]) if a in kept else
            SweptHeat.for_travel(axes.travel(a), MEMORY_S) for a in axes.ref_axes()})  # fmt: skip

    async def read_clock(self) -> None:
        """Read the machine's clock now (the gateway's status unit, where it shows one;
        else the computer's clock needs no reading)."""
        from ..measuring.machine import Links

        links = Links(self.s.motion.request_timeout_s)
        try:
            link = await links.get(self.s.gateway.host, self.s.gateway.port)
            await self.clock.refresh(link, self.config.status.upstream_unit)
        finally:
            links.close()

    async def measure_refs(self) -> dict[str, list[float]]:
        """Deviation (mm) of each commissioned axis at its two drift references (a rotary
        axis's are zero: the laser sees no angle, its readings are taken as they are)."""
        linear = self.axes.ref_axes()
        if self.off():  # none read, but the laser's channels checked once (the first thing)
            if linear and not self.recorded() and not self.record.state.get("channels_checked"):
                await self._read(linear, repeats=1)
                self.record.state["channels_checked"] = True
            linear = []
        if linear and self.recorded():
            out = await self._read_recorded(linear[0])
        else:
            out = await self._read(linear) if linear else {}
        out.update({a: [0.0, 0.0] for a in self.s.axes if a not in out})
        last = self.record.state.get("last_refs") or {}
        at_s = last.get("at_s") if linear and self.recorded() else self.clock.now_s()
        temps = await self.read_temperatures_c(self.sensor_axes()) if linear else {}
        self.record.state["last_refs"] = {"phase": self.record.state.get("phase"), "refs": out,
                                          "odometer_mm": self.odometer(), "at_s": at_s,
                                          "temperature_c": temps}  # fmt: skip
        return out

    def sensor_axes(self) -> list[str]:
        """The commissioned axes whose thermal setting is a temperature sensor, where the
        sensors' instrument is given (``--temperature``)."""
        if self.s.instruments.temperature is None:
            return []
        out = []
        for a in self.s.axes:
            th = self.config.axes[a].compensation.thermal
            src = None if th is None or th.source is None else \
                self.config.thermal_sources[th.source]  # fmt: skip
            if src is not None and src.kind == "temperature":
                out.append(a)
        return out

    async def read_temperatures_c(self, axes: Sequence[str]) -> dict[str, float]:
        """Each of ``axes``'s temperature sensor now (°C), as its thermal source reads it."""
        ep = self.s.instruments.temperature
        if ep is None or not axes:
            return {}
        from ..measuring.machine import Links, TemperatureSensor

        links = Links(self.s.motion.request_timeout_s)
        out: dict[str, float] = {}
        try:
            for a in axes:
                th = self.config.axes[a].compensation.thermal
                assert th is not None and th.source is not None
                src = self.config.thermal_sources[th.source]
                out[a] = await TemperatureSensor.of_source(await links.get(*ep.key), ep.unit,
                                                           src).read_c()  # fmt: skip
        finally:
            links.close()
        return out

    def ref_commands(self, cfg: GatewayConfig, chain: Chain) -> dict[str, dict[str, Any]]:
        """Per linear axis, what the gateway's config as loaded (``cfg``, its ``chain``)
        commands at its two drift references (mm; approached in +, the other plane axis
        parked, no thermal growth), every axis's command there, and its thermal setting:
        the stage a switch cannot be computed across, unless it is a temperature source
        (``sensor``: its correction is computed at the sensor's reading, see
        :func:`..fitting.adaptive.relinked_base`)."""
        out: dict[str, dict[str, Any]] = {}
        for a in self.axes.ref_axes():
            where = {o: [round(x / cfg.axes[o].pulse_mm)] for o, x in self.axes.park(a).items()}
            mm, every = [], []
            for x in self.axes.ref_positions(a):
                pulses = {**where, a: [round(x / cfg.axes[a].pulse_mm)]}
                cmd = chain.command_mm_batch(pulses, dict.fromkeys(pulses, 1))
                mm.append(float(cmd[a][0]))
                every.append({o: float(c[0]) for o, c in cmd.items()})
            th = cfg.axes[a].compensation.thermal
            out[a] = {"mm": mm, "thermal": repr(th), "commands_mm": every,
                      "source": None if th is None else th.source}
            src = None if th is None or th.source is None else cfg.thermal_sources[th.source]
            if src is not None and src.kind == "temperature" and th.profile is None:
                out[a]["sensor"] = [th.origin_mm, th.length_mm, th.gain, src.alpha_per_k,
                                    src.reference_c]  # fmt: skip
            if th is not None and th.motion is not None:  # heat from motion: its section
                out[a]["motion"] = {"origin_mm": th.origin_mm, "length_mm": th.length_mm,
                                    "gain": th.gain, "motion": th.motion.model_dump(),
                                    "profile": th.profile is not None}  # fmt: skip
        return out

    def modelled_growth_um(self, odometer_mm: dict[str, float], wall_s: float
                           ) -> dict[str, list[float]]:  # fmt: skip
        """Per axis whose loaded config corrects heat from motion (the last switch's
        ``ref_commands``), the growth it takes off at the references (µm) at a reading with
        this odometer (mm) and clock (s): the heat counted from the cold start through the
        drift log, as the gateway counts it from every move since it started (its
        MoveLog). What the references no longer read under that config."""
        sections = {a: cmds["motion"] for a, cmds in
                    (self.record.state.get("ref_commands") or {}).items() if cmds.get("motion")}
        if not sections:
            return {}
        odo, wall = self.log_clock()  # the log so far, and this reading
        odo = {b: [*v, odometer_mm.get(b, 0.0) / 1000.0] for b, v in odo.items()}
        wall = [*wall, wall_s]
        out: dict[str, list[float]] = {}
        for a, section in sections.items():
            heat = heat_at_readings_m(section["motion"], a, odo, wall)[-1:]
            out[a] = [float(g) for g in modelled_growth_um(
                section, heat, self.axes.ref_positions(a), self.axes.travel(a))[0]]
        return out

    # -- from the laser software's own recording or capture ----------------------------------
    def recorded(self) -> bool:
        """Whether the laser is read from its own software's file after the moves (a
        recording or capture): the references are then stops of the same recording as the
        runs around them (:meth:`.steps.StepRunner.step`), or a short one of their own."""
        spec = self.s.instruments.kinds.get("laser")
        return spec is not None and spec.reads_later

    def ref_moves(self, axis: str, run: int = 1, repeats: int = REF_REPEATS) -> list[Move]:
        """The moves of one reading of ``axis``'s references: each place approached in +
        from 1 mm below ``repeats`` times, a stop at each (what :meth:`_read` does live)."""
        out = []
        for x in self.axes.ref_positions(axis):
            for _ in range(repeats):
                out += [Move(run, 1, "takeup", (x - 1.0,)), Move(run, 1, "measure", (x,))]
        return out

    def take_recorded(self, axis: str, actual_mm: Sequence[float],
                      odometer_mm: dict[str, float] | None = None,
                      at_s: float | None = None) -> dict[str, list[float]]:
        """The references of ``axis`` from one reading's stops in a recording (positions,
        mm, in :meth:`ref_moves` order; ``at_s``: the wall clock at the last, s): kept as
        :meth:`measure_refs` keeps a live reading (their scatter pooled, the channel
        checked, their machine time counted)."""
        places = self.axes.ref_positions(axis)
        readings = np.asarray(actual_mm, dtype=np.float64).reshape(len(places), -1)
        out = {axis: self._kept(axis, [axis], [list(r - x) for x, r in zip(places, readings)])}
        out.update({a: [0.0, 0.0] for a in self.s.axes if a not in out})
        state = self.record.state
        state["refs_s"] = state.get("refs_s", 0.0) + self.refs_cost_s([axis],
                                                                      readings.shape[1])
        self.read_here = True
        state["last_refs"] = {"phase": state.get("phase"), "refs": out,
                              "odometer_mm": odometer_mm or self.odometer(),
                              "at_s": self.clock.now_s() if at_s is None else at_s}  # fmt: skip
        return out

    def session(self, park: dict[str, float] | None = None) -> Session:
        """A measuring session of this commissioning: every move on the odometer, a
        recording read at the laser's one zero (:meth:`keep_datum`)."""
        return Session(self.config, self.record.config_dir, self.s.gateway,
                       self.s.instruments, self.s.motion, park or {},
                       on_move=self.count_travel,
                       datum_mm=self.record.state.get("laser_datum_mm"),
                       clock=self.clock)  # fmt: skip

    def keep_datum(self, raw: Path) -> None:
        """The laser's zero, from the commissioning's first recording (its first stop):
        every later recording is read at it, so that the drift references of one
        recording and the next share their zero."""
        meta = read_raw_meta(raw)
        if "laser_datum_mm" not in self.record.state and "datum_mm" in meta:
            self.record.state["laser_datum_mm"] = float(meta["datum_mm"])

    def move_zero(self, axis: str, table: PitchTable) -> PitchTable:
        """A laser read from its software's file counts from wherever it was zeroed, so the
        first table fitted from it is off by the error there: absolute positions read
        wrong (smooth-1 through a capture: 4.4 µm low everywhere, off-grid RMS 4.5 µm
        against 0.19 through the Modbus laser), where E does not see it. Once per axis,
        the table is set to zero at the machine's zero (0 mm, or its end nearest it) and
        the laser's zero moved with it: every later reading, the drift base and the
        references last read, so that the drift references relink across config switches
        as before (a table shifted alone puts a false step there). Other lasers, rotary
        axes, and an axis done already: the table as it is."""
        spec = self.s.instruments.kinds.get("laser")
        moved = self.record.state.setdefault("zero_moved_mm", {})
        if spec is None or not spec.reads_later or self.axes.rotary(axis) or axis in moved:
            return table
        shift, table = zeroed_at_origin(table)
        state = self.record.state
        state["laser_datum_mm"] = float(state.get("laser_datum_mm") or 0.0) + shift
        for key in ("drift_base", "last_refs"):
            refs = (state.get(key) or {}).get("refs") or {}
            if axis in refs:
                refs[axis] = [v - shift for v in refs[axis]]
        moved[axis] = shift
        return table

    async def _read_recorded(self, axis: str) -> dict[str, list[float]]:
        """A reading of the references as a short recording of its own (``refs-NNN``):
        across a config switch, where no run's recording holds one."""
        from ..plans.rawdata import read_raw_csv

        count = int(self.record.state.get("refs_recordings", 0))
        raw = self.record.dir / "raw" / "recorded" / f"refs-{count + 1:03d}.csv"
        raw.parent.mkdir(parents=True, exist_ok=True)
        plan = Plan("drift-references", (axis,), tuple(self.ref_moves(axis)),
                    (("kind", "drift-references"), ("axis", axis)))  # fmt: skip
        # the other plane axis parked, as a live reading has it (Y's references read where X
        # stood read its straightness: 4.4 µm on smooth-0, and Y got no heat model)
        session = self.session(self.axes.park(axis))
        try:
            await session.run(plan, raw, "as loaded")
        finally:
            self.record.retried(session.retried)
        self.keep_datum(raw)
        data = read_raw_csv(raw)
        times = data.extra.get(STOP_TIME)
        out = self.take_recorded(axis, data.actual_mm, at_s=float(times[-1]) if times else None)
        self.record.state["refs_recordings"] = count + 1
        return out

    async def _read(self, axes: Sequence[str], repeats: int = REF_REPEATS
                    ) -> dict[str, list[float]]:  # fmt: skip
        """Deviation (mm) of each of ``axes`` at its two drift references, the mean of
        ``repeats`` approaches in + from 1 mm below (the other plane axis parked)."""
        from ...instruments.base import InstrumentError
        from ..measuring.machine import Links, MachineDriver, MachineError

        links = Links(self.s.motion.request_timeout_s)
        out: dict[str, list[float]] = {}
        cost = 0.0
        laser = None
        try:
            link = await links.get(self.s.gateway.host, self.s.gateway.port)
            driver = MachineDriver(link, self.config, self.s.motion, self.clock)
            driver.on_move = self.count_travel
            ins = self.s.instruments
            assert ins.given("laser")
            order = ins.laser_order(self.config)
            laser = await ins.open("laser", links, order=order)
            for a in axes:
                park = self.axes.park(a)
                if park:
                    await driver.move(park)
                places = []
                for x in self.axes.ref_positions(a):
                    readings = []
                    for _ in range(repeats):
                        await driver.move({a: x - 1.0})
                        await driver.move({a: x})
                        try:
                            reading = (await laser.read_mm([a], {a: x}))[a]
                        except InstrumentError as exc:
                            raise MachineError(str(exc)) from None
                        readings.append(reading - x)
                    places.append(readings)
                out[a] = self._kept(a, order, places)
                cost += self.refs_cost_s([a], repeats)
        finally:
            self.record.retried(links.retried)
            if laser is not None:
                await laser.close()
            links.close()
        self.record.state["refs_s"] = self.record.state.get("refs_s", 0.0) + cost
        self.read_here = True
        return out

    def _kept(self, axis: str, order: Sequence[str], places: Sequence[Sequence[float]]
              ) -> list[float]:  # fmt: skip
        """One reading of ``axis``'s references from the deviations (mm) of the stops at
        each place: their means, the stops' scatter pooled, the laser's channel checked."""
        devs = [float(np.mean(stops)) for stops in places]
        for stops in places:
            self.pool_ref_scatter(axis, stops)
        self.check_channel(axis, order, devs)
        return devs

    def check_channel(self, axis: str, order: Sequence[str], devs_mm: Sequence[float]) -> None:
        """The laser's reading for ``axis`` follows it between its two references (the
        first thing commissioning measures): within 5 % of how far the axis was sent, or
        the channels are not in the order given, or the beam is on another axis."""
        from ..measuring.machine import SetupError

        x0, x1 = self.axes.ref_positions(axis)
        sent = x1 - x0
        seen = sent + devs_mm[1] - devs_mm[0]
        if abs(seen - sent) > 0.05 * abs(sent):
            ratio = seen / sent if sent else 0.0
            scale = next((k for k in (10.0, 0.1, 2.0, 0.5, 4.0, 0.25, 100.0, 0.01)
                          if abs(ratio / k - 1.0) < 0.02), None)  # fmt: skip
            if scale is not None:  # the laser followed, by a round factor: the pulse
                pulse = self.config.axes[axis].pulse_mm
                raise SetupError(
                    f"axis {axis} moved {seen:.3f} mm by the laser while it was sent "
                    f"{sent:.3f} mm: {ratio:.3g} times as far, so axes.{axis}.pulse_mm "
                    f"{pulse:g} is likely {pulse * ratio:.3g} (the drive's units per mm, "
                    "its electronic gear); fix it in the config and start again")  # fmt: skip
            given = (f"--laser-axes {','.join(order)}" if self.s.instruments.laser_axes
                     else f"the config's axis order {','.join(order)}; --laser-axes sets it")
            raise SetupError(f"the laser's reading for axis {axis} (channel "
                             f"{list(order).index(axis) + 1}, by {given}) moved {seen:.3f} mm "
                             f"while {axis} was sent {sent:.3f} mm: give --laser-axes in the "
                             f"laser's channel order, and check its beam is on {axis}")  # fmt: skip

    def refs_unmoved(self) -> dict[str, list[float]] | None:
        """The drift references read last (mm), when this process read them and nothing has
        moved since, in the same config: a run's after-reading is then the next run's
        before-reading (the same thermal state: reading it again costs machine time and
        adds its own scatter). None otherwise (and after a resume: the machine may have
        been moved by hand)."""
        last = self.record.state.get("last_refs")
        if not (last and self.read_here):
            return None
        if last["phase"] != self.record.state.get("phase") \
                or last.get("odometer_mm") != self.odometer():  # fmt: skip
            return None
        return last["refs"]

    def refs_cost_s(self, axes: Sequence[str], repeats: int = REF_REPEATS) -> float:
        """Machine time (s) of one reading of the drift references of ``axes``: two places,
        ``repeats`` approaches each from 1 mm below (none where they are :meth:`off`)."""
        if self.off():
            return 0.0
        return len(axes) * 2 * repeats * (self.s.stop_s + 2.0 / self.s.speed_mm_s)

    def off(self) -> bool:
        """Whether the drift references are not read at all: a budget that holds a plain
        calibration's tables only without them (:meth:`.short.ShortBudget.refs_affordable`);
        every reading is then zero drift, and costs nothing."""
        return bool(self.record.state.get("refs_off"))

    def drift_now(self, refs: dict[str, list[float]]) -> dict[str, list[float]]:
        base = self.record.state["drift_base"]["refs"]
        return {a: [refs[a][k] - base[a][k] for k in (0, 1)] for a in self.s.axes}

    def drift_taken_off(self, axis: str) -> bool:
        """Whether ``axis``'s readings have the drift references' drift taken off: an axis
        with no thermal setting (heat from motion, fitted here, leaves what the references
        read), or one whose temperature sensor heat from motion replaces (the sensor's
        linear correction cannot follow a screw warm where its nut works, and the final
        config will not run it: what the references read across every switch is what the
        sensor's config leaves, see :func:`..fitting.adaptive.relinked_base`). An axis that keeps
        its sensor keeps what its compensation leaves, as it will in use."""
        if self.config.axes[axis].compensation.thermal is None:
            return self.drift_stands_out(axis)
        return not self.sensor_kept(axis)

    def sensor_kept(self, axis: str) -> bool:
        """Whether ``axis`` is read with its own sensor's compensation on, as it will run in
        use: a thermal setting of the user's that heat from motion does not replace. Its
        readings are then on one thermal level by that compensation (what it leaves is
        kept, :meth:`drift_taken_off`), and nothing else takes heat off them."""
        return self.config.axes[axis].compensation.thermal is not None \
            and self.replacing_motion(axis) is None  # fmt: skip

    def pool_ref_scatter(self, axis: str, readings_mm: Sequence[float]) -> None:
        """Pool the scatter of one drift reference's back-to-back readings (kept in the
        state as the sum of squares about their mean, mm², and its degrees of freedom)."""
        if len(readings_mm) < 2:
            return
        pooled = self.record.state.setdefault("ref_scatter", {}).setdefault(axis, [0.0, 0])
        r = np.asarray(readings_mm, dtype=np.float64)
        pooled[0] += float(np.sum((r - r.mean()) ** 2))
        pooled[1] += r.size - 1

    def ref_scatter_um(self, axis: str) -> float | None:
        """The scatter of one stop at the drift references of ``axis`` (µm), pooled over
        their back-to-back readings (no drift between them); None before MIN_REF_DOF."""
        squares_mm2, dof = (self.record.state.get("ref_scatter") or {}).get(axis, (0.0, 0))
        if dof < MIN_REF_DOF or not squares_mm2 > 0:
            return None
        return 1e3 * float(np.sqrt(squares_mm2 / dof))

    def iso_scatter_um(self, axis: str) -> float | None:
        """The scatter of one stop of ``axis`` (µm): the ISO runs' pooled standard deviation,
        as the reversal's choice measured it; None before the ISO runs are fitted."""
        ident = self.record.state.get("identify", {})
        s_um = (ident.get(f"reversal-{axis}") or {}).get("scatter_um")
        return float(s_um) if s_um is not None and np.isfinite(s_um) and s_um > 0 else None

    def drift_stands_out(self, axis: str) -> bool:
        """Whether the drift references of ``axis`` have varied by more than their own
        scatter: the variance of their readings since commissioning began over the variance
        of one (s² over REF_REPEATS, s the scatter of their own back-to-back readings,
        :meth:`ref_scatter_um`, else the axis's ISO scatter) above DRIFT_RATIO. A drift that
        is only the references' scatter, taken off, adds it to every run: an offset and a
        tilt per run, and a reversal between a sweep's two passes (0.6-1.1 µm on slit-11361
        X and slit-11360-iso X, machines with no heat, 1.2-1.3 µm of scatter). The ISO
        scatter alone came too late: it is known once the ISO runs are fitted, so their
        first fit always took the drift off, and on a short budget, which fits them once,
        the tables kept it (mcu1025 Y: a tilt of ±1.2 µm over 41 mm, RMS at the points 1.33
        against 1.06 µm without). No scatter known yet: taken off."""
        s_um = self.ref_scatter_um(axis) or self.iso_scatter_um(axis)
        log = [e["drift_mm"][axis] for e in self.record.state.get("drift_log") or []
               if axis in e.get("drift_mm", {})]  # fmt: skip
        if s_um is None or len(log) < 3:
            return True
        spread_um2 = float(np.mean(np.var(np.asarray(log) * 1e3, axis=0)))
        return spread_um2 > DRIFT_RATIO * s_um**2 / REF_REPEATS

    def grown_um(self, axis: str) -> float:
        """The most ``axis``'s drift references have moved since commissioning began (µm)."""
        log = [e["drift_mm"][axis] for e in self.record.state.get("drift_log") or []
               if axis in e.get("drift_mm", {})]  # fmt: skip
        return 1e3 * float(np.abs(np.asarray(log, dtype=np.float64)).max(initial=0.0))

    def drift_spread_mm(self, axis: str) -> float | None:
        """How far the heat of ``axis``'s moves spreads along its screw (mm), where its zone
        warm-up showed the screw warm where its nut works (heat from motion, spread where it
        travelled, replaced its temperature sensor); None: the drift is taken as linear
        between the references (an evenly warm screw, or nothing measured to tell)."""
        spread = (self.replacing_motion(axis) or {}).get("profile") or {}
        return float(spread["spread_mm"]) if spread.get("spread_mm") else None

    def replacing_motion(self, axis: str) -> dict[str, Any] | None:
        """The heat-from-motion thermal section that replaces ``axis``'s temperature sensor
        (its zone warm-up's fit, :mod:`..thermal.warmup_heat`), or None."""
        ident = self.record.state.get("identify", {}).get(f"thermal-{axis}", {})
        return (ident.get("motion") or {}).get("config") or None

    def drift_shapes(self) -> dict[str, list[float]]:
        """The heat shape W of each axis whose drift follows it: a spread known, and no
        thermal compensation in the loaded config (the drift is then the growth itself)."""
        out = {}
        loaded = self.record.state.get("ref_commands") or {}
        for a, heat in self.record.swept.items():
            spread = self.drift_spread_mm(a)
            if spread is not None and (loaded.get(a) or {}).get("thermal") == "None":
                out[a] = heat.shape(spread)
        return out

    def count_travel(self, axis: str, x_mm: float) -> None:
        """The odometer: every target commissioning writes, per axis (mm); and where each
        screw was worked, the machine time taken as the move's travel at the
        commissioning speed and a stop."""
        odo = self.record.state.setdefault("odometer", {"mm": {}, "at": {}})
        last = odo["at"].get(axis)
        if last is not None:
            odo["mm"][axis] = odo["mm"].get(axis, 0.0) + abs(x_mm - last)
        odo["at"][axis] = x_mm
        seconds = (0.0 if last is None else abs(x_mm - last) / self.s.speed_mm_s) + self.s.stop_s
        for heat in self.record.swept.values():
            heat.elapse(seconds)
        if axis in self.record.swept:
            self.record.swept[axis].move_to(x_mm)

    def odometer(self) -> dict[str, float]:
        """Each commissioned axis's travel so far (mm)."""
        odo = self.record.state.get("odometer", {"mm": {}})["mm"]
        return {a: float(odo.get(a, 0.0)) for a in self.s.axes}

    def log_drift(self, drift: dict[str, list[float]],
                   odometer_mm: dict[str, float] | None = None,
                   wall_s: float | None = None,
                   temperature_c: dict[str, float] | None = None) -> None:
        """Keep the drift (mm, at both references) with the odometer and the wall clock when
        it was read (the last references' unless given: a recording's stops were read before
        its file came, minutes at a technician's pace): what heat from motion is fitted to.
        Where a temperature sensor was read with them (°C), what its compensation took off
        there since the cold start (:meth:`sensor_took_um`)."""
        last = self.record.state.get("last_refs") or {}
        odo = odometer_mm or last.get("odometer_mm") or self.odometer()
        if wall_s is None and odometer_mm is None:  # the last reading's own
            wall_s = last.get("at_s")
            temperature_c = last.get("temperature_c")
        wall = self.clock.now_s() if wall_s is None else wall_s
        entry: dict[str, Any] = {"odometer_mm": odo, "wall_s": wall, "drift_mm": drift}
        took = self.sensor_took_um(temperature_c or {})
        if took:  # with the readings, for what another gain would have taken
            entry["sensor_um"] = took
            entry["temperature_c"] = {a: temperature_c[a] for a in took}  # type: ignore[index]
        # the log is the growth since the cold start: under a config that corrects heat
        # from motion, the references read what it leaves; what it takes off is put back
        modelled = self.modelled_growth_um(odo, wall)
        if modelled:
            entry["drift_mm"] = {a: ([d + g / 1000.0 for d, g in zip(v, modelled[a])]
                                     if a in modelled else v) for a, v in drift.items()}
            entry["modelled_um"] = modelled
        self.record.state.setdefault("drift_log", []).append(entry)

    def sensor_model_um(self, axis: str, gain: float, temperature_c: float) -> list[float] | None:
        """What ``axis``'s temperature sensor at ``gain`` commands at its references at this
        reading (°C) since the cold start (µm): its config's section with another gain;
        None before the start's reading."""
        th = self.config.axes[axis].compensation.thermal
        t0 = (self.record.state.get("start_temperature_c") or {}).get(axis)
        if th is None or th.source is None or t0 is None:
            return None
        src = self.config.thermal_sources[th.source]
        commands = {"mm": list(self.axes.ref_positions(axis)), "thermal": "sensor",
                    "sensor": [th.origin_mm, th.length_mm, gain, src.alpha_per_k,
                               src.reference_c]}  # fmt: skip
        now, cold = thermal_mm(commands, temperature_c), thermal_mm(commands, t0)
        assert now is not None and cold is not None
        return [1000.0 * (n - c) for n, c in zip(now, cold)]

    def sensor_took_um(self, temperature_c: dict[str, float]) -> dict[str, list[float]]:
        """Per axis whose loaded config corrects its temperature sensor's reading (the last
        switch's ``ref_commands``), how much its command at the references has changed
        since the cold start (µm) at these readings (°C): what its compensation took off
        the growth, which the references then no longer read."""
        loaded = self.record.state.get("ref_commands") or {}
        start = self.record.state.get("start_temperature_c") or {}
        out = {}
        for a, t_c in temperature_c.items():
            if a not in loaded or a not in start:
                continue
            now, cold = thermal_mm(loaded[a], t_c), thermal_mm(loaded[a], start[a])
            if now is not None and cold is not None:
                out[a] = [1000.0 * (n - c) for n, c in zip(now, cold)]
        return out

    def _logged(self, axis: str) -> tuple[dict[str, list[float]], list[float], list[list[float]]]:
        """The drift log as heat from motion is fitted to it and checked on: each
        commissioned axis's odometer (m), the clock (s), ``axis``'s drift at both
        references (µm)."""
        log = self.record.state.get("drift_log", [])
        return (*self.log_clock(), [[d * 1000.0 for d in e["drift_mm"][axis]] for e in log])

    def log_clock(self) -> tuple[dict[str, list[float]], list[float]]:
        """The drift log's odometer per commissioned axis (m) and clock (s), reading by
        reading."""
        log = self.record.state.get("drift_log", [])
        return ({b: [e["odometer_mm"].get(b, 0.0) / 1000.0 for e in log] for b in self.s.axes},
                [e["wall_s"] for e in log])

    def fit_motion_heat(self) -> None:
        """Heat from motion on every linear axis with no thermal setting of its own, fitted
        to the drift references read so far (once: later drift is what it leaves); a zone
        warm-up's model may replace it at the end (:meth:`adopt_warmed_motion`). Only their
        changes are fitted: the drift is counted from one reading at the cold start, whose
        own scatter is in every later one. Taken as zero, it put smooth-3's Y fixed end
        84 mm off (its near reference read 0.2 µm low all through) and Δa per metre 24 %
        low; fitted as a constant, 35 mm and 16 %."""
        for a in self.s.axes:
            axis = self.config.axes[a]
            key = f"motion-{a}"
            ident = self.record.state.setdefault("identify", {})
            if axis.compensation.thermal is not None or axis.rotary or key in ident:
                continue
            odometer_m, wall_s, growth_um = self._logged(a)
            try:
                fit = motion_heat_fit(
                    a, odometer_m, wall_s, growth_um, self.axes.ref_positions(a),
                    dict.fromkeys(self.s.axes, self.s.speed_mm_s), self.axes.travel(a),
                    self.least_growth_um(a), offset=True)  # fmt: skip
            except TableError as exc:
                ident[key] = {"fitted": False, "why": str(exc)}
                self.say(f"no heat-from-motion model: {exc}")
                continue
            self.record.tables.motion[a] = fit.config()
            ident[key] = {"fitted": True, **fit.config(), "growth_max_um": fit.growth_max_um,
                          "residual_rms_um": fit.residual_rms_um, "points": fit.points}
            self.say(f"{a}: no thermal sensor; heat from its own motion explains the drift "
                     f"({fit.growth_max_um:.1f} µm at most) to {fit.residual_rms_um:.2f} µm "
                     f"RMS: Δa {fit.delta_a_um_per_m:.3g} µm per metre of heat, tau "
                     f"{fit.tau_s:.0f} s, fixed end at {fit.origin_mm:.0f} mm")  # fmt: skip
        self.record.save()

    def least_growth_um(self, axis: str) -> float:
        """The growth (µm) ``axis``'s references must show before heat from motion is fitted
        to them: MIN_GROWTH_UM (or the tolerance, where tighter), down to what stands out of
        their own scatter (SEEN_X_SCATTER times it, at least MIN_SEEN_UM). Light pitch runs
        warm a screw little: at 1.5 x a plain calibration's time four Y screws grew 1.3-1.6
        µm while commissioning (their references' scatter 0.1-0.3 µm), no model was fitted,
        and 30 minutes of work on a zone of 40 % of the travel moved them 13-24 µm."""
        return least_growth_um(self.s.tolerance_um, self.ref_scatter_um(axis), MIN_SEEN_UM)

    def adopt_warmed_motion(self) -> None:
        """Each axis's zone warm-up model (no sensor, :meth:`.identify.IdentifySteps.
        heat_warm_ups`) in place of the one fitted to the drift references, where it holds
        on their drift: the whole commissioning's duty cycle, which it was not fitted on.
        Where the references have a model of their own, only where the two read the same
        τ within TAU_AGREE: a screw cools at one rate, and a warm-up shorter than it cannot
        tell it. (Random machine 3 at 1.0 h: a 4-minute warm-up read τ 294 s, the
        references τ 1040 s, the truth 1033 s; its model left 0.90 µm RMS of their 4.83 µm
        drift, under half. Adopted, it put X's table back to 1.54 µm of shape against the
        truth, 0.47 as fitted. The end-to-end test's X at 2.5 h: 511 s against 553 s.)"""
        ident = self.record.state.setdefault("identify", {})
        for a in self.s.axes:
            warm = ident.get(f"thermal-{a}") or {}
            if self.config.axes[a].compensation.thermal is not None or not warm.get("fitted") \
                    or (ident.get(f"motion-{a}") or {}).get("from") == "warm-up":  # fmt: skip
                continue
            if not self._warmup_holds(a, warm, *self._logged(a)):
                continue
            before = ident.get(f"motion-{a}") or {}
            tau_s = (warm["config"].get("motion") or {}).get("tau_s")
            own_tau_s = (before.get("motion") or {}).get("tau_s") if before.get("fitted") \
                else None  # fmt: skip
            if tau_s and own_tau_s and max(tau_s / own_tau_s, own_tau_s / tau_s) > TAU_AGREE:
                self.say(f"{a}: the drift references' own heat from motion stands: the "
                         f"warm-up read τ {tau_s:.0f} s, they {own_tau_s:.0f} s over the "
                         "whole commissioning; a screw cools at one rate")  # fmt: skip
                continue
            self.record.tables.motion[a] = warm["config"]
            ident[f"motion-{a}"] = {"fitted": True, "from": "warm-up", **warm["config"],
                                    "instead_of": before}  # fmt: skip
        self.record.save()

    def _warmup_holds(self, axis: str, warm: dict[str, Any], odometer_m: dict[str, list[float]],
                      wall_s: list[float], growth_um: list[list[float]]) -> bool:
        """Does the zone warm-up's heat from motion hold on the drift the commissioning's runs
        read before it (another duty cycle than its strokes)? It holds where it leaves at
        most MAX_RESIDUAL_SHARE of that drift, or under the noise where it grew too little
        to tell. Said either way, and kept in the identification results."""
        try:
            left = drift_left_um(axis, warm["config"], odometer_m, wall_s, growth_um,
                                 self.axes.ref_positions(axis), self.axes.travel(axis))
        except TableError:  # no drift read after it: nothing tells against it
            return True
        g = np.asarray(growth_um, dtype=np.float64).reshape(-1, 2)
        spread = float(np.sqrt(np.mean((g - g[0]) ** 2)))
        holds = left <= max(MAX_RESIDUAL_SHARE * spread, NOISE_UM)
        warm["drift_check"] = {"left_rms_um": left, "drift_rms_um": spread, "holds": holds}
        self.say(f"{axis}: the warm-up's heat from motion leaves {left:.2f} µm RMS of the "
                 f"{spread:.2f} µm its drift references read in the commissioning's runs"
                 + ("" if holds else ": it does not hold; the references' own fit is tried"))
        return holds
