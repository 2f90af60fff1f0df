"""Issue 7 through the commands on the example sim: a coarse ISO table (21 points) plus the
cyclic term from `compgw calibrate --cyclic`, fitted jointly by `compgw fit`, against the
same coarse table alone, at 100 random off-grid positions in both directions.

The sim and a gateway run in a background thread (tests/test_calibration_rig.py); every step
is the command a user types. Each off-grid position is visited 3 times (approached from the
same side) and the readings averaged, so the RMS measures the systematic error between the
table's points, not the sim's 0.3 µm repeatability per stop (as tests/test_cyclic_sim.py).
"""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from gateway.calibration.plans.plans import Move, Plan, read_plan, write_plan
from gateway.calibration.plans.rawdata import read_raw_csv
from gateway.formats import read_cyclic
from tests.test_calibration_rig import Bench, compgw, example_config, ok, without

LEAD_MM = 10.0
COARSE = ["--step-mm", "39.7", "--runs", "3", "--overrun-mm", "1"]  # 21 targets, 1..799 mm
#: (at 500 positions: coarse 1.33 µm, with the cyclic term 0.27; at 200, 1.28 and 0.26, half
#: the CPU: 21 s of the suite's 2 cores for 40; at 100, 1.24 and 0.27: 6.8 s of CPU for 9.7)
POSITIONS, VISITS = 100, 3
#: the example machine's X: 1.5 µm once per 10 mm lead at phase 30° (config/example-sim.yaml)
TRUE_AMPLITUDE_UM, TRUE_PHASE_DEG = 1.5, 30.0


def off_grid_plan(axis: str) -> Plan:
    """POSITIONS seeded random positions, alternately approached in + and −, each 3 times from
    1 mm before it (run = visit)."""
    rng = np.random.default_rng(7)
    positions = np.round(rng.uniform(5.0, 795.0, POSITIONS), 4)
    moves: list[Move] = []
    for i, p in enumerate(positions):
        d = 1 if i % 2 == 0 else -1
        for visit in range(1, VISITS + 1):
            moves.append(Move(visit, 0, "takeup", (float(p - d),)))
            moves.append(Move(visit, d, "measure", (float(p),)))
    return Plan("off-grid", (axis,), tuple(moves), (("kind", "off-grid"), ("axis", axis)))


def off_grid_rms_um(path: Path) -> float:
    raw = read_raw_csv(path)
    key = np.round(raw.target_mm, 6) * raw.direction
    _, index = np.unique(key, return_inverse=True)
    means = np.bincount(index, raw.deviation_mm) / np.bincount(index)
    assert np.all(np.bincount(index) == VISITS)
    return float(np.sqrt(np.mean(means**2)) * 1e3)


