"""The pure parts of commissioning (gateway/calibration/fitting/adaptive.py), checked against
numbers made another way: the lead search, the verdict on a verification run, the refined table,
and the drift taken off readings."""

from __future__ import annotations

import numpy as np
import pytest

from gateway.calibration.fitting import adaptive
from gateway.calibration.plans.rawdata import AxisDeviations, RawData
from gateway.compensation import PitchStage, PitchTable


@pytest.mark.parametrize(("lead_mm", "second_um"), [(4.0, 0.0), (5.0, 0.4), (10.0, 0.5),
                                                     (16.0, 0.3), (20.0, 0.0)])
def test_the_lead_search_finds_the_screw_lead(lead_mm: float, second_um: float) -> None:
    rng = np.random.default_rng(int(lead_mm))
    x = adaptive.lead_scan_targets_mm((0.0, 700.0))
    y_um = (1.2 * np.sin(2 * np.pi * x / lead_mm + 0.4)
            + second_um * np.sin(4 * np.pi * x / lead_mm)
            + 3.0 * np.sin(2 * np.pi * x / 70.0)  # waviness longer than the scan
            + 20.0 * (x - 350) / 700 + rng.normal(0, 0.3, x.size))  # a table's slope, noise
    found = adaptive.find_lead(x, y_um * 1e-3)
    assert found.lead_mm == lead_mm  # not a multiple of it, which fits its harmonics too
    assert found.amplitude_um == pytest.approx(1.2, abs=0.15)


def test_no_lead_is_found_in_noise() -> None:
    rng = np.random.default_rng(3)
    x = adaptive.lead_scan_targets_mm((0.0, 500.0))
    found = adaptive.find_lead(x, rng.normal(0, 0.3e-3, x.size))
    assert found.lead_mm is None


def _dev(targets: np.ndarray, up_um: np.ndarray, down_um: np.ndarray) -> AxisDeviations:
    return AxisDeviations("X", targets, np.arange(1, up_um.shape[1] + 1), up_um * 1e-3,
                          down_um * 1e-3)


def test_the_verdict_marks_the_span_where_the_residual_stands_out() -> None:
    table_mm = np.array([0.0, 50.0, 100.0, 150.0, 200.0])
    targets = np.array([25.0, 75.0, 125.0, 175.0])
    rng = np.random.default_rng(5)
    up = rng.normal(0.0, 0.1, (4, 3)) + 0.7  # a constant offset moves no span
    down = rng.normal(0.0, 0.1, (4, 3)) + 0.7
    up[2] += 3.0  # 125 mm, in the span 100..150 (index 2)
    down[2] += 3.0
    v = adaptive.judge_axis(_dev(targets, up, down), table_mm, 2.0, repeatability_sd_um=0.1)
    assert v.failing_spans == (2,)
    assert not v.within and v.E_um == pytest.approx(3.0, abs=0.4)
    calm = adaptive.judge_axis(_dev(targets, up - np.where(np.arange(4)[:, None] == 2, 3.0, 0),
                                    down - np.where(np.arange(4)[:, None] == 2, 3.0, 0)),
                               table_mm, 2.0, repeatability_sd_um=0.1)  # fmt: skip
    assert calm.within and calm.failing_spans == ()


def test_a_budget_refines_the_worst_spans_first() -> None:
    """Three spans stand out of the rest by 3, 6 and 4 µm: with room for two, the 6 and the
    4 are refined (in table order), their severities kept with them."""
    table_mm = np.arange(0.0, 401.0, 50.0)
    targets = table_mm[:-1] + 25.0
    rng = np.random.default_rng(6)
    up = rng.normal(0.0, 0.05, (targets.size, 3))
    up[0] += 3.0
    up[2] += 6.0
    up[6] += 4.0
    v = adaptive.judge_axis(_dev(targets, up, up.copy()), table_mm, 1.0,
                            repeatability_sd_um=0.05)  # fmt: skip
    assert v.failing_spans == (0, 2, 6)
    two = v.worst_first(2)
    assert two.failing_spans == (2, 6)
    assert two.span_worst_um[0] > two.span_worst_um[1] > 3.5
    assert v.worst_first(0).failing_spans == () and v.worst_first(5) is v


