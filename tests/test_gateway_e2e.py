"""End to end: an upper computer → the gateway → the simulated drives (TCP → TCP)."""

from __future__ import annotations

import asyncio
import logging
import math
import re
import shutil
import socket
import struct
from pathlib import Path

import pytest

from gateway.compensation import AxisInput
from gateway.modbus.frames import pack_int32, unpack_int32
from tests.gateway_rig import FEEDBACK, SPEED, TARGET, TRIGGER, rig

PITCH_X = "position_mm,error_um\n0,0\n200,12\n400,20\n600,8\n800,-15\n"


def run(coro, timeout_s: float = 30.0):
    return asyncio.run(asyncio.wait_for(coro, timeout_s))


def with_pitch(data):
    data["axes"]["X"]["compensation"]["pitch"] = "x.csv"
    data["axes"]["Y"]["compensation"]["backlash_mm"] = 0.01


async def read32(client, unit: int, address: int, order: str = "hi_lo") -> int:
    rr = await client.read_holding_registers(address, count=2, device_id=unit)
    assert not rr.isError(), rr
    return unpack_int32(rr.registers, order)


async def write_target(client, unit: int, pulses: int) -> None:
    rr = await client.write_registers(TARGET, list(pack_int32(pulses)), device_id=unit)
    assert not rr.isError(), rr


async def move(client, unit: int, pulses: int) -> None:
    await write_target(client, unit, pulses)
    assert not (await client.write_register(TRIGGER, 0x10, device_id=unit)).isError()


def test_corrected_target_reaches_the_drive_and_nominal_comes_back(tmp_path: Path):
    async def body():
        async with rig(tmp_path, with_pitch, {"x.csv": PITCH_X}) as r:
            master, direct, chain = r["master"], r["direct"], r["chain"]
            await move(master, 1, 300_000)
            expected = chain.command_pulses("X", {"X": AxisInput(300_000, 1)})
            # table: +16 µm deviation at 300 mm → the drive is sent about 16 pulses less
            assert expected == pytest.approx(300_000 - 16, abs=1)
            assert await read32(direct, 1, TARGET) == expected
            assert await read32(master, 1, TARGET) == 300_000  # the shadow
            assert await read32(direct, 1, FEEDBACK) == expected  # drive at the command
            assert await read32(master, 1, FEEDBACK) == 300_000  # reported nominal
            # the other axis: backlash only, direction from successive targets
            await move(master, 2, 100_000)
            assert await read32(direct, 2, TARGET) == 100_005  # +B/2 moving +
            await move(master, 2, 50_000)
            assert await read32(direct, 2, TARGET) == 49_995  # −B/2 moving −
            assert await read32(master, 2, FEEDBACK) == 50_000

    run(body())


def test_split_writes_in_either_order_are_atomic(tmp_path: Path):
    async def body():
        async with rig(tmp_path, with_pitch, {"x.csv": PITCH_X}) as r:
            master, direct, chain = r["master"], r["direct"], r["chain"]
            before = await read32(direct, 1, TARGET)
            for nominal, order in ((700_123, (0, 1)), (-5, (1, 0)), (65_536 * 3 + 7, (1, 0))):
                if nominal < 0:
                    continue  # outside travel: covered by the error test
                words = pack_int32(nominal)
                first, second = order
                rq = await master.write_register(TARGET + first, words[first], device_id=1)
                assert not rq.isError()
                assert await read32(direct, 1, TARGET) == before  # nothing half written
                rq = await master.write_register(TARGET + second, words[second], device_id=1)
                assert not rq.isError()
                direction = 1 if nominal > 0 else -1
                expected = chain.command_pulses("X", {"X": AxisInput(nominal, direction)})
                before = await read32(direct, 1, TARGET)
                assert abs(before - expected) <= 1
                assert await read32(master, 1, TARGET) == nominal

    run(body())


def test_block_write_with_the_target_inside_is_rewritten_whole(tmp_path: Path):
    async def body():
        async with rig(tmp_path, with_pitch, {"x.csv": PITCH_X}) as r:
            master, direct, chain = r["master"], r["direct"], r["chain"]
            block = [1, *pack_int32(400_000), 100, 0, 0, 0]  # 0x6200..0x6206
            assert not (await master.write_registers(0x6200, block, device_id=1)).isError()
            rr = await direct.read_holding_registers(0x6200, count=7, device_id=1)
            expected = chain.command_pulses("X", {"X": AxisInput(400_000, 1)})
            assert rr.registers[0] == 1 and rr.registers[3:] == [100, 0, 0, 0]
            assert unpack_int32(rr.registers[1:3], "hi_lo") == expected
            rr = await master.read_holding_registers(0x6200, count=7, device_id=1)
            assert rr.registers == block

    run(body())


