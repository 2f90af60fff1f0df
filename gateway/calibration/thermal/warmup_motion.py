"""Heat from motion fitted to a zone warm-up on an axis with no thermal sensor.

Without a sensor, the drift references read between commissioning's runs are all that
shows the screw's heat, and those runs heat it in a way that hardly pins how fast it
cools (τ) or where the screw is fixed. A zone warm-up read by the laser itself does: the
axis strokes a zone (the middle of its travel) for a set time, two references beyond the
zone, one on each side, are read every few strokes (the rise over time: τ), and places
inside and beyond the zone are read cold and warm (the shape: linear from the screw's
fixed end, or where the nut worked).

The model is the gateway's own heat from motion (:func:`~gateway.compensation.thermal.
motion_heat_m`): growth(x) = c · H · lever(x), H the heat in metres of travel with τ. For
each τ on a grid the linear shape is a least-squares fit in (c, c · fixed end, each
reference's cold value); the τ with the least residual wins. The travel profile (heat
spread where the axis travelled) is tried at that τ with the fixed end on the side the
linear fit found, and taken when it leaves clearly less at the places surveyed warm (or
just less, where the linear fit's fixed end lies at the travel's end or inside it).
Pure: readings and a plan in, numbers out.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ...compensation.errors import TableError
from ...config import AxisThermal, MotionHeat, TravelProfile
from ..plans.plans import Plan
from ..plans.rawdata import RawData
from .heat_fit import FAR_ENDS, MAX_RESIDUAL_SHARE, TAU_GRID_S, likely_tau
from .thermal_shape import (
    NOISE_UM,
    PROFILE_SHARE,
    SPREADS_MM,
    profile_fractions,
    screw_ends_mm,
    survey_changes,
)
from .warmup_heat import heat_changes, motion_section, readings_clock_s

UM_PER_MM = 1000.0
#: growth (µm) below which a warm-up shows nothing worth a model
MIN_GROWTH_UM = 3.0
#: a linear fit's fixed end this share of the travel beyond its end or less is "at the
#: end": the profile is taken where it leaves less (:func:`_near_ends`)
NEAR_END_SHARE = 0.05
#: a place read once cold and once warm carries two readings' scatter (√2 σ); over a
#: handful of places a right model leaves up to 1.5 times that (a χ of 5-7 degrees of
#: freedom, 95 %): no fit is refused for leaving less (:func:`_scatter`)
SURVEY_SCATTER = 1.5 * np.sqrt(2.0)
#: ... where the growth fitted stands out of one reading's scatter this many times (a plate
#: of 1 µm repeatability that grew 3 µm in its warm-up stays refused)
STANDS_OUT = 4.0


@dataclass(frozen=True)
class WarmupMotionFit:
    """Heat from motion as a zone warm-up showed it on an axis with no sensor."""

    axis: str
    origin_mm: float  # the screw's fixed end, axis coordinates
    length_mm: float
    delta_a_um_per_m: float  # Δa at length_mm per metre of travel whose heat is in the screw
    tau_s: float
    spread_mm: float | None  # the travel profile's; None: linear from the fixed end
    memory_mm: float
    linear_rms_um: float  # at the places surveyed warm
    profile_rms_um: float
    growth_max_um: float
    points: int
    timed: bool = False  # by the readings' own clock (:func:`readings_clock_s`)
    screw_mm: tuple[float, float] | None = None  # the profile's (:func:`screw_ends_mm`)

    @property
    def rms_um(self) -> float:
        """What the chosen shape leaves at the places surveyed warm (µm RMS)."""
        return self.profile_rms_um if self.spread_mm is not None else self.linear_rms_um

    def config(self, speeds_mm_s: dict[str, float] | None = None) -> dict[str, Any]:
        """The axis's ``compensation.thermal`` section (no source). Fitted on the readings'
        own clock, it needs no speeds (``speeds_mm_s`` None: the gateway counts the
        clock alone)."""
        return motion_section(self.origin_mm, self.length_mm, self.delta_a_um_per_m,
                              self.tau_s, self.spread_mm, self.memory_mm, speeds_mm_s or {},
                              self.screw_mm)  # fmt: skip

    def summary(self) -> dict[str, Any]:
        return {"tau_s": self.tau_s, "origin_mm": self.origin_mm,
                "delta_a_um_per_m": self.delta_a_um_per_m, "spread_mm": self.spread_mm,
                "linear_rms_um": self.linear_rms_um, "profile_rms_um": self.profile_rms_um,
                "growth_max_um": self.growth_max_um, "points": self.points}  # fmt: skip


def _lstsq(design: NDArray[np.float64], y: NDArray[np.float64]
           ) -> tuple[NDArray[np.float64], float]:  # fmt: skip
    coef, *_ = np.linalg.lstsq(design, y, rcond=None)
    return coef, float(np.sum((y - design @ coef) ** 2))


def _cold_offsets(place: NDArray[np.float64]) -> NDArray[np.float64]:
    """One column per reference (a place read warm more than once): 1 on its readings.
    Its growth is counted from one cold reading, whose scatter every later reading there
    carries; fitted as an offset, its cold value rests on all of them. smooth-2's 150 mm
    Y grew 3.4 µm in its warm-up: with two references read from one cold reading each
    (±0.45 µm) its fixed end came out at −28 mm, −48 with the offsets (the sim's −59);
    over the bench's eleven smooth no-sensor warm-ups the fixed end moved nearer the sim's
    on seven, 1-3 mm further on three."""
    places, counts = np.unique(place, return_counts=True)
    refs = places[counts > 1]
    return (place[:, None] == refs[None, :]).astype(np.float64)


def _scatter(left: NDArray[np.float64], refs: NDArray[np.float64]) -> float:
    """One reading's scatter (mm, σ), from what the fit leaves at the references' many
    readings (``left``; ``refs`` their offset columns). A light growth read at the noise
    (smooth-2's Y: 3.4 µm, 0.45 µm a stop) leaves the noise at its places read once cold,
    once warm: over forty draws of such a warm-up, half its growth's RMS refused three fits
    that were right; this refuses one. 0 where the references are too few to tell."""
    rows = refs.any(axis=1)
    dof = int(rows.sum()) - 2 - refs.shape[1]
    return float(np.sqrt(np.sum(left[rows] ** 2) / dof)) if dof > 0 else 0.0


def _near_ends(origin_mm: float, lo: float, hi: float) -> bool:
    """A linear fit's fixed end just beyond the travel's (within NEAR_END_SHARE of it):
    the zone's growth fading towards that end fits it about as well as a fixed end there.
    Rough-7's Y with its references' cold values fitted: −3 mm of 0-450, linear, where the
    profile left half the residual."""
    margin = NEAR_END_SHARE * (hi - lo)
    return lo - margin <= origin_mm <= lo or hi <= origin_mm <= hi + margin


def warmup_motion_fit(raw: RawData, plan: Plan, axis: str, travel_mm: tuple[float, float],
                      prior_m: ArrayLike = (), prior_s: ArrayLike = (),
                      clock: tuple[str, ...] = ("time_s",)) -> WarmupMotionFit:  # fmt: skip
    """Heat from motion (τ, fixed end, Δa per metre, linear or profiled) from a zone warm-up
    with no sensor column (``plan`` as it ran: its measured stops are ``raw``'s rows of
    ``axis`` in order). ``prior_m``, ``prior_s``: the axis's travel (m) and time (s), stretch
    by stretch, since the screw was last cold and before the warm-up (still fading in it).
    ``clock``: the raw columns that may time the stops (:func:`readings_clock_s`).
    Raises TableError (naming file and axis) where the warm-up shows no heat to model."""
    warm, first, place, growth, _ = survey_changes(raw, axis, None)
    measured = sum(m.measured for m in plan.moves)
    if measured != int(np.sum(np.array(raw.axis) == axis)):
        raise TableError(f"{raw.source}: axis {axis}: {measured} stops planned, not the rows "
                         "read: the warm-up did not run as planned")  # fmt: skip
    if not np.ptp(growth) * UM_PER_MM >= MIN_GROWTH_UM:
        raise TableError(f"{raw.source}: axis {axis}: the warm-up's growth is under "
                         f"{MIN_GROWTH_UM:g} µm: too little heat to model")  # fmt: skip
    times = readings_clock_s(raw, plan, axis, clock)
    d_heat, d_fade = heat_changes(plan, axis, warm, first, prior_m, prior_s, times)
    heat = d_heat + d_fade  # (readings, τ): metres of travel still in the screw, as changed
    refs = _cold_offsets(place)
    designs = [np.column_stack([heat[:, j] * place, heat[:, j], refs])
               for j in range(TAU_GRID_S.size)]  # fmt: skip
    fits = [_lstsq(d, growth) for d in designs]
    j = likely_tau([sse for _, sse in fits])
    scatter = _scatter(growth - designs[j] @ fits[j][0], refs)
    if np.ptp(designs[j][:, :2] @ fits[j][0][:2]) < STANDS_OUT * scatter:
        scatter = 0.0  # a growth within a few readings' scatter: half of it must go
    growth = growth - refs @ fits[j][0][2:]  # each reference's cold reading, as fitted
    if j == TAU_GRID_S.size - 1:
        raise TableError(f"{raw.source}: axis {axis}: the warm-up's growth does not level off: "
                         "no time constant (a longer --warmup-min shows it)")  # fmt: skip
    per_mm, offset = fits[j][0][:2]  # growth = per_mm · H · (x − origin)
    if not per_mm > 0:
        raise TableError(f"{raw.source}: axis {axis}: the growth does not follow the travel "
                         "(a screw that shrinks with use: still cooling from before?)")
    origin = -offset / per_mm
    lo, hi = travel_mm
    if not lo - FAR_ENDS * (hi - lo) <= origin <= hi + FAR_ENDS * (hi - lo):
        raise TableError(f"{raw.source}: axis {axis}: the warm-up puts the screw's fixed end "
                         f"at {origin:.0f} mm, far off the travel: not the screw's growth")
    tau = float(TAU_GRID_S[j])
    # the places read once cold and once warm (the references' series cannot tell a shape)
    places, counts = np.unique(place, return_counts=True)
    survey = np.isin(place, places[counts == 1])
    if not survey.any():
        survey = np.ones(place.size, dtype=bool)
    length = max(abs(lo - origin), abs(hi - origin))
    lin_rms = float(np.sqrt(np.mean((growth - per_mm * heat[:, j] * (place - origin))[survey]
                                    ** 2)))  # fmt: skip
    # the profile: the fixed end on the side the linear fit put it (inside the travel, the
    # growth was flat there: the nearer end of the travel)
    fixed = (origin if not (lo < origin < hi or _near_ends(origin, lo, hi))
             else (lo if origin - lo < hi - origin else hi))  # fmt: skip
    speed = float(dict(plan.meta).get("speed_mm_s", 0) or 0)
    memory = round(max(speed, 1.0) * tau, -2)
    base = AxisThermal(motion=MotionHeat(delta_a_um_per_m=1.0, tau_s=tau),
                       origin_mm=fixed, length_mm=max(length, 1.0))  # fmt: skip
    best = (np.inf, 0.0, length, SPREADS_MM[0])
    ends = screw_ends_mm(fixed, travel_mm)
    for spread in SPREADS_MM:
        prof = TravelProfile(spread_mm=spread, memory_mm=memory, screw_mm=ends)
        whole = max(abs(lo - fixed), abs(hi - fixed)) + 3.0 * spread
        f = profile_fractions(plan, axis, base, prof, travel_mm, whole)[warm]
        model = d_heat[:, j] * f + d_fade[:, j] * (place - fixed) / whole
        coef, _ = _lstsq(model[:, None], growth)
        rms = float(np.sqrt(np.mean((growth - coef[0] * model)[survey] ** 2)))
        if rms < best[0] and coef[0] > 0:
            best = (rms, float(coef[0]), whole, spread)
    prof_rms, c_prof, whole, spread = best
    profiled = prof_rms < PROFILE_SHARE * lin_rms and (lin_rms - prof_rms) * UM_PER_MM > NOISE_UM
    if _near_ends(origin, lo, hi):  # the end may lie on either side of it: the shapes decide
        profiled = prof_rms < lin_rms
    if lo < origin < hi:
        # a linear growth that changes sign inside the travel is no screw's (heat only
        # lengthens it from its fixed end): the zone's shape. Linear from the nearer end,
        # or the profile, whichever leaves less (rough-0 X: the fit put the end at 638 mm
        # of 700 and kept it linear: 37 % of the judge's warm-up left; its own heat
        # equation synthesised, 29-61 % so, the profile 1-12 %)
        lever = heat[:, j] * (place - fixed)
        (per_mm,), _ = _lstsq(lever[:, None], growth)
        origin, length = fixed, max(abs(lo - fixed), abs(hi - fixed))
        lin_rms = float(np.sqrt(np.mean((growth - per_mm * lever)[survey] ** 2)))
        profiled = prof_rms < lin_rms
    seen = float(np.sqrt(np.mean(growth[survey] ** 2)))
    if min(lin_rms, prof_rms) > max(MAX_RESIDUAL_SHARE * seen, SURVEY_SCATTER * scatter):
        raise TableError(f"{raw.source}: axis {axis}: heat from motion leaves "
                         f"{min(lin_rms, prof_rms) * UM_PER_MM:.1f} µm RMS of the "
                         f"{seen * UM_PER_MM:.1f} µm the places grew, where the readings' "
                         f"scatter explains {SURVEY_SCATTER * scatter * UM_PER_MM:.1f}: not "
                         "the screw's heat")  # fmt: skip
    if profiled:
        return WarmupMotionFit(axis, float(fixed), float(whole), c_prof * UM_PER_MM, tau,
                               spread, float(memory), lin_rms * UM_PER_MM,
                               prof_rms * UM_PER_MM, float(np.abs(growth).max() * UM_PER_MM),
                               int(warm.size), times is not None, ends)  # fmt: skip
    return WarmupMotionFit(axis, float(origin), float(length),
                           float(per_mm * length * UM_PER_MM), tau, None, float(memory),
                           lin_rms * UM_PER_MM, prof_rms * UM_PER_MM,
                           float(np.abs(growth).max() * UM_PER_MM), int(warm.size),
                           times is not None)  # fmt: skip
