"""Run-time fault injection and the control block (holding registers on ``faults.unit``).

Control block map (0-based holding registers, FC03/06/16 on the faults unit, default 250):

=================  =========================================================================
address            meaning
=================  =========================================================================
u*8 + 0            fault mode of unit u (1..247): 0 normal, 1 silent (no reply at all),
                   2 exception (every request answered with the code below),
                   3 garbage (RTU: corrupted bytes instead of the reply, bad CRC;
                   TCP: the reply's PDU bytes scrambled inside a valid MBAP header)
u*8 + 1            delay_ms: every reply of unit u (or exception/garbage) waits this long
u*8 + 2            exception code for mode 2 (0 means 0x04 device failure)
u*8 + 3            drives only: 1 forces the alarm status bit (moves refused), 0 clears
u*8 + 4            drives only, read-only: RTU requests ignored for too short a line
                   silence (``min_silence_s``)
u*8 + 5            drives only, read-only: FC16 requests refused as longer than
                   ``fc16_max_words``
u*8 + 6 .. +7      reserved (stored, no effect)
0x0800             write N: advance the machine clock by N seconds (reads 0)
0x0801             write N: advance the machine clock by N milliseconds (reads 0)
0x0802, 0x0803     machine clock in ms, uint32 high word first (read-only)
0x0804             write anything: clear every fault of every unit (reads 0)
=================  =========================================================================

A dead sensor is its unit in mode 1 (a timeout, like a cut cable) or mode 2 with code 0x04
(a sensor that answers but reports a failure). The control unit itself is never faulted.
"""

from __future__ import annotations

from dataclasses import dataclass

from sim.clock import MachineClock
from sim.drive import Drive
from sim.pdu import ILLEGAL_ADDRESS, ILLEGAL_VALUE, ModbusError, int32_to_words

MODE_NORMAL, MODE_SILENT, MODE_EXCEPTION, MODE_GARBAGE = 0, 1, 2, 3
UNIT_STRIDE = 8
ADDR_ADVANCE_S = 0x0800
ADDR_ADVANCE_MS = 0x0801
ADDR_CLOCK_MS = 0x0802
ADDR_CLEAR = 0x0804
_END = 0x0805


@dataclass
class UnitFault:
    """The fault state of one unit."""

    mode: int = MODE_NORMAL
    delay_ms: int = 0
    exception_code: int = 0


class FaultControl:
    """Fault table for every unit plus the control block unit (a :class:`RegisterUnit`)."""

    def __init__(self, clock: MachineClock, drives: dict[int, Drive], on_clock=None) -> None:
        self.clock = clock
        self.drives = drives
        self._on_clock = on_clock
        self._regs = [0] * (248 * UNIT_STRIDE)

    def fault(self, unit: int) -> UnitFault:
        """Current fault of ``unit`` (normal for ids outside 1..247)."""
        if not 1 <= unit <= 247:
            return UnitFault()
        base = unit * UNIT_STRIDE
        mode = self._regs[base]
        return UnitFault(
            mode=mode if mode in (0, 1, 2, 3) else MODE_NORMAL,
            delay_ms=self._regs[base + 1],
            exception_code=self._regs[base + 2] or 0x04,
        )

    def set_fault(self, unit: int, mode: int = 0, delay_ms: int = 0, code: int = 0) -> None:
        """In-process shortcut of writing the control block (tests, demo)."""
        self.write(unit * UNIT_STRIDE, [mode, delay_ms, code], 0x10)

    def clear(self) -> None:
        """All units back to normal, forced alarms off."""
        self._regs = [0] * len(self._regs)
        for drive in self.drives.values():
            drive.forced_alarm = False

    def read(self, table: str, address: int, count: int) -> list[int]:
        """Read the control block (holding only)."""
        if table != "holding" or address + count > _END:
            raise ModbusError(ILLEGAL_ADDRESS, "control block")
        clock = int32_to_words(round(self.clock.now_s() * 1000.0) & 0xFFFFFFFF, "hi_lo")
        tail = [0, 0, *clock, 0]  # 0x0800..0x0804
        regs = self._regs + [0] * (ADDR_ADVANCE_S - len(self._regs)) + tail
        for unit, drive in self.drives.items():
            base = unit * UNIT_STRIDE
            regs[base + 4] = min(drive.silence_violations, 0xFFFF)
            regs[base + 5] = min(drive.oversize_fc16, 0xFFFF)
        return regs[address : address + count]

    def write(self, address: int, values: list[int], function_code: int) -> None:
        """Write the control block; side effects apply at once."""
        span = range(address, address + len(values))
        for a in span:
            read_only = a in (ADDR_CLOCK_MS, ADDR_CLOCK_MS + 1) or (
                a < len(self._regs) and a % UNIT_STRIDE in (4, 5)
            )
            if a >= _END or len(self._regs) <= a < ADDR_ADVANCE_S or read_only:
                raise ModbusError(ILLEGAL_ADDRESS, f"{a:#06x}")
            if a < len(self._regs) and a % UNIT_STRIDE == 0 and values[a - address] > 3:
                raise ModbusError(ILLEGAL_VALUE, "mode is 0..3")
        for a, v in zip(span, values, strict=True):
            if a < len(self._regs):
                self._regs[a] = v
                unit, field = divmod(a, UNIT_STRIDE)
                if field == 3 and unit in self.drives:
                    self.drives[unit].forced_alarm = bool(v)
            elif a == ADDR_ADVANCE_S:
                self._advance(float(v))
            elif a == ADDR_ADVANCE_MS:
                self._advance(v / 1000.0)
            elif a == ADDR_CLEAR:
                self.clear()

    def _advance(self, seconds: float) -> None:
        self.clock.advance(seconds)
        if self._on_clock is not None:
            self._on_clock()