def test_a_refined_table_holds_the_residual_at_its_new_points() -> None:
    """New point = the table's own value there + the residual measured with it on: the
    truth at that point, wherever the old points were (checked against a known truth)."""
    def truth_mm(x: np.ndarray) -> np.ndarray:
        return 1e-3 * (5 * np.sin(x / 30.0) + 0.02 * x)

    pos = np.array([0.0, 60.0, 120.0, 180.0])
    table = PitchTable(pos, truth_mm(pos), truth_mm(pos) + 0.002)  # reverse: +2 µm lost motion
    stage = PitchStage(table, "linear")
    mids = adaptive.midpoints_mm(pos, [0, 2])
    np.testing.assert_allclose(mids, [30.0, 150.0])
    table_at = np.interp(mids, pos, truth_mm(pos))
    residual = truth_mm(mids) - table_at  # what the axis shows there with the table on
    dev = AxisDeviations("X", mids, np.array([1]), residual[:, None],
                         (residual + 0.0)[:, None])  # fmt: skip
    new = adaptive.refined_table(table, stage, dev)
    np.testing.assert_allclose(new.position_mm, [0, 30, 60, 120, 150, 180])
    np.testing.assert_allclose(new.forward_mm[[1, 4]], truth_mm(mids), atol=1e-9)
    np.testing.assert_allclose(new.reverse_mm[[1, 4]], truth_mm(mids) + 0.002, atol=1e-9)
    np.testing.assert_allclose(new.forward_mm[[0, 2, 3, 5]], table.forward_mm)  # kept


def test_drift_is_taken_off_by_position_and_progress() -> None:
    """Drift measured 1/3 µm at 0/100 mm before a run and 2/6 µm after: a reading half-way
    through at 50 mm loses (1.5 + 4.5)/2 = 3 µm."""
    drift = adaptive.Drift((0.0, 100.0), (1e-3, 3e-3), (2e-3, 6e-3))
    assert drift.at(np.array([50.0]), np.array([0.5]))[0] == pytest.approx(3e-3)
    assert adaptive.Drift.from_json(drift.to_json()) == drift
    n = 5
    raw = RawData(("X",) * n, np.ones(n, dtype=np.int64), np.ones(n, dtype=np.int8),
                  np.full(n, 50.0), np.full(n, 50.0) + np.linspace(2e-3, 4e-3, n), {},
                  tuple(range(n)))  # fmt: skip
    fixed = adaptive.drift_corrected(raw, {"X": drift})
    expected = np.linspace(2e-3, 4e-3, n)  # the drift at 50 mm grows 2 → 4 µm
    np.testing.assert_allclose(fixed.deviation_mm, 0.0, atol=1e-12)
    np.testing.assert_allclose(raw.deviation_mm, expected)


def test_a_targets_two_passes_take_off_the_same_drift() -> None:
    """One bidirectional run over 10, 50, 90 mm, its references drifting 4 µm evenly: each
    target's ↑ and ↓ readings lose the drift at their mean progress (2 µm), so the
    reversal each reads stays as read (10 µm play + the 4, 2.4 and 0.8 µm the screw drifted
    between its two passes) while the level of the run is put back to where it began."""
    drift = adaptive.Drift((0.0, 100.0), (0.0, 0.0), (4e-3, 4e-3))
    targets = np.array([10.0, 50.0, 90.0, 90.0, 50.0, 10.0])
    direction = np.array([1, 1, 1, -1, -1, -1], dtype=np.int8)
    progress = np.linspace(0.0, 1.0, 6)
    actual = targets + np.where(direction > 0, 0.0, 10e-3) + 4e-3 * progress
    raw = RawData(("X",) * 6, np.ones(6, dtype=np.int64), direction, targets, actual, {},
                  tuple(range(6)))  # fmt: skip
    fixed = adaptive.drift_corrected(raw, {"X": drift}).deviation_mm
    np.testing.assert_allclose(fixed, raw.deviation_mm - 2e-3, atol=1e-12)
    reversal = fixed[3:][::-1] - fixed[:3]
    np.testing.assert_allclose(reversal, [14e-3, 12.4e-3, 10.8e-3], atol=1e-12)


