"""`compgw fit` of cyclic raw files on a numpy machine (numbers known in advance): the file
written with uncertainties, nothing added without cyclic error, the joint fit with the ISO
table of the same call, folding, refusals."""

from __future__ import annotations

import asyncio
import json
from pathlib import Path

import numpy as np
import pytest
import yaml

from gateway.calibration.fitting.cyclic_fit import Harmonic
from gateway.calibration.fitting.plans_scans import cyclic_plan
from gateway.calibration.plans.plans import iso230_linear_plan
from gateway.calibration.plans.runner import run_plan
from gateway.cli import main
from gateway.compensation.cyclic import CyclicModel
from gateway.formats import read_cyclic, read_pitch_csv, write_cyclic

LEAD = 10.0
AMP_UM, PHASE_DEG = 1.5, 30.0
CONFIG = {
    "upstream": {"tcp": {"port": 0}},
    "buses": {"line1": {"tcp": {"host": "127.0.0.1", "port": 1}}},
    "axes": {
        "X": {"bus": "line1", "unit": 1, "pulse_mm": 0.001, "travel_mm": [0, 800],
              "registers": {"target": {"address": 0x6201}, "feedback": {"address": 0x602A}},
              "compensation": {"pitch": "x_pitch.csv", "cyclic": "x_cyclic.yaml"}},
    },
}  # fmt: skip


def true_error_mm(x, cyclic=True):
    x = np.asarray(x, dtype=np.float64)
    e = 35e-6 * x + 0.01 * np.sin(x / 150.0)
    if cyclic:
        e = e + AMP_UM * 1e-3 * np.sin(2 * np.pi * x / LEAD + np.radians(PHASE_DEG))
    return e


def run(plan, path, cyclic=True, seed=0, meta=None):
    rng = np.random.default_rng(seed)

    async def move(_):
        return None

    async def measure(m):
        t = m.target_mm[0]
        lost = 0.006 * m.direction  # 12 µm backlash
        return {"X": float(t + true_error_mm(t, cyclic) - lost + rng.normal(0, 0.3e-3))}

    asyncio.run(run_plan(plan, path, move, measure, meta=meta or {"compensation": "off"}))


def config(tmp_path: Path, **comp) -> Path:
    data = json.loads(json.dumps(CONFIG))
    data["axes"]["X"]["compensation"].update(comp)
    data["axes"]["X"]["compensation"] = {
        k: v for k, v in data["axes"]["X"]["compensation"].items() if v is not None
    }
    path = tmp_path / f"gw{len(list(tmp_path.glob('gw*.yaml')))}.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def fit(*args, capsys=None):
    rc = main(["fit", *(str(a) for a in args)])
    out, err = capsys.readouterr() if capsys else ("", "")
    return rc, out, err


@pytest.fixture
def raws(tmp_path):
    run(cyclic_plan("X", (0, 800), LEAD), tmp_path / "cyc.csv")
    run(iso230_linear_plan("X", (0, 800), step_mm=39.7, runs=3, overrun_mm=1),
        tmp_path / "iso.csv")  # fmt: skip
    run(cyclic_plan("X", (0, 800), LEAD), tmp_path / "flat.csv", cyclic=False, seed=1)
    return tmp_path


def test_fit_writes_the_cyclic_file_with_uncertainties(raws, capsys):
    gw = config(raws)
    rc, out, err = fit(raws / "cyc.csv", "-c", gw, "--json", capsys=capsys)
    assert rc == 0, err
    entry = json.loads(out)["X"]["cyclic"]
    assert entry["harmonics"] == 1 and entry["cv_rms_um"]["1"] < entry["cv_rms_um"]["0"]
    assert "note" in entry  # the pitch table was not re-fitted with it
    for h in entry["stations"]:
        assert h["amplitude_um"] == pytest.approx(AMP_UM, abs=4 * h["amplitude_sd_um"])
        assert h["phase_deg"] == pytest.approx(PHASE_DEG, abs=4 * h["phase_sd_deg"])
        assert 0.02 < h["amplitude_sd_um"] < 0.15
    model = read_cyclic(raws / "x_cyclic.yaml")
    assert model.lead_mm == LEAD and model.station_mm.tolist() == [120, 400, 680]
    doc = yaml.safe_load((raws / "x_cyclic.yaml").read_text())
    assert len(doc["stations"][0]["sin_sd_um"]) == 1 and doc["harmonics"] == 1
    assert not (raws / "x_pitch.csv").exists()  # only the cyclic file was fitted
    rc, out, _ = fit(raws / "cyc.csv", "-c", gw, "--harmonics", "2", capsys=capsys)
    assert rc == 0 and "2 harmonic(s)" in out and "k=2" in out
    assert read_cyclic(raws / "x_cyclic.yaml").harmonics == 2


def test_no_cyclic_error_adds_nothing(raws, capsys):
    rc, out, _ = fit(raws / "flat.csv", "-c", config(raws), capsys=capsys)
    assert rc == 0 and "no cyclic error found: the file adds nothing" in out
    model = read_cyclic(raws / "x_cyclic.yaml")
    assert model.peak_mm() == 0.0


