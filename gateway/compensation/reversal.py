"""Which flank of the play a corrected command ends on when the command moves with no
nominal move of its own.

A target sent again can need a different command: the plane's partner moved, the screw
grew. The motor then moves by that change, and the nut follows it through the play:

- back against the last move by more than a dead band, the nut turns through its play and
  the command is corrected as a reversal (trial 9: Y sent 400 again after X moved, 7.2 µm
  back in command, stayed 7.1 µm off in the play);
- back by less, the table stays on its flank (an error of at most the dead band): crossing
  the whole play for less would make the axis hunt each time a Δa reading wanders;
- on along the flank, a soft nut takes up more of its play (a kept rough machine: X sent
  again up a column of Y targets, 35 µm on, corrected as if the first 9 µm had left the
  nut: 11 µm off at the top).

"Back" is measured from the furthest command on the flank, not the last one, so steps back
each under the dead band add up (the same column: each step 1 µm back, 11 µm off at the top).
"""

from __future__ import annotations

from collections.abc import Mapping

from .chain import AxisInput, Chain
from .direction import MotionState

#: a command going back against its move by no more than this (mm, or degrees) stays on its
#: flank. 2 µm let a row of holes, the held axis sent again, read 3.3 µm on a smooth machine
#: whose random points read 1.2 (session 66: 1.4 at 1 µm); a 1 µm sensor toggling one step
#: still does not turn the axis through its play
TURN_DEADBAND_MM = 0.001


def command_on_flank(
    chain: Chain,
    axis: str,
    inputs: Mapping[str, AxisInput],
    start: MotionState,
    motion: MotionState,
    flank_units: int | None,
    units_per_pulse: int = 1,
    deadband_mm: float = TURN_DEADBAND_MM,
) -> tuple[int, MotionState]:
    """The corrected command of ``axis`` (drive units) and its motion state once there.

    ``start``: the state before this target; ``motion``: after the nominal move alone
    (``inputs[axis]`` carries its engagement); ``flank_units``: the furthest command sent
    on the flank ``motion`` arrives on (None: nothing known, the nominal move decides).
    Raises what :meth:`Chain.command_pulses` raises.
    """
    command = chain.command_pulses(axis, inputs, units_per_pulse)
    if flank_units is None:
        return command, motion
    own = chain.axes[axis]
    change_mm = (command - flank_units) * own.pulse_mm / units_per_pulse
    nominal = int(inputs[axis].pulses)
    if change_mm * motion.direction < -deadband_mm:
        turned = own.turned(start, nominal, -motion.direction, abs(change_mm))
        again = chain.command_pulses(axis, _with_engagement(inputs, axis, turned),
                                     units_per_pulse)  # fmt: skip
        if (again - flank_units) * turned.direction > 0:
            return again, turned
        return command, motion
    on_mm = change_mm * motion.direction
    if own.takeup is None or on_mm <= 0.0 or nominal != start.last_target_pulses:
        # a nominal move advances the engagement by the move alone (the curve's terms: the
        # table's travel), whatever the correction does
        return command, motion
    pushed = own.turned(motion, nominal, motion.direction, on_mm)
    return chain.command_pulses(axis, _with_engagement(inputs, axis, pushed),
                                units_per_pulse), pushed  # fmt: skip


def _with_engagement(inputs: Mapping[str, AxisInput], axis: str,
                     motion: MotionState) -> dict[str, AxisInput]:  # fmt: skip
    """``inputs`` with ``axis``'s engagement taken from ``motion``."""
    own = inputs[axis]
    return {**inputs, axis: AxisInput(own.pulses, motion.engagement, own.delta_a_mm)}