def test_a_table_switch_keeps_the_drift_the_reading_after_it_would_hide() -> None:
    """A screw warming 0.5 / 2 µm at the references per reading of them. Cold base 0 / 0;
    just before a switch the references read 1 / 4 µm of drift; the new table commands
    +3 / −5 µm there. The reading after the switch holds one more reading's heat: 1.5 + 3 /
    6 − 5. Re-linked from that reading the drift after the switch would read 1 / 4 again
    (the heat hidden); carried by the commands it reads 1.5 / 6. A switch of the thermal
    setting (Y here) cannot be computed: read, as before."""
    base = {"X": [0.0, 0.0], "Y": [0.0, 0.0]}
    before = {"X": [1e-3, 4e-3], "Y": [1e-3, 4e-3]}
    drift = {a: [before[a][k] - base[a][k] for k in (0, 1)] for a in before}
    after = {"X": [1.5e-3 + 3e-3, 6e-3 - 5e-3], "Y": [1.5e-3 + 3e-3, 6e-3 - 5e-3]}
    old = {"X": {"mm": [10.0, 90.0], "thermal": "None"},
           "Y": {"mm": [10.0, 90.0], "thermal": "None"}}
    new = {"X": {"mm": [10.003, 89.995], "thermal": "None"},
           "Y": {"mm": [10.003, 89.995], "thermal": "ThermalComp(length_mm=500)"}}
    got = adaptive.relinked_base(base, after, drift, old, new)
    now = {a: [after[a][k] - got[a][k] for k in (0, 1)] for a in got}  # drift read after
    np.testing.assert_allclose(now["X"], [1.5e-3, 6e-3], atol=1e-12)
    np.testing.assert_allclose(now["Y"], [1e-3, 4e-3], atol=1e-12)  # the heat hidden: read
    first = adaptive.relinked_base(None, after, {a: [0.0, 0.0] for a in after}, {}, new)
    assert first == after  # the first config: the cold base is what it reads


def test_a_switch_to_a_deep_table_moves_the_axis_where_its_own_error_differs() -> None:
    """A screw whose error climbs 400 µm over 800 mm with a 20 µm wave every 50 mm; the
    table is that error. Switching from no table to it, the reading at a reference moves by
    −e(x): the axis goes to x − e(x), where the error is no longer e(x). The commands'
    difference says −e(c), half a micrometre off; the table's own model says −e(x) exactly, and
    the drift after the switch keeps what it was before."""
    from gateway.compensation import AxisChain, Chain

    pulse = 0.0001
    x = np.linspace(0.0, 800.0, 801)

    def e_mm(p: np.ndarray) -> np.ndarray:
        return 0.4 * p / 800.0 + 0.02 * np.sin(2 * np.pi * p / 50.0)

    table = PitchTable(x, e_mm(x))
    chain = Chain({"X": AxisChain("X", pulse, pitch=PitchStage(table))})
    refs = [41.0, 760.0]
    new_cmd = [float(chain.command_mm_batch({"X": [r / pulse]})["X"][0]) for r in refs]
    old = {"X": {"mm": refs, "thermal": "None", "commands_mm": [{"X": r} for r in refs]}}
    new = {"X": {"mm": new_cmd, "thermal": "None",
                 "commands_mm": [{"X": c} for c in new_cmd]}}  # fmt: skip
    moved = adaptive.reading_moved_mm(chain, "X", old["X"]["commands_mm"],
                                      new["X"]["commands_mm"])  # fmt: skip
    truth = [-float(e_mm(np.array(r))) for r in refs]  # the machine is its table here
    np.testing.assert_allclose(moved, truth, atol=1e-7)
    commanded = [c - r for c, r in zip(new_cmd, refs)]
    assert max(abs(a - b) for a, b in zip(commanded, truth)) > 4e-4  # half a µm off
    base, drift = {"X": [0.0, 0.0]}, {"X": [1e-3, 9e-3]}
    after = {"X": [drift["X"][k] + truth[k] for k in (0, 1)]}  # no heat during the switch
    got = adaptive.relinked_base(base, after, drift, old, new, None, {"X": moved})
    np.testing.assert_allclose([after["X"][k] - got["X"][k] for k in (0, 1)], drift["X"],
                               atol=1e-9)  # fmt: skip
    was = adaptive.relinked_base(base, after, drift, old, new)  # the commands' difference
    assert max(abs(after["X"][k] - was["X"][k] - drift["X"][k]) for k in (0, 1)) > 4e-4


