"""The machine's clock where it is not the computer's (``machine_clock``): a simulator at
``time_scale: 0`` lives hours in a minute, and the heat of motion must count them.

Issue 52's README trial: `compgw sim --random-machine 7` ran its hours of commissioning in
minutes of wall time; the gateway's heat from motion cooled by the wall clock, so the
heat of hours of runs stayed in it, and the tighter rerun read Y 2.35 → 6.87 µm as read.
"""

from __future__ import annotations

import asyncio
from pathlib import Path

import pytest

from gateway.calibration.measuring.machine import GatewayClock, Link
from gateway.modbus.frames import unpack_int32
from gateway.status import MACHINE_CLOCK_REGISTER, format_status
from tests.gateway_rig import rig
from tests.test_gateway_e2e import move, run

STATUS_UNIT, SIM_CONTROL_UNIT, ADVANCE_S, CLOCK_MS = 247, 250, 0x0800, 0x0802
TAU_S = 600.0


def with_motion_heat(clock: bool):
    def edit(data):
        data["axes"]["X"]["compensation"]["thermal"] = {
            "length_mm": 800,
            "motion": {"delta_a_um_per_m": 20.0, "tau_s": TAU_S, "speeds_mm_s": {"X": 100.0}},
        }
        if clock:
            data["machine_clock"] = {
                "bus": "line1", "unit": SIM_CONTROL_UNIT,
                "register": {"address": CLOCK_MS, "table": "holding", "words": 2,
                             "signed": False},
            }  # fmt: skip

    return edit


async def _status(master) -> list[int]:
    rr = await master.read_input_registers(0, count=123, device_id=STATUS_UNIT)
    assert not rr.isError(), rr
    return rr.registers


def _x_delta_a_um(regs: list[int]) -> float:
    return unpack_int32(regs[19:21], "hi_lo") / 10.0


async def _sim_clock_s(direct) -> float:
    rr = await direct.read_holding_registers(CLOCK_MS, count=2, device_id=SIM_CONTROL_UNIT)
    assert not rr.isError(), rr
    return unpack_int32(rr.registers, "hi_lo", signed=False) / 1000.0


async def _advance_s(direct, seconds: int) -> None:
    while seconds > 0:
        step = min(seconds, 0xFFFF)
        rr = await direct.write_register(ADVANCE_S, step, device_id=SIM_CONTROL_UNIT)
        assert not rr.isError(), rr
        seconds -= step


async def _work_and_rest(r) -> tuple[float, float, list[int], list[int]]:
    """X travels 0.9 m (heat), then the machine stands five τ of its own clock: X's Δa
    (µm) as the status unit shows it before and after the rest, and both images."""
    master, direct = r["master"], r["direct"]
    for pulses in (300_000, 0, 300_000, 0):
        await move(master, 1, pulses)
    warm = await _status(master)
    await _advance_s(direct, int(5 * TAU_S))
    await move(master, 2, 1_000)  # Y (no heat of its own) moves: the clock is read for it
    rested = await _status(master)
    return _x_delta_a_um(warm), _x_delta_a_um(rested), warm, rested


def test_heat_from_motion_cools_on_the_machines_clock(tmp_path: Path):
    """With ``machine_clock`` the screw cools while the machine stands, by the machine's
    clock; without it the gateway's wall clock saw a few ms and the heat stays. The status
    unit shows the clock as the last correction read it (a move of Y after the rest)."""

    async def body():
        async with rig(tmp_path / "clock", with_motion_heat(True)) as r:
            warm, rested, before, after = await _work_and_rest(r)
            sim_s = await _sim_clock_s(r["direct"])
        async with rig(tmp_path / "wall", with_motion_heat(False)) as r:
            wall_warm, wall_rested, wall_regs, _ = await _work_and_rest(r)
        return warm, rested, before, after, sim_s, wall_warm, wall_rested, wall_regs

    (tmp_path / "clock").mkdir()
    (tmp_path / "wall").mkdir()
    warm, rested, before, after, sim_s, wall_warm, wall_rested, wall_regs = run(body())
    # 1.2 m of travel (the first move from an unknown place counts none) at 20 µm/m, the
    # moves' own 12 s of cooling: about 17.6 µm, either way
    assert warm == pytest.approx(17.6, abs=0.5) and wall_warm == pytest.approx(warm, abs=0.2)
    assert rested < 0.02 * warm  # e^-5 of it: the screw cooled for 3000 s of machine time
    assert wall_rested > 0.95 * wall_warm  # the wall clock saw milliseconds
    # the status unit shows the machine's clock, read afresh for the read
    assert before[MACHINE_CLOCK_REGISTER] == after[MACHINE_CLOCK_REGISTER] == 1
    ms = [unpack_int32(regs[121:123], "hi_lo", signed=False) for regs in (before, after)]
    # the first image: as read before the last move of X (3 s of it since); the second:
    # the rest and that move
    assert ms[1] - ms[0] == pytest.approx(5 * TAU_S * 1000 + 3000, abs=100)
    assert ms[1] / 1000.0 == pytest.approx(sim_s, abs=0.05)  # (less Y's move)
    assert "machine clock: " in format_status(["X", "Y"], [], after)
    assert wall_regs[MACHINE_CLOCK_REGISTER : MACHINE_CLOCK_REGISTER + 3] == [0, 0, 0]
    assert "machine clock" not in format_status(["X", "Y"], [], wall_regs)


