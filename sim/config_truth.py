"""Config models of the data-driven truth (issue 14): measured tables, screw physics, and
behaviour no table holds. Plain pydantic models, imported by :mod:`sim.config`.

Every model here is optional in the sim config; a machine that uses none of them behaves
exactly as the parametric machine (``pitch``, ``backlash_um``, ``thermal``, ``plane``).
Vocabulary on purpose physical, not the gateway's: a screw's measured *deviation* curves, a
*play* taken up over a *reversal distance*, a *stick band*, *ringing* after a stop, heat
*conducted along the screw*, an XY *error field* sampled at grid nodes.
"""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator

PositiveFloat = Annotated[float, Field(gt=0)]
NonNegFloat = Annotated[float, Field(ge=0)]


class _Model(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class DeviationTable(_Model):
    """Measured deviation (true − commanded, µm) of one axis per approach direction, from CSV.

    ``forward_column``: approached moving +; ``reverse_column`` (optional): approached moving
    − (it then holds the lost motion too). Between rows ``akima`` (a C1 curve through the
    points that does not overshoot between flat stretches) or ``linear``; beyond the first
    and last row the end values hold. Rows with a blank cell are skipped.
    """

    path: str
    position_column: str = "position_mm"
    forward_column: str = "forward_um"
    reverse_column: str | None = None
    scale: float = 1.0
    interpolation: Literal["akima", "linear"] = "akima"


class CurveTable(_Model):
    """A value along the travel from CSV (µm at position mm), e.g. lost motion."""

    path: str
    position_column: str = "position_mm"
    value_column: str = "lost_motion_um"
    scale: float = 1.0


class TakeUp(_Model):
    """How a reversal takes up the play (the reversal distance ``r`` since the last turn).

    ``linear``: the classic dead band; the table stays put while the motor crosses the play,
    then follows (``distance_um`` = the play). ``smooth``: a soft engagement; the table
    starts to follow before the play is crossed and the last part of the play is taken up
    gradually over ``distance_um`` (a short reversal leaves only part of the lost motion).
    ``distance_um`` must be at least 1× (linear) / 2× (smooth) the largest play, so the table
    never moves against the motor; default: exactly that.
    """

    curve: Literal["linear", "smooth"] = "linear"
    distance_um: PositiveFloat | None = None


class LostMotionConfig(_Model):
    """Lost motion on reversal: a constant ``um`` plus a ``table`` along the travel (µm,
    may be negative where a measurement says so), taken up as ``takeup`` says."""

    um: float = 0.0
    table: CurveTable | None = None
    takeup: TakeUp = TakeUp()


class CyclicScrew(_Model):
    """Lead variation within each turn of the screw, from CSV (``path``).

    Columns ``position_mm`` then pairs ``a1_um, phi1_deg, a2_um, phi2_deg, ...`` (any
    number of harmonics): at each listed position the error is
    Σ_k a_k · sin(2πk (x − origin_mm)/lead_mm + φ_k); amplitudes and (unwrapped) phases are
    carried smoothly between the listed positions and held beyond them.
    """

    lead_mm: PositiveFloat
    origin_mm: float = 0.0
    path: str


class StickSlip(_Model):
    """A stop that sticks: with ``probability`` the table stops short of where it would by
    an exponentially distributed amount (mean ``mean_um``) never beyond the stick band
    ``band_um``; always short, i.e. against the direction of the move (heavy on one side)."""

    probability: Annotated[float, Field(ge=0, le=1)]
    mean_um: PositiveFloat
    band_um: PositiveFloat


class Settling(_Model):
    """After each stop the table rings: ``amplitude_um`` · exp(−t/τ) · cos(2πt/period)
    ahead in the direction of the move (negative: it creeps in), t from the moment the
    drive reports in position. ``period_s`` absent: a plain exponential creep."""

    amplitude_um: float
    time_constant_s: PositiveFloat
    period_s: PositiveFloat | None = None


class ScrewHeat(_Model):
    """The screw's temperature along its length: heat from the nut's friction where it
    works, conducted along the steel and lost to the air (1-D heat equation).

    Power at the nut = 2π · ``drag_torque_Nm`` · turns per second (speed / lead); the screw
    spans ``screw_mm`` (default: the travel plus one nut length each side) and is held
    axially at ``fixed_end_mm`` (default: its low end): the table's growth at x is
    α·∫(T − ambient) from the fixed end to x, a Δa sensor at a reads the same integral up
    to a, a temperature sensor reads T where it is.
    """

    alpha_per_K: float = 11.5e-6
    lead_mm: PositiveFloat = 10.0
    drag_torque_Nm: NonNegFloat = 0.1
    diameter_mm: PositiveFloat = 16.0
    nut_length_mm: PositiveFloat = 40.0
    h_W_m2K: PositiveFloat = 15.0
    ambient_C: float = 20.0
    screw_mm: tuple[float, float] | None = None
    fixed_end_mm: float | None = None
    nodes: Annotated[int, Field(ge=11, le=2001)] = 161
    conductivity_W_mK: PositiveFloat = 45.0
    density_kg_m3: PositiveFloat = 7850.0
    heat_capacity_J_kgK: PositiveFloat = 460.0

    @model_validator(mode="after")
    def _screw_order(self) -> ScrewHeat:
        if self.screw_mm is not None and not self.screw_mm[0] < self.screw_mm[1]:
            raise ValueError(f"screw_mm: {list(self.screw_mm)} must be [low end, high end]")
        return self


class PlaneField(_Model):
    """XY error field at the nodes of a rectangular grid, from CSV (µm): every combination
    of the x and y values once. Between nodes a C1 bicubic Hermite surface (slopes from the
    neighbouring nodes); outside the grid the edge values hold."""

    path: str
    x_column: str = "x_mm"
    y_column: str = "y_mm"
    ex_column: str = "ex_um"
    ey_column: str = "ey_um"
    scale: float = 1.0
