"""Three more ways of starting a move, end to end over RTU on a pty: gateway (profile) →
sim emulating that drive (sim/profiles.py, written independently).

- Oriental Motor AZ direct data operation: target and trigger in one 16-register FC16;
- Panasonic MINAS A6 block operation: the start is a coil (FC05, FC15);
- Kinco FD: the start is a 0x2F → 0x3F edge of the control word (low word first).

Every write a simulated drive accepts is recorded in arrival order with the target of the
move it started (``Drive.received``): the tests check that a move only ever starts on a
corrected target written before (or with) the write that starts it, and that no nominal
target ever reaches a drive.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from gateway.axis import overlap
from gateway.compensation import AxisInput
from gateway.config import ConfigError, parse_config, warnings
from gateway.modbus.frames import (
    build_write_multiple_registers,
    build_write_single_coil,
    build_write_single_register,
    pack_int32,
    unpack_int32,
)
from gateway.profiles import PROFILES
from gateway.setup_report import describe
from gateway.tables import build_chain
from sim.drive import Drive
from tests.gateway_rig import rig
from tests.helpers_modbus import RawTcpMaster, wait_for_condition
from tests.test_gateway_e2e import PITCH_X, XY_FILES, run
from tests.test_profiles import control, gateway_profile, read32, regs, sim_profile

AZ, A6, KINCO = "oriental-az-direct", "panasonic-a6-block", "kinco-fd"
AZ_BLOCK = 0x0058  # direct data operation: 16 registers, target at +4, trigger at +14
A6_STB, A6_TABLE = 0x0120, 0x4800
KINCO_CONTROL = 0x3100


def target_words(name: str, pulses: int) -> list[int]:
    return list(pack_int32(pulses, regs(name)["target"]["order"]))


async def ok(reply) -> None:
    assert not reply.isError(), reply


async def set_target(master, name: str, unit: int, pulses: int) -> None:
    """The target as the drive's master software writes it, without a start."""
    words = target_words(name, pulses)
    if name == A6:  # block 0: command (code 2 = absolute in the top byte), target
        await ok(await master.write_registers(A6_TABLE, [0x0200, 0, *words], device_id=unit))
    else:
        address = regs(name)["target"]["address"]
        await ok(await master.write_registers(address, words, device_id=unit))


async def start(master, name: str, unit: int, *, other_form: bool = False) -> None:
    """The drive's own start (``other_form``: FC06 of the trigger field's low word for the
    AZ, FC15 for the A6)."""
    if name == AZ:  # the 32-bit trigger field: 1 = all fields updated, start now
        if other_form:
            await ok(await master.write_register(AZ_BLOCK + 15, 1, device_id=unit))
        else:
            await ok(await master.write_registers(AZ_BLOCK + 14, [0, 1], device_id=unit))
    elif name == A6:  # STB on; it clears itself
        if other_form:
            await ok(await master.write_coils(A6_STB, [True], device_id=unit))
        else:
            await ok(await master.write_coil(A6_STB, True, device_id=unit))
    else:  # Kinco: an absolute move on the new-set-point edge
        for word in (0x2F, 0x3F):
            await ok(await master.write_register(KINCO_CONTROL, word, device_id=unit))


async def move(master, name: str, unit: int, pulses: int) -> None:
    """A whole move as the master writes it (for the AZ one FC16 holding it all)."""
    if name == AZ:  # data No. 0, absolute, target, speed, accel, decel, current, trigger 1
        block = [0, 0, 0, 1, *target_words(name, pulses), 0, 5000, 0, 10000, 0, 10000,
                 0, 1000, 0, 1]
        await ok(await master.write_registers(AZ_BLOCK, block, device_id=unit))
    else:
        await set_target(master, name, unit, pulses)
        await start(master, name, unit)


