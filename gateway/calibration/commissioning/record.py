"""What a commissioning has done, kept in ``DIR/commission.json``: what a resume reads."""

from __future__ import annotations

import json
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ...formats import atomic_write_text
from .configs import Tables

if TYPE_CHECKING:
    from ..thermal.drift_shape import SweptHeat

STATE = "commission.json"


class Record:
    """What a commissioning has done, on disk (``DIR/commission.json``): the state, the tables,
    where each screw was worked; what a resume reads."""

    def __init__(self, out_dir: Path, config_dir: Path) -> None:
        self.dir = out_dir
        self.config_dir = config_dir
        self.state_path = out_dir / STATE
        self.original_path = out_dir / "original.yaml"
        self.state: dict[str, Any] = {"version": 1, "steps": {}, "rounds": [], "notes": []}
        if self.state_path.exists():
            self.state = json.loads(self.state_path.read_text())
        self.tables = Tables.from_json(self.state.get("tables", {}))
        #: where each screw has been worked (:class:`.drift.DriftRefs` fills it)
        self.swept: dict[str, SweptHeat] = {}

    def retried(self, count: int) -> None:
        """Count requests answered only on a later try (kept with the next save; the
        summary and the report say how many)."""
        if count:
            self.state["retried"] = self.state.get("retried", 0) + count

    # -- state ---------------------------------------------------------------------------
    def save(self) -> None:
        self.state["tables"] = self.tables.to_json()
        self.state["swept_heat"] = {a: h.to_json() for a, h in self.swept.items()}
        self.dir.mkdir(parents=True, exist_ok=True)
        # compact: json's C encoder (an indent takes the pure-Python one, 10 x slower on the
        # drift log of a long run, and the state is written after every run)
        atomic_write_text(self.state_path, json.dumps(self.state, default=plain_json,
                                                      separators=(",", ":")))  # fmt: skip

    @property
    def used_s(self) -> float:
        steps = sum(step["machine_s"] for step in self.state["steps"].values())
        return float(steps + self.state.get("refs_s", 0.0))

    def rel(self, path: Path) -> str:
        return str(path.resolve().relative_to(self.config_dir)) if path.resolve().is_relative_to(
            self.config_dir) else str(path.resolve())  # fmt: skip

    def raw_path(self, name: str) -> Path:
        """The raw file of a step measured in one run."""
        return self.dir / "raw" / f"{name}.csv"

    def raw_paths(self, name: str) -> list[Path]:
        """The raw files of a step (one per run when its runs were measured apart)."""
        parts = self.state["steps"].get(name, {}).get("parts")
        if not parts:
            return [self.raw_path(name)]
        return [self.config_dir / part["raw"] for part in parts]

    def forget(self, name: str, keep_in: Path | None = None) -> None:
        """Step ``name`` as if never run: its raw files removed (or moved into ``keep_in``)
        and its records dropped; the next step of that name measures it again."""
        for path in self.raw_paths(name):
            if keep_in is not None and path.exists():
                keep_in.mkdir(parents=True, exist_ok=True)
                path.replace(keep_in / path.name)
            else:
                path.unlink(missing_ok=True)
        for key in ("steps", "parts", "apart"):
            self.state.get(key, {}).pop(name, None)
        self.save()

    def done(self, name: str) -> bool:
        return name in self.state["steps"]

    def note(self, text: str, replacing: str = "") -> bool:
        """Keep ``text`` among the notes once (the report and a resume show them), in place
        of any note that begins with ``replacing``; True when it is new (to be said)."""
        notes = self.state["notes"]
        if text in notes:
            return False
        if replacing:
            self.drop_notes(replacing)
        notes.append(text)
        return True

    def drop_notes(self, beginning: str) -> None:
        """Take back the notes that begin with ``beginning`` (what they said no longer holds)."""
        self.state["notes"][:] = [n for n in self.state["notes"] if not n.startswith(beginning)]

    @property
    def tables_phase(self) -> str:
        """The config the fitted tables run in: "full" once the plane is fitted."""
        return "full" if self.tables.planar_model else "pitch"



def plain_json(value: Any) -> Any:
    """numpy scalars (a bool or float from an array) as plain Python for JSON."""
    if hasattr(value, "item"):
        return value.item()
    raise TypeError(f"{type(value).__name__} is not JSON serializable")
