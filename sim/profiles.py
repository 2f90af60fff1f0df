"""How the simulated drives emulate three real drive families (``profile:`` in the sim).

Written from the drives' public documentation (see ../shared/DRIVES.md), independently of
the gateway's own profiles: the sim is the drive, the gateway's profile is what a user
configures; a shared mistake would otherwise go unnoticed. A profile gives a drive's
register layout, word order, trigger style, feedback units, FC16 limit, line-silence
requirement and EEPROM behaviour; an axis's ``registers`` keys override it one by one.
"""

from __future__ import annotations

import copy
from typing import Any

DRIVE_PROFILES: dict[str, dict[str, Any]] = {
    # Leadshine RS/PR: PR0 block 0x6200.. (mode, target hi, target lo, speed rpm, acc, dec,
    # dwell, trigger mirror), control word 0x6002 (0x10 + path runs it, 0x20 homes),
    # command position 0x602A/B high first, status 0x1003; writes stay in RAM unless saved.
    "leadshine-rs-pr0": {
        "target": {"address": 0x6201, "order": "hi_lo"},
        "feedback": {"address": 0x602A, "table": "holding", "order": "hi_lo"},
        "status": {"address": 0x1003, "alarm_bit": 0, "enabled_bit": 1, "moving_bit": 2,
                   "in_position_bit": 4, "homed_bit": 6},
        "trigger": {"address": 0x6002, "value": 0x10, "rising_bit": None, "home_value": 0x20},
        "speed": {"address": 0x6203, "scale_mm_s": 1.0},
        "memory": [{"address": 0x6200, "count": 8}, {"address": 0x1801, "count": 1}],
        "eeprom": {"counter": {"address": 0x7F00, "count": 2}, "ram_only": True},
    },
    # Inovance SV660P: segment 1 target H11-12 at 0x110C (low word first), speed 0x110E,
    # ramp 0x110F; virtual inputs H31.00 at 0x3100 (bit 4 mapped to position start: a rising
    # edge runs the segment); command position H0B.07 at 0x0B07, encoder position H0B.17 at
    # 0x0B11; status H30.01 at 0x3001 (bit 15 homing done); every bus write goes to EEPROM
    # unless H0C.13 (0x0C0D) = 0.
    "inovance-sv660p": {
        "target": {"address": 0x110C, "order": "lo_hi"},
        "feedback": {"address": 0x0B07, "table": "holding", "order": "lo_hi"},
        "status": {"address": 0x3001, "alarm_bit": 0, "enabled_bit": 1, "moving_bit": 2,
                   "in_position_bit": 3, "homed_bit": 15},
        "trigger": {"address": 0x3100, "value": None, "rising_bit": 4, "home_value": None},
        "speed": {"address": 0x110E, "scale_mm_s": 1.0},
        "memory": [{"address": 0x1100, "count": 12}, {"address": 0x110F, "count": 1},
                   {"address": 0x0C00, "count": 13}],
        "eeprom": {"counter": {"address": 0x7F00, "count": 2}, "ram_only": False,
                   "ram_only_param": {"address": 0x0C0D, "value": 0}},
    },
    # Delta ASDA PR: PR#1 definition P6-02 at 0x0604/5 and target P6-03 at 0x0606/7 (low
    # word at the base address), PR trigger P5-07 at 0x050E (write the PR number),
    # feedback P5-16 at 0x0520/1, status P0-46 at 0x005C; at most 10 words per FC10 and
    # 10 ms of line silence; bus writes go to EEPROM unless P2-30 (0x023C) = 5.
    "delta-asda-pr": {
        "target": {"address": 0x0606, "order": "lo_hi"},
        "feedback": {"address": 0x0520, "table": "holding", "order": "lo_hi"},
        "status": {"address": 0x005C, "alarm_bit": 0, "enabled_bit": 1, "moving_bit": 2,
                   "in_position_bit": 3, "homed_bit": None},
        "trigger": {"address": 0x050E, "value": 1, "rising_bit": None, "home_value": None},
        "speed": None,
        "memory": [{"address": 0x0600, "count": 6}, {"address": 0x0608, "count": 24},
                   {"address": 0x0200, "count": 60}],
        "eeprom": {"counter": {"address": 0x7F00, "count": 2}, "ram_only": False,
                   "ram_only_param": {"address": 0x023C, "value": 5}},
        "fc16_max_words": 10,
        "min_silence_s": 0.010,
    },
}


def profile_registers(name: str, overrides: dict[str, Any] | None) -> dict[str, Any]:
    """The register layout of profile ``name`` with the axis's own keys on top."""
    out = copy.deepcopy(DRIVE_PROFILES[name])
    for key, value in (overrides or {}).items():
        if isinstance(value, dict) and isinstance(out.get(key), dict):
            out[key] = {**out[key], **value}
        else:
            out[key] = copy.deepcopy(value)
    return out
