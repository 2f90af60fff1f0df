"""Exception replies exactly as the Modbus spec and the drive give them: the same request
to an axis unit through the gateway and straight to the simulated drive gets the same
bytes back, and a malformed or out-of-range request never reaches the drive."""

from __future__ import annotations

import asyncio
import struct
from pathlib import Path

import pytest

from gateway.modbus.frames import pack_int32
from tests.gateway_rig import TARGET, rig
from tests.helpers_modbus import mbap, read_mbap, run
from tests.test_gateway_e2e import read32

OVERFLOW = [  # address + quantity past 0xFFFF: 0x02 (illegal data address)
    struct.pack(">BHH", 3, 0xFFF6, 12),
    struct.pack(">BHH", 4, 0xFFF6, 12),
    struct.pack(">BHHB", 16, 0xFFFF, 2, 4) + b"\x00\x01\x00\x02",
    struct.pack(">BHHHHB", 23, 0xFFF6, 12, 0x6204, 1, 2) + b"\x00\x05",  # read part
    struct.pack(">BHHHHB", 23, 0x6204, 1, 0xFFFF, 2, 4) + b"\x00\x01\x00\x02",  # write part
]
MALFORMED = [  # wrong quantity, byte count or length: 0x03 (illegal data value)
    struct.pack(">BHH", 3, 0x6200, 0),
    struct.pack(">BHH", 3, 0x6200, 126),
    struct.pack(">BHH", 3, 0xFFF6, 0),  # the quantity is checked before the range
    struct.pack(">BHHH", 3, 0x602A, 2, 0),  # trailing bytes
    struct.pack(">BH", 6, 0x003C),  # FC06 without its value
    struct.pack(">BHHB", 16, TARGET, 2, 6) + bytes(6),
    struct.pack(">BHHB", 16, TARGET, 3, 4) + bytes(4),
    struct.pack(">BHHHHB", 23, 0x6204, 1, 0x6204, 1, 4) + bytes(4),
]
OTHER = [  # functions the gateway does not intercept: the drive's own answer (0x01 here)
    struct.pack(">BH", 5, 0x0010),  # short FC05
    struct.pack(">BHH", 5, 0x0010, 0xFF00),
    struct.pack(">B", 0x41),
]


async def raw(port: int, unit: int, pdu: bytes) -> bytes:
    reader, writer = await asyncio.open_connection("127.0.0.1", port)
    try:
        writer.write(mbap(0x0102, unit, pdu))
        tid, r_unit, reply = await read_mbap(reader)
        assert (tid, r_unit) == (0x0102, unit)
        return reply
    finally:
        writer.close()


@pytest.mark.parametrize("protect", [False, True], ids=["plain", "write-protected-unit"])
def test_exceptions_are_byte_identical_to_the_drive(tmp_path: Path, protect: bool) -> None:
    """Every case through the gateway (axis unit 1, whose drive is unit 1 of the sim) and
    straight to the drive: the same reply; nothing reached the drive through the gateway.
    With a ``write_protect`` entry on the unit's holding registers elsewhere, malformed
    writes still get the drive's code, and coil writes are not its business."""

    def edit(data: dict) -> None:
        if protect:
            data["write_protect"] = [{"unit": 1, "address": 0x7000, "count": 4}]

    async def body() -> None:
        async with rig(tmp_path, edit) as r:
            gw_port, sim_port = r["app"].tcp_port, r["sim"].tcp_port
            bus = r["app"].buses["line1"]
            target_before = await read32(r["direct"], 1, TARGET)
            for pdu in OVERFLOW + MALFORMED:
                sent = bus.counters.transactions
                expected = await raw(sim_port, 1, pdu)
                got = await raw(gw_port, 1, pdu)
                assert got == expected, f"{pdu.hex()}: gateway {got.hex()}, drive {expected.hex()}"
                want = 0x02 if pdu in OVERFLOW else 0x03
                assert got == bytes((pdu[0] | 0x80, want)), pdu.hex()
                assert bus.counters.transactions == sent, f"{pdu.hex()} reached the drive"
            for pdu in OTHER:
                expected = await raw(sim_port, 1, pdu)
                assert await raw(gw_port, 1, pdu) == expected == bytes((pdu[0] | 0x80, 1))
            assert await read32(r["direct"], 1, TARGET) == target_before
            # still serving, and a well-formed target write still lands
            rr = await r["master"].write_registers(TARGET, list(pack_int32(1000)), device_id=1)
            assert not rr.isError()

    run(body())


def test_pass_through_units_relay_the_drives_own_exceptions(tmp_path: Path) -> None:
    """A pass-through unit forwards every request as it is: the drive's replies, byte for
    byte (the sim's unit 20 is the laser: a register unit like any other)."""

    async def body() -> None:
        async with rig(tmp_path) as r:
            gw_port, sim_port = r["app"].tcp_port, r["sim"].tcp_port
            for pdu in OVERFLOW + MALFORMED + OTHER:
                assert await raw(gw_port, 20, pdu) == await raw(sim_port, 20, pdu), pdu.hex()

    run(body())
