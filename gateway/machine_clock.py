"""The machine's clock where it is not the computer's: a simulator's (``machine_clock``).

A simulator at ``time_scale: 0`` runs hours of machine time in minutes: its screws heat
and cool by its own clock. The gateway's heat from motion and travel profile count time
(a screw cools while it stands), and so does ``compgw commission``'s drift log; on the
wall clock they would see minutes where the screw lived hours. With ``machine_clock``
the gateway reads the machine's clock before it corrects a target (one request more per
move), counts heat by it, and shows it on the status unit as that read found it
(:mod:`gateway.status`, registers 120-122), where commissioning reads it. On a real
machine the computer's clock is the machine's: leave ``machine_clock`` out.
"""

from __future__ import annotations

import logging

from .config import MachineClockSource
from .modbus.downstream import Bus
from .modbus.frames import ModbusError
from .sensors import decode_response, read_request

log = logging.getLogger(__name__)


class WrappingCount:
    """A counter of ``span`` values (a 32-bit ms register: 49.7 days) read now and then:
    the count since 0, going on past each return to 0 (reads closer than one span)."""

    def __init__(self, span: int) -> None:
        self.span = span
        self.total: int | None = None  # None before the first read
        self._last = 0

    def update(self, raw: int) -> int:
        """The count after a read of ``raw``."""
        if self.total is None:
            self.total = raw
        else:
            self.total += (raw - self._last) % self.span
        self._last = raw
        return self.total


class MachineTime:
    """The machine's clock (s), as last read.

    Between two reads it stands still: a simulator's clock jumps by whole moves, and each
    correction reads it first. A counter that goes past its top and back
    to 0 (32 bits of ms: 49.7 days) goes on counting. A read that fails keeps the clock
    where it was (counted in ``failures``, logged once per run of failures)."""

    def __init__(self, source: MachineClockSource, bus: Bus) -> None:
        self.source = source
        self.bus = bus
        self._request = read_request(source.source_register)
        self._counts = WrappingCount(1 << (16 * source.source_register.words))
        self.failures = 0
        self.ok = False  # the last read answered
        self.reads = 0  # reads answered so far

    def now_s(self) -> float:
        """The machine's clock (s) as last read; 0 before the first read."""
        return (self._counts.total or 0) * self.source.scale_s

    async def refresh(self) -> None:
        """Read the clock once; a failure leaves it where it was."""
        try:
            reply = await self.bus.transact(self.source.unit, self._request,
                                            caller=("clock", "machine_clock"))  # fmt: skip
            counts = decode_response(reply, self.source.source_register)
        except (ModbusError, ValueError, OSError) as err:
            if self.ok or self.failures == 0:
                log.warning("machine_clock: read failed, the clock stands: %s", err)
            self.failures += 1
            self.ok = False
            return
        self._counts.update(counts)
        self.ok = True
        self.reads += 1

