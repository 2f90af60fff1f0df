"""The drift commissioning takes off an axis whose temperature sensor heat from motion
replaces (gateway.calibration.commissioning.steps.StepRunner.raw, adaptive.relinked_base): runs
read with the sensor on and runs read with it off must both come back to the cold
machine's own error, whatever the screw's temperature then. Built as the gateway reads:
the sensor's correction moves where the axis lands, the screw grows from its fixed end."""

from __future__ import annotations

import types
from pathlib import Path

import numpy as np
import pytest

from gateway.calibration.commissioning.axes import Axes
from gateway.calibration.commissioning.budget import Budget
from gateway.calibration.commissioning.drift import DriftRefs
from gateway.calibration.commissioning.record import Record
from gateway.calibration.commissioning.steps import StepRunner
from gateway.calibration.fitting import adaptive
from gateway.calibration.plans.rawdata import RawWriter
from gateway.compensation.thermal import (
    ThermalStage,
    delta_a_from_temperature,
    motion_heat_series_m,
)

REFS = (31.0, 570.0)
ORIGIN, LENGTH, GAIN, ALPHA, REF_C, START_C = -40.0, 640.0, 1.0, 11.5e-6, 20.0, 23.0
SENSOR = [ORIGIN, LENGTH, GAIN, ALPHA, REF_C]


def _error_mm(x: np.ndarray) -> np.ndarray:
    """The cold machine's own error (mm)."""
    return 6e-3 * x / 600.0 + 2e-3 * np.sin(x / 50.0)


def _sensor_mm(x: np.ndarray, t_c: float) -> np.ndarray:
    """What the sensor's correction moves the axis by at ``t_c`` (the gateway's stage)."""
    da = GAIN * delta_a_from_temperature(ALPHA, LENGTH, t_c, REF_C)
    return ThermalStage(LENGTH, ORIGIN).forward(x, da) - x


def _growth_mm(x: np.ndarray, scale: float) -> np.ndarray:
    return scale * 1e-5 * (x - ORIGIN)


def _run(path: Path, x: np.ndarray, sensor_c: float | None, scale: float) -> None:
    """One run read at ``x``: the screw grown by ``scale``, the sensor on at ``sensor_c``."""
    read = x + _error_mm(x) + _growth_mm(x, scale)
    if sensor_c is not None:
        read = read + _sensor_mm(x, sensor_c)
    with RawWriter(path, []) as w:
        for t, a in zip(x, read):
            w.append("X", 1, "+", float(t), float(a))


