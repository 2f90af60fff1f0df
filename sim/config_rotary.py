"""Config models of the rotary truths (issue 16): a swing axis driven by a ball screw
through a rocking-block linkage (seed 003), a worm-gear turntable, and an angle instrument.
Plain pydantic models, imported by :mod:`sim.config`.

Angles are degrees, screw lengths mm, small errors µm (on the screw) or arcseconds (at the
table). A rotary axis's drive still counts pulses (``axes.NAME.pulse_mm`` is then degrees
per pulse, ``travel_mm`` and ``speed_mm_s`` degrees and degrees per second).
"""

from __future__ import annotations

from typing import Annotated

from pydantic import BaseModel, ConfigDict, Field, model_validator

PositiveFloat = Annotated[float, Field(gt=0)]
NonNegFloat = Annotated[float, Field(ge=0)]


class _Model(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class SwingConfig(_Model):
    """A head tilting about pivot A, moved by a ball screw through a rocking block (seed 003).

    The rocking block pivots at N, fixed at ``base_mm`` from A; the nut's joint M on the
    head's arm is ``arm_mm`` from A; the screw axis passes ``offset_mm`` beside the block's
    pivot. With ∠MAN = ``phi0_deg`` + θ (θ the tilt, 0 = the head horizontal) the nut sits
    s = √(|MN|² − offset²) from the block, |MN|² = arm² + base² − 2·arm·base·cos∠MAN.
    The control maps pulses linearly to degrees: a commanded angle c puts the nut at
    s(0) + ``screw_mm_per_deg``·c (default: the slope of the chord over ``angle_range_deg``,
    the scale a commissioning engineer sets from the two ends; the head is exact at 0 and
    off by the linkage's curvature elsewhere). The screw adds its own
    error along its length (µm: ``slope_um_per_m``, ``poly_um`` over the stroke t = 0..1,
    a once-per-``lead_mm`` term) and a play ``backlash_um``; ``repeatability_arcsec`` is the
    spread of a stop.
    """

    arm_mm: PositiveFloat = 150.0
    base_mm: PositiveFloat = 450.0
    offset_mm: NonNegFloat = 10.0
    phi0_deg: Annotated[float, Field(gt=0, lt=180)] = 74.4
    angle_range_deg: tuple[float, float] = (-14.0, 13.0)
    screw_mm_per_deg: PositiveFloat | None = None
    lead_mm: PositiveFloat = 5.0
    slope_um_per_m: float = 20.0
    poly_um: tuple[float, ...] = (0.0, 3.0, -3.0)
    periodic_um: float = 1.0
    periodic_phase_deg: float = 30.0
    backlash_um: NonNegFloat = 2.0
    repeatability_arcsec: NonNegFloat = 0.1

    @model_validator(mode="after")
    def _geometry(self) -> SwingConfig:
        lo, hi = self.angle_range_deg
        if not lo < 0 < hi:
            raise ValueError(f"angle_range_deg: {list(self.angle_range_deg)} must be "
                             "[min < 0 < max] (0 = the head horizontal)")  # fmt: skip
        if not (self.phi0_deg + lo > 0 and self.phi0_deg + hi < 180):
            raise ValueError("phi0_deg: the angle MAN must stay within 0..180 deg over "
                             "angle_range_deg")  # fmt: skip
        if self.offset_mm >= abs(self.base_mm - self.arm_mm):
            raise ValueError("offset_mm: must be less than |base_mm - arm_mm| (the screw "
                             "axis must pass between the pivots)")  # fmt: skip
        return self


class Harmonic(_Model):
    """One term a·sin(k·θ + φ) of a per-revolution error (θ the table angle)."""

    order: Annotated[int, Field(ge=1, le=64)]
    amplitude_arcsec: float
    phase_deg: float = 0.0


class WormConfig(_Model):
    """The worm gear's error once per worm revolution, i.e. every 360/``teeth`` degrees of
    the table (the rotary twin of a screw's once-per-lead error)."""

    teeth: Annotated[int, Field(ge=1, le=3600)] = 72
    amplitude_arcsec: float = 3.0
    phase_deg: float = 0.0
    #: a second harmonic of the worm period
    amplitude2_arcsec: float = 0.0


class TurntableConfig(_Model):
    """A worm-gear turntable: modulo 360°, per-revolution error (eccentricity, division
    error: ``harmonics`` of the table angle), the worm's cyclic error, a play and the spread
    of a stop. The drive counts turns on (multi-turn targets and feedback)."""

    harmonics: tuple[Harmonic, ...] = (
        Harmonic(order=1, amplitude_arcsec=20.0, phase_deg=40.0),
        Harmonic(order=2, amplitude_arcsec=8.0, phase_deg=-70.0),
        Harmonic(order=3, amplitude_arcsec=3.0, phase_deg=10.0),
    )
    worm: WormConfig | None = WormConfig()
    backlash_arcsec: NonNegFloat = 12.0
    repeatability_arcsec: NonNegFloat = 0.2


class AngleConfig(_Model):
    """Angle instrument (a reference rotary encoder or autocollimator set-up): channel k of
    ``axes`` at input registers 2k, 2k+1 (int32, µdeg, high word first; a turntable's angle
    modulo 360, 0..360°), stable flags at 2N + k, as the laser's."""

    unit: Annotated[int, Field(ge=1, le=247)] = 24
    axes: tuple[str, ...]
    resolution_udeg: PositiveFloat = 1.0
    noise_udeg: NonNegFloat = 0.0
    sample_s: NonNegFloat = 0.0
    #: a channel is stable once its axis is at rest and any ringing is within this band
    stable_band_udeg: PositiveFloat = 1.0
