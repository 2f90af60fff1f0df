"""Commissioning and calibration with the instruments a technician owns, end to end with
real processes: the sim's laser on the bridge protocol (as a vendor SDK wrapped in a short
script would answer), and a gauge typed at the prompt (scripted through stdin)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

from gateway.calibration.plans.plans import Move, Plan, write_plan
from gateway.calibration.plans.rawdata import read_raw_csv
from tests.commission_rig import running, small_machine

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def template(tmp_path_factory: pytest.TempPathFactory) -> Path:
    directory = tmp_path_factory.mktemp("machine") / "m"
    small_machine(directory, seed=7)
    sim = yaml.safe_load((directory / "sim.yaml").read_text())
    sim["sim"]["instruments"]["laser"]["bridge"] = {"host": "127.0.0.1", "port": 0}
    (directory / "sim.yaml").write_text(yaml.safe_dump(sim, sort_keys=False))
    return directory


def test_commission_through_a_bridge(template: Path, tmp_path: Path) -> None:
    with running(template, tmp_path / "m") as rig:
        port = int(rig.sim.wait_line(r"laser bridge on 127\.0\.0\.1:(\d+)").group(1))
        args = [a if not a.startswith(f"127.0.0.1:{rig.sim_port}:20") else
                f"bridge:tcp:127.0.0.1:{port}" for a in rig.commission_args(
                    "--tolerance-um", "2", "--budget-h", "0.8")]  # fmt: skip
        assert f"bridge:tcp:127.0.0.1:{port}" in args
        proc = subprocess.run([sys.executable, *args], cwd=ROOT, capture_output=True,
                              text=True, timeout=300)  # fmt: skip
        assert proc.returncode in (0, 1), proc.stdout + proc.stderr
        summary = json.loads((rig.dir / "commission" / "summary.json").read_text())
        for axis, entry in summary["axes"].items():
            before, after = entry["before"]["E_um"], entry["after"]["E_um"]
            assert after < 0.5 * before, (axis, before, after, proc.stdout)


def test_a_bridge_that_does_not_answer_is_named_before_anything_moves(
        template: Path, tmp_path: Path) -> None:  # fmt: skip
    with running(template, tmp_path / "m") as rig:
        args = [a if not a.startswith(f"127.0.0.1:{rig.sim_port}:20") else
                "bridge:cmd:" + f"{sys.executable} -c 'import time; time.sleep(30)'"
                for a in rig.commission_args()]  # fmt: skip
        proc = subprocess.run([sys.executable, *args], cwd=ROOT, capture_output=True,
                              text=True, timeout=120)  # fmt: skip
        assert proc.returncode == 1, proc.stdout + proc.stderr
        assert "--laser bridge:cmd:" in proc.stderr and "HELLO 1: no answer within 5 s" \
            in proc.stderr, proc.stderr  # fmt: skip
        assert not (rig.dir / "commission").exists()


def test_calibrate_with_a_gauge_typed_at_the_prompt(template: Path, tmp_path: Path) -> None:
    """Four targets on X read from a dial gauge: deviations typed, one typo, one read
    again; the raw file holds the targets plus the deviations."""
    with running(template, tmp_path / "m") as rig:
        plan = tmp_path / "x.plan"
        write_plan(plan, Plan("gauge", ("X",), tuple(Move(1, +1, "measure", (x,))
                                                     for x in (10.0, 30.0, 50.0, 70.0))))
        typed = "3.1\n\n-2,5\n\nnot\n1.0\nr\n1.5\n\n0\n\n"
        proc = subprocess.run([sys.executable, "-m", "gateway.cli", "calibrate", "-c",
                               str(rig.config), "--gateway", f"127.0.0.1:{rig.gw_port}",
                               "--plan", str(plan), "--no-progress",
                               "--laser", "manual:deviation", "--raw",
                               str(tmp_path / "gauge.csv")],
                              cwd=ROOT, input=typed, capture_output=True, text=True,
                              timeout=120)  # fmt: skip
        assert proc.returncode == 0, proc.stdout + proc.stderr
        assert "'not' is not a number" in proc.stdout
        raw = read_raw_csv(tmp_path / "gauge.csv")
        assert np.allclose(raw.target_mm, [10.0, 30.0, 50.0, 70.0])
        assert np.allclose(raw.deviation_mm * 1000, [3.1, -2.5, 1.5, 0.0], atol=1e-6), raw
