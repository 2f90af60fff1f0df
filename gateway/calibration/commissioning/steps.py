"""The machinery under ``compgw commission``: state, configs, drift references and steps.

Everything a commissioning does to the machine goes through :meth:`Steps.step`: a plan run
once (resumed from its raw file after an interruption), its machine time counted against
the budget, its runs read between drift references so the readings can be put back to the
thermal state commissioning began in. The configs it loads are written over the gateway's
own file and reloaded; :meth:`Steps.restore` puts the user's back.
"""

from __future__ import annotations

import dataclasses
import hashlib
import itertools
import json
import shutil
from collections.abc import Awaitable, Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from ...compensation import PitchStage, PitchTable
from ...compensation.errors import CompensationError, TableError
from ...config import GatewayConfig, load_config
from ...config_types import read_yaml
from ...formats import atomic_write_text
from ...tables import build_chain
from ..fitting import adaptive
from ..measuring.machine import MotionSettings
from ..measuring.session import Instruments, Session
from ..plans.plans import (
    Plan,
    plan_time_s,
    read_plan,
    snap_to_pulses,
    write_plan,
)
from ..plans.rawdata import RawData, read_raw_csv
from ..thermal.drift_shape import SweptHeat
from .configs import HEADER, Tables, identification, with_tables
from .drift import MEMORY_S, DriftRefs

STATE = "commission.json"
Say = Callable[[str], None]
Reload = Callable[[], Awaitable[None]]


class BudgetSpent(Exception):
    """The next step does not fit in the machine-time budget."""

class CommissionAborted(Exception):
    """Commissioning stopped; the message says where the gateway was left."""


@dataclass
class Settings:
    """What the command line gives."""

    config_path: Path
    out_dir: Path
    gateway: Any  # machine.Endpoint
    instruments: Instruments
    axes: tuple[str, ...]
    planar: tuple[str, str] | None = None
    lead_mm: dict[str, float] = field(default_factory=dict)
    tolerance_um: float = 2.0
    budget_s: float = 8 * 3600.0
    speed_mm_s: float = 100.0
    stop_s: float = 2.0
    motion: MotionSettings = field(default_factory=MotionSettings)
    seed: int = 0
    max_rounds: int = 6
    no_lead_search: bool = False  # axes without a lead get no cyclic stage
    runs: int = 3  # coarse ISO runs
    verify_runs: int = 2
    warmup_s: float = 1800.0
    grid: tuple[int, int] = (7, 5)
    tolerance_arcsec: float = 3.0  # rotary axes: ISO 230-2 E between the points