def test_runs_with_the_sensor_on_and_off_both_come_back_to_the_cold_machine(tmp_path: Path):
    refs = np.array(REFS)
    x = np.linspace(10.0, 590.0, 30)
    on = {"mm": list(REFS), "thermal": "ThermalComp(temperature)", "sensor": SENSOR}
    off = {"mm": list(REFS), "thermal": "None"}
    # the cold start, sensor on: the first base is what the references read then
    base0 = {"X": list(_error_mm(refs) + _sensor_mm(refs, START_C))}
    # a warm-up later the sensor is switched off at 27 °C with 30 µm/m grown: computed
    after = {"X": list(_error_mm(refs) + _growth_mm(refs, 3.0))}
    drift = {"X": list(_growth_mm(refs, 3.0) + _sensor_mm(refs, 27.0) - _sensor_mm(refs,
                                                                                   START_C))}
    base_off = adaptive.relinked_base(base0, after, drift, {"X": on}, {"X": off},
                                      {"X": START_C})  # fmt: skip
    # under the config without the sensor the drift is the growth itself
    np.testing.assert_allclose(np.array(after["X"]) - base_off["X"], _growth_mm(refs, 3.0),
                               atol=1e-12)  # fmt: skip

    def refs_drift(scale: float, sensor_c: float | None, base: list[float]) -> list[float]:
        read = _error_mm(refs) + _growth_mm(refs, scale)
        if sensor_c is not None:
            read = read + _sensor_mm(refs, sensor_c)
        return list(read - np.array(base))

    _run(tmp_path / "on.csv", x, 25.0, 1.0)  # sensor on, 25 °C, 10 µm/m (1 → 1.5 over it)
    _run(tmp_path / "off.csv", x, None, 2.0)  # sensor off, 20 µm/m
    parts = [
        {"raw": "on.csv", "cold_mm": {"X": list(_sensor_mm(refs, START_C))},
         "drift": {"X": [*REFS, *refs_drift(1.0, 25.0, base0["X"]),
                         *refs_drift(1.0, 25.0, base0["X"])]}},
        {"raw": "off.csv",
         "drift": {"X": [*REFS, *refs_drift(2.0, None, base_off["X"]),
                         *refs_drift(2.0, None, base_off["X"])]}},
    ]  # fmt: skip
    for spread, left in ((150.0, 0.0), (None, 1.0)):
        record = Record(tmp_path, tmp_path)
        record.state["steps"] = {"s": {"parts": parts}}
        drift = types.SimpleNamespace(drift_taken_off=lambda a: True,
                                      drift_spread_mm=lambda a, s=spread: s)  # fmt: skip
        runner = StepRunner(types.SimpleNamespace(s=None, config=None), record, drift,  # type: ignore[arg-type]
                            None, print)  # type: ignore[arg-type]
        data = runner.raw("s")
        got = data.deviation_mm.reshape(2, -1)
        # off: the cold machine's error; on: the same where its sensor goes (a spread
        # known), else less what the sensor took at the cold start (put back later)
        np.testing.assert_allclose(got[1], _error_mm(x), atol=1e-9)
        np.testing.assert_allclose(got[0], _error_mm(x) + left * _sensor_mm(x, START_C),
                                   atol=1e-9)  # fmt: skip
    assert np.abs(_sensor_mm(x, START_C)).max() > 5e-3  # the start's 3 K: tens of µm


def test_drift_taken_off_only_where_the_references_vary_beyond_their_scatter():
    """References that only scatter (a machine with no heat, 1.2 µm of scatter, 70 readings
    of 3) are not taken off its runs; 4 µm of growth over commissioning among the same
    scatter is; before the ISO runs give the scatter, the drift is taken off."""
    s_um = 1.2
    noise_um = np.random.default_rng(0).normal(0.0, s_um / np.sqrt(3), (70, 2))

    growth_um = noise_um + np.linspace(0.0, 4.0, 70)[:, None]
    assert not _fake(noise_um, s_um).drift_stands_out("X")
    assert _fake(growth_um, s_um).drift_stands_out("X")
    assert _fake(noise_um, None).drift_stands_out("X")


def test_the_references_own_readings_give_their_scatter_before_the_iso_runs():
    """The drift references' back-to-back readings give the scatter before any ISO run is
    fitted: references that only scatter are then not taken off the first fit (which the
    tables of a short budget keep), growth among the same scatter is; one reading (fewer
    than MIN_REF_DOF degrees of freedom) is not enough to tell."""
    rng = np.random.default_rng(2)
    s_um = 1.2
    noise_um = rng.normal(0.0, s_um / np.sqrt(3), (12, 2))
    growth_um = noise_um + np.linspace(0.0, 6.0, 12)[:, None]
    quiet, warming, once = (_fake(log, None) for log in (noise_um, growth_um, noise_um))
    for me in (quiet, warming):
        for _ in range(3):  # three readings of both references, 3 stops each
            for _ in range(2):
                me.pool_ref_scatter("X", list(rng.normal(0.0, s_um, 3) * 1e-3))  # type: ignore[arg-type]
    once.pool_ref_scatter("X", [0.0, 1e-3, 2e-3])  # type: ignore[arg-type]
    assert 0.6 * s_um < quiet.ref_scatter_um("X") < 1.6 * s_um  # type: ignore[arg-type,operator]
    assert not quiet.drift_stands_out("X")
    assert warming.drift_stands_out("X")
    assert once.ref_scatter_um("X") is None  # type: ignore[arg-type]
    assert once.drift_stands_out("X")


