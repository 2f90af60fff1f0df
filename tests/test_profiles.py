"""Real drive profiles end to end: gateway (profile) → RTU on a pty → sim emulating that drive.

The sim's emulation (sim/profiles.py) is written independently of the gateway's profiles
(gateway/profiles.py): if either got a register, a word order or a trigger wrong, these
tests fail.
"""

from __future__ import annotations

import asyncio
import time
from pathlib import Path

import pytest
import serial
import yaml

from gateway.compensation import AxisInput
from gateway.config import load_config, warnings
from gateway.modbus.frames import pack_int32, rtu_encode, unpack_int32
from gateway.profiles import PROFILES
from sim.config import RtuConfig
from sim.config import parse_config as parse_sim_config
from sim.server import SimServer
from tests.conftest import PtyPair
from tests.gateway_rig import SIM_EXAMPLE, rig
from tests.gateway_rig import serial as serial_settings
from tests.test_gateway_e2e import PITCH_X, XY_FILES, run

CONTROL_UNIT = 250
#: the profiles whose start is a register write (value or bit edge) on its own; the other
#: command shapes (block with trigger, coil, control word) are in test_drive_shapes.py
REGISTER_STARTED = ["leadshine-rs-pr0", "inovance-sv660p", "delta-asda-pr"]


def sim_profile(name: str):
    def edit(data):
        for axis in data["sim"]["axes"].values():
            axis.pop("registers", None)
            axis["profile"] = name

    return edit


def gateway_profile(name: str, planar: bool = False):
    def edit(data):
        for axis_name, unit, travel in (("X", 1, [0, 800]), ("Y", 2, [0, 600])):
            data["axes"][axis_name] = {
                "bus": "line1", "unit": unit, "pulse_mm": 0.001, "travel_mm": travel,
                "profile": name, "ram_setting_applied": True,
                "compensation": {"max_correction_mm": 0.2},
            }
        data["axes"]["X"]["compensation"]["pitch"] = "x.csv"
        data["axes"]["Y"]["compensation"]["backlash_mm"] = 0.01
        if planar:
            data["planar"] = {"axes": ["X", "Y"], "model": "xy.yaml", "commit": "on_trigger"}

    return edit


def regs(name: str) -> dict:
    return PROFILES[name].axis["registers"]


async def read32(client, unit: int, address: int, order: str) -> int:
    rr = await client.read_holding_registers(address, count=2, device_id=unit)
    assert not rr.isError(), rr
    return unpack_int32(rr.registers, order)


async def fire_trigger(master, name: str, unit: int) -> None:
    trig = regs(name)["trigger"]
    if "rising_bit" in trig:
        bit = 1 << trig["rising_bit"]
        assert not (await master.write_register(trig["address"], 1, device_id=unit)).isError()
        assert not (await master.write_register(trig["address"], 1 | bit, device_id=unit)).isError()
    else:
        rr = await master.write_register(trig["address"], trig["value"], device_id=unit)
        assert not rr.isError()


async def control(direct, unit: int, field: int) -> int:
    rr = await direct.read_holding_registers(unit * 8 + field, count=1, device_id=CONTROL_UNIT)
    assert not rr.isError()
    return rr.registers[0]