def test_pass_through_is_byte_exact(tmp_path: Path):
    async def body():
        async with rig(tmp_path, with_pitch, {"x.csv": PITCH_X}) as r:
            master, direct = r["master"], r["direct"]
            assert not (await master.write_register(SPEED, 77, device_id=1)).isError()
            via = await master.read_holding_registers(0x6200, count=1, device_id=1)
            raw = await direct.read_holding_registers(0x6200, count=1, device_id=1)
            assert via.registers == raw.registers
            rr = await direct.read_holding_registers(SPEED, count=1, device_id=1)
            assert rr.registers == [77]
            # a pass-through unit (the laser: its noise differs from read to read)
            via = await master.read_input_registers(0, count=2, device_id=20)
            raw = await direct.read_input_registers(0, count=2, device_id=20)
            gap_nm = unpack_int32(via.registers, "hi_lo") - unpack_int32(raw.registers, "hi_lo")
            assert abs(gap_nm) < 500
            # an unmapped drive register: the drive's exception relayed as it is
            via = await master.read_holding_registers(0x0100, count=1, device_id=1)
            raw = await direct.read_holding_registers(0x0100, count=1, device_id=1)
            assert via.isError() and raw.isError()
            assert via.exception_code == raw.exception_code == 0x02

    run(body())


def test_error_cases_return_their_codes(tmp_path: Path):
    async def body():
        async with rig(tmp_path, with_pitch, {"x.csv": PITCH_X}) as r:
            master, direct = r["master"], r["direct"]
            before = await read32(direct, 1, TARGET)
            rr = await master.write_registers(TARGET, list(pack_int32(800_001)), device_id=1)
            assert rr.isError() and rr.exception_code == 0x03  # outside travel
            assert await read32(direct, 1, TARGET) == before  # nothing forwarded
            rr = await master.read_holding_registers(0, count=1, device_id=99)
            assert rr.isError() and rr.exception_code == 0x0A  # not routed
            # drive silent → 0x0B (bus timeout 0.2 s, no retries)
            assert not (await direct.write_registers(1 * 8, [1], device_id=250)).isError()
            rr = await master.read_holding_registers(FEEDBACK, count=2, device_id=1)
            assert rr.isError() and rr.exception_code == 0x0B
            assert not (await direct.write_register(0x0804, 1, device_id=250)).isError()
            rr = await master.read_holding_registers(FEEDBACK, count=2, device_id=1)
            assert not rr.isError()

    run(body())


@pytest.mark.parametrize(
    "pdu",
    [
        # FC16 at the target: count 2 but 6 data bytes (a lenient drive could write them raw)
        struct.pack(">BHHB", 16, TARGET, 2, 6) + struct.pack(">hhh", 4, -27680, 0),
        struct.pack(">BHHB", 16, TARGET, 2, 4) + struct.pack(">hh", 4, -27680) + b"\x00",
        struct.pack(">BHHB", 16, TARGET, 3, 4) + struct.pack(">hh", 4, -27680),
        struct.pack(">BH", 6, TARGET),  # FC06 without its value
        struct.pack(">BHHH", 3, FEEDBACK, 2, 0),  # a read with trailing bytes
    ],
    ids=["fc16-byte-count", "fc16-trailing", "fc16-count", "fc06-short", "fc03-trailing"],
)
def test_malformed_requests_to_an_axis_are_refused_never_forwarded(tmp_path: Path, pdu: bytes):
    """A malformed PDU to an axis unit is answered 0x03 by the gateway: a drive that
    parsed it leniently could write an uncorrected target."""

    async def body():
        async with rig(tmp_path, with_pitch, {"x.csv": PITCH_X}) as r:
            master, direct = r["master"], r["direct"]
            before = await read32(direct, 1, TARGET)
            host, port = "127.0.0.1", r["app"].tcp_port
            reader, writer = await asyncio.open_connection(host, port)
            writer.write(struct.pack(">HHHB", 7, 0, len(pdu) + 1, 1) + pdu)
            header = await reader.readexactly(7)
            tid, _, length, unit = struct.unpack(">HHHB", header)
            reply = await reader.readexactly(length - 1)
            writer.close()
            assert (tid, unit) == (7, 1)
            assert reply == bytes([pdu[0] | 0x80, 0x03])
            assert await read32(direct, 1, TARGET) == before  # nothing reached the drive
            assert await read32(master, 1, FEEDBACK) is not None  # still serving

    run(body())