def test_runs_get_their_own_references_only_where_a_drift_can_be_taken_off():
    """On a short budget, references that only scatter are read around a whole step (they
    watch for a drift to begin); around each run while the drift stands out, while the
    scatter is not known yet, on an axis with a temperature sensor whatever its references
    read, and on a long budget (a drift that stands out later is taken off run by run)."""
    s_um = 1.2
    noise_um = np.random.default_rng(1).normal(0.0, s_um / np.sqrt(3), (12, 2))
    growth_um = noise_um + np.linspace(0.0, 6.0, 12)[:, None]
    assert not _budget(noise_um, s_um).runs_apart()
    assert _budget(growth_um, s_um).runs_apart()
    assert _budget(noise_um, None).runs_apart()
    assert _budget(noise_um, s_um, sensor=True).runs_apart()
    assert _budget(noise_um, s_um, short=False).runs_apart()


def _fake(log_um: np.ndarray, s_um: float | None, sensor: bool = False,
          short: bool = True) -> DriftRefs:
    """The drift references of axis X with just what :meth:`DriftRefs.drift_stands_out` and
    :meth:`Budget.runs_apart` read: its drift log (µm, two references per reading), its ISO
    scatter (None: not fitted yet), whether its compensation has a thermal section and
    whether the budget is short."""
    ident = {"reversal-X": {"scatter_um": s_um}} if s_um is not None else {}
    log = [{"drift_mm": {"X": list(row * 1e-3)}} for row in log_um]
    comp = types.SimpleNamespace(thermal=types.SimpleNamespace(source="t") if sensor else None)
    config = types.SimpleNamespace(axes={"X": types.SimpleNamespace(
        rotary=False, compensation=comp, travel_mm=(0.0, 100.0))})  # fmt: skip
    axes = Axes(types.SimpleNamespace(axes=("X",)), config)  # type: ignore[arg-type]
    record = Record(Path("/nonexistent"), Path("/nonexistent"))
    record.state.update({"identify": ident, "drift_log": log, "short": short})
    return DriftRefs(axes, record, print)


def _budget(log_um: np.ndarray, s_um: float | None, sensor: bool = False,
            short: bool = True) -> Budget:
    """The budget over :func:`_fake`'s drift references."""
    drift = _fake(log_um, s_um, sensor, short)
    return Budget(drift.axes, drift.record, drift)


def test_a_warm_up_model_replaces_the_references_fit_only_where_it_holds(tmp_path: Path):
    """An axis with no sensor: its zone warm-up's heat from motion becomes its thermal
    setting only where it leaves under half of the drift the commissioning's references
    read (another duty cycle than its strokes). One that cools 4 x too slowly does not:
    the references' own fit stays in the tables, and the check is kept, said failed."""
    from gateway.compensation.thermal import motion_heat_series_m

    rng = np.random.default_rng(3)
    truth = {"origin_mm": -40.0, "length_mm": 640.0,
             "motion": {"delta_a_um_per_m": 0.9, "tau_s": 900.0, "speeds_mm_s": {"X": 100.0}}}
    strokes = rng.uniform(0.0, 30.0, 40)  # m of travel between readings, 120 s apart
    heat = motion_heat_series_m(strokes, np.maximum(strokes * 10.0, 120.0), 900.0)
    refs_mm = np.array([31.0, 570.0])  # Axes.ref_positions on 0-600 mm
    growth_um = 0.9 * heat[:, None] * (refs_mm + 40.0)[None, :] / 640.0
    growth_um += rng.normal(0.0, 0.2, growth_um.shape)
    log = [{"odometer_mm": {"X": 1000.0 * m}, "wall_s": 120.0 * (i + 1),
            "drift_mm": {"X": list(g * 1e-3)}}
           for i, (m, g) in enumerate(zip(np.cumsum(strokes), growth_um))]  # fmt: skip
    refs_fit = {**truth, "motion": {**truth["motion"], "tau_s": 1200.0}}
    slow = {**truth, "motion": {**truth["motion"], "tau_s": 3600.0}}
    for warm, adopted in ((truth, True), (slow, False)):
        comp = types.SimpleNamespace(thermal=None)
        config = types.SimpleNamespace(axes={"X": types.SimpleNamespace(
            rotary=False, compensation=comp, travel_mm=(0.0, 600.0), pulse_mm=0.001)})  # fmt: skip
        axes = Axes(types.SimpleNamespace(axes=("X",)), config)  # type: ignore[arg-type]
        record = Record(tmp_path, tmp_path)
        record.state.update({"drift_log": log, "identify": {
            "motion-X": {"fitted": True, **refs_fit},
            "thermal-X": {"fitted": True, "config": warm}}})  # fmt: skip
        record.tables.motion["X"] = refs_fit
        said: list[str] = []
        DriftRefs(axes, record, said.append).adopt_warmed_motion()
        ident = record.state["identify"]
        assert ident["thermal-X"]["drift_check"]["holds"] is adopted, said
        assert record.tables.motion["X"] == (warm if adopted else refs_fit)
        assert (ident["motion-X"].get("from") == "warm-up") is adopted
        assert ("does not hold" in said[-1]) is not adopted, said


