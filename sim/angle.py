"""The angle instrument (issue 16): a reference rotary encoder or autocollimator set-up.

Register map (read-only, FC03 or FC04, 0-based): channel k of ``instruments.angle.axes`` at
2k, 2k+1: the axis's true angle, int32 in µdeg, high word first, quantised to
``resolution_udeg`` plus normal noise ``noise_udeg`` per read; a turntable's channel reads
its angle modulo 360 (0 ≤ angle < 360°, as a reference encoder counts within a turn), a swing
axis's its signed angle. Then 2N + k (N channels): 1 when axis k is at rest and its ringing
within ``stable_band_udeg``, else 0, as the laser's stable flags. The layout is the laser's
with µdeg for nm, so a master reads degrees as it reads a laser's millimetres.
"""

from __future__ import annotations

from sim.config_rotary import AngleConfig
from sim.instruments import Instrument, _take_sample
from sim.pdu import int32_to_words
from sim.rotary import TurntableTruth

UDEG_PER_DEG = 1e6
_TURN_UDEG = 360_000_000


class AngleEncoder(Instrument):
    """One int32 µdeg reading per channel, then a stable flag per channel."""

    def __init__(self, cfg: AngleConfig, *args) -> None:
        super().__init__(*args)
        self.cfg = cfg
        self.axes = list(cfg.axes)

    def sample(self) -> list[int]:
        now_s = _take_sample(self.clock, self.machine, self.cfg.sample_s)
        out: list[int] = []
        for name in self.axes:
            wraps = isinstance(self.machine.axes[name].rotary, TurntableTruth)
            deg = self.machine.table_mm(name, now_s)
            deg += self._noise(self.cfg.noise_udeg) / UDEG_PER_DEG
            steps = round(deg * UDEG_PER_DEG / self.cfg.resolution_udeg)
            udeg = round(steps * self.cfg.resolution_udeg)
            out += int32_to_words(udeg % _TURN_UDEG if wraps else udeg, "hi_lo")
        band = self.cfg.stable_band_udeg / 1000.0  # ringing is in 1/1000 of the axis unit
        return out + [int(self.machine.ringing_um(n, now_s) <= band) for n in self.axes]
