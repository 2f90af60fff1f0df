"""Trigger rules: does a write touch an axis's trigger, and does it start a move (or homing)?
(The move mode and block select, the other registers that decide a move, are
:mod:`gateway.drive_model`'s.)

Pure functions over a parsed write request (:class:`gateway.modbus.frames.Request`) and the
trigger's config. A trigger is a holding register (FC06, FC16 blocks around it), a 32-bit
field of two registers (``words: 2``, either word written counts), or a coil (FC05, FC15
covering it). The router keeps, per axis, what the master last wrote to the trigger
(:class:`TriggerShadow`), so a 32-bit value written one word at a time is judged whole. A
``rising_bit`` write with the bit set is taken as a possible start whatever the shadow says
(the drive sees an edge against what *it* held, which a broadcast it refused can leave
other than the shadow): its pending target is committed and its mode judged first, and a
relative bit with it is refused. It takes the shadow a verdict gives only once the drive
has the write.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from .axis import overlap
from .config_registers import TriggerRegister
from .modbus.frames import (
    READ_WRITE_MULTIPLE_REGISTERS,
    WRITE_MULTIPLE_COILS,
    WRITE_MULTIPLE_REGISTERS,
    WRITE_SINGLE_COIL,
    WRITE_SINGLE_REGISTER,
    Request,
    unpack_int32,
)

REGISTER_WRITES = frozenset({WRITE_SINGLE_REGISTER, WRITE_MULTIPLE_REGISTERS,
                             READ_WRITE_MULTIPLE_REGISTERS})
COIL_WRITES = frozenset({WRITE_SINGLE_COIL, WRITE_MULTIPLE_COILS})


@dataclass(frozen=True)
class TriggerShadow:
    """What the master last wrote to an axis's trigger (0 before any write)."""

    words: tuple[int, int] = (0, 0)
    value: int = 0  # unsigned: 0..0xFFFF, 0..0xFFFFFFFF (words: 2) or 0/1 (a coil)


@dataclass(frozen=True)
class Verdict:
    """What a write of the trigger does: ``fires`` starts a move, ``homes`` the homing;
    ``shadow``: the trigger's shadow once the drive has the write."""

    fires: bool
    homes: bool
    shadow: TriggerShadow = field(default_factory=TriggerShadow)
    #: the start is a relative move (``relative_bit`` set): refused
    relative: bool = False


def writes_trigger(rule: TriggerRegister | None, fc: int, start: int, count: int) -> bool:
    """Whether a write by function ``fc`` of ``count`` registers or coils at ``start``
    writes (part of) the trigger."""
    if rule is None:
        return False
    table = COIL_WRITES if rule.table == "coils" else REGISTER_WRITES
    return fc in table and bool(overlap(start, count, rule.address, rule.words))


def judge(rule: TriggerRegister, shadow: TriggerShadow, req: Request) -> Verdict:
    """The verdict on ``req``, a write that :func:`writes_trigger`, after ``shadow``."""
    start = req.write_address or 0
    words = list(shadow.words)
    if rule.table == "coils":
        value = req.values[rule.address - start]
        mask = 1
    else:
        for offset in overlap(start, req.write_count, rule.address, rule.words):
            words[offset] = req.values[rule.address + offset - start]
        if rule.words == 1:
            value, mask = words[0], 0xFFFF
        else:
            value = unpack_int32(words, rule.order, signed=False)
            mask = 0xFFFFFFFF
    if rule.rising_bit is not None:
        # any write with the bit set may be the drive's edge: what the drive held before is
        # not relied on (a broadcast the drive refused, a write by another path leave it
        # other than the shadow), so its target is committed and its mode judged first
        fires = bool(value >> rule.rising_bit & 1)
    else:
        fires = rule.value is None or value == rule.value & mask
    homes = rule.home_value is not None and value == rule.home_value & mask
    relative = fires and rule.relative_bit is not None and bool(value >> rule.relative_bit & 1)
    return Verdict(fires, homes, TriggerShadow((words[0], words[1]), value), relative)
