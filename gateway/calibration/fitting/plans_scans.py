"""Plans that dwell on places: the thermal warm-up (seed 002) and the dense scans of the
once-per-lead screw error at a few stations (issue 7); :class:`..plans.plans.Plan`'s file format."""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

from ...compensation.errors import TableError
from ..plans.plans import Move, Plan, _meta, _round, _travel
from .cyclic_fit import DENSE_LEAST_PER_LEAD, dense_scan_targets

# -- warm-up (seed 002) ---------------------------------------------------------------------
#: the shortest + approach of a warm-up's reference from the cycle's lower end (mm): more
#: than any play, so every reading has it taken up the same way
WARMUP_APPROACH_MM = 1.0


def warmup_plan(
    axis: str,
    ends_mm: Sequence[float],
    speed_mm_s: float,
    duration_s: float,
    reference_mm: float,
    measure_every: int = 5,
    dwell_s: float = 1.0,
    places_mm: Sequence[float] = (),
    also_mm: float | None = None,
    sensor: bool = True,
) -> Plan:
    """Repeated long moves between ``ends_mm`` at ``speed_mm_s`` for about ``duration_s``.

    A measuring stop at ``reference_mm`` (approached in +, from the lower end) before the
    first cycle, every ``measure_every`` cycles and after the last: the growth of the screw
    against the Δa sensor. Run number = cycle (0 for the cold reading). ``places_mm`` (a
    zone warm-up, ``ends_mm`` inside the travel) are read cold and after the last cycle too,
    each approached in + from 1 mm below: where the growth is, inside the zone and beyond.
    ``also_mm`` (with places): a second reference, read right after the first each time
    (with no sensor the fixed end is not known: one of the two is far from it).
    ``sensor`` False: the laser's readings alone (heat from motion), no sensor column.
    """
    a, b = _travel(ends_mm)
    if speed_mm_s <= 0 or duration_s <= 0 or measure_every < 1:
        raise ValueError("speed_mm_s, duration_s and measure_every must be positive")
    cycles = max(1, math.ceil(duration_s * speed_mm_s / (2 * (b - a))))
    ref = float(_round(reference_mm))
    if not places_mm and not a + WARMUP_APPROACH_MM <= ref <= b:
        raise ValueError(f"warm-up reference {ref:g} mm: it must lie in {a:g}..{b:g} mm and at "
                         f"least {WARMUP_APPROACH_MM:g} mm above the lower end {a:g} mm, so "
                         "every reading there is approached in + (the play taken up alike)")
    places = sorted(float(_round(p)) for p in places_mm)

    def survey(run: int) -> list[Move]:  # every place, each from 1 mm below, then back
        out: list[Move] = []
        for p in places:
            out += [Move(run, -1, "move", (p - WARMUP_APPROACH_MM,), speed_mm_s),
                    Move(run, +1, "measure", (p,), None, dwell_s)]  # fmt: skip
        return out

    refs = [ref] + ([float(_round(also_mm))] if also_mm is not None and places else [])

    def at_ref(run: int) -> list[Move]:
        out: list[Move] = []
        for r in refs:
            if places:
                out.append(Move(run, -1, "move", (r - WARMUP_APPROACH_MM,), speed_mm_s))
            out.append(Move(run, +1, "measure", (r,), None, dwell_s))
        return out

    moves: list[Move] = [*survey(0), Move(0, -1, "move", (a,), speed_mm_s), *at_ref(0)]
    for k in range(1, cycles + 1):
        if places and moves[-1].target_mm != (a,):  # the zone entered from its lower end
            moves.append(Move(k, -1, "move", (a,), speed_mm_s))  # (not a move to where it is)
        moves += [Move(k, +1, "move", (b,), speed_mm_s), Move(k, -1, "move", (a,), speed_mm_s)]
        if k % measure_every == 0 or k == cycles:
            moves += at_ref(k)
    moves += survey(cycles)
    meta = _meta(kind="warmup", axis=axis, ends_mm=(a, b), speed_mm_s=speed_mm_s,
                 duration_s=duration_s, reference_mm=ref, measure_every=measure_every,
                 cycles=cycles, places_mm=places or None,
                 also_mm=refs[1] if len(refs) > 1 else None,
                 sensor=None if sensor else "none")  # fmt: skip
    return Plan("warmup", (axis,), tuple(moves), meta)


# -- cyclic screw error (issue 7) ---------------------------------------------------------
#: Default stations of the dense scans, as fractions of the travel.
CYCLIC_STATIONS = (0.15, 0.50, 0.85)


def cyclic_stations_mm(
    travel_mm: Sequence[float],
    lead_mm: float,
    stations_mm: Sequence[float] | None = None,
    leads: float = 2.0,
    takeup_mm: float = 1.0,
) -> NDArray[np.float64]:
    """Centres of the dense scans: given, or 15 %, 50 %, 85 % of the travel; each moved just
    far enough inside the travel for its scan and take-up moves to fit."""
    lo, hi = _travel(travel_mm)
    if stations_mm is None:
        stations_mm = [lo + f * (hi - lo) for f in CYCLIC_STATIONS]
    half = 0.5 * leads * lead_mm + takeup_mm
    if hi - lo < 2 * half:
        raise ValueError(f"travel {lo:g}..{hi:g} mm is shorter than one dense scan "
                         f"({2 * half:g} mm)")  # fmt: skip
    out = _round(np.clip(np.asarray(stations_mm, dtype=np.float64), lo + half, hi - half))
    if out.size < 1 or np.any(np.diff(out) <= 0):
        raise ValueError(f"stations {list(stations_mm)}: need distinct, increasing positions")
    return out