@pytest.mark.parametrize("name", REGISTER_STARTED)
def test_profile_end_to_end_over_rtu(tmp_path: Path, name: str):
    r_target, r_feedback = regs(name)["target"], regs(name)["feedback"]
    t_addr, t_order = r_target["address"], r_target["order"]
    f_addr, f_order = r_feedback["address"], r_feedback["order"]

    async def body():
        async with rig(tmp_path, gateway_profile(name), {"x.csv": PITCH_X}, drives="rtu",
                       sim_edit=sim_profile(name)) as r:
            master, direct, chain = r["master"], r["direct"], r["chain"]
            # block write of the target, in the drive's word order
            block = list(pack_int32(300_000, t_order))
            assert not (await master.write_registers(t_addr, block, device_id=1)).isError()
            expected = chain.command_pulses("X", {"X": AxisInput(300_000, 1)})
            assert await read32(direct, 1, t_addr, t_order) == expected != 300_000
            before = await read32(direct, 1, f_addr, f_order)
            await fire_trigger(master, name, 1)  # the profile's trigger style
            assert await read32(direct, 1, f_addr, f_order) == expected != before
            assert await read32(master, 1, f_addr, f_order) == 300_000  # nominal back
            assert await read32(master, 1, t_addr, t_order) == 300_000  # the shadow
            # split writes, second word first: nothing reaches the drive until both are in
            words = pack_int32(650_000, t_order)
            assert not (await master.write_register(t_addr + 1, words[1], device_id=1)).isError()
            assert await read32(direct, 1, t_addr, t_order) == expected
            assert not (await master.write_register(t_addr, words[0], device_id=1)).isError()
            assert await read32(direct, 1, t_addr, t_order) == chain.command_pulses(
                "X", {"X": AxisInput(650_000, 1)}
            )
            # an exception: outside travel is refused, nothing sent
            rr = await master.write_registers(t_addr, list(pack_int32(-1, t_order)), device_id=1)
            assert rr.isError() and rr.exception_code == 0x03
            # the drive's own exception relayed: an address it does not have
            rr = await master.read_holding_registers(0x7000, count=1, device_id=1)
            assert rr.isError() and rr.exception_code == 0x02
            for unit in (1, 2):
                assert await control(direct, unit, 4) == 0  # line silence always kept
                assert await control(direct, unit, 5) == 0  # no FC16 over the drive's limit

    run(body())


@pytest.mark.parametrize("name", REGISTER_STARTED)
def test_profile_on_trigger_planar_pair(tmp_path: Path, name: str):
    t = regs(name)["target"]

    async def body():
        async with rig(tmp_path, gateway_profile(name, planar=True), XY_FILES, drives="rtu",
                       sim_edit=sim_profile(name)) as r:
            master, direct, chain = r["master"], r["direct"], r["chain"]
            x0 = await read32(direct, 1, t["address"], t["order"])
            for unit, value in ((1, 500_000), (2, 400_000)):
                words = list(pack_int32(value, t["order"]))
                rr = await master.write_registers(t["address"], words, device_id=unit)
                assert not rr.isError()
            assert await read32(direct, 1, t["address"], t["order"]) == x0  # held
            await fire_trigger(master, name, 1)
            inputs = {"X": AxisInput(500_000, 1), "Y": AxisInput(400_000, 1)}
            for unit, axis in ((1, "X"), (2, "Y")):
                on_drive = await read32(direct, unit, t["address"], t["order"])
                assert on_drive == chain.command_pulses(axis, inputs)

    run(body())


def test_delta_blocks_are_split_at_its_fc16_limit_never_inside_the_target(tmp_path: Path):
    name = "delta-asda-pr"
    assert PROFILES[name].axis["fc16_max_words"] == 10

    async def body():
        async with rig(tmp_path, gateway_profile(name), {"x.csv": PITCH_X}, drives="rtu",
                       sim_edit=sim_profile(name)) as r:
            master, direct, chain = r["master"], r["direct"], r["chain"]
            # 16 words from 0x0600: PR#1 definition, target (0x0606/7), more PR words
            block = list(range(100, 116))
            block[6:8] = pack_int32(123_456, "lo_hi")
            assert not (await master.write_registers(0x0600, block, device_id=1)).isError()
            rr = await direct.read_holding_registers(0x0600, count=16, device_id=1)
            expected = chain.command_pulses("X", {"X": AxisInput(123_456, 1)})
            assert rr.registers[:6] == block[:6] and rr.registers[8:] == block[8:]
            assert unpack_int32(rr.registers[6:8], "lo_hi") == expected
            # a long block elsewhere, forwarded in pieces
            rr = await master.write_registers(0x0608, list(range(20)), device_id=1)
            assert not rr.isError()
            rr = await direct.read_holding_registers(0x0608, count=20, device_id=1)
            assert rr.registers == list(range(20))
            assert await control(direct, 1, 5) == 0  # the drive never saw more than 10 words
            assert await control(direct, 1, 4) == 0  # and always got its 10 ms of silence

    run(body())


