"""What the command line gives a commissioning, and how one stops early."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ..measuring.machine import MotionSettings
from ..measuring.session import Instruments


class BudgetSpent(Exception):
    """The next step does not fit in the machine-time budget."""

class CommissionAborted(Exception):
    """Commissioning stopped; the message says where the gateway was left."""


#: stroking time (s) of the zone warm-up a short budget holds (:meth:`.identify.
#: IdentifySteps._hold_warm_ups`): at 1.5 x a plain calibration's time one of them fits
#: after the midpoints, with its places read cold and warm
SHORT_WARMUP_S = 480.0
#: the plane's random points of the verdict, each read from both sides (``--plane-points``):
#: as many as a customer's acceptance reads. A maximum over 16 fell short of one over 40 on
#: rough screws (rough-0: 0.86 µm as read at 16, 1.45-1.64 at four draws of 40, cold)
VERDICT_XY_POINTS = 40


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
    plane_points: int = VERDICT_XY_POINTS
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
    #: an axis with no thermal sensor gets a zone warm-up read by the laser (heat from motion)
    heat_warmup: bool = True
    #: ``--finish``: no step begins but the after-run (:meth:`.steps.StepRunner.step`)
    finish: bool = False
    grid: tuple[int, int] = (7, 5)
    tolerance_arcsec: float = 3.0  # rotary axes: ISO 230-2 E between the points
