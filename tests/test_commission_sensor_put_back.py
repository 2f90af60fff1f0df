"""A table read with a temperature sensor's compensation on, the sensor then replaced by heat
from motion (gateway.calibration.commissioning.run_heat.RunHeat.put_back_sensor): what the
sensor's compensation took off each reading is given back, reading by reading, so the
reversal loses what the sensor's reading did between a target's two passes. Pure: the
readings are made here, the table fitted as their means."""

from __future__ import annotations

import types
from pathlib import Path

import numpy as np
import pytest

from gateway.calibration.commissioning.configs import Tables
from gateway.calibration.commissioning.record import Record
from gateway.calibration.commissioning.run_heat import Rows, RunHeat
from gateway.calibration.commissioning.thermal import ThermalSteps, start_growth_mm
from gateway.compensation import PitchTable
from gateway.formats import read_pitch_csv, write_pitch_csv

LENGTH_MM, ORIGIN_MM, ALPHA, REFERENCE_C, START_C = 1046.0, -46.0, 12e-6, 20.0, 20.0
TARGETS_MM = np.linspace(0.0, 1000.0, 41)


def _truth_mm(x: np.ndarray, up: bool) -> np.ndarray:
    """The cold screw: a slope and a wave, and 2 µm of lost motion, 3.5 µm mid-travel."""
    lost = 2e-3 + 1.5e-3 * np.exp(-(((x - 400.0) / 120.0) ** 2))
    return 8e-3 * x / 1000.0 + 3e-3 * np.sin(x / 40.0) + (0.0 if up else lost)


def _sensor_took_mm(x: np.ndarray, t_c: np.ndarray) -> np.ndarray:
    """What the gateway's thermal stage took for growth at each (x, T) since the start."""
    return np.array([
        start_growth_mm(np.array([xi]), ORIGIN_MM, LENGTH_MM, 1.0, ALPHA, ti, REFERENCE_C)[0]
        - start_growth_mm(np.array([xi]), ORIGIN_MM, LENGTH_MM, 1.0, ALPHA, START_C,
                          REFERENCE_C)[0] for xi, ti in zip(x, t_c)])  # fmt: skip


def _runs() -> Rows:
    """Three bidirectional runs, up then down, 4 s a stop; the sensor warms 3 K an hour
    while the screw's length does not change (the sensor reads a spot the heat does not
    reach): each reading is the truth less what the sensor's compensation took off."""
    rows = []
    t_s = 0.0
    for run in (1, 2, 3):
        for up, order in ((True, TARGETS_MM), (False, TARGETS_MM[::-1])):
            for x in order:
                t_s += 4.0
                t_c = START_C + 3.0 * t_s / 3600.0
                dev = _truth_mm(np.array([x]), up)[0] - _sensor_took_mm(np.array([x]),
                                                                        np.array([t_c]))[0]
                rows.append((run, x, dev, up, t_s, t_c))
    run, x, dev, up, at, temp = (np.array(c) for c in zip(*rows))
    return Rows(run, x, dev, up.astype(bool), at, {"X": np.zeros(run.size)},
                np.zeros(run.size), temp)  # fmt: skip


def _table(rows: Rows) -> PitchTable:
    """The table as fitted: each target's mean, per direction."""
    means = [[rows.deviation_mm[(rows.target_mm == x) & (rows.up == up)].mean()
              for x in TARGETS_MM] for up in (True, False)]  # fmt: skip
    return PitchTable(TARGETS_MM, np.array(means[0]), np.array(means[1]))


def _run_heat(tmp_path: Path) -> RunHeat:
    """RunHeat with just what put_back reads: the axis's references and travel, the table
    file, the state."""
    record = Record(tmp_path / "commission", tmp_path)
    record.tables = Tables(pitch={"X": "x_pitch.csv"})
    axes = types.SimpleNamespace(ref_positions=lambda a: (0.0, 1000.0),
                                 travel=lambda a: (0.0, 1000.0))  # fmt: skip
    return RunHeat(axes, record, None, None, lambda _: None)  # type: ignore[arg-type]


