"""Calibration: plans, raw data, ISO 230-2 statistics and table fitting (pure functions).

The I/O that drives a machine through a plan lives in ``measuring``; everything exported
here works on arrays and files only, so the CLI, the demo and tests share it.

The subpackages, by concern, each importing only subpackages listed before it: ``plans``
(what to measure, the raw data, the runner), ``thermal`` (how a screw warms), ``fitting``
(readings to tables and models), ``measuring`` (the machine, a session), ``reporting``
(``compgw report``, ``export``), ``commissioning`` (``compgw commission``). On top, the
command line: ``commands`` (calibrate, report, export), ``commands_fit`` (fit) and what
they share, ``cli_common`` (whose FROM_CONFIG measuring reads too).
"""

from .fitting.fit import (
    UnidirectionalFit,
    bidirectional_table,
    fold_backlash,
    fold_residual,
    planar_measurement,
    unidirectional_table,
)
from .fitting.iso230 import (
    JSON_KEYS,
    DirectionStats,
    Iso230Result,
    iso230_2,
    iso230_axis,
    iso230_raw,
    report_json,
)
from .fitting.plans_scans import warmup_plan
from .plans.plans import (
    BacklashResult,
    Move,
    Plan,
    backlash_from_raw,
    backlash_from_readings,
    backlash_plan,
    iso230_linear_plan,
    iso230_targets_mm,
    read_plan,
    resume_index,
    verification_targets_mm,
    write_plan,
)
from .plans.rawdata import (
    RAW_COLUMNS,
    AxisDeviations,
    RawData,
    RawWriter,
    axis_deviations,
    deviations_by_axis,
    read_raw_csv,
)
from .plans.xy import xy_grid_plan, xy_verification_plan

__all__ = [
    "JSON_KEYS",
    "RAW_COLUMNS",
    "AxisDeviations",
    "BacklashResult",
    "DirectionStats",
    "Iso230Result",
    "Move",
    "Plan",
    "RawData",
    "RawWriter",
    "UnidirectionalFit",
    "axis_deviations",
    "backlash_from_raw",
    "backlash_from_readings",
    "backlash_plan",
    "bidirectional_table",
    "deviations_by_axis",
    "fold_backlash",
    "fold_residual",
    "iso230_2",
    "iso230_axis",
    "iso230_linear_plan",
    "iso230_raw",
    "iso230_targets_mm",
    "planar_measurement",
    "read_plan",
    "read_raw_csv",
    "report_json",
    "resume_index",
    "unidirectional_table",
    "verification_targets_mm",
    "warmup_plan",
    "write_plan",
    "xy_grid_plan",
    "xy_verification_plan",
]
