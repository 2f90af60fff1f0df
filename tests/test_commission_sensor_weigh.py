"""A temperature sensor kept by its zone warm-up, weighed again on the drift references.

The warm-up fits the sensor's gain and heat from motion on the same strokes, and keeps the
sensor unless motion is better there by more than the noise. The drift references of the
whole commissioning are another duty cycle: the growth they read (what the sensor's
compensation took off put back, from its reading logged with the references), and what the
sensor's model at its fitted gain and heat from motion would have left of it, decide once
more before the rounds (:meth:`ThermalSteps.weigh_sensors`).
"""

from __future__ import annotations

import types
from pathlib import Path

import numpy as np
import pytest

from gateway.calibration.commissioning.axes import Axes
from gateway.calibration.commissioning.drift import DriftRefs
from gateway.calibration.commissioning.record import Record
from gateway.calibration.commissioning.thermal import ThermalSteps
from gateway.calibration.fitting.adaptive import thermal_mm
from gateway.calibration.thermal.heat_fit import sensor_gives_way
from gateway.compensation.thermal import motion_heat_series_m

ORIGIN_MM, LENGTH_MM, ALPHA, REF_C, START_C = -40.0, 640.0, 11.5e-6, 20.0, 21.0
GAIN = 0.6  # the warm-up's: the screw grows 0.6 of α·ΔT at the sensor (configured: 1)
REFS_MM = np.array([31.0, 570.0])  # Axes.ref_positions on 0-600 mm
MOTION = {"origin_mm": ORIGIN_MM, "length_mm": LENGTH_MM,
          "motion": {"delta_a_um_per_m": 0.9, "tau_s": 900.0, "speeds_mm_s": {"X": 100.0}}}
COMMANDS = {"mm": list(REFS_MM), "thermal": "sensor",
            "sensor": [ORIGIN_MM, LENGTH_MM, 1.0, ALPHA, REF_C]}


#: what the warm-up's two models left at its places (µm RMS): motion not under half of the
#: sensor (smooth-1 X at 8 h), and under half but by less than NOISE_UM (rough-9 Y)
WARMUP_EVEN, WARMUP_UNDER_HALF = (0.26, 0.34), (0.36, 0.84)


def _steps(tmp_path: Path, warmup_rms_um: tuple[float, float] = WARMUP_EVEN,
           candidate: dict | None = None) -> tuple[ThermalSteps, Record]:  # fmt: skip
    """Axis X (0-600 mm) with a temperature sensor, its warm-up having kept the sensor and
    fitted heat from motion beside it (the candidate; leaving ``warmup_rms_um``, motion's
    and the sensor's), the references' scatter 0.2 µm."""
    th = types.SimpleNamespace(source="t", origin_mm=ORIGIN_MM, length_mm=LENGTH_MM, gain=1.0)
    config = types.SimpleNamespace(
        axes={"X": types.SimpleNamespace(rotary=False, travel_mm=(0.0, 600.0), pulse_mm=0.001,
                                         compensation=types.SimpleNamespace(thermal=th))},
        thermal_sources={"t": types.SimpleNamespace(kind="temperature", alpha_per_k=ALPHA,
                                                    reference_c=REF_C)})  # fmt: skip
    settings = types.SimpleNamespace(axes=("X",), instruments=types.SimpleNamespace(
        temperature=None))  # fmt: skip
    axes = Axes(settings, config)  # type: ignore[arg-type]
    record = Record(tmp_path, tmp_path)
    record.state.update({
        "notes": [], "start_temperature_c": {"X": START_C}, "ref_commands": {"X": COMMANDS},
        "ref_scatter": {"X": [10 * 0.2e-3**2, 10]},
        "identify": {"thermal-X": {"gain": GAIN, "motion": {
            "replaces_sensor": False, "motion_rms_um": warmup_rms_um[0],
            "sensor_rms_um": warmup_rms_um[1], "candidate": candidate or MOTION}}}})  # fmt: skip
    drift = DriftRefs(axes, record, print)
    return ThermalSteps(axes, record, drift, lambda _: None), record


#: readings under a config with the sensor off (a warm-up's): the references read the growth
OFF = range(8, 14)


def _log(drift: DriftRefs, temperatures_c: np.ndarray, growth_um: np.ndarray,
         strokes_m: np.ndarray) -> None:
    """The references read under the sensor's compensation: the growth less what it took
    off at each reading's temperature, logged with the temperature; the whole growth under
    a config with the sensor off (OFF)."""
    for i, (t_c, g_um, odo_m) in enumerate(zip(temperatures_c, growth_um,
                                               np.cumsum(strokes_m))):  # fmt: skip
        loaded = {**COMMANDS, "thermal": "None"} if i in OFF else COMMANDS
        drift.record.state["ref_commands"] = {"X": loaded}
        took_mm = np.subtract(thermal_mm(loaded, t_c), thermal_mm(loaded, START_C))
        drift.log_drift({"X": list(g_um * 1e-3 + took_mm)}, {"X": 1000.0 * odo_m},
                        120.0 * (i + 1), {"X": float(t_c)})  # fmt: skip


