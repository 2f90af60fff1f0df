"""One simulated servo drive in position (PR) mode: its registers and move state machine.

A move starts on the trigger write (or, without a trigger, on a write touching the target's
second register), by the rules of the trigger's style (sim/profiles.py: a register value or
bit edge, a 32-bit field inside the target's own block, a coil, a control-word edge), lasts
travel/speed (machine time; wall time x time_scale), and the status bits follow. Feedback
is motor-side pulses x counts_per_pulse (semi-closed loop), never the true table position.
Targets beyond travel +- overtravel raise the alarm bit and do not move (a later valid move
clears it); an alarm forced through the fault block blocks all moves.

Every write the drive accepts is kept, in arrival order, in :attr:`Drive.received` with the
target of the move it started, so a test can check what reached the drive and in what order
(a trigger before its target would start a move to the previous target).
"""

from __future__ import annotations

import itertools
from collections import deque
from dataclasses import dataclass, field

from sim.clock import MachineClock
from sim.config import AxisConfig
from sim.machine import Machine
from sim.pdu import (
    ILLEGAL_ADDRESS,
    ILLEGAL_FUNCTION,
    ILLEGAL_VALUE,
    ModbusError,
    int32_to_words,
    words_to_int32,
)
from sim.profiles import (
    A6_BLOCK_SELECT,
    A6_BLOCK_STRIDE,
    A6_BLOCK_TABLE,
    A6_COILS,
    AZ_OPERATION_TYPE,
    KINCO_ENABLED_MASK,
    KINCO_RELATIVE_BIT,
    LEADSHINE_PR0_MODE,
    LEADSHINE_RELATIVE_BIT,
)

RECEIVED_MAX = 4096  # writes kept in Drive.received (the oldest go first)
_ARRIVAL = itertools.count()  # one order of arrival across all drives of the process


