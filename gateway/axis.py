"""Per-axis state the gateway keeps between transactions, and the word-level rules.

The master writes a 32-bit signed nominal target as one FC16, inside a longer FC16 block,
or as two FC06 in either order. The drive must only ever receive a whole, corrected value,
so the words are collected in a *shadow* (what the master wrote, returned on reads of the
target register) and the pair is committed when both halves have been written since the
last commit, or when a trigger write forces it (the other half then comes from the shadow).
No compensation math here: the router asks the chain.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from .compensation import MotionState
from .modbus.frames import WordOrder, unpack_int32


@dataclass
class AxisState:
    """What the gateway remembers of one axis; survives a config reload."""

    motion: MotionState
    shadow: list[int] = field(default_factory=lambda: [0, 0])
    shadow_known: bool = False
    halves_written: set[int] = field(default_factory=set)
    last_nominal_pulses: int | None = None
    last_command_units: int | None = None  # drive units (pulses × command_scale)
    #: the command (drive units) furthest along the nut's flank since it engaged there:
    #: a command sent back from it by less than a reversal leaves the table where that one
    #: put it (the motor turns inside the play), however many small steps it comes in
    flank_command_units: int | None = None
    enabled: bool = True
    #: whether the last committed target was corrected (False: sent as written, e.g.
    #: compensation off or drive not homed); feedback is inverted only when it was
    applied: bool = False

    def saved(self) -> dict[str, Any]:
        """What a restarted gateway needs to carry on (plain JSON values)."""
        return {
            "last_nominal_pulses": self.last_nominal_pulses,
            "last_command_units": self.last_command_units,
            "flank_command_units": self.flank_command_units,
            "direction": self.motion.direction,
            "engagement": self.motion.engagement,
            "last_target_pulses": self.motion.last_target_pulses,
            "shadow": list(self.shadow),
            "applied": self.applied,
        }

    def restore(self, saved: dict[str, Any]) -> None:
        """Take back :meth:`saved` (the caller checked the drive still holds that command).
        All or nothing: a bad entry raises (KeyError, TypeError, ValueError) and changes
        nothing."""
        nominal = int(saved["last_nominal_pulses"])
        command = int(saved["last_command_units"])
        last = saved["last_target_pulses"]
        if saved["direction"] not in (1, -1):
            raise ValueError(f"direction {saved['direction']!r} is not 1 or -1")
        engagement = float(saved.get("engagement", saved["direction"]))  # older: on a flank
        motion = MotionState(int(saved["direction"]), None if last is None else int(last),
                             engagement)  # fmt: skip
        shadow = [int(w) & 0xFFFF for w in saved["shadow"]]
        if len(shadow) != 2:
            raise ValueError(f"shadow {saved['shadow']!r} is not two words")
        applied = saved["applied"]
        if not isinstance(applied, bool):
            raise TypeError(f"applied {applied!r} is not true or false")
        flank = saved.get("flank_command_units")  # older files: on the last command
        flank = command if flank is None else int(flank)
        self.last_nominal_pulses, self.last_command_units = nominal, command
        self.flank_command_units = flank
        self.motion, self.shadow, self.applied = motion, shadow, applied
        self.shadow_known = True
        self.halves_written.clear()

    def write_words(self, offset: int, words: list[int]) -> None:
        """Record master writes of target words (offset 0 or 1 within the pair)."""
        for i, word in enumerate(words):
            self.shadow[offset + i] = word & 0xFFFF
            self.halves_written.add(offset + i)

    def pair_complete(self) -> bool:
        return self.halves_written >= {0, 1}

    def nominal_target(self, order: WordOrder) -> int:
        """The nominal target (pulses) the shadow holds now."""
        return unpack_int32(self.shadow, order)

    def committed(self, nominal_pulses: int, command_units: int,
                  motion: MotionState | None = None) -> None:  # fmt: skip
        """A corrected target (``command_units``, the drive's units) reached the drive;
        ``motion``: the axis's motion state there, as the correction found it (its chain's
        :meth:`~gateway.compensation.AxisChain.approach`; default: on the flank of the
        move's direction)."""
        new = self.motion.approach(nominal_pulses) if motion is None else motion
        flank = self.flank_command_units
        if (flank is None or new.direction != self.motion.direction
                or (command_units - flank) * new.direction >= 0):
            flank = command_units  # a new flank, or the motor pushes the nut further
        self.flank_command_units = flank
        self.motion = new
        self.last_nominal_pulses = nominal_pulses
        self.last_command_units = command_units
        self.shadow_known = True
        self.halves_written.clear()

    def flank_for(self, direction: int) -> int | None:
        """The command (drive units) a move in ``direction`` is measured from for a reversal:
        the flank's furthest while the nut stays on it, the last command once it turns."""
        if self.flank_command_units is None or direction != self.motion.direction:
            return self.last_command_units
        return self.flank_command_units

    def homing_started(self, home_direction: int) -> None:
        """The drive is homing: the next target is approached as the first after homing,
        and the drive is no longer at its last command."""
        self.motion = MotionState(home_direction)
        self.last_command_units = self.flank_command_units = None

    def reported_feedback(self, command_units: int, nominal_from_chain: float) -> int:
        """Nominal feedback (pulses) for the master, the drive being at ``command_units``.

        At rest on the last corrected target, report exactly the nominal target the master
        wrote, so "feedback == target" checks in the master hold despite whole-pulse
        rounding of the command; elsewhere (in motion), the chain's inverse, rounded.
        """
        if command_units == self.last_command_units and self.last_nominal_pulses is not None:
            return self.last_nominal_pulses
        return round(nominal_from_chain)


def overlap(start: int, count: int, base: int, width: int = 2) -> range:
    """Offsets (0..width-1) of the register pair at ``base`` covered by [start, start+count)."""
    lo = max(start, base)
    hi = min(start + count, base + width)
    return range(lo - base, hi - base) if lo < hi else range(0)
