"""Which sensor a warm-up records: its axis's own thermal source's kind (issue 54: with both
--delta-a and --temperature given, Y's warm-up recorded the Δa column and its fit failed,
46.5 minutes of machine time lost in every default-budget run)."""

from __future__ import annotations

import copy
from pathlib import Path

from gateway.calibration.fitting.plans_scans import warmup_plan
from gateway.calibration.measuring.machine import Endpoint
from gateway.calibration.measuring.session import Instruments, Session
from gateway.calibration.plans.plans import iso230_linear_plan
from gateway.calibration.plans.xy import xy_grid_plan
from gateway.config import parse_config
from tests.test_config import BASE


def _session(delta_a: bool, temperature: bool) -> Session:
    data = copy.deepcopy(BASE)
    data["thermal_sources"]["y_screw"] = {
        "bus": "line1", "unit": 11, "register": {"address": 1, "words": 1},
        "kind": "temperature", "scale_c": 0.01}  # fmt: skip
    data["axes"]["X"]["compensation"]["thermal"] = {"source": "x_ref", "length_mm": 800}
    data["axes"]["Y"]["compensation"] = {"thermal": {"source": "y_screw", "length_mm": 600}}
    ins = Instruments(delta_a=Endpoint("127.0.0.1", 5021, 10) if delta_a else None,
                      temperature=Endpoint("127.0.0.1", 5021, 11) if temperature else None)
    return Session(parse_config(data), Path("."), Endpoint("127.0.0.1", 5020, 1), ins)


def test_a_warm_up_records_its_own_axis_s_sensor():
    both = _session(delta_a=True, temperature=True)
    y = warmup_plan("Y", (0, 600), 100, 600, 590, measure_every=5)
    x = warmup_plan("X", (0, 800), 100, 800, 790, measure_every=5)
    assert both._warmup_reads_temperature(y)  # Y's source is a temperature sensor
    assert not both._warmup_reads_temperature(x)  # X's a displacement (Δa) sensor
    assert not _session(delta_a=True, temperature=False)._warmup_reads_temperature(y)
    assert _session(delta_a=False, temperature=True)._warmup_reads_temperature(y)


def test_an_iso_run_records_its_axis_s_screw_temperature_at_every_stop():
    """As ISO 230-2 asks, and so that what a sensor's compensation took off each reading
    can be given back where heat from motion replaces the sensor later: a run of one axis
    whose thermal source is a temperature sensor, one given (a Δa sensor given records Δa
    at every stop instead: run's order)."""
    y = iso230_linear_plan("Y", (0, 600), step_mm=100, runs=1, overrun_mm=1)
    x = iso230_linear_plan("X", (0, 800), step_mm=100, runs=1, overrun_mm=1)
    assert _session(delta_a=False, temperature=True)._stops_read_temperature(y)
    assert not _session(delta_a=False, temperature=True)._stops_read_temperature(x)  # Δa
    assert not _session(delta_a=False, temperature=False)._stops_read_temperature(y)
    grid = xy_grid_plan((0, 800), (0, 600), 3, 3)
    assert not _session(delta_a=False, temperature=True)._stops_read_temperature(grid)
