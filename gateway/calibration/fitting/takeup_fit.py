"""How a reversal takes up the lost motion: the plans that measure and judge it, its fit.

Seed 000's backlash readings give the whole lost motion L at three places: each − reading
comes back from 5 mm further on. A nut that engages softly shows only part of L after a
short reversal, and the gateway's full switch then overshoots by the rest. At the same
places this plan reverses by a ladder of motor distances m (5 µm to 1.3 mm): from P
approached in +, on to P + m, back to P. The lost motion shown, ℓ(m), is the − reading
less the + one at the same place (pitch and cyclic errors cancel); the table reversed by
r = m − ℓ(m). The curve the gateway uses (:class:`~gateway.compensation.TakeUpCurve`) is
ℓ/L against r, made nondecreasing.

Pure: plans and arrays in, a fit out.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.interpolate import PchipInterpolator

from ...compensation import TakeUpCurve
from ...compensation.errors import TableError
from ..plans.plans import BacklashResult, Move, Plan, _meta, _round, backlash_plan
from ..plans.rawdata import RawData, axis_deviations
from ..plans.runner import read_raw_meta

#: the motor reversals tried (mm): from a few pulses to past any soft engagement we met
RUNGS_MM = (0.005, 0.01, 0.02, 0.04, 0.08, 0.16, 0.32, 0.64, 1.28)
#: below this lost motion (µm) no reversal can miss by much: the ladder is not run
MIN_LOST_UM = 2.0
#: a full switch that misses by less than this (µm) at every rung keeps the switch
MIN_MISS_UM = 1.0


def takeup_plan(axis: str, travel_mm: Sequence[float], rungs_mm: Sequence[float] = RUNGS_MM,
                approach_mm: float = 5.0, speed_mm_s: float | None = None) -> Plan:  # fmt: skip
    """At each of seed 000's three backlash places P (:func:`..plans.plans.backlash_plan`'s: the
    whole lost motion there is what each rung is a fraction of), per rung m (run number =
    rung): from P − ``approach_mm`` to P in + (the play taken up), measure; on to P + m;
    back to P in −, measure."""
    lo, hi = float(travel_mm[0]), float(travel_mm[1])
    moves: list[Move] = []
    for p in np.unique(backlash_plan(axis, (lo, hi)).targets_mm()):
        below = float(_round(max(lo, p - approach_mm)))
        for k, m in enumerate(rungs_mm, start=1):
            above = float(_round(p + m))
            if above > hi:
                raise ValueError(f"take-up place {p:g} mm + {m:g} mm leaves the travel")
            moves += [Move(k, 0, "takeup", (below,), speed_mm_s),
                      Move(k, +1, "measure", (float(p),), speed_mm_s),
                      Move(k, +1, "away", (above,), speed_mm_s),
                      Move(k, -1, "measure", (float(p),), speed_mm_s)]  # fmt: skip
    meta = _meta(kind="takeup", axis=axis, travel_mm=(lo, hi),
                 rungs_mm=tuple(float(m) for m in rungs_mm), approach_mm=approach_mm)
    return Plan("takeup", (axis,), tuple(moves), meta)


def short_steps_plan(axis: str, travel_mm: Sequence[float], seed: int, count: int = 24,
                     approach_mm: float = 5.0) -> Plan:  # fmt: skip
    """Random short steps, 5 µm to 2 mm (log-uniform) either way, from a random place in the
    middle half of the travel, every stop measured (run number = stop): where a reversal
    takes up only part of the play, what a drilling pattern does and no ISO run does. The
    first stop is approached in + from ``approach_mm`` below."""
    lo, hi = float(travel_mm[0]), float(travel_mm[1])
    rng = np.random.default_rng(seed)
    x = float(_round(rng.uniform(lo + 0.25 * (hi - lo), hi - 0.25 * (hi - lo))))
    moves = [Move(0, 0, "takeup", (float(_round(max(lo, x - approach_mm))),)),
             Move(1, +1, "measure", (x,))]  # fmt: skip
    for k in range(2, count + 1):
        step = float(10 ** rng.uniform(np.log10(0.005), np.log10(2.0)))
        sign = 1 if rng.random() < 0.5 else -1
        if not lo <= x + sign * step <= hi:
            sign = -sign
        x = float(_round(x + sign * step))
        moves.append(Move(k, sign, "measure", (x,)))
    meta = _meta(kind="short-steps", axis=axis, travel_mm=(lo, hi), seed=seed, count=count)
    return Plan("short-steps", (axis,), tuple(moves), meta)


@dataclass(frozen=True, eq=False)
class TakeUpFit:
    """Per rung: motor reversal, table reversal (median over places), fraction of the full
    lost motion shown (median) and its spread over places; the full lost motion (µm, mean of
    the places); the curve (None: the full switch is right within ``MIN_MISS_UM``), the
    largest miss of a full switch (µm) and why the curve was or was not kept."""

    motor_mm: NDArray[np.float64]
    table_mm: NDArray[np.float64]
    fraction: NDArray[np.float64]
    spread: NDArray[np.float64]
    lost_um: float
    curve: TakeUpCurve | None
    miss_um: float
    why: str

    def config(self) -> dict[str, list[float]] | None:
        """The ``compensation.takeup`` section (reversals to 0.01 µm, fractions to 4
        decimals), or None: the switch is kept."""
        if self.curve is None:
            return None
        return {"reversal_um": [round(float(r) * 1e3, 2) for r in self.curve.reversal_mm],
                "fraction": [round(float(f), 4) for f in self.curve.fraction]}


def fit_takeup(motor_mm: ArrayLike, lost_mm: ArrayLike, full_mm: ArrayLike,
               noise_mm: float, approach_mm: float = 5.0) -> TakeUpFit:  # fmt: skip
    """The take-up curve from ``lost_mm`` [place, rung] (− less + reading after a reversal
    of ``motor_mm`` [rung]), the whole lost motion ``full_mm`` [place] and one reading's
    scatter ``noise_mm``. Rungs whose table did not move (still in a dead band: r below
    two scatters) say only that the fraction there is at least what they show; the rest
    are the curve. The last point is 1: the rung that shows it, else the backlash
    readings' ``approach_mm``."""
    m = np.asarray(motor_mm, dtype=np.float64)
    lost = np.atleast_2d(np.asarray(lost_mm, dtype=np.float64))
    full = np.asarray(full_mm, dtype=np.float64).reshape(-1)
    usable = full > max(2.0 * noise_mm, 1e-9)
    if not usable.any():
        return _switch_kept(m, lost, full, "no place with a lost motion above the scatter")
    frac = lost[usable] / full[usable, None]
    # the median over the places: one stop that fell short (stick-slip) does not make a dip
    f = np.nanmedian(frac, axis=0)
    spread = np.nanstd(frac, axis=0, ddof=1) if frac.shape[0] > 1 else np.zeros_like(f)
    big = float(full[usable].mean())
    r = m - np.nanmedian(lost[usable], axis=0)
    moved = r > max(2.0 * noise_mm, 1e-4)
    if not moved.any():
        return TakeUpFit(m, r, f, spread, big * 1e3, None, 0.0,
                         "no rung moved the table (a dead band: the full switch is right)")
    from scipy.optimize import isotonic_regression  # (0.3 s to import: not on every start)

    rr, ff = r[moved], np.clip(isotonic_regression(f[moved]).x, 0.0, 1.0)
    keep = np.concatenate([[True], np.diff(rr) > 0])  # a table reversal once
    rr, ff = rr[keep], ff[keep]
    miss = float(((1.0 - ff) * big).max()) * 1e3
    # what the rungs' own scatter allows: the fraction's spread, or one reading's twice
    slack_um = max(MIN_MISS_UM, 2e3 * max(float(spread[moved].max()) * big, noise_mm))
    if miss <= slack_um:
        return TakeUpFit(m, r, f, spread, big * 1e3, None, miss,
                         f"a full switch misses by at most {miss:.2f} µm "
                         f"(within {slack_um:.2f} µm)")  # fmt: skip
    if ff[-1] >= 1.0 - 2.0 * max(noise_mm / big, float(spread[moved].max())):
        ff[-1] = 1.0
    else:
        rr, ff = np.append(rr, max(approach_mm - big, rr[-1] * 2)), np.append(ff, 1.0)
    curve = TakeUpCurve(*_between(rr, np.minimum(ff, 1.0)))
    return TakeUpFit(m, r, f, spread, big * 1e3, curve, miss,
                     f"a full switch misses by up to {miss:.1f} µm")


