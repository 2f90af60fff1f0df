"""What the commissioning report says remains (pure: a summary in, sentences out)."""

from __future__ import annotations

from typing import Any

from gateway.calibration.commission_report import WARM_SCREW_UM, remains


def _summary(identify: dict[str, Any]) -> dict[str, Any]:
    after = {"E_um": 1.2, "A_um": 2.0, "R_um": 1.1}
    return {"tolerance_um": 1.0, "outcome": "floor", "notes": [], "identify": identify,
            "axes": {"X": {"before": {"E_um": 40.0}, "after": after},
                     "Y": {"before": {"E_um": 9.0}, "after": after}}}  # fmt: skip


def test_a_screw_that_warmed_a_lot_without_a_sensor_is_named_with_its_possible_bow() -> None:
    text = remains(_summary({
        "motion-X": {"fitted": True, "growth_max_um": 35.0, "residual_rms_um": 0.6},
        "motion-Y": {"fitted": False, "why": "the screw grew 0.9 µm at most"}}))
    warm = [s for s in text if "grew by up to" in s]
    assert len(warm) == 1 and warm[0].startswith("Axis X: its screw grew by up to 35.0 µm")
    assert "0.60 µm RMS" in warm[0] and "bow of up to about 2.5 µm" in warm[0]


def test_a_screw_that_barely_warmed_gets_no_such_sentence() -> None:
    small = {"motion-X": {"fitted": True, "growth_max_um": WARM_SCREW_UM - 0.5}}
    assert not any("grew by up to" in s for s in remains(_summary(small)))
    assert not any("grew by up to" in s for s in remains(_summary({})))