def started_targets(drive: Drive, name: str) -> list[int]:
    """The targets of the moves the drive started, checking the order on the wire: each
    start comes with or after a write of that very target, made since the previous start
    (a trigger before its target would start a move to the previous one)."""
    target = regs(name)["target"]
    address, order = target["address"], target["order"]
    written, fresh, out = None, False, []
    for entry in drive.received:
        if entry.table == "holding" and len(overlap(entry.address, len(entry.values),
                                                    address)) == 2:
            i = address - entry.address
            written, fresh = unpack_int32(entry.values[i : i + 2], order), True
        if entry.started is not None:
            assert fresh, f"{drive.name}: a start with no target written since the last one"
            assert entry.started == written
            out.append(entry.started)
            fresh = False
    return out


def target_values_seen(drive: Drive, name: str) -> set[int]:
    """Every target value a write to the drive ever carried."""
    target = regs(name)["target"]
    seen = set()
    for entry in drive.received:
        if entry.table == "holding":
            i = target["address"] - entry.address
            if i >= 0 and i + 1 < len(entry.values):
                seen.add(unpack_int32(entry.values[i : i + 2], target["order"]))
    return seen


@pytest.mark.parametrize("name", [AZ, A6, KINCO])
def test_moves_land_on_the_corrected_target_and_read_back_nominal(tmp_path: Path, name: str):
    f = regs(name)["feedback"]

    async def body():
        async with rig(tmp_path, gateway_profile(name), {"x.csv": PITCH_X}, drives="rtu",
                       sim_edit=sim_profile(name)) as r:
            master, direct, chain = r["master"], r["direct"], r["chain"]
            drives = r["sim"].sim.drives
            plan = [(1, "X", 300_000), (2, "Y", 100_000), (1, "X", 650_000),
                    (1, "X", 200_000)]
            expected = {"X": [], "Y": []}
            for unit, axis, nominal in plan:
                direction = 1 if not expected[axis] or nominal > expected[axis][-1][0] else -1
                await move(master, name, unit, nominal)
                corrected = chain.command_pulses(axis, {axis: AxisInput(nominal, direction)})
                assert corrected != nominal
                expected[axis].append((nominal, corrected))
                assert await read32(direct, unit, f["address"], f["order"]) == corrected
                assert await read32(master, unit, f["address"], f["order"]) == nominal
            if name == A6:  # the FC15 form of the start, covering the STB coil
                await set_target(master, name, 2, 50_000)
                await start(master, name, 2, other_form=True)
                corrected = chain.command_pulses("Y", {"Y": AxisInput(50_000, -1)})
                expected["Y"].append((50_000, corrected))
            if name in (AZ, A6):  # an incremental move asked in its mode field: refused,
                # nothing of that write reaches the drive (a distance corrected as a position)
                seen = len(drives["Y"].received)
                if name == AZ:  # operation type 2: incremental from the command position
                    block = [0, 0, 0, 2, *target_words(name, 10_000), 0, 5000, 0, 10000, 0,
                             10000, 0, 1000, 0, 1]
                    rr = await master.write_registers(AZ_BLOCK, block, device_id=2)
                else:  # block 0's command code 1: relative
                    rr = await master.write_registers(A6_TABLE, [0x0100, 0,
                                                                 *target_words(name, 10_000)],
                                                      device_id=2)  # fmt: skip
                assert rr.isError() and rr.exception_code == 0x03
                assert len(drives["Y"].received) == seen
            if name == KINCO:  # a relative move (0x4F → 0x5F): a distance, refused (it
                # was corrected as a position: trial 9, 77 µm off), no start reaches it
                await set_target(master, name, 2, 10_000)
                await ok(await master.write_register(KINCO_CONTROL, 0x4F, device_id=2))
                rr = await master.write_register(KINCO_CONTROL, 0x5F, device_id=2)
                assert rr.isError() and rr.exception_code == 0x03
                assert await read32(direct, 2, f["address"], f["order"]) == expected["Y"][-1][1]
            for unit, axis in ((1, "X"), (2, "Y")):
                drive = drives[axis]
                assert started_targets(drive, name) == [c for _, c in expected[axis]]
                assert not target_values_seen(drive, name) & {n for n, _ in expected[axis]}
                if name == AZ:  # each move: the master's one block, as one write
                    assert all((e.address, len(e.values)) == (AZ_BLOCK, 16)
                               for e in drive.received)
                assert await control(direct, unit, 4) == 0  # its line silence always kept

    run(body())