def test_homing_makes_the_next_move_the_first_after_homing(tmp_path: Path):
    """After a homing trigger (0x20) the axis is at home, not at its last target: the next
    move's approach is ``home_direction`` (+ from 0), not the sign from the last target."""

    def edit(data):
        with_pitch(data)
        data["axes"]["Y"]["registers"]["trigger"]["home_value"] = 0x20

    async def body():
        async with rig(tmp_path, edit, {"x.csv": PITCH_X}) as r:
            master, direct = r["master"], r["direct"]
            await move(master, 2, 100_000)
            await move(master, 2, 50_000)
            assert await read32(direct, 2, TARGET) == 49_995  # −B/2 moving −
            assert not (await master.write_register(TRIGGER, 0x20, device_id=2)).isError()
            assert await read32(direct, 2, FEEDBACK) == 0  # the sim homed to 0
            await move(master, 2, 30_000)  # from 0: approached going +
            assert await read32(direct, 2, TARGET) == 30_005
            assert await read32(master, 2, FEEDBACK) == 30_000

    run(body())


@pytest.mark.parametrize(("max_age_s", "per_move"), [(0.0, 3), (30.0, 2)])
def test_status_max_age_decides_when_the_homed_check_reads_the_drive(
    tmp_path: Path, max_age_s: float, per_move: int
):
    """A target write needs "homed": a status word older than ``max_age_s`` costs one more
    drive transaction per move (status read + target + trigger), a fresh one does not."""

    def edit(data):
        with_pitch(data)
        data["axes"]["X"]["registers"]["status"]["max_age_s"] = max_age_s

    async def body():
        async with rig(tmp_path, edit, {"x.csv": PITCH_X}) as r:
            master, bus = r["master"], r["app"].buses["line1"]
            await move(master, 1, 100_000)  # the first move reads the status (none seen)
            before = bus.counters.transactions
            for target in (200_000, 300_000, 400_000):
                await move(master, 1, target)
            assert bus.counters.transactions - before == 3 * per_move
            assert r["app"].gateway.axis_state("X").applied

    run(body())


def test_not_homed_means_uncorrected(tmp_path: Path):
    """Compensation applies only while the drive reports homed."""

    def homed_bit_5(data):
        with_pitch(data)
        data["axes"]["X"]["registers"]["status"]["homed_bit"] = 5  # the sim never sets bit 5

    async def body():
        async with rig(tmp_path, homed_bit_5, {"x.csv": PITCH_X}) as r:
            master, direct = r["master"], r["direct"]
            await move(master, 1, 300_000)
            assert await read32(direct, 1, TARGET) == 300_000
            assert await read32(master, 1, FEEDBACK) == 300_000

    run(body())


XY_POINTS = "x_mm,y_mm,dx_um,dy_um\n" + "".join(
    f"{x},{y},{0.145 * y:.3f},{0.02 * x:.3f}\n" for x in (0, 400, 800) for y in (0, 300, 600)
)
XY_FILES = {"x.csv": PITCH_X, "xy.csv": XY_POINTS, "xy.yaml": "points: xy.csv\nmodel: grid\n"}


def with_planar(commit: str):
    def edit(data):
        with_pitch(data)
        data["planar"] = {"axes": ["X", "Y"], "model": "xy.yaml", "commit": commit}

    return edit


def test_on_trigger_holds_planar_targets_then_writes_both(tmp_path: Path):
    async def body():
        async with rig(tmp_path, with_planar("on_trigger"), XY_FILES) as r:
            master, direct, chain = r["master"], r["direct"], r["chain"]
            x0, y0 = await read32(direct, 1, TARGET), await read32(direct, 2, TARGET)
            await write_target(master, 1, 500_000)
            await write_target(master, 2, 400_000)
            assert (await read32(direct, 1, TARGET), await read32(direct, 2, TARGET)) == (x0, y0)
            assert await read32(master, 1, TARGET) == 500_000  # acknowledged, held in the shadow
            assert not (await master.write_register(TRIGGER, 0x10, device_id=1)).isError()
            inputs = {"X": AxisInput(500_000, 1), "Y": AxisInput(400_000, 1)}
            ex, ey = chain.command_pulses("X", inputs), chain.command_pulses("Y", inputs)
            # X error: 0.145 µm per mm of Y (58 µm at Y = 400) + pitch 14 µm at 500 mm
            assert ex == pytest.approx(500_000 - 58 - 14, abs=2)
            assert await read32(direct, 1, TARGET) == ex
            assert await read32(direct, 2, TARGET) == ey  # partner written before the trigger
            assert await read32(master, 1, FEEDBACK) == 500_000

    run(body())


