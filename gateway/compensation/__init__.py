"""Pure compensation math: pitch, backlash, planar (XY), thermal, and their chain.

No I/O here: the Modbus layers move bytes and call these functions; file formats live in
``gateway.formats``. Positions are in mm (degrees for rotary axes) unless a name says
``_pulses``; deviations follow the ISO 230-2 sign (actual − commanded).
"""

from .backlash import BacklashStage
from .chain import AxisChain, AxisInput, Chain, round_pulses, round_pulses_array
from .cyclic import CyclicModel, CyclicStage
from .direction import MotionState
from .errors import (
    CompensationError,
    ConvergenceError,
    CorrectionLimitError,
    TableError,
    TravelError,
)
from .linkage import LinkageModel, LinkageStage
from .monotone_map import MonotoneMap
from .pitch import PitchStage, PitchTable
from .planar import GridModel, PlanarMeasurement, PlanarStage, PolyModel
from .reversal import TURN_DEADBAND_MM, command_on_flank
from .takeup import TakeUpCurve
from .thermal import (
    STEEL_ALPHA_PER_K,
    ThermalStage,
    delta_a_from_temperature,
    pulse_equivalent_mm,
    pulses_for_travel,
)

__all__ = [
    "STEEL_ALPHA_PER_K",
    "TURN_DEADBAND_MM",
    "AxisChain",
    "AxisInput",
    "BacklashStage",
    "Chain",
    "CompensationError",
    "ConvergenceError",
    "CorrectionLimitError",
    "CyclicModel",
    "CyclicStage",
    "GridModel",
    "LinkageModel",
    "LinkageStage",
    "MonotoneMap",
    "MotionState",
    "PitchStage",
    "PitchTable",
    "PlanarMeasurement",
    "PlanarStage",
    "PolyModel",
    "TableError",
    "TakeUpCurve",
    "ThermalStage",
    "TravelError",
    "command_on_flank",
    "delta_a_from_temperature",
    "pulse_equivalent_mm",
    "pulses_for_travel",
    "round_pulses",
    "round_pulses_array",
]