def test_commissioning_reads_the_machines_clock_through_the_gateway_past_its_wrap(
        tmp_path: Path):  # fmt: skip
    """`compgw commission` times its drift log and readings by what the status unit shows,
    read after each move (as the gateway read it for the move's target); a 32-bit ms
    counter wraps after 49.7 days and the time goes on.
    A gateway that shows no machine clock is asked once: the computer's clock counts."""

    async def body():
        async with rig(tmp_path, with_motion_heat(True)) as r:
            direct = r["direct"]
            link = Link("127.0.0.1", r["app"].tcp_port)
            await link.connect()
            try:
                clock = GatewayClock()
                await _advance_s(direct, (1 << 32) // 1000 - 20)  # 20 s before the wrap
                await clock.refresh(link, STATUS_UNIT)
                first_s = clock.now_s()
                sim_first_s = await _sim_clock_s(direct)
                await _advance_s(direct, 50)
                await move(r["master"], 1, 0)  # the gateway reads the clock for a target
                await clock.refresh(link, STATUS_UNIT)
                return clock.shown, first_s, sim_first_s, clock.now_s(), \
                    await _sim_clock_s(direct)  # fmt: skip
            finally:
                link.close()

    shown, first_s, sim_first_s, then_s, sim_then_s = run(body())
    assert shown is True
    assert first_s == pytest.approx(sim_first_s, abs=0.01)
    assert sim_then_s < sim_first_s  # the sim's register wrapped
    assert then_s - first_s == pytest.approx(50.0, abs=0.01)  # the time went on
    assert then_s == pytest.approx(sim_first_s + 50.0, abs=0.01)

    async def without():
        async with rig(tmp_path / "none") as r:
            link = Link("127.0.0.1", r["app"].tcp_port)
            await link.connect()
            try:
                clock = GatewayClock()
                await clock.refresh(link, STATUS_UNIT)
                return clock.shown, clock.now_s()
            finally:
                link.close()

    (tmp_path / "none").mkdir()
    loop_s = asyncio.run(_wall_now())
    shown, now_s = run(without())
    assert shown is False and now_s == pytest.approx(loop_s, abs=30.0)


def test_a_machine_that_stood_shows_its_clock_read_afresh(tmp_path: Path):
    """Issue 52's README trial, cooled: the sim's clock advanced 3 h between two runs, and
    the run carried on said "it has stood 0 minutes since": the status unit showed the
    clock as the last correction read it, and nothing had moved. Where no correction read
    it since a master last read it there, the status unit reads it for the read."""

    def ms(regs: list[int]) -> int:
        return unpack_int32(regs[121:123], "hi_lo", signed=False)

    async def body():
        async with rig(tmp_path, with_motion_heat(True)) as r:
            master, direct = r["master"], r["direct"]
            await move(master, 1, 100_000)  # 1 s of it after the correction read the clock
            after_move = await _status(master)  # as that correction read it
            moved_s = await _sim_clock_s(direct)
            await _advance_s(direct, 10_800)  # the machine stands 3 h
            stood = await _status(master)  # nothing moved since: read afresh
            again = await _status(master)
            await move(master, 1, 0)
            moving = await _status(master)  # as the correction read it: before the move
            return after_move, moved_s, stood, again, moving, await _sim_clock_s(direct)

    after_move, moved_s, stood, again, moving, end_s = run(body())
    assert ms(after_move) == pytest.approx((moved_s - 1.0) * 1000, abs=50)
    assert ms(stood) == pytest.approx((moved_s + 10_800) * 1000, abs=50)
    assert ms(again) == ms(stood)
    assert ms(moving) == ms(stood) and end_s == pytest.approx(moved_s + 10_801, abs=0.05)


async def _wall_now() -> float:
    import time

    return time.time()


def test_check_names_the_machine_clock_and_a_reload_cannot_change_it(tmp_path: Path):
    """`compgw check` says the gateway counts a simulator's clock; a reload that adds or
    drops it is refused (the heat counted so far is in one clock's seconds)."""
    import yaml

    from gateway.app import load
    from gateway.setup_report import describe

    async def body():
        async with rig(tmp_path, with_motion_heat(True)) as r:
            path = r["config_path"]
            config, chain = load(path)
            text = describe(config, chain)
            data = yaml.safe_load(path.read_text())
            data.pop("machine_clock")
            path.write_text(yaml.safe_dump(data))
            return text, await r["app"].reload_file()

    text, refused = run(body())
    assert "machine clock: line1 unit 250 holding 0x802, 0.001 s per count" in text
    assert refused is not None and "machine_clock cannot change on reload" in refused


def test_without_a_machine_clock_the_heat_keeps_its_classes_default_clock(tmp_path: Path):
    """No ``machine_clock``: the move log and travel profiles keep their classes' own
    default clock (the computer's). bench/lockstep.py puts the simulated machine's clock
    in those defaults; a clock passed in their place went past it, and the bench's
    gateway counted rough-0's heat on the wall clock (X E 27.6 µm as read, 3.4 with the
    drift taken off)."""
    from gateway.thermal_travel import MoveLog, TravelHistory

    def with_profile(data):
        with_motion_heat(False)(data)
        data["axes"]["Y"]["compensation"]["thermal"] = {
            "length_mm": 800, "motion": {"delta_a_um_per_m": 20.0, "tau_s": TAU_S},
            "profile": {"spread_mm": 50.0, "memory_s": 600.0}}  # fmt: skip

    async def body():
        async with rig(tmp_path, with_profile) as r:
            app = r["app"]
            return app.sensors.moves.clock, [t.clock for t in app.gateway.shared.travel.values()]

    moves_clock, travel_clocks = run(body())
    assert moves_clock is MoveLog.__init__.__defaults__[0]
    assert travel_clocks and all(c is TravelHistory.__init__.__defaults__[0]
                                 for c in travel_clocks)  # fmt: skip


def test_a_measuring_session_times_its_readings_by_the_machines_clock(tmp_path: Path):
    """The readings' ``time_s`` (what a warm-up's heat fit is timed by) counts the
    machine's clock as the gateway shows it: seconds of moves at the sim's 100 mm/s,
    where the computer's clock saw milliseconds (a move late: heat takes minutes)."""
    from gateway.app import load
    from gateway.calibration.measuring.machine import Endpoint
    from gateway.calibration.measuring.session import Instruments, Session
    from gateway.calibration.plans.plans import targets_plan
    from gateway.calibration.plans.rawdata import read_raw_csv

    async def body():
        async with rig(tmp_path, with_motion_heat(True)) as r:
            config, _ = load(r["config_path"])
            gateway = Endpoint("127.0.0.1", r["app"].tcp_port, 1)
            laser = Instruments(laser=Endpoint("127.0.0.1", r["sim"].tcp_port, 20))
            plan = targets_plan("X", (0.0, 800.0), [100.0, 300.0, 500.0], runs=1)
            spans = {}
            for label, clock in (("machine", GatewayClock()), ("computer", None)):
                raw = tmp_path / f"{label}.csv"
                start_s = await _sim_clock_s(r["direct"])
                await Session(config, tmp_path, gateway, laser, clock=clock).run(plan, raw,
                                                                                 "off")
                t = [float(v) for v in read_raw_csv(raw).extra["time_s"]]
                spans[label] = (float(t[-1] - t[0]), await _sim_clock_s(r["direct"]) - start_s)
            return spans

    spans = run(body())
    span_s, sim_s = spans["machine"]
    # each reading timed as the gateway read the clock for its move's target: from the
    # start of the move to the first reading (100 mm) to the start of the move to the
    # last (back from 300 mm), 603 mm at 100 mm/s; the whole run took longer
    assert span_s == pytest.approx(6.03, abs=0.05) and span_s < sim_s, spans
    wall_s, _ = spans["computer"]
    assert wall_s < span_s / 2, spans  # the computer's clock: the moves took no time
