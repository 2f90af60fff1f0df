"""A short budget holds machine time for a short zone warm-up (issues 52 and 54): at 1.5 x a
plain calibration's time no warm-up fitted after the extras, and a sensor's own model (a
temperature at one spot, growth taken linear from the fixed end) left 10-50 µm of what 30
minutes of work on a zone moved a rough screw. The collaborators are stubs: what is held,
in what order, and what the budget then leaves the other steps."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace
from typing import Any

import pytest

from gateway.calibration.commissioning.budget import Budget
from gateway.calibration.commissioning.identify import IdentifySteps
from gateway.calibration.commissioning.settings import SHORT_WARMUP_S


def _steps(tmp_path: Path, left_s: float, kinds: dict[str, str], little: tuple[str, ...] = (),
           more_s: float = 0.0) -> tuple[IdentifySteps, dict[str, Any], Budget]:  # fmt: skip
    """An identification whose warm-ups cost their strokes and 100 s of surveys; ``kinds``
    each axis's heat ("sensor" or "motion"); ``little``: axes whose references read no
    growth that stands out of their scatter; ``more_s``: the runs that bring the tables to
    a plain calibration's."""
    state: dict[str, Any] = {"steps": {}, "notes": []}
    record = SimpleNamespace(state=state, dir=tmp_path, used_s=0.0, save=lambda: None,
                             done=lambda name: name in state["steps"],
                             note=lambda text, replacing="": True)  # fmt: skip
    budget = Budget.__new__(Budget)
    budget.s = SimpleNamespace(budget_s=left_s)
    budget.record = record
    budget.reserve_s = lambda: 0.0  # type: ignore[method-assign]
    budget.step_cost_s = lambda plan, drift=True, whole=False: plan  # type: ignore[method-assign]
    steps = IdentifySteps.__new__(IdentifySteps)
    steps.s = SimpleNamespace(warmup_s=1800.0)
    steps.record = record
    steps.budget = budget
    steps.axes = SimpleNamespace(snap=lambda plan: plan)
    steps.short = SimpleNamespace(plane_held_s=lambda: 300.0, scans_left_s=lambda axes: 0.0,
                                  more_runs_left_s=lambda axes: more_s)  # fmt: skip
    steps.thermal = SimpleNamespace(
        zoned=lambda: [a for a, k in kinds.items() if k == "sensor"],
        heat_zoned=lambda: [a for a, k in kinds.items() if k == "motion"],
        # the references of an axis with no sensor: 0.5 µm grown where little, else 4
        drift=SimpleNamespace(grown_um=lambda a: 0.5 if a in little else 4.0,
                              least_growth_um=lambda a: 1.0),
        # a warm-up's plan is its machine time here: its strokes and the places read
        warmup_plan=lambda a, duration_s=None: 100.0 + (
            duration_s if duration_s is not None else
            state.get("warmup_held", {}).get(a, {}).get("duration_s", 1800.0)))  # fmt: skip
    steps.say = lambda text: None
    return steps, state, budget


def test_a_short_budget_holds_a_short_warm_up_of_the_sensor_axes_first(tmp_path: Path) -> None:
    steps, state, budget = _steps(tmp_path, 1200.0, {"X": "sensor", "Y": "motion"})
    steps._hold_warm_ups(["X", "Y"])
    cost_s = 100.0 + SHORT_WARMUP_S
    # room: 1200 s less the plain grid's 300 holds one warm-up (X, its sensor's first)
    assert state["warmup_held"] == {"X": {"duration_s": SHORT_WARMUP_S, "cost_s": cost_s}}
    assert budget.left_s() == 1200.0 - cost_s  # the other steps see the rest
    assert budget.left_s("X") == 1200.0  # X's own warm-up sees its hold
    state["steps"]["warmup-X"] = {}  # made: nothing held any more
    assert budget.held_s() == 0.0 and budget.left_s() == 1200.0
    steps._hold_warm_ups(["X", "Y"])  # decided once
    assert list(state["warmup_held"]) == ["X"]

    steps, state, budget = _steps(tmp_path, 3000.0, {"X": "sensor", "Y": "motion"})
    steps._hold_warm_ups(["X", "Y"])  # room for both
    assert list(state["warmup_held"]) == ["X", "Y"]
    steps, state, budget = _steps(tmp_path, 3000.0, {"X": "sensor", "Y": "motion"}, ("Y",))
    steps._hold_warm_ups(["X", "Y"])  # Y's references read no heat: none held for it
    assert list(state["warmup_held"]) == ["X"]
    steps, state, budget = _steps(tmp_path, 800.0, {"X": "sensor", "Y": "sensor"})
    steps._hold_warm_ups(["X", "Y"])  # room for less than a short one: shortened by tenths
    held = state["warmup_held"]
    assert list(held) == ["X"] and held["X"]["duration_s"] == pytest.approx(SHORT_WARMUP_S * 0.81)
    assert budget.left_s() == pytest.approx(800.0 - 100.0 - SHORT_WARMUP_S * 0.81)
    steps, state, budget = _steps(tmp_path, 600.0, {"X": "sensor", "Y": "sensor"})
    steps._hold_warm_ups(["X", "Y"])  # not even half a short one beside the plain grid
    assert state["warmup_held"] == {} and budget.left_s() == 600.0