@pytest.mark.parametrize(("name", "drives"), [(AZ, "rtu"), (A6, "rtu"), (KINCO, "rtu"),
                                             (A6, "tcp")])
def test_on_trigger_planar_pair_commits_both_before_the_start(tmp_path: Path, name: str,
                                                              drives: str):
    """(On a Modbus TCP bus too: a coil write there must not take the callback fast path
    that forwards a request without looking at it.)"""

    async def body():
        async with rig(tmp_path, gateway_profile(name, planar=True), XY_FILES, drives=drives,
                       sim_edit=sim_profile(name)) as r:
            master, chain = r["master"], r["chain"]
            x, y = r["sim"].sim.drives["X"], r["sim"].sim.drives["Y"]
            if name == AZ:  # both drives: data No. 0, operation type 1 (absolute)
                for unit in (1, 2):
                    await ok(await master.write_registers(AZ_BLOCK, [0, 0, 0, 1],
                                                          device_id=unit))
            await set_target(master, name, 2, 400_000)  # Y: held (on_trigger)
            assert 400_000 not in target_values_seen(y, name) and y.moves_started == 0
            await move(master, name, 1, 500_000)  # X's start commits Y, then X
            inputs = {"X": AxisInput(500_000, 1), "Y": AxisInput(400_000, 1)}
            want = {axis: chain.command_pulses(axis, inputs) for axis in ("X", "Y")}
            # Y's corrected target reached Y before X's start reached X, and Y did not move
            y_target = [e for e in y.received if want["Y"] in target_values_seen_of(e, name)]
            x_start = [e for e in x.received if e.started is not None]
            assert len(y_target) == 1 and len(x_start) == 1
            assert y_target[0].seq < x_start[0].seq and y.moves_started == 0
            # Y's own start (for the AZ the trigger's low word alone, which the drive
            # takes): its target is already corrected
            await start(master, name, 2, other_form=True)
            assert started_targets(x, name) == [want["X"]]
            assert started_targets(y, name) == [want["Y"]]
            for drive in (x, y):
                assert not target_values_seen(drive, name) & {500_000, 400_000}

    run(body())


def target_values_seen_of(entry, name: str) -> set[int]:
    target = regs(name)["target"]
    i = target["address"] - entry.address
    if entry.table != "holding" or not (i >= 0 and i + 1 < len(entry.values)):
        return set()
    return {unpack_int32(entry.values[i : i + 2], target["order"])}


@pytest.mark.parametrize("name", [AZ, A6, KINCO])
def test_exceptions_pass_through_and_a_refused_move_sends_nothing(tmp_path: Path, name: str):
    async def body():
        async with rig(tmp_path, gateway_profile(name), {"x.csv": PITCH_X}, drives="rtu",
                       sim_edit=sim_profile(name)) as r:
            master = r["master"]
            drive = r["sim"].sim.drives["X"]
            # outside travel: refused by compgw with 0x03, nothing reaches the drive (for
            # the AZ the whole block with its trigger: no start either)
            outside = target_words(name, -1000)
            if name == AZ:
                rr = await master.write_registers(AZ_BLOCK, [0, 0, 0, 1, *outside, *[0] * 9, 1],
                                                  device_id=1)
            elif name == A6:
                rr = await master.write_registers(A6_TABLE, [0x0200, 0, *outside], device_id=1)
            else:
                rr = await master.write_registers(0x4000, outside, device_id=1)
            assert rr.isError() and rr.exception_code == 0x03
            assert not drive.received and drive.moves_started == 0
            # the drive's own exception, relayed: a register it does not have
            rr = await master.read_holding_registers(0x7000, count=1, device_id=1)
            assert rr.isError() and rr.exception_code == 0x02
            if name == A6:  # a coil it does not have: the drive's 0x02, relayed
                rr = await master.write_coil(0x0121, True, device_id=1)
                assert rr.isError() and rr.exception_code == 0x02

    run(body())