def test_joint_fit_nets_the_table_of_the_same_call_in_any_order(raws, capsys):
    alone = config(raws, pitch="alone.csv", cyclic=None)
    assert fit(raws / "iso.csv", "-c", alone, capsys=capsys)[0] == 0
    gw = config(raws)
    for order in ((raws / "iso.csv", raws / "cyc.csv"), (raws / "cyc.csv", raws / "iso.csv")):
        rc, out, _ = fit(*order, "-c", gw, capsys=capsys)
        assert rc == 0 and "net of the cyclic term" in out
        table, base = read_pitch_csv(raws / "x_pitch.csv"), read_pitch_csv(raws / "alone.csv")
        cyc = read_cyclic(raws / "x_cyclic.yaml").error_mm(base.position_mm)
        np.testing.assert_allclose(table.forward_mm, base.forward_mm - cyc, atol=2e-7)
        np.testing.assert_allclose(table.reverse_mm, base.reverse_mm - cyc, atol=2e-7)


def test_residual_scans_fold_into_the_current_file(raws, capsys):
    gw = config(raws)
    half = CyclicModel(LEAD, np.array([100.0, 700.0]), np.full((2, 1), 0.6e-3),
                       np.full((2, 1), 0.35e-3))  # about half the truth, in phase
    write_cyclic(raws / "x_cyclic.yaml", half)
    meta = {"compensation": "on"}
    run(cyclic_plan("X", (0, 800), LEAD), raws / "on.csv", meta=meta)  # the machine as is:
    # the residual is then the whole truth, and the folded file current + truth
    rc, out, _ = fit(raws / "on.csv", "-c", gw, "--json", capsys=capsys)
    assert rc == 0
    assert json.loads(out)["X"]["cyclic"]["folded"] is True
    model = read_cyclic(raws / "x_cyclic.yaml")
    a, b = model.sin_mm[:, 0] * 1e3, model.cos_mm[:, 0] * 1e3
    np.testing.assert_allclose(a, 0.6 + AMP_UM * np.cos(np.radians(30)), atol=0.3)
    np.testing.assert_allclose(b, 0.35 + AMP_UM * np.sin(np.radians(30)), atol=0.3)


def test_refusals_are_one_line(raws, capsys):
    rc, out, err = fit(raws / "cyc.csv", "-c", config(raws, cyclic=None), capsys=capsys)
    assert rc == 1 and out == "" and err.count("\n") == 1
    assert "axes.X.compensation.cyclic is not set" in err
    text = (raws / "cyc.csv").read_text().replace("# lead_mm: 10\n", "")
    (raws / "nolead.csv").write_text(text)
    rc, _, err = fit(raws / "nolead.csv", "-c", config(raws), capsys=capsys)
    assert rc == 1 and "lead_mm" in err and err.count("\n") == 1


def test_dry_run_writes_nothing(raws, capsys):
    rc, out, _ = fit(raws / "cyc.csv", raws / "iso.csv", "-c", config(raws), "--dry-run",
                     capsys=capsys)  # fmt: skip
    assert rc == 0 and "would write" in out
    assert not (raws / "x_cyclic.yaml").exists() and not (raws / "x_pitch.csv").exists()


def test_amplitude_and_phase_uncertainty_propagation():
    h = Harmonic(0.0, 1, 1.3, 0.75, 0.1, 0.1)
    assert h.amplitude_um == pytest.approx(np.hypot(1.3, 0.75))
    assert h.phase_deg == pytest.approx(np.degrees(np.arctan2(0.75, 1.3)))
    assert h.amplitude_sd_um == pytest.approx(0.1)  # equal u(a) = u(b): u(A) = u
    assert h.phase_sd_deg == pytest.approx(np.degrees(0.1 / h.amplitude_um))
    # against a Monte Carlo propagation with unequal uncertainties
    h = Harmonic(0.0, 1, 1.0, 0.5, 0.05, 0.12)
    rng = np.random.default_rng(0)
    a, b = rng.normal(1.0, 0.05, 200_000), rng.normal(0.5, 0.12, 200_000)
    assert h.amplitude_sd_um == pytest.approx(np.hypot(a, b).std(), rel=0.03)
    assert h.phase_sd_deg == pytest.approx(np.degrees(np.arctan2(b, a)).std(), rel=0.05)


def test_scans_found_without_the_stations_line(raws, capsys):
    """A raw file without `# stations_mm:` (e.g. a hand-made plan): scans are split where
    the targets jump by more than a lead, each station at its scan's centre."""
    text = (raws / "cyc.csv").read_text().replace("# stations_mm: 120 400 680\n", "")
    (raws / "nostations.csv").write_text(text)
    rc, out, _ = fit(raws / "nostations.csv", "-c", config(raws), "--json", capsys=capsys)
    assert rc == 0
    entry = json.loads(out)["X"]["cyclic"]
    assert [h["station_mm"] for h in entry["stations"]] == [120, 400, 680]
