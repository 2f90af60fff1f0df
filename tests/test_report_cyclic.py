"""`compgw report` of cyclic runs: amplitudes and phases with uncertainty, the scan plot."""

from __future__ import annotations

import json

import pytest

from gateway.calibration.fitting.plans_scans import cyclic_plan
from gateway.cli import main
from tests.test_cyclic_cal_offline import AMP_UM, LEAD, PHASE_DEG, run


@pytest.fixture(scope="module")
def raws(tmp_path_factory):
    d = tmp_path_factory.mktemp("cyclic_report")
    run(cyclic_plan("X", (0, 800), LEAD), d / "cyc.csv")
    run(cyclic_plan("X", (0, 800), LEAD), d / "flat.csv", cyclic=False, seed=1)
    return d


def test_json_gives_amplitude_and_phase_with_uncertainty(raws, capsys):
    assert main(["report", str(raws / "cyc.csv"), "--json"]) == 0
    data = json.loads(capsys.readouterr().out)["X"]["cyclic"]
    assert data["harmonics"] == 1 and data["readings"] == 198
    assert [h["station_mm"] for h in data["stations"]] == [120, 400, 680]
    for h in data["stations"]:
        assert h["amplitude_um"] == pytest.approx(AMP_UM, abs=4 * h["amplitude_sd_um"])
        assert h["phase_deg"] == pytest.approx(PHASE_DEG, abs=4 * h["phase_sd_deg"])
    assert not (raws / "report").exists()  # --json alone writes nothing
    assert main(["report", str(raws / "cyc.csv"), "--json", "--harmonics", "3"]) == 0
    assert len(json.loads(capsys.readouterr().out)["X"]["cyclic"]["stations"]) == 9


def test_html_has_the_table_and_the_plot(raws, tmp_path, capsys):
    assert main(["report", str(raws / "cyc.csv"), "--out", str(tmp_path / "r")]) == 0
    text = (tmp_path / "r" / "report.html").read_text()
    assert "id='cyclic-X-harmonics'" in text and " ± " in text and "phase °" in text
    assert text.count("data:image/png;base64,") == 1 and "id='cyclic-X'" in text
    assert (tmp_path / "r" / "cyclic-X.png").read_bytes()[:4] == b"\x89PNG"


def test_no_cyclic_error_says_so(raws, tmp_path, capsys):
    assert main(["report", str(raws / "flat.csv"), "--out", str(tmp_path / "f")]) == 0
    text = (tmp_path / "f" / "report.html").read_text()
    assert "No cyclic error found" in text and text.count("data:image/png;base64,") == 1


def test_before_is_refused_for_cyclic_runs(raws, capsys):
    rc = main(["report", str(raws / "cyc.csv"), "--before", str(raws / "flat.csv")])
    assert rc == 1 and "cyclic run is reported on its own" in capsys.readouterr().err
