"""A carried-on run's after-run against the run before's: no figure reads worse than the
run before left it.

At the carry-on the run before's tables (their files and their config), its best tables and
its after-run are kept aside. At the after-run:

- an axis, or the plane, whose tables this run left as they were keeps the run before's
  after-run, not read again: a fresh reading of the same tables is the machine's scatter
  and heat, not the tables (random machine 7's tighter rerun: Y 0.74 → 1.00 µm as read
  on the table the run before left; ``--recheck`` reads them again where that is wanted);
- one this run changed that reads worse as read than the run before's is put back as the
  run before left it, with its reading: a refinement that reads worse is never kept.

The plane is read with both axes' tables: its reading is kept only where its model and
both axes are as the run before left them.
"""

from __future__ import annotations

import copy
import shutil
from pathlib import Path
from typing import TYPE_CHECKING, Any

from .best import copy_aside, put_back_files
from .configs import Tables

if TYPE_CHECKING:
    from .record import Record

#: where the run before's table files are kept (under the commissioning's ``tables/``)
KEEP_DIR = "run_before"
#: what each step of a run's records is kept under in the state
STEP_KEYS = ("steps", "parts", "apart")


class RunBefore:
    """The run before's tables and after-run, for a carried-on run (``state["run_before"]``:
    its after-run's figures as read, µm, and its tables' digests)."""

    def __init__(self, record: Record) -> None:
        self.record = record

    @property
    def _keep(self) -> Path:
        return self.record.dir / "tables" / KEEP_DIR

    @property
    def _kept(self) -> dict[str, Any]:
        return self.record.state.setdefault("run_before_kept", {})

    def keep(self, after_steps: list[str]) -> None:
        """At the carry-on (the tables still the run before's): its tables' files and config,
        its best tables and its after-run steps' records, kept aside; then the after-run
        steps forgotten (their raw files moved to ``raw/superseded/``)."""
        state = self.record.state
        shutil.rmtree(self._keep, ignore_errors=True)
        for name in state.get("run_before") or {}:
            copy_aside(self.record, name, self._keep)
        steps = {}
        for name in after_steps:
            steps[name] = {"records": {k: copy.deepcopy(state.get(k, {})[name])
                                       for k in STEP_KEYS if name in state.get(k, {})},
                           "raw": [str(p) for p in self.record.raw_paths(name)]}  # fmt: skip
            self.record.forget(name, keep_in=self.record.dir / "raw" / "superseded")
        state["put_back"] = []  # what this run puts back (the verdict says so)
        state["run_before_kept"] = {"tables": copy.deepcopy(self.record.tables.to_json()),
                                    "best": copy.deepcopy(state.get("best", {})),
                                    "steps": steps}  # fmt: skip
        self.record.save()

    def _axes_of(self, name: str) -> list[str]:
        """What a name's reading is made with: an axis its own tables; the plane its model
        and both its axes' tables."""
        axes = self.record.tables.planar_axes
        return ["XY", *axes] if name == "XY" and axes else [name]

    def same(self, name: str) -> bool:
        """This run left what ``name``'s reading is made with as the run before left it."""
        return all(self.same_one(n) for n in self._axes_of(name))

    def same_one(self, name: str) -> bool:
        """``name``'s own tables (the plane: its model) as the run before left them."""
        was = (self.record.state.get("run_before") or {}).get(name)
        return was is not None and was["tables"] == self.record.tables.digest(
            name, self.record.config_dir)  # fmt: skip

    def figure_um(self, name: str, key: str = "read") -> float | None:
        """The run before's after-run figure of ``name``, as read (µm): its E (the plane:
        its maximum), or with ``key`` "read_A" an axis's A; None: none."""
        was = ((self.record.state.get("run_before") or {}).get(name) or {}).get(key)
        return None if was is None else float(was)

    def carry(self, step: str, name: str) -> bool:
        """The run before's after-run step ``step`` (of ``name``) made this run's, not read
        again, where its tables are as it left them and its readings were kept; its machine
        time was the run before's (0 here). True when carried."""
        kept = self._kept.get("steps", {}).get(step)
        if kept is None or self.record.done(step) or not self.same(name):
            return False
        superseded = self.record.dir / "raw" / "superseded"
        files = [Path(p) for p in kept["raw"]]
        if not all((superseded / p.name).exists() for p in files):
            return False
        for path in files:
            path.parent.mkdir(parents=True, exist_ok=True)
            (superseded / path.name).replace(path)
        for key, rec in kept["records"].items():
            rec = copy.deepcopy(rec)
            if key == "steps":
                rec.update(machine_s=0.0, carried=True)
            self.record.state.setdefault(key, {})[step] = rec
        self.record.save()
        return True

    def reads_worse(self, name: str, now_um: float, now_a_um: float | None = None) -> bool:
        """This run's after-run reads ``name`` worse as read than the run before's did (to
        the hundredth of a µm printed): its E (the plane: its maximum), or an axis's A
        (``now_a_um``), the acceptance figure. Random machine 7's tighter rerun swept X: E
        1.44 → 1.43 µm, but A 3.73 → 5.32."""
        def worse(now: float | None, was: float | None) -> bool:
            return now is not None and was is not None and round(now, 2) > round(was, 2)

        return (worse(now_um, self.figure_um(name))
                or worse(now_a_um, self.figure_um(name, "read_A")))

    def put_back(self, name: str) -> None:
        """``name``'s tables (the plane: its model) as the run before left them: their
        config, files and best, so a run carried on again starts from them."""
        kept = self._kept
        old = Tables.from_json(kept["tables"])
        now = self.record.tables
        if name == "XY":
            now.planar_model, now.planar_axes = old.planar_model, old.planar_axes
        else:
            for field in ("pitch", "cyclic", "thermal_length_mm", "thermal_gain", "motion",
                          "thermal_profile", "thermal_motion", "takeup", "interpolation"):
                mine, theirs = getattr(now, field), getattr(old, field)
                if name in theirs:
                    mine[name] = copy.deepcopy(theirs[name])
                else:
                    mine.pop(name, None)
        put_back_files(self.record, name, self._keep)
        if name not in self.record.state.setdefault("put_back", []):
            self.record.state["put_back"].append(name)
        best = kept.get("best", {})
        if name in best:
            self.record.state.setdefault("best", {})[name] = copy.deepcopy(best[name])
            copy_aside(self.record, name, self.record.dir / "tables" / "best")
        self.record.save()

    def set_aside(self, step: str) -> None:
        """This run's reading of a step whose tables were put back: kept aside in
        ``raw/put-back/`` (not this run's figure any more)."""
        self.record.forget(step, keep_in=self.record.dir / "raw" / "put-back")
