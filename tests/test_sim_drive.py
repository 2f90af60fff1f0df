"""Configurable drive register layouts, as a Modbus master sees them."""

from __future__ import annotations

from typing import Any

from sim.server import SimServer
from tests.test_sim_support import config_from, run, s32, tcp_client, words

UNIT = 1


def one_axis(registers: dict[str, Any], **axis: Any) -> dict:
    """A single-axis, error-free machine with the given register layout."""
    return {
        "sim": {
            "seed": 1,
            "axes": {"X": {"unit": UNIT, "travel_mm": [0, 800], "registers": registers, **axis}},
        }
    }


def script(data: dict, body) -> Any:
    async def go() -> Any:
        async with SimServer(config_from(data), tcp_port=0) as server:
            client = await tcp_client(server.tcp_port)
            try:
                return await body(client, server)
            finally:
                client.close()

    return run(go())


async def read_s32(client, address: int, order: str = "hi_lo", input_table: bool = False) -> int:
    read = client.read_input_registers if input_table else client.read_holding_registers
    rr = await read(address, count=2, device_id=UNIT)
    assert not rr.isError(), rr
    r = rr.registers
    return s32(r[0], r[1]) if order == "hi_lo" else s32(r[1], r[0])


def test_default_profile_fc06_halves_then_trigger() -> None:
    """Halves as two FC06 in either order: nothing moves until the trigger."""

    async def body(client, server) -> None:
        hi, lo = words(-345)
        await client.write_register(0x6202, lo, device_id=UNIT)
        await client.write_register(0x6201, hi, device_id=UNIT)
        assert await read_s32(client, 0x602A) == 0
        assert await read_s32(client, 0x6201) == -345  # the target reads back as written
        await client.write_register(0x6002, 0x11, device_id=UNIT)  # another path: no move
        assert await read_s32(client, 0x602A) == 0
        await client.write_register(0x6002, 0x10, device_id=UNIT)
        assert await read_s32(client, 0x602A) == -345
        # a target beyond travel +- overtravel: alarm bit 0, no motion
        await client.write_registers(0x6201, words(900_000), device_id=UNIT)
        await client.write_register(0x6002, 0x10, device_id=UNIT)
        st = (await client.read_holding_registers(0x1003, device_id=UNIT)).registers[0]
        assert st & 0x01 and not st & 0x10
        assert await read_s32(client, 0x602A) == -345
        # one FC16 over the PR0 block (0x6200..0x6207) is stored as plain parameters
        rr = await client.write_registers(0x6200, [1, *words(5000), 0, 0, 0, 0, 0], device_id=UNIT)
        assert not rr.isError()
        await client.write_register(0x6002, 0x10, device_id=UNIT)
        assert await read_s32(client, 0x602A) == 5000
        # unknown address -> 0x02
        rr = await client.read_holding_registers(0x0100, device_id=UNIT)
        assert rr.isError() and rr.exception_code == 0x02

    script(one_axis({}, overtravel_mm=1.0), body)


def test_lo_hi_order_counts_per_pulse_and_input_feedback() -> None:
    regs = {
        "target": {"address": 0x110C, "order": "lo_hi"},
        "feedback": {"address": 0x0B11, "order": "lo_hi", "table": "input", "counts_per_pulse": 4},
        "trigger": {"address": 0x3100, "value": None},  # any write starts the move
        "speed": None,
        "memory": [],
        "status": {"address": 0x3001},
    }

    async def body(client, server) -> None:
        await client.write_registers(0x110C, words(250_000, "lo_hi"), device_id=UNIT)
        await client.write_register(0x3100, 0x1234, device_id=UNIT)
        assert await read_s32(client, 0x0B11, "lo_hi", input_table=True) == 1_000_000

    script(one_axis(regs), body)