def test_immediate_uses_the_partners_latest_target(tmp_path: Path):
    async def body():
        async with rig(tmp_path, with_planar("immediate"), XY_FILES) as r:
            master, direct, chain = r["master"], r["direct"], r["chain"]
            await write_target(master, 2, 300_000)
            await write_target(master, 1, 200_000)
            inputs = {"X": AxisInput(200_000, 1), "Y": AxisInput(300_000, 1)}
            assert await read32(direct, 1, TARGET) == chain.command_pulses("X", inputs)

    run(body())


def test_the_first_move_after_a_start_takes_its_direction_from_where_the_axis_stands(
        tmp_path: Path) -> None:  # fmt: skip
    """No state file, Y left at 300 mm (an earlier run, a jog): its first move, to 100 mm, is
    a − move and arrives on the − flank of its 10 µm play (trial 9: taken as home_direction
    +, it landed 8.7 µm off); a drive that cannot say where it stands: home_direction."""

    async def body():
        async with rig(tmp_path, with_pitch, {"x.csv": PITCH_X}) as r:
            master, direct, chain = r["master"], r["direct"], r["chain"]
            await move(direct, 2, 300_000)  # not through the gateway
            await move(master, 2, 100_000)
            assert await read32(direct, 2, TARGET) == chain.command_pulses(
                "Y", {"Y": AxisInput(100_000, -1)}) == 100_000 - 5  # fmt: skip
            assert await read32(master, 2, FEEDBACK) == 100_000

    run(body())


def test_a_target_sent_again_whose_command_goes_back_is_a_reversal(tmp_path: Path):
    """Y at 300 mm approached +; X moves 800 mm, the plane's Y error there is 16 µm: Y sent
    300 mm again goes 16 µm back in command, through the nut's play, so it is corrected as
    a reversal (−B/2 of Y's 10 µm backlash), and forward again when X comes back (trial 9:
    it kept the + flank, and Y stood 7.1 µm off in the play with its feedback at 400.000)."""

    async def body():
        async with rig(tmp_path, with_planar("immediate"), XY_FILES) as r:
            master, direct, chain = r["master"], r["direct"], r["chain"]
            await move(master, 1, 0)
            await move(master, 2, 300_000)
            up = chain.command_pulses("Y", {"Y": AxisInput(300_000, 1), "X": AxisInput(0)})
            assert await read32(direct, 2, TARGET) == up
            await move(master, 1, 800_000)
            await move(master, 2, 300_000)  # the same target, sent again
            back = chain.command_pulses("Y", {"Y": AxisInput(300_000, -1),
                                              "X": AxisInput(800_000)})  # fmt: skip
            assert await read32(direct, 2, TARGET) == back == up - 16 - 10
            assert await read32(master, 2, FEEDBACK) == 300_000
            await move(master, 1, 0)
            await move(master, 2, 300_000)
            assert await read32(direct, 2, TARGET) == up  # forward again: the + flank
            await move(master, 2, 300_000)  # nothing changed: nothing turns
            assert await read32(direct, 2, TARGET) == up
            # 1 µm back (X at 50 mm), within the dead band: no turn through the whole play
            # (a Δa sensor's wander would otherwise make the axis hunt by its lost motion)
            await move(master, 1, 50_000)
            await move(master, 2, 300_000)
            assert await read32(direct, 2, TARGET) == up - 1

    run(body())