def full_takeup_um(section: dict[str, list[float]], level: float = 0.99) -> float:
    """The reversal (µm) by which a take-up section shows the whole lost motion (``level``
    of it): its first point that does, not its last (trial: "taken up over a reversal of
    about 1269 µm" where the ladder showed all of it by the 40 µm rung)."""
    reversal, fraction = section["reversal_um"], section["fraction"]
    return next((r for r, f in zip(reversal, fraction, strict=True) if f >= level),
                reversal[-1])  # fmt: skip


def _between(r_mm: NDArray[np.float64], f: NDArray[np.float64], sub: int = 4
             ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:  # fmt: skip
    """The rungs' points with ``sub`` − 1 more between each two, on the monotone cubic
    (PCHIP) through them: the gateway interpolates a curve linearly, and straight lines
    between rungs a factor 2 apart miss a soft engagement's bend by up to 4 % of the lost
    motion (0.8-1.0 µm RMS on random short steps of a 40-70 µm play; 0.25-0.34 µm so)."""
    if r_mm.size < 3:
        return r_mm, f
    t = np.linspace(0.0, 1.0, sub + 1)[:-1]
    dense = np.concatenate([(r_mm[:-1, None] + np.diff(r_mm)[:, None] * t).ravel(), r_mm[-1:]])
    values = np.clip(PchipInterpolator(r_mm, f)(dense), 0.0, 1.0)
    values[::sub] = f  # exact at the rungs
    return dense, np.maximum.accumulate(values)


def _switch_kept(m: NDArray[np.float64], lost: NDArray[np.float64],
                 full: NDArray[np.float64], why: str) -> TakeUpFit:  # fmt: skip
    nan = np.full(m.shape, np.nan)
    return TakeUpFit(m, m - np.nanmean(lost, axis=0), nan, nan,
                     float(np.mean(full)) * 1e3, None, 0.0, why)


def fit_takeup_raw(raw: RawData, axis: str, backlash: BacklashResult,
                   rungs_mm: Sequence[float] | None = None) -> TakeUpFit:  # fmt: skip
    """:func:`fit_takeup` from a :func:`takeup_plan`'s raw data and seed 000's ``backlash``
    result at the same places (the whole lost motion there; one reading's scatter from its
    repeats, whose lost motion is two readings apart). ``rungs_mm``: the plan's (default:
    the raw file's own ``rungs_mm``, else :data:`RUNGS_MM`)."""
    dev = axis_deviations(raw, axis)
    if dev.up_mm is None or dev.down_mm is None:
        raise TableError(f"{dev.source}: axis {axis}: take-up needs readings in + and -")
    if rungs_mm is None:
        text = read_raw_meta(raw.source).get("rungs_mm") if raw.source != "<raw>" else None
        rungs_mm = [float(v) for v in text.split()] if text else RUNGS_MM
    full_at = dict(zip(map(float, backlash.place_mm), map(float, backlash.mean_mm)))
    full = []
    for p in (float(p) for p in dev.target_mm):
        near = min(full_at, key=lambda q: abs(q - p))
        if abs(near - p) > 1e-3:
            raise TableError(f"{dev.source}: take-up place {p:g} mm has no backlash reading")
        full.append(full_at[near])
    motor = np.array([rungs_mm[int(j) - 1] for j in dev.runs])
    noise_mm = float(np.sqrt(np.mean(backlash.std_mm**2) / 2.0))
    return fit_takeup(motor, dev.down_mm - dev.up_mm, full, noise_mm)
