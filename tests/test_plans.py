"""Calibration plans: spacing, overrun, verification offsets, serpentine, files."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from gateway.calibration.fitting.plans_scans import warmup_plan
from gateway.calibration.plans.plans import (
    Move,
    Plan,
    backlash_from_raw,
    backlash_from_readings,
    backlash_plan,
    iso230_linear_plan,
    iso230_targets_mm,
    read_plan,
    snap_to_pulses,
    write_plan,
)
from gateway.calibration.plans.rawdata import RawWriter, read_raw_csv
from gateway.calibration.plans.xy import xy_grid_plan, xy_verification_plan
from gateway.compensation.errors import TableError

TRAVEL = (0.0, 800.0)


@pytest.mark.parametrize("seed", range(5))
def test_targets_uneven_and_clear_of_the_lead(seed: int) -> None:
    t = iso230_targets_mm(TRAVEL, step_mm=25.0, margin_mm=3.0, seed=seed, lead_mm=5.0)
    assert t[0] == 3.0 and t[-1] == 797.0 and t.size == 33
    spacing = np.diff(t)
    assert np.all(spacing > 25.0 / 2 - 1e-9) and np.all(spacing < 25.0 * 1.5 + 1e-9)
    assert np.ptp(spacing) > 2.0  # uneven
    turns = spacing / 5.0
    assert np.all(np.abs(turns - np.round(turns)) >= 0.05)  # no whole number of leads
    phases = np.mod(t, 5.0) / 5.0  # the screw is sampled at many phases, not one
    assert np.histogram(phases, bins=4, range=(0, 1))[0].min() >= 3


def test_targets_deterministic_and_seeded() -> None:
    a = iso230_targets_mm(TRAVEL, seed=7)
    np.testing.assert_array_equal(a, iso230_targets_mm(TRAVEL, seed=7))
    assert not np.array_equal(a, iso230_targets_mm(TRAVEL, seed=8))
    assert iso230_targets_mm((0, 40), step_mm=25, margin_mm=1).size == 5  # ISO minimum


def test_iso230_plan_cycle_and_overrun() -> None:
    plan = iso230_linear_plan("X", TRAVEL, step_mm=50.0, overrun_mm=4.0, runs=5, seed=1)
    targets = iso230_targets_mm(TRAVEL, step_mm=50.0, margin_mm=4.0, seed=1)
    measured = [m for m in plan.moves if m.measured]
    assert len(measured) == 5 * 2 * targets.size
    per_run = len(plan.moves) // 5
    run1 = plan.moves[:per_run]
    assert [m.run for m in plan.moves[per_run : 2 * per_run]] == [2] * per_run
    assert run1[0] == Move(1, -1, "overrun", (0.0,))
    ups = [m.target_mm[0] for m in run1 if m.measured and m.direction == 1]
    downs = [m.target_mm[0] for m in run1 if m.measured and m.direction == -1]
    np.testing.assert_array_equal(ups, targets)
    np.testing.assert_array_equal(downs, targets[::-1])
    over = plan.targets_mm(role="overrun")
    assert np.all((over >= TRAVEL[0]) & (over <= TRAVEL[1]))  # inside travel
    assert over.min() < targets.min() and over.max() > targets.max()  # beyond the targets
    # every measured + target is reached moving up, every − target moving down
    pos = [m.target_mm[0] for m in plan.moves]
    for k, m in enumerate(plan.moves[1:], start=1):
        assert np.sign(pos[k] - pos[k - 1]) == m.direction


def test_overrun_clipped_to_travel() -> None:
    plan = iso230_linear_plan("X", (0, 100), step_mm=20, margin_mm=1.0, overrun_mm=5.0)
    over = plan.targets_mm(role="overrun")
    assert over.min() == 0.0 and over.max() == 100.0


def test_verification_targets_differ_from_calibration() -> None:
    cal = iso230_linear_plan("X", TRAVEL, step_mm=40.0, seed=3, lead_mm=5.0)
    ver = iso230_linear_plan("X", TRAVEL, step_mm=40.0, seed=3, lead_mm=5.0, verification=True)
    assert ver.kind == "iso230-verification"
    t_cal, t_ver = np.unique(cal.targets_mm()), np.unique(ver.targets_mm())
    assert t_ver.size == t_cal.size - 1 >= 5
    gap = np.abs(t_ver[:, None] - t_cal[None, :]).min()
    assert gap >= 0.5 * np.diff(t_cal).min() - 1e-4 and gap > 5.0  # 1e-4: rounding


def test_backlash_plan_and_value() -> None:
    plan = backlash_plan("X", TRAVEL, takeup_mm=5, away_mm=5, repeats=7, margin_mm=5)
    meas = [m for m in plan.moves if m.measured]
    places = sorted({m.target_mm[0] for m in meas})
    assert places == [10.0, 400.0, 790.0] and len(meas) == 3 * 7 * 2
    assert all(0 <= m.target_mm[0] <= 800 for m in plan.moves)
    # each repeat: take-up move below P, then + to P, + beyond, − back to P
    first = plan.moves[:4]
    assert [m.role for m in first] == ["takeup", "measure", "away", "measure"]
    assert first[0].target_mm[0] < first[1].target_mm[0] < first[2].target_mm[0]
    assert [m.direction for m in first[1:]] == [1, 1, -1]
    # machine with lost motion 8, 12, 10 µm at the three places, ±0.5 µm noise
    rng = np.random.default_rng(0)
    lost = {10.0: 0.008, 400.0: 0.012, 790.0: 0.010}
    place = np.repeat(places, 7)
    up = place - np.vectorize(lost.get)(place) / 2 + rng.normal(0, 5e-4, place.size)
    down = place + np.vectorize(lost.get)(place) / 2 + rng.normal(0, 5e-4, place.size)
    res = backlash_from_readings(place, up, down)
    np.testing.assert_allclose(res.mean_mm, [0.008, 0.012, 0.010], atol=5e-4)
    assert res.backlash_mm == res.mean_mm.max() and list(res.repeats) == [7, 7, 7]


def test_backlash_from_raw_file(tmp_path) -> None:
    plan = backlash_plan("Z", (0, 100), repeats=3)
    path = tmp_path / "raw.csv"
    with RawWriter(path) as w:
        for m in plan.moves:
            if m.measured:
                p = m.target_mm[0]
                w.append("Z", m.run, m.direction, p, p - m.direction * 0.003)  # B = 6 µm
    res = backlash_from_raw(read_raw_csv(path), "Z")
    np.testing.assert_allclose(res.mean_mm, 0.006, atol=1e-12)
    assert res.backlash_mm == pytest.approx(0.006)


def test_xy_grid_serpentine_and_verification() -> None:
    plan = xy_grid_plan((0, 300), (0, 200), nx=4, ny=3)
    pts = plan.measured_points_mm()
    assert pts.shape == (12, 2) and plan.axes == ("X", "Y")
    np.testing.assert_array_equal(pts[:4, 0], [0, 100, 200, 300])
    np.testing.assert_array_equal(pts[4:8, 0], [300, 200, 100, 0])
    np.testing.assert_array_equal(pts[8:, 0], [0, 100, 200, 300])
    assert np.all(np.abs(np.diff(pts, axis=0)).sum(axis=1) > 0)
    steps = np.abs(np.diff(pts, axis=0))
    assert np.all((steps[:, 0] == 0) | (steps[:, 1] == 0))  # one axis at a time: serpentine
    centres = xy_verification_plan((0, 300), (0, 200), 4, 3).measured_points_mm()
    assert centres.shape == (6, 2)
    np.testing.assert_array_equal(np.unique(centres[:, 0]), [50, 150, 250])
    rnd = xy_verification_plan((0, 300), (0, 200), 4, 3, mode="random", count=30, seed=2)
    rp = rnd.measured_points_mm()
    assert rp.shape == (30, 2)
    assert np.all((rp >= 0) & (rp <= [300, 200]))
    dist = np.hypot(*(rp[:, None, :] - pts[None, :, :]).transpose(2, 0, 1)).min()
    assert dist >= 25.0 - 1e-9


def test_the_plane_s_random_points_read_from_both_sides() -> None:
    """With the travel's upper ends too, each random point is read twice: run 1 in + from
    1 mm below, run 2 in − from 1 mm above (clipped at the travel's ends), as a PLC going
    point to point reaches it from either side."""
    one = xy_verification_plan((2, 298), (2, 198), 4, 3, mode="random", count=8, seed=5,
                               approach_mm=1.0, lower_mm=(0, 0))  # fmt: skip
    both = xy_verification_plan((2, 298), (2, 198), 4, 3, mode="random", count=8, seed=5,
                                approach_mm=1.0, lower_mm=(0, 0), upper_mm=(298.5, 200))
    pts = one.measured_points_mm()
    np.testing.assert_array_equal(both.measured_points_mm(), np.vstack([pts, pts]))
    assert dict(both.meta)["both_ways"] == "True" and "both_ways" not in dict(one.meta)
    for run, way in ((1, 1), (2, -1)):
        moves = [m for m in both.moves if m.run == run]
        takeups, measures = moves[0::2], moves[1::2]
        assert all(m.role == "takeup" for m in takeups)
        assert all(m.measured and m.direction == way for m in measures)
        start, at = (np.array([m.target_mm for m in ms]) for ms in (takeups, measures))
        np.testing.assert_allclose(start, np.clip(at + way * -1.0, (0, 0), (298.5, 200)))


def test_warmup_plan() -> None:
    plan = warmup_plan("X", (0, 600), speed_mm_s=100, duration_s=1800, reference_mm=300,
                       measure_every=10)  # fmt: skip
    cycles = int(dict(plan.meta)["cycles"])
    assert cycles == 150  # 1800 s at 12 s per cycle (2 × 600 mm at 100 mm/s)
    stops = [m for m in plan.moves if m.measured]
    assert [m.run for m in stops] == list(range(0, 151, 10))
    short = warmup_plan("X", (0, 600), 100, 1750, 300, measure_every=10)
    assert [m.run for m in short.moves if m.measured][-2:] == [140, 146]  # last cycle too
    assert all(m.target_mm == (300.0,) and m.direction == 1 for m in stops)
    long_moves = [m for m in plan.moves if m.role == "move" and m.run > 0]
    assert len(long_moves) == 2 * cycles and all(m.speed_mm_s == 100 for m in long_moves)
    # a reference at the cycle's lower end would be read once approached in + (the cold
    # reading) and then from above, the play between them: refused, as one outside the ends
    for ref in (0.0, 0.5, 601.0):
        with pytest.raises(ValueError, match="approached in \\+"):
            warmup_plan("X", (0, 600), 100, 1800, ref)


def test_a_zone_warm_up_sends_no_move_to_where_the_axis_stands() -> None:
    """Each cycle enters the zone from its lower end, but only where a reference reading
    left the axis elsewhere: a move to where it stands is a round trip of Modbus requests
    that moves nothing (a third of a zone warm-up's moves were)."""
    plan = warmup_plan("X", (100, 300), 100, 600, 310, measure_every=5,
                       places_mm=(50, 150, 250, 350), also_mm=50)  # fmt: skip
    targets = [m.target_mm for m in plan.moves]
    assert all(a != b for a, b in itertools.pairwise(targets)), targets
    cycles = int(dict(plan.meta)["cycles"])
    strokes = [m for m in plan.moves if m.role == "move" and m.target_mm == (300.0,)]
    assert len(strokes) == cycles  # every cycle still goes up to the zone's upper end


@pytest.mark.parametrize(
    "plan",
    [
        iso230_linear_plan("X", TRAVEL, step_mm=100, seed=4, speed_mm_s=50.0, dwell_s=0.5),
        backlash_plan("Y", (0, 300)),
        xy_grid_plan((0, 300), (10, 200), 3, 3),
        warmup_plan("X", (0, 600), 100, 120, 300),
    ],
    ids=lambda p: p.kind,
)
def test_plan_file_round_trip(tmp_path, plan: Plan) -> None:
    path = tmp_path / "plan.csv"
    write_plan(path, plan)
    back = read_plan(path)
    assert back == plan
    text = path.read_text()
    assert text.startswith("# compgw plan\n# kind: ")


def test_plan_file_user_edits_and_errors(tmp_path) -> None:
    path = tmp_path / "plan.csv"
    path.write_text(
        "# kind: custom\nrun,direction,role,X_mm\n1,+,measure,10  # edited\n\n1,-,measure,5\n"
    )
    plan = read_plan(path)
    assert plan.kind == "custom" and plan.targets_mm().tolist() == [10.0, 5.0]
    for body, msg in [
        ("1,*,measure,10\n", r"line 2: direction"),
        ("1,+,probe,10\n", r"line 2: role 'probe'"),
        ("1,+,measure,ten\n", r"line 2: X_mm 'ten' is not a number"),
        ("x,+,measure,10\n", r"line 2: run 'x'"),
        ("1,+,measure\n", r"line 2: expected 4"),
    ]:
        path.write_text("run,direction,role,X_mm\n" + body)
        with pytest.raises(TableError, match=msg):
            read_plan(path)
    path.write_text("run,role,X_mm\n")
    with pytest.raises(TableError, match="line 1: header"):
        read_plan(path)


def test_snap_to_pulses_puts_every_target_on_its_axis_pulse_grid():
    plan = xy_grid_plan((0.1234, 99.8766), (1.0004, 50.0006), 3, 2, ("X", "Y"), runs=1)
    snapped = snap_to_pulses(plan, {"X": 0.001, "Y": 0.0005})
    pts = np.array([m.target_mm for m in snapped.moves])
    assert np.allclose(pts[:, 0] / 0.001, np.round(pts[:, 0] / 0.001), atol=1e-6)
    assert np.allclose(pts[:, 1] / 0.0005, np.round(pts[:, 1] / 0.0005), atol=1e-6)
    assert np.abs(pts - np.array([m.target_mm for m in plan.moves])).max() <= 0.0005 + 1e-12
    assert [m.role for m in snapped.moves] == [m.role for m in plan.moves]
    assert snap_to_pulses(plan, {}).moves == plan.moves  # unknown axes are left alone


@pytest.mark.parametrize(("step_mm", "lead_mm"), [(10.0, 10.0), (5.0, 5.0), (20.0, 10.0)])
def test_one_point_per_lead_is_planned_clear_of_whole_leads(step_mm: float, lead_mm: float):
    """A step of (a multiple of) the lead, a natural choice, gets targets whose every
    spacing is clear of a whole number of leads (the once-per-lead error sampled at
    different phases), deterministically per seed."""
    t = iso230_targets_mm((0, 800), step_mm=step_mm, lead_mm=lead_mm, seed=3)
    turns = np.diff(t) / lead_mm
    assert np.all(np.abs(turns - np.round(turns)) >= 0.05)
    assert t[0] == 5.0 and t[-1] == 795.0 and len(t) == round(790 / step_mm) + 1
    assert np.array_equal(t, iso230_targets_mm((0, 800), step_mm=step_mm, lead_mm=lead_mm,
                                               seed=3))