@pytest.fixture(scope="module")
def flow(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    d = tmp_path_factory.mktemp("cyclic")
    (d / "tables").mkdir()
    t0 = time.monotonic()
    out: dict[str, Any] = {"dir": d}
    with Bench(d) as b:
        base = without(example_config(b.sim_port), "planar")
        base["axes"]["Y"]["compensation"].pop("pitch")
        x = base["axes"]["X"]["compensation"]
        x["pitch"] = {"file": "tables/x_coarse.csv", "interpolation": "linear"}
        coarse = b.write_config("coarse.yaml", base)  # the coarse table alone
        x["pitch"] = {"file": "tables/x_pitch.csv", "interpolation": "linear"}
        x["cyclic"] = "tables/x_cyclic.yaml"
        gw = b.write_config("gw.yaml", base)  # the coarse table net of cyclic + cyclic
        ident = d / "ident.yaml"
        ok("calibrate", "-c", gw, "--identify-config", ident)
        laser = b.instrument(20)
        common = ["-c", gw, "--gateway", b.gateway, "--laser", laser, "--park", "Y=0"]

        # identification, thermal on, pitch and cyclic off: coarse ISO run + dense scans
        b.use(ident)
        b.cool_down()
        ok("calibrate", *common, "--iso", "X", *COARSE, "--raw", d / "X_id.csv")
        out["calibrate_cyclic"] = ok("calibrate", *common, "--cyclic", "X", "--lead-mm", LEAD_MM,
                                     "--save-plan", d / "X_cyclic.plan",
                                     "--raw", d / "X_cyclic.csv")  # fmt: skip

        # fits: the coarse table alone; the refusal; the joint fit (files in any order)
        ok("fit", d / "X_id.csv", "-c", coarse)
        out["refused"] = compgw("fit", d / "X_cyclic.csv", "-c", coarse)
        out["fit"] = json.loads(ok("fit", d / "X_id.csv", d / "X_cyclic.csv", "-c", gw, "--json"))
        out["fit_text"] = ok("fit", d / "X_id.csv", d / "X_cyclic.csv", "-c", gw, "--dry-run")

        # verification at the off-grid positions, coarse alone vs coarse + cyclic
        write_plan(d / "offgrid.plan", off_grid_plan("X"))
        for label, config in (("coarse", coarse), ("coarse+cyclic", gw)):
            b.use(config)
            b.cool_down()
            ok("calibrate", *common, "--plan", d / "offgrid.plan", "--compensation", "on",
               "--raw", d / f"offgrid_{label}.csv")  # fmt: skip
            out[label] = off_grid_rms_um(d / f"offgrid_{label}.csv")
    out["seconds"] = time.monotonic() - t0
    print(f"\ncyclic calibration on the example sim: {out['seconds']:.1f} s; off-grid RMS "
          f"coarse {out['coarse']:.3f} µm, coarse+cyclic {out['coarse+cyclic']:.3f} µm")
    print(out["fit_text"])
    return out


def test_coarse_plus_cyclic_halves_the_off_grid_rms(flow):
    assert flow["coarse+cyclic"] <= 0.5 * flow["coarse"], flow


def test_plan_is_dense_both_ways_at_three_stations(flow):
    plan = read_plan(flow["dir"] / "X_cyclic.plan")
    assert plan.kind == "cyclic"
    assert "min of machine time" in flow["calibrate_cyclic"]
    raw = read_raw_csv(flow["dir"] / "X_cyclic.csv")
    assert len(raw) == sum(m.measured for m in plan.moves) == 3 * 2 * 33


def test_fit_writes_the_cyclic_file_with_uncertainties_and_nets_the_table(flow):
    d, fit = flow["dir"], flow["fit"]["X"]
    assert fit["net_of_cyclic"] is True
    cyc = fit["cyclic"]
    assert cyc["harmonics"] >= 1 and cyc["file"].endswith("x_cyclic.yaml")
    first = [h for h in cyc["stations"] if h["k"] == 1]
    assert len(first) == 3
    for h in first:
        # the truth within 4 standard uncertainties (at least 0.3 µm, 10°: the thermal
        # sensors' polling adds a little run-to-run noise)
        tol_um, tol_deg = max(0.3, 4 * h["amplitude_sd_um"]), max(10.0, 4 * h["phase_sd_deg"])
        assert h["amplitude_um"] == pytest.approx(TRUE_AMPLITUDE_UM, abs=tol_um), h
        assert h["phase_deg"] == pytest.approx(TRUE_PHASE_DEG, abs=tol_deg), h
        assert 0 < h["amplitude_sd_um"] < 0.2
    model = read_cyclic(d / "tables" / "x_cyclic.yaml")
    assert model.lead_mm == LEAD_MM and model.station_mm.tolist() == [120.0, 400.0, 680.0]
    text = (d / "tables" / "x_cyclic.yaml").read_text()
    assert "sin_sd_um" in text and "cv_rms_um" in text
    assert "net of the cyclic term" in (d / "tables" / "x_pitch.csv").read_text()
    assert "± " in flow["fit_text"] and "net of the cyclic term" in flow["fit_text"]


def test_fit_refuses_without_a_cyclic_path(flow):
    rc, out, err = flow["refused"]
    assert rc == 1 and out == ""
    assert err.count("\n") == 1 and "axes.X.compensation.cyclic is not set" in err


def test_report_shows_amplitudes_with_uncertainty_and_the_scan_plot(flow, tmp_path):
    d = flow["dir"]
    rc, out, _ = compgw("report", d / "X_cyclic.csv", "--json")
    assert rc == 0
    data = json.loads(out)["X"]["cyclic"]
    assert data["harmonics"] == flow["fit"]["X"]["cyclic"]["harmonics"]
    h = data["stations"][0]
    assert {"amplitude_um", "amplitude_sd_um", "phase_deg", "phase_sd_deg"} <= set(h)
    ok("report", d / "X_cyclic.csv", "--out", tmp_path / "r")
    text = (tmp_path / "r" / "report.html").read_text()
    assert "cyclic-X" in text and text.count("data:image/png;base64,") == 1
    assert "±" in text and "phase" in text
    assert (tmp_path / "r" / "cyclic-X.png").stat().st_size > 1000
