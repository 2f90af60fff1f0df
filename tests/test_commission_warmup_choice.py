"""Which axis with no sensor gets its zone warm-up (gateway.calibration.commissioning.thermal,
ThermalSteps.too_little_heat): what the drift references cannot rule out is warmed up.
smooth-2 Y on the bench: its references moved 0.8 µm in 19 m of pitch runs, within their
0.4 µm scatter, and it got no warm-up; the judge's 30 minutes of work then grew it 3.2 µm,
none of it modelled."""

from __future__ import annotations

import types

import numpy as np

from gateway.calibration.commissioning.thermal import ThermalSteps


def _steps(grown_um: float, so_far_m: float, scatter_um: float | None,
           warm_m: float = 215.0) -> ThermalSteps:
    """The thermal steps with just what ``too_little_heat`` reads: the references' growth,
    scatter and odometer, the warm-up's strokes (``warm_m`` of travel), the tolerance."""
    drift = types.SimpleNamespace(
        grown_um=lambda a: grown_um, odometer=lambda: {"Y": 1000.0 * so_far_m},
        ref_scatter_um=lambda a: scatter_um, iso_scatter_um=lambda a: None)
    strokes = int(warm_m / 0.4)
    x = np.where(np.arange(strokes + 1) % 2 == 0, 100.0, 500.0)  # 400 mm strokes
    plan = types.SimpleNamespace(axes=["Y"], moves=[types.SimpleNamespace(target_mm=[v])
                                                    for v in x])  # fmt: skip
    axes = types.SimpleNamespace(s=types.SimpleNamespace(tolerance_um=2.0), config=None)
    steps = ThermalSteps(axes, None, drift, lambda _: None)  # type: ignore[arg-type]
    steps.warmup_plan = lambda a: plan  # type: ignore[method-assign]
    return steps


def test_a_drift_within_the_scatter_of_light_work_is_warmed_up() -> None:
    # smooth-2 Y: 0.8 µm in 19 m, scatter 0.43 µm: at most 1.7 µm so far, ~19 µm over
    # the warm-up's 215 m: not ruled out
    assert _steps(0.8, 19.0, 0.43).too_little_heat("Y") is None


def test_a_screw_worked_as_long_as_the_warm_up_and_still_cold_is_not() -> None:
    # the same references over more travel than the warm-up's: at most 0.3 + 0.2 µm
    why = _steps(0.3, 300.0, 0.1).too_little_heat("Y")
    assert why is not None and "too little heat" in why and "300 m" in why, why


def test_no_scatter_known_rules_nothing_out() -> None:
    assert _steps(0.0, 300.0, None).too_little_heat("Y") is None


def test_a_clear_growth_is_warmed_up() -> None:
    assert _steps(5.0, 300.0, 0.3).too_little_heat("Y") is None
