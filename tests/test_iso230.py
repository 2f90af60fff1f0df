"""ISO 230-2 statistics on small synthetic data, checked against hand/independent sums."""

from __future__ import annotations

import statistics

import numpy as np
import pytest

from gateway.calibration.fitting.iso230 import JSON_KEYS, iso230_2, report_json
from gateway.calibration.plans.rawdata import RawWriter, read_raw_csv
from gateway.compensation.errors import TableError

T = np.array([10.0, 20.0, 30.0])
UP = np.array([[1.0, 2.0, 3.0], [0.0, 0.0, 0.0], [-4.0, -5.0, -6.0]]) * 1e-3
DOWN = np.array([[6.0, 6.0, 6.0], [2.0, 4.0, 6.0], [-1.0, -1.0, -1.0]]) * 1e-3


def test_hand_computed_figures() -> None:
    """Every figure from its definition, with statistics.stdev as the n−1 estimator."""
    res = iso230_2(T, UP, DOWN)
    mu = [statistics.mean(r) for r in UP * 1e3]
    md = [statistics.mean(r) for r in DOWN * 1e3]
    su = [statistics.stdev(r) for r in UP * 1e3]
    sd = [statistics.stdev(r) for r in DOWN * 1e3]
    b = [u - d for u, d in zip(mu, md)]
    r_i = [max(2 * a + 2 * c + abs(bb), 4 * a, 4 * c) for a, c, bb in zip(su, sd, b)]
    xbar = [(u + d) / 2 for u, d in zip(mu, md)]
    want = {
        "B_um": max(abs(x) for x in b),
        "Bmean_um": statistics.mean(b),
        "E_up_um": max(mu) - min(mu),
        "E_down_um": max(md) - min(md),
        "E_um": max(mu + md) - min(mu + md),
        "M_um": max(xbar) - min(xbar),
        "R_up_um": 4 * max(su),
        "R_down_um": 4 * max(sd),
        "R_um": max(r_i),
        "A_um": max([u + 2 * s for u, s in zip(mu, su)] + [d + 2 * s for d, s in zip(md, sd)])
        - min([u - 2 * s for u, s in zip(mu, su)] + [d - 2 * s for d, s in zip(md, sd)]),
    }
    got = res.to_json_dict()
    assert set(JSON_KEYS) <= set(got)
    for key, value in want.items():
        assert got[key] == pytest.approx(value, abs=1e-9), key
    assert res.B_i_um == pytest.approx(b)
    assert res.s_defined and res.runs == 3


def test_single_run_sets_s_zero_and_flags_it() -> None:
    res = iso230_2(T, UP[:, :1], DOWN[:, :1])
    assert not res.s_defined
    assert np.all(res.up.s_um == 0) and np.all(res.down.s_um == 0)
    assert res.R_um == pytest.approx(res.B_um)  # only |Bi| remains in Ri
    assert res.A_um == pytest.approx(res.E_um)
    assert res.to_json_dict()["s_defined"] is False


def test_unidirectional_only() -> None:
    res = iso230_2(T, UP, None)
    got = res.to_json_dict()
    for key in ("A_um", "B_um", "Bmean_um", "E_um", "M_um", "R_um", "E_down_um", "R_down_um"):
        assert got[key] is None, key
    assert got["E_up_um"] == pytest.approx(2.0 - (-5.0))
    assert got["A_up_um"] is not None and got["R_up_um"] == pytest.approx(4.0)
    down_only = iso230_2(T, None, DOWN).to_json_dict()
    assert down_only["E_up_um"] is None and down_only["E_down_um"] == pytest.approx(7.0)


def test_missing_measurements_are_left_out() -> None:
    up = UP.copy()
    up[0, 2] = np.nan
    res = iso230_2(T, up, DOWN)
    assert res.up.mean_um[0] == pytest.approx(1.5)
    assert list(res.up.n) == [2, 3, 3]
    up[1, :] = np.nan
    with pytest.raises(TableError, match="target 2 has no measurement"):
        iso230_2(T, up, DOWN)


def test_report_json_from_raw_file(tmp_path) -> None:
    """Raw CSV → {"X": {...}, "Y": {...}}; each axis's figures are the array version's."""
    path = tmp_path / "raw.csv"
    with RawWriter(path) as w:
        for axis, scale in (("X", 1.0), ("Y", 2.0)):
            for j in range(3):
                for i, t in enumerate(T):
                    w.append(axis, j + 1, "+", t, t + scale * UP[i, j])
                for i, t in reversed(list(enumerate(T))):
                    w.append(axis, j + 1, "-", t, t + scale * DOWN[i, j])
    out = report_json(read_raw_csv(path))
    assert list(out) == ["X", "Y"]
    ref = iso230_2(T, UP, DOWN).to_json_dict()
    for key in JSON_KEYS:
        assert out["X"][key] == pytest.approx(ref[key], abs=1e-9)
        assert out["Y"][key] == pytest.approx(2 * ref[key], abs=1e-9)