def test_sim_enforces_delta_line_silence():
    """The emulation really refuses frames that come too close (so the tests above count).
    The Delta's 10 ms made 0.3 s here: "at once" from a thread of a loaded machine can
    come 10 ms late, never 0.3 s (the test read "at once" as seen under load)."""
    data = yaml.safe_load(SIM_EXAMPLE.read_text())
    sim_profile("delta-asda-pr")(data)
    data["sim"]["axes"]["X"]["registers"] = {"min_silence_s": 0.3}  # on top of the profile
    pair = PtyPair()
    request = rtu_encode(1, bytes([0x03, 0x05, 0x20, 0x00, 0x02]))

    def exchange(port: serial.Serial, pause_s: float) -> int:
        """Send the request ``pause_s`` after the last reply; bytes answered."""
        time.sleep(pause_s)
        port.write(request)
        return len(port.read(9))

    async def body():
        cfg = parse_sim_config(data, SIM_EXAMPLE.parent)
        rtu = RtuConfig(**serial_settings(pair.a))
        cfg = cfg.model_copy(update={"sim": cfg.sim.model_copy(update={"rtu": rtu})})
        async with SimServer(cfg, tcp_port=0, time_scale=0) as sim:
            port = serial.Serial(pair.b, 115200, timeout=1.0)
            try:
                assert await asyncio.to_thread(exchange, port, 0.0) == 9  # first frame
                assert await asyncio.to_thread(exchange, port, 0.4) == 9  # 0.4 s later
                assert await asyncio.to_thread(exchange, port, 0.0) == 0  # at once: unseen
            finally:
                port.close()
            assert sim.sim.drives["X"].silence_violations == 1

    try:
        asyncio.run(asyncio.wait_for(body(), 20))
    finally:
        pair.close()


def test_eeprom_counter_and_check_warning(tmp_path: Path):
    """Inovance writes every bus write to EEPROM unless H0C.13 = 0: with the RAM setting the
    counter stays at zero through a calibration-like run; compgw check warns without it."""
    name = "inovance-sv660p"
    t = regs(name)["target"]
    ram_param = 0x0C0D

    async def runs(set_ram: bool) -> int:
        async with rig(tmp_path, gateway_profile(name), {"x.csv": PITCH_X}, drives="rtu",
                       sim_edit=sim_profile(name)) as r:
            master, direct = r["master"], r["direct"]
            if set_ram:  # what the profile tells the user to set on the drive
                assert not (await direct.write_register(ram_param, 0, device_id=1)).isError()
            for target in [10_000, 200_000, 400_000, 600_000, 400_000, 200_000, 10_000]:
                words = list(pack_int32(target, t["order"]))
                rr = await master.write_registers(t["address"], words, device_id=1)
                assert not rr.isError()
                await fire_trigger(master, name, 1)
            rr = await direct.read_holding_registers(0x7F00, count=2, device_id=1)
            return unpack_int32(rr.registers, "hi_lo", signed=False)

    assert asyncio.run(runs(set_ram=True)) == 0
    assert asyncio.run(runs(set_ram=False)) == 7

    config = tmp_path / "gw.yaml"
    text = config.read_text().replace("ram_setting_applied: true", "ram_setting_applied: false")
    config.write_text(text)
    found = warnings(load_config(config))
    assert any("H0C.13 = 0" in w and "axes.X" in w for w in found), found
    config.write_text(text.replace("ram_setting_applied: false", "ram_setting_applied: true"))
    assert not any("EEPROM" in w for w in warnings(load_config(config)))
