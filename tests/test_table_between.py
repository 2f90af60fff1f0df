"""Whether a table misses between its points more than its scatter explains
(``table_cv.between_points``, its ratio): what decides, on a short budget, that the ISO runs are
read at the first table's midpoints too."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from gateway.calibration.fitting.table_cv import between_points
from gateway.calibration.plans.rawdata import AxisDeviations, RawData


def between_points_ratio(dev: AxisDeviations, cyclic=None) -> float | None:
    """:func:`between_points`'s ratio (None where it gives none)."""
    found = between_points(dev, cyclic)
    return None if found is None else found[0]


def _runs(truth_um, x_mm: np.ndarray, scatter_um: float, seed: int, runs: int = 3
          ) -> AxisDeviations:  # fmt: skip
    rng = np.random.default_rng(seed)
    up = truth_um(x_mm)[:, None] + rng.normal(0, scatter_um, (x_mm.size, runs))
    down = truth_um(x_mm)[:, None] + 2.0 + rng.normal(0, scatter_um, (x_mm.size, runs))
    return AxisDeviations("Y", x_mm, np.arange(1, runs + 1), up * 1e-3, down * 1e-3)


def _bow_um(x: np.ndarray) -> np.ndarray:
    return 6.0 * np.sin(np.pi * (x - 10.0) / 50.0) + 0.05 * x


def _dip_um(x: np.ndarray) -> np.ndarray:
    """The bow and a dip of 3.5 µm, 2 mm wide, between two of the points (slit-11358's Y)."""
    return _bow_um(x) - 3.5 * np.exp(-(((x - 19.6) / 1.0) ** 2))


def test_a_table_that_follows_its_screw_reads_its_scatter_and_a_dip_between_points_does_not(
) -> None:  # fmt: skip
    """21 uneven points over 50 mm, 3 runs each way: a bow read with 1 µm of scatter gives
    about 1 (under 1.6 on every seed); the same with the dip, read with 0.3 µm, over 3 on
    every seed. Fewer than 3 points or a single run: no figure."""
    x = np.sort(np.random.default_rng(0).uniform(11, 59, 21))
    for seed in range(10):
        assert between_points_ratio(_runs(_bow_um, x, 1.0, seed)) < 1.6
        assert between_points_ratio(_runs(_dip_um, x, 0.3, seed)) > 3.0
    assert between_points_ratio(_runs(_bow_um, x[:2], 1.0, 0)) is None
    assert between_points_ratio(_runs(_bow_um, x, 1.0, 0, runs=1)) is None


def test_a_table_every_few_leads_is_judged_net_of_its_once_per_lead_error() -> None:
    """A screw of 16 mm lead read every 25 mm: its once-per-lead error (2 µm) falls at a
    new phase at every point, and through the points alone it reads as a table missing
    between them (over 3 on every seed). Net of the cyclic term the scans read, the same
    points read their scatter (under 1.6); the periodic error is the scans' to correct, not
    the midpoints' (which would alias it)."""
    from gateway.compensation.cyclic import CyclicModel

    x = np.arange(0.0, 401.0, 25.0)
    cyclic = CyclicModel(16.0, np.array([0.0, 400.0]), np.full((2, 1), 2e-3),
                         np.zeros((2, 1)))  # fmt: skip

    def screw_um(at: np.ndarray) -> np.ndarray:
        return 0.02 * at + cyclic.error_mm(at) * 1e3

    for seed in range(10):
        dev = _runs(screw_um, x, 0.3, seed, runs=5)
        assert between_points_ratio(dev) > 3.0
        assert between_points_ratio(dev, cyclic) < 1.6


