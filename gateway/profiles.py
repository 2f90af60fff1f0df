"""Register profiles of real servo drives in position mode (see ../shared/DRIVES.md).

A profile is a set of axis defaults (``registers``, ``fc16_max_words``, ``min_silence_s``)
that an axis starts from with ``profile: NAME`` and overrides key by key. Each profile
says whether its map is verified (two agreeing public sources) and which manual section a
user must check, and how the drive keeps bus writes in RAM instead of EEPROM.

Every profile is an example to check against the drive's own manual, never gospel.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass, field
from typing import Any


@dataclass(frozen=True)
class Eeprom:
    """How a drive stores parameters written over the bus."""

    writes_eeprom_by_default: bool
    ram_setting: str  # what to set on the drive so that bus writes stay in RAM
    verified: bool = True


@dataclass(frozen=True)
class DriveProfile:
    name: str
    title: str
    verified: bool
    check: str  # the manual sections a user must check
    serial: str  # the drive's serial defaults (the user sets both ends)
    axis: dict[str, Any] = field(default_factory=dict)
    eeprom: Eeprom = field(default_factory=lambda: Eeprom(False, ""))
    notes: str = ""
    #: what the machine's own master must have done before compgw moves the drive itself
    #: (calibrate, commission write only the target and the start)
    before_moves: str = ""

    def defaults(self) -> dict[str, Any]:
        """A fresh copy of the axis defaults (to be overridden by the user's keys)."""
        return copy.deepcopy(self.axis)


PROFILES: dict[str, DriveProfile] = {
    p.name: p
    for p in (
        DriveProfile(
            name="leadshine-rs-pr0",
            title="Leadshine RS/PR family (EL7-RS, ELD2-RS, CS2RS, iCL-RS), PR path 0",
            verified=True,
            check="Modbus chapter: Pr9.xx PR0 block (0x6200..0x6207), Pr8.02 trigger "
            "(0x6002), command position 0x602A; status word 0x1003 bits (stepper manuals)",
            serial="model-dependent (38400 8N2, 38400 8N1 or 19200 8E1): set both ends",
            axis={
                "registers": {
                    "target": {"address": 0x6201, "words": 2, "order": "hi_lo"},
                    "feedback": {"address": 0x602A, "table": "holding", "order": "hi_lo",
                                 "counts_per_pulse": 1},
                    "status": {"address": 0x1003, "table": "holding", "homed_bit": 6,
                               "in_position_bit": 4, "moving_bit": 2, "alarm_bit": 0},
                    "trigger": {"address": 0x6002, "value": 0x10, "home_value": 0x20},
                    # PR0's mode word: 1 absolute, 0x41 relative (bit 6): refused
                    "mode": {"address": 0x6200, "words": 1, "absolute": 0, "mask": 0x40},
                },
                "fc16_max_words": 123,
                "min_silence_s": 0.0,
            },
            eeprom=Eeprom(
                writes_eeprom_by_default=False,
                ram_setting="none needed: writes stay in RAM unless saved (0x1801 = 0x2211)",
            ),
            before_moves=("PR mode with path 0 absolute (0x6200 = 1), the drive enabled"),
            notes="An 8-word FC16 at 0x6200 whose last word is 0x10 sets and starts a move "
            "(configure trigger address 0x6207 for that style). A relative PR0 (0x6200 bit 6, "
            "0x41) is refused (0x03). Reading 0x6002 back after a "
            "move is unreliable: completion comes from the status word or the position.",
        ),
        DriveProfile(
            name="inovance-sv660p",
            title="Inovance SV630P/SV660P (also IS620P), multi-segment position, segment 1",
            verified=False,
            check="H0C.09 virtual inputs on, H17 mapping of the position-start function to a "
            "virtual input bit, H11-12 segment 1 target (0x110C low word first), H0B.07 "
            "command position, H30.01 status (bit 15 homing done)",
            serial="unit 1, 57600 8N2",
            axis={
                "registers": {
                    "target": {"address": 0x110C, "words": 2, "order": "lo_hi"},
                    "feedback": {"address": 0x0B07, "table": "holding", "order": "lo_hi",
                                 "counts_per_pulse": 1},
                    "status": {"address": 0x3001, "table": "holding", "homed_bit": 15},
                    "trigger": {"address": 0x3100, "rising_bit": 4},
                },
                "fc16_max_words": 123,
                "min_silence_s": 0.0,
            },
            eeprom=Eeprom(
                writes_eeprom_by_default=True,
                ram_setting="H0C.13 = 0 (address 0x0C0D): bus writes to RAM only",
            ),
            before_moves=("servo on and the position-start function mapped to virtual input bit "
                          "4 (H0C.09 = 1, H17), segment 1 absolute"),
            notes="No trigger register: writing H31.00 (0x3100) with bit 4 going 0→1 (e.g. 1 "
            "= servo on, then 17) starts segment 1 once H17 maps it. For encoder feedback "
            "use H0B.17 (0x0B11) with counts_per_pulse = encoder counts per command pulse.",
        ),
        DriveProfile(
            name="delta-asda-pr",
            title="Delta ASDA-B2/A2/B3 (also SureServo2), PR mode, PR#1 (beta)",
            verified=False,
            check="P6-02/P6-03 PR#1 definition and target (0x0604..0x0607), P5-07 PR trigger "
            "(0x050E), P5-16 feedback units, P0-46 status bits, P2-30 (EEPROM)",
            serial="RTU 8N2; at most 10 words per FC10; ≥ 10 ms line silence",
            axis={
                "registers": {
                    "target": {"address": 0x0606, "words": 2, "order": "lo_hi"},
                    "feedback": {"address": 0x0520, "table": "holding", "order": "lo_hi",
                                 "counts_per_pulse": 1},
                    "trigger": {"address": 0x050E, "value": 1},
                },
                "fc16_max_words": 10,
                "min_silence_s": 0.010,
            },
            eeprom=Eeprom(
                writes_eeprom_by_default=True,
                ram_setting="P2-30 = 5 (address 0x023C): parameters written over the bus are "
                "not saved to EEPROM",
                verified=False,
            ),
            before_moves=("PR#1 defined as an absolute move (P6-02 at 0x0604), servo on"),
            notes="P5-07 reads 20000+PR# when the path is done. No homed bit is known: "
            "compensation is applied whenever enabled.",
        ),
        DriveProfile(
            name="oriental-az-direct",
            title="Oriental Motor AZ series (AZD-CD, AZD-CX; also AR-KD), direct data "
            "operation",
            verified=True,
            check="direct data operation block 0x0058..0x0067 (operation type 0x005A = 1 "
            "absolute, target 0x005C, trigger 0x0066), command position 0x0122, driver "
            "output status 0x007F (HOME-END bit in its default assignment), frame spacing",
            serial="8E1 by default (baud rate as set on the drive); unit 0 is broadcast",
            axis={
                "registers": {
                    "target": {"address": 0x005C, "words": 2, "order": "hi_lo"},
                    "feedback": {"address": 0x0122, "table": "holding", "order": "hi_lo",
                                 "counts_per_pulse": 1},
                    # any write of the 32-bit trigger field starts: 1 (all fields) and
                    # -1..-7 (one field updated) alike
                    "trigger": {"address": 0x0066, "words": 2, "order": "hi_lo"},
                    # operation type: 1 absolute (2, 3 incremental: refused)
                    "mode": {"address": 0x005A, "words": 2, "order": "hi_lo", "absolute": 1},
                },
                "fc16_max_words": 123,
                "min_silence_s": 0.005,
            },
            eeprom=Eeprom(
                writes_eeprom_by_default=False,
                ram_setting="none expected: direct data operation fields act at once and "
                "are not saved (check the manual's non-volatile memory section)",
                verified=False,
            ),
            before_moves=("the 16-register block at 0x0058 written once by your master: "
                          "operation type 1 (absolute), speed, rates, current"),
            notes="The master writes one FC16 of 16 registers at 0x0058 holding the target "
            "and the trigger: compgw corrects the target inside it and sends it as one "
            "write. Use operation type 1 (absolute): an incremental move (2, 3) is refused "
            "(0x03). Feedback position (encoder) is 0x0120. No homed bit "
            "by default: compensation is applied whenever enabled.",
        ),
        DriveProfile(
            name="panasonic-a6-block",
            title="Panasonic MINAS A6 over Modbus, block operation, block 0",
            verified=False,
            check="Pr5.37 = 2 and Pr6.28 = 1 (block operation over Modbus: EEPROM save and "
            "power cycle), block 0 command 0x4800 (code 2 = absolute in the top byte) and "
            "target 0x4802 (high word first), block number 0x4414 = 0, STB coil 0x0120, "
            "actual position 0x600F",
            serial="as set in Pr5.xx (set both ends)",
            axis={
                "registers": {
                    "target": {"address": 0x4802, "words": 2, "order": "hi_lo"},
                    "feedback": {"address": 0x600F, "table": "holding", "order": "hi_lo",
                                 "counts_per_pulse": 1},
                    "trigger": {"address": 0x0120, "table": "coils", "value": 1},
                    # block 0's command: code 2 absolute in the top byte (1 relative: refused)
                    "mode": {"address": 0x4800, "words": 2, "order": "hi_lo",
                             "absolute": 0x02000000, "mask": 0xFF000000},
                    # the block a start runs: block 0, whose target compgw corrects
                    "block_select": {"address": 0x4414, "value": 0},
                },
                "fc16_max_words": 123,
                "min_silence_s": 0.0,
            },
            eeprom=Eeprom(
                writes_eeprom_by_default=False,
                ram_setting="unknown: check whether block data written over Modbus stays "
                "in RAM",
                verified=False,
            ),
            before_moves=("block 0's command 2 (absolute) at 0x4800, block 0 selected (0x4414 = "
                          "0), servo on (SRV-ON)"),
            notes="The start is the coil STB (FC05 ON to 0x0120, or FC15 covering it): "
            "compgw writes the corrected target, then forwards the coil write. Only block 0 "
            "is corrected (0x4414 = 0; a start with another block selected is refused; for "
            "block n set target to 0x4802 + 4n and block_select.value to n). "
            "Homed (HOME-CMP) is a coil, which compgw does not read: compensation is applied "
            "whenever enabled.",
        ),
        DriveProfile(
            name="kinco-fd",
            title="Kinco FD / CD / FD5P servo drives, profile position mode",
            verified=False,
            check="operating mode 0x3500 = 1, target position 0x4000 (low word first), "
            "control word 0x3100 (0x2F -> 0x3F starts an absolute move), actual position "
            "0x3700, status word 0x3200 (one source says 0x3000) bit 15 home found",
            serial="as set on the drive (some series need a save and restart for it)",
            axis={
                "registers": {
                    "target": {"address": 0x4000, "words": 2, "order": "lo_hi"},
                    "feedback": {"address": 0x3700, "table": "holding", "order": "lo_hi",
                                 "counts_per_pulse": 1},
                    # bit 10 target reached, bit 3 fault (CiA 402); no "moving" bit
                    "status": {"address": 0x3200, "table": "holding", "homed_bit": 15,
                               "in_position_bit": 10, "alarm_bit": 3},
                    "trigger": {"address": 0x3100, "rising_bit": 4, "relative_bit": 6},
                },
                "fc16_max_words": 123,
                "min_silence_s": 0.0,
            },
            eeprom=Eeprom(
                writes_eeprom_by_default=False,
                ram_setting="none expected: objects are saved only by the drive's store "
                "command",
                verified=False,
            ),
            before_moves=("profile position mode (0x3500 = 1) and the drive switched on "
                          "(control word 0x3100 = 0x2F)"),
            notes="The start is a 0->1 edge of the control word's new-set-point bit 4 "
            "(0x2F -> 0x3F): compgw commits the corrected target before forwarding it. Use "
            "absolute moves: a relative one (0x4F -> 0x5F) is refused (0x03).",
        ),
    )
}


def profile_names() -> str:
    return ", ".join(PROFILES)


def merge_defaults(defaults: dict[str, Any], overrides: dict[str, Any]) -> dict[str, Any]:
    """``overrides`` on top of ``defaults``, key by key, recursively (new dicts)."""
    out = copy.deepcopy(defaults)
    for key, value in overrides.items():
        if isinstance(value, dict) and isinstance(out.get(key), dict):
            out[key] = merge_defaults(out[key], value)
        else:
            out[key] = copy.deepcopy(value)
    return out
