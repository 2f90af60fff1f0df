"""ThermalFilter and register decoding: pure logic, injected time, no I/O."""

from __future__ import annotations

import math

import pytest

from gateway.config import SourceRegister, ThermalSource
from gateway.modbus.downstream import TcpBus
from gateway.modbus.frames import build_read_registers_response, exception_pdu
from gateway.sensors import (
    MAX_BACKOFF_S,
    FilterSettings,
    SensorReadError,
    ThermalFilter,
    ThermalSensor,
    ThermalState,
    decode_counts,
    decode_response,
    failed_wait_s,
    read_request,
)

S = ThermalState


def make(**kw: object) -> ThermalFilter:
    base: dict[str, object] = dict(range_mm=(-0.5, 0.5), max_rate_mm_s=0.01, smoothing=1.0,
                                   hold_s=10.0, fallback="hold", noise_mm=0.0, recover_count=1)
    base.update(kw)
    return ThermalFilter(FilterSettings(**base))  # type: ignore[arg-type]


def feed(f: ThermalFilter, samples: list[tuple[float, float | None]]) -> list[str]:
    return [f.step(t, x) for t, x in samples]


# -------------------------------------------------------------------- starting


def test_starting_is_zero_until_first_trusted_value() -> None:
    f = make(recover_count=3)
    assert f.state is S.STARTING and f.delta_a_mm == 0.0 and not f.alarm
    feed(f, [(0.0, 0.010), (1.0, 0.010)])
    assert f.state is S.STARTING and f.delta_a_mm == 0.0
    f.step(2.0, 0.011)
    assert f.state is S.OK
    assert f.delta_a_mm == pytest.approx(0.011)  # smoothing 1: the reading itself


def test_starting_with_disable_fallback_is_still_zero_not_none() -> None:
    f = make(fallback="disable")
    assert f.delta_a_mm == 0.0


def test_sensor_dead_at_boot_raises_alarm_after_hold() -> None:
    f = make(hold_s=5.0, fallback="hold")
    feed(f, [(100.0, None), (104.9, None)])
    assert f.state is S.STARTING
    f.step(105.0, None)
    assert f.state is S.ALARM and f.alarm
    assert f.delta_a_mm == 0.0  # hold, but there is nothing to hold: the cold state


def test_startup_outlier_does_not_lock_out_true_readings() -> None:
    # first reading is a spike (in range); the true readings that follow disagree with it
    f = make(recover_count=3, noise_mm=0.001)
    verdicts = feed(f, [(0, 0.300), (1, 0.020), (2, 0.020), (3, 0.021)])
    assert verdicts == ["accepted", "rate", "accepted", "accepted"]
    assert f.state is S.OK and f.delta_a_mm == pytest.approx(0.021)


# -------------------------------------------------------------------- plausibility


def test_range_rejected_and_counted() -> None:
    f = make()
    f.step(0, 0.01)
    assert f.step(1, 0.6) == "range"
    assert f.step(2, -0.51) == "range"
    assert f.step(3, math.nan) == "range"
    assert f.state is S.HOLDING and f.delta_a_mm == pytest.approx(0.01)
    c = f.counters
    assert (c.reads, c.accepted, c.rejected_range, c.rejected_rate, c.rejected) == (4, 1, 3, 0, 3)


def test_rate_rejects_a_step_and_allows_more_after_a_gap() -> None:
    f = make(max_rate_mm_s=0.001, noise_mm=0.0005)
    f.step(0.0, 0.010)
    assert f.step(1.0, 0.013) == "rate"  # 3 µm in 1 s > 1 µm/s + 0.5 µm
    assert f.step(1.0, 0.0114) == "accepted"  # 1.4 µm ≤ 1.5 µm
    assert f.step(2.0, 0.0131) == "rate"  # measured from the last accepted reading
    # after a longer gap (readings failed meanwhile) proportionally more is allowed
    feed(f, [(3.0, None), (4.0, None)])
    assert f.step(6.0, 0.0155) == "accepted"  # 4.1 µm in 5 s ≤ 5.5 µm
    assert f.counters.rejected_rate == 2 and f.counters.failures == 2


def test_exponential_smoothing() -> None:
    f = make(smoothing=0.5, max_rate_mm_s=1.0)
    f.step(0, 0.0)
    f.step(1, 0.008)
    assert f.delta_a_mm == pytest.approx(0.004)
    f.step(2, 0.008)
    assert f.delta_a_mm == pytest.approx(0.006)
    f.step(3, 0.008)
    assert f.delta_a_mm == pytest.approx(0.007)


# -------------------------------------------------------------------- loss, alarm, fallback


@pytest.mark.parametrize(("fallback", "expected"), [("hold", 0.02), ("zero", 0.0),
                                                    ("disable", None)])
