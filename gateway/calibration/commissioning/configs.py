"""The configs ``compgw commission`` makes the gateway run, as pure dict transforms of the
user's config: *identification* (no pitch, backlash, cyclic or planar stage; thermal kept,
with the fitted length once known, or heat from motion once fitted on an axis without
one), *pitch* (the axes' tables and cyclic terms, no planar model: what the XY grid is
measured with) and *full* (everything: the final config).

Only sections the gateway can reload change (``axes.*.compensation`` and ``planar``);
everything else is the user's, untouched. Table paths are relative to the config file.
"""

from __future__ import annotations

import copy
import hashlib
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ...config import COMMISSION_WRITTEN as WRITTEN

#: the first line of every config commissioning writes over the user's (gateway.config
#: recognises it: ``compgw check`` warns of one left behind)
HEADER = WRITTEN + " ({phase} config): your own config is kept in {original}\n"


def own_config_path(config_path: Path, original_path: Path) -> Path:
    """The user's own config: the file the gateway runs, or, where commissioning wrote over
    it (a run carried on, a resume mid-run), the copy of theirs it kept before it began.
    What the user set (a thermal sensor, none) decides what commissioning does, not the
    tables a run before left: a carried-on run took the heat-from-motion model the first
    left for the user's own thermal setting and stopped taking the drift off its readings
    (random machine 7's tighter rerun: Y E 0.69 → 2.28 µm)."""
    try:
        written = config_path.read_text().startswith(WRITTEN)
    except (OSError, UnicodeDecodeError):
        return config_path
    return original_path if written and original_path.exists() else config_path


@dataclass
class Tables:
    """What commissioning has fitted so far (paths relative to the config file)."""

    pitch: dict[str, str] = field(default_factory=dict)  # axis → table CSV
    cyclic: dict[str, str] = field(default_factory=dict)  # axis → cyclic YAML
    thermal_length_mm: dict[str, float] = field(default_factory=dict)
    thermal_gain: dict[str, float] = field(default_factory=dict)  # temperature sources
    #: axes with no sensor: heat from motion (their thermal section, heat_fit)
    motion: dict[str, dict[str, Any]] = field(default_factory=dict)
    planar_model: str | None = None
    planar_axes: tuple[str, str] | None = None
    #: Δa axes after a zone warm-up: their thermal.profile, None for the linear spread
    thermal_profile: dict[str, dict[str, float] | None] = field(default_factory=dict)
    #: temperature axes whose zone warm-up their own motion explained better: their
    #: thermal section (heat from motion) from the tables' configs on
    thermal_motion: dict[str, dict[str, Any]] = field(default_factory=dict)
    #: temperature axes measured without their sensor until the after-run: heat from motion
    #: spread where it travelled replaces it, and their drift follows that shape
    sensor_off: list[str] = field(default_factory=list)
    #: axes whose lost motion is taken up over a reversal: their compensation.takeup
    takeup: dict[str, dict[str, list[float]]] = field(default_factory=dict)
    #: linear axes whose table is interpolated other than straight (leave-one-out chose it)
    interpolation: dict[str, str] = field(default_factory=dict)

    def to_json(self) -> dict[str, Any]:
        return {"pitch": self.pitch, "cyclic": self.cyclic,
                "thermal_length_mm": self.thermal_length_mm,
                "thermal_gain": self.thermal_gain, "motion": self.motion,
                "planar_model": self.planar_model,
                "planar_axes": list(self.planar_axes) if self.planar_axes else None,
                "thermal_profile": self.thermal_profile,
                "thermal_motion": self.thermal_motion, "sensor_off": self.sensor_off,
                "takeup": self.takeup, "interpolation": self.interpolation}  # fmt: skip

    def digest(self, name: str, config_dir: Path) -> str:
        """What corrects axis ``name`` (``"XY"``: the plane), files' contents included: a
        carried-on run tells a table it changed from one it left as it was."""
        if name == "XY":
            parts: list[Any] = [self.planar_model, self.planar_axes]
            files = [self.planar_model]
        else:
            parts = [self.pitch.get(name), self.cyclic.get(name), self.takeup.get(name),
                     self.interpolation.get(name), self.motion.get(name),
                     self.thermal_motion.get(name)]  # fmt: skip
            files = [self.pitch.get(name), self.cyclic.get(name)]
        for f in files:
            path = config_dir / f if f else None
            parts.append(hashlib.sha1(path.read_bytes()).hexdigest()
                         if path is not None and path.is_file() else None)  # fmt: skip
        return hashlib.sha1(json.dumps(parts, sort_keys=True, default=str).encode()).hexdigest()

    @classmethod
    def from_json(cls, data: dict[str, Any]) -> Tables:
        axes = data.get("planar_axes")
        return cls(dict(data.get("pitch", {})), dict(data.get("cyclic", {})),
                   {k: float(v) for k, v in data.get("thermal_length_mm", {}).items()},
                   {k: float(v) for k, v in data.get("thermal_gain", {}).items()},
                   dict(data.get("motion", {})), data.get("planar_model"),
                   tuple(axes) if axes else None,  # type: ignore[arg-type]
                   dict(data.get("thermal_profile", {})),
                   dict(data.get("thermal_motion", {})),
                   list(data.get("sensor_off", [])),
                   dict(data.get("takeup", {})),
                   dict(data.get("interpolation", {})))  # fmt: skip


