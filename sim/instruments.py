"""Simulated measuring instruments, each a read-only Modbus unit (FC03 and FC04 both work).

Register maps (0-based addresses; int32 = two registers, high word first, two's complement):

* laser interferometer (``instruments.laser``): axis k (config order, or ``axes``) at
  registers 2k, 2k+1: true table position along that axis, int32 in nanometres, quantised
  to ``resolution_um``, plus normal noise ``noise_um`` per read; then, after the N axes'
  readings, register 2N + k: 1 when axis k is at rest and stable (its settling ringing within
  ``stable_band_um``), else 0 — a laser's "capture when stable". With
  ``laser.recording`` (sim/recorder.py) it has two holding registers besides: 0x0100 (FC06
  or a one-register FC16: 1 starts a recording, 2 stops it and saves ``DIR/rec-NNN``;
  reads 1 while recording, else 0), 0x0101 (read-only: NNN of the last file saved, 0
  before any) and 0x0102 (the channel k the laser is set up on, as recorded; written
  between recordings: the laser moved to another axis); a start while recording, a stop
  while not or a move while recording is refused with 0x04. Every other write is refused
  (0x02). The same laser answers the bridge line protocol
  (sim/bridge.py) through :meth:`Laser.reading`.
* 2-D device (``instruments.xy``): 0-1 true X, 2-3 true Y of the plane axes, int32 nm;
  4, 5: X, Y stable flags as the laser's.
* Laser and XY device take ``sample_s`` of machine time per reading: at time_scale 0 each
  read advances the machine clock by it (a master that reads until stable lets the axis
  settle; at time_scale > 0 the wall clock does).
* displacement sensor at reference point A (``instruments.delta_a``): 0 = delta_a as int16
  in steps of ``resolution_um`` (so a gateway reads it with ``scale_mm = resolution_um/1000``),
  1-2 = delta_a as int32 nm (same quantisation).
* temperatures (``instruments.temperature``): channel k at register k, int16 in 0.01 degC;
  a channel is an axis name (its screw temperature) or ``ambient``.
Every read request samples once (so the two words of an int32 always belong together) and
draws fresh noise from the instrument's own seeded generator.
"""

from __future__ import annotations

import numpy as np

from sim.clock import MachineClock
from sim.config import DeltaAConfig, LaserConfig, TemperatureConfig, XYConfig
from sim.machine import Machine
from sim.pdu import (
    DEVICE_FAILURE,
    ILLEGAL_ADDRESS,
    ILLEGAL_VALUE,
    ModbusError,
    int32_to_words,
)
from sim.recorder import Recorder, RecorderError

#: the laser's recording control (holding registers; only with ``laser.recording``)
REC_CONTROL = 0x0100  # write 1: start, 2: stop and save; reads 1 while recording
REC_LAST = 0x0101  # the number NNN of the last rec-NNN file saved
REC_AXIS = 0x0102  # the channel the laser is set up on (recorded); written between recordings
REC_START, REC_STOP = 1, 2


def _quantised_nm(value_mm: float, resolution_um: float) -> int:
    steps = round(value_mm * 1000.0 / resolution_um)
    return round(steps * resolution_um * 1000.0)


class Instrument:
    """Base: a read-only bank of registers computed on each read."""

    def __init__(self, machine: Machine, clock: MachineClock, rng: np.random.Generator) -> None:
        self.machine = machine
        self.clock = clock
        self.rng = rng

    def sample(self) -> list[int]:
        """All registers of the instrument, sampled now."""
        raise NotImplementedError

    def _noise(self, sigma: float) -> float:
        return float(self.rng.normal(0.0, sigma)) if sigma > 0 else 0.0

    def read(self, table: str, address: int, count: int) -> list[int]:
        """Read registers (holding and input tables are the same)."""
        regs = self.sample()
        if address + count > len(regs):
            raise ModbusError(ILLEGAL_ADDRESS, f"{len(regs)} registers")
        return regs[address : address + count]

    def write(self, address: int, values: list[int], function_code: int) -> None:
        """Instruments are read-only."""
        raise ModbusError(ILLEGAL_ADDRESS, "read-only")


