"""Executing a plan: move, wait, measure, append one raw row per axis, resume after a stop.

The runner is transport-free: it is given a ``move`` coroutine (targets → machine at rest)
and a ``measure`` coroutine (move → measured positions), so the same loop runs against a
gateway (:mod:`..measuring.machine`), and tests can drive it with anything. Each reading
is appended and flushed by :class:`~.rawdata.RawWriter` before the next move, so an
interruption (Ctrl-C, a crash, a cancelled task) loses nothing already measured (a power
cut, at most the last second's); running the same plan into the same raw file again
continues at the first move not yet measured
(:func:`~.plans.resume_index`), after going to the previous move's target so the move is
approached from the planned side.

Raw files written here start with ``# key: value`` comment lines (``kind``, ``axes``,
``compensation``, the plan's own parameters) that :func:`read_raw_meta` returns, so
``compgw fit`` knows what a file measured.

Offline (``--join``): :func:`join_readings` pairs the plan's measured moves, in order, with
the rows of a CSV exported from a laser system (see its docstring).
"""

from __future__ import annotations

import asyncio
import os
import time
from collections.abc import Awaitable, Callable, Mapping, Sequence
from dataclasses import dataclass, replace
from pathlib import Path

from ...compensation.errors import TableError
from ...formats.lines import csv_header, data_lines, parse_number
from .plans import Move, Plan, resume_index
from .rawdata import RawData, RawWriter, read_raw_csv

MoveFn = Callable[[Mapping[str, float]], Awaitable[None]]
MeasureFn = Callable[[Move], Awaitable[Mapping[str, float]]]
ExtraFn = Callable[[Move], Awaitable[Mapping[str, float]]]
ProgressFn = Callable[[int, int], None]


@dataclass(frozen=True)
class RunSummary:
    """What a call of :func:`run_plan` did: moves done, where it started, the total."""

    raw_path: Path
    total_moves: int
    resumed_at: int
    measured_now: int
    complete: bool


def extra_columns(plan: Plan, extra_names: tuple[str, ...] = ()) -> tuple[str, ...]:
    """Raw extra columns: ``time_s``, the commanded point of multi-axis plans, then others."""
    point = tuple(f"{a.lower()}_mm" for a in plan.axes) if len(plan.axes) > 1 else ()
    return ("time_s", *point, *extra_names)


def read_raw_meta(path: str | os.PathLike[str]) -> dict[str, str]:
    """The ``# key: value`` lines before the header of a raw file (empty if none)."""
    meta: dict[str, str] = {}
    try:
        text = Path(path).read_text(encoding="utf-8")
    except OSError as exc:
        raise TableError(f"{path}: cannot read: {exc.strerror}") from None
    for line in text.splitlines():
        stripped = line.strip()
        if not stripped:
            continue
        if not stripped.startswith("#"):
            break
        key, sep, value = stripped[1:].partition(":")
        if sep and key.strip() and " " not in key.strip():
            meta[key.strip()] = value.strip()
    return meta


def _start_file(path: Path, plan: Plan, meta: Mapping[str, str]) -> None:
    """Write the meta comment lines into a new (or empty) raw file."""
    if path.exists() and path.stat().st_size > 0:
        return
    info = {"kind": plan.kind, "axes": " ".join(plan.axes), **dict(plan.meta), **meta}
    lines = ["# compgw raw data (see gateway/calibration/plans/rawdata.py)"]
    lines += [f"# {k}: {v}" for k, v in info.items()]
    with open(path, "w", encoding="utf-8") as handle:
        handle.write("\n".join(lines) + "\n")
        handle.flush()
        os.fsync(handle.fileno())


def _existing(path: Path) -> RawData | None:
    if not path.exists():
        return None
    try:
        return read_raw_csv(path)
    except TableError as exc:
        if "empty table" in str(exc):
            return None  # only the meta lines so far
        raise


