"""Thermal sources against the real simulator over a real TcpBus (no mocked Modbus).

The sim's truth (``sim.machine``) is the reference: its screw growth and temperatures are
computed by the sim's own model, independently of the gateway. Faults are switched through
the sim's control block (unit 250) over Modbus, as an operator's tool would.
"""

from __future__ import annotations

import asyncio
import contextlib
import socket
import time
from collections.abc import AsyncIterator
from typing import Any

import pytest

from gateway.config import GatewayConfig, ThermalSource, parse_config
from gateway.modbus.downstream import TcpBus
from gateway.modbus.frames import (
    build_read_request,
    build_write_multiple_registers,
    build_write_single_register,
    pack_int32,
    parse_read_registers_response,
    unpack_int32,
)
from gateway.sensors import SensorSet, ThermalSensor, ThermalState
from sim.server import SimServer
from tests.helpers_modbus import run, wait_for_condition
from tests.test_sim_support import config_from, example_dict

DELTA_A_UNIT, TEMP_UNIT, FAULTS_UNIT = 10, 23, 250
X_UNIT, X_TARGET, X_TRIGGER, TRIGGER_VALUE = 1, 0x6201, 0x6002, 0x10
A_MM = 800.0  # the sim's delta_a sensor sits at a_mm = 800 on X
ALPHA = 11.5e-6
CLEAR_FAULTS = 0x0804
MODE_SILENT, MODE_EXCEPTION = 1, 2


class FakeClock:
    """The filter's time, advanced by the test."""

    def __init__(self, t_s: float = 1000.0) -> None:
        self.t_s = t_s

    def __call__(self) -> float:
        return self.t_s


@contextlib.asynccontextmanager
async def sim_and_bus(timeout_s: float = 0.05) -> AsyncIterator[tuple[SimServer, TcpBus]]:
    async with SimServer(config_from(example_dict()), tcp_port=0) as server:  # 1 µm pulses
        assert server.tcp_port is not None
        bus = TcpBus("127.0.0.1", server.tcp_port, timeout_s=timeout_s, retries=0)
        try:
            yield server, bus
        finally:
            await bus.close()


async def heat_x(bus: TcpBus, moves: int = 50) -> None:
    """Full-travel moves on X: the sim heats its screw (instant at time_scale 0)."""
    for i in range(moves):
        target = 800_000 if i % 2 == 0 else 0
        await bus.transact(X_UNIT, build_write_multiple_registers(X_TARGET, pack_int32(target)))
        await bus.transact(X_UNIT, build_write_single_register(X_TRIGGER, TRIGGER_VALUE))


async def set_fault(bus: TcpBus, unit: int, mode: int) -> None:
    await bus.transact(FAULTS_UNIT, build_write_single_register(unit * 8, mode))


async def clear_faults(bus: TcpBus) -> None:
    await bus.transact(FAULTS_UNIT, build_write_single_register(CLEAR_FAULTS, 1))


def true_delta_a_mm(server: SimServer, axis: str = "X", a_mm: float = A_MM) -> float:
    return server.sim.machine.delta_a_mm(axis, a_mm, server.sim.clock.now_s())


def source(**kw: Any) -> ThermalSource:
    base: dict[str, Any] = {"bus": "line1", "unit": DELTA_A_UNIT,
                            "register": {"address": 0, "table": "input", "words": 1},
                            "scale_mm": 0.001, "poll_s": 0.05, "max_rate_mm_s": 0.01}
    base.update(kw)
    return ThermalSource.model_validate(base)


