"""The XY grid smoothed by its own leave-one-out: the field kept, the stops' scatter not
followed (what one axis sees along a grid line with the other parked)."""

from __future__ import annotations

import numpy as np
import pytest

from gateway.calibration.fitting.grid_smooth import smooth_grid
from gateway.calibration.fitting.models import choose_planar_model, grid_clearly_better
from gateway.compensation import GridModel, PlanarMeasurement


def _field_mm(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """A guide-like field over 500 × 400 mm: waves of 250 and 160 mm, a sag, a twist (µm
    sizes), as (ex, ey) in mm."""
    tx, ty = x / 500.0, y / 400.0
    ex = (3.0 * np.sin(2 * np.pi * x / 250.0 + 0.4) * (0.5 + ty)
          + 4.0 * np.sin(np.pi * tx) * np.sin(np.pi * ty) + 2.0 * tx * ty)
    ey = 2.5 * np.sin(2 * np.pi * y / 160.0 + 1.1) * (1.0 - 0.5 * tx) + 3.0 * np.sin(np.pi * tx)
    return np.stack([ex, ey], axis=-1) * 1e-3


def _grid(nx: int, ny: int, sigma_um: float, seed: int) -> PlanarMeasurement:
    xs, ys = np.linspace(2, 498, nx), np.linspace(2, 398, ny)
    pts = np.stack(np.meshgrid(xs, ys), axis=-1).reshape(-1, 2)
    rng = np.random.default_rng(seed)
    err = _field_mm(pts[:, 0], pts[:, 1]) + rng.normal(0, sigma_um * 1e-3, pts.shape)
    return PlanarMeasurement(pts, pts + err, "test grid")


def _along_x_ptp_um(model, y_mm: float) -> float:
    """Peak to peak of the X error left along a line at ``y_mm`` (µm): what an X run with Y
    parked there reads beyond a constant."""
    x = np.linspace(5, 495, 400)
    p = np.stack([x, np.full_like(x, y_mm)], axis=-1)
    left = _field_mm(x, p[:, 1])[:, 0] - model.error_mm(p)[:, 0]
    return float(np.ptp(left) * 1e3)


def test_a_noisy_grid_is_smoothed_and_the_field_kept() -> None:
    """25 × 17 stops with 0.6 µm of scatter each: the cubic grid through them leaves over
    1.8 µm peak to peak along lines of X; the smoothed one under 1.2 µm, at every park."""
    meas = _grid(25, 17, 0.6, seed=5)
    choice = choose_planar_model(meas, "grid")
    raw = GridModel.from_measurement(meas)
    parks = (60.0, 150.0, 230.0, 330.0)
    through = [_along_x_ptp_um(raw, y) for y in parks]
    smoothed = [_along_x_ptp_um(choice.model, y) for y in parks]
    assert min(through) > 1.8
    assert max(smoothed) < 1.2
    # the model file is made of the points: they are the smoothed values, not the stops
    again = GridModel.from_measurement(choice.points)
    probe = np.array([[123.0, 77.0], [401.0, 311.0]])
    np.testing.assert_allclose(again.error_mm(probe), choice.model.error_mm(probe), atol=1e-9)


def test_a_clean_grid_is_not_smoothed_away() -> None:
    """No scatter: the smoothing chosen leaves the field to within 0.15 µm anywhere."""
    choice = choose_planar_model(_grid(25, 17, 0.0, seed=1), "grid")
    rng = np.random.default_rng(2)
    p = np.column_stack([rng.uniform(5, 495, 300), rng.uniform(5, 395, 300)])
    worst_um = np.abs(choice.model.error_mm(p) - _field_mm(p[:, 0], p[:, 1])).max() * 1e3
    assert worst_um < 0.15


def test_scatter_alone_is_mostly_taken_out() -> None:
    """A flat field read with 1 µm of scatter: what is kept is a fraction of it, and the
    leave-one-out residuals say how large the scatter is."""
    rng = np.random.default_rng(9)
    z = rng.normal(0.0, 1.0, (17, 25))
    got = smooth_grid(z)
    assert np.std(got.values) < 0.3
    assert np.sqrt(np.mean(got.loo**2)) == pytest.approx(1.0, abs=0.15)
    assert got.lambda_x > 1.0 and got.lambda_y > 1.0


def test_a_grid_too_coarse_to_smooth_along_is_kept_as_measured() -> None:
    """Three lines each way: no second difference to judge by; the grid passes through."""
    z = np.arange(9.0).reshape(3, 3) ** 2
    got = smooth_grid(z)
    np.testing.assert_array_equal(got.values, z)


def test_a_polynomial_field_gets_its_own_degree_not_one_for_the_scatter() -> None:
    """A degree-2 field (squareness, bows, a twist: a smooth machine's) read at 13 × 9
    stops with 0.3 µm of scatter: degree 2 and the polynomial, for every seed (higher
    degrees and the grid predict left-out stops no better, within the scatter)."""
    xs, ys = np.linspace(2, 498, 13), np.linspace(2, 398, 9)
    pts = np.stack(np.meshgrid(xs, ys), axis=-1).reshape(-1, 2)
    tx, ty = pts[:, 0] / 500.0, pts[:, 1] / 400.0
    field_mm = np.column_stack([8.0 * 4 * ty * (1 - ty) + 3.0 * tx * ty + 20.0 * ty,
                                -6.0 * 4 * tx * (1 - tx)]) * 1e-3  # fmt: skip
    for seed in range(5):
        noise = np.random.default_rng(seed).normal(0, 0.3e-3, pts.shape)
        choice = choose_planar_model(PlanarMeasurement(pts, pts + field_mm + noise, "t"))
        assert (choice.kind, choice.degree) == ("poly", 2), choice.loo_rms_um


def test_a_plane_read_with_scatter_is_a_plane_and_a_field_a_grid() -> None:
    """A plane (out of square, a tilt) read at 9 × 6 stops with 1.6 µm of scatter (a small
    stage's, mcu1025): a polynomial on all but 2 of 40 seeds, though the grid's
    leave-one-out comes out 5 % lower by chance on 6 of them (it must also win by twice
    its standard error, point by point). A guide-like field read the same way: the grid,
    on every seed."""
    xs, ys = np.linspace(2, 498, 9), np.linspace(2, 398, 6)
    pts = np.stack(np.meshgrid(xs, ys), axis=-1).reshape(-1, 2)
    plane_mm = np.column_stack([4e-6 * pts[:, 1], 2e-6 * pts[:, 0]])
    field_mm = _field_mm(pts[:, 0], pts[:, 1]) * 3.0
    grids = 0
    for seed in range(40):
        noise = np.random.default_rng(seed).normal(0, 1.6e-3, pts.shape)
        choice = choose_planar_model(PlanarMeasurement(pts, pts + plane_mm + noise, "t"))
        grids += choice.kind == "grid"
        choice = choose_planar_model(PlanarMeasurement(pts, pts + field_mm + noise, "t"))
        assert choice.kind == "grid", choice.loo_rms_um
    assert grids <= 2


def test_a_grid_that_wins_narrowly_is_kept_against_a_high_degree() -> None:
    """The grid's leave-one-out 8 % under a degree-4 polynomial's, the difference within
    its noise: the grid (the polynomial is no simpler; sdss-1396's 9 × 7 plate, where the
    degree-4 fit left E worse than uncorrected); the same margin over a plane: the plane."""
    grid = np.full(63, np.sqrt(3.0))  # µm: the misses at 63 nodes, left out one by one
    poly = np.sqrt(3.0 * 1.08**2 + 2.5 * np.where(np.arange(63) % 2, -1.0, 1.0))
    assert np.sqrt(np.mean(grid**2)) * 1.05 < np.sqrt(np.mean(poly**2))
    assert grid_clearly_better(grid, poly, 4)
    assert not grid_clearly_better(grid, poly, 1)


# -- a pitch table's line of points --------------------------------------------------------
def _screw_mm(x: np.ndarray) -> np.ndarray:
    """A screw's slow error over 400 mm (µm sizes, as mm): a bow and a 90 mm wave."""
    return (8.0 * np.sin(np.pi * x / 400.0) + 3.0 * np.sin(2 * np.pi * x / 90.0)) * 1e-3


def _miss_um(x: np.ndarray, values: np.ndarray, truth) -> float:
    """RMS (µm) of straight lines through the points against ``truth`` between them."""
    between = np.linspace(x[0] + 0.5, x[-1] - 0.5, 997)
    return float(np.sqrt(np.mean((np.interp(between, x, values) - truth(between)) ** 2)) * 1e3)


def test_table_of_noisy_means_is_smoothed_closer_to_the_screw() -> None:
    """45 points, each a mean with 0.5 µm of standard error: smoothed, the correction
    between them is nearer the screw than straight lines through the points (seeded
    draws, every one, by 10 % or more on average), moved by no more than the cap."""
    from gateway.calibration.fitting.fit import smoothed_table
    from gateway.compensation import PitchTable

    x = np.linspace(0, 400, 45)
    ratios = []
    for seed in range(6):
        rng = np.random.default_rng(seed)
        fwd = _screw_mm(x) + rng.normal(0, 0.5e-3, x.size)
        rev = _screw_mm(x) - 4e-3 + rng.normal(0, 0.5e-3, x.size)
        got = smoothed_table(PitchTable(x, fwd, rev), 0.5e-3, 1)
        for smooth, raw, offset in ((got.table.forward_mm, fwd, 0.0),
                                    (got.table.reverse_mm, rev, 4e-3)):  # fmt: skip
            ratios.append(_miss_um(x, smooth + offset, _screw_mm)
                          / _miss_um(x, raw + offset, _screw_mm))  # fmt: skip
        assert got.change_rms_mm <= 0.5e-3 and all(lam > 0 for lam in got.lambdas)
    assert max(ratios) < 1.0 and np.mean(ratios) < 0.9


def test_points_apart_by_more_than_their_scatter_are_kept() -> None:
    """A sparse table of a wavy screw (15 points on 400 mm, a 90 mm wave: 3.3 points a
    period) read to 0.1 µm: leave-one-out alone flattens the wave (each point left out is
    two steps from the next), the cap keeps the points where they were read; a line of
    three points is returned as it is."""
    from gateway.calibration.fitting.grid_smooth import smooth_line

    x = np.linspace(0, 400, 15)
    z = _screw_mm(x) + np.random.default_rng(1).normal(0, 0.1e-3, x.size)
    free = smooth_line(x, z, 1.0)  # no cap to speak of: leave-one-out's own choice
    capped = smooth_line(x, z, 0.1e-3)
    assert _miss_um(x, free.values, _screw_mm) > 1.5 * _miss_um(x, z, _screw_mm)
    assert capped.change_rms <= 0.1e-3
    assert _miss_um(x, capped.values, _screw_mm) < 1.1 * _miss_um(x, z, _screw_mm)
    few = smooth_line(x[:3], _screw_mm(x[:3]), 1e-3)
    assert np.array_equal(few.values, _screw_mm(x[:3])) and few.lam == 0.0
    with pytest.raises(ValueError, match="strictly increasing"):
        smooth_line(x[::-1], _screw_mm(x), 1e-3)
