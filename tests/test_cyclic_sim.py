"""Issue 7 on the simulated machine: a coarse table plus the cyclic stage fitted from three
short dense scans, against the same coarse table alone, at 100 random off-grid positions."""

from __future__ import annotations

import asyncio
from pathlib import Path

import numpy as np
import yaml

from gateway.calibration.fitting.cyclic_fit import (
    StationScan,
    dense_scan_targets,
    fit_cyclic,
    net_of_cyclic,
)
from gateway.compensation import PitchTable
from gateway.demos import tour as demo
from gateway.event_loop import run_loop  # uvloop, as the daemon and the sim serve
from gateway.formats import read_pitch_csv, write_cyclic, write_pitch_csv
from sim.config import parse_config
from sim.server import SimServer

LEAD_MM = 10.0
STATIONS_MM = [120.0, 400.0, 680.0]
COARSE_MM = list(np.linspace(1.0, 799.0, 21))
#: (RMS coarse, coarse+cyclic: at 200 positions 1.31 and 0.35 µm, at 100 1.35 and 0.38, at 67
#: 1.30 and 0.37: the cut is the same; the judging was two thirds of the test's 12.8 s of CPU)
POSITIONS = 100
VISITS = 3  # each position measured 3 times and averaged: the RMS measures the systematic
# error between calibration points, not the 0.5 µm repeatability of each stop


def sim_config(cyclic_error: bool):
    data = yaml.safe_load(demo.SIM_EXAMPLE.read_text())
    for axis in data["sim"]["machine"].values():
        # No self-heating: at time_scale 0 the machine clock runs far ahead of the wall
        # clock the gateway polls Δa on, so how stale Δa is at each move (and the thermal
        # residual in the scans) would depend on the machine's load: not deterministic.
        axis["thermal"]["heat_K_per_m"] = 0.0
        if not cyclic_error:
            axis["pitch"]["periodic"] = []
    return parse_config(data, demo.SIM_EXAMPLE.parent)


def gateway_config(sim_port: int, pitch: Path | None = None, cyclic: Path | None = None):
    stages = {"thermal", "pitch"} if pitch else {"thermal"}
    data = demo.gateway_config(sim_port, frozenset(stages))
    data["axes"]["Y"]["compensation"].pop("pitch", None)
    comp = data["axes"]["X"]["compensation"]
    if pitch is not None:
        comp["pitch"] = {"file": str(pitch), "interpolation": "linear"}
    if cyclic is not None:
        comp["cyclic"] = str(cyclic)
    return data


async def dense_scan(pc: demo.UpperComputer, station_mm: float) -> StationScan:
    targets = dense_scan_targets(station_mm, LEAD_MM)
    rows = []
    for direction, order in ((1, targets), (-1, targets[::-1])):
        await pc.move("X", order[0] - direction)
        for target in order:
            await pc.move("X", float(target))
            rows.append((target, await pc.laser_mm("X") - target, direction))
    data = np.array(rows)
    return StationScan(data[:, 0], data[:, 1], data[:, 2].astype(np.int64))


async def off_grid_rms_um(pc: demo.UpperComputer) -> float:
    rng = np.random.default_rng(7)
    positions = rng.uniform(5.0, 795.0, POSITIONS)
    errors = []
    for i, position in enumerate(positions):
        direction = 1 if i % 2 == 0 else -1
        visits = []
        for _ in range(VISITS):
            await pc.move("X", position - direction)
            await pc.move("X", position)
            visits.append(await pc.laser_mm("X") - position)
        errors.append(np.mean(visits))
    return float(np.sqrt(np.mean(np.square(errors))) * 1e3)


async def experiment(tmp_path: Path, cyclic_error: bool, judge: bool = True):
    """The coarse table and the scans, fitted; with ``judge``, each config's off-grid RMS."""
    async with SimServer(sim_config(cyclic_error), tcp_port=0, time_scale=0) as sim:
        async with demo._Session(sim, gateway_config(sim.tcp_port), demo.CONFIG_DIR) as pc:
            await pc.move("Y", 0.0)
            up, down = await demo.bidirectional_runs(pc, "X", COARSE_MM, 3, (0.0, 800.0))
            coarse = PitchTable(np.array(COARSE_MM), up.mean(axis=1), down.mean(axis=1))
            scans = [await dense_scan(pc, s) for s in STATIONS_MM]
        fit = fit_cyclic(STATIONS_MM, scans, LEAD_MM)
        write_pitch_csv(tmp_path / "coarse.csv", coarse)
        write_pitch_csv(tmp_path / "net.csv", net_of_cyclic(coarse, fit.model))
        cyclic_file = None
        if fit.model is not None:
            cyclic_file = tmp_path / "cyclic.yaml"
            write_cyclic(cyclic_file, fit.model, sd_mm=fit.sd_mm)
        rms: dict[str, float] = {}
        for label, pitch, cyc in () if not judge else (
            ("coarse", tmp_path / "coarse.csv", None),
            ("coarse+cyclic", tmp_path / "net.csv", cyclic_file),
        ):
            async with demo._Session(sim, gateway_config(sim.tcp_port, pitch, cyc),
                                     demo.CONFIG_DIR) as pc:
                await pc.move("Y", 0.0)
                rms[label] = await off_grid_rms_um(pc)
        return fit, rms


def test_cyclic_stage_halves_the_off_grid_error(tmp_path: Path):
    fit, rms = run_loop(asyncio.wait_for(experiment(tmp_path, True), 120))
    print(f"harmonics {fit.harmonics}, CV {fit.cv_rms_um}, RMS {rms}")
    assert fit.harmonics >= 1
    # the example machine: 1.5 µm once per 10 mm lead at phase 30° (sin 1.30, cos 0.75 µm)
    amplitude_um = np.hypot(fit.model.sin_mm[:, 0], fit.model.cos_mm[:, 0]) * 1e3
    assert np.all(np.abs(amplitude_um - 1.5) < 0.4), amplitude_um
    assert rms["coarse+cyclic"] <= 0.5 * rms["coarse"], rms


def test_no_cyclic_error_no_cyclic_stage(tmp_path: Path):
    """Nothing added at all: no cyclic file, and the table net of it is the coarse table
    itself, value for value (so the two configs' off-grid RMS need not be read: they
    compensate alike)."""
    fit, _ = run_loop(asyncio.wait_for(experiment(tmp_path, False, judge=False), 120))
    print(f"harmonics {fit.harmonics}, CV {fit.cv_rms_um}")
    assert fit.harmonics == 0 and fit.model is None
    assert not (tmp_path / "cyclic.yaml").exists()
    coarse, net = read_pitch_csv(tmp_path / "coarse.csv"), read_pitch_csv(tmp_path / "net.csv")
    for column in ("position_mm", "forward_mm", "reverse_mm"):
        assert np.array_equal(getattr(net, column), getattr(coarse, column)), column