def gateway_config(port: int) -> GatewayConfig:
    """X fed by the Δa sensor, Y by its screw temperature (channel 1 of unit 23)."""

    def axis(unit: int, thermal: dict[str, Any]) -> dict[str, Any]:
        return {"bus": "line1", "unit": unit, "pulse_mm": 0.001, "travel_mm": [0, 800],
                "registers": {"target": {"address": X_TARGET},
                              "feedback": {"address": 0x602A}},
                "compensation": {"thermal": thermal}}

    return parse_config({
        "upstream": {"tcp": {"port": 0}},
        "buses": {"line1": {"tcp": {"host": "127.0.0.1", "port": port}}},
        "axes": {"X": axis(1, {"source": "x_ref", "length_mm": A_MM}),
                 "Y": axis(2, {"source": "y_temp", "length_mm": 600})},
        "thermal_sources": {
            "x_ref": {"bus": "line1", "unit": DELTA_A_UNIT,
                      "register": {"address": 0, "table": "input"}, "scale_mm": 0.001},
            "y_temp": {"bus": "line1", "unit": TEMP_UNIT, "kind": "temperature",
                       "register": {"address": 1, "table": "holding"}, "scale_c": 0.01,
                       "alpha_per_k": ALPHA, "reference_c": 20.0},
        },
    })


# ---------------------------------------------------------------------------- readings


@pytest.mark.parametrize("register", [
    {"address": 0, "table": "input", "words": 1},  # int16, 1 µm steps
    {"address": 1, "table": "holding", "words": 2, "order": "hi_lo"},  # int32 nm
], ids=["int16-um-fc04", "int32-nm-fc03"])
def test_delta_a_matches_sim_truth_after_moves(register: dict[str, Any]) -> None:
    scale_mm = 0.001 if register["words"] == 1 else 1e-6

    async def main() -> None:
        async with sim_and_bus() as (server, bus):
            clock = FakeClock()
            # noise_mm: the sim quantises both registers to 1 µm
            sensor = ThermalSensor("x_ref", source(register=register, scale_mm=scale_mm),
                                   bus, clock=clock, noise_mm=0.002)
            assert await sensor.poll_once() == "accepted"
            assert sensor.delta_a_mm == 0.0 and sensor.state is ThermalState.STARTING
            await heat_x(bus)
            truth_mm = true_delta_a_mm(server)
            assert truth_mm > 0.010  # the moves really heated the screw
            # a long pause (in filter time): the step is within max_rate over the gap
            clock.t_s += 60.0
            for _ in range(10):
                assert await sensor.poll_once() == "accepted"
                clock.t_s += 1.0
            assert sensor.state is ThermalState.OK
            # quantised to 1 µm, noise 0.1 µm: within one step of the truth
            assert sensor.delta_a_mm == pytest.approx(truth_mm, abs=0.001)
            assert sensor.delta_a_mm_for(A_MM) == sensor.delta_a_mm
            # and equal to the sim's nm register read directly
            words = parse_read_registers_response(
                await bus.transact(DELTA_A_UNIT, build_read_request(4, 1, 2)))
            assert sensor.delta_a_mm == pytest.approx(unpack_int32(words) * 1e-6, abs=0.0011)
            c = sensor.counters
            assert (c.reads, c.accepted, c.failures, c.rejected) == (11, 11, 0, 0)

    run(main())


