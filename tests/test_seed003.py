"""Seed 003 on the sim (issue 16): `compgw demo --seed003` as a user runs it. One
identification run of the swing head; the seed's method and compgw's choice fitted from the
same readings; all judged at the same random targets, none of them measured before."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np

from gateway.demos.seed003 import RANGE_DEG, STEP_DEG, judge_targets

ROOT = Path(__file__).resolve().parent.parent


def test_judged_targets_are_not_the_measured_ones():
    targets = np.array(judge_targets())
    grid = np.arange(RANGE_DEG[0], RANGE_DEG[1] + 1e-9, STEP_DEG)
    assert np.min(np.abs(targets[:, None] - grid[None, :])) >= 0.03
    assert targets.min() < -13.0 and targets.max() > 12.0  # the whole range, ends included


def test_seed003_demo_reproduces_the_seed_and_beats_it_sevenfold(tmp_path: Path):
    result = subprocess.run(
        [sys.executable, "-m", "gateway.cli", "demo", "--seed003", "--json",
         "--save", str(tmp_path)],
        capture_output=True, text=True, timeout=120, cwd=ROOT,
    )  # fmt: skip
    assert result.returncode == 0, result.stderr
    data = json.loads(result.stdout)
    m = data["methods"]
    # the sim's linkage has the seed's size: 5.9e-4 deg left by straight lines at 1 deg
    assert abs(data["sim_linkage"]["straight_lines_deg"] - 5.9e-4) < 0.2e-4
    assert m["uncompensated"]["max_deg"] > 0.05
    # the seed's method lands near the seed's result (0.0015 deg after compensation)
    assert 0.0005 < m["seed003"]["max_deg"] < 0.003
    # compgw's choice: within 0.0002 deg over the whole range, both directions, >= 7x better
    # than the seed's 0.0015 deg; the linkage model is what cross-validation picks
    for key in ("max_deg", "max_up_deg", "max_down_deg"):
        assert m["compgw"][key] <= 0.0002, m["compgw"]
    assert 0.0015 / m["compgw"]["max_deg"] >= 7
    assert data["compgw_choice"]["kind"] == "linkage"
    assert data["measured"]["targets"] == 109 and data["judged"]["targets"] == 40
    # what a user gets to keep: the raw files, the tables and the fitted linkage
    for name in ("identify.csv", "a_seed.csv", "a_linkage.csv", "a_linkage.yaml",
                 "judge_compgw.csv"):
        assert (tmp_path / name).is_file(), name