def _raw(truth_um, x_mm: np.ndarray, runs: int, seed: int, heat_um=None) -> RawData:
    """ISO runs of axis X at ``x_mm``, both directions, 0.2 µm of scatter; ``heat_um(x,
    run)`` what the machine's heat adds to each reading."""
    rng = np.random.default_rng(seed)
    rows = [(run, sign, x) for run in range(1, runs + 1) for sign in (1, -1) for x in x_mm]
    run = np.array([r[0] for r in rows])
    sign = np.array([r[1] for r in rows], dtype=np.int8)
    target = np.array([r[2] for r in rows])
    dev_um = truth_um(target) + 1.5 * (sign < 0) + rng.normal(0, 0.2, target.size)
    if heat_um is not None:
        dev_um = dev_um + heat_um(target, run)
    return RawData(("X",) * target.size, run, sign, target, target + dev_um * 1e-3, {},
                   tuple(range(target.size)))  # fmt: skip


def test_midpoints_read_on_a_warmer_machine_are_put_on_the_first_table_s_level() -> None:
    """A screw with waves of 30-60 mm read every 25 mm at 5 runs, then at the midpoints
    (3 runs) on a machine grown meanwhile (4 µm at the fixed end, 10 µm/m along the screw,
    more each run). Levelled, the midpoints keep their waves and lose the heat: the table
    through both sets misses the screw at its midpoints by under 0.4 µm RMS on every seed
    (their own scatter 0.12); unlevelled, by over 3 µm."""
    from gateway.calibration.fitting.table_cv import levelled_midpoints
    from gateway.calibration.plans.rawdata import axis_deviations

    def waves_um(x: np.ndarray) -> np.ndarray:
        return 2.0 * np.sin(2 * np.pi * x / 37.0) + 1.5 * np.sin(2 * np.pi * x / 58.0 + 1.0)

    def heat_um(x: np.ndarray, run: np.ndarray) -> np.ndarray:
        return (4.0 + 0.01 * x) * (1.0 + 0.1 * run)

    first_x = np.arange(0.0, 501.0, 25.0)
    mid_x = (first_x[1:] + first_x[:-1]) / 2
    for seed in range(5):
        first = _raw(waves_um, first_x, 5, seed)
        mid = _raw(waves_um, mid_x, 3, seed + 100, heat_um)
        for raw, bound in ((levelled_midpoints(first, mid, "X"), 0.4), (mid, None)):
            up = np.nanmean(axis_deviations(raw, "X").up_mm, axis=1) * 1e3
            miss = float(np.sqrt(np.mean((up - waves_um(mid_x)) ** 2)))
            assert miss < bound if bound else miss > 3.0, (seed, miss)


def test_midpoints_are_levelled_net_of_the_once_per_lead_error_they_read_at_another_phase(
) -> None:  # fmt: skip
    """A 5 mm lead whose once-per-lead error grows from 1.5 to 3 µm along the travel: the
    points every 25 mm read it at its crest, their midpoints at its trough, a line in
    position apart. Levelled net of the scans' term, the midpoints keep their waves (under
    0.4 µm RMS from the screw, net of the term, on every seed); levelled on their raw
    readings, the line takes the term's growth for heat (over 1 µm)."""
    from gateway.calibration.fitting.table_cv import levelled_midpoints
    from gateway.calibration.plans.rawdata import axis_deviations
    from gateway.compensation.cyclic import CyclicModel

    cyclic = CyclicModel(5.0, np.array([0.0, 500.0]), np.zeros((2, 1)),
                         np.array([[1.5e-3], [3e-3]]))  # fmt: skip

    def waves_um(x: np.ndarray) -> np.ndarray:
        return 2.0 * np.sin(2 * np.pi * x / 37.0) + 1.5 * np.sin(2 * np.pi * x / 58.0 + 1.0)

    def screw_um(x: np.ndarray) -> np.ndarray:
        return waves_um(x) + cyclic.error_mm(x) * 1e3

    first_x = np.arange(0.0, 501.0, 25.0)
    mid_x = (first_x[1:] + first_x[:-1]) / 2
    for seed in range(5):
        first, mid = _raw(screw_um, first_x, 5, seed), _raw(screw_um, mid_x, 2, seed + 100)
        for model, bound in ((cyclic, 0.4), (None, None)):
            raw = levelled_midpoints(first, mid, "X", model)
            up = np.nanmean(axis_deviations(raw, "X").up_mm, axis=1) * 1e3
            miss = up - cyclic.error_mm(mid_x) * 1e3 - waves_um(mid_x)
            rms = float(np.sqrt(np.mean(miss**2)))
            assert rms < bound if bound else rms > 1.0, (seed, rms)


