"""Word-level rules of the per-axis state: 32-bit packing, halves, feedback at rest."""

from __future__ import annotations

import json

import pytest

from gateway.axis import AxisState, overlap
from gateway.compensation import MotionState
from gateway.modbus.frames import pack_int32


def test_two_halves_in_either_order_complete_the_pair():
    for first_offset in (0, 1):
        state = AxisState(MotionState(1))
        words = pack_int32(123456, "hi_lo")
        state.write_words(first_offset, [words[first_offset]])
        assert not state.pair_complete()
        state.write_words(1 - first_offset, [words[1 - first_offset]])
        assert state.pair_complete()
        assert state.nominal_target("hi_lo") == 123456
        state.committed(123456, 123470)
        assert not state.pair_complete()
        assert state.motion.last_target_pulses == 123456


def test_feedback_at_rest_reports_the_exact_nominal_target():
    state = AxisState(MotionState(1))
    state.committed(500_000, 500_013)
    assert state.reported_feedback(500_013, 499_999.6) == 500_000
    assert state.reported_feedback(400_000, 399_990.4) == 399_990


def test_overlap_of_a_read_with_the_pair():
    assert list(overlap(0x6200, 8, 0x6201)) == [0, 1]
    assert list(overlap(0x6202, 4, 0x6201)) == [1]
    assert list(overlap(0x6200, 2, 0x6201)) == [0]
    assert list(overlap(0x6203, 2, 0x6201)) == []


def test_saved_state_round_trips_and_a_bad_entry_changes_nothing():
    state = AxisState(MotionState(1))
    state.write_words(0, [4, 0x93E0])
    state.committed(300_000, 2_999_879)
    state.applied = True
    saved = json.loads(json.dumps(state.saved()))  # through the file's format
    again = AxisState(MotionState(-1))
    again.restore(saved)
    assert again.saved() == state.saved() and again.shadow_known
    for key, bad in (("direction", 0), ("shadow", [1]), ("applied", "yes"),
                     ("last_command_units", None), ("last_nominal_pulses", "x")):
        fresh = AxisState(MotionState(-1))
        before = fresh.saved()
        with pytest.raises((KeyError, TypeError, ValueError)):
            fresh.restore({**saved, key: bad})
        assert fresh.saved() == before and not fresh.shadow_known


def test_a_nut_part_way_across_its_play_is_saved_and_older_saves_load():
    from gateway.compensation import AxisChain, BacklashStage, TakeUpCurve

    chain = AxisChain("X", 0.001, backlash=BacklashStage(0.04),
                      takeup=TakeUpCurve([0.01, 0.3], [0.1, 1.0]))  # fmt: skip
    state = AxisState(MotionState(1))
    state.committed(300_000, 3_000_000, chain.approach(state.motion, 300_000))
    # 50 µm back: part of the play taken up
    state.committed(299_950, 2_999_500, chain.approach(state.motion, 299_950))
    assert state.motion.direction == -1 and 0.0 < state.motion.engagement < 1.0  # 22 %
    saved = json.loads(json.dumps(state.saved()))
    again = AxisState(MotionState(1))
    again.restore(saved)
    assert again.motion == state.motion
    older = {k: v for k, v in saved.items() if k != "engagement"}  # saved before take-up
    again.restore(older)
    assert again.motion.engagement == -1.0
    with pytest.raises(ValueError, match="engagement"):
        AxisState(MotionState(1)).restore({**saved, "engagement": 1.5})
