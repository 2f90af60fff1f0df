"""The compensation chain: nominal pulses → corrected command pulses, and back.

Stages, from the upper computer's nominal side to the drive:

``planar`` (XY pair) → ``backlash`` → ``pitch`` → ``linkage`` (a swing axis's kinematics) →
``cyclic`` → ``thermal`` → round to whole pulses.

Each stage has a ``forward`` (target → command) and an exact ``inverse`` (command → where the
axis actually is), like Klipper's move transforms; the chain composes them and rounds once,
at the end. Every method has a vectorised form over numpy arrays and a scalar twin for the
per-transaction path; both evaluate the same precomputed breakpoints.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .backlash import BacklashStage
from .cyclic import CyclicStage
from .direction import MotionState
from .errors import CompensationError, CorrectionLimitError, TableError, TravelError
from .linkage import LinkageStage
from .pitch import PitchStage
from .planar import PlanarStage
from .takeup import TakeUpCurve
from .thermal import ThermalStage

#: The planar command iteration stops when the actual position is within this many pulses.
ITERATION_TOLERANCE_PULSES = 0.01


#: how far past a travel end a target computed from pulses may land by float rounding (mm)
TRAVEL_SLACK_MM = 1e-6

class AxisInput(NamedTuple):
    """One axis's position (pulses), direction of motion (+1/−1; between: the nut's
    engagement part way across its play, :mod:`.takeup`) and screw growth Δa (mm)."""

    pulses: float
    direction: float = 1
    delta_a_mm: float = 0.0


def round_pulses(value: float) -> int:
    """Round half away from zero, the same for every platform and numpy version."""
    return math.floor(value + 0.5) if value >= 0 else -math.floor(-value + 0.5)


def round_pulses_array(values: ArrayLike) -> NDArray[np.int64]:
    v = np.asarray(values, dtype=np.float64)
    return (np.sign(v) * np.floor(np.abs(v) + 0.5)).astype(np.int64)


@dataclass(frozen=True, eq=False)
class AxisChain:
    """The per-axis stages of one axis, with its pulse equivalent and limits.

    ``pulse_mm`` is C (mm, or degrees for rotary axes, per pulse). ``travel_mm`` bounds the
    nominal target; ``max_correction_mm`` bounds |command − nominal| for any single command.
    """

    name: str
    pulse_mm: float
    pitch: PitchStage | None = None
    backlash: BacklashStage | None = None
    thermal: ThermalStage | None = None
    rotary: bool = False
    cyclic: CyclicStage | None = None
    travel_mm: tuple[float, float] | None = None
    max_correction_mm: float = math.inf
    allow_backlash_with_bidirectional: bool = False
    linkage: LinkageStage | None = None
    #: how a reversal takes the lost motion up (None: at once, the classic switch)
    takeup: TakeUpCurve | None = None

    def __post_init__(self) -> None:
        if not (math.isfinite(self.pulse_mm) and self.pulse_mm > 0):
            raise CompensationError(f"axes.{self.name}.pulse_mm: {self.pulse_mm!r} must be > 0")
        if (
            self.pitch is not None
            and self.pitch.bidirectional
            and self.backlash is not None
            and self.backlash.backlash_mm > 0
            and not self.allow_backlash_with_bidirectional
        ):
            raise CompensationError(
                f"axes.{self.name}.compensation: a bidirectional pitch table already contains "
                f"backlash; backlash_mm must be 0 (or set allow_backlash_with_bidirectional)"
            )
        lost = (self.backlash is not None and self.backlash.backlash_mm > 0) or (
            self.pitch is not None and self.pitch.bidirectional)
        if self.takeup is not None and not lost:
            raise CompensationError(
                f"axes.{self.name}.compensation.takeup: there is no lost motion to take up "
                "(no backlash_mm and no bidirectional pitch table)")
        if self.linkage is not None and not self.rotary:
            raise CompensationError(f"axes.{self.name}: a linkage needs a rotary (swing) axis")
        if self.rotary and self.thermal is not None:
            raise CompensationError(f"axes.{self.name}: thermal correction needs a linear axis")
        if self.pitch is not None and self.pitch.table.rotary != self.rotary:
            raise CompensationError(
                f"axes.{self.name}: pitch table {self.pitch.table.source} is "
                f"{'rotary' if self.pitch.table.rotary else 'linear'} but the axis is not"
            )

    def approach(self, motion: MotionState, target_pulses: int) -> MotionState:
        """The axis's motion state after a move to ``target_pulses`` (nominal)."""
        return motion.approach(target_pulses, self.takeup, self.pulse_mm)

    def turned(self, motion: MotionState, target_pulses: int, direction: int,
               moved_mm: float) -> MotionState:  # fmt: skip
        """The motion state after the motor moved ``moved_mm`` in ``direction`` to reach
        nominal ``target_pulses`` (:meth:`MotionState.turned`)."""
        return motion.turned(direction, target_pulses, moved_mm, self.takeup)

    # -- vectorised ---------------------------------------------------------------------
    def command_mm(
        self, target_mm: ArrayLike, direction: ArrayLike, delta_a_mm: float = 0.0
    ) -> NDArray[np.float64]:
        """Drive command (mm, cold-screw scale) that lands on ``target_mm``."""
        x = np.asarray(target_mm, dtype=np.float64)
        if self.backlash is not None:
            x = self.backlash.forward(x, direction)
        if self.pitch is not None:
            x = self.pitch.forward(x, direction)
        if self.linkage is not None:
            x = self.linkage.forward(x)
        if self.cyclic is not None:
            x = self.cyclic.forward(x)
        if self.thermal is not None:
            x = self.thermal.forward(x, delta_a_mm)
        return x

    def actual_mm(
        self, command_mm: ArrayLike, direction: ArrayLike, delta_a_mm: float = 0.0
    ) -> NDArray[np.float64]:
        """Where the axis is (mm) after the drive reached ``command_mm``."""
        x = np.asarray(command_mm, dtype=np.float64)
        if self.thermal is not None:
            x = self.thermal.inverse(x, delta_a_mm)
        if self.cyclic is not None:
            x = self.cyclic.inverse(x)
        if self.linkage is not None:
            x = self.linkage.inverse(x)
        if self.pitch is not None:
            x = self.pitch.inverse(x, direction)
        if self.backlash is not None:
            x = self.backlash.inverse(x, direction)
        return x

    # -- scalar twins -------------------------------------------------------------------
    def command_mm_scalar(self, target_mm: float, direction: float, delta_a_mm: float) -> float:
        x = target_mm
        if self.backlash is not None:
            x = self.backlash.forward_scalar(x, direction)
        if self.pitch is not None:
            x = self.pitch.forward_scalar(x, direction)
        if self.linkage is not None:
            x = self.linkage.forward_scalar(x)
        if self.cyclic is not None:
            x = self.cyclic.forward_scalar(x)
        if self.thermal is not None:
            x = self.thermal.forward_scalar(x, delta_a_mm)
        return x

    def actual_mm_scalar(self, command_mm: float, direction: float, delta_a_mm: float) -> float:
        x = command_mm
        if self.thermal is not None:
            x = self.thermal.inverse_scalar(x, delta_a_mm)
        if self.cyclic is not None:
            x = self.cyclic.inverse_scalar(x)
        if self.linkage is not None:
            x = self.linkage.inverse_scalar(x)
        if self.pitch is not None:
            x = self.pitch.inverse_scalar(x, direction)
        if self.backlash is not None:
            x = self.backlash.inverse_scalar(x, direction)
        return x

    def check_travel(self, nominal_mm: float) -> None:
        if self.travel_mm is None:
            return
        lo, hi = self.travel_mm
        # a target on the travel's end, in pulses × pulse_mm, may land a rounding past it
        # (55800 × 0.001 = 55.800000000000004): 1 nm of slack, far below any pulse
        if not (lo - TRAVEL_SLACK_MM <= nominal_mm <= hi + TRAVEL_SLACK_MM):
            raise TravelError(
                f"axis {self.name}: target {nominal_mm:g} mm is outside travel_mm [{lo:g}, {hi:g}]"
            )

    def check_correction(self, nominal_mm: float, command_mm: float) -> None:
        correction = command_mm - nominal_mm
        if abs(correction) > self.max_correction_mm:
            raise CorrectionLimitError(
                f"axis {self.name}: correction {correction * 1000:.1f} µm at {nominal_mm:g} mm "
                f"exceeds max_correction_mm {self.max_correction_mm:g}"
            )