def test_a_switch_across_a_temperature_sensor_is_computed_at_its_reading() -> None:
    """A temperature-source axis whose sensor correction is switched off (a warm-up) and on
    again: each switch moves the base by what the sensor's stage commands at the references
    at the sensor's reading then (the gateway's own ThermalStage at Δa = gain·α·a·(T − T_ref)),
    so the drift keeps meaning what the sensor's config leaves, however warm the screw is at
    the switch. Without the reading it is read, as before."""
    from gateway.compensation.thermal import ThermalStage, delta_a_from_temperature

    origin, length, gain, alpha, ref_c, t_c = -40.0, 640.0, 1.2, 11.5e-6, 20.0, 24.0
    refs = [31.0, 570.0]
    sensor = {"mm": refs, "thermal": "ThermalComp(temperature)",
              "sensor": [origin, length, gain, alpha, ref_c]}  # fmt: skip
    off = {"mm": refs, "thermal": "None"}
    da = gain * delta_a_from_temperature(alpha, length, t_c, ref_c)
    stage = ThermalStage(length, origin)
    s_mm = [stage.forward_scalar(x, da) - x for x in refs]  # what the sensor commands
    assert min(abs(v) for v in s_mm) > 2e-3  # tens of µm: a switch would hide it all
    base = {"X": [0.0, 0.0]}
    drift = {"X": [1e-3, 4e-3]}
    # the same thermal state on both sides of the switch: the sensor's correction gone
    after = {"X": [drift["X"][k] - s_mm[k] for k in (0, 1)]}
    got = adaptive.relinked_base(base, after, drift, {"X": sensor}, {"X": off}, {"X": t_c})
    now = [after["X"][k] - got["X"][k] for k in (0, 1)]
    # what the sensor's config would read: the drift before the switch, nothing hidden
    np.testing.assert_allclose(now, drift["X"], atol=1e-12)
    # and on again: the sensor's correction back, the drift still what it was
    on_again = {"X": [after["X"][k] + s_mm[k] for k in (0, 1)]}
    back = adaptive.relinked_base(got, on_again, {"X": now}, {"X": off}, {"X": sensor},
                                  {"X": t_c})  # fmt: skip
    np.testing.assert_allclose([on_again["X"][k] - back["X"][k] for k in (0, 1)], drift["X"],
                               atol=1e-12)  # fmt: skip
    read = adaptive.relinked_base(base, after, drift, {"X": sensor}, {"X": off})
    np.testing.assert_allclose(read["X"], [after["X"][k] - drift["X"][k] for k in (0, 1)])


def test_a_refinement_scan_gives_the_point_its_mean_and_the_cyclic_term_a_station() -> None:
    """Truth: a wavy screw whose once-per-turn amplitude grows along the travel. The model
    on: a flat table and a constant 1 µm cyclic term. A one-lead scan at 130 mm (residual
    of truth − model, with noise) must give the table the truth's level there, not the
    level plus whatever phase of the cyclic term the point happens to sit at, and the new
    station the truth's amplitude."""
    from gateway.calibration.fitting.cyclic_fit import StationScan
    from gateway.compensation.cyclic import CyclicModel

    lead, centre = 5.0, 130.0
    rng = np.random.default_rng(11)

    def level_um(x: np.ndarray) -> np.ndarray:  # waviness, 40 mm
        return 4.0 * np.sin(2 * np.pi * x / 40.0)

    def amp_um(x: np.ndarray) -> np.ndarray:  # 1 µm at 0, 3 µm at 200 mm
        return 1.0 + x / 100.0

    table = PitchTable(np.array([0.0, 100.0, 200.0]), np.zeros(3), np.full(3, 0.004))
    model = CyclicModel(lead, np.array([0.0, 200.0]), np.array([[1e-3], [1e-3]]),
                        np.zeros((2, 1)))  # fmt: skip
    x = np.linspace(centre - lead / 2, centre + lead / 2, 9)
    xs = np.concatenate([x, x[::-1]])
    dirs = np.array([1] * 9 + [-1] * 9)
    theta = 2 * np.pi * xs / lead
    truth_um = level_um(xs) + 4.0 * (dirs < 0) + amp_um(xs) * np.sin(theta)
    model_um = 4.0 * (dirs < 0) + 1.0 * np.sin(theta)
    resid_mm = (truth_um - model_um + rng.normal(0, 0.05, xs.size)) * 1e-3
    scan = StationScan(xs, resid_mm, dirs)
    got = adaptive.scan_refinement(table, PitchStage(table, "linear"), model, [centre], [scan])
    i = int(np.flatnonzero(got.table.position_mm == centre)[0])
    want_um = level_um(np.array([centre]))[0]
    assert got.table.forward_mm[i] * 1e3 == pytest.approx(want_um, abs=0.15)
    assert got.table.reverse_mm[i] * 1e3 == pytest.approx(want_um + 4.0, abs=0.15)
    # a single reading at the centre would carry the cyclic term's phase there instead
    assert abs(amp_um(np.array([centre]))[0] * np.sin(2 * np.pi * centre / lead + 0.5)) > 0.5
    j = int(np.flatnonzero(got.cyclic.station_mm == centre)[0])
    assert got.cyclic.sin_mm[j, 0] * 1e3 == pytest.approx(amp_um(np.array([centre]))[0],
                                                          abs=0.1)  # fmt: skip
    assert got.cyclic.station_mm.tolist() == [0.0, centre, 200.0]  # the old ones kept


