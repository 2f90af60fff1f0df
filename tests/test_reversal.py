"""Which flank a command ends on when it moves with no nominal move (pure, no sockets)."""

from __future__ import annotations

import pytest

from gateway.compensation import (
    TURN_DEADBAND_MM,
    AxisChain,
    AxisInput,
    BacklashStage,
    Chain,
    MotionState,
    TakeUpCurve,
    ThermalStage,
    command_on_flank,
)

PULSE_MM = 0.0001  # 0.1 µm: fine enough to see a step inside the dead band
BACKLASH_MM = 0.020
SCREW_MM = 1000.0
AT_PULSES = 1_000_000  # 100 mm: Δa of 0.01 mm moves the command 1 µm back


def _chain(takeup: TakeUpCurve | None = None) -> Chain:
    axis = AxisChain("X", PULSE_MM, backlash=BacklashStage(BACKLASH_MM),
                     thermal=ThermalStage(SCREW_MM), takeup=takeup)  # fmt: skip
    return Chain({"X": axis})


def _grown(back_um: float) -> float:
    """Δa (mm) that moves the command at AT_PULSES back by ``back_um``."""
    at_mm = AT_PULSES * PULSE_MM
    return SCREW_MM * back_um / 1000.0 / (at_mm - back_um / 1000.0)


def _sent_again(chain: Chain, motion: MotionState, back_um: float, flank: int | None
                ) -> tuple[int, MotionState]:  # fmt: skip
    """X's target sent again (approached in +) with the screw grown so its command goes
    ``back_um`` back."""
    inputs = {"X": AxisInput(AT_PULSES, motion.engagement, _grown(back_um))}
    return command_on_flank(chain, "X", inputs, motion, motion, flank)


def test_a_step_back_inside_the_dead_band_stays_on_its_flank() -> None:
    chain = _chain()
    on_plus = MotionState(1, AT_PULSES)
    flank = chain.command_pulses("X", {"X": AxisInput(AT_PULSES, 1)})
    command, motion = _sent_again(chain, on_plus, 0.5, flank)
    assert motion == on_plus
    assert command == flank - 5  # 0.5 µm back, still on the + flank's correction


def test_a_command_back_beyond_the_dead_band_from_its_flank_turns_the_nut() -> None:
    """Measured from the flank's furthest command (the caller's: steps back add up), the
    command crosses the play to the − flank's correction."""
    chain = _chain()
    on_plus = MotionState(1, AT_PULSES)
    flank = chain.command_pulses("X", {"X": AxisInput(AT_PULSES, 1)})
    command, motion = _sent_again(chain, on_plus, 2.0, flank)
    assert TURN_DEADBAND_MM < 2.0 / 1000
    assert motion.direction == -1 and motion.engagement == -1
    assert command == chain.command_pulses("X", {"X": AxisInput(AT_PULSES, -1, _grown(2.0))})
    assert flank - command == pytest.approx((2.0 + 1000 * BACKLASH_MM) / 1000 / PULSE_MM, abs=1)


def test_a_command_going_on_leaves_a_hard_nut_where_it_was() -> None:
    chain = _chain()
    on_plus = MotionState(1, AT_PULSES)
    flank = chain.command_pulses("X", {"X": AxisInput(AT_PULSES, 1)})
    command, motion = _sent_again(chain, on_plus, -3.0, flank)
    assert motion == on_plus
    assert command == flank + 30


def test_nothing_known_of_the_flank_leaves_the_nominal_move_to_decide() -> None:
    chain = _chain()
    on_plus = MotionState(1, AT_PULSES)
    command, motion = _sent_again(chain, on_plus, 5.0, None)
    assert motion == on_plus
    assert command == chain.command_pulses("X", {"X": AxisInput(AT_PULSES, 1, _grown(5.0))})


SOFT = TakeUpCurve([0.001, 0.300], [0.1, 1.0])  # lost motion taken up over 0.3 mm


def test_a_command_going_on_along_its_flank_takes_a_soft_nut_further_up() -> None:
    chain = _chain(SOFT)
    part_way = MotionState(1, AT_PULSES, -0.5)  # a short reversal in + left it part way
    flank = chain.command_pulses("X", {"X": AxisInput(AT_PULSES, -0.5)})
    command, motion = _sent_again(chain, part_way, -35.0, flank)
    assert motion.engagement == pytest.approx(SOFT.advance(-0.5, 1, 0.035))
    assert motion.engagement > -0.5
    expected = chain.command_pulses("X", {"X": AxisInput(AT_PULSES, motion.engagement,
                                                         _grown(-35.0))})  # fmt: skip
    assert command == expected


def test_a_nominal_move_advances_a_soft_nut_by_the_move_alone() -> None:
    """Going on by a nominal move: the curve is in the table's travel, so the correction's
    change does not push the nut on a second time."""
    chain = _chain(SOFT)
    before = MotionState(1, AT_PULSES - 100, -0.5)
    arrived = chain.axes["X"].approach(before, AT_PULSES)
    flank = chain.command_pulses("X", {"X": AxisInput(AT_PULSES - 100, -0.5)})
    inputs = {"X": AxisInput(AT_PULSES, arrived.engagement, _grown(-35.0))}
    command, motion = command_on_flank(chain, "X", inputs, before, arrived, flank)
    assert motion == arrived
    assert command == chain.command_pulses("X", inputs)
