"""A temperature sensor replaced by heat from motion (gateway.calibration.commissioning.thermal):
the tables were measured with the sensor's compensation on, which at a cold start away from
its reference temperature already took the screw for grown. Heat from motion starts at
zero, so that growth goes back into the table, once. Judged through the gateway's own
stages: the machine started cold lands on its targets with the final config."""

from __future__ import annotations

import types
from pathlib import Path

import numpy as np
import pytest

from gateway.calibration.commissioning.configs import Tables
from gateway.calibration.commissioning.record import Record
from gateway.calibration.commissioning.thermal import ThermalSteps, start_growth_mm
from gateway.compensation import PitchStage, PitchTable
from gateway.compensation.thermal import ThermalStage, delta_a_from_temperature
from gateway.formats import read_pitch_csv, write_pitch_csv

LENGTH_MM, ORIGIN_MM, ALPHA, REFERENCE_C, START_C = 600.0, 0.0, 11.5e-6, 20.0, 23.0


def _truth_mm(x: np.ndarray) -> np.ndarray:
    """The cold screw's own error: a slope and a wave (mm)."""
    return 8e-3 * x / 600.0 + 3e-3 * np.sin(x / 40.0)


def _measured_table() -> PitchTable:
    """What commissioning's readings make the table on a cold machine, the sensor's
    compensation on (T = START_C, so Δa ≠ 0): deviation at each point, as read."""
    x = np.linspace(0.0, 600.0, 61)
    stage = ThermalStage(LENGTH_MM, ORIGIN_MM)
    da = delta_a_from_temperature(ALPHA, LENGTH_MM, START_C, REFERENCE_C)
    cmd = stage.forward(x, da)  # the sensor's compensation, the table not yet on
    dev = cmd + _truth_mm(cmd) - x
    return PitchTable(x, dev, dev + 4e-3)


def _landing_error_um(table: PitchTable) -> float:
    """The final config on the machine started cold: table, then heat from motion at zero
    (the thermal stage with Δa 0); the largest miss at random targets (µm)."""
    targets = np.random.default_rng(3).uniform(5.0, 595.0, 200)
    cmd = PitchStage(table, "linear").forward(targets, np.ones(targets.size))
    cmd = ThermalStage(LENGTH_MM, ORIGIN_MM).forward(cmd, 0.0)
    return float(np.abs(cmd + _truth_mm(cmd) - targets).max() * 1e3)


def test_the_cold_start_growth_put_back_lands_the_cold_machine_on_its_targets() -> None:
    table = _measured_table()
    grown = start_growth_mm(table.position_mm, ORIGIN_MM, LENGTH_MM, 1.0, ALPHA, START_C,
                            REFERENCE_C)  # fmt: skip
    assert grown.max() * 1e3 == pytest.approx(11.5e-6 * 3.0 * 600.0 * 1e3, rel=1e-6)
    before = _landing_error_um(table)
    after = _landing_error_um(PitchTable(table.position_mm, table.forward_mm + grown,
                                         table.reverse_mm + grown))  # fmt: skip
    assert before > 15.0  # 3 K from its reference on 600 mm: 20.7 µm at the far end
    assert after < 0.3, (before, after)  # what is left: the table's linear interpolation
    # at the reference temperature nothing is added
    assert not np.any(start_growth_mm(table.position_mm, ORIGIN_MM, LENGTH_MM, 1.0, ALPHA,
                                      REFERENCE_C, REFERENCE_C))  # fmt: skip


def _steps(tmp_path: Path, cap_mm: float) -> ThermalSteps:
    """The thermal steps with just what ThermalSteps._add_start_growth reads: the config's
    thermal setting and source, the axis's correction cap, the table file, the state."""
    th = types.SimpleNamespace(source="t", origin_mm=ORIGIN_MM, length_mm=LENGTH_MM, gain=1.0)
    comp = types.SimpleNamespace(thermal=th, pitch_file=None, max_correction_mm=cap_mm)
    config = types.SimpleNamespace(
        axes={"X": types.SimpleNamespace(compensation=comp, wraps=False)},
        thermal_sources={"t": types.SimpleNamespace(kind="temperature", alpha_per_k=ALPHA,
                                                    reference_c=REFERENCE_C)})  # fmt: skip
    record = Record(tmp_path / "commission", tmp_path)
    record.tables = Tables(pitch={"X": "x_pitch.csv"})
    record.state.update({"start_temperature_c": {"X": START_C}, "notes": []})
    write_pitch_csv(tmp_path / "x_pitch.csv", _measured_table())
    return ThermalSteps(types.SimpleNamespace(s=None, config=config), record,  # type: ignore[arg-type]
                        None, lambda _: None)  # type: ignore[arg-type]


def test_the_table_gets_it_once_even_across_a_resume(tmp_path: Path) -> None:
    """ThermalSteps._add_start_growth on a table file: added, noted, and not again when the
    step runs a second time (a resume after it was written)."""
    steps = _steps(tmp_path, 0.2)
    steps._add_start_growth("X")
    once = read_pitch_csv(tmp_path / "x_pitch.csv")
    assert _landing_error_um(once) < 0.3
    assert "cold start" in steps.record.state["notes"][0]
    steps._add_start_growth("X")  # again: the state says it was written
    np.testing.assert_allclose(read_pitch_csv(tmp_path / "x_pitch.csv").forward_mm,
                               once.forward_mm)  # fmt: skip


def test_what_the_gateway_would_refuse_is_not_written(tmp_path: Path) -> None:
    """Past the axis's correction cap the table stays as it was, and the note says why."""
    steps = _steps(tmp_path, 0.012)
    before = read_pitch_csv(tmp_path / "x_pitch.csv")
    steps._add_start_growth("X")
    np.testing.assert_allclose(read_pitch_csv(tmp_path / "x_pitch.csv").forward_mm,
                               before.forward_mm)  # fmt: skip
    assert "not put back" in steps.record.state["notes"][0]


def test_a_resume_past_the_start_reads_no_start_temperature() -> None:
    """A commissioning resumed after its first drift references (an older state file, or
    one that lost the reading): the sensor now reads a warmed machine, so nothing is read
    and nothing will be put back (no Modbus here: an attempt would fail the test)."""
    import asyncio

    th = types.SimpleNamespace(source="t")
    axes = types.SimpleNamespace(
        s=types.SimpleNamespace(axes=("X",), instruments=types.SimpleNamespace(
            temperature=types.SimpleNamespace(key=("127.0.0.1", 9), unit=23))),
        config=types.SimpleNamespace(
            axes={"X": types.SimpleNamespace(compensation=types.SimpleNamespace(thermal=th))},
            thermal_sources={"t": types.SimpleNamespace(kind="temperature")}))  # fmt: skip
    record = Record(Path("/nonexistent"), Path("/nonexistent"))
    record.state["drift_base"] = {"phase": "identification", "refs": {}}
    steps = ThermalSteps(axes, record, None, print)  # type: ignore[arg-type]
    asyncio.run(steps.read_start_temperatures())
    assert record.state["start_temperature_c"] == {}
