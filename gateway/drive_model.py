"""What a drive will do when a move starts: the registers besides the target that decide it.

A start (the trigger, :mod:`gateway.triggers`) moves the drive to its target register *as
the drive's latched fields read it*: a move mode (absolute or a distance: Leadshine's PR
mode, Oriental AZ's operation type, Panasonic A6's block command code) and a block select
(A6: which block's target runs). compgw corrects positions of one block; so a start is
forwarded only while every latched field holds what makes it that (:class:`LatchedField`,
``expected`` under ``mask``). The gateway keeps a shadow of those fields' words, whatever
function wrote them, and reads a word it has not seen from the drive before judging;
nothing here is guessed.

Pure functions and small immutable objects over plain ints; the router does the I/O
(:mod:`gateway.axis_writes`).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass

from .axis import overlap
from .config_registers import Registers
from .modbus.frames import WordOrder, unpack_int32


@dataclass(frozen=True)
class LatchedField:
    """A register field whose value (under ``mask``) must be ``expected`` for a start to
    go where compgw corrected it; ``what`` names it in messages."""

    what: str
    address: int
    words: int
    order: WordOrder
    expected: int
    mask: int
    hint: str

    @property
    def span(self) -> range:
        return range(self.address, self.address + self.words)

    def needed(self) -> tuple[int, ...]:
        """The addresses whose words carry bits under ``mask`` (the others never matter)."""
        if self.words == 1:
            return (self.address,)
        high_first = self.order == "hi_lo"
        out = []
        for offset in range(2):
            high = (offset == 0) == high_first
            if self.mask & (0xFFFF0000 if high else 0x0000FFFF):
                out.append(self.address + offset)
        return tuple(out)

    def value(self, words: Mapping[int, int]) -> int | None:
        """The field's value under ``mask`` from ``words`` (address → word); None when a
        word that matters is not in it. Words that do not matter read as 0."""
        if any(a not in words for a in self.needed()):
            return None
        if self.words == 1:
            return words[self.address] & self.mask
        pair = [words.get(self.address, 0), words.get(self.address + 1, 0)]
        return unpack_int32(pair, self.order, signed=False) & self.mask

    def holds(self, value: int) -> bool:
        return value & self.mask == self.expected & self.mask

    def refusal(self, axis: str, value: int, when: str) -> str:
        """The one-line reason a write or start is refused (exception 0x03)."""
        return (f"axis {axis}: {when} refused: {self.what} at {self.address:#06x} reads "
                f"{value:#x}{_under(self.mask, self.words)}, not {self.expected:#x}; "
                f"{self.hint}")


def _under(mask: int, words: int) -> str:
    full = 0xFFFF if words == 1 else 0xFFFFFFFF
    return "" if mask & full == full else f" under mask {mask:#x}"


def latched_fields(regs: Registers) -> tuple[LatchedField, ...]:
    """The fields of an axis's registers that decide what a start does."""
    out = []
    if regs.mode is not None:
        m = regs.mode
        out.append(LatchedField("move mode", m.address, m.words, m.order, m.absolute, m.mask,
                                "compgw corrects positions, not distances: use absolute "
                                f"moves ({m.absolute:#x})"))  # fmt: skip
    if regs.block_select is not None:
        b = regs.block_select
        out.append(LatchedField("block select", b.address, 1, "hi_lo", b.value, 0xFFFF,
                                f"compgw corrects block {b.value} only (its target at "
                                f"{regs.target.address:#06x}): select it"))  # fmt: skip
    return tuple(out)


def touched(fields: Iterable[LatchedField], start: int, count: int) -> list[LatchedField]:
    """The fields a register write of ``count`` words at ``start`` writes (part of)."""
    return [f for f in fields if overlap(start, count, f.address, f.words)]


def written_words(fields: Iterable[LatchedField], start: int,
                  values: Iterable[int]) -> dict[int, int]:  # fmt: skip
    """The words of ``fields`` a register write of ``values`` at ``start`` sets."""
    spans = {a for f in fields for a in f.span}
    return {start + i: v & 0xFFFF for i, v in enumerate(values) if start + i in spans}


def missing(fields: Iterable[LatchedField], words: Mapping[int, int]) -> list[int]:
    """Addresses of words that matter to ``fields`` and are not known in ``words``."""
    return sorted({a for f in fields for a in f.needed() if a not in words})


def first_refusal(fields: Iterable[LatchedField], words: Mapping[int, int], axis: str,
                  when: str) -> str | None:  # fmt: skip
    """Why a write or start must be refused given the fields' ``words``; None when every
    field holds its expected value. A field whose words are not all known is a refusal
    too (the caller reads them first: "never guessed")."""
    for f in fields:
        value = f.value(words)
        if value is None:
            return (f"axis {axis}: {when} refused: {f.what} at {f.address:#06x} is not known "
                    "(the drive did not answer its read): write it first")
        if not f.holds(value):
            return f.refusal(axis, value, when)
    return None


def mask_write(current: int, and_mask: int, or_mask: int) -> int:
    """The register after a Modbus mask write (FC22) of ``current``: the spec's
    (current AND and_mask) OR (or_mask AND NOT and_mask)."""
    return (current & and_mask | or_mask & ~and_mask) & 0xFFFF
