"""A swing axis driven through a rocking-block linkage (seed 003): its kinematic stage.

The head tilts about pivot A. A ball screw, pivoted in a rocking block at N (``base_mm``
from A), drives the nut's joint M on the head's arm (``arm_mm`` from A); the screw axis
passes ``offset_mm`` beside the block's pivot. With the angle MAN = ``phi0_deg`` + θ (θ the
head's angle) the nut sits along the screw at

    S(θ) = √(arm² + base² − 2·arm·base·cos(phi0 + θ) − offset²)     (law of cosines)

The control maps pulses linearly to degrees: a command of c degrees puts the nut at
S(``zero_deg``) + ``mm_per_deg``·c, so the head reaches

    θ(c) = acos((arm² + base² − offset² − s²) / (2·arm·base)) − phi0,
    s = S(zero_deg) + mm_per_deg·c

and the command that puts it at θ is c = (S(θ) − S(zero_deg)) / mm_per_deg. Both are closed
forms, so the stage is exact both ways like every other stage: ``forward`` (target angle →
command) and ``inverse`` (command → actual angle). The parameters come from the drawing and
are refined by a least-squares fit to measured angles
(:mod:`gateway.calibration.fitting.linkage_fit`); the pitch table before this stage in the
chain holds what the kinematics leave.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields, replace

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .errors import TableError

#: Names of the model's parameters, in file order.
PARAMETERS = ("arm_mm", "base_mm", "offset_mm", "phi0_deg", "mm_per_deg", "zero_deg")
#: samples per degree when the stage checks its span and measures its largest correction
_CHECK_PER_DEG = 20


@dataclass(frozen=True)
class LinkageModel:
    """Geometry of the rocking block and the control's linear scale (mm, degrees)."""

    arm_mm: float
    base_mm: float
    phi0_deg: float
    mm_per_deg: float
    offset_mm: float = 0.0
    zero_deg: float = 0.0
    source: str = "<linkage>"

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            if f.name != "source" and not (isinstance(value, float | int)
                                           and math.isfinite(value)):  # fmt: skip
                raise TableError(f"{self.source}: {f.name} {value!r} is not a finite number")
        if not (self.arm_mm > 0 and self.base_mm > 0 and self.mm_per_deg > 0):
            raise TableError(f"{self.source}: arm_mm, base_mm and mm_per_deg must be > 0 (the "
                             "angle rises with the command)")
        if not 0 <= self.offset_mm < abs(self.base_mm - self.arm_mm):
            raise TableError(f"{self.source}: offset_mm {self.offset_mm:g} must be >= 0 and "
                             f"below |base_mm - arm_mm| ({abs(self.base_mm - self.arm_mm):g})")
        if not 0 < self.phi0_deg + self.zero_deg < 180:
            raise TableError(f"{self.source}: phi0_deg + zero_deg must lie in 0..180 deg")

    def with_values(self, **values: float) -> LinkageModel:
        return replace(self, **values)

    def values(self) -> dict[str, float]:
        return {name: float(getattr(self, name)) for name in PARAMETERS}

    # -- closed forms (numpy) -----------------------------------------------------------
    def nut_mm(self, angle_deg: ArrayLike) -> NDArray[np.float64]:
        """S(θ): the nut's distance along the screw with the head at ``angle_deg``."""
        a, b, e = self.arm_mm, self.base_mm, self.offset_mm
        man = np.radians(self.phi0_deg + np.asarray(angle_deg, dtype=np.float64))
        return np.sqrt(a * a + b * b - e * e - 2.0 * a * b * np.cos(man))

    def angle_deg(self, nut_mm: ArrayLike) -> NDArray[np.float64]:
        """θ for the nut at ``nut_mm`` (NaN where the triangle cannot close)."""
        a, b, e = self.arm_mm, self.base_mm, self.offset_mm
        s = np.asarray(nut_mm, dtype=np.float64)
        cos_man = (a * a + b * b - e * e - s * s) / (2.0 * a * b)
        with np.errstate(invalid="ignore"):
            return np.degrees(np.arccos(cos_man)) - self.phi0_deg

    def zero_nut_mm(self) -> float:
        return float(self.nut_mm(self.zero_deg))

    def actual_deg(self, command_deg: ArrayLike) -> NDArray[np.float64]:
        """Where the head is for a command of ``command_deg`` (the control's degrees)."""
        c = np.asarray(command_deg, dtype=np.float64)
        return self.angle_deg(self.zero_nut_mm() + self.mm_per_deg * c)

    def command_deg(self, angle_deg: ArrayLike) -> NDArray[np.float64]:
        """The command that puts the head at ``angle_deg``."""
        return (self.nut_mm(angle_deg) - self.zero_nut_mm()) / self.mm_per_deg


@dataclass(frozen=True, eq=False)
class LinkageStage:
    """The linkage as a chain stage over ``span_deg`` (the axis travel); checked at build:
    the triangle closes and the angle rises with the command over the span and a margin."""

    model: LinkageModel
    span_deg: tuple[float, float]
    margin_deg: float = 1.0
    _zero_mm: float = field(init=False, repr=False)
    _max_correction: float = field(init=False, repr=False)

    def __post_init__(self) -> None:
        m = self.model
        lo, hi = self.span_deg[0] - self.margin_deg, self.span_deg[1] + self.margin_deg
        theta = np.linspace(lo, hi, max(3, int((hi - lo) * _CHECK_PER_DEG) + 1))
        man = m.phi0_deg + theta
        if man.min() <= 0 or man.max() >= 180:
            raise TableError(f"{m.source}: the angle MAN leaves 0..180 deg within the travel "
                             f"{self.span_deg[0]:g}..{self.span_deg[1]:g} deg (check phi0_deg)")
        cmd = m.command_deg(theta)
        if not np.all(np.isfinite(cmd)) or not np.all(np.diff(cmd) > 0):
            raise TableError(f"{m.source}: the screw does not move steadily over the travel "
                             f"{self.span_deg[0]:g}..{self.span_deg[1]:g} deg")
        object.__setattr__(self, "_zero_mm", m.zero_nut_mm())
        object.__setattr__(self, "_max_correction", float(np.abs(cmd - theta).max()))

    # -- stage interface ----------------------------------------------------------------
    def forward(self, target_deg: ArrayLike) -> NDArray[np.float64]:
        """Command (deg) that puts the head at ``target_deg``."""
        return self.model.command_deg(target_deg)

    def inverse(self, command_deg: ArrayLike) -> NDArray[np.float64]:
        """Where the head is (deg) for ``command_deg``."""
        return self.model.actual_deg(command_deg)

    def forward_scalar(self, target_deg: float) -> float:
        m = self.model
        a, b, e = m.arm_mm, m.base_mm, m.offset_mm
        s = math.sqrt(a * a + b * b - e * e
                      - 2.0 * a * b * math.cos(math.radians(m.phi0_deg + target_deg)))
        return (s - self._zero_mm) / m.mm_per_deg

    def inverse_scalar(self, command_deg: float) -> float:
        m = self.model
        a, b, e = m.arm_mm, m.base_mm, m.offset_mm
        s = self._zero_mm + m.mm_per_deg * command_deg
        cos_man = (a * a + b * b - e * e - s * s) / (2.0 * a * b)
        return math.degrees(math.acos(max(-1.0, min(1.0, cos_man)))) - m.phi0_deg

    def max_abs_correction_mm(self) -> float:
        """Largest |command − target| over the span (deg)."""
        return self._max_correction