def test_sensor_set_per_axis_from_config() -> None:
    """Displacement (X) and temperature (Y, its own length) through SensorSet."""

    async def main() -> None:
        async with sim_and_bus() as (server, bus):
            await heat_x(bus, 20)
            for i in range(20):  # heat Y too
                target = 600_000 if i % 2 == 0 else 0
                await bus.transact(2, build_write_multiple_registers(X_TARGET,
                                                                     pack_int32(target)))
                await bus.transact(2, build_write_single_register(X_TRIGGER, TRIGGER_VALUE))
            cfg = gateway_config(server.tcp_port or 0)
            clock = FakeClock()
            sensors = SensorSet.from_config(cfg.thermal_sources, {"line1": bus},
                                            axes=cfg.axes, clock=clock)
            assert sensors["y_temp"].reference_length_mm == 600.0
            assert sensors.axis_delta_a_mm("X") == 0.0  # starting: the cold state
            for _ in range(6):
                for name in sensors:
                    await sensors[name].poll_once()
                clock.t_s += 1.0
            assert {sensors[n].state for n in sensors} == {ThermalState.OK}
            now = server.sim.clock.now_s()
            t_y = server.sim.machine.screw_temp_C("Y", now)
            assert t_y > 20.3
            assert sensors["y_temp"].temperature_c == pytest.approx(t_y, abs=0.02)
            dy = sensors.axis_delta_a_mm("Y")
            assert dy == pytest.approx(ALPHA * 600 * (t_y - 20.0), abs=ALPHA * 600 * 0.02)
            assert dy == pytest.approx(true_delta_a_mm(server, "Y", 600.0), abs=0.0002)
            dx = sensors.axis_delta_a_mm("X")
            assert dx == pytest.approx(true_delta_a_mm(server), abs=0.001)
            assert sensors.axis_delta_a_mm("Z") is None  # no thermal source
            assert not sensors.alarm

    run(main())


# ---------------------------------------------------------------------------- faults


@pytest.mark.parametrize("mode", [MODE_SILENT, MODE_EXCEPTION], ids=["silent", "exception"])
def test_dead_sensor_hold_then_alarm_stepped(mode: int) -> None:
    """Injected clock: the alarm comes exactly when hold_s has passed since the last good."""

    async def main() -> None:
        async with sim_and_bus() as (_server, bus):
            clock = FakeClock()
            sensor = ThermalSensor("x_ref", source(hold_s=5.0, fallback="zero"), bus,
                                   clock=clock)
            for _ in range(3):
                await sensor.poll_once()
                clock.t_s += 1.0
            last_good_s = clock.t_s - 1.0
            assert sensor.state is ThermalState.OK
            await set_fault(bus, DELTA_A_UNIT, mode)
            clock.t_s = last_good_s + 4.99
            assert await sensor.poll_once() == "failed"
            assert sensor.state is ThermalState.HOLDING and sensor.delta_a_mm == 0.0
            expected = "DriveTimeout" if mode == MODE_SILENT else "SensorReadError"
            assert sensor.last_error is not None and sensor.last_error.startswith(expected)
            clock.t_s = last_good_s + 5.0
            await sensor.poll_once()
            assert sensor.alarm and sensor.delta_a_mm == 0.0
            await clear_faults(bus)
            for i in range(3):
                clock.t_s += 1.0
                await sensor.poll_once()
                assert sensor.alarm == (i < 2)  # three consistent readings to recover
            assert sensor.counters.failures == 2

    run(main())


@pytest.mark.parametrize(("mode", "fallback"), [(MODE_SILENT, "hold"),
                                                (MODE_EXCEPTION, "zero"),
                                                (MODE_EXCEPTION, "disable")])
def test_dead_sensor_live_loop(mode: int, fallback: str) -> None:
    """The real poll loop and clock: holding, alarm after hold_s, fallback, recovery."""
    hold_s = 0.3

    async def main() -> None:
        async with sim_and_bus() as (server, bus):
            await heat_x(bus, 30)
            truth_mm = true_delta_a_mm(server)
            sensor = ThermalSensor("x_ref", source(hold_s=hold_s, fallback=fallback,
                                                   max_rate_mm_s=1.0), bus)
            stop = asyncio.Event()
            task = asyncio.create_task(sensor.run(stop))
            try:
                await wait_for_condition(lambda: sensor.state is ThermalState.OK, 3.0)
                await wait_for_condition(lambda: sensor.counters.accepted >= 8, 3.0)
                held_mm = sensor.delta_a_mm
                assert held_mm == pytest.approx(truth_mm, abs=0.001)

                await set_fault(bus, DELTA_A_UNIT, mode)
                dead_s = time.monotonic()
                await wait_for_condition(lambda: sensor.state is ThermalState.HOLDING, 3.0)
                assert sensor.delta_a_mm == held_mm and not sensor.alarm
                await wait_for_condition(lambda: sensor.alarm, 3.0)
                # not at the first failure: hold_s counts from the last good reading, which
                # came at most a poll (plus scheduling slack) before the fault
                assert time.monotonic() - dead_s >= hold_s / 2
                expected = {"hold": held_mm, "zero": 0.0, "disable": None}[fallback]
                assert sensor.delta_a_mm == expected

                await clear_faults(bus)
                await wait_for_condition(lambda: sensor.state is ThermalState.OK, 3.0)
                assert sensor.delta_a_mm == pytest.approx(truth_mm, abs=0.001)
                assert sensor.counters.failures >= 2
            finally:
                stop.set()
                await asyncio.wait_for(task, 1.0)

    run(main())


