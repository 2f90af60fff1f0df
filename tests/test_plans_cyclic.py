"""The cyclic plan (issue 7): dense scans, both directions, take-up moves, the plan file."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from gateway.calibration.fitting.plans_scans import cyclic_plan, cyclic_stations_mm
from gateway.calibration.plans.plans import iso230_linear_plan, plan_time_s, read_plan, write_plan
from gateway.cli import main

LEAD = 10.0
CONFIG = str(Path(__file__).resolve().parent.parent / "config" / "example.yaml")


def scans(plan):
    """{(run, direction): [targets in order]} of the measured moves."""
    out: dict[tuple[int, int], list[float]] = {}
    for m in plan.moves:
        if m.measured:
            out.setdefault((m.run, m.direction), []).append(m.target_mm[0])
    return out


def test_plan_file_round_trip(tmp_path) -> None:
    plan = cyclic_plan("X", (0, 800), LEAD)
    write_plan(tmp_path / "c.plan", plan)
    back = read_plan(tmp_path / "c.plan")
    assert back == plan and back.kind == "cyclic"
    meta = dict(back.meta)
    assert meta["lead_mm"] == "10" and meta["stations_mm"] == "120 400 680"


@pytest.mark.parametrize("per_lead,leads", [(16, 2), (20, 3), (32, 2.5)])
def test_dense_at_three_stations_both_directions(per_lead, leads) -> None:
    plan = cyclic_plan("X", (0, 800), LEAD, per_lead=per_lead, leads=leads, takeup_mm=1.5)
    by_scan = scans(plan)
    assert sorted(by_scan) == [(j, d) for j in (1, 2, 3) for d in (-1, 1)]
    centres = []
    for (_, d), t in by_scan.items():
        t = np.array(t)
        step = np.diff(t) * d
        assert np.all(step > 0) and np.all(step <= LEAD / 16 + 1e-9)  # monotone, ≤ lead/16
        assert np.ptp(t) >= 2 * LEAD - 1e-9  # ≥ 2 leads
        centres.append(0.5 * (t.min() + t.max()))
    assert sorted(set(np.round(centres, 6))) == [120.0, 400.0, 680.0]  # 15, 50, 85 %


def test_a_takeup_move_before_each_scan_direction() -> None:
    plan = cyclic_plan("X", (0, 800), LEAD, takeup_mm=2.0)
    moves = plan.moves
    for k, m in enumerate(moves):
        first = m.measured and (k == 0 or not moves[k - 1].measured)
        if not first:
            continue
        before = moves[k - 1]
        assert before.role == "takeup"
        # from the side the scan approaches from, by the take-up distance
        assert (m.target_mm[0] - before.target_mm[0]) * m.direction == pytest.approx(2.0)
    assert sum(m.role == "takeup" for m in moves) == 6


def test_stations_given_or_kept_inside_the_travel() -> None:
    st = cyclic_stations_mm((0, 300), LEAD, [0, 150, 300], takeup_mm=1)
    np.testing.assert_array_equal(st, [11, 150, 289])
    plan = cyclic_plan("Y", (0, 300), LEAD, [0, 150, 300])
    t = plan.targets_mm()
    assert t.min() >= 0 and t.max() <= 300
    with pytest.raises(ValueError, match="increasing"):
        cyclic_stations_mm((0, 300), LEAD, [150, 100])
    with pytest.raises(ValueError, match="shorter than one dense scan"):
        cyclic_plan("X", (0, 15), LEAD)
    with pytest.raises(ValueError, match="16 points per lead"):
        cyclic_plan("X", (0, 800), LEAD, per_lead=8)
    with pytest.raises(ValueError, match="lead_mm"):
        cyclic_plan("X", (0, 800), 0.0)


def test_machine_time_of_the_dense_scans() -> None:
    plan = cyclic_plan("X", (0, 800), LEAD)
    assert sum(m.measured for m in plan.moves) == 198
    # 198 readings × 2 s + about 600 mm of travel at 100 mm/s
    assert plan_time_s(plan, 100.0, 2.0) == pytest.approx(198 * 2 + 6.0, abs=2.0)
    iso = iso230_linear_plan("X", (0, 800), step_mm=39.7, runs=5, overrun_mm=1)
    assert plan_time_s(plan) < plan_time_s(iso)


def test_calibrate_cyclic_generates_the_plan(tmp_path, capsys) -> None:
    config = CONFIG
    rc = main(["calibrate", "-c", config, "--cyclic", "X", "--lead-mm", "10",
               "--stations", "100,400,700", "--save-plan", str(tmp_path / "c.plan")])
    assert rc == 0  # no --gateway: the plan is written (for another software), nothing runs
    out, _ = capsys.readouterr()
    assert "min of machine time" in out and f"wrote {tmp_path / 'c.plan'}: " in out
    assert read_plan(tmp_path / "c.plan") == cyclic_plan("X", (0, 800), 10, [100, 400, 700])
    rc = main(["calibrate", "-c", config, "--cyclic", "X", "--raw", str(tmp_path / "r.csv")])
    assert rc == 1 and "--cyclic needs --lead-mm" in capsys.readouterr().err
