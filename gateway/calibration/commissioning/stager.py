"""Commissioning's config writer: each phase's config over the gateway's file, reloaded."""

from __future__ import annotations

import hashlib
import shutil
from collections.abc import Awaitable, Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

import yaml

from ...compensation.errors import TableError
from ...config import GatewayConfig, load_config
from ...config_types import read_yaml
from ...formats import atomic_write_text
from ...tables import build_chain
from ..fitting import adaptive
from ..fitting.plane_frame import reframe_plane
from .configs import HEADER, WRITTEN, identification, with_tables

if TYPE_CHECKING:
    from .axes import Axes
    from .drift import DriftRefs
    from .record import Record

Say = Callable[[str], None]
Reload = Callable[[], Awaitable[None]]


class Stager:
    """The config writer: each phase's config written over the gateway's file and reloaded, the
    drift references read across the switch; the user's own config kept and put back."""

    def __init__(self, axes: Axes, record: Record, drift: DriftRefs, reload: Reload,
                 say: Say) -> None:  # fmt: skip
        self.reload_fn = reload
        self.s = axes.s
        self.config = axes.config
        self.axes = axes
        self.record = record
        self.drift = drift
        self.say = say

    # -- configs -------------------------------------------------------------------------
    def original(self) -> dict[str, Any]:
        """The user's config as it was before commissioning (kept in DIR/original.yaml)."""
        if not self.record.original_path.exists():
            self.record.dir.mkdir(parents=True, exist_ok=True)
            shutil.copyfile(self.s.config_path, self.record.original_path)
        return read_yaml(self.record.original_path, TableError)

    def adopt_edits(self) -> None:
        """A resume after the user changed their own config (the file the gateway runs,
        put back at the abort, no phase's header): what they changed is taken as their
        config from here, and said (a baud rate fixed after an abort was written over by
        the first run's copy at the next abort). Changed axes (travel, pulses, units: what
        the readings so far were measured in) are refused: they need a new commissioning."""
        if not self.record.original_path.exists():
            return
        text = self.s.config_path.read_text()
        if text.startswith(WRITTEN) or \
                text == self.record.original_path.read_text():  # fmt: skip
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
                    f"over (remove {self.record.dir}, or give --out) or put back "
                    f"{self.record.original_path}")  # fmt: skip
        atomic_write_text(self.record.original_path, text)
        note = (f"your config changed since this commissioning began: {self.s.config_path} "
                "is taken as your config from here (an abort puts it back)")  # fmt: skip
        self.record.state.setdefault("notes", []).append(note)
        self.record.save()
        self.say(note)

    def _linear_phase(self, phase: str) -> dict[str, Any]:
        """The phase's config as the linear axes and the plane have it."""
        original = self.original()
        if phase == "identification":
            return identification(original, self.s.axes, self.record.tables)
        if phase == "warmup":  # nothing on, thermal neither: the laser sees the whole growth
            data = identification(original, self.s.axes, self.record.tables)
            for a in self.s.axes:
                data["axes"][a]["compensation"].pop("thermal", None)
            return data
        # on_trigger where both plane axes have a trigger: a master writing both targets
        # before the start gets both corrected for the point it asked for (immediate would
        # correct the first with the other's previous target)
        both = self.s.planar is not None and all(
            self.config.axes[a].registers.trigger is not None for a in self.s.planar)
        return with_tables(original, self.s.axes, self.record.tables, planar=phase == "full",
                           commit_default="on_trigger" if both else "immediate")

    def staged(self, phase: str) -> tuple[GatewayConfig, Path]:
        """The phase's config written under DIR/configs (for the fits' paths and checks)."""
        path = self.record.dir / "configs" / f"{phase}.yaml"
        path.parent.mkdir(parents=True, exist_ok=True)
        atomic_write_text(path, yaml.safe_dump(self.phase_config(phase), sort_keys=False))
        return load_config(path), path

    async def use(self, phase: str) -> None:
        """Write the phase's config over the gateway's config file and have it reload.

        The drift references are read just before and just after the switch (the same
        thermal state): what they read differently is the new config, not drift, so the
        drift since the start stays known across configs."""
        base = self.record.state.get("drift_base")
        self.before_load(phase)
        text = HEADER.format(phase=phase, original=self.record.rel(self.record.original_path))
        text += yaml.safe_dump(self.phase_config(phase), sort_keys=False)
        digest = self._digest(text)
        if (base is not None and self.record.state.get("phase") == phase == base["phase"]
                and self.s.config_path.read_text() == text
                and self.record.state.get("loaded") == digest):
            return  # loaded already, tables and all: nothing to switch
        before, before_odo, before_at, before_c = None, None, None, None
        if base is not None and self.record.state.get("phase") == base["phase"]:
            last = self.record.state.get("last_refs")  # read since the last moves: the same state
            if not (last and last["phase"] == base["phase"]):
                await self.drift.measure_refs()
                last = self.record.state["last_refs"]
            before, before_odo = last["refs"], last.get("odometer_mm")
            before_at, before_c = last.get("at_s"), last.get("temperature_c")
        atomic_write_text(self.s.config_path, text)
        await self.reload_fn()
        self.record.state["phase"] = phase
        self.record.state["loaded"] = digest
        if self.drift.off():  # no references read (the channels checked): no drift known
            await self.drift.measure_refs()
            self.record.save()
            return
        after = await self.drift.measure_refs()
        drift = {a: [0.0, 0.0] for a in self.s.axes}
        if base is not None:
            if before is None:  # the chain broke (an abort restored your config): the last
                drift = self.record.state.get("drift_last", drift)  # known drift carries on
                note = f"drift references re-linked when {phase} was loaded after an interruption"
                # (rotary: none)
                if self.axes.ref_axes():
                    self.record.note(note)
            else:
                drift = {a: [before[a][k] - base["refs"][a][k] for k in (0, 1)]
                         for a in self.s.axes}  # fmt: skip
        cfg = load_config(self.s.config_path)
        chain = build_chain(cfg, self.record.config_dir)
        commands = self.drift.ref_commands(cfg, chain)
        old_commands = self.record.state.get("ref_commands") or {}
        # where the new commands put each axis at its references, by the loaded tables' own
        # error model (an axis without tables: the commands' difference); a state saved
        # before the commands were kept: the commands' difference
        moved = {a: adaptive.reading_moved_mm(chain, a, old_commands[a]["commands_mm"],
                                              now["commands_mm"])
                 for a, now in commands.items()
                 if "commands_mm" in (old_commands.get(a) or {})}  # fmt: skip
        new_base = adaptive.relinked_base(
            None if base is None or before is None else base["refs"], after, drift,
            old_commands, commands, self.record.state.get("start_temperature_c"),
            moved)  # fmt: skip
        # at every switch too, with the odometer and clock of the reading that gave the
        # drift (a warm-up is its own stretch), as read under the config before it
        if base is None or before is not None:
            self.drift.log_drift(drift, before_odo, before_at, before_c)
        self.record.state["ref_commands"] = commands
        self.record.state["drift_base"] = {"phase": phase, "refs": new_base}
        self.record.state["drift_last"] = drift
        self.record.save()

    def _digest(self, text: str) -> str:
        """What the gateway loads: the config text and every table file it names (a
        refinement rewrites a table under the same name: the gateway must reload it)."""
        h = hashlib.sha256(text.encode())
        for path in sorted((self.record.dir / "tables").glob("*.*")):
            h.update(path.name.encode() + b"\0" + path.read_bytes())
        return h.hexdigest()

    async def restore(self, failed: BaseException | None = None) -> str:
        """Put the user's own config back and have the gateway load it; says what happened
        (``failed``: what stopped the commissioning, not said twice)."""
        if not self.record.original_path.exists():
            return "the gateway's config file was not changed"
        shutil.copyfile(self.record.original_path, self.s.config_path)
        self.record.state["phase"] = "original"
        self.record.save()
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

    def _linkage_copy(self, axis: str) -> str | None:
        """The swing axis's linkage file commissioning fits (a copy of yours, made once under
        DIR/tables: yours keeps the drawing's values), relative to the config; None without
        one."""
        original = self.original()
        name = ((original["axes"][axis].get("compensation") or {}).get("linkage"))
        if not name:
            return None
        copy = self.record.dir / "tables" / f"{axis.lower()}_linkage.yaml"
        if not copy.exists():
            source = Path(name) if Path(name).is_absolute() else self.record.config_dir / name
            read_yaml(source, TableError)  # a missing or broken file: a clear error
            copy.parent.mkdir(parents=True, exist_ok=True)
            shutil.copyfile(source, copy)
        return self.record.rel(copy)

    def phase_config(self, phase: str) -> dict[str, Any]:
        """The config of ``phase`` ("identification", "warmup", "pitch", "full"); rotary
        axes: no linkage while identifying, then the table with its chosen interpolation
        and the linkage commissioning fitted."""
        data = self._linear_phase(phase)
        for axis in self.s.axes:
            if not self.axes.rotary(axis):
                continue
            comp = data["axes"][axis]["compensation"]
            if phase in ("identification", "warmup"):
                comp.pop("linkage", None)
                continue
            if isinstance(comp.get("pitch"), dict):
                info = self.record.state.get("rotary", {}).get(axis, {})
                comp["pitch"]["interpolation"] = info.get("interpolation", "linear")
            link = self._linkage_copy(axis)
            if link is None:
                comp.pop("linkage", None)
            else:
                comp["linkage"] = link
        return data

    def before_load(self, phase: str) -> None:
        """The plane re-expressed against the tables it is about to run with, where it is
        faded and they changed since it was fitted (:mod:`..fitting.plane_frame`)."""
        if phase == "full":
            reframe_plane(self.staged("full")[0], self.record.config_dir)