@pytest.mark.parametrize("sensor_follows", [False, True])
def test_a_kept_sensor_gives_way_to_motion_only_where_the_references_say_so(
        tmp_path: Path, sensor_follows: bool) -> None:  # fmt: skip
    """Heat from motion grows the screw. A sensor whose reading follows that heat, at the
    gain its warm-up fitted, leaves the references at their scatter and is kept (at the
    configured gain, which the references were read with, it over-corrects by two thirds;
    where the config then loaded had it off, the references read the whole growth);
    one that warms on its own clock (a spot the nut's heat reaches late) leaves
    micrometres, and heat from motion replaces it, said, noted and kept in the
    identification results."""
    rng = np.random.default_rng(5)
    strokes = rng.uniform(0.0, 30.0, 40)  # m of travel between readings, 120 s apart
    heat_m = motion_heat_series_m(strokes, np.maximum(strokes * 10.0, 120.0), 900.0)
    growth_um = 0.9 * heat_m[:, None] * (REFS_MM - ORIGIN_MM)[None, :] / LENGTH_MM
    per_k_um = 1e3 * ALPHA * LENGTH_MM  # Δa per kelvin (µm)
    if sensor_follows:
        temps = START_C + 0.9 * heat_m / per_k_um / GAIN
    else:
        temps = START_C + 0.9 * heat_m.max() / per_k_um * (1 - np.exp(-np.arange(40) / 60.0))
    steps, record = _steps(tmp_path)
    _log(steps.drift, temps, growth_um + rng.normal(0.0, 0.1, growth_um.shape), strokes)
    took = np.array([e["sensor_um"]["X"] for e in record.state["drift_log"]])
    if sensor_follows:  # (the log's sign: the sensor's command takes the growth off)
        on = [i for i in range(40) if i not in OFF]
        np.testing.assert_allclose(took[on], -growth_um[on] / GAIN, rtol=1e-3)
        assert not took[list(OFF)].any()
    steps.weigh_sensors()
    motion = record.state["identify"]["thermal-X"]["motion"]
    weighed = motion["weighed"]
    assert weighed["readings"] == 40
    assert weighed["replaces"] is not sensor_follows, weighed
    assert (steps.drift.replacing_motion("X") == MOTION) is not sensor_follows
    # a sensor kept levels the readings itself: neither the references' drift nor a
    # line between a table's sets is taken off them
    assert steps.drift.sensor_kept("X") is sensor_follows
    assert steps.drift.drift_taken_off("X") is not sensor_follows
    assert bool(record.state["notes"]) is not sensor_follows
    if sensor_follows:
        assert weighed["sensor_left_um"] < 0.2, weighed
    else:
        assert weighed["motion_left_um"] < 0.2 < 1.0 < weighed["sensor_left_um"], weighed
        assert motion["replaces_sensor"] and "replace the sensor" in record.state["notes"][-1]
    steps.weigh_sensors()  # once: weighed already
    assert len(record.state["notes"]) == (0 if sensor_follows else 1)


def _following_sensor(tmp_path: Path, warmup_rms_um: tuple[float, float],
                      candidate: dict | None = None) -> tuple[ThermalSteps, Record]:  # fmt: skip
    """Heat from motion (MOTION) grows the screw and the sensor follows it at the warm-up's
    gain: the references read under it, with 0.1 µm of noise."""
    rng = np.random.default_rng(5)
    strokes = rng.uniform(0.0, 30.0, 40)
    heat_m = motion_heat_series_m(strokes, np.maximum(strokes * 10.0, 120.0), 900.0)
    growth_um = 0.9 * heat_m[:, None] * (REFS_MM - ORIGIN_MM)[None, :] / LENGTH_MM
    temps = START_C + 0.9 * heat_m / (1e3 * ALPHA * LENGTH_MM) / GAIN
    steps, record = _steps(tmp_path, warmup_rms_um, candidate)
    _log(steps.drift, temps, growth_um + rng.normal(0.0, 0.1, growth_um.shape), strokes)
    return steps, record


def test_where_the_warm_up_and_the_references_agree_motion_replaces_the_sensor(
        tmp_path: Path) -> None:  # fmt: skip
    """The warm-up had motion under half of the sensor, by less than the noise; the
    references (a sensor that follows the heat, so both models leave about their scatter)
    leave no more with motion, within their scatter: two duty cycles agree, heat from motion
    replaces the sensor, and the note says both."""
    steps, record = _following_sensor(tmp_path, WARMUP_UNDER_HALF)
    steps.weigh_sensors()
    weighed = record.state["identify"]["thermal-X"]["motion"]["weighed"]
    assert weighed["motion_left_um"] < 0.2 and weighed["sensor_left_um"] < 0.2, weighed
    assert weighed["replaces"], weighed
    assert steps.drift.replacing_motion("X") == MOTION
    assert "on its zone warm-up 0.36 where the sensor's leaves 0.84" in record.state["notes"][-1]