def test_a_refused_start_leaves_the_edge_still_to_come(tmp_path: Path):
    """Kinco, planar on_trigger: the edge that is refused (a relative start) never reached
    the drive, so the master's next 0x3F is still an edge: the gateway must commit then, not
    forward it as a repeat (the drive would start on a stale target). A held target outside
    travel is refused at its write, not kept for the start."""

    async def body():
        async with rig(tmp_path, gateway_profile(KINCO, planar=True), XY_FILES, drives="rtu",
                       sim_edit=sim_profile(KINCO)) as r:
            master, chain = r["master"], r["chain"]
            x = r["sim"].sim.drives["X"]
            await set_target(master, KINCO, 2, 400_000)
            rr = await master.write_registers(0x4000, target_words(KINCO, 900_000),
                                              device_id=1)  # beyond X's 800 mm travel
            assert rr.isError() and rr.exception_code == 0x03
            await set_target(master, KINCO, 1, 500_000)
            await ok(await master.write_register(KINCO_CONTROL, 0x2F, device_id=1))
            rr = await master.write_register(KINCO_CONTROL, 0x5F, device_id=1)  # relative
            assert rr.isError() and rr.exception_code == 0x03 and x.moves_started == 0
            assert not x.received or all(e.address == KINCO_CONTROL for e in x.received)
            await ok(await master.write_register(KINCO_CONTROL, 0x3F, device_id=1))
            inputs = {"X": AxisInput(500_000, 1), "Y": AxisInput(400_000, 1)}
            assert started_targets(x, KINCO) == [chain.command_pulses("X", inputs)]

    run(body())


def test_a6_malformed_coil_write_is_refused_not_forwarded(tmp_path: Path):
    async def body():
        async with rig(tmp_path, gateway_profile(A6), {"x.csv": PITCH_X}, drives="rtu",
                       sim_edit=sim_profile(A6)) as r:
            raw = await RawTcpMaster.connect(r["app"].tcp_port)
            bus = r["app"].buses["line1"]
            before = bus.counters.transactions
            try:
                reply = await raw.request(1, bytes([0x05, 0x01, 0x20, 0x12, 0x34]))
            finally:
                await raw.close()
            assert reply == bytes([0x85, 0x03])  # compgw's: the coil value is not ON/OFF
            assert bus.counters.transactions == before  # never sent to the drive

    run(body())


def broadcast_start(name: str) -> list[bytes]:
    """The drive's start as broadcast request PDUs (unit 0)."""
    if name == AZ:
        return [build_write_multiple_registers(AZ_BLOCK + 14, [0, 1])]
    if name == A6:
        return [build_write_single_coil(A6_STB, True)]
    return [build_write_single_register(KINCO_CONTROL, w) for w in (0x2F, 0x3F)]


@pytest.mark.parametrize("name", [AZ, A6, KINCO])
def test_broadcast_start_commits_every_corrected_target_first(tmp_path: Path, name: str):
    def edit(data):
        gateway_profile(name, planar=True)(data)
        data["buses"]["line1"]["turnaround_s"] = 0.01

    async def body():
        async with rig(tmp_path, edit, XY_FILES, drives="rtu", sim_edit=sim_profile(name)) as r:
            master, chain = r["master"], r["chain"]
            drives = r["sim"].sim.drives
            bus = r["app"].buses["line1"]
            if name == AZ:
                for unit in (1, 2):
                    await ok(await master.write_registers(AZ_BLOCK, [0, 0, 0, 1],
                                                          device_id=unit))
            await set_target(master, name, 1, 300_000)  # both held (on_trigger)
            await set_target(master, name, 2, 200_000)
            raw = await RawTcpMaster.connect(r["app"].tcp_port)
            try:
                for pdu in broadcast_start(name):
                    assert not (await raw.request(0, pdu))[0] & 0x80
            finally:
                await raw.close()
            assert bus.counters.broadcasts == len(broadcast_start(name))  # unit-0 frames
            inputs = {"X": AxisInput(300_000, 1), "Y": AxisInput(200_000, 1)}
            # no reply on the line: the drives act when the frame arrives
            await wait_for_condition(lambda: all(d.moves_started for d in drives.values()))
            for axis in ("X", "Y"):
                assert started_targets(drives[axis], name) == [chain.command_pulses(axis,
                                                                                    inputs)]
                assert not target_values_seen(drives[axis], name) & {300_000, 200_000}

    run(body())