class Steps(DriftRefs):
    """One commissioning's state and the steps it runs (resumable from its state file)."""


    def __init__(self, settings: Settings, reload: Reload, say: Say = print,
                 progress: Callable[[str, int, int], None] | None = None) -> None:
        self.s = settings
        self.reload_fn = reload
        self.say = say
        self.progress = progress
        self.dir = settings.out_dir
        self.config_dir = settings.config_path.resolve().parent
        self.state_path = self.dir / STATE
        self.state: dict[str, Any] = {"version": 1, "steps": {}, "rounds": [], "notes": []}
        self._refs_read_here = False  # the drift references read by this process yet
        if self.state_path.exists():
            self.state = json.loads(self.state_path.read_text())
        self.original_path = self.dir / "original.yaml"
        self.tables = Tables.from_json(self.state.get("tables", {}))
        self.config: GatewayConfig = load_config(settings.config_path)
        for axis, lead in self.state.get("leads", {}).items():  # found by a lead search
            if lead and axis not in self.s.lead_mm:
                self.s.lead_mm[axis] = float(lead)
        # where each screw has been worked: the shape of its drift between the references
        kept = self.state.get("swept_heat", {})
        self.swept: dict[str, SweptHeat] = {
            a: SweptHeat.from_json(kept[a]) if a in kept else
            SweptHeat.for_travel(self._travel(a), MEMORY_S) for a in self.ref_axes()}  # fmt: skip

    # -- state ---------------------------------------------------------------------------
    def _save(self) -> None:
        self.state["tables"] = self.tables.to_json()
        self.state["swept_heat"] = {a: h.to_json() for a, h in self.swept.items()}
        self.dir.mkdir(parents=True, exist_ok=True)
        # compact: json's C encoder (an indent takes the pure-Python one, 10 x slower on the
        # drift log of a long run, and the state is written after every run)
        atomic_write_text(self.state_path, json.dumps(self.state, default=_plain,
                                                      separators=(",", ":")))  # fmt: skip

    def _plane_travel(self) -> tuple[tuple[float, float], tuple[float, float]]:
        """The travel (mm) of the plane's two axes, X role first."""
        assert self.s.planar is not None  # (only the plane's steps ask)
        ax, ay = self.s.planar
        return self._travel(ax), self._travel(ay)

    @property
    def used_s(self) -> float:
        steps = sum(step["machine_s"] for step in self.state["steps"].values())
        return float(steps + self.state.get("refs_s", 0.0))

    def _rel(self, path: Path) -> str:
        return str(path.resolve().relative_to(self.config_dir)) if path.resolve().is_relative_to(
            self.config_dir) else str(path.resolve())  # fmt: skip

    # -- configs -------------------------------------------------------------------------
    def original(self) -> dict[str, Any]:
        """The user's config as it was before commissioning (kept in DIR/original.yaml)."""
        if not self.original_path.exists():
            self.dir.mkdir(parents=True, exist_ok=True)
            shutil.copyfile(self.s.config_path, self.original_path)
        return read_yaml(self.original_path, TableError)

    def adopt_edits(self) -> None:
        """A resume after the user changed their own config (the file the gateway runs,
        put back at the abort, no phase's header): what they changed is taken as their
        config from here, and said (a baud rate fixed after an abort was written over by
        the first run's copy at the next abort). Changed axes (travel, pulses, units: what
        the readings so far were measured in) are refused: they need a new commissioning."""
        if not self.original_path.exists():
            return
        text = self.s.config_path.read_text()
        if text.startswith("# written by compgw commission") or \
                text == self.original_path.read_text():  # fmt: skip
            return
        mine, kept = read_yaml(self.s.config_path, TableError), self.original()
        for a in self.s.axes:
            now = {k: v for k, v in (mine.get("axes") or {}).get(a, {}).items()
                   if k != "compensation"}  # fmt: skip
            then = {k: v for k, v in kept["axes"][a].items() if k != "compensation"}
            if now != then:
                changed = sorted(k for k in {*now, *then} if now.get(k) != then.get(k))
                raise TableError(
                    f"{self.s.config_path}: axes.{a} changed since this commissioning began "
                    f"({', '.join(changed)}), which its readings were measured in: start "
                    f"over (remove {self.dir}, or give --out) or put back "
                    f"{self.original_path}")  # fmt: skip
        atomic_write_text(self.original_path, text)
        note = (f"your config changed since this commissioning began: {self.s.config_path} "
                "is taken as your config from here (an abort puts it back)")  # fmt: skip
        self.state.setdefault("notes", []).append(note)
        self._save()
        self.say(note)

    def phase_config(self, phase: str) -> dict[str, Any]:
        original = self.original()
        if phase == "identification":
            return identification(original, self.s.axes, self.tables)
        if phase == "warmup":  # nothing on, thermal neither: the laser sees the whole growth
            data = identification(original, self.s.axes, self.tables)
            for a in self.s.axes:
                data["axes"][a]["compensation"].pop("thermal", None)
            return data
        # on_trigger where both plane axes have a trigger: a master writing both targets
        # before the start gets both corrected for the point it asked for (immediate would
        # correct the first with the other's previous target)
        both = self.s.planar is not None and all(
            self.config.axes[a].registers.trigger is not None for a in self.s.planar)
        return with_tables(original, self.s.axes, self.tables, planar=phase == "full",
                           commit_default="on_trigger" if both else "immediate")

    def before_load(self, phase: str) -> None:
        """Bring the phase's files in line with each other before the gateway loads them
        (nothing here; the commissioning re-expresses its plane, :mod:`..fitting.plane_frame`)."""

    def staged(self, phase: str) -> tuple[GatewayConfig, Path]:
        """The phase's config written under DIR/configs (for the fits' paths and checks)."""
        path = self.dir / "configs" / f"{phase}.yaml"
        path.parent.mkdir(parents=True, exist_ok=True)
        atomic_write_text(path, yaml.safe_dump(self.phase_config(phase), sort_keys=False))
        return load_config(path), path

    async def use(self, phase: str) -> None:
        """Write the phase's config over the gateway's config file and have it reload.

        The drift references are read just before and just after the switch (the same
        thermal state): what they read differently is the new config, not drift, so the
        drift since the start stays known across configs."""
        base = self.state.get("drift_base")
        self.before_load(phase)
        text = HEADER.format(phase=phase, original=self._rel(self.original_path))
        text += yaml.safe_dump(self.phase_config(phase), sort_keys=False)
        digest = self._digest(text)
        if (base is not None and self.state.get("phase") == phase == base["phase"]
                and self.s.config_path.read_text() == text
                and self.state.get("loaded") == digest):
            return  # loaded already, tables and all: nothing to switch
        before, before_odo = None, None
        if base is not None and self.state.get("phase") == base["phase"]:
            last = self.state.get("last_refs")  # read since the last moves: the same state
            if not (last and last["phase"] == base["phase"]):
                await self._measure_refs()
                last = self.state["last_refs"]
            before, before_odo = last["refs"], last.get("odometer_mm")
        atomic_write_text(self.s.config_path, text)
        await self.reload_fn()
        self.state["phase"] = phase
        self.state["loaded"] = digest
        after = await self._measure_refs()
        drift = {a: [0.0, 0.0] for a in self.s.axes}
        if base is not None:
            if before is None:  # the chain broke (an abort restored your config): the last
                drift = self.state.get("drift_last", drift)  # known drift carries on
                note = f"drift references re-linked when {phase} was loaded after an interruption"
                if self.ref_axes() and note not in self.state["notes"]:  # (rotary: none)
                    self.state["notes"].append(note)
            else:
                drift = {a: [before[a][k] - base["refs"][a][k] for k in (0, 1)]
                         for a in self.s.axes}  # fmt: skip
        cfg = load_config(self.s.config_path)
        chain = build_chain(cfg, self.config_dir)
        commands = self._ref_commands(cfg, chain)
        old_commands = self.state.get("ref_commands") or {}
        # where the new commands put each axis at its references, by the loaded tables' own
        # error model (an axis without tables: the commands' difference); a state saved
        # before the commands were kept: the commands' difference
        moved = {a: adaptive.reading_moved_mm(chain, a, old_commands[a]["commands_mm"],
                                              now["commands_mm"])
                 for a, now in commands.items()
                 if "commands_mm" in (old_commands.get(a) or {})}  # fmt: skip
        new_base = adaptive.relinked_base(
            None if base is None or before is None else base["refs"], after, drift,
            old_commands, commands, self.state.get("start_temperature_c"), moved)  # fmt: skip
        self.state["ref_commands"] = commands
        self.state["drift_base"] = {"phase": phase, "refs": new_base}
        self.state["drift_last"] = drift
        if base is None or before is not None:  # at every switch too (the odometer when the
            self._log_drift(drift, before_odo)  # drift was read): a warm-up is its own stretch
        self._save()

    def _digest(self, text: str) -> str:
        """What the gateway loads: the config text and every table file it names (a
        refinement rewrites a table under the same name: the gateway must reload it)."""
        h = hashlib.sha256(text.encode())
        for path in sorted((self.dir / "tables").glob("*.*")):
            h.update(path.name.encode() + b"\0" + path.read_bytes())
        return h.hexdigest()

    def raw_paths(self, name: str) -> list[Path]:
        """The raw files of a step (one per run when its runs were measured apart)."""
        parts = self.state["steps"].get(name, {}).get("parts")
        if not parts:
            return [self.dir / "raw" / f"{name}.csv"]
        return [self.config_dir / part["raw"] for part in parts]

    def forget(self, name: str, keep_in: Path | None = None) -> None:
        """Step ``name`` as if never run: its raw files removed (or moved into ``keep_in``)
        and its records dropped; the next :meth:`step` of that name measures it again."""
        for path in self.raw_paths(name):
            if keep_in is not None and path.exists():
                keep_in.mkdir(parents=True, exist_ok=True)
                path.replace(keep_in / path.name)
            else:
                path.unlink(missing_ok=True)
        for key in ("steps", "parts", "apart"):
            self.state.get(key, {}).pop(name, None)
        self._save()

    def raw_as_read(self, name: str) -> RawData:
        """A step's raw data (all its runs) as the instrument read it: the machine's drift
        in it (what the technician gets from the same readings, and what a recheck reads)."""
        step = self.state["steps"].get(name, {})
        parts = step.get("parts") or [{"raw": self._rel(self.dir / "raw" / f"{name}.csv")}]
        return concat_raw([read_raw_csv(self.config_dir / part["raw"]) for part in parts])

    def raw(self, name: str) -> RawData:
        """A step's raw data (all its runs) with the machine's thermal drift during each run
        taken off: what the readings would have been in the state commissioning began in."""
        step = self.state["steps"].get(name, {})
        parts = step.get("parts") or [{"raw": self._rel(self.dir / "raw" / f"{name}.csv")}]
        datas = []
        for part in parts:
            data = read_raw_csv(self.config_dir / part["raw"])
            drifts = {a: adaptive.Drift.from_json(v) for a, v in (part.get("drift") or {}).items()
                      if self.drift_taken_off(a)}  # fmt: skip
            for a, cold in (part.get("cold_mm") or {}).items():
                if a in drifts and self.drift_spread_mm(a) is not None:
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

    async def restore(self, failed: BaseException | None = None) -> str:
        """Put the user's own config back and have the gateway load it; says what happened
        (``failed``: what stopped the commissioning, not said twice)."""
        if not self.original_path.exists():
            return "the gateway's config file was not changed"
        shutil.copyfile(self.original_path, self.s.config_path)
        self.state["phase"] = "original"
        self._save()
        from ..measuring.machine import ConfigMismatch

        if isinstance(failed, ConfigMismatch):  # the gateway runs another file: left alone
            return (f"{self.s.config_path} is back as it was; the gateway runs its own file, "
                    "which commissioning did not touch")  # fmt: skip
        try:
            await self.reload_fn()
        except Exception as exc:  # the gateway may be down: it loads the file at its start
            why = ("for the same reason" if failed is not None and str(exc) == str(failed)
                   else str(exc))  # fmt: skip
            return (f"your own config is back in {self.s.config_path} (the gateway did not "
                    f"reload it: {why}; it loads it when it starts)")  # fmt: skip
        return f"the gateway runs your own config again ({self.s.config_path})"

    # -- steps ---------------------------------------------------------------------------
    def _snap(self, plan: Plan) -> Plan:
        return snap_to_pulses(plan, {n: a.pulse_mm for n, a in self.config.axes.items()})

    def _check_limits(self, plan: Plan) -> None:
        for move in plan.moves:
            for name, target in zip(plan.axes, move.target_mm):
                lo, hi = self.config.axes[name].travel_mm
                if not lo <= target <= hi:
                    raise TableError(f"plan {plan.kind}: axis {name} target {target:g} mm is "
                                     f"outside the soft limits {lo:g}..{hi:g} mm")  # fmt: skip

    def estimate_s(self, plan: Plan) -> float:
        return plan_time_s(plan, self.s.speed_mm_s, self.s.stop_s)

    def refs_around_s(self, plan: Plan, whole: bool = False) -> float:
        """Machine time (s) of the drift references read around ``plan``'s runs (around
        the whole plan with ``whole``): before the first and after each, one run's
        after-reading being the next one's before-reading."""
        parts = 1 if whole or not self.runs_apart() else len(_parts(plan))
        return (parts + 1) * self.refs_cost_s(self.ref_axes())

    def runs_apart(self) -> bool:
        """Whether a step's runs each get their own drift references, not the whole step
        one pair. One pair only on a short budget (:meth:`short`), and only while no linear
        axis has a temperature sensor and no axis's references have varied by more than
        their own scatter (:meth:`drift_stands_out`, so not before they have been read three
        times): there the references only watch for a drift to begin, and around every
        run they cost a small stage a third of its budget (mcu1025 at 1.5 x a manual
        calibration's time: 6.1 of 17.7 minutes). A long budget keeps them around every
        run: a drift that stands out only later is then taken off run by run, where one
        pair around a whole sweep left its heat in the tables as a bow (mcu1025 at 8 h,
        noise-free: 0.6 → 1.2 µm on X, 1.4 → 2.6 µm on Y)."""
        if not self.state.get("short"):
            return True
        return any(self.config.axes[a].compensation.thermal is not None
                   or self.drift_stands_out(a) for a in self.ref_axes())  # fmt: skip

    def step_cost_s(self, plan: Plan, drift: bool = True, whole: bool = False) -> float:
        """Machine time (s) of running ``plan`` as a step: its moves, and the drift
        references read around its runs once drift is counted (see :meth:`step`)."""
        drifting = drift and "drift_base" in self.state
        return self.estimate_s(plan) + (self.refs_around_s(plan, whole) if drifting else 0.0)

    def reserve_s(self) -> float:
        """Machine time kept back from every step for the steps that must end the job."""
        return 0.0

    def iso_runs(self) -> int:
        """Runs per target of the ISO runs: the configured ones, or fewer where a short
        budget holds every axis's table only so (``Commission._iso_runs_that_fit``)."""
        return int(self.state.get("iso_runs") or self.s.runs)

    def left_s(self) -> float:
        """Machine time (s) the budget has left for the steps before the after-run: what is
        neither used nor kept for it (:meth:`reserve_s`); negative when overspent."""
        return self.s.budget_s - self.used_s - self.reserve_s()

    def done(self, name: str) -> bool:
        return name in self.state["steps"]

    async def step(self, name: str, make: Callable[[], Plan], compensation: str,
                   park: dict[str, float] | None = None, drift: bool = True,
                   whole: bool = False) -> Path:
        """Run the plan ``make()`` as step ``name`` (once: a done step is skipped; a step
        begun resumes from its raw file with its saved plan); its raw file. ``drift``: the
        drift references are read before and after each of its runs (see :meth:`raw`);
        ``whole``: around the whole plan only (many short runs)."""
        raw = self.dir / "raw" / f"{name}.csv"
        if self.done(name):
            return raw
        if self.state.get("phase") == "original":  # never read under the user's own config
            raise RuntimeError(f"step {name}: the gateway runs your own config, not a "
                               "commissioning phase (a bug in compgw: please report it)")
        plan_path = self.dir / "plans" / f"{name}.plan"
        if plan_path.exists():
            plan = read_plan(plan_path)
        else:
            plan = self._snap(make())
            self._check_limits(plan)
            plan_path.parent.mkdir(parents=True, exist_ok=True)
            write_plan(plan_path, plan)
        cost_s = self.estimate_s(plan)
        reserve_s = 0.0 if name.startswith("after") else self.reserve_s()
        need_s = self.step_cost_s(plan, drift, whole)
        if self.used_s + need_s + reserve_s > self.s.budget_s:
            left_s = max(0.0, self.s.budget_s - self.used_s - reserve_s)
            refs = " with its drift references" if need_s > cost_s else ""
            raise BudgetSpent(f"{name} needs {need_s / 60:.1f} min of machine time{refs}, "
                              f"{left_s / 60:.1f} min left"
                              + (f" ({reserve_s / 60:.1f} min kept for the after-run)"
                                 if reserve_s else ""))  # fmt: skip
        raw.parent.mkdir(parents=True, exist_ok=True)
        self.say(f"{name}: {sum(m.measured for m in plan.moves)} readings, "
                 f"{cost_s / 60:.1f} min of machine time ({compensation})")
        drifting = drift and "drift_base" in self.state
        # decided when the step begins, and kept: a resume cuts it as it was cut
        apart = self.state.setdefault("apart", {}).setdefault(name, not whole
                                                              and self.runs_apart())
        parts = _parts(plan) if drifting and apart else [plan]
        done_parts = self.state.setdefault("parts", {}).setdefault(name, [])
        for k, part in enumerate(parts):
            if k < len(done_parts):
                continue
            part_raw = raw if len(parts) == 1 else raw.with_name(f"{name}.part{k + 1}.csv")
            entry = await self._run_part(f"{name}.part{k + 1}", part, part_raw, compensation,
                                         park, drifting)  # fmt: skip
            done_parts.append(entry)
            self._save()
        self.state["steps"][name] = {"machine_s": cost_s, "parts": done_parts}
        self.state["parts"].pop(name, None)
        self._save()
        return raw

    async def _run_part(self, key: str, plan: Plan, raw: Path, compensation: str,
                        park: dict[str, float] | None, drifting: bool) -> dict[str, Any]:
        """One run of a step (its own raw file), the drift references read around it."""
        pending = self.state.setdefault("pending_refs", {})
        shapes = self.state.setdefault("pending_shapes", {})
        if drifting and key not in pending:
            unmoved = self._refs_unmoved()  # the last run's after-reading, when it serves
            pending[key] = self._drift_now(unmoved or await self._measure_refs())
            shapes[key] = self._drift_shapes()
            if unmoved is None:
                self._log_drift(pending[key])
            self._save()
        self.state["last_refs"] = None  # the moves change the thermal state
        session = Session(self.config, self.config_dir, self.s.gateway, self.s.instruments,
                          self.s.motion, park or {}, on_move=self._count_travel)  # fmt: skip
        if self.progress is not None:
            name = key.rsplit(".", 1)[0]
            session.progress = lambda k, n: self.progress(name, k, n)  # type: ignore[misc]
        try:
            await session.run(plan, raw, compensation)
        finally:
            self._retried(session.retried)
        entry: dict[str, Any] = {"raw": self._rel(raw)}
        if drifting:
            after = self._drift_now(await self._measure_refs())
            self._log_drift(after)
            before = pending.pop(key)
            shape_before, shape_after = shapes.pop(key, {}), self._drift_shapes()
            # kept for every axis (taken off where :meth:`drift_taken_off` says), along the
            # heat shape where :meth:`drift_spread_mm` says the screw is warm where it works
            loaded = self.state.get("ref_commands") or {}
            start_c = self.state.get("start_temperature_c") or {}
            cold = {a: adaptive.thermal_mm(loaded[a], start_c.get(a)) for a in loaded
                    if loaded[a].get("sensor") and a in start_c}  # fmt: skip
            if cold:  # what the sensor commands at the references at the cold start
                entry["cold_mm"] = cold
            entry["drift"] = {
                a: adaptive.Drift(
                    self._ref_positions(a), tuple(before[a]), tuple(after[a]),
                    self._travel(a) if a in shape_before and a in shape_after else None,
                    tuple(shape_before.get(a, ())), tuple(shape_after.get(a, ()))).to_json()
                for a in self.ref_axes()}  # fmt: skip
            self.state["drift_last"] = after
        return entry

    # -- axes and tables ------------------------------------------------------------------
    def _rotary(self, axis: str) -> bool:
        return axis in self.config.axes and self.config.axes[axis].rotary

    def _wraps(self, axis: str) -> bool:
        return axis in self.config.axes and self.config.axes[axis].wraps

    def within_cap(self, axis: str, table: PitchTable, method: str) -> str:
        """``method``, or straight lines where ``table`` read along it would pass the axis's
        correction cap (the gateway would refuse the config)."""
        if method == "linear":
            return method
        try:
            PitchStage(table, method, wrap=self._wraps(axis)).check_cap(  # type: ignore[arg-type]
                self.config.axes[axis].compensation.max_correction_mm)
        except CompensationError:
            return "linear"
        return method

    def interpolation_of(self, axis: str) -> str:
        """The interpolation chosen for ``axis``'s table (a rotary axis's by its fit)."""
        if not self._rotary(axis):
            return self.tables.interpolation.get(axis, "linear")
        return str(self.state.get("rotary", {}).get(axis, {}).get("interpolation", "linear"))

    def table_stage(self, axis: str, table: PitchTable, method: str | None = None
                    ) -> PitchStage:  # fmt: skip
        """The stage the gateway builds from ``table``: the chosen interpolation (or
        ``method``), the wrap."""
        return PitchStage(table, method or self.interpolation_of(axis),  # type: ignore[arg-type]
                          wrap=self._wraps(axis))  # fmt: skip


def _plain(value: Any) -> Any:
    """numpy scalars (a bool or float from an array) as plain Python for JSON."""
    if hasattr(value, "item"):
        return value.item()
    raise TypeError(f"{type(value).__name__} is not JSON serializable")


def _parts(plan: Plan) -> list[Plan]:
    """A plan cut into its runs (each measured with its own drift references), in order;
    a plan whose runs interleave (seed 000's backlash repeats) stays whole."""
    runs = [m.run for m in plan.moves]
    if len(set(runs)) < 2 or any(b < a for a, b in itertools.pairwise(runs)):
        return [plan]
    return [Plan(plan.kind, plan.axes, tuple(m for m in plan.moves if m.run == j), plan.meta)
            for j in sorted(set(runs))]  # fmt: skip


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
