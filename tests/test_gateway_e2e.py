"""End to end: an upper computer → the gateway → the simulated drives (TCP → TCP)."""

from __future__ import annotations

import asyncio
from pathlib import Path

import pytest

from gateway.compensation import AxisInput
from gateway.frames import pack_int32, unpack_int32
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
