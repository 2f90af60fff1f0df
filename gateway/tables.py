"""Build the compensation chain a config describes: read its tables, check them, compose.

Everything is validated before anything is used: a config whose tables are malformed, not
monotone, or need corrections above ``max_correction_mm`` anywhere in the travel does not
load, and the error names the file and the point.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import TypeVar

import numpy as np

from .compensation import (
    AxisChain,
    BacklashStage,
    Chain,
    CompensationError,
    CyclicStage,
    LinkageStage,
    PitchStage,
    PitchTable,
    PlanarStage,
    TakeUpCurve,
    ThermalStage,
)
from .config import Axis, ConfigError, GatewayConfig
from .formats import load_planar_model, read_cyclic, read_linkage, read_linuxcnc, read_pitch_csv

#: a turntable's period (deg): its tables and worm term repeat every turn
TURN_DEG = 360.0


T = TypeVar("T")


def _named(key: str, read: Callable[[Path], T], path: Path) -> T:
    """``read(path)``, its error (a missing file, a bad line) named by the config key that
    points at the file, as every config error is."""
    try:
        return read(path)
    except CompensationError as exc:
        text = str(exc)
        if text.startswith(key):
            raise
        raise type(exc)(f"{key}: {text}") from None


def _read_pitch(axis_name: str, axis: Axis, base_dir: Path) -> PitchStage | None:
    spec = axis.compensation.pitch_file
    if spec is None:
        return None
    path = base_dir / spec.file
    table: PitchTable
    key = f"axes.{axis_name}.compensation.pitch.file"
    if spec.format == "csv":
        table = _named(key, read_pitch_csv, path)
    else:  # a LinuxCNC file has no unit: it is in the axis's (mm or degrees)
        table = _named(key, lambda p: read_linuxcnc(p, int(spec.format[-1])), path)
        table = PitchTable(table.position_mm, table.forward_mm, table.reverse_mm,
                           axis.rotary, table.source, table.lines)  # fmt: skip
    if table.rotary != axis.rotary:
        kind = "rotary (position_deg)" if table.rotary else "linear (position_mm)"
        raise CompensationError(
            f"axes.{axis_name}.compensation.pitch: {path} is a {kind} table but the axis is "
            f"{'rotary' if axis.rotary else 'linear'}"
        )
    stage = PitchStage(table, spec.interpolation, spec.outside, spec.taper_mm, axis.wraps)
    stage.check_cap(axis.compensation.max_correction_mm)
    return stage


def build_axis(name: str, axis: Axis, base_dir: Path) -> AxisChain:
    comp = axis.compensation
    backlash = None
    if comp.backlash_mm > 0:
        backlash = BacklashStage(comp.backlash_mm, comp.backlash_table_direction)
    thermal = None
    if comp.thermal is not None:
        thermal = ThermalStage(comp.thermal.length_mm, comp.thermal.origin_mm)
    cyclic = None
    if comp.cyclic is not None:
        period = TURN_DEG if axis.wraps else None
        model = _named(f"axes.{name}.compensation.cyclic", read_cyclic, base_dir / comp.cyclic)
        cyclic = CyclicStage(model, axis.travel_mm, period)
    takeup = None
    if comp.takeup is not None:
        takeup = TakeUpCurve(np.asarray(comp.takeup.reversal_um) / 1000.0, comp.takeup.fraction,
                             f"axes.{name}.compensation.takeup")  # fmt: skip
    linkage = None
    if comp.linkage is not None:
        linkage = LinkageStage(_named(f"axes.{name}.compensation.linkage", read_linkage,
                                      base_dir / comp.linkage), axis.travel_mm)  # fmt: skip
    return AxisChain(
        name,
        axis.pulse_mm,
        cyclic=cyclic,
        pitch=_read_pitch(name, axis, base_dir),
        backlash=backlash,
        thermal=thermal,
        rotary=axis.rotary,
        travel_mm=axis.travel_mm,
        max_correction_mm=comp.max_correction_mm,
        allow_backlash_with_bidirectional=comp.allow_backlash_with_bidirectional,
        linkage=linkage,
        takeup=takeup,
    )


def build_chain(config: GatewayConfig, base_dir: str | Path) -> Chain:
    """The chain for ``config``, table paths relative to ``base_dir``; raises ConfigError."""
    base = Path(base_dir)
    try:
        axes = {name: build_axis(name, axis, base) for name, axis in config.axes.items()}
        planar = None
        if config.planar is not None:
            model_path = base / config.planar.model
            planar = PlanarStage(
                _named("planar.model", load_planar_model, model_path),
                tuple(config.planar.axes), source=str(model_path)
            )
        chain = Chain(axes, planar)
        chain.check_limits()
    except CompensationError as exc:
        raise ConfigError(str(exc)) from None
    return chain
