"""A small random machine for the commissioning tests: `compgw sim --random-machine`, its
travel cut to a few centimetres so a whole commissioning takes seconds at time_scale 0, the
sim and `compgw run` as real processes, and `compgw commission` as a real process too.
(No tests here.)"""

from __future__ import annotations

import atexit
import contextlib
import json
import shutil
import tempfile
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

from tests.test_service_helpers import Proc

#: the verdict's plane points in the tests but the end-to-end one (the default is 40): the
#: plane's verdict is read before and after, each point twice; at 40 the suite ran 15-20 s
#: longer on 2 cores
PLANE_POINTS = 16
TRAVEL_MM = (0.0, 90.0)


#: what `compgw sim --random-machine SEED --roughness R` wrote, by (SEED, R): each machine
#: drawn by the command once in a worker and copied after (a process each, 0.6 s of CPU;
#: a dozen tests commission machine 7)
_DRAWN: dict[tuple[int, str], Path] = {}


def random_machine(directory: Path, seed: int = 7, roughness: str = "smooth") -> None:
    """``compgw sim --random-machine SEED --roughness ROUGHNESS --out DIRECTORY``: the files
    it writes (drawn by that command, a real process, the first time in this process)."""
    drawn = _DRAWN.get((seed, roughness))
    if drawn is None:
        if not _DRAWN:
            keep = Path(tempfile.mkdtemp(prefix="compgw-machines-"))
            atexit.register(shutil.rmtree, keep, ignore_errors=True)
        else:
            keep = next(iter(_DRAWN.values())).parent
        drawn = keep / f"{seed}-{roughness}"
        proc = Proc(["-m", "gateway.cli", "sim", "--random-machine", str(seed), "--roughness",
                     roughness, "--out", str(drawn)])  # fmt: skip
        assert proc.popen.wait(timeout=60) == 0, proc.text()
        _DRAWN[(seed, roughness)] = drawn
    shutil.copytree(drawn, directory)


def small_machine(directory: Path, seed: int = 7, roughness: str = "smooth") -> dict[str, Any]:
    """Write a random machine into ``directory`` with both axes' travel cut to TRAVEL_MM
    (the truth files cover more: a part of them is used); machine.json returned."""
    random_machine(directory, seed, roughness)
    sim = yaml.safe_load((directory / "sim.yaml").read_text())
    sim["sim"]["tcp"]["port"] = 0
    for axis in sim["sim"]["axes"].values():
        axis["travel_mm"] = list(TRAVEL_MM)
    (directory / "sim.yaml").write_text(yaml.safe_dump(sim, sort_keys=False))
    gw = yaml.safe_load((directory / "gateway.yaml").read_text())
    for axis in gw["axes"].values():
        axis["travel_mm"] = list(TRAVEL_MM)
        axis["compensation"].pop("thermal", None)
    gw["upstream"]["tcp"]["port"] = 0
    gw["status"]["remote_control"] = True
    # the tests give no --delta-a (an axis without a sensor): not polled 100 times a second
    # (the gateway's and the sim's 7 % of a CPU while each test commissions)
    gw.pop("thermal_sources", None)
    (directory / "gateway.yaml").write_text(yaml.safe_dump(gw, sort_keys=False))
    return json.loads((directory / "machine.json").read_text())


def recording_machine(directory: Path, fmt: str, rate_hz: float) -> None:
    """:func:`small_machine` (seed 7) whose laser records X in the laser software's own
    files (``fmt``: csv or rtx, at ``rate_hz``, wall time at rest as machine time), with a
    Δa sensor on X at unit 22."""
    small_machine(directory, seed=7)
    sim = yaml.safe_load((directory / "sim.yaml").read_text())
    sim["sim"]["instruments"]["laser"]["recording"] = {
        "dir": "recordings", "format": fmt, "axis": "X", "rate_hz": rate_hz, "unit": "um",
        "idle_time_scale": 1.0}  # fmt: skip
    sim["sim"]["instruments"]["delta_a"] = {"unit": 22, "axis": "X", "a_mm": 0.0}
    (directory / "sim.yaml").write_text(yaml.safe_dump(sim, sort_keys=False))


@dataclass
class Rig:
    dir: Path
    machine: dict[str, Any]
    sim: Proc
    sim_port: int
    gw: Proc
    gw_port: int
    config: Path  # the file the gateway runs (commissioning writes over it)

    def commission_args(self, *extra: str, heat_warmup: bool = False,
                        plane_points: int | None = PLANE_POINTS) -> list[str]:  # fmt: skip
        """``compgw commission`` on this rig; without the no-sensor axes' zone warm-up
        unless ``heat_warmup``, and its verdict's plane at ``plane_points`` (None: the
        default, 40) (the end-to-end test has both; the others test other things, and the
        suite's time is counted)."""
        leads = ",".join(f"{a}={v['lead_mm']:g}" for a, v in self.machine["axes"].items())
        points = () if plane_points is None else ("--plane-points", str(plane_points))
        return ["-m", "gateway.cli", "commission", "-c", str(self.config),
                "--gateway", f"127.0.0.1:{self.gw_port}",
                "--laser", f"127.0.0.1:{self.sim_port}:20",
                "--xy-device", f"127.0.0.1:{self.sim_port}:21",
                "--lead-mm", leads, "--no-progress", *points,
                *(() if heat_warmup else ("--no-heat-warmup",)), *extra]  # fmt: skip

    def commission(self, *extra: str, heat_warmup: bool = False,
                   plane_points: int | None = PLANE_POINTS) -> Proc:  # fmt: skip
        return Proc(self.commission_args(*extra, heat_warmup=heat_warmup,
                                         plane_points=plane_points))  # fmt: skip


@contextlib.contextmanager
def running(template: Path, directory: Path, machine_clock: bool = False) -> Iterator[Rig]:
    """The machine in ``template`` copied to ``directory``, its sim and gateway running;
    the gateway on the computer's clock unless ``machine_clock`` (one request more per move;
    most tests time no heat; tests/test_machine_clock.py runs a session on it)."""
    shutil.copytree(template, directory)
    machine = json.loads((directory / "machine.json").read_text())
    sim = Proc(["-m", "gateway.cli", "sim", "-c", str(directory / "sim.yaml")])
    gw = None
    try:
        sim_port = int(sim.wait_line(r"modbus tcp on 127\.0\.0\.1:(\d+)").group(1))
        data = yaml.safe_load((directory / "gateway.yaml").read_text())
        data["buses"]["line1"]["tcp"]["port"] = sim_port
        if not machine_clock:
            data.pop("machine_clock", None)
        config = directory / "gw.yaml"
        config.write_text(yaml.safe_dump(data, sort_keys=False))
        gw = Proc(["-m", "gateway.cli", "run", "-c", str(config)])
        gw_port = int(gw.wait_line(r"listening on 127\.0\.0\.1:(\d+)").group(1))
        yield Rig(directory, machine, sim, sim_port, gw, gw_port, config)
    finally:
        if gw is not None:
            gw.stop()
        sim.stop()


def commissioned(rig: Rig, *args: str) -> tuple[Proc, dict[str, Any], dict[str, Any]]:
    """``compgw commission ARGS`` run to exit 0: the process, its summary and its state."""
    proc = rig.commission(*args)
    assert proc.popen.wait(timeout=300) == 0, proc.text()
    out = rig.dir / "commission"
    return (proc, json.loads((out / "summary.json").read_text()),
            json.loads((out / "commission.json").read_text()))
