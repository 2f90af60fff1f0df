"""Heat from motion fitted to a zone warm-up, against a temperature sensor at one spot.

A temperature sensor says how warm the screw is where it sits. On a screw warm only
where its nut runs, that spot may be inside the zone or beyond it, and the growth
follows it only in proportion to nothing in particular. The heat the axis's own motion
put in (:func:`~gateway.compensation.thermal.motion_heat_m`), spread where it travelled
(the gateway's travel profile) or linearly, is a different model of the same warm-up:
fitted here to the readings inside and beyond the zone, it replaces the sensor when it
leaves clearly less (under half, and by more than the noise) at the places surveyed warm.

Time is the plan's machine time (travel over speed, dwells): what the gateway counts in
a commissioning and on a machine in steady motion. Pure: readings and a plan in, numbers
out.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ...compensation.errors import TableError
from ...compensation.thermal import motion_heat_series_m
from ...config import AxisThermal, TravelProfile
from ..plans.plans import Plan
from ..plans.rawdata import RawData
from .heat_fit import TAU_GRID_S, likely_tau
from .thermal_shape import (
    NOISE_UM,
    PROFILE_SHARE,
    SPREADS_MM,
    profile_fractions,
    screw_ends_mm,
    stop_times_s,
    survey_changes,
    survey_mask,
)

UM_PER_MM = 1000.0


@dataclass(frozen=True)
class WarmupHeatFit:
    """Heat from motion as a zone warm-up showed it, and what the sensor explained."""

    axis: str
    origin_mm: float
    length_mm: float
    delta_a_um_per_m: float  # Δa at length_mm per metre of travel whose heat is in the screw
    tau_s: float
    spread_mm: float | None  # the travel profile's; None: linear from the fixed end
    memory_mm: float
    motion_rms_um: float  # at the places surveyed warm
    sensor_rms_um: float  # the temperature sensor's model (gain fitted) there
    growth_max_um: float
    timed: bool = False  # by the readings' own clock (``clock`` of :func:`warmup_heat_fit`)
    screw_mm: tuple[float, float] | None = None  # the profile's (:func:`screw_ends_mm`)

    @property
    def replaces_sensor(self) -> bool:
        return self.motion_rms_um < PROFILE_SHARE * self.sensor_rms_um and \
            self.sensor_rms_um - self.motion_rms_um > NOISE_UM  # fmt: skip

    def config(self, speeds_mm_s: dict[str, float] | None = None) -> dict[str, Any]:
        """The axis's ``compensation.thermal`` section (no source). Fitted on the readings'
        own clock, it needs no speeds (None: the gateway counts the clock alone)."""
        return motion_section(self.origin_mm, self.length_mm, self.delta_a_um_per_m,
                              self.tau_s, self.spread_mm, self.memory_mm, speeds_mm_s or {},
                              self.screw_mm)  # fmt: skip

    def summary(self) -> dict[str, Any]:
        return {"replaces_sensor": self.replaces_sensor, "tau_s": self.tau_s,
                "delta_a_um_per_m": self.delta_a_um_per_m, "spread_mm": self.spread_mm,
                "motion_rms_um": self.motion_rms_um, "sensor_rms_um": self.sensor_rms_um,
                "growth_max_um": self.growth_max_um, "timed": self.timed}  # fmt: skip


def motion_section(origin_mm: float, length_mm: float, delta_a_um_per_m: float, tau_s: float,
                   spread_mm: float | None, memory_mm: float, speeds_mm_s: dict[str, float],
                   screw_mm: tuple[float, float] | None = None) -> dict[str, Any]:  # fmt: skip
    """A ``compensation.thermal`` section of heat from motion (no source) as a zone warm-up
    fitted it: linear from the fixed end, or spread where the axis travelled."""
    out: dict[str, Any] = {
        "origin_mm": round(origin_mm, 2), "length_mm": round(length_mm, 2),
        "motion": {"delta_a_um_per_m": float(f"{delta_a_um_per_m:.5g}"),
                   "tau_s": round(tau_s, 1),
                   "speeds_mm_s": {a: float(v) for a, v in speeds_mm_s.items()}}}
    if spread_mm is not None:
        out["profile"] = {"spread_mm": spread_mm, "memory_mm": memory_mm,
                          "memory_s": round(tau_s, 1)}  # fmt: skip
        if screw_mm is not None:
            out["profile"]["screw_mm"] = list(screw_mm)
    return out


def _own_travel(plan: Plan, axis: str) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Per measured stop: the axis's travel (m) and machine time (s) since the stop before."""
    k = plan.axes.index(axis)
    speed = float(dict(plan.meta).get("speed_mm_s", 0) or 0)
    travel, elapsed, out_d, out_t, pos = 0.0, 0.0, [], [], None
    for m in plan.moves:
        x = float(m.target_mm[k])
        v = m.speed_mm_s or speed
        if pos is not None:
            travel += abs(x - pos)
            elapsed += abs(x - pos) / v if v > 0 else 0.0
        pos = x
        if m.measured:
            elapsed += m.dwell_s or 0.0
            out_d.append(travel / 1000.0)
            out_t.append(elapsed)
            travel, elapsed = 0.0, 0.0
    return np.asarray(out_d), np.asarray(out_t)