def test_no_busy_loop_on_a_dead_bus() -> None:
    """Nothing listens: every read fails at once; the loop still waits poll_s."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]  # closed again: connections are refused

    async def main() -> None:
        bus = TcpBus("127.0.0.1", port, timeout_s=0.05, retries=0)
        sensor = ThermalSensor("x_ref", source(poll_s=0.05, hold_s=0.2), bus)
        stop = asyncio.Event()
        started = time.monotonic()
        task = asyncio.create_task(sensor.run(stop))
        await wait_for_condition(lambda: sensor.alarm, 3.0)
        await asyncio.sleep(0.3)
        stop.set()
        await asyncio.wait_for(task, 0.5)  # stops promptly
        elapsed = time.monotonic() - started
        assert sensor.counters.failures == sensor.counters.reads
        assert sensor.last_error is not None and "BusUnavailable" in sensor.last_error
        assert 3 <= sensor.counters.reads <= elapsed / 0.05 + 2
        assert sensor.delta_a_mm == 0.0  # hold with nothing to hold: the cold state

    run(main())


def test_silent_sensor_does_not_hog_the_line() -> None:
    """A failed read that took timeout_s is followed by at least as long a pause."""

    async def main() -> None:
        async with sim_and_bus(timeout_s=0.1) as (_server, bus):
            await set_fault(bus, DELTA_A_UNIT, MODE_SILENT)
            sensor = ThermalSensor("x_ref", source(poll_s=0.01, hold_s=0.0), bus)
            stop = asyncio.Event()
            started = time.monotonic()
            task = asyncio.create_task(sensor.run(stop))
            await wait_for_condition(lambda: sensor.counters.reads >= 3, 3.0)
            stop.set()
            await asyncio.wait_for(task, 1.0)
            elapsed = time.monotonic() - started
            # each read takes ~0.1 s and is followed by ~0.1 s of silence
            assert sensor.counters.reads <= elapsed / 0.2 + 1
            assert bus.counters.timeouts == sensor.counters.reads

    run(main())


def test_sensor_set_checks_buses_and_axis_sources() -> None:
    cfg = gateway_config(1)
    bus = TcpBus("127.0.0.1", 1)
    with pytest.raises(ValueError, match=r"thermal_sources\.x_ref\.bus"):
        SensorSet.from_config(cfg.thermal_sources, {}, axes=cfg.axes)
    sensors = SensorSet.from_config(cfg.thermal_sources, {"line1": bus}, axes=cfg.axes)
    assert set(sensors.axis_thermal) == {"X", "Y"}
    y = cfg.axes["Y"].compensation.thermal
    assert y is not None
    with pytest.raises(ValueError, match=r"axes\.Y\.compensation\.thermal\.source"):
        sensors.set_axis_thermal({"Y": y.model_copy(update={"source": "nope"})})
    assert set(sensors.axis_thermal) == {"X", "Y"}  # unchanged after a refused reload
    sensors.set_axes({"X": cfg.axes["X"]})
    assert sensors.axis_delta_a_mm("Y") is None and sensors.axis_delta_a_mm("X") == 0.0