def test_under_heat_from_motion_the_log_keeps_the_growth_and_a_switch_is_computed(
        tmp_path: Path) -> None:  # fmt: skip
    """Once a config corrects heat from motion, the references read what it leaves: the
    drift log puts back what the model takes off (the heat counted from the cold start
    through the log, as the gateway counts it from its start), so the growth fitted and
    checked on stays the growth; a switch onto such a config is computed, not read (the
    model commands nothing on the cold machine), so the drift taken off a run under it is
    what the model leaves, not the whole growth again."""
    section = {"origin_mm": -40.0, "length_mm": 640.0, "gain": 1.0,
               "motion": {"delta_a_um_per_m": 0.9, "tau_s": 900.0, "speeds_mm_s": {}}}
    comp = types.SimpleNamespace(thermal=None)
    config = types.SimpleNamespace(axes={"X": types.SimpleNamespace(
        rotary=False, compensation=comp, travel_mm=(0.0, 600.0), pulse_mm=0.001)})  # fmt: skip
    axes = Axes(types.SimpleNamespace(axes=("X",)), config)  # type: ignore[arg-type]
    record = Record(tmp_path, tmp_path)
    drift = DriftRefs(axes, record, print)
    drift.log_drift({"X": [0.0, 0.0]}, {"X": 0.0}, 0.0)
    drift.log_drift({"X": [2e-3, 9e-3]}, {"X": 20000.0}, 600.0)  # 20 m in 10 min
    assert "modelled_um" not in record.state["drift_log"][-1]  # no model loaded: as read
    record.state["ref_commands"] = {"X": {"mm": [31.0, 570.0], "thermal": "motion",
                                          "motion": section}}  # fmt: skip
    drift.log_drift({"X": [0.1e-3, 0.2e-3]}, {"X": 40000.0}, 1200.0)
    entry = record.state["drift_log"][-1]
    heat_m = motion_heat_series_m([0.0, 20.0, 20.0], [0.0, 600.0, 600.0], 900.0)[-1]
    want_um = 0.9 * heat_m * (np.array([31.0, 570.0]) + 40.0) / 640.0
    assert entry["modelled_um"]["X"] == pytest.approx(want_um, rel=1e-9)
    assert np.array(entry["drift_mm"]["X"]) * 1e3 == pytest.approx(want_um + np.array([0.1, 0.2]))
    assert min(want_um) > 2.0  # µm: a warm screw the references no longer read
    motion = {"mm": [31.0, 570.0], "thermal": "motion", "motion": section}
    off = {"mm": [31.0, 570.0], "thermal": "None"}
    base0, after = {"X": [0.0, 0.0]}, {"X": [0.5e-3, 0.4e-3]}  # read after the switch
    got = adaptive.relinked_base(base0, after, {"X": [9e-3, 30e-3]}, {"X": off}, {"X": motion})
    assert got == {"X": [0.0, 0.0]}  # computed: the cold machine reads the same
