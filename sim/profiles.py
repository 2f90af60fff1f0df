"""How the simulated drives emulate real drive families (``profile:`` in the sim).

Written from the drives' public documentation (see ../shared/DRIVES.md), independently of
the gateway's own profiles: the sim is the drive, the gateway's profile is what a user
configures; a shared mistake would otherwise go unnoticed. A profile gives a drive's
register layout, word order, trigger style, feedback units, FC16 limit, line-silence
requirement and EEPROM behaviour; an axis's ``registers`` keys override it one by one.

Trigger styles (``trigger.style``; the rules are in :class:`sim.drive.Drive`):

- ``plain``: a write of ``value`` (any write without one) or a 0->1 edge of ``rising_bit``
  starts a move to the target register; ``home_value`` homes;
- ``leadshine-pr`` (Leadshine RS/PR): as ``plain``, but the move runs PR0 as its mode word
  at :data:`LEADSHINE_PR0_MODE` says: 0x41 (bit 6) relative to the command position, 1
  absolute;
- ``oriental-direct`` (Oriental Motor AZ direct data operation): the 32-bit trigger field
  (``words: 2``, high word first) written non-zero (1: all fields, -1..-7: one field
  updated) executes at once with the operation type at :data:`AZ_OPERATION_TYPE`
  (1 absolute, 2 incremental from the command position, 3 from the feedback position);
  target, type and trigger usually arrive in one FC16 of 16 registers at 0x0058;
- ``panasonic-block`` (Panasonic MINAS A6 block operation): the STB coil (``table:
  coils``) switched on starts block n = register :data:`A6_BLOCK_SELECT`: command at
  0x4800 + 4n (code in the top byte: 1 relative, 2 absolute, 4 homing, 5 stop), target
  at 0x4802 + 4n, both 32-bit high word first; STB clears itself; other coils in
  :data:`A6_COILS`;
- ``kinco-control`` (Kinco FD, CiA 402 control word): a 0->1 edge of ``rising_bit`` (bit
  4, new set point) while bits 0-3 are set (operation enabled) starts an absolute move
  (0x2F -> 0x3F), or a relative one when bit 6 is set (0x4F -> 0x5F).
"""

from __future__ import annotations

import copy
from typing import Any

TRIGGER_STYLES = ("plain", "leadshine-pr", "oriental-direct", "panasonic-block",
                  "kinco-control")

#: Leadshine PR0's mode word (Pr9.00): bit 6 set (0x41) a move relative to the command
#: position, otherwise (1) absolute
LEADSHINE_PR0_MODE = 0x6200
LEADSHINE_RELATIVE_BIT = 6

#: Oriental AZ direct data operation: the operation type field (32-bit, high word first)
AZ_OPERATION_TYPE = 0x005A
#: Panasonic A6 block operation: the block number register, the block table and stride
A6_BLOCK_SELECT = 0x4414
A6_BLOCK_TABLE = 0x4800
A6_BLOCK_STRIDE = 4
#: Panasonic A6 coils besides STB: name -> address (BUSY, HOME-CMP, COIN read-only)
A6_COILS = {"SRV-ON": 0x0060, "A-CLR": 0x0061, "COIN": 0x00A0, "BUSY": 0x0140,
            "HOME-CMP": 0x0141}
#: Kinco control word: bits that must be set for a start (switch on, enable voltage,
#: quick stop off, enable operation) and the relative bit (the new-set-point bit is the
#: trigger's ``rising_bit``)
KINCO_ENABLED_MASK = 0x000F
KINCO_RELATIVE_BIT = 6