def test_hold_then_alarm_then_fallback(fallback: str, expected: float | None) -> None:
    f = make(hold_s=3.0, fallback=fallback)
    f.step(10.0, 0.02)
    f.step(11.0, None)
    assert f.state is S.HOLDING and f.delta_a_mm == pytest.approx(0.02) and not f.alarm
    f.step(12.9, 0.4)  # implausible readings do not count as good
    assert f.state is S.HOLDING
    f.step(13.0, None)  # 3 s since the last good reading
    assert f.state is S.ALARM and f.alarm
    if expected is None:
        assert f.delta_a_mm is None
    else:
        assert f.delta_a_mm == pytest.approx(expected)
    assert f.smoothed_mm == pytest.approx(0.02)


def test_hold_zero_goes_to_alarm_at_first_failure() -> None:
    f = make(hold_s=0.0, fallback="zero")
    f.step(0, 0.02)
    f.step(1, None)
    assert f.state is S.ALARM and f.delta_a_mm == 0.0


# -------------------------------------------------------------------- recovery


def test_holding_recovers_on_one_good_reading() -> None:
    f = make(hold_s=5.0, recover_count=3)
    feed(f, [(0, 0.02), (1, 0.02), (2, 0.02)])
    assert f.state is S.OK
    f.step(3, None)
    assert f.state is S.HOLDING
    f.step(4, 0.021)
    assert f.state is S.OK and f.delta_a_mm == pytest.approx(0.021)


def test_alarm_needs_consecutive_consistent_readings() -> None:
    f = make(hold_s=2.0, recover_count=3, fallback="zero", smoothing=0.5, noise_mm=0.001)
    feed(f, [(0, 0.02), (1, 0.02), (2, 0.02), (3, None), (4, None)])
    assert f.state is S.ALARM and f.delta_a_mm == 0.0
    feed(f, [(5, 0.05), (6, 0.05)])  # the screw grew meanwhile: no rate check vs 0.02
    assert f.state is S.ALARM and f.delta_a_mm == 0.0
    f.step(7, None)  # interrupted: the run starts again
    feed(f, [(8, 0.05), (9, 0.05)])
    assert f.state is S.ALARM
    assert f.step(10, 0.051) == "accepted"
    assert f.state is S.OK and not f.alarm
    # the recovered value is smoothed over the run only, not blended with the stale 0.02
    assert f.delta_a_mm == pytest.approx(0.05 + 0.5 * 0.001)


def test_alarm_run_restarts_on_an_inconsistent_reading() -> None:
    f = make(hold_s=0.0, recover_count=2, noise_mm=0.001)
    feed(f, [(0, 0.02), (1, None)])
    assert f.state is S.ALARM
    assert feed(f, [(2, 0.03), (3, 0.3), (4, 0.3)]) == ["accepted", "rate", "accepted"]
    assert f.state is S.OK and f.delta_a_mm == pytest.approx(0.3)


def test_settings_validated() -> None:
    with pytest.raises(ValueError, match="smoothing"):
        FilterSettings(smoothing=0.0)
    with pytest.raises(ValueError, match="range_mm"):
        FilterSettings(range_mm=(0.1, -0.1))
    with pytest.raises(ValueError, match="recover_count"):
        FilterSettings(recover_count=0)


# -------------------------------------------------------------------- registers


def test_read_request_per_table() -> None:
    assert read_request(SourceRegister(address=5, table="input", words=1)) == bytes.fromhex(
        "0400050001")
    assert read_request(SourceRegister(address=1, table="holding", words=2)) == bytes.fromhex(
        "0300010002")


@pytest.mark.parametrize(("words", "reg", "expected"), [
    ([0xFFFE], dict(words=1), -2),
    ([0xFFFE], dict(words=1, signed=False), 0xFFFE),
    ([0x0001, 0x0002], dict(words=2), 0x00010002),
    ([0x0002, 0x0001], dict(words=2, order="lo_hi"), 0x00010002),
    ([0xFFFF, 0xFC18], dict(words=2), -1000),
    ([0xFFFF, 0xFC18], dict(words=2, signed=False), 0xFFFFFC18),
])
def test_decode_counts(words: list[int], reg: dict[str, object], expected: int) -> None:
    assert decode_counts(words, SourceRegister(address=0, **reg)) == expected  # type: ignore[arg-type]


def test_decode_response_errors() -> None:
    reg = SourceRegister(address=0, words=2)
    with pytest.raises(SensorReadError, match="0x04"):
        decode_response(exception_pdu(4, 4), reg)
    with pytest.raises(SensorReadError, match="expected 2"):
        decode_response(build_read_registers_response(4, [1]), reg)


