"""The rotary truths (issue 16); the angle instrument that reads them is :mod:`sim.angle`.

- :class:`SwingTruth`: seed 003's swing head. The drive's count is a *commanded angle*
  (the control maps pulses linearly to degrees); the screw moves the nut by
  ``screw_mm_per_deg`` per commanded degree, plus the screw's own error; the head's angle
  follows from the rocking block's triangle (law of cosines), not linearly.
- :class:`TurntableTruth`: a worm-gear table; the angle is the motor's plus a
  per-revolution error of the table angle and the worm's once-per-worm-turn error.

Both truths give the play between motor and table (in the drive's degrees) to the
machine's play operator, and the spread of a stop; the machine does the rest (moves,
reversals, settling). Written from the geometry, independently of the gateway's model.
"""

from __future__ import annotations

import math

from sim.config_rotary import SwingConfig, TurntableConfig

ARCSEC_DEG = 1.0 / 3600.0


class SwingTruth:
    """Commanded angle (deg) at the nut → the head's true angle (deg), seed 003."""

    def __init__(self, cfg: SwingConfig) -> None:
        self.cfg = cfg
        lo, hi = cfg.angle_range_deg
        self.s_zero_mm = self.nut_mm(0.0)
        self.stroke_mm = (self.nut_mm(lo), self.nut_mm(hi))
        chord = (self.stroke_mm[1] - self.stroke_mm[0]) / (hi - lo)
        self.mm_per_deg = cfg.screw_mm_per_deg or chord
        self.repeatability_deg = cfg.repeatability_arcsec * ARCSEC_DEG

    # -- the triangle ------------------------------------------------------------------
    def nut_mm(self, angle_deg: float) -> float:
        """Nut-to-block distance along the screw when the head is at ``angle_deg``."""
        a, b, e = self.cfg.arm_mm, self.cfg.base_mm, self.cfg.offset_mm
        man = math.radians(self.cfg.phi0_deg + angle_deg)
        return math.sqrt(a * a + b * b - 2.0 * a * b * math.cos(man) - e * e)

    def angle_deg(self, nut_mm: float) -> float:
        """The head's angle for the nut ``nut_mm`` along the screw (inverse of the above)."""
        a, b, e = self.cfg.arm_mm, self.cfg.base_mm, self.cfg.offset_mm
        mn2 = nut_mm * nut_mm + e * e
        cos_man = (a * a + b * b - mn2) / (2.0 * a * b)
        return math.degrees(math.acos(max(-1.0, min(1.0, cos_man)))) - self.cfg.phi0_deg

    # -- the screw ---------------------------------------------------------------------
    def screw_error_mm(self, nut_mm: float) -> float:
        """The screw's own error at ``nut_mm`` (true − nominal travel), mm."""
        cfg = self.cfg
        s0, s1 = self.stroke_mm
        t = (nut_mm - s0) / (s1 - s0)
        err_um = cfg.slope_um_per_m * (nut_mm - s0) / 1000.0
        err_um += sum(c * t**k for k, c in enumerate(cfg.poly_um))
        err_um += cfg.periodic_um * math.sin(
            2.0 * math.pi * (nut_mm - s0) / cfg.lead_mm + math.radians(cfg.periodic_phase_deg))
        return err_um / 1000.0

    def play_deg(self, motor_deg: float) -> float:
        """The screw's play in the drive's (commanded) degrees."""
        return self.cfg.backlash_um / 1000.0 / self.mm_per_deg

    def true_deg(self, nut_deg: float) -> float:
        """The head's angle when the nut stands where ``nut_deg`` commanded degrees put it."""
        s = self.s_zero_mm + self.mm_per_deg * nut_deg
        return self.angle_deg(s + self.screw_error_mm(s))


class TurntableTruth:
    """Motor angle at the worm (deg, multi-turn) → the table's true angle (deg)."""

    def __init__(self, cfg: TurntableConfig) -> None:
        self.cfg = cfg
        self.repeatability_deg = cfg.repeatability_arcsec * ARCSEC_DEG

    def error_deg(self, angle_deg: float) -> float:
        """Per-revolution plus worm error at ``angle_deg`` (periodic in 360°)."""
        th = math.radians(angle_deg)
        err = sum(h.amplitude_arcsec * math.sin(h.order * th + math.radians(h.phase_deg))
                  for h in self.cfg.harmonics)  # fmt: skip
        worm = self.cfg.worm
        if worm is not None:
            w = worm.teeth * th
            err += worm.amplitude_arcsec * math.sin(w + math.radians(worm.phase_deg))
            err += worm.amplitude2_arcsec * math.sin(2.0 * w)
        return err * ARCSEC_DEG

    def play_deg(self, motor_deg: float) -> float:
        return self.cfg.backlash_arcsec * ARCSEC_DEG

    def true_deg(self, nut_deg: float) -> float:
        return nut_deg + self.error_deg(nut_deg)


RotaryTruth = SwingTruth | TurntableTruth


def rotary_truth(swing: SwingConfig | None, turntable: TurntableConfig | None
                 ) -> RotaryTruth | None:  # fmt: skip
    """The truth an axis's ``swing`` or ``turntable`` section describes, if any."""
    if swing is not None:
        return SwingTruth(swing)
    if turntable is not None:
        return TurntableTruth(turntable)
    return None