def identification(original: dict[str, Any], axes: tuple[str, ...], tables: Tables,
                   profile: bool = False) -> dict[str, Any]:  # fmt: skip
    """The user's config with the commissioned axes' pitch, backlash and cyclic stages and
    the planar model removed; thermal kept (with the fitted length once known). The zone
    warm-up's travel profile only with ``profile`` (the tables' phases): the gateway's
    travel history starts at the reload, after the zone it would have to know about, so
    the identification runs use the linear spread while the zone's heat fades."""
    data = copy.deepcopy(original)
    for name in axes:
        comp = data["axes"][name].setdefault("compensation", {}) or {}
        for key in ("pitch", "backlash_mm", "cyclic", "backlash_table_direction",
                    "allow_backlash_with_bidirectional", "takeup"):  # fmt: skip
            comp.pop(key, None)
        comp["enabled"] = True
        if name in tables.thermal_length_mm and comp.get("thermal"):
            comp["thermal"] = {**comp["thermal"], "length_mm": tables.thermal_length_mm[name]}
        if name in tables.motion and not comp.get("thermal"):
            comp["thermal"] = copy.deepcopy(tables.motion[name])
        if name in tables.thermal_profile and comp.get("thermal"):  # the zone warm-up's
            comp["thermal"] = {**comp["thermal"],
                               "profile": tables.thermal_profile[name] if profile else None}
        if name in tables.thermal_gain and comp.get("thermal"):
            comp["thermal"] = {**comp["thermal"], "gain": round(tables.thermal_gain[name], 4)}
        if name in tables.sensor_off:
            comp.pop("thermal", None)
        data["axes"][name]["compensation"] = comp
    if tables.planar_axes is not None or set(axes) & set((data.get("planar") or {}).get(
            "axes", ())):  # fmt: skip
        data.pop("planar", None)
    return data


def with_tables(original: dict[str, Any], axes: tuple[str, ...], tables: Tables,
                planar: bool, commit_default: str = "immediate") -> dict[str, Any]:
    """Identification plus the fitted tables and cyclic terms; the planar model too when
    ``planar`` (and fitted), committed as the user's planar section says, else
    ``commit_default``."""
    data = identification(original, axes, tables, profile=True)
    for name in axes:
        comp = data["axes"][name]["compensation"]
        if name in tables.thermal_motion:  # in place of a temperature sensor
            comp["thermal"] = copy.deepcopy(tables.thermal_motion[name])
        if name in tables.pitch:
            comp["pitch"] = {"file": tables.pitch[name],
                             "interpolation": tables.interpolation.get(name, "linear")}
            if name in tables.takeup:  # the bidirectional table's lost motion, taken up
                comp["takeup"] = copy.deepcopy(tables.takeup[name])
        if name in tables.cyclic:
            comp["cyclic"] = tables.cyclic[name]
    if planar and tables.planar_model is not None and tables.planar_axes is not None:
        commit = (original.get("planar") or {}).get("commit", commit_default)
        data["planar"] = {"axes": list(tables.planar_axes), "model": tables.planar_model,
                          "commit": commit}  # fmt: skip
    return data