@pytest.mark.parametrize(("trigger", "message"), [
    ({"address": 0x0120, "table": "coils", "rising_bit": 0}, "coil trigger has no"),
    ({"address": 0x0120, "table": "coils", "value": 2}, r"trigger\.value: 2 is not in 0\.\.1"),
    ({"address": 0x0066, "words": 2, "rising_bit": 3}, "rising_bit needs words: 1"),
    ({"address": 0x3100, "value": 0x10000}, r"trigger\.value: 65536 is not in 0\.\.65535"),
    ({"address": 0x6200, "words": 2}, "overlaps the target pair"),
])
def test_trigger_config_errors_name_the_key(trigger: dict, message: str):
    data = {"upstream": {"tcp": {"port": 0}},
            "buses": {"b": {"rtu_over_tcp": {"host": "127.0.0.1", "port": 4001}}},
            "axes": {"X": {"bus": "b", "unit": 1, "pulse_mm": 0.001, "travel_mm": [0, 800],
                           "registers": {"target": {"address": 0x6201},
                                         "feedback": {"address": 0x602A},
                                         "trigger": trigger}}}}
    with pytest.raises(ConfigError, match=r"axes\.X\.registers.*" + message):
        parse_config(data)


def test_a_bus_is_one_of_rtu_tcp_or_rtu_over_tcp():
    bus = {"tcp": {"host": "127.0.0.1"}, "rtu_over_tcp": {"host": "127.0.0.1", "port": 4001}}
    data = {"upstream": {"tcp": {"port": 0}}, "buses": {"b": bus}}
    with pytest.raises(ConfigError, match=r"buses\.b: .*exactly one of rtu or tcp or "
                                          r"rtu_over_tcp"):
        parse_config(data)
    bus.pop("tcp")
    assert parse_config(data).buses["b"].rtu_over_tcp.baudrate == 19200


def test_split_block_sends_the_trigger_last(tmp_path: Path):
    """A block holding target and trigger that the drive takes only in pieces: the piece
    with the trigger goes last, whatever its address (here before the target)."""

    def sim_edit(data):
        axis = data["sim"]["axes"]["X"]
        axis["registers"] = {**axis.get("registers", {}), "fc16_max_words": 2,
                             "trigger": {"address": 0x6200, "value": 0x10, "home_value": None},
                             "memory": [{"address": 0x6200, "count": 8}]}

    def edit(data):
        x = data["axes"]["X"]
        x["fc16_max_words"] = 2
        x["registers"]["trigger"] = {"address": 0x6200, "value": 0x10}
        x["compensation"]["pitch"] = "x.csv"

    async def body():
        async with rig(tmp_path, edit, {"x.csv": PITCH_X}, drives="rtu",
                       sim_edit=sim_edit) as r:
            master, chain = r["master"], r["chain"]
            drive = r["sim"].sim.drives["X"]
            block = [0x10, *pack_int32(300_000), 7]  # trigger 0x6200, target, speed
            await ok(await master.write_registers(0x6200, block, device_id=1))
            corrected = chain.command_pulses("X", {"X": AxisInput(300_000, 1)})
            assert [e.address for e in drive.received] == [0x6201, 0x6203, 0x6200]
            assert [e.started for e in drive.received] == [None, None, corrected]
            assert await control(r["direct"], 1, 5) == 0  # no piece over its limit

    run(body())