def test_a_line_between_the_sets_is_not_taken_for_heat_where_a_sensor_levels_them() -> None:
    """The same screw read under its own sensor's compensation (no heat between the sets),
    its once-per-lead term modelled at its mean amplitude (2.5 µm where it grows from 1 to
    4): net of the model, the midpoints (read at its trough, the points at its crest) sit a
    line away from the first points, and the line stands out. Without the tilt the
    midpoints keep what they read (under 0.45 µm RMS from the screw on every seed, the
    first points' spline missing its 37 mm waves in the offset); with it the line is taken
    for heat (over 1.2)."""
    from gateway.calibration.fitting.table_cv import levelled_midpoints
    from gateway.calibration.plans.rawdata import axis_deviations
    from gateway.compensation.cyclic import CyclicModel

    truth = CyclicModel(5.0, np.array([0.0, 500.0]), np.zeros((2, 1)),
                        np.array([[1e-3], [4e-3]]))  # fmt: skip
    model = CyclicModel(5.0, np.array([0.0, 500.0]), np.zeros((2, 1)),
                        np.array([[2.5e-3], [2.5e-3]]))  # fmt: skip

    def screw_um(x: np.ndarray) -> np.ndarray:
        return 2.0 * np.sin(2 * np.pi * x / 37.0) + truth.error_mm(x) * 1e3

    first_x = np.arange(0.0, 501.0, 25.0)
    mid_x = (first_x[1:] + first_x[:-1]) / 2
    for seed in range(5):
        first, mid = _raw(screw_um, first_x, 5, seed), _raw(screw_um, mid_x, 2, seed + 100)
        for tilt, bound in ((False, 0.45), (True, None)):
            raw = levelled_midpoints(first, mid, "X", model, tilt)
            up = np.nanmean(axis_deviations(raw, "X").up_mm, axis=1) * 1e3
            rms = float(np.sqrt(np.mean((up - screw_um(mid_x)) ** 2)))
            assert rms < bound if bound else rms > 1.2, (seed, tilt, rms)


def test_a_curved_error_read_at_few_midpoints_is_not_taken_for_heat() -> None:
    """smooth-2's Y: 7 uneven points over 150 mm, its error rising 10 µm in the last 20 mm,
    6 midpoints at 2 runs, no heat between. Levelled against a spline through the first
    points' means, the midpoints keep what they read (under 0.3 µm RMS from the screw on
    every seed; against straight lines the line took their curvature for heat: 0.45)."""
    from gateway.calibration.fitting.table_cv import levelled_midpoints
    from gateway.calibration.plans.rawdata import axis_deviations

    def screw_um(x: np.ndarray) -> np.ndarray:
        return 17.0 * (x / 150.0) ** 6 + 3.0 * np.sin(np.pi * x / 150.0)

    first_x = np.array([1.0, 22.8, 44.7, 69.0, 103.5, 129.4, 149.0])
    mid_x = (first_x[1:] + first_x[:-1]) / 2
    for seed in range(10):
        first, mid = _raw(screw_um, first_x, 5, seed), _raw(screw_um, mid_x, 2, seed + 100)
        raw = levelled_midpoints(first, mid, "X")
        up = np.nanmean(axis_deviations(raw, "X").up_mm, axis=1) * 1e3
        assert float(np.sqrt(np.mean((up - screw_um(mid_x)) ** 2))) < 0.3, seed


