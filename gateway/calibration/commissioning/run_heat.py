"""Heat from motion read off the ISO runs themselves, where no drift references were read.

A budget of a plain calibration's machine time has no room for drift references
(:meth:`.short.ShortBudget.refs_affordable`), so :meth:`.drift.DriftRefs.fit_motion_heat`
has nothing to fit, and an axis without a sensor met the customer's warm machine with no
heat model at all (smooth-8's plane at 1 x: 16-20 µm at the judge, all heat). Its ISO runs
warm its screw all the same, and each reads every target: what a run reads differently
from the run before is the growth between them (:mod:`..thermal.run_levels`). Heat from
motion is fitted to those changes (:func:`..thermal.heat_fit.motion_heat_fit` with
``offset``), and the table, which holds the runs' mean growth, is put back to the cold
start the gateway's heat model counts from.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any

import numpy as np

from ...compensation import PitchTable
from ...compensation.errors import TableError
from ...config import AxisThermal
from ..fitting.fit import zeroed_at_origin
from ..fitting.outputs import read_table, write_table
from ..measuring.from_file import STOP_TIME
from ..plans.plans import Move, Plan, read_plan
from ..plans.rawdata import read_raw_csv
from ..thermal.heat_fit import (
    growth_at_um,
    heat_at_readings_m,
    least_growth_um,
    motion_heat_fit,
)
from ..thermal.run_levels import means_by, on_the_way, row_odometer_mm, run_levels_um
from ..thermal.thermal_shape import profile_fractions
from .planner import BETWEEN

if TYPE_CHECKING:
    from .axes import Axes
    from .drift import DriftRefs
    from .record import Record
    from .steps import StepRunner

Say = Callable[[str], None]
#: (axis, x_mm, temperature_c) → what its sensor's compensation took for growth since the
#: cold start (mm)
SensorGrowth = Callable[[str, np.ndarray, np.ndarray], np.ndarray]

#: the steps of an axis's ISO runs (the midpoints', quarter and eighth points' read other targets:
#: their levels are a group of their own)
STEPS = ("iso-{a}", "iso-more-{a}", *(b.step + "-{a}" for b in BETWEEN))
#: the least growth heat is fitted to, however well the levels stand out of their scatter
#: (five times it: :func:`..thermal.heat_fit.least_growth_um`)
RUN_MIN_SEEN_UM = 0.3
#: a run label per step, so that the runs of several steps stay apart
RUN_STRIDE = 1000


@dataclass(frozen=True)
class RunHeat:
    """Heat from motion fitted to the ISO runs' own levels (no drift references read)."""

    axes: Axes
    record: Record
    drift: DriftRefs
    runner: StepRunner
    say: Say

    def fit(self) -> None:
        """Per linear axis with no thermal setting, where no drift references were read:
        heat from motion fitted to its ISO runs' levels, and its table put back to the cold
        start (kept in the identification results either way)."""
        if self.record.state.get("drift_log") or not self.drift.off():
            return  # the references' own fit (DriftRefs.fit_motion_heat)
        ident = self.record.state.setdefault("identify", {})
        for a in self.axes.ref_axes():
            key = f"motion-{a}"
            if self.axes.config.axes[a].compensation.thermal is not None or key in ident \
                    or a not in self.record.tables.pitch:  # fmt: skip
                continue
            rows = self.rows(a)
            if rows is None:
                continue
            way = self.on_the_way()
            refs = self.axes.ref_positions(a)
            lv = run_levels_um(rows.run, rows.target_mm, rows.deviation_mm, refs)
            where, at_s, odo_mm = on_the_way(
                means_by(rows.run, rows.at_s),
                {b: means_by(rows.run, v) for b, v in rows.odometer_mm.items()}, *way)
            levels = np.full((at_s.size, 2), np.nan)  # nothing read on the way
            levels[where] = lv.levels_um
            group = np.full(at_s.size, -1)
            group[where] = lv.group
            try:
                fit = motion_heat_fit(
                    a, {b: v / 1000.0 for b, v in odo_mm.items()}, at_s, levels, refs,
                    dict.fromkeys(self.axes.s.axes, self.axes.s.speed_mm_s), self.axes.travel(a),
                    least_growth_um(self.axes.s.tolerance_um, lv.noise_um, RUN_MIN_SEEN_UM),
                    offset=group)  # fmt: skip
            except TableError as exc:
                ident[key] = {"fitted": False, "from": "runs", "why": str(exc),
                              "level_noise_um": lv.noise_um}  # fmt: skip
                self.say(f"no heat-from-motion model from the ISO runs: {exc}")
                continue
            config = fit.config()
            held = self.put_back(a, rows, config, way)
            self.record.tables.motion[a] = config
            ident[key] = {"fitted": True, "from": "runs", **config,
                          "growth_max_um": fit.growth_max_um,
                          "residual_rms_um": fit.residual_rms_um, "points": fit.points,
                          "level_noise_um": lv.noise_um,
                          "table_held_um": held}  # fmt: skip
            self.say(f"{a}: no thermal sensor and no drift references; heat from its own "
                     f"motion explains its ISO runs' levels (they moved {fit.growth_max_um:.1f}"
                     f" µm) to {fit.residual_rms_um:.2f} µm RMS: Δa "
                     f"{fit.delta_a_um_per_m:.3g} µm per metre of heat, tau {fit.tau_s:.0f} s;"
                     f" its table put back to the cold start (it held {held[0]:+.2f} µm at "
                     f"{refs[0]:g} mm, {held[1]:+.2f} at {refs[1]:g})")  # fmt: skip
        self.record.save()

    def put_back_refs(self) -> None:
        """Per linear axis with no thermal setting whose table only the identification's
        runs made (no round refined it), where drift references were read: the table put
        back reading by reading, instead of by the references' drift alone.

        With heat from motion fitted (to the references, or a zone warm-up): to the cold
        start by that model. The references read at their own stops, a few times a step:
        their scatter tilts the table, and a target's two passes keep the drift between
        them (its reversal as read). smooth-3's X at 1.5 x: noise-free E 0.60 µm on the
        pitch line, 0.35 put back (a perfect table 0.26).

        With no model to follow its heat: to the state its runs were read in (the
        references' drift given back), as a plain calibration's table is. The machine is
        never cold in use, and a cold-start table with nothing to follow the heat meets it
        wrong by all its growth: smooth-5's Y at 1.5 x read E 96.1 % where 1 x, as read,
        read 97.2 % (the judges' mean)."""
        if not self.record.state.get("drift_log") or self.record.state.get("rounds"):
            return
        ident = self.record.state.setdefault("identify", {})
        for a in self.axes.ref_axes():
            fitted = ident.get(f"motion-{a}")  # the references' fit, or why none
            if self.axes.config.axes[a].compensation.thermal is not None or fitted is None \
                    or "table_held_um" in fitted or a not in self.record.tables.pitch:  # fmt: skip
                continue
            model = self.record.tables.motion.get(a) if fitted.get("fitted") else None
            if model is not None and model.get("profile"):
                continue  # a zone warm-up's travel profile: its table left as fitted
            rows = self.rows(a)
            if rows is not None and not self._drift_off_at_fit(a):
                rows = replace(rows, taken_mm=np.zeros_like(rows.taken_mm))
            if rows is None or (model is None and not rows.taken_mm.any()):
                continue  # (no drift taken off: the table is as read already)
            held = self.put_back(a, rows, model, self.on_the_way())
            fitted["table_held_um"] = held
            if model is not None:
                self.say(f"{a}: its table put back to the cold start by its heat from "
                         f"motion, reading by reading (it held {held[0]:+.2f} µm at the first "
                         f"reference, {held[1]:+.2f} at the second, beyond what the "
                         "references took off)")  # fmt: skip
            else:
                self.say(f"{a}: no heat model follows it, so its table keeps the state its "
                         f"runs were read in: the references' drift given back "
                         f"({-held[0]:+.2f} µm at the first reference, {-held[1]:+.2f} at "
                         "the second)")  # fmt: skip
        self.record.save()

    def put_back_sensor(self, sensor_growth_mm: SensorGrowth) -> None:
        """Per linear axis whose temperature sensor heat from motion replaces, whose table
        only the identification's runs made, with no drift references read, and whose
        sensor was read at each of its ISO readings: the table put back to the cold start
        reading by reading, what the sensor's compensation took off each given back and the
        model's growth taken off (:meth:`put_back`), so the reversal loses the heat between
        a target's two passes too.

        ``sensor_growth_mm(axis, x_mm, temperature_c)``: what the sensor's compensation
        takes for growth at ``x_mm`` since the cold start (mm). (Rough-9's X at 1.5 x: read
        under a sensor that explained its zone warm-up to 3.54 µm RMS, heat from motion to
        0.28; its runs' reversal read 0.5-0.9 µm short between 450 and 700 mm, where a
        backlash test read the truth's, and its table kept that.)"""
        if self.record.state.get("drift_log") or self.record.state.get("rounds"):
            return
        ident = self.record.state.setdefault("identify", {})
        for a in self.axes.ref_axes():
            fitted = (ident.get(f"thermal-{a}") or {}).get("motion") or {}
            model = self.record.tables.thermal_motion.get(a)
            if model is None or not fitted.get("replaces_sensor") or "table_held_um" in fitted \
                    or a not in self.record.tables.pitch:  # fmt: skip
                continue
            rows = self.rows(a)
            if rows is None or not np.isfinite(rows.temperature_c).all():
                continue  # (a state from before the runs read their sensor)
            took_mm = sensor_growth_mm(a, rows.target_mm, rows.temperature_c)
            held = self.put_back(a, rows, model, self.on_the_way(), took_mm,
                                 self.profile_shares(a, rows, model))
            fitted["table_held_um"] = held
            self.say(f"{a}: its table, read with its temperature sensor's compensation on, "
                     "put back to the cold start reading by reading: the sensor's "
                     "compensation given back, the growth of the heat from motion that "
                     f"replaces it taken off (it held {held[0]:+.2f} µm at the first "
                     f"reference, {held[1]:+.2f} at the second)")  # fmt: skip
        self.record.save()

    def profile_shares(self, axis: str, rows: Rows, thermal: dict[str, Any]
                       ) -> np.ndarray | None:  # fmt: skip
        """A travel profile's share of the whole elongation at each of ``rows``, as the
        gateway would count it had it run every step's moves of ``axis`` so far in their
        order (:func:`..thermal.thermal_shape.profile_fractions`); None without a profile,
        or where a step's plan is missing or its readings are not its plan's stops. The
        heat of the down pass lies beyond the targets it passes: spread linearly over the
        travel's reach, it grew each target between its two passes (rough-9's X: reversal
        0.27 µm RMS off the truth's, 0.22 with the profile)."""
        if not thermal.get("profile"):
            return None
        th = AxisThermal.model_validate(thermal)
        moves: list[Move] = []
        stops: dict[str, tuple[int, int]] = {}
        for step in self.record.state["steps"]:
            path = self.record.dir / "plans" / f"{step}.plan"
            if not path.exists():
                continue
            plan = read_plan(path)
            if axis not in plan.axes:
                continue
            k = plan.axes.index(axis)
            first = sum(m.measured for m in moves)
            moves += [replace(m, target_mm=(m.target_mm[k],)) for m in plan.moves]
            stops[step] = (first, sum(m.measured for m in moves))
        steps = [s.format(a=axis) for s in STEPS]
        counts = np.bincount(rows.run // RUN_STRIDE, minlength=len(steps))
        spans = [stops.get(s) for s, n in zip(steps, counts) if n]
        if any(span is None or span[1] - span[0] != n
               for span, n in zip(spans, counts[counts > 0])):  # fmt: skip
            return None
        assert th.profile is not None
        share = profile_fractions(Plan("replay", (axis,), tuple(moves)), axis, th, th.profile,
                                  self.axes.travel(axis), th.length_mm)  # fmt: skip
        return np.concatenate([share[a:b] for a, b in spans])  # type: ignore[misc]

    def _drift_off_at_fit(self, axis: str) -> bool:
        """Whether ``axis``'s table was fitted with the references' drift off its runs. The
        references read after it (the plane's grid and random points, with the tables on)
        may make a drift that only scattered stand out: random machine 14's Y at 1.0 h,
        fitted as read, then given back a drift never taken off it (a 1.2 µm tilt). A
        state from before this was kept: taken off."""
        return bool((self.record.state.get("drift_off_at_fit") or {}).get(axis, True))

    def rows(self, axis: str) -> Rows | None:
        """The readings of ``axis``'s ISO runs, each row timed and its odometers; None
        where a step was not timed (a state kept before the steps kept their span)."""
        parts: list[Rows] = []
        for k, step in enumerate(s.format(a=axis) for s in STEPS):
            entries = (self.record.state["steps"].get(step) or {}).get("parts") or []
            if not entries:
                continue
            # what the references' drift took off each reading (none where none was read)
            taken = self.runner.raw_as_read(step).actual_mm - self.runner.raw(step).actual_mm
            first = 0
            for part in entries:
                span = part.get("span")
                if span is None:
                    return None
                data = read_raw_csv(self.record.config_dir / part["raw"])
                rows = slice(first, first + len(data))
                first += len(data)
                on = np.array(data.axis) == axis
                row_s = (data.column_mm(STOP_TIME) if STOP_TIME in data.extra  # a recording's
                         else span["at_s"][0] + data.column_mm("time_s"))[on]  # fmt: skip
                odo = row_odometer_mm(row_s, tuple(span["at_s"]),  # type: ignore[arg-type]
                                      tuple(span["odometer_mm"]))  # type: ignore[arg-type]
                temps = (data.column_mm("temperature_c") if "temperature_c" in data.extra
                         else np.full(len(data), np.nan))  # fmt: skip
                parts.append(Rows(k * RUN_STRIDE + data.run[on], data.target_mm[on],
                                  data.actual_mm[on] - data.target_mm[on],
                                  data.direction[on] > 0, row_s, odo, taken[rows][on],
                                  temps[on]))  # fmt: skip
        if not parts:
            return None
        return Rows(*(np.concatenate([getattr(p, f) for p in parts])
                      for f in ("run", "target_mm", "deviation_mm", "up", "at_s")),
                    {b: np.concatenate([p.odometer_mm[b] for p in parts])
                     for b in parts[0].odometer_mm},
                    np.concatenate([p.taken_mm for p in parts]),
                    np.concatenate([p.temperature_c for p in parts]))  # fmt: skip

    def on_the_way(self) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        """The clock (s) and each axis's odometer (mm) at both ends of every step's runs
        (every axis's): where the travel between an axis's own runs lies in time. Spread
        evenly from one run to the next instead, smooth-8 Y's τ came out 1319 s for the
        sim's 1054 (1126 with them)."""
        at: list[float] = []
        odo: dict[str, list[float]] = {b: [] for b in self.axes.s.axes}
        for entry in self.record.state["steps"].values():
            for part in (entry or {}).get("parts") or []:
                span = part.get("span")
                for k in (0, 1) if span else ():
                    at.append(float(span["at_s"][k]))
                    for b, v in odo.items():
                        v.append(float(span["odometer_mm"][k].get(b, 0.0)))
        return np.array(at), {b: np.array(v) for b, v in odo.items()}

    def put_back(self, axis: str, rows: Rows, thermal: dict[str, Any] | None,
                 way: tuple[np.ndarray, dict[str, np.ndarray]],
                 sensor_took_mm: np.ndarray | None = None,
                 shares: np.ndarray | None = None) -> list[float]:  # fmt: skip
        """``axis``'s table less the growth the model ``thermal`` puts at each of its ISO
        readings, per target and direction (so the reversal loses the heat between its two
        passes too), the heat run through the points ``way`` (:meth:`on_the_way`),
        rewritten in place: the cold start's table (the one fitted kept as
        ``<name>.as_read.csv``); with no model (None), the drift the references took off
        given back: the runs' own state. Returns the growth the table held at the
        references (µm, mean of both directions, beyond what the references took off).
        ``sensor_took_mm``: what a temperature sensor's compensation took off each reading
        since the cold start (mm), given back too. ``shares``: a travel profile's share of
        the whole elongation at each reading (:meth:`profile_shares`), in place of the
        linear spread over the travel's reach."""
        grown_um = -rows.taken_mm * 1000.0  # the references' drift: given back
        if sensor_took_mm is not None:
            grown_um = grown_um - sensor_took_mm * 1000.0
        if thermal is not None:  # the model's growth, less what the references took off
            where, at_s, odo_mm = on_the_way(rows.at_s, rows.odometer_mm, *way)
            heat = heat_at_readings_m(thermal["motion"], axis,
                                      {b: v / 1000.0 for b, v in odo_mm.items()}, at_s)[where]
            grown_um = grown_um + growth_at_um(thermal, heat, rows.target_mm,
                                               self.axes.travel(axis), shares)
        path = self.record.config_dir / self.record.tables.pitch[axis]
        # the table as fitted, kept beside it first: an interrupted put-back, resumed,
        # starts from it again (never from a table already put back)
        as_read = path.with_name(f"{path.stem}.as_read.csv")
        if not as_read.exists():
            write_table(as_read, "csv", read_table(path, "csv"),
                        "compgw commission: the table as fitted, before it was put back")
        table = read_table(as_read, "csv")
        held: dict[bool, np.ndarray] = {}
        for up in (True, False):
            at = rows.up == up
            xs = np.unique(rows.target_mm[at])
            mean = means_by(rows.target_mm[at], grown_um[at])
            held[up] = np.interp(table.position_mm, xs, mean) / 1000.0  # mm
        if axis in (self.record.state.get("zero_moved_mm") or {}):
            # a laser zeroed anywhere: the table stays zero at the machine's zero
            # (:meth:`.drift.DriftRefs.move_zero`), only its shape is put back
            at_zero = zeroed_at_origin(PitchTable(table.position_mm, held[True]))[0]
            held = {up: h - at_zero for up, h in held.items()}
        if table.reverse_mm is None:
            both = (held[True] + held[False]) / 2.0
            cold = PitchTable(table.position_mm, table.forward_mm - both, None, table.rotary,
                              table.source)  # fmt: skip
        else:
            cold = PitchTable(table.position_mm, table.forward_mm - held[True],
                              table.reverse_mm - held[False], table.rotary, table.source)
        write_table(path, "csv", cold, "compgw commission: put back to the cold start "
                    "(heat from motion, fitted to the ISO runs' levels)" if thermal is not None
                    else "compgw commission: the runs' own state (the references' drift "
                    "given back: no heat model follows this axis)")  # fmt: skip
        mean_mm = (held[True] + held[False]) / 2.0
        refs = self.axes.ref_positions(axis)
        return [float(v) * 1000.0 for v in np.interp(refs, table.position_mm, mean_mm)]


@dataclass(frozen=True)
class Rows:
    """An axis's ISO readings: run label, target (mm), deviation (mm) as read, ↑ or not,
    when (s), each axis's odometer then (mm), the drift taken off it (mm)."""

    run: np.ndarray
    target_mm: np.ndarray
    deviation_mm: np.ndarray
    up: np.ndarray
    at_s: np.ndarray
    odometer_mm: dict[str, np.ndarray]
    taken_mm: np.ndarray  # the drift the references' readings took off it (mm)
    temperature_c: np.ndarray  # its screw's sensor at each reading (°C; NaN: not read)


__all__ = ["RunHeat"]
