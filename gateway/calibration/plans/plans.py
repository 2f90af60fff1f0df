"""Calibration plans: the ordered moves of a test, as a CSV file a user can read and edit.

::

    # compgw plan
    # kind: iso230-linear
    # axis: X
    # travel_mm: 0 800
    run,direction,role,X_mm,speed_mm_s,dwell_s
    1,-,overrun,3.0,,
    1,+,measure,5.0,,
    1,+,measure,27.912,,

One row per move, executed top to bottom. Columns: ``run`` (ISO 230-2 run, backlash repeat,
warm-up cycle; integer ≥ 0), ``direction`` (``+``/``-``: the direction the move approaches its
target; empty when not meaningful), ``role`` (see :data:`ROLES`; only ``measure`` rows are
measured), one ``<AXIS>_mm`` column per axis moved (the nominal target), and optional
``speed_mm_s`` and ``dwell_s`` (empty: the runner's default). ``# key: value`` comment lines
before the header describe the plan (kind, the parameters it was made from) and are kept
when read; every other comment is ignored. Edit targets, delete rows or add rows freely:
the runner measures what the file says.

Generators: :func:`iso230_linear_plan` (and its ``verification`` variant),
:func:`backlash_plan` (seed 000) here; :func:`.xy.xy_grid_plan` /
:func:`.xy.xy_verification_plan` (seed 001); :func:`..fitting.plans_scans.warmup_plan` (seed
002), :func:`..fitting.plans_scans.cyclic_plan` (issue 7: dense scans of the once-per-lead screw
error).
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from ...compensation.errors import TableError
from ...config_types import read_text
from ...formats.atomic import atomic_write_text
from ...formats.lines import POSITION_DECIMALS, fmt, parse_number
from .rawdata import RawData, axis_deviations

#: measure: stop and measure; overrun: reversal point past a travel end; takeup: approach
#: move that takes up the play; away: move away before returning; move: a plain move.
ROLES = ("measure", "overrun", "takeup", "away", "move")
_DIRECTION_TEXT = {1: "+", -1: "-", 0: ""}
_TEXT_DIRECTION = {v: k for k, v in _DIRECTION_TEXT.items()}
#: Targets are rounded to this many decimals (0.1 µm) so plan files stay readable.
TARGET_DECIMALS = 4
#: a rotary axis's ISO runs start this far inside its travel, their overrun (deg): calibrate's
#: and commission's alike
ROTARY_OVERRUN_DEG = 0.5


@dataclass(frozen=True)
class Move:
    """One move of a plan: targets (mm, one per plan axis), approach direction and role."""

    run: int
    direction: int  # +1, −1, or 0 (not meaningful)
    role: str
    target_mm: tuple[float, ...]
    speed_mm_s: float | None = None
    dwell_s: float | None = None

    @property
    def measured(self) -> bool:
        return self.role == "measure"


@dataclass(frozen=True)
class Plan:
    """An ordered list of moves over ``axes``; ``meta`` describes how it was made."""

    kind: str
    axes: tuple[str, ...]
    moves: tuple[Move, ...]
    meta: tuple[tuple[str, str], ...] = ()

    def targets_mm(self, axis: str | None = None, role: str = "measure") -> NDArray[np.float64]:
        """Targets of ``axis`` (default: the first) of the moves with ``role``, in order."""
        k = self.axes.index(axis) if axis is not None else 0
        return np.array([m.target_mm[k] for m in self.moves if m.role == role])

    def measured_points_mm(self) -> NDArray[np.float64]:
        """Targets of measured moves, shape (moves, axes)."""
        return np.array([m.target_mm for m in self.moves if m.measured]).reshape(
            -1, len(self.axes)
        )


def _meta(**params: object) -> tuple[tuple[str, str], ...]:
    def text(v: object) -> str:
        if isinstance(v, (tuple, list)):
            return " ".join(text(x) for x in v)
        return f"{v:g}" if isinstance(v, float) else str(v)

    return tuple((k, text(v)) for k, v in params.items() if v is not None)


def _round(x: float | NDArray[np.float64]) -> NDArray[np.float64]:
    return np.round(np.asarray(x, dtype=np.float64), TARGET_DECIMALS)


def snap_to_pulses(plan: Plan, pulse_mm: Mapping[str, float]) -> Plan:
    """The plan with every target moved to the nearest whole pulse of its axis.

    The machine can only be commanded in whole pulses, so a target between two pulses is
    reached as the nearer one and its deviation would carry up to half a pulse of rounding
    (0.5 µm at 1 µm per pulse), different at every target: systematic error that is not the
    machine's. Snapped, ``target_mm`` in the raw data is exactly what was commanded. Axes
    missing from ``pulse_mm`` are left as they are.
    """
    steps = [pulse_mm.get(a) for a in plan.axes]

    def snap(target_mm: tuple[float, ...]) -> tuple[float, ...]:
        return tuple(
            t if p is None else round(round(t / p) * p, 9)
            for t, p in zip(target_mm, steps, strict=True)
        )

    moves = tuple(replace(m, target_mm=snap(m.target_mm)) for m in plan.moves)
    return Plan(plan.kind, plan.axes, moves, plan.meta)


def _travel(travel_mm: Sequence[float]) -> tuple[float, float]:
    lo, hi = (float(v) for v in travel_mm)
    if not hi > lo:
        raise ValueError(f"travel_mm {travel_mm!r}: the upper end must exceed the lower")
    return lo, hi


# -- ISO 230-2 linear test ----------------------------------------------------------------
def iso230_targets_mm(
    travel_mm: Sequence[float],
    n_targets: int | None = None,
    step_mm: float = 25.0,
    margin_mm: float = 5.0,
    seed: int = 0,
    lead_mm: float | None = None,
    min_lead_fraction: float = 0.05,
) -> NDArray[np.float64]:
    """Unevenly spaced targets over the travel (ISO 230-2 clause 5.3.2).

    First and last at the travel ends minus ``margin_mm``; the ones between at the nominal
    step plus a seeded random offset within ±step/4, so that a periodic error of the screw
    (period ``lead_mm``) is sampled at different phases instead of aliased. When ``lead_mm``
    is given, offsets are re-drawn until no spacing is within ``min_lead_fraction`` of a
    lead of a whole number of leads. At least 5 targets (ISO 230-2).
    """
    lo, hi = _travel(travel_mm)
    first, last = lo + margin_mm, hi - margin_mm
    if not last > first:
        raise ValueError(f"travel {lo:g}..{hi:g} mm leaves no room inside margin {margin_mm:g}")
    if n_targets is None:
        n_targets = max(5, round((last - first) / step_mm) + 1)
    if n_targets < 2:
        raise ValueError("n_targets must be at least 2")
    nominal = np.linspace(first, last, n_targets)
    step = (last - first) / (n_targets - 1)
    rng = np.random.default_rng(seed)
    for _ in range(100):
        offsets = rng.uniform(-step / 4, step / 4, n_targets)
        offsets[[0, -1]] = 0.0
        targets = _round(nominal + offsets)
        if lead_mm is None or _clear_of_lead(np.diff(targets), lead_mm, min_lead_fraction):
            return targets
    # steps near a whole number of leads (one point per lead, say): drawn target by target
    assert lead_mm is not None
    targets = _targets_clear_of_lead(nominal, step, lead_mm, min_lead_fraction, rng)
    if targets is None:
        raise ValueError(
            f"no target spacing clear of multiples of lead {lead_mm:g} mm with step "
            f"{step:g} mm: use a step that is not close to a whole number of leads (e.g. "
            f"{0.45 * lead_mm:g} or {1.45 * lead_mm:g} mm), or add the cyclic stage")
    return targets


def _targets_clear_of_lead(nominal: NDArray[np.float64], step: float, lead_mm: float,
                           fraction: float, rng: np.random.Generator
                           ) -> NDArray[np.float64] | None:
    """Targets near ``nominal`` (within ±step/4, the ends fixed) with every spacing clear of
    a whole number of leads, chosen one after the other; None when none is found."""
    out = _round(nominal.copy())
    n = out.size
    for i in range(1, n - 1):
        for _ in range(200):
            candidate = _round(nominal[i] + rng.uniform(-step / 4, step / 4))
            gaps = [candidate - out[i - 1]]
            if i == n - 2:
                gaps.append(out[-1] - candidate)
            if _clear_of_lead(np.asarray(gaps), lead_mm, fraction):
                out[i] = candidate
                break
        else:
            return None
    if not _clear_of_lead(np.diff(out), lead_mm, fraction):
        return None
    return out


def _clear_of_lead(spacing_mm: NDArray[np.float64], lead_mm: float, fraction: float) -> bool:
    turns = spacing_mm / lead_mm
    return bool(np.all(np.abs(turns - np.round(turns)) >= fraction))


def verification_targets_mm(calibration_mm: NDArray[np.float64]) -> NDArray[np.float64]:
    """Targets between calibration targets (midpoints): the machine between table points."""
    t = np.asarray(calibration_mm, dtype=np.float64)
    return _round(0.5 * (t[1:] + t[:-1]))


def iso230_linear_plan(
    axis: str,
    travel_mm: Sequence[float],
    n_targets: int | None = None,
    step_mm: float = 25.0,
    margin_mm: float | None = None,
    overrun_mm: float = 3.0,
    runs: int = 5,
    seed: int = 0,
    lead_mm: float | None = None,
    verification: bool = False,
    speed_mm_s: float | None = None,
    dwell_s: float | None = None,
) -> Plan:
    """ISO 230-2 standard test cycle: ``runs`` bidirectional runs over uneven targets.

    Each run: go to the overrun point below the first target (approaching it in −), measure
    every target going up (+), go to the overrun point past the last target, measure every
    target going down (−). Overrun points are clipped to the travel; the default margin
    equals the overrun so they stay past the targets. ``verification``: the midpoints between
    the calibration targets of the same parameters instead (different from them by at least
    half the smallest spacing).
    """
    lo, hi = _travel(travel_mm)
    if runs < 1:
        raise ValueError("runs must be at least 1")
    if overrun_mm < 0:
        raise ValueError("overrun_mm must be >= 0")
    margin = overrun_mm if margin_mm is None else margin_mm
    targets = iso230_targets_mm((lo, hi), n_targets, step_mm, margin, seed, lead_mm)
    if verification:
        targets = verification_targets_mm(targets)
    kind = "iso230-verification" if verification else "iso230-linear"
    meta = _meta(
        kind=kind, axis=axis, travel_mm=(lo, hi), n_targets=n_targets, step_mm=step_mm,
        margin_mm=margin, overrun_mm=overrun_mm, runs=runs, seed=seed, lead_mm=lead_mm,
    )  # fmt: skip
    return Plan(kind, (axis,), _bidirectional_moves((lo, hi), targets, runs, overrun_mm,
                                                    speed_mm_s, dwell_s), meta)  # fmt: skip


def targets_plan(
    axis: str, travel_mm: Sequence[float], targets_mm: Sequence[float], runs: int = 2,
    overrun_mm: float = 1.0, kind: str = "iso230-verification", speed_mm_s: float | None = None,
    one_way: bool = False, **meta: object,
) -> Plan:  # fmt: skip
    """The ISO 230-2 cycle (``runs`` bidirectional runs, overrun past each end) over given
    targets: verification and refinement targets chosen by someone else (sorted here).
    ``one_way``: each run reads them going up (+) only (points put between a table's
    others, :func:`..fitting.fit.with_one_way_points`)."""
    lo, hi = _travel(travel_mm)
    targets = _round(np.sort(np.asarray(targets_mm, dtype=np.float64)))
    if targets.size == 0 or targets[0] < lo or targets[-1] > hi:
        raise ValueError(f"targets must lie in the travel {lo:g}..{hi:g} mm")
    if one_way:
        meta["one_way"] = "+"
    info = _meta(kind=kind, axis=axis, travel_mm=(lo, hi), overrun_mm=overrun_mm, runs=runs,
                 **meta)  # type: ignore[arg-type]  # fmt: skip
    moves = _bidirectional_moves((lo, hi), targets, runs, overrun_mm, speed_mm_s, None)
    if one_way:  # the overrun below and the pass up of each run
        moves = tuple(m for m in moves if (m.direction > 0 and m.role == "measure")
                      or (m.role == "overrun" and m.direction < 0))  # fmt: skip
    return Plan(kind, (axis,), moves, info)


def _bidirectional_moves(travel: tuple[float, float], targets: NDArray[np.float64], runs: int,
                         overrun_mm: float, speed_mm_s: float | None, dwell_s: float | None
                         ) -> tuple[Move, ...]:
    """Each run: the overrun point below the first target (approached in −), every target
    going up (+), the overrun point past the last, every target going down (−)."""
    lo, hi = travel
    below = float(_round(max(lo, targets[0] - overrun_mm)))
    above = float(_round(min(hi, targets[-1] + overrun_mm)))
    moves: list[Move] = []
    for j in range(1, runs + 1):
        moves.append(Move(j, -1, "overrun", (below,), speed_mm_s))
        moves += [Move(j, +1, "measure", (float(t),), speed_mm_s, dwell_s) for t in targets]
        moves.append(Move(j, +1, "overrun", (above,), speed_mm_s))
        moves += [
            Move(j, -1, "measure", (float(t),), speed_mm_s, dwell_s) for t in targets[::-1]
        ]
    return tuple(moves)


# -- backlash (seed 000) ------------------------------------------------------------------
def backlash_plan(
    axis: str,
    travel_mm: Sequence[float],
    takeup_mm: float = 5.0,
    away_mm: float = 5.0,
    repeats: int = 7,
    margin_mm: float = 5.0,
    speed_mm_s: float | None = None,
) -> Plan:
    """Seed 000's backlash procedure near both ends and the middle of the travel.

    At each place P, ``repeats`` times: from P − takeup move to P in + (the play is taken
    up), measure; go on to P + away in +; come back to P in −, measure. The two readings at
    P differ by the lost motion. Run number = repeat.
    """
    lo, hi = _travel(travel_mm)
    first = lo + margin_mm + takeup_mm
    last = hi - margin_mm - away_mm
    if not last > first:
        raise ValueError(f"travel {lo:g}..{hi:g} mm too short for the backlash moves")
    places = _round(np.array([first, 0.5 * (first + last), last]))
    moves: list[Move] = []
    for p in places:
        for j in range(1, repeats + 1):
            moves += [
                Move(j, 0, "takeup", (float(_round(p - takeup_mm)),), speed_mm_s),
                Move(j, +1, "measure", (float(p),), speed_mm_s),
                Move(j, +1, "away", (float(_round(p + away_mm)),), speed_mm_s),
                Move(j, -1, "measure", (float(p),), speed_mm_s),
            ]
    meta = _meta(
        kind="backlash", axis=axis, travel_mm=(lo, hi), takeup_mm=takeup_mm, away_mm=away_mm,
        repeats=repeats, margin_mm=margin_mm,
    )  # fmt: skip
    return Plan("backlash", (axis,), tuple(moves), meta)


@dataclass(frozen=True, eq=False)
class BacklashResult:
    """Lost motion per place (mean and sample std over repeats, mm) and B = largest mean."""

    place_mm: NDArray[np.float64]
    mean_mm: NDArray[np.float64]
    std_mm: NDArray[np.float64]
    repeats: NDArray[np.int64]
    backlash_mm: float


def backlash_from_readings(
    place_mm: NDArray[np.float64],
    reading_up_mm: NDArray[np.float64],
    reading_down_mm: NDArray[np.float64],
) -> BacklashResult:
    """B from paired readings at P after the + approach and after the − return.

    Lost motion of one repeat = reading after the − return − reading after the + approach
    (the table stops short by B on each side of the play). Averaged per place; B is the
    largest mean (seed 000), clipped at 0.
    """
    place = np.asarray(place_mm, dtype=np.float64)
    lost = np.asarray(reading_down_mm, np.float64) - np.asarray(reading_up_mm, np.float64)
    places, index = np.unique(_round(place), return_inverse=True)
    means = np.array([lost[index == k].mean() for k in range(places.size)])
    counts = np.array([(index == k).sum() for k in range(places.size)], dtype=np.int64)
    stds = np.array(
        [lost[index == k].std(ddof=1) if c > 1 else 0.0 for k, c in enumerate(counts)]
    )
    return BacklashResult(places, means, stds, counts, max(0.0, float(means.max())))


def backlash_from_raw(raw: RawData, axis: str) -> BacklashResult:
    """:func:`backlash_from_readings` from the raw data of a backlash plan's run.

    The + and − readings at the same target and run are paired.
    """
    dev = axis_deviations(raw, axis)
    if dev.up_mm is None or dev.down_mm is None:
        raise TableError(f"{dev.source}: axis {axis}: backlash needs readings in + and -")
    ok = np.isfinite(dev.up_mm) & np.isfinite(dev.down_mm)
    ii, _ = np.nonzero(ok)
    place = dev.target_mm[ii]
    # deviations share the target, so their difference is the difference of the readings
    return backlash_from_readings(place, dev.up_mm[ok], dev.down_mm[ok])


def plan_time_s(
    plan: Plan,
    speed_mm_s: float = 100.0,
    stop_s: float = 2.0,
    start_mm: Sequence[float] | None = None,
) -> float:
    """Machine time of ``plan`` (s): every move at ``speed_mm_s`` (its own speed if given,
    axes moving together), plus ``stop_s`` at each measured move (settling and the
    instrument's averaging) and its ``dwell_s``. Starts at the first move's targets unless
    ``start_mm`` is given."""
    if not plan.moves:
        return 0.0
    here = np.asarray(start_mm if start_mm is not None else plan.moves[0].target_mm, float)
    total = 0.0
    for m in plan.moves:
        to = np.asarray(m.target_mm, dtype=np.float64)
        total += float(np.max(np.abs(to - here))) / (m.speed_mm_s or speed_mm_s)
        if m.measured:
            total += stop_s + (m.dwell_s or 0.0)
        here = to
    return total


# -- resuming an interrupted run ----------------------------------------------------------
def resume_index(plan: Plan, raw: RawData) -> int:
    """Index of the first move of ``plan`` whose measurement is not in ``raw`` yet.

    The raw rows must be the plan's measured moves in order (one row per plan axis and
    move; axis, run, target and, on one-axis plans, direction checked), else TableError:
    the file belongs to another plan. A runner resuming at index k should first go to move
    k − 1's target without measuring, so move k is approached from the planned side.
    ``len(plan.moves)`` means the run is complete.
    """
    rows, single = 0, len(plan.axes) == 1
    for k, move in enumerate(plan.moves):
        if not move.measured:
            continue
        if rows == len(raw):
            return k
        for a, target in zip(plan.axes, move.target_mm):
            if rows == len(raw):
                raise TableError(f"{raw.source}: ends half-way through a point of the plan")
            ok = (
                raw.axis[rows] == a
                and raw.run[rows] == move.run
                and abs(raw.target_mm[rows] - target) <= 1e-6
                and (single or move.direction == 0 or raw.direction[rows] == move.direction)
            )
            if not ok:
                raise TableError(
                    f"{raw.where(rows)}: row does not match plan move {k + 1} "
                    f"(axis {a}, run {move.run}, target {target:g} mm)"
                )
            rows += 1
    if rows != len(raw):
        raise TableError(f"{raw.where(rows)}: more rows than the plan measures")
    return len(plan.moves)


# -- file format ----------------------------------------------------------------------------
def format_plan(plan: Plan) -> str:
    """The CSV text of ``plan`` (see the module docstring)."""
    meta = dict(plan.meta)
    meta.setdefault("kind", plan.kind)
    out = ["# compgw plan"]
    out += [f"# {k}: {v}" for k, v in [("kind", meta.pop("kind")), *meta.items()]]
    out.append(",".join(["run", "direction", "role", *(f"{a}_mm" for a in plan.axes),
                         "speed_mm_s", "dwell_s"]))  # fmt: skip

    def opt(v: float | None) -> str:
        return "" if v is None else fmt(v)

    for m in plan.moves:
        cells = [str(m.run), _DIRECTION_TEXT[m.direction], m.role]
        cells += [fmt(t, POSITION_DECIMALS) for t in m.target_mm]
        cells += [opt(m.speed_mm_s), opt(m.dwell_s)]
        out.append(",".join(cells))
    return "\n".join(out) + "\n"


def write_plan(path: str | os.PathLike[str], plan: Plan) -> None:
    """Write ``plan`` atomically."""
    atomic_write_text(path, format_plan(plan))


def read_plan(path: str | os.PathLike[str]) -> Plan:
    """Read a plan CSV; a malformed line is a TableError naming file and line."""
    meta: list[tuple[str, str]] = []
    header: list[str] | None = None
    moves: list[Move] = []
    axes: tuple[str, ...] = ()
    for number, raw in enumerate(read_text(path, TableError).splitlines(), start=1):
        text, _, comment = raw.partition("#")
        text = text.strip()
        if not text:
            if header is None and ":" in comment:
                key, _, value = comment.partition(":")
                meta.append((key.strip(), value.strip()))
            continue
        cells = [c.strip() for c in text.split(",")]
        if header is None:
            header = cells
            axes = tuple(c[:-3] for c in cells[3:] if c.endswith("_mm") and c != "speed_mm_s")
            want = ["run", "direction", "role", *(f"{a}_mm" for a in axes)]
            if cells[: len(want)] != want or not axes or not set(cells[len(want):]) <= {
                "speed_mm_s", "dwell_s"
            }:
                raise TableError(
                    f"{path}: line {number}: header {text!r} is not "
                    f"'run,direction,role,<AXIS>_mm[,...][,speed_mm_s][,dwell_s]'"
                )
            continue
        moves.append(_parse_move(path, number, header, cells, len(axes)))
    if header is None:
        raise TableError(f"{path}: empty plan (no header)")
    info = dict(meta)
    return Plan(info.get("kind", "custom"), axes, tuple(moves), tuple(meta))


def _parse_move(
    path: str | os.PathLike[str], number: int, header: list[str], cells: list[str], n_axes: int
) -> Move:
    if len(cells) != len(header):
        raise TableError(
            f"{path}: line {number}: expected {len(header)} comma-separated fields, "
            f"got {len(cells)}"
        )
    row = dict(zip(header, cells))
    if not row["run"].isdigit():
        raise TableError(f"{path}: line {number}: run {row['run']!r} is not an integer >= 0")
    if row["direction"] not in _TEXT_DIRECTION:
        raise TableError(f"{path}: line {number}: direction {row['direction']!r} is not +, -")
    if row["role"] not in ROLES:
        raise TableError(
            f"{path}: line {number}: role {row['role']!r} is not one of {', '.join(ROLES)}"
        )
    targets = tuple(parse_number(path, number, h, row[h]) for h in header[3 : 3 + n_axes])

    def opt(name: str) -> float | None:
        text = row.get(name, "")
        if text == "":
            return None
        value = parse_number(path, number, name, text)
        if value < 0 or (name == "speed_mm_s" and value == 0):
            raise TableError(f"{path}: line {number}: {name} {text!r} must be positive")
        return value

    return Move(int(row["run"]), _TEXT_DIRECTION[row["direction"]], row["role"], targets,
                opt("speed_mm_s"), opt("dwell_s"))  # fmt: skip