def test_an_axis_refinement_must_pay_a_denser_plane_grid_must_not_lose() -> None:
    """An axis's refinement replaces the best table only when clearly better (10 %, at
    least 0.2 µm); the plane's denser, smoothed grid and an axis's sweep stay unless
    clearly worse: the same
    0.17 µm better (rough-0's plane, 1.03 → 0.86 µm, put back before) or 0.1 µm worse."""
    assert not adaptive.keeps_refinement(0.86, 1.03)
    assert adaptive.keeps_refinement(0.80, 1.03)
    assert adaptive.keeps_refinement(0.86, 1.03, plane=True)
    assert adaptive.keeps_refinement(1.13, 1.03, plane=True)
    assert not adaptive.keeps_refinement(1.30, 1.03, plane=True)
    assert not adaptive.keeps_refinement(6.9, 6.19, plane=True)  # worse by over 10 %
    # an axis's sweep, more readings of the same axis, too (smooth-7's X: 1.35 → 1.19 µm,
    # put back before; noise-free its table missed 0.34 µm, the one kept instead 0.73)
    assert not adaptive.keeps_refinement(1.19, 1.35)
    assert adaptive.keeps_refinement(1.19, 1.35, swept=True)
    assert adaptive.keeps_refinement(0.80, 0.71, swept=True)
    assert not adaptive.keeps_refinement(1.20, 0.71, swept=True)
    # ... and worse only within a target mean's noise: chance (rough-2's Y, 1.95 → 2.46 µm
    # at a noise of 0.97 µm; noise-free the sweep left 1.02 µm, the table kept 1.30)
    assert not adaptive.keeps_refinement(2.46, 1.95, swept=True)
    assert adaptive.keeps_refinement(2.46, 1.95, swept=True, noise_um=0.97)
    assert not adaptive.keeps_refinement(3.10, 1.95, swept=True, noise_um=0.97)
    assert not adaptive.keeps_refinement(2.46, 1.95, noise_um=0.97)  # new points: must pay


def test_random_targets_find_room_between_a_swept_tables_points() -> None:
    """A swept table's points every 0.25 (mm or °) leave no room at a 0.2 clearance: the
    clearance shrinks to 0.4 of their spacing, so a round still has its random targets,
    each between two points; a coarse table keeps the 0.2."""
    dense = np.round(np.arange(-14.0, 13.01, 0.25), 4)
    t = adaptive.random_targets_mm((-14.0, 13.0), 12, 7, dense, margin_mm=0.0)
    assert t.size == 12
    gap = np.min(np.abs(t[:, None] - dense[None, :]), axis=1)
    assert np.all(gap >= 0.1 - 1e-9) and np.all(gap < 0.125 + 1e-9)
    coarse = np.arange(0.0, 101.0, 2.0)
    t = adaptive.random_targets_mm((0.0, 100.0), 12, 7, coarse)
    assert t.size == 12 and np.min(np.abs(t[:, None] - coarse[None, :])) >= 0.2