def _source(**kw: object) -> ThermalSource:
    return ThermalSource.model_validate({"bus": "b", "unit": 23,
                                         "register": {"address": 0}, **kw})


def test_temperature_source_converts_per_axis_length() -> None:
    src = _source(kind="temperature", scale_c=0.01, alpha_per_k=11.5e-6, reference_c=20.0,
                  smoothing=1.0)
    sensor = ThermalSensor("t", src, TcpBus("127.0.0.1", 9), reference_length_mm=800.0)
    counts = 2300  # 23.00 °C
    ref_mm = sensor.to_delta_a_mm(counts)
    assert ref_mm == pytest.approx(11.5e-6 * 800 * 3.0)  # computed here, not by the module
    for i in range(3):
        sensor.filter.step(float(i), ref_mm)
    assert sensor.state is S.OK
    assert sensor.temperature_c == pytest.approx(23.0)
    assert sensor.delta_a_mm_for(800.0) == pytest.approx(0.0276)
    assert sensor.delta_a_mm_for(400.0) == pytest.approx(0.0138)
    # noise allowance defaults to two counts at the reference length
    assert sensor.filter.settings.noise_mm == pytest.approx(2 * 0.01 * 11.5e-6 * 800)


def test_an_axis_gain_scales_its_delta_a_and_is_reloadable() -> None:
    """``compensation.thermal.gain`` (fitted by commissioning when the sensor is not at the
    screw's temperature) scales the axis's Δa; the source itself is untouched."""
    from gateway.config import AxisThermal
    from gateway.sensors import SensorSet

    src = _source(kind="temperature", scale_c=0.01, alpha_per_k=11.5e-6, reference_c=20.0,
                  smoothing=1.0)
    sensor = ThermalSensor("t", src, TcpBus("127.0.0.1", 9), reference_length_mm=800.0)
    for i in range(3):
        sensor.filter.step(float(i), sensor.to_delta_a_mm(2300))  # 23.00 °C
    sensors = SensorSet({"t": sensor}, {"X": AxisThermal(source="t", length_mm=800.0)})
    assert sensors.axis_delta_a_mm("X") == pytest.approx(11.5e-6 * 800 * 3.0)
    sensors.set_axis_thermal({"X": AxisThermal(source="t", length_mm=800.0, gain=0.8)})
    assert sensors.axis_delta_a_mm("X") == pytest.approx(0.8 * 11.5e-6 * 800 * 3.0)
    assert sensor.delta_a_mm_for(800.0) == pytest.approx(11.5e-6 * 800 * 3.0)


def test_temperature_source_needs_positive_alpha() -> None:
    with pytest.raises(ValueError, match="alpha_per_k"):
        ThermalSensor("t", _source(kind="temperature", alpha_per_k=0.0),
                      TcpBus("127.0.0.1", 9))


def test_displacement_source_ignores_axis_length() -> None:
    sensor = ThermalSensor("d", _source(scale_mm=0.001, smoothing=1.0),
                           TcpBus("127.0.0.1", 9), recover_count=1)
    sensor.filter.step(0.0, sensor.to_delta_a_mm(12))
    assert sensor.delta_a_mm_for(800.0) == pytest.approx(0.012)
    assert sensor.delta_a_mm_for(400.0) == pytest.approx(0.012)
    assert sensor.temperature_c is None


def test_a_device_that_keeps_failing_is_read_less_and_less_often() -> None:
    """After a failed read, a wait as long as it took (at least poll_s), doubling with each
    failure in a row up to MAX_BACKOFF_S: a silent sensor on a drive's line leaves the
    line to the masters (their 0x0B queued behind each poll's timeout)."""
    assert failed_wait_s(1.0, 0.4, 1) == 1.0
    assert failed_wait_s(0.01, 0.1, 1) == 0.1  # as long as it took
    assert [failed_wait_s(1.0, 0.4, k) for k in (2, 3, 4, 5, 9)] == [2.0, 4.0, 8.0,
                                                                     MAX_BACKOFF_S,
                                                                     MAX_BACKOFF_S]  # fmt: skip
    assert failed_wait_s(30.0, 0.4, 6) == 30.0  # a poll_s longer than the cap stays


def test_the_alarm_is_due_hold_s_after_the_last_accepted_reading() -> None:
    """What the poll loop's back-off keeps to: the read that raises the alarm is not put
    off (the filter only changes state when it is stepped)."""
    f = ThermalFilter(FilterSettings(hold_s=30.0))
    assert f.alarm_due_s(0.0) is None  # before the first step
    f.step(100.0, None)  # starting, nothing read: due hold_s after the first step
    assert f.alarm_due_s(110.0) == 20.0
    f.step(131.0, None)
    assert f.alarm and f.alarm_due_s(140.0) is None