@pytest.mark.parametrize("commit", ["immediate", "on_trigger"])
def test_steps_back_each_inside_the_dead_band_add_up_to_a_reversal(tmp_path: Path,
                                                                   commit: str) -> None:
    """Y at 300 mm approached +, sent again while X steps 50 mm at a time (a column of
    holes along the other axis): each step takes 1 µm off Y's command. Inside the play the
    table stays where the furthest command put it, so the steps add up: past the 1 µm dead
    band Y turns as a reversal and then follows the − flank (before: each step was within
    the dead band of the one before, Y kept the + flank with its command 16 µm back, and
    stood off by what the play swallowed; a kept rough machine read 11 µm off in X at the
    top of a column of Y targets)."""

    async def body():
        async with rig(tmp_path, with_planar(commit), XY_FILES) as r:
            master, direct, chain = r["master"], r["direct"], r["chain"]

            def y_command(x_pulses: int, flank: int) -> int:
                return chain.command_pulses("Y", {"Y": AxisInput(300_000, flank),
                                                  "X": AxisInput(x_pulses)})  # fmt: skip

            await move(master, 1, 0)
            await move(master, 2, 300_000)
            up = y_command(0, 1)
            assert await read32(direct, 2, TARGET) == up
            sent = []
            for x in range(50_000, 800_001, 50_000):
                await move(master, 1, x)
                await move(master, 2, 300_000)  # the same target, sent again
                sent.append(await read32(direct, 2, TARGET))
            assert sent[0] == up - 1  # inside the 1 µm dead band: on the + flank
            assert sent[1] == y_command(100_000, -1) == up - 2 - 10  # 2 µm: a reversal
            assert sent[2:] == [y_command(x, -1) for x in range(150_000, 800_001, 50_000)]
            assert sent[-1] == up - 16 - 10
            assert await read32(master, 2, FEEDBACK) == 300_000

    run(body())


def test_a_partner_no_target_was_seen_of_is_read_from_its_drive(tmp_path: Path):
    """A gateway started (no state file) with Y standing at 400 mm where an earlier run or
    a jog left it: X's first target takes the plane's term at Y's place, read from Y's
    drive (trial 8: it was left out, X 79-88 µm off until Y was moved once); Y's drive
    silent: X's target is refused with the drive's 0x0B, never sent without it."""

    async def body():
        async with rig(tmp_path, with_planar("immediate"), XY_FILES) as r:
            master, direct, chain = r["master"], r["direct"], r["chain"]
            await move(direct, 2, 400_000)  # not through the gateway
            assert await read32(direct, 2, FEEDBACK) == 400_000
            await write_target(master, 1, 500_000)
            bare = chain.command_pulses("X", {"X": AxisInput(500_000, 1)})
            ex = chain.command_pulses("X", {"X": AxisInput(500_000, 1), "Y": AxisInput(400_000)})
            assert ex == pytest.approx(bare - 58, abs=2)  # 0.145 µm per mm of Y
            assert await read32(direct, 1, TARGET) == ex
            assert not (await direct.write_register(2 * 8, 1, device_id=250)).isError()
            rr = await master.write_registers(TARGET, list(pack_int32(510_000)), device_id=1)
            assert rr.isError() and rr.exception_code == 0x0B
            assert await read32(direct, 1, TARGET) == ex  # nothing sent
            assert not (await direct.write_register(0x0804, 1, device_id=250)).isError()
            await write_target(master, 2, 300_000)  # Y known from here: no read needed
            assert not (await direct.write_register(2 * 8, 1, device_id=250)).isError()
            await write_target(master, 1, 200_000)
            inputs = {"X": AxisInput(200_000, 1), "Y": AxisInput(300_000, 1)}
            assert await read32(direct, 1, TARGET) == chain.command_pulses("X", inputs)

    run(body())


@pytest.mark.parametrize(("upstream", "drives"), [("tcp", "rtu"), ("rtu", "rtu"), ("rtu", "tcp")])
def test_same_results_over_rtu(tmp_path: Path, upstream: str, drives: str):
    """TCP→RTU(pty), RTU(pty)→RTU(pty), RTU→TCP: corrected out, nominal back, split writes."""

    async def body():
        async with rig(tmp_path, with_pitch, {"x.csv": PITCH_X}, upstream=upstream,
                       drives=drives) as r:
            master, direct, chain = r["master"], r["direct"], r["chain"]
            await move(master, 1, 300_000)
            expected = chain.command_pulses("X", {"X": AxisInput(300_000, 1)})
            assert await read32(direct, 1, TARGET) == expected
            assert await read32(master, 1, FEEDBACK) == 300_000
            words = pack_int32(700_000)
            assert not (await master.write_register(TARGET + 1, words[1], device_id=1)).isError()
            assert await read32(direct, 1, TARGET) == expected  # half held back
            assert not (await master.write_register(TARGET, words[0], device_id=1)).isError()
            assert await read32(direct, 1, TARGET) == chain.command_pulses(
                "X", {"X": AxisInput(700_000, 1)}
            )
            rr = await master.write_registers(TARGET, list(pack_int32(900_000)), device_id=1)
            assert rr.isError() and rr.exception_code == 0x03

    run(body())