def _four_harmonics_um(x: np.ndarray, lead: float) -> np.ndarray:
    """A rough screw's once-per-turn error with a 4th harmonic (the random rough machines
    carry up to 4): 2, 0.8, 0.5 and 0.6 µm."""
    theta = 2 * np.pi * x / lead
    return (2.0 * np.sin(theta) + 0.8 * np.cos(2 * theta) + 0.5 * np.sin(3 * theta)
            + 0.6 * np.sin(4 * theta + 0.7))  # fmt: skip


def test_dense_scans_fit_a_fourth_harmonic_where_the_screw_has_one() -> None:
    """Three dense scans (16 a lead, 2 leads, both ways, 0.2 µm noise) of a screw with a
    4th harmonic of 0.6 µm: the fit keeps it (at most 3 it stayed in the residual, its
    0.6 µm at every phase the tables do not read), and a screw without one still gets 3."""
    from gateway.calibration.fitting.cyclic_fit import StationScan, dense_scan_targets, fit_cyclic

    lead, stations = 5.0, [100.0, 300.0, 500.0]
    rng = np.random.default_rng(3)

    def scans(fourth: bool) -> list[StationScan]:
        out = []
        for s in stations:
            x = dense_scan_targets(s, lead)
            xs = np.concatenate([x, x[::-1]])
            d = _four_harmonics_um(xs, lead) - (0.0 if fourth else 0.6 * np.sin(
                4 * 2 * np.pi * xs / lead + 0.7)) + 0.01 * (xs - s) + rng.normal(0, 0.2, xs.size)
            out.append(StationScan(xs, d * 1e-3, np.repeat([1, -1], x.size)))
        return out

    fit = fit_cyclic(stations, scans(True), lead)
    assert fit.harmonics == 4
    amp_um = np.hypot(fit.model.sin_mm[:, 3], fit.model.cos_mm[:, 3]) * 1e3
    assert np.all(np.abs(amp_um - 0.6) < 0.15), amp_um
    assert fit.residual_rms_um < 0.25
    assert fit_cyclic(stations, scans(False), lead).harmonics == 3


def test_a_refinement_scan_leaves_the_harmonics_it_cannot_resolve_as_they_were() -> None:
    """A refinement scan reads 8 a lead over one lead: a 4th harmonic's sine and cosine are
    one alternating column there. With a 4-harmonic model the new station takes the first
    three from the scan and the 4th from the model (not a least-norm split of whatever
    alternates in the residual)."""
    from gateway.calibration.fitting.cyclic_fit import StationScan
    from gateway.compensation.cyclic import CyclicModel

    lead, centre = 5.0, 130.0
    assert adaptive.resolved_harmonics(np.linspace(0, lead, 9), lead) == 3
    assert adaptive.resolved_harmonics(np.linspace(0, 2 * lead, 33), lead) == 7
    assert adaptive.resolved_harmonics(np.linspace(0, lead, 10), lead) == 4
    sin4 = np.zeros((2, 4))
    sin4[:, 0], sin4[:, 3] = 1e-3, 0.6e-3
    model = CyclicModel(lead, np.array([0.0, 200.0]), sin4, np.zeros((2, 4)))
    table = PitchTable(np.array([0.0, 100.0, 200.0]), np.zeros(3), np.zeros(3))
    x = np.linspace(centre - lead / 2, centre + lead / 2, 9)
    xs = np.concatenate([x, x[::-1]])
    theta = 2 * np.pi * xs / lead
    # the residual: 0.5 µm more of the first harmonic, and an alternating 0.3 µm (what the
    # 4th's columns would take)
    resid_um = 0.5 * np.sin(theta) + 0.3 * np.cos(4 * theta + 0.3)
    scan = StationScan(xs, resid_um * 1e-3, np.repeat([1, -1], x.size))
    got = adaptive.scan_refinement(table, PitchStage(table, "linear"), model, [centre], [scan])
    j = int(np.flatnonzero(got.cyclic.station_mm == centre)[0])
    assert got.cyclic.sin_mm[j, 0] * 1e3 == pytest.approx(1.5, abs=0.1)
    assert got.cyclic.sin_mm[j, 3] * 1e3 == pytest.approx(0.6, abs=1e-9)
    assert got.cyclic.cos_mm[j, 3] == pytest.approx(0.0, abs=1e-12)