def test_rising_bit_trigger() -> None:
    regs = {"trigger": {"address": 0x3100, "value": None, "rising_bit": 4}, "memory": []}

    async def body(client, server) -> None:
        await client.write_registers(0x6201, words(1000), device_id=UNIT)
        await client.write_register(0x3100, 0x0001, device_id=UNIT)  # other bit: no move
        assert await read_s32(client, 0x602A) == 0
        await client.write_register(0x3100, 0x0011, device_id=UNIT)  # bit 4 rises
        assert await read_s32(client, 0x602A) == 1000
        await client.write_registers(0x6201, words(2000), device_id=UNIT)
        await client.write_register(0x3100, 0x0011, device_id=UNIT)  # still high: no edge
        assert await read_s32(client, 0x602A) == 1000
        await client.write_register(0x3100, 0x0001, device_id=UNIT)
        await client.write_register(0x3100, 0x0011, device_id=UNIT)
        assert await read_s32(client, 0x602A) == 2000

    script(one_axis(regs), body)


def test_no_trigger_moves_on_target_write() -> None:
    async def body(client, server) -> None:
        await client.write_registers(0x6201, words(3000), device_id=UNIT)
        assert await read_s32(client, 0x602A) == 3000
        await client.write_register(0x6201, 0, device_id=UNIT)  # first half only: no move
        assert await read_s32(client, 0x602A) == 3000
        await client.write_register(0x6202, 100, device_id=UNIT)  # second half: moves
        assert await read_s32(client, 0x602A) == 100

    script(one_axis({"trigger": None}), body)


def test_fc16_limit_answers_0x03() -> None:
    async def body(client, server) -> None:
        rr = await client.write_registers(0x6200, [0, 0, 0], device_id=UNIT)
        assert rr.isError() and rr.exception_code == 0x03
        rr = await client.write_registers(0x6201, words(10), device_id=UNIT)
        assert not rr.isError()

    script(one_axis({"fc16_max_words": 2}), body)


def test_eeprom_counter_and_ram_only_parameter() -> None:
    regs = {
        "eeprom": {
            "counter": {"address": 0x7F00, "count": 2},
            "ram_only_param": {"address": 0x0C0D, "value": 0},
        }
    }

    async def body(client, server) -> None:
        for target in (10, 20, 30):
            await client.write_registers(0x6201, words(target), device_id=UNIT)
        assert await read_s32(client, 0x7F00) == 3
        await client.write_register(0x0C0D, 0, device_id=UNIT)  # keep writes in RAM
        await client.write_registers(0x6201, words(40), device_id=UNIT)
        assert await read_s32(client, 0x7F00) == 3
        rr = await client.write_registers(0x7F00, [0, 0], device_id=UNIT)  # read-only
        assert rr.isError() and rr.exception_code == 0x02

    script(one_axis(regs), body)


def test_homing_when_not_homed_at_start() -> None:
    async def body(client, server) -> None:
        st = (await client.read_holding_registers(0x1003, device_id=UNIT)).registers[0]
        assert not st & (1 << 6)
        await client.write_registers(0x6201, words(5000), device_id=UNIT)
        await client.write_register(0x6002, 0x10, device_id=UNIT)
        await client.write_register(0x6002, 0x20, device_id=UNIT)  # homing: back to 0
        st = (await client.read_holding_registers(0x1003, device_id=UNIT)).registers[0]
        assert st & (1 << 6)
        assert await read_s32(client, 0x602A) == 0

    script(one_axis({}, homed_at_start=False), body)


def test_speed_register_sets_the_move_duration() -> None:
    """200 mm at speed register 50 (x scale 1 mm/s) advances the machine clock by 4 s."""

    async def body(client, server) -> None:
        await client.write_register(0x6203, 50, device_id=UNIT)
        await client.write_registers(0x6201, words(200_000), device_id=UNIT)
        await client.write_register(0x6002, 0x10, device_id=UNIT)
        rr = await client.read_holding_registers(0x0802, count=2, device_id=250)
        assert (rr.registers[0] << 16 | rr.registers[1]) == 4000

    script(one_axis({}), body)