def test_a_warm_up_never_takes_the_place_of_a_plain_calibrations_runs(tmp_path: Path) -> None:
    """The runs that bring the tables to a plain calibration's are held before any warm-up:
    at its machine time smooth-8 warmed X in place of both axes' 4th and 5th runs."""
    steps, state, budget = _steps(tmp_path, 1200.0, {"X": "sensor"}, more_s=700.0)
    steps._hold_warm_ups(["X"])  # 1200 s less the grid's 300 and the runs' 700: none fits
    assert state["warmup_held"] == {} and budget.left_s() == 1200.0
    steps, state, budget = _steps(tmp_path, 1200.0, {"X": "sensor"}, more_s=400.0)
    steps._hold_warm_ups(["X"])  # 500 s: a shortened one
    held = state["warmup_held"]["X"]
    assert held["duration_s"] == pytest.approx(SHORT_WARMUP_S * 0.81) and held["cost_s"] <= 500.0


def test_a_held_warm_up_shortens_to_what_the_steps_before_it_left(tmp_path: Path) -> None:
    steps, state, budget = _steps(tmp_path, 1500.0, {"X": "sensor"})
    steps._hold_warm_ups(["X"])
    steps.record.used_s = 1500.0 - 0.8 * (100.0 + SHORT_WARMUP_S)  # the steps overran
    steps._fit_held_warm_up("X")
    held = state["warmup_held"]["X"]
    assert SHORT_WARMUP_S / 2 <= held["duration_s"] < SHORT_WARMUP_S
    assert held["cost_s"] <= budget.left_s("X")
    steps.record.used_s = 1500.0  # nothing left: down to half its strokes, no shorter
    steps._fit_held_warm_up("X")
    assert state["warmup_held"]["X"]["duration_s"] >= SHORT_WARMUP_S / 2 * 0.9


def test_a_held_warm_up_that_no_longer_fits_lets_its_hold_go(tmp_path: Path) -> None:
    """A held warm-up the steps before left too little for, even at half its strokes, is
    not made, said why, and its hold let go: the after-run is not kept from its time."""
    import asyncio

    steps, state, budget = _steps(tmp_path, 1500.0, {"X": "sensor"})
    steps._hold_warm_ups(["X"])
    steps.record.used_s = 1450.0  # 50 s left: no warm-up fits
    steps._warmed = lambda a: False  # type: ignore[method-assign]
    steps.thermal.heat_warms_up = lambda a: False
    asyncio.run(steps._warm_up_if_affordable("X"))
    assert not state["identify"]["thermal-X"]["fitted"]
    assert "not in the budget left" in state["identify"]["thermal-X"]["why"]
    assert budget.held_s() == 0.0 and "X" not in state["warmup_held"]


def test_a_budget_that_is_not_short_holds_the_heat_warm_ups_from_the_rounds(tmp_path: Path) -> None:
    """Once every axis is identified, each axis with no sensor whose references read heat
    gets a short warm-up held: the rounds after it no longer spend all of that time (at
    the guide's 4 h a sweep took 78 minutes of rough-0's and left no warm-up: 99.9 % of
    X's heat left after a judge's 30 minutes of work), nor have to give it a full one (a
    full one held took rough-8's X sweep: E 1.0 → 9.4 µm). An axis with a sensor was warmed
    before its identification; one whose references read no heat is held nothing. When it
    is made, it grows to the full one where the budget the rounds left holds it."""
    steps, state, budget = _steps(tmp_path, 5000.0, {"X": "motion", "Y": "motion", "Z": "sensor"},
                                  little=("Y",))  # fmt: skip
    steps._warmed = lambda a: False  # type: ignore[method-assign]
    steps._hold_heat_warm_ups()
    cost_s = 100.0 + SHORT_WARMUP_S
    assert state["warmup_held"] == {"X": {"duration_s": SHORT_WARMUP_S, "cost_s": cost_s,
                                          "grow_s": 1800.0}}  # fmt: skip
    assert budget.left_s() == 5000.0 - cost_s  # what the rounds see
    steps._hold_heat_warm_ups()  # decided once
    assert list(state["warmup_held"]) == ["X"]
    # the rounds left room for the full one: it grows to it
    steps._fit_held_warm_up("X")
    assert state["warmup_held"]["X"]["duration_s"] == 1800.0
    # they left room for a part of it: as much of it as fits (in tenths)
    steps, state, budget = _steps(tmp_path, 5000.0, {"X": "motion"})
    steps._warmed = lambda a: False  # type: ignore[method-assign]
    steps._hold_heat_warm_ups()
    steps.record.used_s = 5000.0 - 1500.0
    steps._fit_held_warm_up("X")
    held = state["warmup_held"]["X"]
    assert held["cost_s"] <= 1500.0 and held["duration_s"] == pytest.approx(1800.0 * 0.9**3)
    # they left no more than its hold: it stays short
    steps, state, budget = _steps(tmp_path, 5000.0, {"X": "motion"})
    steps._warmed = lambda a: False  # type: ignore[method-assign]
    steps._hold_heat_warm_ups()
    steps.record.used_s = 5000.0 - cost_s
    steps._fit_held_warm_up("X")
    assert state["warmup_held"]["X"]["duration_s"] == SHORT_WARMUP_S