@dataclass(frozen=True)
class Received:
    """One write a drive accepted: registers (``holding``) or coils (values 0/1)."""

    table: str
    address: int
    values: tuple[int, ...]
    function_code: int
    started: int | None = None  # target (pulses) of the move this write started
    #: arrival order, comparable between drives (which write reached which drive first)
    seq: int = field(default_factory=lambda: next(_ARRIVAL))


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
        self.received: deque[Received] = deque(maxlen=RECEIVED_MAX)
        self._command_pulses: int | None = None  # target of the last move (None: none yet)
        self._coils: dict[int, int] = {}  # writable coils besides the trigger (stored)
        # plain storage for every writable register; computed registers are not stored
        self._store: dict[int, int] = {}
        r = self.regs_cfg
        for block in r.memory:
            for a in range(block.address, min(block.address + block.count, 0x10000)):
                self._store[a] = 0
        writable = [r.target.address, r.target.address + 1]
        if r.trigger is not None and r.trigger.table == "holding":
            writable += range(r.trigger.address, r.trigger.address + r.trigger.words)
        if r.trigger is not None and r.trigger.style == "panasonic-block":
            self._coils = {A6_COILS["SRV-ON"]: 0, A6_COILS["A-CLR"]: 0}
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
        old_trigger = self._trigger_value()
        for a, v in zip(span, values, strict=True):
            self._store[a] = v
        p = r.eeprom.ram_only_param
        if p is not None and p.address in span:
            self.ram_only = self._store[p.address] == p.value
        touches_target = r.target.address in span or r.target.address + 1 in span
        if touches_target and not self.ram_only:
            self.eeprom_writes += 1
        started = self._act_on_registers(span, old_trigger)
        self.received.append(Received("holding", address, tuple(values), function_code, started))

    def _trigger_value(self) -> int:
        """The trigger register (a 32-bit field: signed, high word first) as stored."""
        t = self.regs_cfg.trigger
        if t is None or t.table != "holding":
            return 0
        if t.words == 2:
            return words_to_int32([self._store[t.address], self._store[t.address + 1]], "hi_lo")
        return self._store[t.address]

    def _act_on_registers(self, span: range, old: int) -> int | None:
        """Start what a register write starts; the move's target, or None."""
        r = self.regs_cfg
        t = r.trigger
        if t is None:
            if r.target.address + 1 in span:
                return self._start_move(self.target_pulses())
            return None
        if t.table != "holding" or not set(span) & set(range(t.address, t.address + t.words)):
            return None
        new = self._trigger_value()
        if t.style == "oriental-direct":
            return self._oriental_direct(new)
        if t.style == "kinco-control":
            return self._kinco_control(old, new)
        if t.style == "leadshine-pr" and new == t.value:
            if self._store.get(LEADSHINE_PR0_MODE, 1) >> LEADSHINE_RELATIVE_BIT & 1:
                return self._start_move(self._command() + self.target_pulses())
            return self._start_move(self.target_pulses())
        if t.rising_bit is not None:
            mask = 1 << t.rising_bit
            if new & mask and not old & mask:
                return self._start_move(self.target_pulses())
        elif t.value is None or new == t.value:
            return self._start_move(self.target_pulses())
        elif t.home_value is not None and new == t.home_value:
            self._start_move(0, homing=True)
        return None

    def _oriental_direct(self, trigger: int) -> int | None:
        """AZ direct data operation: a non-zero trigger executes at once."""
        if trigger == 0:
            return None
        a = AZ_OPERATION_TYPE
        operation = words_to_int32([self._store.get(a, 0), self._store.get(a + 1, 0)], "hi_lo")
        if operation == 1:  # absolute
            return self._start_move(self.target_pulses())
        if operation == 2:  # incremental from the command position
            return self._start_move(self._command() + self.target_pulses())
        if operation == 3:  # incremental from the feedback position
            return self._start_move(self._motor_pulses() + self.target_pulses())
        self.limit_alarm = True  # an operation data error
        return None

    def _kinco_control(self, old: int, new: int) -> int | None:
        """CiA 402 profile position: the new-set-point edge while operation is enabled."""
        t = self.regs_cfg.trigger
        assert t is not None and t.rising_bit is not None
        bit = 1 << t.rising_bit
        if not (new & bit and not old & bit) or new & KINCO_ENABLED_MASK != KINCO_ENABLED_MASK:
            return None
        if new >> KINCO_RELATIVE_BIT & 1:
            return self._start_move(self._command() + self.target_pulses())
        return self._start_move(self.target_pulses())

    # ------------------------------------------------------------ coils
    @property
    def has_coils(self) -> bool:
        """Whether the drive answers coil requests (its trigger is a coil)."""
        t = self.regs_cfg.trigger
        return t is not None and t.table == "coils"

    def write_coils(self, address: int, bits: list[int], function_code: int) -> None:
        """FC05/FC15: the trigger coil (and, for the A6, SRV-ON and A-CLR)."""
        t = self.regs_cfg.trigger
        if t is None or t.table != "coils":
            raise ModbusError(ILLEGAL_FUNCTION, "no coils")
        span = range(address, address + len(bits))
        for a in span:
            if a != t.address and a not in self._coils:
                raise ModbusError(ILLEGAL_ADDRESS, f"coil {a:#06x} is not writable")
        started = None
        for a, bit in zip(span, bits, strict=True):
            if a in self._coils:
                self._coils[a] = bit
                if bit and a == A6_COILS["A-CLR"]:
                    self.limit_alarm = False
            elif bit or t.value is None:  # the trigger coil (STB clears itself)
                if t.style == "panasonic-block":
                    started = self._panasonic_block()
                else:
                    started = self._start_move(self.target_pulses())
        self.received.append(Received("coils", address, tuple(bits), function_code, started))

    def read_bits(self, table: str, address: int, count: int) -> list[int]:
        """FC01/FC02: the trigger coil reads 0; the A6's state coils."""
        t = self.regs_cfg.trigger
        if t is None or t.table != "coils":
            raise ModbusError(ILLEGAL_FUNCTION, "no coils")
        state: dict[int, int] = {t.address: 0, **self._coils}
        if t.style == "panasonic-block":
            moving = self.moving()
            state[A6_COILS["A-CLR"]] = 0
            state[A6_COILS["BUSY"]] = int(moving)
            state[A6_COILS["COIN"]] = int(not moving and not self.alarm)
            state[A6_COILS["HOME-CMP"]] = int(self.homed)
        out = []
        for a in range(address, address + count):
            if a not in state:
                raise ModbusError(ILLEGAL_ADDRESS, f"coil {a:#06x}")
            out.append(state[a])
        return out

    def _panasonic_block(self) -> int | None:
        """A6 block operation: run the block selected in the block number register."""
        base = A6_BLOCK_TABLE + A6_BLOCK_STRIDE * self._store.get(A6_BLOCK_SELECT, 0)
        words = [self._store.get(a, 0) for a in range(base, base + 4)]
        code = words_to_int32(words[:2], "hi_lo") >> 24 & 0xFF
        target = words_to_int32(words[2:], "hi_lo")
        if code == 2:  # absolute
            return self._start_move(target)
        if code == 1:  # relative
            return self._start_move(self._command() + target)
        if code == 4:
            self._start_move(0, homing=True)
        return None  # 5 (decelerate and stop) and undefined codes: no move

    # ------------------------------------------------------------ motion
    def _command(self) -> int:
        """The command position: the last move's target (the motor's position before any)."""
        return self._motor_pulses() if self._command_pulses is None else self._command_pulses

    def _motor_pulses(self) -> int:
        return self.machine.motor_pulses(self.name, self.clock.now_s())

    def _start_move(self, target_pulses: int, homing: bool = False) -> int | None:
        """Start a move (or homing); the target when it started, None when refused."""
        if self.forced_alarm:
            return None
        lo_mm, hi_mm = self.cfg.travel_mm
        margin_mm = self.cfg.overtravel_mm
        target_mm = target_pulses * self.cfg.pulse_mm
        if not homing and not lo_mm - margin_mm <= target_mm <= hi_mm + margin_mm:
            self.limit_alarm = True
            return None
        self.limit_alarm = False
        self._homing = homing
        self.moves_started += 1
        self._command_pulses = target_pulses
        duration_s = self.machine.begin_move(
            self.name, target_pulses, self.speed_mm_s(), self.clock.now_s()
        )
        if self.clock.time_scale == 0:
            self.clock.advance(duration_s)
            self.machine.update(self.clock.now_s())
        return target_pulses