async def run_plan(
    plan: Plan,
    raw_path: str | os.PathLike[str],
    move: MoveFn,
    measure: MeasureFn,
    *,
    extra: ExtraFn | None = None,
    extra_names: tuple[str, ...] = (),
    meta: Mapping[str, str] | None = None,
    progress: ProgressFn | None = None,
    dwell: Callable[[float], Awaitable[None]] | None = None,
    clock: Callable[[], float] = time.time,
) -> RunSummary:
    """Run ``plan``, appending raw rows to ``raw_path``; resume if it already has some.

    ``progress(done, total)`` is called after every move (done counts from the resume
    point's index). ``dwell(seconds)`` is awaited before measuring moves with ``dwell_s``.
    ``clock`` (s) times the rows' ``time_s``: the machine's, where it is not the computer's.
    """
    path = Path(raw_path)
    plan, offset = raw_runs(plan)
    if offset:
        meta = {**(meta or {}), "run_offset": f"{offset} (raw run = plan run + {offset})"}
    existing = _existing(path)
    start = 0 if existing is None else resume_index(plan, existing)
    total = len(plan.moves)
    if start >= total:
        if progress is not None:
            progress(total, total)
        return RunSummary(path, total, start, 0, True)
    _start_file(path, plan, meta or {})
    t0 = clock()
    measured = 0
    with RawWriter(path, extra_columns(plan, extra_names)) as writer:
        if start > 0:
            await move(dict(zip(plan.axes, plan.moves[start - 1].target_mm)))
        if progress is not None:
            progress(start, total)
        for k in range(start, total):
            m = plan.moves[k]
            targets = dict(zip(plan.axes, m.target_mm))
            await move(targets)
            if m.measured:
                if m.dwell_s and dwell is not None:
                    await dwell(m.dwell_s)
                actual = await measure(m)
                more = dict(await extra(m)) if extra is not None else {}
                more["time_s"] = round(clock() - t0, 3)
                if len(plan.axes) > 1:
                    more.update({f"{a.lower()}_mm": t for a, t in targets.items()})
                direction = m.direction if m.direction != 0 else 1
                for name, target in targets.items():
                    writer.append(name, m.run, direction, target, float(actual[name]), **more)
                measured += 1
            if progress is not None:
                progress(k + 1, total)
    return RunSummary(path, total, start, measured, True)


def raw_runs(plan: Plan) -> tuple[Plan, int]:
    """The plan with runs shifted to start at 1 where it uses run 0 (the warm-up's cold
    reading): raw files number runs from 1. Returns the plan and the offset added."""
    if not plan.moves or min(m.run for m in plan.moves) >= 1:
        return plan, 0
    moves = tuple(replace(m, run=m.run + 1) for m in plan.moves)
    return Plan(plan.kind, plan.axes, moves, plan.meta), 1