def test_what_the_sensor_took_off_each_reading_is_given_back(tmp_path: Path) -> None:
    rows = _runs()
    as_read = _table(rows)
    write_pitch_csv(tmp_path / "x_pitch.csv", as_read)
    truth_rev_um = (_truth_mm(TARGETS_MM, False) - _truth_mm(TARGETS_MM, True)) * 1e3
    # as read: the sensor's compensation grew between a target's two passes (most at the
    # start of the travel, read first going up and last coming down)
    short_um = truth_rev_um - (as_read.reverse_mm - as_read.forward_mm) * 1e3
    assert short_um.max() > 0.5, short_um
    took = _sensor_took_mm(rows.target_mm, rows.temperature_c)
    _run_heat(tmp_path).put_back("X", rows, None, (np.zeros(0), {}), took)
    back = read_pitch_csv(tmp_path / "x_pitch.csv")
    np.testing.assert_allclose((back.reverse_mm - back.forward_mm) * 1e3, truth_rev_um,
                               atol=2e-3)  # (the file's 4 decimals of µm)  # fmt: skip
    np.testing.assert_allclose(back.forward_mm, _truth_mm(TARGETS_MM, True), atol=2e-6)
    # the table as fitted is kept beside it
    kept = read_pitch_csv(tmp_path / "x_pitch.as_read.csv")
    np.testing.assert_allclose(kept.forward_mm, as_read.forward_mm, atol=1e-6)


def test_the_sensor_s_compensation_since_the_cold_start() -> None:
    """ThermalSteps.sensor_took_mm: nothing at the start's temperature; 1 K later, α·(x −
    the fixed end) (the gateway's own stage); nothing without a start's reading."""
    th = types.SimpleNamespace(source="t", origin_mm=ORIGIN_MM, length_mm=LENGTH_MM, gain=1.0)
    config = types.SimpleNamespace(
        axes={"X": types.SimpleNamespace(compensation=types.SimpleNamespace(thermal=th))},
        thermal_sources={"t": types.SimpleNamespace(alpha_per_k=ALPHA,
                                                    reference_c=REFERENCE_C)})  # fmt: skip
    record = types.SimpleNamespace(state={"start_temperature_c": {"X": 21.0}})
    steps = ThermalSteps(types.SimpleNamespace(s=None, config=config), record,  # type: ignore[arg-type]
                         None, lambda _: None)  # type: ignore[arg-type]
    x = np.array([0.0, 500.0, 1000.0])
    assert not steps.sensor_took_mm("X", x, np.full(3, 21.0)).any()
    took = steps.sensor_took_mm("X", x, np.array([22.0, 22.0, 22.0]))
    np.testing.assert_allclose(took, ALPHA * (x - ORIGIN_MM), rtol=1e-9)
    record.state["start_temperature_c"] = {}
    assert not steps.sensor_took_mm("X", x, np.full(3, 22.0)).any()
    assert took[-1] * 1e3 == pytest.approx(12.55, abs=0.01)


class _RunHeatOn(RunHeat):
    """RunHeat with its ISO readings given (no steps' files read)."""

    def rows(self, axis: str) -> Rows | None:
        return _runs()

    def on_the_way(self) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        return np.zeros(0), {"X": np.zeros(0)}


