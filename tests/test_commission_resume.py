"""`compgw commission` interrupted (sim, gateway and the command as real processes, time_scale
0): SIGKILL mid-run and mid-sweep (a power loss) carries on where it stopped, Ctrl-C leaves
the gateway on your own config. (Beside tests/test_commission.py, split so that the two
halves run on different workers.)"""

from __future__ import annotations

import json
import signal
import time
from pathlib import Path

import pytest

from gateway.calibration.plans import read_plan
from gateway.calibration.rawdata import read_raw_csv
from tests.commission_rig import running, small_machine, wait_for_steps


@pytest.fixture(scope="module")
def template(tmp_path_factory: pytest.TempPathFactory) -> Path:
    directory = tmp_path_factory.mktemp("machine") / "m"
    small_machine(directory, seed=7)
    return directory


def test_commission_resumes_after_a_kill(template: Path, tmp_path: Path) -> None:
    """SIGKILL in the middle (a power loss): the same command carries on; every reading
    taken before the kill is kept, none is taken twice."""
    with running(template, tmp_path / "m") as rig:
        state = rig.dir / "commission" / "commission.json"
        # (a tolerance the first verification meets: no rounds after the resumed steps)
        first = rig.commission("--tolerance-um", "5")
        wait_for_steps(state, 4, first)
        first.kill()
        done_before = set(json.loads(state.read_text())["steps"])
        second = rig.commission("--tolerance-um", "5")
        assert second.popen.wait(timeout=300) in (0, 1), second.text()
        text = second.text()
        assert not any(f"{name}:" in line for name in done_before for line in second.lines
                       if "readings" in line), text  # fmt: skip
        out = rig.dir / "commission"
        for name, step in json.loads(state.read_text())["steps"].items():
            plan = read_plan(out / "plans" / f"{name}.plan")
            files = [rig.dir / part["raw"] for part in step["parts"]]  # one per run
            rows = sum(len(read_raw_csv(f)) for f in files)
            assert rows == sum(m.measured for m in plan.moves) * len(plan.axes), name
        assert json.loads((out / "summary.json").read_text())["axes"]["X"]["after"]


def test_a_sweep_killed_half_way_carries_on(template: Path, tmp_path: Path) -> None:
    """SIGKILL while X's sweep is measuring (a power loss): the same command carries on
    from the last reading (none taken twice) and folds the sweep once, from the table as
    it was before it."""
    with running(template, tmp_path / "m") as rig:
        state = rig.dir / "commission" / "commission.json"
        raw = rig.dir / "commission" / "raw" / "sweep1-X.csv"
        first = rig.commission("--tolerance-um", "1", "--budget-h", "1.7")
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline:
            if raw.exists() and raw.read_text().count("\n") > 40:
                break
            assert first.popen.poll() is None, first.text()
            time.sleep(0.005)
        first.kill()
        before = json.loads(state.read_text())
        assert before["sweeping"] == {"X": 0} and "sweep1-X" not in before["steps"]
        taken = len(read_raw_csv(raw))
        second = rig.commission("--tolerance-um", "1", "--budget-h", "1.7")
        assert second.popen.wait(timeout=300) in (0, 1), second.text()
        out = rig.dir / "commission"
        after = json.loads(state.read_text())
        plan = read_plan(out / "plans" / "sweep1-X.plan")
        parts = after["steps"]["sweep1-X"]["parts"]
        rows = sum(len(read_raw_csv(rig.dir / part["raw"])) for part in parts)
        assert rows > taken
        assert rows == sum(m.measured for m in plan.moves)
        assert "X" in after["swept"] and not after["sweeping"]
        assert after["identify"]["sweep-X"]["readings"] == rows
        # folded from the files kept before the sweep, which the fold never touched
        kept = out / "tables" / "sweep1-X" / "x_pitch.csv"
        assert kept.exists() and "swept" not in kept.read_text()


def test_an_abort_leaves_the_gateway_on_your_config(template: Path, tmp_path: Path) -> None:
    """Ctrl-C mid-run: exit 3, your config back in the file and loaded by the gateway (its
    config generation moved on), the message says so; running again resumes."""
    with running(template, tmp_path / "m") as rig:
        original = rig.config.read_text()
        state = rig.dir / "commission" / "commission.json"
        proc = rig.commission()
        wait_for_steps(state, 2, proc)
        proc.signal(signal.SIGINT)
        assert proc.popen.wait(timeout=60) == 3, proc.text()
        assert "the gateway runs your own config again" in proc.text()
        assert rig.config.read_text() == original
        reloads = [ln for ln in rig.gw.lines if "reloaded" in ln]
        assert len(reloads) >= 2  # identification, then yours again
        assert json.loads(state.read_text())["phase"] == "original"