def cyclic_plan(
    axis: str,
    travel_mm: Sequence[float],
    lead_mm: float,
    stations_mm: Sequence[float] | None = None,
    per_lead: int = 16,
    leads: float = 2.0,
    takeup_mm: float = 1.0,
    speed_mm_s: float | None = None,
    dwell_s: float | None = None,
    kind: str = "cyclic",
    both_ways: bool = True,
    least_per_lead: int = DENSE_LEAST_PER_LEAD,
) -> Plan:
    """Dense scans for the cyclic (once-per-lead) screw error, issue 7.

    At each station (default 15 %, 50 %, 85 % of the travel): a ``takeup`` move
    ``takeup_mm`` below the scan, then ``per_lead`` (≥ ``least_per_lead``) points per lead
    over ``leads`` (≥ 2) leads measured going up (+); with ``both_ways``, a ``takeup`` move
    ``takeup_mm`` above, then the same points measured going down (−). The take-up distance
    must exceed the backlash, so every point of a direction is approached with the play
    taken up the same way. Run number = station number (1, 2, …), so each scan is one run
    of the raw file. (One way: the term is the screw's, the same both ways; the scan costs
    half.)

    ``kind="refine-scan"``: commissioning's short scans (``per_lead`` ≥ 8 over ``leads`` ≥ 1)
    that give a new table point its value as a mean over whole leads (no cyclic term
    aliased into it) and the cyclic term a new station.
    """
    def scan_targets(station: float) -> NDArray[np.float64]:
        if kind == "cyclic":
            return dense_scan_targets(station, lead_mm, per_lead=per_lead, leads=leads,
                                      least_per_lead=least_per_lead)  # fmt: skip
        if per_lead < 8 or leads < 1:
            raise TableError("a refinement scan needs ≥ 8 points per lead over ≥ 1 lead")
        half = 0.5 * leads * lead_mm
        return np.linspace(station - half, station + half, round(per_lead * leads) + 1)

    if not (math.isfinite(lead_mm) and lead_mm > 0):
        raise ValueError(f"lead_mm {lead_mm!r} must be > 0")
    if takeup_mm <= 0:
        raise ValueError("takeup_mm must be > 0 (it takes up the backlash)")
    lo, hi = _travel(travel_mm)
    stations = cyclic_stations_mm((lo, hi), lead_mm, stations_mm, leads, takeup_mm)
    moves: list[Move] = []
    for j, station in enumerate(stations, start=1):
        try:
            targets = _round(scan_targets(float(station)))
        except TableError as exc:
            raise ValueError(str(exc)) from None
        below = float(_round(max(lo, targets[0] - takeup_mm)))
        above = float(_round(min(hi, targets[-1] + takeup_mm)))
        moves.append(Move(j, -1, "takeup", (below,), speed_mm_s))
        moves += [Move(j, +1, "measure", (float(t),), speed_mm_s, dwell_s) for t in targets]
        if not both_ways:
            continue
        moves.append(Move(j, +1, "takeup", (above,), speed_mm_s))
        moves += [
            Move(j, -1, "measure", (float(t),), speed_mm_s, dwell_s) for t in targets[::-1]
        ]
    meta = _meta(
        kind=kind, axis=axis, travel_mm=(lo, hi), lead_mm=float(lead_mm),
        stations_mm=tuple(float(s) for s in stations), per_lead=per_lead,
        leads=float(leads), takeup_mm=float(takeup_mm),
    )  # fmt: skip
    return Plan(kind, (axis,), tuple(moves), meta)


# -- the whole travel, densely (commissioning's sweep) -------------------------------------
def sweep_plan(axis: str, travel_mm: Sequence[float], targets_mm: Sequence[float],
               piece_mm: float = 120.0, overrun_mm: float = 1.0) -> Plan:  # fmt: skip
    """Commissioning's sweep: ``targets_mm`` (dense, over the whole travel) cut into pieces
    about ``piece_mm`` long; each piece one run, its targets measured going up (+) from an
    overrun point below it, then going down (−) from one above. Short runs keep each
    between its own drift references, and a resume loses at most one piece."""
    lo, hi = _travel(travel_mm)
    targets = _round(np.sort(np.asarray(targets_mm, dtype=np.float64)))
    if targets.size < 2 or targets[0] < lo or targets[-1] > hi:
        raise ValueError(f"a sweep needs ≥ 2 targets in the travel {lo:g}..{hi:g} mm")
    pieces = max(1, round(float(targets[-1] - targets[0]) / piece_mm))
    moves: list[Move] = []
    for j, chunk in enumerate(np.array_split(targets, pieces), start=1):
        below = float(_round(max(lo, chunk[0] - overrun_mm)))
        above = float(_round(min(hi, chunk[-1] + overrun_mm)))
        moves.append(Move(j, -1, "overrun", (below,)))
        moves += [Move(j, +1, "measure", (float(t),)) for t in chunk]
        moves.append(Move(j, +1, "overrun", (above,)))
        moves += [Move(j, -1, "measure", (float(t),)) for t in chunk[::-1]]
    return Plan("sweep", (axis,), tuple(moves),
                _meta(kind="sweep", axis=axis, travel_mm=(lo, hi), pieces=pieces))
