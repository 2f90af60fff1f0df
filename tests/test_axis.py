"""Word-level rules of the per-axis state: 32-bit packing, halves, feedback at rest."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from gateway.axis import AxisState, int32_to_words, overlap, words_to_int32
from gateway.compensation import MotionState


@given(st.integers(-(1 << 31), (1 << 31) - 1), st.sampled_from(["hi_lo", "lo_hi"]))
def test_int32_round_trip_both_word_orders(value, order):
    first, second = int32_to_words(value, order)
    assert 0 <= first <= 0xFFFF and 0 <= second <= 0xFFFF
    assert words_to_int32(first, second, order) == value


def test_word_orders_by_hand():
    assert int32_to_words(-2, "hi_lo") == (0xFFFF, 0xFFFE)
    assert int32_to_words(-2, "lo_hi") == (0xFFFE, 0xFFFF)
    assert int32_to_words(0x12345678, "hi_lo") == (0x1234, 0x5678)
    assert words_to_int32(0x5678, 0x1234, "lo_hi") == 0x12345678
    with pytest.raises(OverflowError):
        int32_to_words(1 << 31, "hi_lo")


def test_two_halves_in_either_order_complete_the_pair():
    for first_offset in (0, 1):
        state = AxisState(MotionState(1))
        words = int32_to_words(123456, "hi_lo")
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
