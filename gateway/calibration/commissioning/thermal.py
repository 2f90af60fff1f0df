"""``compgw commission``'s thermal identification: the warm-up of an axis with a thermal
source and what is fitted to it (called by :mod:`.identify`).

- a Δa sensor (``--delta-a``): the thermal length; over a zone (ZONE) with places read cold
  and warm inside and beyond it, also the linear spread or the travel profile
  (:mod:`..thermal.thermal_shape`) and how fast old zones fade (``memory_s``);
- a temperature source (``--temperature``): the thermal gain; over the zone, also whether
  the heat of the axis's own motion explains the growth clearly better than the sensor at
  one spot (:mod:`..thermal.warmup_heat`), in which case it replaces the sensor from the tables on;
- no sensor (no thermal setting): heat from the axis's own motion, its time constant, fixed
  end and shape read by the laser over the zone (:mod:`..thermal.warmup_motion`); the drift
  references of the whole commissioning check it on a duty cycle it was not fitted on
  (:meth:`.drift.DriftRefs.adopt_warmed_motion`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace
from typing import TYPE_CHECKING, Any

import numpy as np

from ...compensation.errors import CompensationError, TableError
from ...compensation.thermal import ThermalStage, delta_a_from_temperature
from ...formats import read_pitch_csv
from ..fitting.models import thermal_fit, thermal_gain_fit
from ..fitting.plans_scans import warmup_plan
from ..measuring.from_file import STOP_TIME
from ..plans.plans import (
    Plan,
    read_plan,
)
from ..plans.rawdata import RawData
from ..thermal.heat_fit import MIN_GROWTH_UM, sensor_and_motion_left_um, sensor_gives_way
from ..thermal.thermal_shape import thermal_shape_fit
from ..thermal.warmup_heat import readings_clock_s, warmup_heat_fit
from ..thermal.warmup_motion import warmup_motion_fit
from .drift import DRIFT_RATIO, REF_REPEATS

if TYPE_CHECKING:
    from .axes import Axes
    from .drift import DriftRefs
    from .record import Record

Say = Callable[[str], None]

#: a zone warm-up (a Δa or temperature sensor) cycles over this share of travel ...
ZONE = (0.3, 0.7)
#: ... and reads these places cold and warm: inside the zone and beyond it on both sides
ZONE_PLACES = (0.12, 0.22, 0.4, 0.5, 0.6, 0.78, 0.88)
#: the raw columns that time a warm-up's stops: a live reading's clock, or when a recorded
#: step's stop was stood at (its recording came later)
CLOCK_COLUMNS = ("time_s", STOP_TIME)
#: with no sensor, the references (the outermost places) are read every this many strokes:
#: each reading is a trip beyond both ends of the zone (at 5, a third of the warm-up's time)
HEAT_MEASURE_EVERY = 10


class ThermalSteps:
    """The thermal identification: which axes warm up, the warm-up plan and its fit."""

    def __init__(self, axes: Axes, record: Record, drift: DriftRefs, say: Say) -> None:
        self.s = axes.s
        self.config = axes.config
        self.axes = axes
        self.record = record
        self.drift = drift
        self.say = say

    def warms_up(self, axis: str) -> bool:
        """A warm-up identifies this axis's thermal setting: its length from a Δa sensor
        (--delta-a), or its gain from a temperature source (--temperature)."""
        kind = self.source_kind(axis)
        if kind is None:  # none, or heat from motion: no sensor to warm up with
            return False
        if kind == "temperature":
            return self.s.instruments.temperature is not None
        return self.s.instruments.given("delta_a")

    def heat_warms_up(self, axis: str) -> bool:
        """A zone warm-up read by the laser fits this axis's heat from motion: a linear axis
        with no thermal setting (no sensor), unless --no-heat-warmup."""
        th = self.config.axes[axis].compensation.thermal
        return self.s.heat_warmup and th is None and not self.axes.rotary(axis)

    def warmup_plan(self, axis: str, duration_s: float | None = None) -> Plan:
        """Cycling over the travel; read at the end farthest from the screw's fixed end
        (the thermal origin), where the growth is largest against the noise. With a Δa
        or temperature sensor, over the middle of the travel only (ZONE), the places read
        cold and warm too: is the growth linear from the fixed end, or where the nut
        worked? With no sensor (heat from motion), the same zone, its fixed end not known:
        the outermost places both read as references, every HEAT_MEASURE_EVERY strokes."""
        lo, hi = self.axes.travel(axis)
        margin = 0.05 * (hi - lo)
        th = self.config.axes[axis].compensation.thermal
        origin = th.origin_mm if th is not None else lo
        ref = hi - margin if abs(hi - origin) >= abs(lo - origin) else lo + 2 * margin
        pulse = self.config.axes[axis].pulse_mm
        places = [round((lo + f * (hi - lo)) / pulse) * pulse for f in ZONE_PLACES]
        zone = [lo + f * (hi - lo) for f in ZONE]
        duration_s = self.warmup_s(axis) if duration_s is None else duration_s
        if th is not None and th.source is not None:  # a Δa or temperature sensor
            return warmup_plan(axis, zone, self.s.speed_mm_s, duration_s, ref,
                               places_mm=places)  # fmt: skip
        if self.heat_warms_up(axis):
            return warmup_plan(axis, zone, self.s.speed_mm_s, duration_s, places[-1],
                               HEAT_MEASURE_EVERY, places_mm=places, also_mm=places[0],
                               sensor=False)  # fmt: skip
        return warmup_plan(axis, (lo + margin, hi - margin), self.s.speed_mm_s, duration_s,
                           ref)  # fmt: skip

    def warmup_s(self, axis: str) -> float:
        """How long ``axis``'s warm-up strokes (s of machine time): ``--warmup-min``, or
        the shorter one a short budget held for it
        (:meth:`.identify.IdentifySteps._hold_warm_ups`)."""
        return float((self.record.state.get("warmup_held") or {}).get(axis, {}).get(
            "duration_s", self.s.warmup_s))  # fmt: skip

    def fit(self, axis: str, raw: RawData) -> dict[str, float]:
        """The warm-up's fit: a Δa source's length, or a temperature source's gain."""
        th = self.config.axes[axis].compensation.thermal
        plan = read_plan(self.record.dir / "plans" / f"warmup-{axis}.plan")
        if th is None:
            return self._motion_fit(axis, raw, plan)
        src = self.config.thermal_sources[th.source]
        if src.kind == "temperature":
            g = thermal_gain_fit(raw, axis, th.origin_mm, src.alpha_per_k)
            self.record.tables.thermal_gain[axis] = g.gain
            self.say(f"{axis}: the screw grows {g.gain:.2f}× what its sensor's "
                     f"{g.temperature_rise_K:.2f} K predict: thermal gain {g.gain:.3f}")
            out = {"gain": g.gain, "growth_max_um": g.growth_max_um,
                   "residual_rms_um": g.residual_rms_um, "rise_K": g.temperature_rise_K}
            if dict(plan.meta).get("places_mm"):  # a zone warm-up: is motion the better model?
                out["motion"] = self._heat_instead(axis, raw, plan, th, src.alpha_per_k)
                if out["motion"].get("config"):
                    # a gain fitted to heat the sensor cannot place is wrong for the spread
                    # heat of the runs until the after-run: the configured one serves there
                    self.record.tables.thermal_gain[axis] = th.gain
                    out["gain_used"] = th.gain
            return out
        if dict(plan.meta).get("places_mm"):  # a zone warm-up: the shape too
            shape = thermal_shape_fit(raw, plan, axis, th, self.axes.travel(axis))
            self.record.tables.thermal_length_mm[axis] = shape.length_mm
            self.record.tables.thermal_profile[axis] = shape.profile()
            self.say(f"{axis}: after the zone warm-up the growth ({shape.growth_max_um:.1f} µm"
                     f" at most) is {'where the nut worked' if shape.profile() else 'linear'}"
                     f": the linear spread leaves {shape.linear_rms_um:.2f} µm RMS, the travel "
                     f"profile {shape.profile_rms_um:.2f}; thermal length "
                     f"{shape.length_mm:g} mm"
                     + (f"; the Δa rose with τ {shape.tau_s:.0f} s: old zones fade over it"
                        if shape.profile() and shape.tau_s else ""))  # fmt: skip
            return shape.summary()
        tf = thermal_fit(raw, axis, th.origin_mm, th.length_mm)
        self.record.tables.thermal_length_mm[axis] = float(tf.length_mm)
        return {"length_mm": tf.length_mm, "growth_max_um": tf.growth_max_um,
                "residual_rms_um": tf.residual_rms_um}

    def _motion_fit(self, axis: str, raw: RawData, plan: Plan) -> dict[str, Any]:
        """Heat from motion on an axis with no sensor, from its zone warm-up: kept in the
        identification results, and made the axis's thermal setting only where it holds on
        the drift references (:meth:`.drift.DriftRefs.adopt_warmed_motion`); otherwise
        the references' own fit stands."""
        try:
            mf = warmup_motion_fit(raw, plan, axis, self.axes.travel(axis),
                                   *self._travel_before_warmup(axis, raw, plan),
                                   clock=CLOCK_COLUMNS)  # fmt: skip
        except TableError as exc:
            self.say(f"{axis}: no heat from motion from the warm-up: {exc}; the drift "
                     "references' fit stands")  # fmt: skip
            return {"fitted": False, "why": str(exc)}
        # timed by the readings' own clock where it is the machine's: no speeds; else by
        # the plan's estimated speed, which its config's speeds then count
        config = mf.config(None if mf.timed else self._estimated_speeds(axis))
        self.say(f"{axis}: no thermal sensor; its zone warm-up grew {mf.growth_max_um:.1f} µm "
                 f"at most: heat from its own motion leaves {mf.rms_um:.2f} µm RMS at the "
                 f"places read warm ({'where it travelled' if mf.spread_mm else 'linear'}, "
                 f"tau {mf.tau_s:.0f} s, fixed end at {mf.origin_mm:.0f} mm)")  # fmt: skip
        return {"fitted": True, **mf.summary(), "config": config}

    def _estimated_speeds(self, axis: str) -> dict[str, float]:
        """The speeds (mm/s) a warm-up's model not timed by a clock counts moves by: its
        own axis at the plan's estimate (``--estimate-speed-mm-s``, its τ is in those
        seconds), each other axis at the ratio a drift references' fit found between the
        two (the axis's own first), else the estimate too. A sim at ``time_scale: 0``
        without a clock: random machine 7's X runs at 50 mm/s, its Y at 120; Y's model,
        counting X at 100, took a 25-minute X sweep for half that and read 7 µm."""
        est = self.s.speed_mm_s
        speeds = dict.fromkeys(self.s.axes, est)
        ident = self.record.state.get("identify") or {}
        fits = [ident.get(f"motion-{a}") or {} for a in (axis, *self.s.axes)]
        for fit in fits:
            found = ((fit.get("instead_of") or fit).get("motion") or {}).get("speeds_mm_s") or {}
            if axis not in found or len(set(found.values())) < 2:
                continue  # no ratio to this axis fitted there
            for b in self.s.axes:
                if b != axis and b in found and speeds[b] == est:
                    speeds[b] = est * float(found[b]) / float(found[axis])
        return speeds

    def _heat_instead(self, axis: str, raw: RawData, plan: Plan, th: Any,
                      alpha_per_k: float) -> dict[str, Any]:  # fmt: skip
        """Heat from its own motion in place of a temperature sensor at one spot, when it
        explains the zone warm-up clearly better: kept here (``config``) and put in place
        with the other motion models before the after-run (:meth:`motion_for_sensors`)."""
        try:
            hf = warmup_heat_fit(raw, plan, axis, th, alpha_per_k, self.axes.travel(axis),
                                 *self._travel_before_warmup(axis, raw, plan),
                                 clock=CLOCK_COLUMNS)  # fmt: skip
        except TableError as exc:
            return {"fitted": False, "why": str(exc)}
        out = hf.summary()
        # timed by the readings' clock: no speeds (as _motion_fit)
        config = hf.config(None if hf.timed else self._estimated_speeds(axis))
        if not hf.replaces_sensor:  # the drift references may tell otherwise (weigh_sensors)
            out["candidate"] = config
            return out
        self._replace_sensor(axis, out, config)
        self.say(f"{axis}: the heat of its own motion explains the zone warm-up "
                 f"({hf.growth_max_um:.1f} µm) to {hf.motion_rms_um:.2f} µm RMS where the "
                 f"sensor explains {hf.sensor_rms_um:.2f}: heat from motion (tau "
                 f"{hf.tau_s:.0f} s{', where it travelled' if hf.spread_mm else ''}) "
                 "will replace the sensor in the final config")  # fmt: skip
        return out

    def _replace_sensor(self, axis: str, motion: dict[str, Any], config: dict[str, Any]) -> None:
        """Heat from motion (``config``) to replace ``axis``'s temperature sensor: kept in its
        warm-up's results (``motion``) and put in place before the after-run
        (:meth:`motion_for_sensors`). Warm where it works (a spread): measured with the
        sensor off until then, so the drift its references read is the growth, taken off
        along that shape."""
        motion["config"] = config
        motion["replaces_sensor"] = True
        if (config.get("profile") or {}).get("spread_mm") \
                and axis not in self.record.tables.sensor_off:  # fmt: skip
            self.record.tables.sensor_off.append(axis)

    def weigh_sensors(self) -> None:
        """A temperature sensor its zone warm-up kept, weighed again on the drift references
        read since the commissioning began (the cold start, the other axes' identification,
        the cool-down: duty cycles neither model was fitted on). The growth there is what
        they read with what the sensor's compensation as loaded took off put back; what heat
        from motion and the sensor's model at its fitted gain leave of it decide, with the
        warm-up's own figures (:func:`..thermal.heat_fit.sensor_gives_way`). The sensor's
        model is computed at each reading's temperature: taken as what the config then
        loaded commanded, a reading with the sensor off (at the end of a warm-up) counted
        the whole growth against it, the sensors of three smooth machines lost by 2-7 µm RMS
        and were replaced, and the judge's work then left 0.8-1.8 µm of heat where they had
        left 0.2-0.3.
        Once, before the rounds: a choice the warm-up made on 0.02 µm of its own readings
        (rough-9 Y at 8 h: motion 0.36 µm RMS, the sensor 0.84, so by less than NOISE_UM)
        left 3.77 µm after the judge's 30 minutes of work, where the sensor's model
        corrected the wrong way."""
        ident = self.record.state.get("identify", {})
        log = self.record.state.get("drift_log", [])
        for a in self.s.axes:
            motion = (ident.get(f"thermal-{a}") or {}).get("motion") or {}
            if not motion.get("candidate") or motion.get("config") or "weighed" in motion:
                continue
            odometer_m, wall_s = self.drift.log_clock()
            drift_um = [[1000.0 * d for d in e["drift_mm"][a]] for e in log]
            applied = np.array([(e.get("sensor_um") or {}).get(a, [np.nan, np.nan])
                                for e in log], dtype=np.float64).reshape(-1, 2)  # fmt: skip
            # the sensor's model at its fitted gain (the one it would be kept with), at each
            # reading's temperature: also where the config then loaded had it off
            gain = float((ident.get(f"thermal-{a}") or {}).get("gain") or 1.0)
            model = np.array([self.drift.sensor_model_um(a, gain, e["temperature_c"][a])
                              if a in (e.get("temperature_c") or {}) else [np.nan, np.nan]
                              for e in log], dtype=np.float64).reshape(-1, 2)  # fmt: skip
            try:
                sensor_left, motion_left, n = sensor_and_motion_left_um(
                    a, motion["candidate"], odometer_m, wall_s, drift_um, applied, model,
                    self.axes.ref_positions(a), self.axes.travel(a))  # fmt: skip
            except TableError as exc:
                motion["weighed"] = {"why": str(exc)}
                continue
            scatter = self.drift.ref_scatter_um(a) or self.drift.iso_scatter_um(a) or 0.0
            noise_um = float(np.sqrt(DRIFT_RATIO * 2.0 * scatter**2 / REF_REPEATS))
            warm_m = float(motion.get("motion_rms_um", np.inf))
            warm_s = float(motion.get("sensor_rms_um", 0.0))
            why = sensor_gives_way(sensor_left, motion_left, noise_um, warm_s, warm_m)
            motion["weighed"] = {"sensor_left_um": sensor_left, "motion_left_um": motion_left,
                                 "readings": n, "noise_um": noise_um, "replaces": bool(why)}
            if why is None:
                continue
            self._replace_sensor(a, motion, motion["candidate"])
            note = (f"{a}: on its drift references read since the start ({n} readings) heat "
                    f"from its own motion leaves {motion_left:.2f} µm RMS where the temperature "
                    f"sensor's model leaves {sensor_left:.2f}"
                    + (f", and on its zone warm-up {warm_m:.2f} where the sensor's leaves "
                       f"{warm_s:.2f}" if why == "both" else "")
                    + ": heat from motion will replace the sensor in the final config")  # fmt: skip
            self.record.state["notes"].append(note)
            self.say(note)
        self.record.save()

    def _travel_before_warmup(self, axis: str, raw: RawData, plan: Plan
                              ) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
        """:func:`travel_before_warmup` of this commissioning's drift log, on the clock the
        warm-up's fit counts (``raw``'s own, where it is the machine's)."""
        state = self.record.state
        log = state.get("drift_log", [])[: state.get("warmup_log", {}).get(axis, 0)]
        timed = readings_clock_s(raw, plan, axis, CLOCK_COLUMNS) is not None
        parts = (state.get("steps", {}).get(f"warmup-{axis}") or {}).get("parts") or [{}]
        span = parts[0].get("span") or {}
        start = ({"odometer_mm": span["odometer_mm"][0], "wall_s": span["at_s"][0]}
                 if span.get("odometer_mm") and span.get("at_s") else None)  # fmt: skip
        return travel_before_warmup(log, axis, self.s.axes, self.s.speed_mm_s, timed, start)

    async def read_start_temperatures(self) -> None:
        """Each temperature-source axis's sensor as commissioning begins (°C, once): what
        its compensation commanded at the cold start (:func:`start_growth_mm`), and the
        temperature a switch across its setting is computed at (see
        :func:`..fitting.adaptive.relinked_base`). Not on a resume past the start (the machine has
        moved: no longer the start's reading)."""
        kept = self.record.state.setdefault("start_temperature_c", {})
        if "drift_base" in self.record.state:
            return
        axes = [a for a in self.drift.sensor_axes() if a not in kept]
        kept.update(await self.drift.read_temperatures_c(axes))
        self.record.save()

    def source_kind(self, axis: str) -> str | None:
        """The kind of the axis's thermal source ("temperature", "displacement"), or None: no
        thermal setting, or heat from motion (no sensor)."""
        th = self.config.axes[axis].compensation.thermal
        if th is None or th.source is None:
            return None
        return self.config.thermal_sources[th.source].kind

    def _start_growth_mm(self, axis: str, x_mm: np.ndarray) -> np.ndarray:
        """What the sensor's compensation took for growth at ``x_mm`` at the cold start (mm,
        the config's own thermal setting; zero at its reference temperature)."""
        t0 = self.record.state.get("start_temperature_c", {}).get(axis)
        return self._sensor_growth_mm(axis, x_mm, t0)

    def _sensor_growth_mm(self, axis: str, x_mm: np.ndarray, temperature_c: float | None
                          ) -> np.ndarray:  # fmt: skip
        """What ``axis``'s temperature sensor's compensation takes for growth at ``x_mm`` at
        ``temperature_c`` (mm; zeros without a sensor or a temperature)."""
        th = self.config.axes[axis].compensation.thermal
        if th is None or th.source is None or temperature_c is None:
            return np.zeros_like(np.asarray(x_mm, dtype=np.float64))
        src = self.config.thermal_sources[th.source]
        return start_growth_mm(x_mm, th.origin_mm, th.length_mm, th.gain, src.alpha_per_k,
                               float(temperature_c), src.reference_c)  # fmt: skip

    def sensor_took_mm(self, axis: str, x_mm: np.ndarray, temperature_c: np.ndarray
                       ) -> np.ndarray:  # fmt: skip
        """What ``axis``'s temperature sensor's compensation took for growth at ``x_mm`` at
        these readings (°C) since the cold start (mm; none without a sensor or a start's
        reading): the cold start's own growth is :meth:`_add_start_growth`'s. (The stage
        scales by one Δa at a time: once per temperature read, a sensor's 0.01 °C steps.)"""
        x = np.asarray(x_mm, dtype=np.float64)
        t0 = self.record.state.get("start_temperature_c", {}).get(axis)
        if t0 is None:
            return np.zeros_like(x)
        temps = np.broadcast_to(np.asarray(temperature_c, dtype=np.float64), x.shape)
        took = np.empty_like(x)
        for t_c in np.unique(temps):
            at = temps == t_c
            took[at] = self._sensor_growth_mm(axis, x[at], float(t_c))
        return took - self._sensor_growth_mm(axis, x, float(t0))

    def motion_for_sensors(self) -> None:
        """The heat-from-motion models that replace a temperature sensor, from the
        after-run on (it judges the final config). Not in the rounds: their tables were
        measured with the sensor, or without it where the heat was spread where the axis
        travelled (``Tables.sensor_off``: their drift is then the growth, taken off along
        that shape). The gateway counts the model's heat from every move since it started
        (:class:`~gateway.thermal_travel.MoveLog`); when it began cold at a reload instead,
        the after-run read the heat of the hours before it (rough-9 X: E 22 µm there, 2.7
        µm in a judge after a cool-down), so the after-run kept the sensor until then.

        Tables measured with the sensor's compensation on, which at the cold start already
        took the screw for grown by the sensor's distance from its reference temperature,
        hold that much less. Heat from motion starts at zero, so that growth goes back into
        the table (once: the table as it was is kept in the state until it is written);
        where the axis ran without its sensor, its readings taken with it lost that growth
        with their drift (:meth:`raw`) instead."""
        for a in self.s.axes:
            motion = self.drift.replacing_motion(a)
            if motion is not None and a not in self.record.tables.thermal_motion:
                if self.drift.drift_spread_mm(a) is None:  # else its readings lost it (raw)
                    self._add_start_growth(a)
                self.record.tables.thermal_motion[a] = motion
                note = (f"{a}: heat from motion replaces the temperature sensor from the "
                        "after-run on, and in the final config")
                self.record.state["notes"].append(note)
                self.say(note)
        self.record.save()

    def _add_start_growth(self, axis: str) -> None:
        """Put the sensor's cold-start growth back into ``axis``'s table (see
        :meth:`motion_for_sensors`); resumable: the table as it was is kept until written."""
        from ..fitting.outputs import check_pitch, write_table

        if axis not in self.record.tables.pitch:
            return
        path = self.record.config_dir / self.record.tables.pitch[axis]
        pending = self.record.state.setdefault("start_growth", {})
        if pending.get(axis, {}).get("written"):
            return
        if axis not in pending:
            table = read_pitch_csv(path)
            pending[axis] = {"position_mm": table.position_mm.tolist(),
                             "forward_mm": table.forward_mm.tolist(),
                             "reverse_mm": None if table.reverse_mm is None else
                             table.reverse_mm.tolist()}  # fmt: skip
            self.record.save()
        old = pending[axis]
        x = np.asarray(old["position_mm"], dtype=np.float64)
        grown = self._start_growth_mm(axis, x)
        if not float(np.abs(grown).max(initial=0.0)) >= 1e-6:  # under a nanometre: none
            pending[axis]["written"] = True
            return
        table = read_pitch_csv(path)
        fwd = np.asarray(old["forward_mm"]) + grown
        rev = None if old["reverse_mm"] is None else np.asarray(old["reverse_mm"]) + grown
        new = replace(table, position_mm=x, forward_mm=fwd, reverse_mm=rev)
        pending[axis]["written"] = True
        try:  # what the gateway would refuse (the correction cap) stays out, said so
            check_pitch(new, self.config, axis)
        except (TableError, CompensationError) as exc:
            self.record.state["notes"].append(
                f"{axis}: the sensor's cold-start growth not put back: "
                                       f"{exc}")  # fmt: skip
            return
        write_table(path, "csv", new, "compgw commission: the sensor's cold-start growth "
                    "put back")  # fmt: skip
        note = (f"{axis}: {1e3 * float(np.abs(grown).max()):.2f} µm at most put back into the "
                f"table: the sensor's compensation at the cold start "
                f"({self.record.state['start_temperature_c'][axis]:.2f} °C), which heat from "
                "motion "
                "does not apply")  # fmt: skip
        self.record.state["notes"].append(note)
        self.say(note)

    def zoned(self) -> list[str]:
        """The linear axes with a thermal setting: each gets a zone warm-up (on a short
        budget after the plain calibration's steps, where the budget holds it)."""
        return [a for a in self.s.axes if not self.axes.rotary(a) and self.warms_up(a)]

    def heat_zoned(self) -> list[str]:
        """The linear axes with no sensor whose heat from motion a zone warm-up fits."""
        return [a for a in self.s.axes if self.heat_warms_up(a)]

    def least_growth_um(self) -> float:
        """The drift (µm) an axis with no sensor must show before its zone warm-up is
        worth its machine time: what heat from motion models at all."""
        return min(MIN_GROWTH_UM, self.s.tolerance_um)

    def too_little_heat(self, axis: str) -> str | None:
        """Why an axis with no sensor gets no zone warm-up (None: it warms): the most its
        drift references can have grown so far (what they moved, plus twice the scatter
        of one reading), scaled from its travel so far to the warm-up's, grows it less
        than :meth:`least_growth_um`. What the references cannot rule out is warmed up:
        the pitch runs are light work, and a drift within the references' scatter over
        them is no bound on a working day's (smooth-2 Y moved 0.8 µm in 19 m, within its
        0.4 µm scatter; then 3.2 µm in the bench judge's 30 minutes of work, none of it
        modelled; smooth-0 Y 1.8 µm in 24 m, then 22 µm)."""
        grown = self.drift.grown_um(axis)
        so_far_m = self.drift.odometer()[axis] / 1000.0
        plan = self.warmup_plan(axis)
        k = plan.axes.index(axis)
        x = np.array([m.target_mm[k] for m in plan.moves])
        warm_m = float(np.abs(np.diff(x)).sum()) / 1000.0
        scale = max(1.0, warm_m / max(so_far_m, 1e-3))
        s_um = self.drift.ref_scatter_um(axis) or self.drift.iso_scatter_um(axis)
        if s_um is None:
            return None  # nothing known of the references' scatter: nothing ruled out
        most_um = (grown + 2.0 * s_um) * scale
        if most_um >= self.least_growth_um():
            return None
        return (f"its drift references moved {grown:.1f} µm in {so_far_m:.0f} m of its travel "
                f"(their scatter {s_um:.1f} µm): at most about {most_um:.1f} µm over the "
                f"warm-up's {warm_m:.0f} m, under {self.least_growth_um():g}: too little heat "
                "for a warm-up")



