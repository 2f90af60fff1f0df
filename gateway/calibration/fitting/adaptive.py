"""Adaptive calibration, the pure part: how coarse to start, how to judge a verification
run, where to refine, and the refined table (``compgw commission``; I/O in
:mod:`..commissioning.commission`).

Judging happens where the machine will be used: at verification targets that were never
used to fit anything (midpoints of the table's spans and seeded random targets). A
verification residual that stands out of the machine's repeatability, from the run's own
median, marks the table span it lies in as failing; failing spans get the midpoint as a
new table point, whose value is the table's own value there plus the residual measured
with compensation on (seed 001's fold, at a new point). Positions are mm, deviations mm
unless the name says µm.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from ...compensation import Chain, PitchStage, PitchTable
from ...compensation.cyclic import CyclicModel
from ...compensation.thermal import ThermalStage, delta_a_from_temperature
from ..plans.rawdata import AxisDeviations, RawData
from ..thermal.drift_shape import shaped_drift_mm
from .cyclic_fit import StationScan
from .iso230 import iso230_axis

#: the coarse table: about this many points over the travel, at least this far apart
COARSE_POINTS = 21
#: the fewest targets ISO 230-2 takes along an axis (a short budget's least)
ISO_LEAST_POINTS = 5
#: a plain ISO 230-2 calibration's target spacing (mm; ``compgw calibrate --step-mm``)
PLAIN_STEP_MM = 25.0
#: ... and its runs per target (``compgw calibrate --runs``; ISO 230-2's five)
PLAIN_RUNS = 5
#: random verification targets per axis and round, besides the new spans' midpoints
RANDOM_TARGETS = 16
#: a table never gets points closer than this (mm): below it noise would set the slope
MIN_SPACING_MM = 0.5
#: a failing span is cut into this many pieces: structure a few centimetres long (a screw's
#: waviness) is followed after one refinement, not after several halvings
REFINE_PARTS = 4


def plain_points(travel_mm: Sequence[float], least: int = COARSE_POINTS) -> int:
    """Targets of a plain calibration's table over ``travel_mm`` (one every
    ``PLAIN_STEP_MM``), at least ``least``: what a short budget reads first where it fits,
    since no round of its own will sweep between the points."""
    span_mm = float(travel_mm[1]) - float(travel_mm[0])
    return max(least, math.ceil(span_mm / PLAIN_STEP_MM - 1e-9) + 1)


def coarse_step_mm(travel_mm: Sequence[float], lead_mm: float | None = None,
                   points: int = 0) -> float:  # fmt: skip
    """Nominal spacing of the first table: the travel in ``points`` (default
    ``COARSE_POINTS``) − 1 steps, kept clear of a whole number of leads by the plan (uneven
    spacing)."""
    lo, hi = float(travel_mm[0]), float(travel_mm[1])
    step = (hi - lo) / ((points or COARSE_POINTS) - 1)
    if lead_mm:
        turns = step / lead_mm
        if abs(turns - round(turns)) < 0.1 and turns >= 0.5:
            step = (round(turns) + 0.45) * lead_mm  # a step of whole leads aliases
    return step


def random_targets_mm(
    travel_mm: Sequence[float], count: int, seed: int, avoid_mm: NDArray[np.float64],
    margin_mm: float = 2.0, clearance_mm: float = 0.2, period_mm: float | None = None,
) -> NDArray[np.float64]:  # fmt: skip
    """``count`` seeded random targets inside the travel, each at least ``clearance_mm``
    from every position in ``avoid_mm`` (the table's points: never judged where fitted);
    with ``period_mm`` (a turntable's 360°) the distance is the short way round. The
    clearance is at most 0.4 of the points' median spacing: a swept table's points (every
    0.25 mm or 0.25°) leave no room between them at 0.2."""
    lo, hi = float(travel_mm[0]) + margin_mm, float(travel_mm[1]) - margin_mm
    if avoid_mm.size > 1:
        gaps = np.diff(np.unique(avoid_mm))
        clearance_mm = min(clearance_mm, 0.4 * float(np.median(gaps)))
    rng = np.random.default_rng(seed)
    out: list[float] = []
    for _ in range(200 * count):
        if len(out) == count:
            break
        t = round(float(rng.uniform(lo, hi)), 4)
        d = avoid_mm - t
        if period_mm is not None:
            d = (d + 0.5 * period_mm) % period_mm - 0.5 * period_mm
        if avoid_mm.size == 0 or np.min(np.abs(d)) >= clearance_mm:
            out.append(t)
    return np.sort(np.array(out))


def midpoints_mm(positions_mm: NDArray[np.float64], spans: Sequence[int] | None = None,
                 parts: int = 2) -> NDArray[np.float64]:
    """The points that cut the table spans ``spans`` (indices i of [x_i, x_i+1]; all when
    None) into ``parts`` equal pieces (2: the midpoints), for spans long enough that no
    piece is shorter than ``MIN_SPACING_MM``."""
    x = np.asarray(positions_mm, dtype=np.float64)
    idx = np.arange(x.size - 1) if spans is None else np.asarray(sorted(set(spans)), dtype=int)
    idx = idx[(x[idx + 1] - x[idx]) >= parts * MIN_SPACING_MM] if idx.size else idx
    f = np.arange(1, parts) / parts
    return np.round((x[idx, None] + (x[idx + 1] - x[idx])[:, None] * f).ravel(), 4)


@dataclass(frozen=True)
class AxisVerdict:
    """What a verification run of one axis says (µm)."""

    axis: str
    E_um: float
    A_um: float
    R_um: float
    #: largest |target mean − the run's median| over targets and directions
    worst_um: float
    #: what a target mean may differ by from noise alone (3 standard errors)
    noise_um: float
    #: spans of the table holding a target whose residual stands out
    failing_spans: tuple[int, ...]
    tolerance_um: float
    #: per failing span, the largest residual that stands out in it (µm): refined first
    span_worst_um: tuple[float, ...] = ()

    def worst_first(self, count: int) -> AxisVerdict:
        """The verdict with only its ``count`` worst failing spans (what a budget allows)."""
        if count >= len(self.failing_spans):
            return self
        if not self.span_worst_um:  # no severities: the first ones
            return replace(self, failing_spans=self.failing_spans[:count])
        order = np.argsort(self.span_worst_um)[::-1][:count]
        keep = sorted(int(k) for k in order)
        return replace(self, failing_spans=tuple(self.failing_spans[k] for k in keep),
                       span_worst_um=tuple(self.span_worst_um[k] for k in keep))

    @property
    def within(self) -> bool:
        return self.E_um <= self.tolerance_um

    def to_json(self) -> dict[str, object]:
        return {"E_um": self.E_um, "A_um": self.A_um, "R_um": self.R_um,
                "worst_um": self.worst_um, "noise_um": self.noise_um,
                "failing_spans": list(self.failing_spans), "within": self.within,
                "span_worst_um": list(self.span_worst_um)}  # fmt: skip


def judge_axis(dev: AxisDeviations, table_mm: NDArray[np.float64], tolerance_um: float,
               repeatability_sd_um: float | None = None) -> AxisVerdict:
    """ISO 230-2 E, A, R of a verification run, and the table spans where its residual
    stands out: by more than half the tolerance and more than 3 standard errors of a target
    mean from the run's median (a constant offset moves no span)."""
    iso = iso230_axis(dev)
    means = []
    runs = 1
    for x in (dev.up_mm, dev.down_mm):
        if x is not None:
            means.append(np.nanmean(x, axis=1))
            runs = max(runs, int(np.min(np.sum(np.isfinite(x), axis=1))))
    m = np.column_stack(means) * 1e3  # µm, targets × directions
    spread = m - np.median(m, axis=0)
    sd = repeatability_sd_um
    if sd is None:  # the run's own scatter, pooled over targets and directions
        var = [np.nanvar(x, axis=1, ddof=1) for x in (dev.up_mm, dev.down_mm)
               if x is not None and x.shape[1] > 1]  # fmt: skip
        sd = float(np.sqrt(np.nanmean(np.concatenate(var)))) * 1e3 if var else \
            (iso.R_um or 0.0) / 4.0
    noise = 3.0 * sd / math.sqrt(runs)
    bad = np.flatnonzero(np.max(np.abs(spread), axis=1) > max(0.5 * tolerance_um, noise))
    x = np.asarray(table_mm, dtype=np.float64)
    worst: dict[int, float] = {}
    for k in bad:
        span = int(np.clip(np.searchsorted(x, dev.target_mm[k]) - 1, 0, x.size - 2))
        worst[span] = max(worst.get(span, 0.0), float(np.max(np.abs(spread[k]))))
    spans = sorted(worst)
    return AxisVerdict(dev.axis, float(iso.E_um or 0.0), float(iso.A_um or 0.0),
                       float(iso.R_um or 0.0), float(np.max(np.abs(spread))), float(noise),
                       tuple(spans), tolerance_um, tuple(worst[s] for s in spans))  # fmt: skip


def keeps_refinement(score_um: float, best_um: float, plane: bool = False,
                     swept: bool = False, noise_um: float = 0.0) -> bool:  # fmt: skip
    """Whether a refinement that verifies at ``score_um`` replaces the best so far
    (``best_um``). An axis's new points must make it better by 10 %, at least 0.2 µm: less
    is the verification's own scatter, and the older table stays. The plane's refinement
    is a denser grid of readings smoothed by their own scatter (:mod:`.grid_smooth`), more
    readings of the same field: it stays unless it is worse by that margin (its RMS
    vector error at a few random points read once, ``BestTables._keep_best``). So does an
    axis's sweep (``swept``): thousands of readings over the whole travel, fitted by
    cross-validation, against a table of a few dozen points. (Noise-free on the sim's
    truth, the sweeps the 10 % rule took back on the random machines were better than the
    tables kept instead in 5 of 7: E 0.15 against 0.40, 0.21/0.67, 0.44/1.00, 0.34/0.73,
    0.31/0.54 µm; equal in one, 0.57/0.56; worse in one, 0.47/0.35.) A sweep is put back
    only when it reads worse by more than a target mean's own noise too (``noise_um``,
    three of its standard errors at the verification's runs): two verifications are at
    different random targets, and near that noise their E tells the tables apart by
    chance (rough-2's Y: 1.95 → 2.46 µm, noise 0.97 µm, put back; noise-free the sweep's
    table left 1.02 µm on the pitch line, the one kept instead 1.30)."""
    margin = max(0.1 * best_um, 0.2)
    if swept:
        return score_um <= best_um + max(margin, noise_um)
    if plane:
        return score_um <= best_um + margin
    return score_um < best_um - margin


def refined_table(table: PitchTable, stage: PitchStage, dev: AxisDeviations) -> PitchTable:
    """``table`` with a new point at each target of ``dev`` (measured with ``stage`` on):
    the table's value there plus the mean residual, per direction. Targets closer than
    ``MIN_SPACING_MM`` to an existing point are left out (a pair that close would let
    noise set the slope)."""
    x = table.position_mm
    keep = np.array([np.min(np.abs(x - t)) >= MIN_SPACING_MM for t in dev.target_mm])
    if not keep.any():
        return table
    p = dev.target_mm[keep]
    cols = []
    for direction, values, meas in ((1, table.forward_mm, dev.up_mm),
                                    (-1, table.reverse_mm, dev.down_mm)):  # fmt: skip
        if values is None:
            cols.append(None)
            continue
        own = stage.inverse(p, np.full(p.size, direction)) - p  # e_t(p): the table's value
        other = dev.down_mm if meas is None else meas  # one direction measured: use it
        r = np.nanmean(other, axis=1)[keep]
        cols.append((values, own + r))
    pos = np.concatenate([x, p])
    order = np.argsort(pos, kind="stable")
    fwd = np.concatenate(cols[0])[order]  # type: ignore[index]
    rev = None if cols[1] is None else np.concatenate(cols[1])[order]
    return PitchTable(pos[order], fwd, rev, table.rotary, table.source)


#: refinement scans: points per lead and leads per scan (a mean over whole leads carries no
#: cyclic term; 8 per lead resolve harmonics 1-3)
SCAN_PER_LEAD = 8
SCAN_LEADS = 1.0


@dataclass(frozen=True)
class ScanRefinement:
    """A table and cyclic model refined from short scans measured with both applied."""

    table: PitchTable
    cyclic: CyclicModel
    #: per scan: station (mm), table offset ↑ and ↓ (µm), cyclic amplitude added (µm)
    found: tuple[tuple[float, float, float, float], ...]


def resolved_harmonics(x_mm: NDArray[np.float64], lead_mm: float) -> int:
    """The most harmonics of a lead that readings every ``np.diff(x_mm)`` resolve apart
    (below half their readings per lead: at 8 a lead the 4th's sine and cosine are one
    column, alternating)."""
    steps = np.diff(np.unique(np.round(np.asarray(x_mm, dtype=np.float64), 6)))
    if steps.size == 0:
        return 0
    per_lead = lead_mm / float(np.median(steps))
    return max(0, int(np.ceil(per_lead / 2.0 - 1e-9)) - 1)


def scan_refinement(table: PitchTable, stage: PitchStage, cyclic: CyclicModel,
                    stations_mm: Sequence[float], scans: Sequence[StationScan]
                    ) -> ScanRefinement:  # fmt: skip
    """Fold short scans (residuals with the table and the cyclic term on) into both: each
    scan's mean per direction at its centre (a least-squares level with a slope and the
    harmonics: no cyclic term aliased into it) becomes a table point, its harmonics a new
    cyclic station (the model's amplitudes there plus the residual's), kept where it is at
    least a lead from every other station. Table points closer than ``MIN_SPACING_MM`` to
    an existing one are left out."""
    lead = cyclic.lead_mm
    new_x, fwd, rev, found = [], [], [], []
    st_new: list[tuple[float, np.ndarray, np.ndarray]] = []
    for centre, scan in zip(stations_mm, scans):
        x, d = scan.position_mm, scan.deviation_mm
        k = min(cyclic.harmonics, resolved_harmonics(x, lead))
        theta = 2 * np.pi * (x - cyclic.origin_mm) / lead
        cols = [np.ones_like(x), (x - centre) / lead, (scan.direction < 0).astype(np.float64)]
        for h in range(1, k + 1):
            cols += [np.sin(h * theta), np.cos(h * theta)]
        coef = np.linalg.lstsq(np.column_stack(cols), d, rcond=None)[0]
        up, down = float(coef[0]), float(coef[0] + coef[2])
        a0, b0 = cyclic.amplitudes_mm(np.array([centre]))
        da = np.zeros(cyclic.harmonics)  # those it does not resolve: the model's, as they are
        db = np.zeros(cyclic.harmonics)
        da[:k], db[:k] = coef[3::2], coef[4::2]
        st_new.append((float(centre), a0[0] + da, b0[0] + db))
        found.append((float(centre), up * 1e3, down * 1e3,
                      float(np.sum(np.hypot(da, db))) * 1e3))  # fmt: skip
        if np.min(np.abs(table.position_mm - centre)) >= MIN_SPACING_MM and \
                (not new_x or np.min(np.abs(np.array(new_x) - centre)) >= MIN_SPACING_MM):
            p = np.array([centre])
            new_x.append(float(centre))
            fwd.append(float(stage.inverse(p, np.array([1]))[0] - centre) + up)
            rev.append(float(stage.inverse(p, np.array([-1]))[0] - centre) + down)
    pos = np.concatenate([table.position_mm, new_x])
    order = np.argsort(pos, kind="stable")
    f = np.concatenate([table.forward_mm, fwd])[order]
    r = None if table.reverse_mm is None else np.concatenate([table.reverse_mm, rev])[order]
    if table.reverse_mm is None:  # a one-direction table: the mean of both
        f = np.concatenate([table.forward_mm, (np.array(fwd) + np.array(rev)) / 2])[order]
    new_table = PitchTable(pos[order], f, r, table.rotary, table.source)
    stations = [(float(s), a, b) for s, a, b in zip(cyclic.station_mm, cyclic.sin_mm,
                                                     cyclic.cos_mm)]  # fmt: skip
    for s, a, b in st_new:
        if all(abs(s - o[0]) >= lead for o in stations):
            stations.append((s, a, b))
    stations.sort(key=lambda e: e[0])
    model = CyclicModel(lead, np.array([s[0] for s in stations]),
                        np.array([s[1] for s in stations]), np.array([s[2] for s in stations]),
                        cyclic.origin_mm, cyclic.source)  # fmt: skip
    return ScanRefinement(new_table, model, tuple(found))


def denser_grid(nx: int, ny: int, limit: int = 33) -> tuple[int, int]:
    """The next XY grid: every cell split in two each way (at most ``limit`` per axis)."""
    return min(2 * nx - 1, limit), min(2 * ny - 1, limit)


# -- thermal drift during commissioning ---------------------------------------------------
@dataclass(frozen=True)
class Drift:
    """How far an axis's deviation has drifted since commissioning began (mm), measured at
    two reference positions ``x_mm`` just before and just after a run; linear in the run's
    progress. Between (and beyond) the references: linear in position, or along the heat
    shape W read before and after the run (:mod:`..thermal.drift_shape`, places over
    ``travel_mm``) where one was kept."""

    x_mm: tuple[float, float]
    before_mm: tuple[float, float]
    after_mm: tuple[float, float]
    travel_mm: tuple[float, float] | None = None
    shape_before: tuple[float, ...] = ()
    shape_after: tuple[float, ...] = ()

    def at(self, x_mm: NDArray[np.float64], fraction: NDArray[np.float64]
           ) -> NDArray[np.float64]:
        """Drift (mm) at positions ``x_mm`` a ``fraction`` (0..1) through the run."""
        x = np.asarray(x_mm, dtype=np.float64)
        f = np.asarray(fraction, dtype=np.float64)
        if self.travel_mm is not None and self.shape_before and self.shape_after:
            b = shaped_drift_mm(x, self.x_mm, self.before_mm, self.travel_mm,
                                self.shape_before)  # fmt: skip
            a = shaped_drift_mm(x, self.x_mm, self.after_mm, self.travel_mm, self.shape_after)
            return b + (a - b) * f
        lo = self.before_mm[0] + (self.after_mm[0] - self.before_mm[0]) * f
        hi = self.before_mm[1] + (self.after_mm[1] - self.before_mm[1]) * f
        x0, x1 = self.x_mm
        return lo + (hi - lo) * (x - x0) / (x1 - x0)

    def to_json(self) -> list[float]:
        out = [*self.x_mm, *self.before_mm, *self.after_mm]
        if self.travel_mm is not None and self.shape_before and self.shape_after:
            out += [*self.travel_mm, *self.shape_before, *self.shape_after]
        return out

    @classmethod
    def from_json(cls, v: Sequence[float]) -> Drift:
        if len(v) > 8:
            k = (len(v) - 8) // 2
            return cls((v[0], v[1]), (v[2], v[3]), (v[4], v[5]), (v[6], v[7]),
                       tuple(v[8 : 8 + k]), tuple(v[8 + k : 8 + 2 * k]))  # fmt: skip
        return cls((v[0], v[1]), (v[2], v[3]), (v[4], v[5]))


def relinked_base(
    base: dict[str, list[float]] | None, after: dict[str, list[float]],
    drift: dict[str, list[float]], old_commands: dict[str, dict], new_commands: dict[str, dict],
    temperature_c: dict[str, float] | None = None,
    moved_mm: dict[str, list[float]] | None = None,
) -> dict[str, list[float]]:  # fmt: skip
    """The drift base (mm at each axis's two references) once a new config is loaded, so
    that drift keeps counting from the start across it.

    Read: ``after`` the switch, with ``drift`` known just before it. Then the base is
    ``after − drift``, but the reading after the switch also holds the heat of the travel
    between the two readings, and that much drift is lost at every switch. Where the two
    configs differ in an axis's tables only (the same ``thermal`` in ``old_commands`` and
    ``new_commands``, each axis's commands in mm at its references), the base moves by what
    they command differently there instead: computed, no heat in it. So it does where the
    thermal setting changes but both sides are computable: none, or a temperature source
    (``sensor``: origin, length, gain, α, reference), at the sensor's reading as
    commissioning began (``temperature_c``): each config's base is then what it would have
    read on the cold machine, so the drift under a config without thermal compensation is
    the growth itself, and under the sensor's what its correction leaves of it beyond the
    cold start's. ``base`` None: the first config, or a broken chain (read).

    ``moved_mm``: per axis, how far the new commands move the axis at its references (mm),
    where known (:func:`reading_moved_mm`); else the commands' difference. A table hundreds
    of µm deep sends the axis to where its own error differs from the nominal place's."""
    out = {a: [after[a][k] - drift[a][k] for k in (0, 1)] for a in after}
    if base is None:
        return out
    temps = temperature_c or {}
    moved = moved_mm or {}
    for a, new in new_commands.items():
        was = old_commands.get(a)
        if a not in base or was is None:
            continue
        shift = moved.get(a) or [new["mm"][k] - was["mm"][k] for k in (0, 1)]
        if was["thermal"] == new["thermal"]:
            out[a] = [base[a][k] + shift[k] for k in (0, 1)]
            continue
        old_t, new_t = thermal_mm(was, temps.get(a)), thermal_mm(new, temps.get(a))
        if old_t is not None and new_t is not None:
            out[a] = [base[a][k] + shift[k] + new_t[k] - old_t[k] for k in (0, 1)]
    return out


def reading_moved_mm(model: Chain, axis: str, old: Sequence[Mapping[str, float]],
                     new: Sequence[Mapping[str, float]]) -> list[float]:  # fmt: skip
    """How far a switch of commands moves ``axis`` at each reference (mm), by the error
    model ``model`` (a chain whose tables know the axis): where the new commands put it
    less where the old ones did, each command of every axis involved (mm, approached in
    +) turned into the position it reaches. Not the commands' difference: a switch from no
    tables to a table that commands 346 µm moves the axis to where its error is 1.2 µm
    different (smooth-6 Y's far reference, where the readings moved 1.7 µm more than the
    commands; the drift after it was that much too large, and every table measured
    later tilted by it)."""

    def reached_mm(commands: Sequence[Mapping[str, float]]) -> NDArray[np.float64]:
        pulses = {a: [c[a] / model.axes[a].pulse_mm for c in commands] for a in commands[0]}
        return model.nominal_pulses_batch(pulses)[axis] * model.axes[axis].pulse_mm

    return [float(d) for d in reached_mm(new) - reached_mm(old)]


def thermal_mm(commands: dict, temperature_c: float | None) -> list[float] | None:
    """What a config's thermal stage adds to the commands at the references (mm) on the
    machine as commissioning began: nothing without one, nor for heat from motion (no
    heat in a cold screw: the gateway counts it from the moves it relays since its start,
    so the references read what the model leaves of the growth), a temperature source's
    correction at ``temperature_c``; None where it cannot be computed (a Δa: the sensor's
    own state)."""
    if commands["thermal"] == "None" or commands.get("motion"):
        return [0.0, 0.0]
    sensor = commands.get("sensor")
    if sensor is None or temperature_c is None:
        return None
    origin, length, gain, alpha, reference = sensor
    da = gain * delta_a_from_temperature(alpha, length, temperature_c, reference)
    stage = ThermalStage(length, origin)
    return [stage.forward_scalar(x, da) - x for x in commands["mm"]]


def drift_corrected(raw: RawData, drifts: dict[str, Drift]) -> RawData:
    """``raw`` with each reading's drift taken off (a row's progress through its run is its
    measured move's place among them all, one row per plan axis and move; a target's ↑ and
    ↓ of one run share their mean progress, :func:`_paired`)."""
    if not drifts or len(raw) == 0:
        return raw
    per_move = max(1, len(raw.axes))
    moves = np.arange(len(raw)) // per_move
    fraction = _paired(raw, moves / max(1, moves[-1]))
    actual = raw.actual_mm.copy()
    names = np.array(raw.axis)
    for axis, drift in drifts.items():
        rows = names == axis
        actual[rows] -= drift.at(raw.target_mm[rows], fraction[rows])
    return replace(raw, actual_mm=actual)


def _paired(raw: RawData, fraction: NDArray[np.float64]) -> NDArray[np.float64]:
    """``fraction`` with each target's ↑ and ↓ readings of one run of a one-axis plan given
    their mean: both take off the same drift, so the reversal stays as read. (The drift
    read at the references minutes apart is no measure of the drift between the two
    passes of one run: smooth-8's Y, its references drifting 1.4 µm a run, read a reversal
    0.9 µm too large with it taken off pass by pass, 1.0 µm too small as read.)"""
    if len(raw.axes) != 1:
        return fraction
    keys = np.stack([raw.run.astype(np.float64), raw.target_mm])
    group = np.unique(keys, axis=1, return_inverse=True)[1].ravel()
    counts = np.bincount(group)
    ups = np.bincount(group, weights=(raw.direction > 0).astype(np.float64))
    both = (ups > 0) & (ups < counts)  # read in both directions
    mean = np.bincount(group, weights=fraction) / counts
    return np.where(both[group], mean[group], fraction)


# -- the screw lead, when nobody said -------------------------------------------------------
#: leads of standard ball screws (mm), the candidates of a lead search
STANDARD_LEADS_MM = (2.0, 2.5, 3.0, 4.0, 5.0, 6.0, 8.0, 10.0, 12.0, 16.0, 20.0, 25.0)
LEAD_HARMONICS = 3
TREND_DEGREE = 4


def lead_scan_targets_mm(travel_mm: Sequence[float], length_mm: float = 60.0,
                         step_mm: float = 0.25) -> NDArray[np.float64]:
    """Dense targets for a lead search: ``length_mm`` (at most half the travel) around the
    middle of the travel, every ``step_mm`` (16 points per lead down to 4 mm)."""
    lo, hi = float(travel_mm[0]), float(travel_mm[1])
    length = min(length_mm, 0.5 * (hi - lo))
    mid = 0.5 * (lo + hi)
    return np.round(np.arange(mid - length / 2, mid + length / 2 + 1e-9, step_mm), 4)


@dataclass(frozen=True)
class LeadSearch:
    """The screw lead read from a dense scan: the standard lead whose harmonics 1..3 explain
    the scan best (the shortest of those that do about equally well), or None when no
    periodic error stands out of the noise."""

    lead_mm: float | None
    amplitude_um: float  # the largest harmonic's amplitude at that lead
    f_ratio: float  # variance explained per parameter over residual variance
    rss_um2: dict[float, float]


def find_lead(x_mm: NDArray[np.float64], deviation_mm: NDArray[np.float64],
              candidates: Sequence[float] = STANDARD_LEADS_MM, f_min: float = 10.0,
              amplitude_min_um: float = 0.2) -> LeadSearch:
    """Search the lead among ``candidates`` that fit 2.5 times in the scan (see
    LeadSearch)."""
    x = np.asarray(x_mm, dtype=np.float64)
    y = np.asarray(deviation_mm, dtype=np.float64) * 1e3
    u = (x - x.mean()) / max(float(np.ptp(x)), 1e-9)
    trend = np.column_stack([u**k for k in range(TREND_DEGREE + 1)])  # waviness longer
    # than the scan, and the table's slope, are not a lead
    rss0 = float(np.sum((y - trend @ np.linalg.lstsq(trend, y, rcond=None)[0]) ** 2))
    step = float(np.median(np.diff(np.sort(x)))) if x.size > 1 else 1.0
    rss: dict[float, float] = {}
    amps: dict[float, float] = {}
    for lead in candidates:
        if lead < 4 * step or 2.5 * lead > np.ptp(x):
            continue
        cols = [trend]
        for k in range(1, LEAD_HARMONICS + 1):
            phase = 2 * np.pi * k * x / lead
            cols.append(np.column_stack([np.sin(phase), np.cos(phase)]))
        design = np.hstack(cols)
        coef = np.linalg.lstsq(design, y, rcond=None)[0]
        rss[lead] = float(np.sum((y - design @ coef) ** 2))
        t = TREND_DEGREE + 1
        amps[lead] = float(max(np.hypot(coef[t + 2 * k], coef[t + 1 + 2 * k])
                               for k in range(LEAD_HARMONICS)))  # fmt: skip
    if not rss:
        return LeadSearch(None, 0.0, 0.0, rss)
    best = min(rss.values())
    p = 2 * LEAD_HARMONICS
    dof = max(1, x.size - TREND_DEGREE - 1 - p)
    # the shortest lead not significantly worse than the best (a multiple of the true lead
    # fits its harmonics too, and some noise besides)
    lead = min(lead for lead, r in rss.items() if (r - best) / p < 4.0 * best / dof)
    f_ratio = ((rss0 - rss[lead]) / p) / max(rss[lead] / dof, 1e-12)
    found = f_ratio >= f_min and amps[lead] >= amplitude_min_um
    return LeadSearch(lead if found else None, amps[lead], f_ratio, rss)