def test_third_party_master_mbpoll(tmp_path: Path):
    """mbpoll (Debian's Modbus master) writes a target and reads feedback through the gateway."""
    mbpoll = shutil.which("mbpoll")
    if mbpoll is None:
        pytest.skip("mbpoll is not installed (make test installs it with apt-get)")

    async def call(port: int, *args: str) -> str:
        proc = await asyncio.create_subprocess_exec(
            mbpoll, "-m", "tcp", "-p", str(port), "-a", "1", "-0", "-1", "-o", "2", *args,
            stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.STDOUT,
        )
        out, _ = await proc.communicate()
        assert proc.returncode == 0, out.decode()
        return out.decode()

    async def body():
        async with rig(tmp_path, with_pitch, {"x.csv": PITCH_X}) as r:
            port, direct, chain = r["app"].tcp_port, r["direct"], r["chain"]
            # 32-bit integer, big-endian word order (-B): the drive's hi_lo
            await call(port, "-r", str(TARGET), "-t", "4:int", "-B", "127.0.0.1", "--", "300000")
            await call(port, "-r", str(TRIGGER), "-t", "4", "127.0.0.1", "16")
            expected = chain.command_pulses("X", {"X": AxisInput(300_000, 1)})
            assert await read32(direct, 1, TARGET) == expected != 300_000
            out = await call(port, "-r", str(FEEDBACK), "-t", "4:int", "-B", "127.0.0.1")
            assert re.search(rf"\[{FEEDBACK}\]:\s+300000\b", out), out

    run(body())


def test_pipelined_requests_each_get_their_reply(tmp_path: Path):
    """Several requests in one TCP segment, then back to back: every reply, in order,
    with its own transaction id, through the interception layer."""

    def mbap(tid: int, unit: int, pdu: bytes) -> bytes:
        return struct.pack(">HHHB", tid, 0, len(pdu) + 1, unit) + pdu

    async def body():
        async with rig(tmp_path, with_pitch, {"x.csv": PITCH_X}) as r:
            reader, writer = await asyncio.open_connection("127.0.0.1", r["app"].tcp_port)
            requests = [
                (1, struct.pack(">BHHBHH", 0x10, TARGET, 2, 4, *pack_int32(250_000))),
                (1, struct.pack(">BHH", 0x06, TRIGGER, 0x10)),
                (1, struct.pack(">BHH", 0x03, FEEDBACK, 2)),
                (1, struct.pack(">BHH", 0x03, TARGET, 2)),
                (2, struct.pack(">BHH", 0x03, 0x1003, 1)),
                (99, struct.pack(">BHH", 0x03, 0, 1)),
            ]
            segment = b"".join(mbap(100 + i, u, p) for i, (u, p) in enumerate(requests))
            writer.write(segment)  # one segment
            for i in range(10):  # then back to back without waiting
                writer.write(mbap(200 + i, 1, struct.pack(">BHH", 0x03, FEEDBACK, 2)))
            await writer.drain()
            replies = []
            for _ in range(len(requests) + 10):
                head = await reader.readexactly(7)
                tid, _, length, unit = struct.unpack(">HHHB", head)
                replies.append((tid, unit, await reader.readexactly(length - 1)))
            writer.close()
            tids = [t for t, _, _ in replies]
            assert tids == [100 + i for i in range(len(requests))] + [200 + i for i in range(10)]
            assert replies[0][2] == struct.pack(">BHH", 0x10, TARGET, 2)
            assert replies[1][2] == struct.pack(">BHH", 0x06, TRIGGER, 0x10)
            feedback = struct.unpack(">BBHH", replies[2][2])
            assert unpack_int32(feedback[2:], "hi_lo") == 250_000
            assert unpack_int32(struct.unpack(">HH", replies[3][2][2:]), "hi_lo") == 250_000
            assert replies[5][2] == bytes([0x83, 0x0A])  # unit 99: not routed
            for _, _, pdu in replies[6:]:
                assert unpack_int32(struct.unpack(">HH", pdu[2:]), "hi_lo") == 250_000

    run(body())


