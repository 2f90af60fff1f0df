"""How a commissioning step runs: :class:`StepRunner`.

Everything a commissioning does to the machine goes through :meth:`StepRunner.step`: a
plan run once (resumed from its raw file after an interruption), its machine time counted
against the budget, its runs read between drift references so the readings can be put back
to the thermal state commissioning began in.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ..fitting import adaptive
from ..measuring.from_file import STOP_TIME
from ..plans.plans import (
    Move,
    Plan,
    read_plan,
    write_plan,
)
from ..plans.rawdata import RawData, read_raw_csv
from ..plans.runner import join_values_async
from .budget import split_runs
from .settings import BudgetSpent, CommissionAborted, Settings

if TYPE_CHECKING:
    from .axes import Axes
    from .budget import Budget
    from .drift import DriftRefs
    from .record import Record

Say = Callable[[str], None]


class StepRunner:
    """Runs a plan as a step: once, resumed from its raw file, counted against the budget, its
    runs read between drift references; and reads a step's readings back."""

    def __init__(self, axes: Axes, record: Record, drift: DriftRefs, budget: Budget, say: Say,
                 progress: Callable[[str, int, int], None] | None = None) -> None:
        self.progress = progress
        self.s = axes.s
        self.config = axes.config
        self.axes = axes
        self.record = record
        self.drift = drift
        self.budget = budget
        self.say = say

    def raw_as_read(self, name: str) -> RawData:
        """A step's raw data (all its runs) as the instrument read it: the machine's drift
        in it (what the technician gets from the same readings, and what a recheck reads)."""
        step = self.record.state["steps"].get(name, {})
        parts = step.get("parts") or [{"raw": self.record.rel(self.record.raw_path(name))}]
        return concat_raw([read_raw_csv(self.record.config_dir / part["raw"]) for part in parts])

    def raw(self, name: str) -> RawData:
        """A step's raw data (all its runs) with the machine's thermal drift during each run
        taken off: what the readings would have been in the state commissioning began in."""
        step = self.record.state["steps"].get(name, {})
        parts = step.get("parts") or [{"raw": self.record.rel(self.record.raw_path(name))}]
        datas = []
        for part in parts:
            data = read_raw_csv(self.record.config_dir / part["raw"])
            drifts = {a: adaptive.Drift.from_json(v) for a, v in (part.get("drift") or {}).items()
                      if self.drift.drift_taken_off(a)}  # fmt: skip
            for a, cold in (part.get("cold_mm") or {}).items():
                if a in drifts and self.drift.drift_spread_mm(a) is not None:
                    # measured with the sensor on, its axis's tables without it: what the
                    # sensor commanded at the cold start is taken off too
                    d = drifts[a]
                    drifts[a] = dataclasses.replace(
                        d, before_mm=(d.before_mm[0] + cold[0], d.before_mm[1] + cold[1]),
                        after_mm=(d.after_mm[0] + cold[0], d.after_mm[1] + cold[1]))
            if drifts:
                data = adaptive.drift_corrected(data, drifts)
            datas.append(data)
        return concat_raw(datas)

    def join(self, name: str, more: str) -> None:
        """Done step ``more``'s runs made done step ``name``'s (more runs at its targets):
        its parts and machine time; ``more`` then no step of its own (its raw files are
        ``name``'s now). Nothing where ``more`` is not done (joined already)."""
        steps = self.record.state["steps"]
        if more not in steps or name not in steps:
            return
        steps[name]["parts"] = [*steps[name].get("parts", []), *steps[more].get("parts", [])]
        steps[name]["machine_s"] = steps[name].get("machine_s", 0.0) + steps[more]["machine_s"]
        steps[name]["joined"] = [*steps[name].get("joined", []), more]
        del steps[more]
        self.record.state.get("apart", {}).pop(more, None)
        self.record.save()

    async def step(self, name: str, make: Callable[[], Plan], compensation: str,
                   park: dict[str, float] | None = None, drift: bool = True,
                   whole: bool = False) -> Path:
        """Run the plan ``make()`` as step ``name`` (once: a done step is skipped; a step
        begun resumes from its raw file with its saved plan); its raw file. ``drift``: the
        drift references are read before and after each of its runs (see :meth:`raw`);
        ``whole``: around the whole plan only (many short runs)."""
        raw = self.record.raw_path(name)
        if self.record.done(name):
            return raw
        if self.record.state.get("phase") == "original":  # never read under the user's own config
            raise RuntimeError(f"step {name}: the gateway runs your own config, not a "
                               "commissioning phase (a bug in compgw: please report it)")
        plan_path = self.record.dir / "plans" / f"{name}.plan"
        if plan_path.exists():
            plan = read_plan(plan_path)
        else:
            plan = self.axes.snap(make())
            self.axes.check_limits(plan)
            plan_path.parent.mkdir(parents=True, exist_ok=True)
            write_plan(plan_path, plan)
        cost_s = self.axes.estimate_s(plan)
        after = name.startswith("after")  # (what was kept and held is for the steps before)
        warming = name.removeprefix("warmup-")
        if self.s.finish and not after:
            raise BudgetSpent(f"--finish: {name} and the steps after it are not read")
        left_s = (self.s.budget_s - self.record.used_s if after
                  else self.budget.left_s(warming))  # fmt: skip
        need_s = self.budget.step_cost_s(plan, drift, whole)
        if need_s > left_s and not self.s.finish:  # (--finish: the after-run, whatever it takes)
            reserve_s = 0.0 if after else self.budget.reserve_s()
            held_s = 0.0 if after else self.budget.held_s(warming)
            refs = " with its drift references" if need_s > cost_s else ""
            raise BudgetSpent(f"{name} needs {need_s / 60:.1f} min of machine time{refs}, "
                              f"{max(0.0, left_s) / 60:.1f} min left"
                              + (f" ({reserve_s / 60:.1f} min kept for the after-run)"
                                 if reserve_s else "")
                              + (f" ({held_s / 60:.1f} min held for the warm-ups)"
                                 if held_s else ""))  # fmt: skip
        raw.parent.mkdir(parents=True, exist_ok=True)
        self.say(f"{name}: {sum(m.measured for m in plan.moves)} readings, "
                 f"{cost_s / 60:.1f} min of machine time ({compensation})")
        drifting = drift and "drift_base" in self.record.state
        # decided when the step begins, and kept: a resume cuts it as it was cut
        apart = self.record.state.setdefault("apart", {}).setdefault(name, not whole
                                                              and self.budget.runs_apart())
        parts = split_runs(plan) if drifting and apart else [plan]
        done_parts = self.record.state.setdefault("parts", {}).setdefault(name, [])
        # one recording holds the whole step the laser reads (the XY device's are read live)
        if self.drift.recorded() and len(plan.axes) == 1 and not done_parts:
            done_parts += await self._run_recorded(name, parts, raw, compensation, park,
                                                   drifting)  # fmt: skip
            self.record.save()
        for k, part in enumerate(parts):
            if k < len(done_parts):
                continue
            entry = await self._run_part(f"{name}.part{k + 1}", part,
                                         _part_raw(raw, k, len(parts)), compensation, park,
                                         drifting)  # fmt: skip
            done_parts.append(entry)
            self.record.save()
        self.record.state["steps"][name] = {"machine_s": cost_s, "parts": done_parts}
        self.record.state["parts"].pop(name, None)
        self.record.save()
        return raw

    async def _run_recorded(self, name: str, parts: list[Plan], raw: Path, compensation: str,
                            park: dict[str, float] | None, drifting: bool
                            ) -> list[dict[str, Any]]:  # fmt: skip
        """A step read from the laser software's own file: its runs, with a reading of
        the drift references before the first and after each, run as one plan, so that
        the technician makes one recording (or capture) per step (``DIR/<step>.rtx``), and
        cut back into the runs' raw files and the references' readings afterwards. The
        references are then stops of the same recording as the runs: one zero, one clock."""
        axis = parts[0].axes[0]
        refs = self.drift.ref_moves(axis, run=parts[0].moves[0].run) if drifting else []
        moves: list[Move] = []
        spans: list[tuple[int | None, int, int]] = []  # (run k or None: references, rows)

        def add(label: int | None, more: Sequence[Move]) -> None:
            start = sum(m.measured for m in moves)
            moves.extend(more)
            spans.append((label, start, start + sum(m.measured for m in more)))

        if drifting:
            add(None, refs)
        for k, part in enumerate(parts):
            add(k, part.moves)
            if drifting:
                add(None, refs)
        whole = self.record.dir / "raw" / "recorded" / f"{name}.csv"
        whole.parent.mkdir(parents=True, exist_ok=True)
        odo0 = self.drift.odometer()
        at0 = (self.record.state.get("odometer") or {}).get("at", {}).get(axis)
        self.record.state["last_refs"] = None  # the moves change the thermal state
        session = self.drift.session(park)
        try:
            await session.run(Plan(parts[0].kind, (axis,), tuple(moves), parts[0].meta),
                              whole, compensation)  # fmt: skip
        finally:
            self.record.retried(session.retried)
        self.drift.keep_datum(whole)
        odo1 = self.drift.odometer()
        data = read_raw_csv(whole)
        actual = data.actual_mm
        # a sensor read at each stop while the laser recorded (a warm-up's temperature or Δa)
        sensed = tuple(c for c in ("temperature_c", "delta_a_mm") if c in data.extra)
        extras = [{c: float(data.extra[c][i]) for c in sensed} for i in range(actual.size)]
        # when each stop was read (the recording came later): the drift log's clock, and
        # kept with its row (a warm-up with no sensor is timed by it)
        times = data.extra.get(STOP_TIME)
        if times:
            sensed = (*sensed, STOP_TIME)
            extras = [{**e, STOP_TIME: float(times[i])} for i, e in enumerate(extras)]
        # the odometer at each row (the travel of the moves up to it), for the drift log
        xs = np.array([m.target_mm[0] for m in moves])
        steps = np.abs(np.diff(np.concatenate([[xs[0] if at0 is None else at0], xs])))
        travel = np.cumsum(steps)[[i for i, m in enumerate(moves) if m.measured]]
        ending, starting = {}, {}  # each reading of the references by its first and last row
        for label, a, b in spans:
            if label is None:
                odo = {**odo0, axis: odo0.get(axis, 0.0) + float(travel[b - 1])}
                when = float(times[b - 1]) if times else None
                ending[b] = starting[a] = (self.drift.take_recorded(axis, actual[a:b], odo,
                                                                    when), odo, when)  # fmt: skip
        entries = []
        for label, a, b in spans:
            if label is None:
                continue
            part_raw = _part_raw(raw, label, len(parts))
            await join_values_async(parts[label], [{axis: float(v)} for v in actual[a:b]],
                                    whole, part_raw, {"compensation": compensation},
                                    extras[a:b], sensed)  # fmt: skip
            entry: dict[str, Any] = {"raw": self.record.rel(part_raw)}
            if times:  # the recording's span (its rows keep their own times)
                entry["span"] = {"at_s": [float(times[0]), float(times[-1])],
                                 "odometer_mm": [odo0, odo1]}  # fmt: skip
            if drifting:
                (before, odo_b, at_b), (after, odo_a, at_a) = ending[a], starting[b]
                before, after = self.drift.drift_now(before), self.drift.drift_now(after)
                if label == 0:
                    self.drift.log_drift(before, odo_b, at_b)
                self.drift.log_drift(after, odo_a, at_a)
                self._keep_drift(entry, before, after, {}, {})
            entries.append(entry)
        return entries

    async def _run_part(self, key: str, plan: Plan, raw: Path, compensation: str,
                        park: dict[str, float] | None, drifting: bool) -> dict[str, Any]:
        """One run of a step (its own raw file), the drift references read around it."""
        pending = self.record.state.setdefault("pending_refs", {})
        shapes = self.record.state.setdefault("pending_shapes", {})
        if drifting and key not in pending:
            unmoved = self.drift.refs_unmoved()  # the last run's after-reading, when it serves
            pending[key] = self.drift.drift_now(unmoved or await self.drift.measure_refs())
            shapes[key] = self.drift.drift_shapes()
            if unmoved is None:
                self.drift.log_drift(pending[key])
            self.record.save()
        self.record.state["last_refs"] = None  # the moves change the thermal state
        span = {"at_s": [self.drift.clock.now_s()], "odometer_mm": [self.drift.odometer()]}
        session = self.drift.session(park)
        if self.progress is not None:
            name = key.rsplit(".", 1)[0]
            session.progress = lambda k, n: self.progress(name, k, n)  # type: ignore[misc]
        try:
            await session.run(plan, raw, compensation)
        finally:
            self.record.retried(session.retried)
        span["at_s"].append(self.drift.clock.now_s())
        span["odometer_mm"].append(self.drift.odometer())
        # when it ran, and the travel then: the runs' own levels time the heat by it
        entry: dict[str, Any] = {"raw": self.record.rel(raw), "span": span}
        if drifting:
            after = self.drift.drift_now(await self.drift.measure_refs())
            self.drift.log_drift(after)
            before = pending.pop(key)
            self._keep_drift(entry, before, after, shapes.pop(key, {}),
                             self.drift.drift_shapes())  # fmt: skip
        return entry

    def _keep_drift(self, entry: dict[str, Any], before: dict[str, list[float]],
                    after: dict[str, list[float]], shape_before: dict[str, list[float]],
                    shape_after: dict[str, list[float]]) -> None:  # fmt: skip
        """A run's drift (mm at the references, before and after it) kept in its ``entry``
        for every axis (taken off where :meth:`DriftRefs.drift_taken_off` says), along the
        heat shape where :meth:`DriftRefs.drift_spread_mm` says the screw is warm where it
        works, and what a temperature sensor commanded at the cold start."""
        loaded = self.record.state.get("ref_commands") or {}
        start_c = self.record.state.get("start_temperature_c") or {}
        cold = {a: adaptive.thermal_mm(loaded[a], start_c.get(a)) for a in loaded
                if loaded[a].get("sensor") and a in start_c}  # fmt: skip
        if cold:  # what the sensor commands at the references at the cold start
            entry["cold_mm"] = cold
        entry["drift"] = {
            a: adaptive.Drift(
                self.axes.ref_positions(a), tuple(before[a]), tuple(after[a]),
                self.axes.travel(a) if a in shape_before and a in shape_after else None,
                tuple(shape_before.get(a, ())), tuple(shape_after.get(a, ()))).to_json()
            for a in self.axes.ref_axes()}  # fmt: skip
        self.record.state["drift_last"] = after


def _part_raw(raw: Path, k: int, count: int) -> Path:
    """The raw file of run ``k`` of a step's ``count`` (the step's own when it is one)."""
    return raw if count == 1 else raw.with_name(f"{raw.stem}.part{k + 1}.csv")


def concat_raw(parts: Sequence[RawData]) -> RawData:
    """Raw data of several files as one (rows in order)."""
    if len(parts) == 1:
        return parts[0]
    keys = set().union(*(p.extra for p in parts))
    return RawData(
        tuple(a for p in parts for a in p.axis),
        np.concatenate([p.run for p in parts]),
        np.concatenate([p.direction for p in parts]),
        np.concatenate([p.target_mm for p in parts]),
        np.concatenate([p.actual_mm for p in parts]),
        {k: tuple(v for p in parts for v in p.extra.get(k, ("",) * len(p))) for k in keys},
        tuple(n for p in parts for n in p.lines),
        parts[0].source,
    )


__all__ = ["BudgetSpent", "CommissionAborted", "Settings", "StepRunner", "concat_raw"]