def test_only_a_replaced_sensor_s_table_read_with_no_references_is_put_back(
        tmp_path: Path) -> None:  # fmt: skip
    """put_back_sensor: the table put back once, by the heat from motion that replaced the
    sensor (here one that never grows: the sensor's part alone) and what the sensor took off;
    not where drift references were read (put_back_refs' case), nor twice."""
    rows = _runs()
    write_pitch_csv(tmp_path / "x_pitch.csv", _table(rows))
    heat = _run_heat(tmp_path)
    heat = _RunHeatOn(heat.axes, heat.record, None, None, lambda _: None)  # type: ignore[arg-type]
    model = {"origin_mm": ORIGIN_MM, "length_mm": LENGTH_MM,
             "motion": {"delta_a_um_per_m": 0.0, "tau_s": 900.0, "speeds_mm_s": {}}}
    heat.record.tables.thermal_motion["X"] = model
    fitted = {"replaces_sensor": True, "config": model}
    heat.record.state["identify"] = {"thermal-X": {"motion": fitted}}
    heat.axes.ref_axes = lambda: ["X"]  # type: ignore[attr-defined]

    def took(axis: str, x: np.ndarray, t_c: np.ndarray) -> np.ndarray:
        return _sensor_took_mm(x, t_c)

    heat.record.state["drift_log"] = [{"wall_s": 0.0}]  # references read: not this case
    heat.put_back_sensor(took)
    assert "table_held_um" not in fitted
    heat.record.state["drift_log"] = []
    heat.put_back_sensor(took)
    back = read_pitch_csv(tmp_path / "x_pitch.csv")
    np.testing.assert_allclose(back.forward_mm, _truth_mm(TARGETS_MM, True), atol=2e-6)
    np.testing.assert_allclose(back.reverse_mm, _truth_mm(TARGETS_MM, False), atol=2e-6)
    assert len(fitted["table_held_um"]) == 2
    write_pitch_csv(tmp_path / "x_pitch.csv", _table(rows))  # as if put back: not again
    again = read_pitch_csv(tmp_path / "x_pitch.csv")
    heat.put_back_sensor(took)
    assert np.array_equal(read_pitch_csv(tmp_path / "x_pitch.csv").forward_mm, again.forward_mm)


def test_a_travel_profile_s_share_at_each_reading_follows_the_steps_moves(
        tmp_path: Path) -> None:  # fmt: skip
    """RunHeat.profile_shares: the gateway's travel profile replayed over the axis's steps'
    moves in their order; a target's down pass has the heat of the travel beyond it, so its
    share of the whole elongation is less than its up pass's. None without a profile, or
    where the readings are not the plans' stops."""
    from gateway.calibration.plans.plans import iso230_linear_plan, write_plan

    heat = _run_heat(tmp_path)
    (heat.record.dir / "plans").mkdir(parents=True)
    plan = iso230_linear_plan("X", (0.0, 1000.0), step_mm=25.0, runs=3, overrun_mm=1.0)
    write_plan(heat.record.dir / "plans" / "iso-X.plan", plan)
    heat.record.state["steps"] = {"iso-X": {}}
    n = sum(m.measured for m in plan.moves)
    x = plan.targets_mm()
    up = np.array([m.direction > 0 for m in plan.moves if m.measured])
    rows = Rows(np.ones(n, dtype=np.int64), x, np.zeros(n), up, np.arange(n, dtype=float),
                {"X": np.zeros(n)}, np.zeros(n), np.full(n, START_C))  # fmt: skip
    model = {"origin_mm": ORIGIN_MM, "length_mm": 1421.0,
             "motion": {"delta_a_um_per_m": 0.53, "tau_s": 961.0, "speeds_mm_s": {}},
             "profile": {"spread_mm": 125.0, "memory_mm": 96100.0, "memory_s": 961.0,
                         "screw_mm": [ORIGIN_MM, 1046.0]}}  # fmt: skip
    shares = heat.profile_shares("X", rows, model)
    assert shares is not None and shares.shape == (n,)
    assert np.all((shares >= 0.0) & (shares <= 1.0))
    last = rows.run == 1  # the first run: each target's up and down pass
    at = x[np.argmin(np.abs(x - 500.0))]  # (ISO 230-2 targets are uneven)
    going_up = shares[last & up & (x == at)][0]
    coming_down = shares[last & ~up & (x == at)][0]
    assert coming_down < going_up, (going_up, coming_down)
    assert heat.profile_shares("X", rows, {k: v for k, v in model.items() if k != "profile"}) \
        is None  # fmt: skip
    short = Rows(*(v[1:] if isinstance(v, np.ndarray) else {"X": v["X"][1:]}
                   for v in (rows.run, rows.target_mm, rows.deviation_mm, rows.up, rows.at_s,
                             rows.odometer_mm, rows.taken_mm, rows.temperature_c)))  # fmt: skip
    assert heat.profile_shares("X", short, model) is None
