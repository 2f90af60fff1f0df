"""The registers of an axis's drive: where its target, feedback, status, trigger, move mode
and block select are, and how a move is started (``axes.NAME.registers``). A config section
of its own: what the gateway intercepts, and why a start is refused
(:mod:`gateway.drive_model`, :mod:`gateway.triggers`)."""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import Field, model_validator

from .config_types import Address, Bit, Positive, WordOrder, in_range, path_error
from .config_types import StrictModel as Model


class TargetRegister(Model):
    """The 32-bit signed position target (holding registers)."""

    address: Address
    words: Literal[2] = 2
    order: WordOrder = "hi_lo"


class FeedbackRegister(Model):
    """The 32-bit signed position feedback.

    ``counts_per_pulse``: counts per drive command unit (1 when the register counts command
    units, else the encoder counts per unit). ``upstream_counts_per_pulse``: counts per
    upper-computer pulse as the master expects to read them (default ``counts_per_pulse``;
    required when the axis has ``command_scale`` > 1).
    """

    address: Address
    table: Literal["holding", "input"] = "holding"
    words: Literal[2] = 2
    order: WordOrder = "hi_lo"
    counts_per_pulse: Positive = 1.0
    upstream_counts_per_pulse: Positive | None = None


class StatusRegister(Model):
    """The drive's status word. ``homed_bit``: compensation only while it is set.
    ``max_age_s``: how old a status word (seen in the master's polls or read by compgw)
    may be to decide "homed" at a target write; older, compgw reads it first (one more
    drive transaction per move when the master does not poll the status).

    ``in_position_bit``, ``moving_bit``, ``alarm_bit``: how compgw's own moves (calibrate,
    commission) see a move end or a fault; the gateway does not use them. Given any of
    them, the others unset mean the drive has no such bit; none given: bits 4, 2 and 0
    (Leadshine's status word) without a ``profile``, the feedback alone with one whose
    bits are not known."""

    address: Address
    table: Literal["holding", "input"] = "holding"
    homed_bit: Bit | None = None
    max_age_s: float = Field(default=0.5, ge=0.0, le=60.0)
    in_position_bit: Bit | None = None
    moving_bit: Bit | None = None
    alarm_bit: Bit | None = None


class TriggerRegister(Model):
    """What starts a move: any write (no value), a write of ``value``, or ``rising_bit``.

    ``table: holding`` (default): a holding register written by FC06/FC16 (and the words of
    FC16 blocks around it); ``words: 2`` a 32-bit trigger field (``order``; ``value`` then
    compares the 32-bit value; a write of either word counts). ``table: coils``: a coil
    written by FC05 or FC15 (``value`` 1: switched on, 0: off; none: any write).

    ``home_value``: a write of this value starts the drive's homing; the gateway forwards
    it and then takes the next move as the first after homing (``home_direction``), since
    the axis no longer stands at its last target.

    ``relative_bit``: a start with this bit of the trigger word set is a relative move (a
    distance, not a position: Kinco's 0x4F → 0x5F): refused with exception 0x03, since a
    correction added to a distance lands nowhere meant.
    """

    address: Address
    table: Literal["holding", "coils"] = "holding"
    words: Literal[1, 2] = 1
    order: WordOrder = "hi_lo"
    value: Annotated[int, in_range(-(2**31), 2**32 - 1)] | None = None
    rising_bit: Bit | None = None
    home_value: Annotated[int, in_range(-(2**31), 2**32 - 1)] | None = None
    relative_bit: Bit | None = None

    @model_validator(mode="after")
    def _one_rule(self) -> TriggerRegister:
        if self.value is not None and self.rising_bit is not None:
            raise ValueError("give value or rising_bit, not both")
        if (self.home_value is not None and self.value is not None
                and self.home_value & 0xFFFFFFFF == self.value & 0xFFFFFFFF):
            raise ValueError(f"home_value {self.home_value} is also the move value")
        if self.table == "coils":
            if self.words != 1 or self.rising_bit is not None:
                raise ValueError("a coil trigger has no words or rising_bit (value 1: on)")
            top, what = 1, "a coil"
        elif self.words == 2:
            if self.rising_bit is not None:
                raise ValueError("rising_bit needs words: 1 (one 16-bit register)")
            if self.address == 0xFFFF:
                raise path_error(("address",), self.address, "+ 2 words runs past 0xFFFF")
            return self
        else:
            top, what = 0xFFFF, "a one-register trigger"
        for key in ("value", "home_value"):
            got = getattr(self, key)
            if got is not None and not 0 <= got <= top:
                raise path_error((key,), got, f"is not in 0..{top} ({what})")
        return self

    @property
    def span(self) -> range:
        """The registers (or the coil) it occupies."""
        return range(self.address, self.address + self.words)


class ModeRegister(Model):
    """Where a drive is told whether a move is absolute or relative (Leadshine's PR mode,
    Oriental AZ's operation type, Panasonic A6's block command code). compgw corrects
    positions: a correction added to a distance lands nowhere meant. So a write (any
    function code, the whole field or one word of it) that would leave the field, under
    ``mask``, at anything but ``absolute`` is refused with exception 0x03 and not forwarded,
    and a start while the drive's field is not ``absolute`` is refused too; a word compgw
    has not seen written is read from the drive first, never guessed."""

    address: Address
    words: Literal[1, 2] = 2
    order: WordOrder = "hi_lo"
    absolute: Annotated[int, in_range(0, 2**32 - 1)]
    mask: Annotated[int, in_range(1, 2**32 - 1)] = 0xFFFFFFFF


class BlockSelectRegister(Model):
    """Which stored block a start runs (Panasonic A6's block number, 0x4414): compgw
    corrects the block whose target is ``target``, so a start while this register holds
    anything but ``value`` is refused with exception 0x03 (the drive would run a block
    whose target compgw never corrected), and so is a write that sets another value."""

    address: Address
    value: Annotated[int, in_range(0, 0xFFFF)] = 0


class Registers(Model):
    target: TargetRegister
    feedback: FeedbackRegister
    status: StatusRegister | None = None
    trigger: TriggerRegister | None = None
    mode: ModeRegister | None = None
    block_select: BlockSelectRegister | None = None

    @model_validator(mode="after")
    def _no_overlap(self) -> Registers:
        t = self.target.address
        f = self.feedback.address
        if self.feedback.table == "holding" and abs(t - f) < 2:
            raise ValueError(f"target {t} and feedback {f} registers overlap")
        trigger = self.trigger
        if trigger is not None and trigger.table == "holding" and set(trigger.span) & {t, t + 1}:
            raise ValueError(f"trigger {trigger.address} overlaps the target pair")
        return self