def test_correction_above_the_cap_is_refused_and_nothing_sent(tmp_path: Path):
    def thermal(data):
        with_pitch(data)
        data["thermal_sources"] = {
            "x_ref": {"bus": "line1", "unit": 10, "register": {"address": 1, "words": 2},
                      "scale_mm": 1e-6}
        }
        data["axes"]["X"]["compensation"]["thermal"] = {"source": "x_ref", "length_mm": 800}

    async def body():
        async with rig(tmp_path, thermal, {"x.csv": PITCH_X}) as r:
            master, direct, app = r["master"], r["direct"], r["app"]
            await move(master, 1, 700_000)
            before = await read32(direct, 1, TARGET)
            app.gateway.delta_a_mm = lambda axis: 0.4  # an implausible 0.4 mm of growth
            rr = await master.write_registers(TARGET, list(pack_int32(750_000)), device_id=1)
            assert rr.isError() and rr.exception_code == 0x04
            assert await read32(direct, 1, TARGET) == before
            assert app.gateway.counters.refused_correction == 1

    run(body())


def test_a_travel_profile_puts_the_growth_where_the_axis_worked(tmp_path: Path):
    """thermal.profile: after the axis has cycled over 100..300 mm, a Δa of 0.08 mm is the
    growth of that stretch: 60 mm (below it, next to the fixed end at 0) grows nothing and
    600 mm (beyond it) the whole Δa, where the linear spread would give 6 and 60 µm."""

    def thermal(data):
        data["thermal_sources"] = {
            "x_ref": {"bus": "line1", "unit": 10, "register": {"address": 1, "words": 2},
                      "scale_mm": 1e-6}
        }
        data["axes"]["X"]["compensation"]["thermal"] = {
            "source": "x_ref", "length_mm": 800, "profile": {"spread_mm": 10}}

    async def body():
        async with rig(tmp_path, thermal, {}) as r:
            master, direct, app = r["master"], r["direct"], r["app"]
            app.gateway.delta_a_mm = lambda axis: 0.08 if axis == "X" else None
            await move(master, 1, 60_000)  # before any travel: the linear spread
            assert await read32(direct, 1, TARGET) == round(60_000 * 800 / 800.08)
            for _ in range(6):
                await move(master, 1, 100_000)
                await move(master, 1, 300_000)
            await move(master, 1, 60_000)
            assert await read32(direct, 1, TARGET) == 60_000
            await move(master, 1, 600_000)  # all 0.08 mm of growth below it
            assert await read32(direct, 1, TARGET) == 600_000 - 80
            # feedback reads back the nominal target through the same profile
            assert await read32(master, 1, FEEDBACK) == 600_000

    run(body())


def test_heat_from_motion_shrinks_the_command_as_the_axis_works(tmp_path: Path):
    """thermal.motion, no sensor: after ten 200 mm strokes at 100 mm/s (20 s of moves, a
    tau of 100 s), 1.81 m of heat at 10 µm per metre is a Δa of 18.1 µm over 800 mm; the
    target at 600 mm goes out that much shorter and the feedback reads back nominal."""

    def thermal(data):
        data["axes"]["X"]["compensation"]["thermal"] = {
            "length_mm": 800, "motion": {"delta_a_um_per_m": 10.0, "tau_s": 100.0,
                                         "speeds_mm_s": {"X": 100}}}

    async def body():
        async with rig(tmp_path, thermal, {}) as r:
            master, direct = r["master"], r["direct"]
            await move(master, 1, 100_000)
            assert await read32(direct, 1, TARGET) == 100_000  # cold
            for _ in range(5):
                await move(master, 1, 300_000)
                await move(master, 1, 100_000)
            heat_m = 0.1 * 100.0 * (1 - math.exp(-20.0 / 100.0))  # rate · tau · (1 − e^-t/tau)
            delta_a_mm = 10.0 * heat_m / 1000
            await move(master, 1, 600_000)
            want = 600_000 * 800 / (800 + delta_a_mm)
            assert abs(await read32(direct, 1, TARGET) - want) <= 1
            assert await read32(master, 1, FEEDBACK) == 600_000

    run(body())


