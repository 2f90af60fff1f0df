"""Load-time checks of the data-driven truth: every file readable, every rule that needs
the data (a take-up distance against the largest play, a heated screw covering the travel).
Errors name the YAML path: ``sim.machine.X.lost_motion.takeup.distance_um: ...``."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

from sim.truth import XYField, load_screw

if TYPE_CHECKING:
    from sim.config import SimSection


def check_truth_data(sim: SimSection, base_dir: str | Path) -> None:
    """Raise ValueError (one line, with the YAML path) if a data file or rule fails."""
    for name, errs in sim.machine.items():
        where = f"sim.machine.{name}"
        lo, hi = sim.axes[name].travel_mm
        if errs.data_driven:
            key = "deviation" if errs.deviation else "lost_motion" if errs.lost_motion else "cyclic"
            try:
                screw = load_screw(errs.deviation, errs.lost_motion, errs.cyclic,
                                   errs.backlash_um, base_dir)  # fmt: skip
            except (OSError, ValueError, KeyError) as err:
                raise ValueError(f"{where}.{key}: {err}") from None
            if errs.backlash_um_per_m:
                raise ValueError(f"{where}.backlash_um_per_m: not with data-driven lost motion "
                                 "(give lost_motion.table)")  # fmt: skip
            takeup = screw.takeup
            if takeup.distance_mm is not None:
                need_mm = takeup.factor * screw.largest_play_mm(lo, hi)
                if takeup.distance_mm < need_mm - 1e-9:
                    raise ValueError(
                        f"{where}.lost_motion.takeup.distance_um: {takeup.distance_mm * 1e3:g} "
                        f"is less than {takeup.factor:g} x the largest play "
                        f"({need_mm * 1e3 / takeup.factor:.2f} um): the table would move "
                        "against the motor")  # fmt: skip
        if errs.heat is not None and errs.heat.screw_mm is not None:
            s0, s1 = errs.heat.screw_mm
            if lo < s0 or hi > s1:
                raise ValueError(f"{where}.heat.screw_mm: {[s0, s1]} does not cover the travel "
                                 f"{[lo, hi]}")  # fmt: skip
    if sim.plane is not None and sim.plane.field is not None:
        try:
            XYField(sim.plane.field, base_dir)
        except (OSError, ValueError, KeyError) as err:
            raise ValueError(f"sim.plane.field: {err}") from None
    temp = sim.instruments.temperature
    if temp is not None:
        channels = temp.channels or (*sim.axes, "ambient")
        for ch in temp.positions_mm:
            if ch not in channels or ch == "ambient":
                raise ValueError(f"sim.instruments.temperature.positions_mm: {ch!r} is not a "
                                 "screw channel")  # fmt: skip