def test_the_miss_between_points_is_given_in_millimetres_beside_the_ratio() -> None:
    """What midpoints may win, for ordering the axes by it: the dip's table misses about
    its dip's share of 3.5 µm between its points, the bow's a fraction of a micrometre."""
    x = np.sort(np.random.default_rng(0).uniform(11, 59, 21))
    ratio, miss_mm = between_points(_runs(_dip_um, x, 0.3, 0))
    assert ratio == between_points_ratio(_runs(_dip_um, x, 0.3, 0))
    bow_mm = between_points(_runs(_bow_um, x, 0.3, 0))[1]
    assert 0.3e-3 < miss_mm < 3.5e-3 and bow_mm < 0.5 * miss_mm, (miss_mm, bow_mm)


def test_more_runs_read_after_the_scans_are_put_on_the_first_runs_level() -> None:
    """A short budget reads a table at 3 runs, and 2 more on the same targets after the
    cyclic scans, on a machine grown meanwhile (3 µm at the fixed end, 8 µm/m along the
    screw). Levelled, the 5 runs' means follow the screw as the first 3 do (under 0.25 µm
    RMS on every seed, their scatter's share 0.09); mixed as read, the table keeps 2/5 of
    the growth (over 1 µm)."""
    from gateway.calibration.commissioning.steps import concat_raw
    from gateway.calibration.fitting.table_cv import levelled_midpoints
    from gateway.calibration.plans.rawdata import axis_deviations

    def waves_um(x: np.ndarray) -> np.ndarray:
        return 2.0 * np.sin(2 * np.pi * x / 37.0) + 0.01 * x

    def heat_um(x: np.ndarray, run: np.ndarray) -> np.ndarray:
        return (3.0 + 0.008 * x) * np.ones_like(run)

    x = np.arange(0.0, 501.0, 25.0)
    for seed in range(5):
        first, more = _raw(waves_um, x, 3, seed), _raw(waves_um, x, 2, seed + 100, heat_um)
        more = replace(more, run=more.run + 3)
        for later, bound in ((levelled_midpoints(first, more, "X"), 0.25), (more, None)):
            up = np.nanmean(axis_deviations(concat_raw([first, later]), "X").up_mm, axis=1)
            rms = float(np.sqrt(np.mean((up * 1e3 - waves_um(x)) ** 2)))
            assert rms < bound if bound else rms > 1.0, (seed, rms)


def test_along_its_curve_a_table_that_a_spline_follows_does_not_miss_between_its_points(
) -> None:  # fmt: skip
    """Quarter points are bought where the table still misses as it will be read: a steep
    end (17 µm over the last fifth of 150 mm, 13 points, 0.3 µm of scatter) misses its
    straight lines by over 2 x its scatter on every seed, along a spline under 2; the dip
    between two points misses along every curve (over 3)."""
    x = np.linspace(1.0, 149.0, 13)

    def steep_um(at: np.ndarray) -> np.ndarray:
        return 17.0 * (at / 150.0) ** 6 + 3.0 * np.sin(np.pi * at / 150.0)

    for seed in range(10):
        dev = _runs(steep_um, x, 0.3, seed, runs=4)
        assert between_points(dev)[0] > 2.0
        assert between_points(dev, curves=True)[0] < 2.0
        dip = _runs(_dip_um, np.sort(np.random.default_rng(0).uniform(11, 59, 21)), 0.3, seed)
        assert between_points(dip, curves=True)[0] > 3.0