class Laser(Instrument):
    """Laser interferometer, one channel per axis, with a stable flag per channel."""

    def __init__(self, cfg: LaserConfig, axes: list[str], *args) -> None:
        super().__init__(*args)
        self.cfg = cfg
        self.axes = list(cfg.axes) if cfg.axes is not None else axes
        #: the continuous recording (set by the simulation with ``laser.recording``)
        self.recorder: Recorder | None = None

    def sample(self) -> list[int]:
        """Axis k at 2k: true position, nm; 2N + k: stable flag."""
        nm, stable = self.reading(self.axes)
        out: list[int] = []
        for value_nm in nm:
            out += int32_to_words(value_nm, "hi_lo")
        return out + [int(flag) for flag in stable]

    def reading(self, channels: list[str]) -> tuple[list[int], list[bool]]:
        """One reading (``sample_s`` of machine time) of these channels: (nm quantised to
        ``resolution_um`` with noise, stable flags); the Modbus registers and the bridge
        both read through here."""
        now_s = _take_sample(self.clock, self.machine, self.cfg.sample_s)
        nm: list[int] = []
        for name in channels:
            pos_mm = self.machine.table_mm(name, now_s) + self._noise(self.cfg.noise_um) / 1000
            nm.append(_quantised_nm(pos_mm, self.cfg.resolution_um))
        band = self.cfg.stable_band_um
        return nm, [self.machine.ringing_um(n, now_s) <= band for n in channels]

    def read(self, table: str, address: int, count: int) -> list[int]:
        """Readings (no control registers in the span), or the recording control."""
        if self.recorder is None or address + count <= REC_CONTROL:
            return super().read(table, address, count)
        if address < REC_CONTROL or address + count > REC_AXIS + 1:
            raise ModbusError(ILLEGAL_ADDRESS, "readings, or 0x0100-0x0102")
        regs = [int(self.recorder.recording), self.recorder.last_number & 0xFFFF,
                self.axes.index(self.recorder.axis)]  # fmt: skip
        return regs[address - REC_CONTROL : address - REC_CONTROL + count]

    def write(self, address: int, values: list[int], function_code: int) -> None:
        """Only the recording control takes a write (one register at 0x0100, or the axis
        at 0x0102)."""
        if (self.recorder is None or address not in (REC_CONTROL, REC_AXIS)
                or len(values) != 1 or function_code not in (0x06, 0x10)):
            raise ModbusError(ILLEGAL_ADDRESS, "read-only")  # fmt: skip
        if address == REC_AXIS and values[0] >= len(self.axes):
            raise ModbusError(ILLEGAL_VALUE, f"channels 0-{len(self.axes) - 1}")
        try:
            if address == REC_AXIS:
                self.recorder.set_axis(self.axes[values[0]])
            elif values[0] == REC_START:
                self.recorder.start()
            elif values[0] == REC_STOP:
                self.recorder.stop()
            else:
                raise ModbusError(ILLEGAL_VALUE, "1 starts, 2 stops and saves")
        except RecorderError as err:
            raise ModbusError(DEVICE_FAILURE, str(err)) from None


class XYDevice(Instrument):
    """2-D measuring device over the plane axes."""

    def __init__(self, cfg: XYConfig, *args) -> None:
        super().__init__(*args)
        self.cfg = cfg

    def sample(self) -> list[int]:
        """0-1 X nm, 2-3 Y nm, 4-5 stable flags."""
        now_s = _take_sample(self.clock, self.machine, self.cfg.sample_s)
        x_mm, y_mm = self.machine.table_xy_mm(now_s)
        out: list[int] = []
        for v_mm in (x_mm, y_mm):
            v_mm += self._noise(self.cfg.noise_um) / 1000
            out += int32_to_words(_quantised_nm(v_mm, self.cfg.resolution_um), "hi_lo")
        assert self.machine.plane is not None
        band = self.cfg.stable_band_um
        axes = self.machine.plane.axes
        return out + [int(self.machine.ringing_um(n, now_s) <= band) for n in axes]


def _take_sample(clock: MachineClock, machine: Machine, sample_s: float) -> float:
    """The machine time of a reading that takes ``sample_s`` (advanced at time_scale 0)."""
    if sample_s > 0 and clock.time_scale == 0:
        clock.advance(sample_s)
        machine.update(clock.now_s())
    return clock.now_s()


class DeltaASensor(Instrument):
    """Displacement sensor at reference point A on the screw."""

    def __init__(self, cfg: DeltaAConfig, *args) -> None:
        super().__init__(*args)
        self.cfg = cfg

    def sample(self) -> list[int]:
        """0 = int16 resolution steps, 1-2 = int32 nm."""
        d_mm = self.cfg.direction * self.machine.delta_a_mm(
            self.cfg.axis, self.cfg.a_mm, self.clock.now_s()
        )
        d_mm += self._noise(self.cfg.noise_um) / 1000
        steps = round(d_mm * 1000.0 / self.cfg.resolution_um)
        steps = max(-32768, min(32767, steps))
        nm = _quantised_nm(d_mm, self.cfg.resolution_um)
        return [steps & 0xFFFF, *int32_to_words(nm, "hi_lo")]


class TemperatureSensors(Instrument):
    """Screw and ambient temperatures."""

    def __init__(self, cfg: TemperatureConfig, axes: list[str], *args) -> None:
        super().__init__(*args)
        self.cfg = cfg
        self.channels = list(cfg.channels) if cfg.channels is not None else [*axes, "ambient"]

    def sample(self) -> list[int]:
        """Channel k at k: int16, 0.01 degC."""
        now_s = self.clock.now_s()
        out: list[int] = []
        for ch in self.channels:
            temp_C = (
                self.machine.ambient_C()
                if ch == "ambient"
                else self.machine.screw_temp_C(ch, now_s, self.cfg.positions_mm.get(ch))
            )
            temp_C += self._noise(self.cfg.noise_C)
            out.append(max(-32768, min(32767, round(temp_C * 100.0))) & 0xFFFF)
        return out
