"""Write protection: registers no master may write, whatever the network lets through.

Modbus has no authentication, so the gateway guards the drives itself: a write request
(FC05/06/0F/10/16/17) to an upstream unit whose written range touches a ``write_protect``
entry is answered with exception 0x02 (illegal data address) and sent to no drive. A write
PDU too short to show its range is refused with 0x03 (as a drive answers a malformed
request) when the unit protects the table it writes; a rule protects only its own table.
The rules are read from the current config at each request, so a reload changes them
between transactions.
"""

from __future__ import annotations

import logging
from collections.abc import Awaitable, Callable, Sequence

from ..config import WriteProtect
from .frames import (
    ILLEGAL_DATA_ADDRESS,
    ILLEGAL_DATA_VALUE,
    MASK_WRITE_REGISTER,
    READ_WRITE_MULTIPLE_REGISTERS,
    WRITE_MULTIPLE_COILS,
    WRITE_MULTIPLE_REGISTERS,
    WRITE_SINGLE_COIL,
    WRITE_SINGLE_REGISTER,
    ModbusError,
)

log = logging.getLogger(__name__)

Handler = Callable[[int, bytes], Awaitable[bytes | None]]
Done = Callable[[bytes | None, BaseException | None], None]
FastHandler = Callable[[int, bytes, Done], bool]

_HOLDING_WRITES = {WRITE_SINGLE_REGISTER, WRITE_MULTIPLE_REGISTERS, MASK_WRITE_REGISTER,
                   READ_WRITE_MULTIPLE_REGISTERS}
_COIL_WRITES = {WRITE_SINGLE_COIL, WRITE_MULTIPLE_COILS}


def written_table(pdu: bytes) -> str | None:
    """The table ("holding" or "coils") a write request writes; None for other requests."""
    fc = pdu[0] if pdu else 0
    if fc in _HOLDING_WRITES:
        return "holding"
    return "coils" if fc in _COIL_WRITES else None


def written_range(pdu: bytes) -> tuple[str, int, int] | None:
    """(table, first address, count) a write request touches; None for other requests.

    Raises ValueError when the PDU is a write too short to tell.
    """
    table = written_table(pdu)
    if table is None:
        return None
    fc = pdu[0]
    if fc == READ_WRITE_MULTIPLE_REGISTERS:
        if len(pdu) < 9:
            raise ValueError("short FC23")
        return table, int.from_bytes(pdu[5:7], "big"), max(1, int.from_bytes(pdu[7:9], "big"))
    if len(pdu) < 5:
        raise ValueError(f"short FC{fc:02d}")
    address = int.from_bytes(pdu[1:3], "big")
    if fc in (WRITE_MULTIPLE_REGISTERS, WRITE_MULTIPLE_COILS):
        return table, address, max(1, int.from_bytes(pdu[3:5], "big"))
    return table, address, 1


class WriteGuard:
    """Wraps a handler; ``rules()`` gives the current ``write_protect`` list."""

    def __init__(self, rules: Callable[[], Sequence[WriteProtect]]) -> None:
        self.rules = rules
        self.refused = 0

    def check(self, unit_id: int, pdu: bytes) -> None:
        """Raise ModbusError(0x02) when ``pdu`` writes a protected register of ``unit_id``.

        Only the rules of the table the request writes apply. A write of a protected table
        too short to show its range is refused with 0x03, as a conforming drive answers a
        malformed request (and never reaches the drive, which might act on it leniently).
        """
        rules = self.rules()
        if not rules:
            return
        table = written_table(pdu)
        if table is None:
            return
        # a broadcast (unit 0) writes every unit: every unit's rules apply
        rules = [r for r in rules if r.table == table and unit_id in (0, r.unit)]
        if not rules:
            return
        try:
            span = written_range(pdu)
        except ValueError as exc:
            self.refused += 1
            log.warning("malformed write to unit %d refused: it has write_protect %s: %s",
                        unit_id, table, exc)
            raise ModbusError(f"unit {unit_id}: malformed write", ILLEGAL_DATA_VALUE) from None
        assert span is not None
        _, start, count = span
        for rule in rules:
            if start < rule.address + rule.count and rule.address < start + count:
                self.refused += 1
                log.warning("write to unit %d %s %d..%d refused: write_protect %d..%d",
                            unit_id, rule.table, start, start + count - 1, rule.address,
                            rule.address + rule.count - 1)
                raise ModbusError(f"unit {unit_id}: protected range", ILLEGAL_DATA_ADDRESS)

    def wrap(self, handler: Handler) -> Handler:
        async def guarded(unit_id: int, pdu: bytes) -> bytes | None:
            self.check(unit_id, pdu)
            return await handler(unit_id, pdu)

        return guarded

    def wrap_fast(self, fast: FastHandler) -> FastHandler:
        """The same check in front of a fast handler (see :mod:`gateway.modbus.upstream`): a
        refused write is answered at once, through ``done``."""

        def guarded(unit_id: int, pdu: bytes, done: Done) -> bool:
            try:
                self.check(unit_id, pdu)
            except ModbusError as err:
                done(None, err)
                return True
            return fast(unit_id, pdu, done)

        return guarded