def test_heat_from_motion_counts_the_moves_made_before_homing(tmp_path: Path):
    """Moves sent before the drive reports homed go out as written, but they heat the
    screw: once homed, the first corrected target is as short as all the strokes made."""

    def thermal(data):
        data["axes"]["X"]["compensation"]["thermal"] = {
            "length_mm": 800, "motion": {"delta_a_um_per_m": 10.0, "tau_s": 100.0,
                                         "speeds_mm_s": {"X": 100}}}

    def not_homed(data):
        data["sim"]["axes"]["X"]["homed_at_start"] = False

    async def body():
        async with rig(tmp_path, thermal, {}, sim_edit=not_homed) as r:
            master, direct = r["master"], r["direct"]
            await move(master, 1, 100_000)
            for _ in range(5):
                await move(master, 1, 300_000)
                await move(master, 1, 100_000)
            assert await read32(direct, 1, TARGET) == 100_000  # not homed: as written
            assert not (await master.write_register(TRIGGER, 0x20, device_id=1)).isError()
            rr = await master.read_holding_registers(0x1003, count=1, device_id=1)
            assert rr.registers[0] >> 6 & 1  # homed
            heat_m = 0.1 * 100.0 * (1 - math.exp(-20.0 / 100.0))
            delta_a_mm = 10.0 * heat_m / 1000  # 18.1 µm; homing's wall time cools it a little
            await move(master, 1, 600_000)
            want = 600_000 * 800 / (800 + delta_a_mm)
            assert abs(await read32(direct, 1, TARGET) - want) <= 3, want

    run(body())


def test_bus_unavailable_is_0x0a(tmp_path: Path):
    def dead_bus(data):
        with socket.socket() as probe:  # a loopback port nobody listens on
            probe.bind(("127.0.0.1", 0))
            port = probe.getsockname()[1]
        data["buses"]["dead"] = {"tcp": {"host": "127.0.0.1", "port": port}}
        data["passthrough"][30] = {"bus": "dead", "unit": 1}

    async def body():
        async with rig(tmp_path, dead_bus, {}) as r:
            rr = await r["master"].read_holding_registers(0, count=1, device_id=30)
            assert rr.isError() and rr.exception_code == 0x0A
            # the rest of the gateway keeps serving
            rr = await r["master"].read_holding_registers(FEEDBACK, count=2, device_id=1)
            assert not rr.isError()

    run(body())


def test_a_move_the_drive_did_not_get_is_logged(tmp_path: Path,
                                                 caplog: pytest.LogCaptureFixture):  # fmt: skip
    """A target the master sent that the drive did not get (its bus down: 0x0A) is a
    warning naming the axis and the target, not only an exception to the master."""
    def dead_x(data):
        with socket.socket() as probe:  # a loopback port nobody listens on
            probe.bind(("127.0.0.1", 0))
            port = probe.getsockname()[1]
        data["buses"]["dead"] = {"tcp": {"host": "127.0.0.1", "port": port}}
        data["axes"]["X"]["bus"] = "dead"

    async def body():
        async with rig(tmp_path, dead_x, {}) as r:
            with caplog.at_level(logging.WARNING, logger="gateway.router"):
                master = r["master"]
                replies = [await master.write_registers(TARGET, list(pack_int32(300_000)),
                                                        device_id=1),
                           await master.write_register(TRIGGER, 0x10, device_id=1)]  # fmt: skip
            assert any(rr.isError() and rr.exception_code == 0x0A for rr in replies)
            assert re.search(r"axis X: (trigger|write) to target 300000 not delivered",
                             caplog.text), caplog.text  # fmt: skip

    run(body())


def test_compensation_starts_when_the_drive_reports_homed(tmp_path: Path):
    def not_homed(data):
        data["sim"]["axes"]["X"]["homed_at_start"] = False

    async def body():
        async with rig(tmp_path, with_pitch, {"x.csv": PITCH_X}, sim_edit=not_homed) as r:
            master, direct, chain = r["master"], r["direct"], r["chain"]
            await move(master, 1, 300_000)
            assert await read32(direct, 1, TARGET) == 300_000  # not homed: as written
            assert await read32(master, 1, FEEDBACK) == 300_000
            assert not (await master.write_register(TRIGGER, 0x20, device_id=1)).isError()
            rr = await master.read_holding_registers(0x1003, count=1, device_id=1)
            assert rr.registers[0] >> 6 & 1  # the master sees homing done
            await move(master, 1, 400_000)
            expected = chain.command_pulses("X", {"X": AxisInput(400_000, 1)})
            assert await read32(direct, 1, TARGET) == expected != 400_000
            assert await read32(master, 1, FEEDBACK) == 400_000

    run(body())