# -- offline join ---------------------------------------------------------------------------
def join_readings(
    plan: Plan,
    readings_path: str | os.PathLike[str],
    raw_path: str | os.PathLike[str],
    meta: Mapping[str, str] | None = None,
) -> RunSummary:
    """Raw data from a plan and a laser system's export, paired in measuring order.

    The export is a CSV (``#`` comments allowed) with one row per measured move of the plan,
    in the plan's order, and for a one-axis plan a column ``actual_mm`` (position read by the
    laser, mm) or ``deviation_um`` (actual − target, µm); for a multi-axis plan one
    ``<axis>_actual_mm`` or ``<axis>_deviation_um`` column per axis (axis name in lower case).
    An optional ``target_mm`` (one axis) or ``<axis>_target_mm`` column is checked against the
    plan (within 1 µm), so an export of another plan, or one with a reading missing or added,
    is refused at the first row that is not the plan's. With the targets, fewer rows than the
    plan measures give a partial raw file (joining again later appends the rest); without
    them the rows must be exactly the plan's readings (a missing one would shift every
    reading after it into another target's place, unseen).
    """
    plan, _ = raw_runs(plan)
    rows = data_lines(readings_path)
    _, header = csv_header(readings_path, rows)
    col = {name: k for k, name in enumerate(header)}
    single = len(plan.axes) == 1

    def names(axis: str, what: str) -> str:
        return what if single else f"{axis.lower()}_{what}"

    for a in plan.axes:
        if names(a, "actual_mm") not in col and names(a, "deviation_um") not in col:
            raise TableError(
                f"{readings_path}: needs a column {names(a, 'actual_mm')} or "
                f"{names(a, 'deviation_um')}"
            )
    measured = [m for m in plan.moves if m.measured]
    readings: list[tuple[int, dict[str, float]]] = []
    for k, (number, text) in enumerate(rows):
        if k >= len(measured):
            raise TableError(f"{readings_path}: line {number}: more rows than the plan measures "
                             f"({len(measured)})")  # fmt: skip
        cells = [c.strip() for c in text.split(",")]
        if len(cells) != len(header):
            raise TableError(f"{readings_path}: line {number}: expected {len(header)} fields")
        move = measured[k]
        values: dict[str, float] = {}
        for a, target in zip(plan.axes, move.target_mm):
            check = names(a, "target_mm")
            if check in col:
                t = parse_number(readings_path, number, check, cells[col[check]])
                if abs(t - target) > 1e-3:
                    raise TableError(
                        f"{readings_path}: line {number}: {check} {t:g} is not the plan's "
                        f"target {target:g} (move {k + 1} measured)"
                    )
            if names(a, "actual_mm") in col:
                name = names(a, "actual_mm")
                values[a] = parse_number(readings_path, number, name, cells[col[name]])
            else:
                name = names(a, "deviation_um")
                dev = parse_number(readings_path, number, name, cells[col[name]])
                values[a] = target + dev * 1e-3
        readings.append((number, values))

    targets_given = all(names(a, "target_mm") in col for a in plan.axes)
    if not targets_given and len(readings) != len(measured):
        raise TableError(f"{readings_path}: {len(readings)} readings, the plan measures "
                         f"{len(measured)}: without a {names(plan.axes[0], 'target_mm')} "
                         "column a missing or added reading would shift every reading after "
                         "it into another target's place: export the whole run, or with its "
                         "targets")  # fmt: skip
    return join_values(plan, [values for _, values in readings], readings_path, raw_path, meta)


def join_values(plan: Plan, readings: Sequence[Mapping[str, float]],
                source: str | os.PathLike[str], raw_path: str | os.PathLike[str],
                meta: Mapping[str, str] | None = None) -> RunSummary:  # fmt: skip
    """Raw data from a plan and readings (mm per axis) of its first measured moves, in
    order, taken from ``source`` (a file checked against the plan by the caller)."""
    return asyncio.run(join_values_async(plan, readings, source, raw_path, meta))


async def join_values_async(plan: Plan, readings: Sequence[Mapping[str, float]],
                            source: str | os.PathLike[str], raw_path: str | os.PathLike[str],
                            meta: Mapping[str, str] | None = None,
                            extras: Sequence[Mapping[str, float]] = (),
                            extra_names: tuple[str, ...] = ()) -> RunSummary:  # fmt: skip
    """:func:`join_values` in a running event loop; ``extras``: each reading's other
    columns (``extra_names``: a sensor read at the stop), kept beside it."""
    plan, _ = raw_runs(plan)
    # each move its own object: a move listed twice (the same drift references read again
    # in one recording) is two stops, and took the later stop's reading for both
    plan = Plan(plan.kind, plan.axes, tuple(replace(m) for m in plan.moves), plan.meta)
    measured = [m for m in plan.moves if m.measured]
    by_move = {id(m): values for m, values in zip(measured, readings)}
    more = {id(m): values for m, values in zip(measured, extras)}

    async def no_move(_: Mapping[str, float]) -> None:
        return None

    async def measure(move: Move) -> Mapping[str, float]:
        return by_move[id(move)]

    async def extra(move: Move) -> Mapping[str, float]:
        return more[id(move)]

    plan_part = Plan(plan.kind, plan.axes, _through_last(plan, len(readings)), plan.meta)
    return await run_plan(plan_part, raw_path, no_move, measure,
                          extra=extra if extra_names else None, extra_names=extra_names,
                          meta={"joined": str(source), **(meta or {})})  # fmt: skip


def _through_last(plan: Plan, count: int) -> tuple[Move, ...]:
    """The plan's moves up to and including its ``count``-th measured move."""
    seen = 0
    for k, m in enumerate(plan.moves):
        seen += m.measured
        if seen == count:
            return plan.moves[: k + 1]
    return plan.moves
