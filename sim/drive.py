"""One simulated servo drive in position (PR) mode: its registers and move state machine.

A move starts on the trigger write (or, without a trigger, on a write touching the target's
second register), lasts travel/speed (machine time; wall time x time_scale), and the status
bits follow. Feedback is motor-side pulses x counts_per_pulse (semi-closed loop), never the
true table position. Targets beyond travel +- overtravel raise the alarm bit and do not move
(a later valid move clears it); an alarm forced through the fault block blocks all moves.
"""

from __future__ import annotations

from sim.clock import MachineClock
from sim.config import AxisConfig
from sim.machine import Machine
from sim.pdu import ILLEGAL_ADDRESS, ILLEGAL_VALUE, ModbusError, int32_to_words, words_to_int32


class Drive:
    """Register bank + behaviour of one drive (implements :class:`sim.pdu.RegisterUnit`)."""

    def __init__(self, name: str, cfg: AxisConfig, machine: Machine, clock: MachineClock) -> None:
        self.name = name
        self.cfg = cfg
        self.regs_cfg = cfg.registers
        self.machine = machine
        self.clock = clock
        self.homed = cfg.homed_at_start
        self._homing = False
        self.limit_alarm = False
        self.forced_alarm = False
        self.eeprom_writes = 0
        self.oversize_fc16 = 0  # FC16 requests longer than the drive accepts (refused)
        self.silence_violations = 0  # RTU requests ignored for too short a line silence
        self.ram_only = cfg.registers.eeprom.ram_only
        self.moves_started = 0
        # plain storage for every writable register; computed registers are not stored
        self._store: dict[int, int] = {}
        r = self.regs_cfg
        for block in r.memory:
            for a in range(block.address, min(block.address + block.count, 0x10000)):
                self._store[a] = 0
        writable = [r.target.address, r.target.address + 1]
        if r.trigger is not None:
            writable.append(r.trigger.address)
        if r.speed is not None:
            writable.append(r.speed.address)
        if r.eeprom.ram_only_param is not None:
            p = r.eeprom.ram_only_param
            writable.append(p.address)
            self._store[p.address] = p.value if self.ram_only else (p.value + 1) & 0xFFFF
        for a in writable:
            self._store.setdefault(a, 0)
        self._computed: set[int] = {r.status.address}
        if r.feedback.table == "holding":
            self._computed |= {r.feedback.address, r.feedback.address + 1}
        if r.eeprom.counter is not None:
            self._computed |= {r.eeprom.counter.address, r.eeprom.counter.address + 1}
        for a in self._computed:
            self._store.pop(a, None)

    # ------------------------------------------------------------ state
    @property
    def alarm(self) -> bool:
        """Alarm bit: a refused target or a fault-forced alarm."""
        return self.limit_alarm or self.forced_alarm

    def target_pulses(self) -> int:
        """The target currently held in the target register pair."""
        a = self.regs_cfg.target.address
        return words_to_int32([self._store[a], self._store[a + 1]], self.regs_cfg.target.order)

    def moving(self) -> bool:
        """True while a move is under way."""
        moving = self.machine.is_moving(self.name, self.clock.now_s())
        if not moving and self._homing:
            self._homing = False
            self.homed = True
        return moving

    def status_word(self) -> int:
        """The status register from the current state."""
        s = self.regs_cfg.status
        moving = self.moving()
        bits = {
            s.alarm_bit: self.alarm,
            s.enabled_bit: True,
            s.moving_bit: moving,
            s.in_position_bit: not moving and not self.alarm,
            s.homed_bit: self.homed,
        }
        word = 0
        for bit, on in bits.items():
            if bit is not None and on:
                word |= 1 << bit
        return word

    def feedback_counts(self) -> int:
        """Motor-side position in feedback counts."""
        pulses = self.machine.motor_pulses(self.name, self.clock.now_s())
        return pulses * self.regs_cfg.feedback.counts_per_pulse

    def speed_mm_s(self) -> float:
        """Commanded speed: the speed register scaled, or the axis default when 0."""
        sp = self.regs_cfg.speed
        raw = self._store[sp.address] if sp is not None else 0
        return raw * sp.scale_mm_s if sp is not None and raw else self.cfg.speed_mm_s

    # ------------------------------------------------------------ register access
    def read(self, table: str, address: int, count: int) -> list[int]:
        """Read registers; unknown addresses -> exception 0x02."""
        r = self.regs_cfg
        out: list[int] = []
        computed: dict[int, int] = {}
        fb_table = r.feedback.table
        if table == "input" and fb_table != "input":
            raise ModbusError(ILLEGAL_ADDRESS, "no input registers")
        span = range(address, address + count)
        fb_span = {r.feedback.address, r.feedback.address + 1}
        if fb_table == table and fb_span.intersection(span):
            words = int32_to_words(self.feedback_counts(), r.feedback.order)
            computed[r.feedback.address], computed[r.feedback.address + 1] = words
        if table == "holding":
            if r.status.address in span:
                computed[r.status.address] = self.status_word()
            if r.eeprom.counter is not None:
                c = r.eeprom.counter.address
                computed[c], computed[c + 1] = int32_to_words(self.eeprom_writes, "hi_lo")
        for a in span:
            if a in computed:
                out.append(computed[a])
            elif table == "holding" and a in self._store:
                out.append(self._store[a])
            else:
                raise ModbusError(ILLEGAL_ADDRESS, f"{a:#06x}")
        return out

    def write(self, address: int, values: list[int], function_code: int) -> None:
        """Write holding registers, then act: EEPROM count, RAM flag, move start."""
        r = self.regs_cfg
        if function_code == 0x10 and r.fc16_max_words and len(values) > r.fc16_max_words:
            self.oversize_fc16 += 1
            raise ModbusError(ILLEGAL_VALUE, f"FC16 of {len(values)} > {r.fc16_max_words}")
        span = range(address, address + len(values))
        for a in span:
            if a not in self._store:
                raise ModbusError(ILLEGAL_ADDRESS, f"{a:#06x} is not writable")
        old_trigger = self._store[r.trigger.address] if r.trigger is not None else 0
        for a, v in zip(span, values, strict=True):
            self._store[a] = v
        p = r.eeprom.ram_only_param
        if p is not None and p.address in span:
            self.ram_only = self._store[p.address] == p.value
        touches_target = r.target.address in span or r.target.address + 1 in span
        if touches_target and not self.ram_only:
            self.eeprom_writes += 1
        if r.trigger is None:
            if r.target.address + 1 in span:
                self._start_move(self.target_pulses())
            return
        t = r.trigger
        if t.address not in span:
            return
        new = self._store[t.address]
        if t.rising_bit is not None:
            mask = 1 << t.rising_bit
            if new & mask and not old_trigger & mask:
                self._start_move(self.target_pulses())
        elif t.value is None or new == t.value:
            self._start_move(self.target_pulses())
        elif t.home_value is not None and new == t.home_value:
            self._start_move(0, homing=True)

    # ------------------------------------------------------------ motion
    def _start_move(self, target_pulses: int, homing: bool = False) -> None:
        if self.forced_alarm:
            return
        lo_mm, hi_mm = self.cfg.travel_mm
        margin_mm = self.cfg.overtravel_mm
        target_mm = target_pulses * self.cfg.pulse_mm
        if not homing and not lo_mm - margin_mm <= target_mm <= hi_mm + margin_mm:
            self.limit_alarm = True
            return
        self.limit_alarm = False
        self._homing = homing
        self.moves_started += 1
        duration_s = self.machine.begin_move(
            self.name, target_pulses, self.speed_mm_s(), self.clock.now_s()
        )
        if self.clock.time_scale == 0:
            self.clock.advance(duration_s)
            self.machine.update(self.clock.now_s())