@dataclass(frozen=True, eq=False)
class Chain:
    """All axes of a machine, and the optional planar stage coupling two of them."""

    axes: Mapping[str, AxisChain]
    planar: PlanarStage | None = None
    #: planar iteration tolerance (mm): ITERATION_TOLERANCE_PULSES of the finer planar axis
    planar_tolerance_mm: float = field(init=False, default=0.0)

    def __post_init__(self) -> None:
        if self.planar is not None:
            for name in self.planar.axes:
                if name not in self.axes:
                    raise CompensationError(f"planar.axes: {name!r} is not a configured axis")
                if self.axes[name].rotary:
                    raise CompensationError(f"planar.axes: {name!r} is rotary")
            finest = min(self.axes[n].pulse_mm for n in self.planar.axes)
            object.__setattr__(self, "planar_tolerance_mm", ITERATION_TOLERANCE_PULSES * finest)

    def partner(self, axis: str) -> str | None:
        """The other axis of the planar pair, or None."""
        if self.planar is None or axis not in self.planar.axes:
            return None
        a, b = self.planar.axes
        return b if axis == a else a

    # -- scalar (per transaction) -------------------------------------------------------
    def command_pulses(
        self, axis: str, inputs: Mapping[str, AxisInput], units_per_pulse: int = 1
    ) -> int:
        """Corrected command for ``axis`` in whole drive units (``units_per_pulse`` per
        pulse: a drive geared finer than the master's pulse); the planar partner is read
        from ``inputs`` (its latest nominal target). Raises TravelError /
        CorrectionLimitError."""
        chain = self.axes[axis]
        own = inputs[axis]
        nominal_mm = own.pulses * chain.pulse_mm
        chain.check_travel(nominal_mm)
        target_mm = nominal_mm
        partner = self.partner(axis)
        if partner is not None and partner in inputs:
            assert self.planar is not None
            other_mm = inputs[partner].pulses * self.axes[partner].pulse_mm
            first = axis == self.planar.axes[0]
            xy = (nominal_mm, other_mm) if first else (other_mm, nominal_mm)
            cxy = self.planar.forward_scalar(xy[0], xy[1], self.planar_tolerance_mm)
            target_mm = cxy[0] if first else cxy[1]
        command_mm = chain.command_mm_scalar(target_mm, own.direction, own.delta_a_mm)
        chain.check_correction(nominal_mm, command_mm)
        return round_pulses(command_mm / chain.pulse_mm * units_per_pulse)

    def nominal_pulses(self, axis: str, inputs: Mapping[str, AxisInput]) -> float:
        """Nominal position (pulses, unrounded) of ``axis`` whose drive is at
        ``inputs[axis].pulses`` command pulses; the partner's command position is used for
        the planar term when given."""
        chain = self.axes[axis]
        own = inputs[axis]
        actual_mm = chain.actual_mm_scalar(
            own.pulses * chain.pulse_mm, own.direction, own.delta_a_mm
        )
        partner = self.partner(axis)
        if partner is not None and partner in inputs:
            assert self.planar is not None
            p = inputs[partner]
            pc = self.axes[partner]
            other_mm = pc.actual_mm_scalar(p.pulses * pc.pulse_mm, p.direction, p.delta_a_mm)
            first = axis == self.planar.axes[0]
            xy = (actual_mm, other_mm) if first else (other_mm, actual_mm)
            pxy = self.planar.inverse_scalar(xy[0], xy[1])
            actual_mm = pxy[0] if first else pxy[1]
        return actual_mm / chain.pulse_mm

    # -- vectorised (batches, calibration, safety checks) -------------------------------
    def command_pulses_batch(
        self,
        nominal_pulses: Mapping[str, ArrayLike],
        direction: Mapping[str, ArrayLike] | None = None,
        delta_a_mm: Mapping[str, float] | None = None,
    ) -> dict[str, NDArray[np.int64]]:
        """Corrected commands (whole pulses) for every axis given, element-wise."""
        return {
            name: round_pulses_array(mm / self.axes[name].pulse_mm)
            for name, mm in self.command_mm_batch(nominal_pulses, direction, delta_a_mm).items()
        }

    def command_mm_batch(
        self,
        nominal_pulses: Mapping[str, ArrayLike],
        direction: Mapping[str, ArrayLike] | None = None,
        delta_a_mm: Mapping[str, float] | None = None,
    ) -> dict[str, NDArray[np.float64]]:
        """Unrounded corrected commands (mm) for every axis given."""
        direction = direction or {}
        delta_a_mm = delta_a_mm or {}
        target = {
            name: np.asarray(n, dtype=np.float64) * self.axes[name].pulse_mm
            for name, n in nominal_pulses.items()
        }
        if self.planar is not None and all(a in target for a in self.planar.axes):
            a, b = self.planar.axes
            xy = np.stack(np.broadcast_arrays(target[a], target[b]), axis=-1)
            cxy = self.planar.forward(xy, self.planar_tolerance_mm)
            target[a], target[b] = cxy[..., 0], cxy[..., 1]
        return {
            name: self.axes[name].command_mm(
                t, direction.get(name, 1), delta_a_mm.get(name, 0.0)
            )
            for name, t in target.items()
        }

    def nominal_pulses_batch(
        self,
        command_pulses: Mapping[str, ArrayLike],
        direction: Mapping[str, ArrayLike] | None = None,
        delta_a_mm: Mapping[str, float] | None = None,
    ) -> dict[str, NDArray[np.float64]]:
        """Nominal positions (unrounded pulses) for the given drive positions."""
        direction = direction or {}
        delta_a_mm = delta_a_mm or {}
        actual = {
            name: self.axes[name].actual_mm(
                np.asarray(c, dtype=np.float64) * self.axes[name].pulse_mm,
                direction.get(name, 1),
                delta_a_mm.get(name, 0.0),
            )
            for name, c in command_pulses.items()
        }
        if self.planar is not None and all(a in actual for a in self.planar.axes):
            a, b = self.planar.axes
            pxy = self.planar.inverse(np.stack(np.broadcast_arrays(actual[a], actual[b]), axis=-1))
            actual[a], actual[b] = pxy[..., 0], pxy[..., 1]
        return {name: mm / self.axes[name].pulse_mm for name, mm in actual.items()}

    def check_limits(self, samples: int = 2049) -> None:
        """Refuse a chain whose correction exceeds any axis's cap anywhere in its travel.

        Samples every axis's travel in both directions (Δa = 0) and, for the planar pair,
        the whole travel rectangle. Raises TableError naming the axis and position.
        """
        grids: dict[str, NDArray[np.float64]] = {}
        for name, chain in self.axes.items():
            if chain.travel_mm is None:
                continue
            lo, hi = chain.travel_mm
            grids[name] = np.linspace(lo, hi, samples)
        pair = self.planar.axes if self.planar is not None else ()
        if pair and all(a in grids for a in pair):
            gx = np.linspace(*self.axes[pair[0]].travel_mm, 129)  # type: ignore[misc]
            gy = np.linspace(*self.axes[pair[1]].travel_mm, 129)  # type: ignore[misc]
            mx, my = np.meshgrid(gx, gy)
            self._check_samples({pair[0]: mx.ravel(), pair[1]: my.ravel()})
        for name, grid in grids.items():
            if name in pair and all(a in grids for a in pair):
                continue
            self._check_samples({name: grid})

    def _check_samples(self, nominal_mm: Mapping[str, NDArray[np.float64]]) -> None:
        for direction in (1, -1):
            pulses = {n: v / self.axes[n].pulse_mm for n, v in nominal_mm.items()}
            cmd = self.command_mm_batch(pulses, {n: direction for n in nominal_mm})
            for name, values in cmd.items():
                chain = self.axes[name]
                corr = np.abs(values - nominal_mm[name])
                worst = int(np.argmax(corr))
                if corr[worst] > chain.max_correction_mm:
                    where = ", ".join(f"{n}={v[worst]:g}" for n, v in nominal_mm.items())
                    raise TableError(
                        f"axes.{name}.compensation: correction {corr[worst] * 1000:.1f} µm at "
                        f"{where} mm (direction {'+' if direction > 0 else '-'}) exceeds "
                        f"max_correction_mm {chain.max_correction_mm:g}"
                    )