DRIVE_PROFILES: dict[str, dict[str, Any]] = {
    # Leadshine RS/PR: PR0 block 0x6200.. (mode, target hi, target lo, speed rpm, acc, dec,
    # dwell, trigger mirror), control word 0x6002 (0x10 + path runs it, 0x20 homes),
    # command position 0x602A/B high first, status 0x1003; writes stay in RAM unless saved.
    "leadshine-rs-pr0": {
        "target": {"address": 0x6201, "order": "hi_lo"},
        "feedback": {"address": 0x602A, "table": "holding", "order": "hi_lo"},
        "status": {"address": 0x1003, "alarm_bit": 0, "enabled_bit": 1, "moving_bit": 2,
                   "in_position_bit": 4, "homed_bit": 6},
        "trigger": {"address": 0x6002, "value": 0x10, "rising_bit": None, "home_value": 0x20,
                    "style": "leadshine-pr"},
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
    # Oriental Motor AZ, direct data operation: one FC16 of 16 registers at 0x0058 (data No.,
    # operation type 0x005A, target 0x005C, speed 0x005E in Hz, accel, decel, current,
    # trigger 0x0066), each field 32-bit high word first; 0x0068 forwarding destination;
    # command position 0x0122/3; driver output status 0x007F (HOME-END 4, READY 5, ALM-A 7,
    # MOVE 13, IN-POS 14). Frames closer than 3 ms after the last one are not seen (public
    # drivers keep 3-5 ms). Direct data is not saved.
    "oriental-az-direct": {
        "target": {"address": 0x005C, "order": "hi_lo"},
        "feedback": {"address": 0x0122, "table": "holding", "order": "hi_lo"},
        "status": {"address": 0x007F, "alarm_bit": 7, "enabled_bit": 5, "moving_bit": 13,
                   "in_position_bit": 14, "homed_bit": 4},
        "trigger": {"address": 0x0066, "words": 2, "value": None, "rising_bit": None,
                    "home_value": None, "style": "oriental-direct"},
        "speed": None,
        "memory": [{"address": 0x0058, "count": 18}, {"address": 0x007C, "count": 2}],
        "eeprom": {"counter": {"address": 0x7F00, "count": 2}, "ram_only": True},
        "min_silence_s": 0.003,
    },
    # Panasonic MINAS A6, block operation over Modbus: block table at 0x4800 + 4n (command,
    # target; 32-bit high word first), block number 0x4414, STB coil 0x0120 starts it;
    # actual position 0x600F/0x6010, error code 0x6001. Its state is in coils (BUSY 0x0140,
    # HOME-CMP 0x0141, COIN 0x00A0): the status word at 0x7F10 is the sim's own (the real
    # drive has none there).
    "panasonic-a6-block": {
        "target": {"address": 0x4802, "order": "hi_lo"},
        "feedback": {"address": 0x600F, "table": "holding", "order": "hi_lo"},
        "status": {"address": 0x7F10, "alarm_bit": 0, "enabled_bit": 1, "moving_bit": 2,
                   "in_position_bit": 3, "homed_bit": 4},
        "trigger": {"address": 0x0120, "table": "coils", "value": 1, "rising_bit": None,
                    "home_value": None, "style": "panasonic-block"},
        "speed": None,
        "memory": [{"address": 0x4800, "count": 64}, {"address": 0x4414, "count": 1},
                   {"address": 0x6001, "count": 1}],
        "eeprom": {"counter": {"address": 0x7F00, "count": 2}, "ram_only": True},
    },
    # Kinco FD (CANopen objects on Modbus): control word 0x3100 (6040h), status word 0x3200
    # (6041h: bit 3 fault, bit 2 operation enabled, bit 10 target reached, bit 15 home
    # found), operating mode 0x3500, target 0x4000 (607Ah), actual position 0x3700, profile
    # speed 0x4A00; 32-bit values low word first.
    "kinco-fd": {
        "target": {"address": 0x4000, "order": "lo_hi"},
        "feedback": {"address": 0x3700, "table": "holding", "order": "lo_hi"},
        "status": {"address": 0x3200, "alarm_bit": 3, "enabled_bit": 2, "moving_bit": None,
                   "in_position_bit": 10, "homed_bit": 15},
        "trigger": {"address": 0x3100, "value": None, "rising_bit": 4, "home_value": None,
                    "style": "kinco-control"},
        "speed": None,
        "memory": [{"address": 0x3500, "count": 1}, {"address": 0x4A00, "count": 2}],
        "eeprom": {"counter": {"address": 0x7F00, "count": 2}, "ram_only": True},
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
