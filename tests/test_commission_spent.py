"""What each commissioning step cost and bought (the report's Machine time section), from
a summary alone: every minute counted once, rounds judged by the round after them."""

from __future__ import annotations

import pytest

from gateway.calibration.commissioning.spent import spent_rows, step_group


def test_steps_fall_into_the_groups_a_technician_pays_for() -> None:
    assert step_group("iso-X") == ("iso", "X")
    assert step_group("takeup-probe-Y") == ("backlash", "Y")
    assert step_group("sweep2-X") == ("round 2", "")
    assert step_group("refine1-xy") == ("round 1", "")
    assert step_group("after-steps-X") == ("judging", "")
    assert step_group("before-xy") == ("judging", "")
    assert step_group("xy-grid") == ("plane", "")


def test_every_minute_counted_once_and_each_group_says_what_it_bought() -> None:
    summary = {
        "spent_s": {"backlash-X": 90.0, "takeup-probe-X": 30.0, "iso-X": 300.0,
                    "before-X": 240.0, "verify1-X": 300.0, "sweep1-X": 1800.0,
                    "verify2-X": 150.0, "warmup-X": 2400.0, "after-X": 240.0},
        "refs_s": 600.0,
        "axes": {"X": {"before": {"E_um": 9.0}, "after": {"E_um": 1.1}, "table_points": 40}},
        "rounds": [{"round": 1, "axes": {"X": {"E_um": 6.0}}, "swept": ["X"],
                    "added": {"X": 30}},
                   {"round": 2, "axes": {"X": {"E_um": 1.2}}, "outcome": "within"}],
        "identify": {
            "backlash-X": {"B_um": 4.0, "places_um": [3.0, 4.0, 3.5]},
            "thermal-X": {"fitted": True, "tau_s": 700.0, "origin_mm": 600.0,
                          "delta_a_um_per_m": 0.3, "spread_mm": None, "linear_rms_um": 0.9,
                          "profile_rms_um": 0.6, "growth_max_um": 18.2,
                          "drift_check": {"left_rms_um": 0.48, "drift_rms_um": 3.24,
                                          "holds": True}}},
        "warmed_um": {"X": 18.2},
    }  # fmt: skip
    rows = {step: (minutes, bought) for step, minutes, bought in spent_rows(summary)}
    total_s = sum(summary["spent_s"].values()) + summary["refs_s"]
    assert sum(m for m, _ in rows.values()) == pytest.approx(total_s / 60.0)
    assert rows["X backlash and take-up"][0] == pytest.approx(2.0)
    assert rows["round 1"][0] == pytest.approx(35.0)
    assert "round 2 read X E 6.00 → 1.20 µm" in rows["round 1"][1]
    assert "swept X" in rows["round 1"][1] and "+30" not in rows["round 1"][1]
    assert "X E 9.00 → 1.10 µm" in rows["before- and after-runs"][1]
    assert "40 points" in rows["X ISO 230-2 runs"][1]
    warm = rows["X zone warm-up"][1]
    assert "time constant 700 s" in warm and "leaves 0.48 of 3.24 µm RMS" in warm, warm
    assert "4.00 µm at most" in rows["X backlash and take-up"][1]
    assert "X 18.2 µm" in rows["drift references"][1]