def readings_clock_s(raw: RawData, plan: Plan, axis: str,
                     columns: tuple[str, ...] = ("time_s",)) -> NDArray[np.float64] | None:
    """When each of ``axis``'s stops was read (s, the first of the raw file's ``columns``
    that is the machine's clock: it spans at least half the plan's estimated time). None
    where none does (no such column, a recording's joined rows, a simulator whose clock
    runs with its moves, not with the computer's): the plan's times then, and the
    config's speeds count them."""
    planned = stop_times_s(plan, axis)
    rows = np.flatnonzero(np.array(raw.axis) == axis)
    for name in (c for c in columns if c in raw.extra):
        read = raw.column_mm(name)[rows]
        if read.size == planned.size >= 2 and np.ptp(read) >= 0.5 * np.ptp(planned):
            return read
    return None


def heat_changes(plan: Plan, axis: str, warm: NDArray[np.int64], first: NDArray[np.int64],
                 prior_m: ArrayLike = (), prior_s: ArrayLike = (),
                 times_s: ArrayLike | None = None,
                 ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:  # fmt: skip
    """Per warm reading and per τ on TAU_GRID_S (shape (readings, τ), metres of travel):
    the change since its cold reading of the heat the warm-up's own travel put in, and of
    the heat from before the warm-up (``prior_m``, ``prior_s``: travel and time, stretch by
    stretch), which only fades. ``times_s``: when each measured stop was read (the raw
    file's clock): the stretches last that long, not what the plan's estimated speed says
    (smooth-8's X runs at 200 mm/s, its Y at 60, against 100 estimated), as the gateway's
    clock counts a model with no speeds."""
    d_m, t_s = _own_travel(plan, axis)
    if times_s is not None:
        read = np.asarray(times_s, dtype=np.float64).reshape(-1)
        if read.size == t_s.size:
            t_s = np.concatenate([t_s[:1], np.diff(read).clip(min=0.0)])
    before_m = np.asarray(prior_m, dtype=np.float64).reshape(-1)
    before_s = np.asarray(prior_s, dtype=np.float64).reshape(-1)
    if before_m.size != before_s.size:
        raise TableError(f"axis {axis}: prior travel and times differ in length")
    heat = motion_heat_series_m(d_m, t_s[:, None] * np.ones(TAU_GRID_S.size), TAU_GRID_S)
    start = np.zeros(TAU_GRID_S.size)
    if before_m.size:
        start = motion_heat_series_m(before_m, before_s[:, None] * np.ones(TAU_GRID_S.size),
                                     TAU_GRID_S)[-1]  # fmt: skip
    fading = start[None, :] * np.exp(-np.cumsum(t_s)[:, None] / TAU_GRID_S[None, :])
    return heat[warm] - heat[first], fading[warm] - fading[first]


def _ls(design: NDArray[np.float64], y: NDArray[np.float64]) -> tuple[float, float]:
    """Least squares of y = c·design: (c, sum of squares left)."""
    den = float(np.dot(design, design))
    c = float(np.dot(design, y) / den) if den > 0 else 0.0
    return c, float(np.sum((y - c * design) ** 2))


def warmup_heat_fit(raw: RawData, plan: Plan, axis: str, thermal: AxisThermal,
                    alpha_per_k: float, travel_mm: tuple[float, float],
                    prior_m: ArrayLike = (), prior_s: ArrayLike = (),
                    clock: tuple[str, ...] = ()) -> WarmupHeatFit:  # fmt: skip
    """Heat from motion (τ, Δa per metre, linear or profiled) fitted to a zone warm-up with
    a temperature column, and the temperature model's residual at the same places.

    ``prior_m``, ``prior_s``: the axis's travel (m) and the time it took (s), stretch by
    stretch, since the screw was last cold and before the warm-up began (the commissioning's
    own runs). That heat is still going out of the screw while the warm-up puts more in,
    so the growth read is less than the warm-up's own heat makes: left out, the fitted Δa
    per metre came out 15-20 % short (rough-1 Y, 29 m of travel before a 200 m warm-up).
    It spreads over the travel the runs covered: linear from the fixed end.

    ``clock``: the raw columns that may time the stops
    (:func:`readings_clock_s`); none that does: the plan's times, at its
    estimated speed (rough-9's Y runs at 60 mm/s against 100 estimated: τ and the heat's
    fading were counted in the wrong seconds, and the judge's warm-up read 3 µm of it)."""
    warm, first, place, growth, d_temp = survey_changes(raw, axis, "temperature_c")
    if sum(m.measured for m in plan.moves) != int(np.sum(np.array(raw.axis) == axis)):
        raise TableError(f"{raw.source}: axis {axis}: the warm-up did not run as planned")
    survey = survey_mask(place)
    o = thermal.origin_mm
    lever = place - o
    # the sensor: growth = gain · α · ΔT · (x − o)
    gain, _ = _ls(alpha_per_k * d_temp * lever, growth)
    sensor_rms = float(np.sqrt(np.mean((growth - gain * alpha_per_k * d_temp * lever)[survey]
                                       ** 2)))  # fmt: skip
    times = readings_clock_s(raw, plan, axis, clock)
    d_heat, d_fade = heat_changes(plan, axis, warm, first, prior_m, prior_s, times)
    length = float(thermal.length_mm)
    sse = [_ls((d_heat[:, j] + d_fade[:, j]) * lever / length, growth)[1]
           for j in range(TAU_GRID_S.size)]  # fmt: skip
    j = likely_tau(sse)
    if j == TAU_GRID_S.size - 1 or not np.ptp(growth) * UM_PER_MM >= 3.0:
        raise TableError(f"{raw.source}: axis {axis}: the warm-up's growth does not level "
                         "off or is under 3 µm: no heat-from-motion model")  # fmt: skip
    tau = float(TAU_GRID_S[j])
    lin = (d_heat[:, j] + d_fade[:, j]) * lever / length
    c_lin, _ = _ls(lin, growth)
    lin_rms = float(np.sqrt(np.mean((growth - c_lin * lin)[survey] ** 2)))
    speed = float(dict(plan.meta).get("speed_mm_s", 0) or 0)
    memory = round(max(speed, 1.0) * tau, -2)
    best = (np.inf, 0.0, length, SPREADS_MM[0])
    ends = screw_ends_mm(o, travel_mm)
    for spread in SPREADS_MM:
        prof = TravelProfile(spread_mm=spread, memory_mm=memory, screw_mm=ends)
        # Δa at a point past all the heat: the whole elongation, which follows the heat
        # put in wherever the zone is (a point inside the travel would see only the share
        # of heat between it and the fixed end, and that depends on where the axis works)
        whole = max(abs(travel_mm[0] - o), abs(travel_mm[1] - o)) + 3.0 * spread
        f = profile_fractions(plan, axis, thermal, prof, travel_mm, whole)[warm]
        model = d_heat[:, j] * f + d_fade[:, j] * lever / whole
        c, _ = _ls(model, growth)
        rms = float(np.sqrt(np.mean((growth - c * model)[survey] ** 2)))
        if rms < best[0]:
            best = (rms, c, whole, spread)
    profiled = best[0] < PROFILE_SHARE * lin_rms and (lin_rms - best[0]) * UM_PER_MM > NOISE_UM
    rms, c, length_fit, spread = best if profiled else (lin_rms, c_lin, length, None)
    if not c > 0:
        raise TableError(f"{raw.source}: axis {axis}: the growth does not follow the travel")
    return WarmupHeatFit(axis, o, float(length_fit), float(c * UM_PER_MM), tau,
                         spread, float(memory), float(rms * UM_PER_MM),
                         float(sensor_rms * UM_PER_MM),
                         float(np.abs(growth).max() * UM_PER_MM), times is not None,
                         ends if profiled else None)  # fmt: skip
