"""The whole simulated machine without I/O: units by id, and how each request is answered.

Transports (sim/server.py) hand it a unit id and a request PDU and get back a :class:`Reply`
saying what to send, after how long, and whether to corrupt it. Keeping this free of sockets
makes the behaviour identical over TCP and RTU.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from sim.angle import AngleEncoder
from sim.clock import MachineClock
from sim.config import SimConfig, load_pitch_table
from sim.drive import Drive
from sim.faults import MODE_EXCEPTION, MODE_GARBAGE, MODE_SILENT, FaultControl
from sim.instruments import DeltaASensor, Instrument, Laser, TemperatureSensors, XYDevice
from sim.machine import Machine
from sim.pdu import RegisterUnit, exception_pdu, handle_pdu
from sim.recorder import Recorder

# spawn keys for instrument noise, well away from the machine's per-axis keys (0..n-1)
_INSTRUMENT_KEYS = {"laser": 1001, "xy": 1002, "delta_a": 1003, "temperature": 1004,
                    "angle": 1005, "recording": 1006}
_GARBAGE_KEY = 1100


@dataclass(frozen=True)
class Reply:
    """What a transport should do with one request."""

    pdu: bytes | None  # None = send nothing
    delay_s: float = 0.0
    garbage: bool = False
    unknown_unit: bool = False


class Simulation:
    """Clock, machine, drives, instruments and faults built from one config."""

    def __init__(self, config: SimConfig, wall_s: Callable[[], float] = time.monotonic) -> None:
        self.config = config
        cfg = config.sim
        self.clock = MachineClock(cfg.time_scale, wall_s)
        tables = {
            name: load_pitch_table(errs.pitch.table, config.base_dir)
            for name, errs in cfg.machine.items()
            if errs.pitch.table is not None
        }
        self.machine = Machine(cfg, tables, config.base_dir)
        self.drives: dict[str, Drive] = {
            name: Drive(name, axis, self.machine, self.clock) for name, axis in cfg.axes.items()
        }
        self.drives_by_unit: dict[int, Drive] = {d.cfg.unit: d for d in self.drives.values()}
        self.faults = FaultControl(self.clock, self.drives_by_unit, on_clock=self._clock_moved)
        self.instruments: dict[str, Instrument] = {}
        axes = list(cfg.axes)

        def rng(key: str) -> np.random.Generator:
            return np.random.default_rng(
                np.random.SeedSequence(cfg.seed, spawn_key=(_INSTRUMENT_KEYS[key],))
            )

        ins = cfg.instruments
        base = (self.machine, self.clock)
        #: the laser's continuous recording (``instruments.laser.recording``), if any
        self.recorder: Recorder | None = None
        if ins.laser is not None:
            laser = Laser(ins.laser, axes, *base, rng("laser"))
            self.instruments["laser"] = laser
            if ins.laser.recording is not None:
                rec = ins.laser.recording
                self.recorder = Recorder(rec, rec.axis or laser.axes[0], self.machine,
                                         self.clock, rng("recording"), config.base_dir,
                                         wall_s)  # fmt: skip
                laser.recorder = self.recorder
        if ins.xy is not None:
            self.instruments["xy"] = XYDevice(ins.xy, *base, rng("xy"))
        if ins.delta_a is not None:
            self.instruments["delta_a"] = DeltaASensor(ins.delta_a, *base, rng("delta_a"))
        if ins.temperature is not None:
            self.instruments["temperature"] = TemperatureSensors(
                ins.temperature, axes, *base, rng("temperature")
            )
        if ins.angle is not None:
            self.instruments["angle"] = AngleEncoder(ins.angle, *base, rng("angle"))
        self.units: dict[int, RegisterUnit] = dict(self.drives_by_unit)
        for key, inst in self.instruments.items():
            self.units[getattr(ins, key).unit] = inst
        self.units[cfg.faults.unit] = self.faults
        self.garbage_rng = np.random.default_rng(
            np.random.SeedSequence(cfg.seed, spawn_key=(_GARBAGE_KEY,))
        )

    def _clock_moved(self) -> None:
        self.machine.update(self.clock.now_s())

    def respond(self, unit: int, pdu: bytes) -> Reply:
        """Answer one request PDU for ``unit``, faults applied."""
        if self.recorder is not None:
            self.recorder.catch_up()  # time_scale > 0: record up to now before any change
        target = self.units.get(unit)
        if target is None or not pdu:
            return Reply(None, unknown_unit=target is None)
        if unit == self.config.sim.faults.unit:
            return Reply(handle_pdu(target, pdu))
        fault = self.faults.fault(unit)
        delay_s = fault.delay_ms / 1000.0
        if fault.mode == MODE_SILENT:
            return Reply(None)
        if fault.mode == MODE_EXCEPTION:
            return Reply(exception_pdu(pdu[0], fault.exception_code), delay_s)
        return Reply(handle_pdu(target, pdu), delay_s, garbage=fault.mode == MODE_GARBAGE)

    def scramble(self, frame: bytes) -> bytes:
        """Deterministically corrupt a frame (every byte XOR a nonzero seeded mask)."""
        mask = self.garbage_rng.integers(1, 256, size=len(frame), dtype=np.uint8)
        return (np.frombuffer(frame, dtype=np.uint8) ^ mask).tobytes()
