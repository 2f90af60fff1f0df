"""Backlash (reversal) compensation by direction of motion.

Convention: ``backlash_mm`` B ≥ 0 is the lost motion of a semi-closed-loop axis: on a
reversal the motor turns B before the table follows. Approaching in + the table lags the
motor, so the motor is sent further in the direction of motion. ``table_direction`` says
which approach the pitch table describes:

- ``mean`` (default; tables measured in both directions and averaged, as LinuxCNC's
  BACKLASH): the command is offset by +B/2 moving +, −B/2 moving −;
- ``forward`` (table measured approaching in +, FANUC style): 0 moving +, −B moving −;
- ``reverse``: +B moving +, 0 moving −.

The direction state after homing comes from config (``home_direction``), because homing
decides which flank of the nut is engaged. A direction between −1 and +1 is a nut part way
across its play (:mod:`.takeup`): the offset is the same straight line in between.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .errors import CompensationError

TableDirection = Literal["mean", "forward", "reverse"]
_REFERENCE = {"mean": 0.0, "forward": 1.0, "reverse": -1.0}


@dataclass(frozen=True)
class BacklashStage:
    """Constant reversal correction: ``command = target + offset(direction)``."""

    backlash_mm: float
    table_direction: TableDirection = "mean"

    def __post_init__(self) -> None:
        if not np.isfinite(self.backlash_mm) or self.backlash_mm < 0:
            raise CompensationError(f"backlash_mm: {self.backlash_mm!r} must be a number >= 0")
        if self.table_direction not in _REFERENCE:
            raise CompensationError(
                f"backlash table_direction: {self.table_direction!r} is not one of "
                f"{', '.join(_REFERENCE)}"
            )

    def offset_mm(self, direction: ArrayLike) -> NDArray[np.float64]:
        """Command offset (mm) for the given direction(s) of motion (+1 or −1)."""
        d = np.clip(np.asarray(direction, dtype=np.float64), -1.0, 1.0)
        return 0.5 * self.backlash_mm * (d - _REFERENCE[self.table_direction])

    def offset_scalar(self, direction: float) -> float:
        d = max(-1.0, min(1.0, float(direction)))
        return 0.5 * self.backlash_mm * (d - _REFERENCE[self.table_direction])

    def forward(self, target_mm: ArrayLike, direction: ArrayLike) -> NDArray[np.float64]:
        return np.asarray(target_mm, dtype=np.float64) + self.offset_mm(direction)

    def inverse(self, command_mm: ArrayLike, direction: ArrayLike) -> NDArray[np.float64]:
        return np.asarray(command_mm, dtype=np.float64) - self.offset_mm(direction)

    def forward_scalar(self, target_mm: float, direction: float) -> float:
        return target_mm + self.offset_scalar(direction)

    def inverse_scalar(self, command_mm: float, direction: float) -> float:
        return command_mm - self.offset_scalar(direction)

    def max_abs_correction_mm(self) -> float:
        return float(max(abs(self.offset_scalar(1)), abs(self.offset_scalar(-1))))