def start_growth_mm(x_mm: np.ndarray, origin_mm: float, length_mm: float, gain: float,
                    alpha_per_k: float, temperature_c: float, reference_c: float
                    ) -> np.ndarray:  # fmt: skip
    """The growth (mm) a temperature source's compensation takes at ``x_mm``: the gateway's
    own thermal stage at Δa = gain · α · a · (T − T_ref), moved off the fixed end."""
    da = gain * delta_a_from_temperature(alpha_per_k, length_mm, temperature_c, reference_c)
    x = np.asarray(x_mm, dtype=np.float64)
    return ThermalStage(length_mm, origin_mm).inverse(x, da) - x


def travel_before_warmup(log: list[dict[str, Any]], axis: str, axes: list[str] | tuple[str, ...],
                         speed_mm_s: float, timed: bool, start: dict[str, Any] | None = None
                         ) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """``axis``'s travel (m) and the machine time (s), stretch by stretch, since the
    commissioning began (the odometers' zero, the screw cold) and before its warm-up:
    between the drift readings ``log`` (drift-log entries: ``odometer_mm`` per axis,
    ``wall_s``) and on to the warm-up's own ``start`` (an entry alike). The travel before
    the first reading has no time logged: it counts at ``speed_mm_s``. (Rough-1's X moved
    3.4 m before its warm-up, all of it before the first reading or after the last: left
    out, the warm-up grew 4 % less than its own heat made, the fitted Δa per metre came
    out 2.4 % short, and the judge's zone replayed 3.0-3.7 % short; with it 0.9-2.2 %.)
    ``timed``: the log's clock is the machine's, and the warm-up's fit counts it alone (the
    gateway counts a model with no speeds so); else each axis's travel at the estimated
    ``speed_mm_s``, or the clock where that is longer (a pause cools too). Random machine
    3's X runs at 160 mm/s: counted at 100 on a machine clock, 28 of its 31 stretches
    lasted longer than they did, the heat left from before its warm-up came out 16 %
    short, and the fitted Δa per metre 8 % short with it."""
    log = [*log, *([start] if start is not None else [])]
    if log:
        lead_mm = {b: float(log[0]["odometer_mm"].get(b, 0.0)) for b in axes}
        if any(v > 0.0 for v in lead_mm.values()):  # moves before the first reading
            lead_s = sum(lead_mm.values()) / speed_mm_s
            log.insert(0, {"odometer_mm": dict.fromkeys(axes, 0.0),
                           "wall_s": float(log[0]["wall_s"]) - lead_s})  # fmt: skip
    if len(log) < 2:
        return np.zeros(0), np.zeros(0)
    odo = {b: np.array([e["odometer_mm"].get(b, 0.0) for e in log]) for b in axes}
    wall_s = np.diff([e["wall_s"] for e in log]).clip(min=0.0)
    travel_m = np.diff(odo[axis]).clip(min=0.0) / 1000.0
    if timed:
        return travel_m, wall_s
    moving_s = sum(np.diff(v).clip(min=0.0) / speed_mm_s for v in odo.values())
    return travel_m, np.maximum(moving_s, wall_s)
