"""No write path moves a drive where it was not told: the registers that decide a move (move
mode, block select, the trigger's relative bit) judged whatever function wrote them, end to
end over RTU-over-TCP (gateway → sim emulating each drive, sim/profiles.py).

The first three are the issue's cases: a mode set by a write of part of its field (Oriental
AZ's low word, Panasonic A6's top byte), and a Kinco distance written before a refused
relative start. On the code before the guard each ended in an incremental move by the
corrected target (AZ: 176511 → 226519) or a corrected distance in the drive.
"""

from __future__ import annotations

import struct
from pathlib import Path

from gateway.compensation import AxisInput
from gateway.modbus.frames import (
    build_write_multiple_registers,
    build_write_single_coil,
    build_write_single_register,
    pack_int32,
)
from tests.gateway_rig import rig
from tests.helpers_modbus import RawTcpMaster
from tests.test_gateway_e2e import PITCH_X, run
from tests.test_profiles import gateway_profile, sim_profile

AZ, A6, KINCO, LEADSHINE = ("oriental-az-direct", "panasonic-a6-block", "kinco-fd",
                            "leadshine-rs-pr0")


def mask_write(address: int, and_mask: int, or_mask: int) -> bytes:
    return struct.pack(">BHHH", 0x16, address, and_mask, or_mask)


def read_write(read_at: int, count: int, write_at: int, values: list[int]) -> bytes:
    return struct.pack(f">BHHHHB{len(values)}H", 0x17, read_at, count, write_at, len(values),
                       2 * len(values), *values)


def refused(reply: bytes) -> bool:
    return reply == bytes([reply[0] | 0x80, 0x03]) and bool(reply[0] & 0x80)


def ok(reply: bytes) -> bool:
    return not reply[0] & 0x80


def starts(drive) -> list[int]:
    return [e.started for e in drive.received if e.started is not None]


def corrected(chain, nominal: int) -> int:
    return chain.command_pulses("X", {"X": AxisInput(nominal, 1)})


def guarded(name: str, body) -> None:
    """Run ``body(master, drive, direct, chain)`` against a gateway with profile ``name``
    in front of a sim drive of that family on an RTU-over-TCP line."""

    async def outer(tmp_path: Path):
        async with rig(tmp_path, gateway_profile(name), {"x.csv": PITCH_X},
                       drives="rtu_over_tcp", sim_edit=sim_profile(name)) as r:
            master = await RawTcpMaster.connect(r["app"].tcp_port)
            try:
                drives = r["sim"].sim.drives
                drives["X"].y = drives["Y"]  # the other axis's drive, for a test to check
                await body(master, drives["X"], r["direct"], r["chain"])
            finally:
                await master.close()

    return outer


def az_block(target: int, operation: int | None = 1) -> tuple[int, list[int]]:
    """Oriental AZ direct data: (address, words) of the FC16 the issue sent: target 0x005C
    .. trigger 0x0067 (operation type left out), or from 0x005A with ``operation``."""
    tail = [*pack_int32(target, "hi_lo"), 0, 5000, 0, 10000, 0, 10000, 0, 1000, 0, 1]
    return (0x005C, tail) if operation is None else (0x005A, [0, operation, *tail])


def test_az_operation_type_set_by_its_low_word_is_refused(tmp_path: Path):
    async def body(master, drive, direct, chain):
        address, words = az_block(176_511)
        assert ok(await master.request(1, build_write_multiple_registers(address, words)))
        assert starts(drive) == [corrected(chain, 176_511)]
        # the case: FC06 of the low word alone asks for an incremental move
        assert refused(await master.request(1, build_write_single_register(0x005B, 2)))
        assert [drive._store[0x005A], drive._store[0x005B]] == [0, 1]
        address, words = az_block(50_000, operation=None)
        assert ok(await master.request(1, build_write_multiple_registers(address, words)))
        assert starts(drive) == [corrected(chain, 176_511), corrected(chain, 50_000)]
        # the drive's operation type set behind compgw's back before it ever saw it: read
        # from the drive at the start, and the start refused
        await direct.write_registers(0x005A, [0, 3], device_id=2)
        address, words = az_block(60_000, operation=None)
        reply = await master.request(2, build_write_multiple_registers(address, words))
        assert refused(reply) and drive.y.moves_started == 0

    run(guarded(AZ, body)(tmp_path))


def test_a6_block_command_set_by_its_top_byte_is_refused(tmp_path: Path):
    async def body(master, drive, direct, chain):
        # the case: FC06 0x4800 = 0x0100 (code 1, relative, in the top byte)
        assert refused(await master.request(1, build_write_single_register(0x4800, 0x0100)))
        assert not drive.received
        # the drive's own code unknown to compgw (never written through it): read first
        await direct.write_registers(0x4800, [0x0100, 0], device_id=1)
        assert ok(await master.request(1, build_write_multiple_registers(
            0x4802, list(pack_int32(300_000, "hi_lo")))))  # held: the start decides
        assert refused(await master.request(1, build_write_single_coil(0x0120, True)))
        assert drive.moves_started == 0
        assert all(e.address == 0x4800 for e in drive.received)  # direct: no target went
        assert ok(await master.request(1, build_write_single_register(0x4800, 0x0200)))
        assert ok(await master.request(1, build_write_single_coil(0x0120, True)))
        assert starts(drive) == [corrected(chain, 300_000)]
        # another block selected: its target was never corrected, the start is refused
        assert refused(await master.request(1, build_write_single_register(0x4414, 1)))
        await direct.write_register(0x4414, 1, device_id=2)
        await direct.write_registers(0x4800, [0x0200, 0], device_id=2)
        assert ok(await master.request(2, build_write_multiple_registers(
            0x4802, list(pack_int32(100_000, "hi_lo")))))
        assert refused(await master.request(2, build_write_single_coil(0x0120, True)))
        assert drive.y.moves_started == 0

    run(guarded(A6, body)(tmp_path))


