"""Whether a table misses between its points more than its scatter explains
(``table_cv.between_points_ratio``): what decides, on a short budget, that the ISO runs are
read at the first table's midpoints too."""

from __future__ import annotations

import numpy as np

from gateway.calibration.fitting.table_cv import between_points_ratio
from gateway.calibration.plans.rawdata import AxisDeviations


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