def test_compgw_check_describes_the_trigger_shapes(tmp_path: Path):
    data = {"upstream": {"tcp": {"port": 0}},
            "buses": {"b": {"rtu_over_tcp": {"host": "127.0.0.1", "port": 4001}}},
            "axes": {name: {"bus": "b", "unit": unit, "profile": profile, "pulse_mm": 0.001,
                            "travel_mm": [0, 800], "ram_setting_applied": True}
                     for unit, (name, profile) in enumerate(
                         [("X", AZ), ("Y", A6), ("Z", KINCO)], start=1)}}
    config = parse_config(data)
    text = describe(config, build_chain(config, tmp_path))
    assert "b: rtu over tcp 127.0.0.1:4001 19200 8E1" in text
    assert "trigger 32-bit (hi_lo) 0x0066 on any write" in text
    assert "trigger coil 0x0120 on value 0x1" in text
    assert "trigger 0x3100 on rising bit 4" in text
    assert [w.split(":")[0] for w in warnings(config)] == ["axes.Y", "axes.Z"]  # unverified
    # a generated config's registers block left beside a profile (trial 8): said, per key
    data["axes"]["Z"]["registers"] = {"target": {"address": 0x6201, "order": "hi_lo"}}
    found = [w for w in warnings(parse_config(data)) if "registers" in w]
    assert found == ["axes.Z.registers.target: address 0x6201 where the kinco-fd profile has "
                     "0x4000: a registers block left from another drive beside the profile? "
                     'Remove it to take the profile\'s whole (docs/retrofit.md, "A profile '
                     'replaces the registers")']  # fmt: skip


def test_profiles_are_marked_with_their_sources():
    for name in (AZ, A6, KINCO):
        profile = PROFILES[name]
        assert profile.check and profile.notes
    assert PROFILES[AZ].verified and not PROFILES[A6].verified
    assert PROFILES[A6].axis["registers"]["trigger"]["table"] == "coils"


@pytest.mark.parametrize("name", sorted(PROFILES))
def test_calibration_moves_every_profile_as_its_master_does(tmp_path: Path, name: str):
    """compgw's own moves (calibrate, commission) on each drive family, through the gateway
    to the sim's emulation: the start as the drive wants it (a coil, the 32-bit field, a bit
    edge keeping the control word's other bits) and the end from the profile's status bits
    or, where they are not known, the feedback (trial 8: Kinco never moved, its enable bits
    written to 0 with the edge; Inovance waited 120 s on Leadshine's in-position bit 4)."""
    from gateway.calibration.measuring.machine import (
        Link,
        MachineDriver,
        MachineError,
        MotionSettings,
    )

    async def body():
        async with rig(tmp_path, gateway_profile(name), {"x.csv": PITCH_X}, drives="rtu",
                       sim_edit=sim_profile(name)) as r:
            master, direct, chain = r["master"], r["direct"], r["chain"]
            # what the machine's own master set up once: the rest of a block, the enable
            if name in (AZ, A6):
                await move(master, name, 1, 1_000)
            link = Link("127.0.0.1", r["app"].tcp_port, timeout_s=2)
            await link.connect()
            try:
                if name == KINCO:  # not switched on: it never moves, and the error says so
                    brief = MachineDriver(link, r["app"].config, MotionSettings(timeout_s=0.3))
                    with pytest.raises(MachineError, match=r"not in position at 5 mm after "
                                       r"0.3 s \(feedback at 0 mm, status 0x[0-9a-f]{4}, "
                                       r"in-position bit 10 set\): never moved\? a kinco-fd "
                                       r"drive needs profile position mode \(0x3500 = 1\) and "
                                       r"the drive switched on \(control word 0x3100 = "
                                       r"0x2F\)"):  # fmt: skip
                        await brief.move({"X": 5.0})
                    await ok(await master.write_register(KINCO_CONTROL, 0x2F, device_id=1))
                driver = MachineDriver(link, r["app"].config, MotionSettings(timeout_s=10))
                feedback = regs(name)["feedback"]
                for mm in (300.0, 120.5, 300.0):
                    await driver.move({"X": mm})
                    expected = chain.command_pulses("X", {"X": AxisInput(round(mm * 1000),
                                                                         1 if mm > 200 else -1)})
                    assert await read32(direct, 1, feedback["address"],
                                        feedback["order"]) == expected  # fmt: skip
                    assert await driver.feedback_pulses("X") == round(mm * 1000)
            finally:
                link.close()
            if name == KINCO:  # the enable bits kept: the edge only
                rr = await direct.read_holding_registers(KINCO_CONTROL, count=1, device_id=1)
                assert rr.registers[0] & 0x0F == 0x0F

    run(body())