def test_kinco_distance_before_a_refused_relative_start_never_reaches_the_drive(
        tmp_path: Path):  # fmt: skip
    async def body(master, drive, direct, chain):
        assert ok(await master.request(1, build_write_multiple_registers(
            0x4000, list(pack_int32(200_000, "lo_hi")))))
        for word in (0x2F, 0x3F):  # one absolute move first
            assert ok(await master.request(1, build_write_single_register(0x3100, word)))
        assert starts(drive) == [corrected(chain, 200_000)]
        seen = len(drive.received)
        # the case: a distance of 5000 written, then a relative start (0x4F → 0x5F)
        assert ok(await master.request(1, build_write_multiple_registers(
            0x4000, list(pack_int32(5000, "lo_hi")))))
        assert ok(await master.request(1, build_write_single_register(0x3100, 0x4F)))
        assert refused(await master.request(1, build_write_single_register(0x3100, 0x5F)))
        assert all(e.address == 0x3100 for e in list(drive.received)[seen:])  # no target went
        rr = await direct.read_holding_registers(0x4000, count=2, device_id=1)
        assert rr.registers == list(pack_int32(corrected(chain, 200_000), "lo_hi"))
        # the same edge by a mask write (FC22: bit 4 set, bit 6 cleared): absolute, moves
        assert ok(await master.request(1, build_write_multiple_registers(
            0x4000, list(pack_int32(300_000, "lo_hi")))))
        assert ok(await master.request(1, build_write_single_register(0x3100, 0x2F)))
        assert ok(await master.request(1, mask_write(0x3100, 0xFFFF & ~0x50, 0x10)))
        assert starts(drive) == [corrected(chain, 200_000), corrected(chain, 300_000)]
        # FC22 setting the relative bit with the edge: refused, the control word unchanged
        assert ok(await master.request(1, build_write_single_register(0x3100, 0x2F)))
        assert refused(await master.request(1, mask_write(0x3100, 0xFFFF & ~0x50, 0x50)))
        assert drive._store[0x3100] == 0x2F and len(starts(drive)) == 2
        # FC22 on a target word: refused (a position is written whole)
        assert refused(await master.request(1, mask_write(0x4000, 0xFF00, 0x0001)))

    run(guarded(KINCO, body)(tmp_path))


def test_mask_write_and_fc23_of_a_mode_are_judged_as_any_write(tmp_path: Path):
    async def body(master, drive, direct, chain):
        # FC22 turning AZ's operation type to 2 (incremental): refused, not forwarded
        assert ok(await master.request(1, build_write_multiple_registers(0x005A, [0, 1])))
        assert refused(await master.request(1, mask_write(0x005B, 0x0000, 0x0002)))
        # FC23 writing operation type 3 while reading the feedback: refused
        assert refused(await master.request(1, read_write(0x0122, 2, 0x005A, [0, 3])))
        assert [drive._store[0x005A], drive._store[0x005B]] == [0, 1]
        # FC23 writing the absolute type: forwarded, its read answered
        assert ok(await master.request(1, read_write(0x0122, 2, 0x005A, [0, 1])))
        # FC22 on a register that decides nothing: forwarded as it is
        assert ok(await master.request(1, mask_write(0x005E, 0x0000, 0x1234)))
        assert drive._store[0x005E] == 0x1234

    run(guarded(AZ, body)(tmp_path))


def test_leadshine_relative_pr_mode_is_refused(tmp_path: Path):
    async def body(master, drive, direct, chain):
        assert refused(await master.request(1, build_write_single_register(0x6200, 0x41)))
        block = [0x41, *pack_int32(100_000, "hi_lo"), 100, 100, 100, 0, 0x10]
        assert refused(await master.request(1, build_write_multiple_registers(0x6200, block)))
        assert not drive.received
        await direct.write_register(0x6200, 0x41, device_id=1)  # behind compgw's back
        assert ok(await master.request(1, build_write_multiple_registers(
            0x6201, list(pack_int32(100_000, "hi_lo")))))  # held: the start decides
        assert refused(await master.request(1, build_write_single_register(0x6002, 0x10)))
        assert drive.moves_started == 0
        assert ok(await master.request(1, build_write_single_register(0x6200, 0x01)))
        assert ok(await master.request(1, build_write_single_register(0x6002, 0x10)))
        assert starts(drive) == [corrected(chain, 100_000)]

    run(guarded(LEADSHINE, body)(tmp_path))


def test_broadcast_relative_start_and_mask_write_are_refused(tmp_path: Path):
    async def body(master, drive, direct, chain):
        assert ok(await master.request(1, build_write_multiple_registers(
            0x4000, list(pack_int32(250_000, "lo_hi")))))
        assert ok(await master.request(0, build_write_single_register(0x3100, 0x4F)))
        assert refused(await master.request(0, build_write_single_register(0x3100, 0x5F)))
        assert refused(await master.request(0, mask_write(0x3100, 0xFFAF, 0x0050)))
        assert drive.moves_started == 0
        assert ok(await master.request(0, build_write_single_register(0x3100, 0x2F)))
        assert ok(await master.request(0, build_write_single_register(0x3100, 0x3F)))
        assert starts(drive) == [corrected(chain, 250_000)]

    run(guarded(KINCO, body)(tmp_path))