def test_quarter_points_are_bought_where_the_midpoints_showed_a_table_that_does_not_converge(
) -> None:  # fmt: skip
    """What a table through its points and midpoints is expected to miss: the first
    table's miss at its midpoints, times how much it fell from twice the spacing. A bow
    (a spline follows it) read every 5 mm and at the midpoints: under 2 x the midpoints'
    scatter on every seed; a screw whose waves are as short as the spacing (15-25 mm,
    read every 25 mm): over 3 on every seed, and its expected miss within a factor 2 of
    what a table through both misses at the quarter points."""
    from gateway.calibration.fitting.table_cv import denser_miss
    from gateway.calibration.plans.rawdata import axis_deviations

    def waves_um(x: np.ndarray) -> np.ndarray:
        return 2.0 * np.sin(2 * np.pi * x / 17.0) + 1.5 * np.sin(2 * np.pi * x / 23.0 + 1.0)

    from gateway.calibration.commissioning.steps import concat_raw

    for seed in range(5):
        for truth, step, rough in ((lambda x: 8.0 * np.sin(np.pi * x / 500.0), 50.0, False),
                                   (waves_um, 25.0, True)):  # fmt: skip
            x = np.arange(0.0, 501.0, step)
            mid_x = (x[1:] + x[:-1]) / 2
            first = _raw(truth, x, 3, seed)
            both = concat_raw([first, _raw(truth, mid_x, 2, seed + 100)])
            ratio, miss_mm = denser_miss(axis_deviations(both, "X"), first.target_mm)
            if not rough:
                assert ratio < 2.0, (seed, ratio)
                continue
            assert ratio > 3.0, (seed, ratio)
            dense = np.sort(np.concatenate([x, mid_x]))
            quarters = (dense[1:] + dense[:-1]) / 2
            actual_um = float(np.sqrt(np.mean(
                (np.interp(quarters, dense, truth(dense)) - truth(quarters)) ** 2)))
            assert 0.5 < miss_mm * 1e3 / actual_um < 2.0, (seed, miss_mm, actual_um)


@pytest.mark.parametrize("kept", [True, False])
def test_a_short_budget_levels_an_axis_that_keeps_its_sensor_by_the_offset_alone(
        kept: bool) -> None:  # fmt: skip
    """The table a short budget fits (:meth:`ShortBudget.iso_raw`), of a screw read with no
    heat between its sets whose midpoints sit a line off its first points (a 25 mm wave
    whose amplitude runs from −1.5 to 1.5 µm, read at its crests and troughs, beside 37 mm
    waves): an axis
    that keeps its sensor keeps the midpoints as read (under 0.45 µm RMS from the screw);
    one that does not takes the line for heat (over 1 µm)."""
    from types import SimpleNamespace

    from gateway.calibration.commissioning.short import ShortBudget
    from gateway.calibration.plans.rawdata import axis_deviations

    def screw_um(x: np.ndarray) -> np.ndarray:  # a crest at every first point, a trough between
        wave = 0.006 * (x - 250.0) * np.cos(2 * np.pi * x / 25.0)
        return 2.0 * np.sin(2 * np.pi * x / 37.0) + wave

    first_x = np.arange(0.0, 501.0, 25.0)
    mid_x = (first_x[1:] + first_x[:-1]) / 2
    raws = {"iso-X": _raw(screw_um, first_x, 5, 0), "iso-mid-X": _raw(screw_um, mid_x, 2, 100)}
    drift = SimpleNamespace(sensor_kept=lambda a: kept)
    short = ShortBudget(SimpleNamespace(s=SimpleNamespace(lead_mm={})), None, None,  # type: ignore[arg-type]
                        SimpleNamespace(raw=raws.__getitem__, drift=drift),  # type: ignore[arg-type]
                        SimpleNamespace(iso_steps=lambda a: list(raws)), None, print)  # type: ignore[arg-type]
    dev = axis_deviations(short.iso_raw("X"), "X")
    at = np.isin(dev.target_mm, mid_x)
    up = np.nanmean(dev.up_mm[at], axis=1) * 1e3
    rms = float(np.sqrt(np.mean((up - screw_um(mid_x)) ** 2)))
    assert rms < 0.45 if kept else rms > 1.0, (kept, rms)