def test_where_the_references_read_motion_worse_the_warm_up_alone_does_not_replace(
        tmp_path: Path) -> None:  # fmt: skip
    """The same warm-up, but its motion model is short by a third (Δa per metre 0.6 where
    the screw grows 0.9): the references leave more with it than with the sensor, and the
    sensor stays."""
    short = {**MOTION, "motion": {**MOTION["motion"], "delta_a_um_per_m": 0.6}}
    steps, record = _following_sensor(tmp_path, WARMUP_UNDER_HALF, short)
    steps.weigh_sensors()
    weighed = record.state["identify"]["thermal-X"]["motion"]["weighed"]
    assert weighed["sensor_left_um"] + weighed["noise_um"] < weighed["motion_left_um"], weighed
    assert not weighed["replaces"]
    assert steps.drift.replacing_motion("X") is None
    assert not record.state["notes"]


@pytest.mark.parametrize(("refs_um", "warmup_um", "noise_um", "expected"), [
    ((0.69, 0.60), (0.84, 0.36), 0.25, "both"),  # rough-9 Y at 8 h
    ((1.71, 0.60), (0.84, 0.90), 0.25, "references"),  # the references alone
    ((0.69, 0.60), (0.34, 0.26), 0.25, None),  # a tie, and the warm-up not under half
    ((0.30, 0.80), (0.84, 0.36), 0.25, None),  # motion worse beyond the references' scatter
    ((0.20, 0.05), (0.84, 0.90), 0.25, None),  # under half, but the sensor inside the noise
])
def test_the_evidence_a_sensor_gives_way_on(refs_um: tuple[float, float],
                                            warmup_um: tuple[float, float], noise_um: float,
                                            expected: str | None) -> None:  # fmt: skip
    """(sensor, motion) µm RMS on the references and on the warm-up: which duty cycles say
    motion replaces the sensor."""
    assert sensor_gives_way(*refs_um, noise_um, *warmup_um) == expected


def test_without_the_sensor_read_at_the_references_nothing_is_weighed(tmp_path: Path) -> None:
    """A log with no temperatures (a laser read from its software's file, or an older
    state): the warm-up's choice stands, and why is kept."""
    steps, record = _steps(tmp_path)
    for i in range(10):
        steps.drift.log_drift({"X": [0.0, 1e-3 * i]}, {"X": 1000.0 * i}, 120.0 * i)
    steps.weigh_sensors()
    motion = record.state["identify"]["thermal-X"]["motion"]
    assert "0 drift readings" in motion["weighed"]["why"]
    assert steps.drift.replacing_motion("X") is None


def test_the_references_read_the_sensor_as_its_thermal_source_does(tmp_path: Path) -> None:
    """Live, against the simulator over loopback: the sensor read with the references is
    the screw's temperature the sim's own model gives (its register through the config's
    thermal source), for the axis whose source is a temperature (Y) and not for the Δa
    one (X)."""
    import asyncio

    from gateway.calibration.measuring.machine import Endpoint
    from gateway.modbus.downstream import TcpBus
    from gateway.modbus.frames import (
        build_write_multiple_registers,
        build_write_single_register,
        pack_int32,
    )
    from sim.server import SimServer
    from tests.test_sensors_live import (
        TEMP_UNIT,  # fmt: skip
        TRIGGER_VALUE,
        X_TARGET,
        X_TRIGGER,
        gateway_config,
    )
    from tests.test_sim_support import config_from, example_dict

    async def main() -> None:
        async with SimServer(config_from(example_dict()), tcp_port=0) as server:
            port = server.tcp_port or 0
            bus = TcpBus("127.0.0.1", port, timeout_s=1.0, retries=0)
            try:
                for i in range(20):  # Y's screw warms (instant at time_scale 0)
                    await bus.transact(2, build_write_multiple_registers(
                        X_TARGET, pack_int32(600_000 if i % 2 == 0 else 0)))  # fmt: skip
                    await bus.transact(2, build_write_single_register(X_TRIGGER, TRIGGER_VALUE))
            finally:
                await bus.close()
            settings = types.SimpleNamespace(
                axes=("X", "Y"), motion=types.SimpleNamespace(request_timeout_s=1.0),
                instruments=types.SimpleNamespace(
                    temperature=Endpoint("127.0.0.1", port, TEMP_UNIT)))  # fmt: skip
            drift = DriftRefs(Axes(settings, gateway_config(port)),  # type: ignore[arg-type]
                              Record(tmp_path, tmp_path), print)  # fmt: skip
            assert drift.sensor_axes() == ["Y"]
            got = await drift.read_temperatures_c(drift.sensor_axes())
            truth_c = server.sim.machine.screw_temp_C("Y", server.sim.clock.now_s())
            assert truth_c > 20.3  # warmed
            assert got == {"Y": pytest.approx(truth_c, abs=0.02)}

    asyncio.run(main())
