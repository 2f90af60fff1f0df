"""A budget that holds every axis's ISO runs only with fewer runs per target: each axis gets a
table from 2 runs, said so, rather than the first axis one from 3 and the last none (at
0.12 h the small machine's X got its table and Y none)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import yaml

from gateway.calibration.plans.plans import read_plan
from tests.commission_rig import running, small_machine


def test_a_tiny_budget_reads_every_axis_with_fewer_runs(tmp_path: Path) -> None:
    small_machine(tmp_path / "t", seed=7)
    with running(tmp_path / "t", tmp_path / "m") as rig:
        proc = rig.commission("--budget-h", "0.14")
        assert proc.popen.wait(timeout=300) == 1, proc.text()
        out = rig.dir / "commission"
        summary = json.loads((out / "summary.json").read_text())
        state = json.loads((out / "commission.json").read_text())
        assert summary["outcome"] == "budget" and summary["machine_h"] <= 0.14
        assert state["iso_runs"] == 2
        note = "X, Y: 2 ISO runs per target instead of 3"
        assert any(n.startswith(note) for n in summary["notes"]) and note in proc.text()
        final = yaml.safe_load(rig.config.read_text())["axes"]
        for a in ("X", "Y"):
            plan = read_plan(out / "plans" / f"iso-{a}.plan")
            assert len({m.run for m in plan.moves}) == 2, a
            assert "pitch" in final[a]["compensation"], final[a]
            # smoothed within the standard error of a 2-run mean, not a 3-run one
            smoothed = state["identify"][f"smoothed-{a}"]
            cap_um = state["identify"][f"reversal-{a}"]["scatter_um"] / np.sqrt(2)
            assert smoothed["change_rms_um"] <= cap_um + 1e-9, (smoothed, cap_um)
