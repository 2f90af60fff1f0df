"""`compgw demo`: the example machine with and without compensation, no hardware needed.

Starts the simulated machine (``config/example-sim.yaml``) and the gateway
(``config/example.yaml``, with the tables shipped in ``config/tables``) in one process on
free loopback ports, then acts as the upper computer: ISO 230-2-style bidirectional runs on
X and Y and an XY grid, first with compensation off, then on, measured with the simulated
laser and XY device. Verification targets lie between the tables' calibration points.

``--identify DIR`` runs the identification instead (compensation off, dense bidirectional
runs and an XY grid with the pitch tables on) and writes the tables the demo ships.
"""

from __future__ import annotations

import asyncio
import copy
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from ..app import GatewayApp
from ..calibration.fitting.iso230 import iso230_2
from ..calibration.fitting.outputs import fit_planar, save_planar
from ..calibration.measuring.machine import Link, MachineDriver
from ..compensation import PitchTable, PlanarMeasurement
from ..config import parse_config
from ..formats import write_pitch_csv
from ..instruments.modbus import ModbusChannels, ModbusXY
from ..sensors import ThermalState
from ..tables import build_chain

CONFIG_DIR = Path(__file__).resolve().parents[2] / "config"
GATEWAY_EXAMPLE = CONFIG_DIR / "example.yaml"
SIM_EXAMPLE = CONFIG_DIR / "example-sim.yaml"

LASER_UNIT, XY_UNIT, CONTROL_UNIT = 20, 21, 250
ADVANCE_CLOCK_S = 0x0800
COOL_DOWN_S = 20_000  # ≫ the screws' thermal time constant: a cold machine
OVERRUN_MM = 1.0

#: verification targets (mm): between the calibration points, deliberately uneven
VERIFY_MM = {
    "X": [3.7, 88.3, 161.9, 247.2, 333.6, 402.1, 488.8, 571.4, 650.3, 733.9, 796.2],
    "Y": [2.9, 71.3, 143.8, 204.6, 288.1, 356.7, 431.2, 509.9, 597.1],
}
RUNS = 5
GRID_PASSES = 3  # the XY grid is measured this many times and averaged


@dataclass
class UpperComputer:
    """The scripted master: moves through the gateway (the calibration's machine driver)
    and reads the sim's laser and XY device on the bench link."""

    driver: MachineDriver
    laser: ModbusChannels
    xy: ModbusXY
    bench: Link  # the sim: its instruments and control block

    async def move(self, axis: str, position_mm: float) -> None:
        await self.driver.move({axis: position_mm})

    async def move_xy(self, x_mm: float, y_mm: float) -> None:
        """Both targets, then both triggers (with on_trigger the first commits both)."""
        await self.driver.move({"X": x_mm, "Y": y_mm})

    async def laser_mm(self, axis: str) -> float:
        return (await self.laser.read_mm([axis]))[axis]

    async def xy_mm(self) -> np.ndarray:
        reading = await self.xy.read_mm(["X", "Y"])
        return np.array([reading["X"], reading["Y"]])

    async def cool_down(self) -> None:
        await self.bench.write(CONTROL_UNIT, ADVANCE_CLOCK_S, [COOL_DOWN_S])


async def bidirectional_runs(
    pc: UpperComputer, axis: str, targets_mm: list[float], runs: int, travel: tuple[float, float]
) -> tuple[np.ndarray, np.ndarray]:
    """ISO 230-2 cycle: up through the targets from below, down from above, ``runs`` times.

    Returns deviations actual − target (mm) as arrays ``[target, run]`` for + and −.
    """
    n = len(targets_mm)
    up, down = np.zeros((n, runs)), np.zeros((n, runs))
    below = max(travel[0], targets_mm[0] - OVERRUN_MM)
    above = min(travel[1], targets_mm[-1] + OVERRUN_MM)
    for j in range(runs):
        await pc.move(axis, below)
        for i, target in enumerate(targets_mm):
            await pc.move(axis, target)
            up[i, j] = await pc.laser_mm(axis) - target
        await pc.move(axis, above)
        for i in reversed(range(n)):
            await pc.move(axis, targets_mm[i])
            down[i, j] = await pc.laser_mm(axis) - targets_mm[i]
    return up, down


async def xy_errors(pc: UpperComputer, points_mm: np.ndarray) -> np.ndarray:
    """Actual − commanded XY (mm) at each point, approached from the lower-left."""
    errors = np.zeros_like(points_mm)
    for k, (x, y) in enumerate(points_mm):
        await pc.move_xy(max(0.0, x - OVERRUN_MM), max(0.0, y - OVERRUN_MM))
        await pc.move_xy(x, y)
        errors[k] = await pc.xy_mm() - (x, y)
    return errors


def verification_points() -> np.ndarray:
    """Off-grid XY points: the centres of the 100 mm calibration cells, and a few more."""
    xs, ys = np.meshgrid(np.arange(50.0, 800.0, 100.0), np.arange(50.0, 600.0, 100.0))
    return np.column_stack([xs.ravel(), ys.ravel()])


ALL_STAGES = frozenset({"pitch", "planar", "thermal"})
#: the sim runs faster than real time (time_scale 0): the demo polls the thermal sensors
#: often enough that the screw cannot grow noticeably between two polls
DEMO_POLL_S = 0.002


def gateway_config(sim_port: int, stages: frozenset[str] = ALL_STAGES) -> dict[str, Any]:
    """The example config on free ports, with only the given compensation stages."""
    data = yaml.safe_load(GATEWAY_EXAMPLE.read_text())
    data["upstream"]["tcp"]["port"] = 0
    for bus in data["buses"].values():
        bus["tcp"]["port"] = sim_port
    for source in data.get("thermal_sources", {}).values():
        source["poll_s"] = DEMO_POLL_S
        source["smoothing"] = 1.0  # at this poll rate smoothing would only add lag
    for axis in data["axes"].values():
        comp = axis["compensation"]
        for stage in ("pitch", "thermal"):
            if stage not in stages:
                comp.pop(stage, None)
        comp["enabled"] = bool(stages)
    if "planar" not in stages:
        data.pop("planar", None)
    return data


def _apply_overrides(data: dict[str, Any], pitch_files: dict[str, str] | None) -> dict[str, Any]:
    data = copy.deepcopy(data)
    for axis, path in (pitch_files or {}).items():
        data["axes"][axis]["compensation"]["pitch"]["file"] = path
    return data


class _Session:
    """Sim + one gateway configuration + the upper computer, as an async context."""

    def __init__(self, sim: Any, data: dict[str, Any], base_dir: Path) -> None:
        self.sim = sim
        self.config = parse_config(data, "example.yaml")
        self.chain = build_chain(self.config, base_dir)

    async def __aenter__(self) -> UpperComputer:
        self.app = GatewayApp(self.config, self.chain)
        await self.app.start()
        self.master = Link("127.0.0.1", self.app.tcp_port)
        self.bench = Link("127.0.0.1", self.sim.tcp_port)
        await self.master.connect()
        await self.bench.connect()
        axes = list(self.config.axes)
        pc = UpperComputer(
            MachineDriver(self.master, self.config),
            ModbusChannels("laser", f"unit {LASER_UNIT}", self.bench.read, LASER_UNIT, axes),
            ModbusXY("XY device", f"unit {XY_UNIT}", self.bench.read, XY_UNIT, ("X", "Y")),
            self.bench,
        )
        await pc.cool_down()
        await self.settle()
        return pc

    async def settle(self, timeout_s: float = 5.0) -> None:
        """Wait until every thermal sensor trusts a cold reading again (after cool-down the
        growth drops at once, faster than the plausibility rate allows: the filter needs
        a few polls to accept it)."""
        loop = asyncio.get_running_loop()
        deadline = loop.time() + timeout_s
        sensors = self.app.sensors
        while not all(
            sensors[name].state == ThermalState.OK and abs(sensors[name].delta_a_mm or 0) < 5e-4
            for name in sensors
        ):
            if loop.time() > deadline:
                raise RuntimeError("thermal sensors did not settle after the cool-down")
            await asyncio.sleep(DEMO_POLL_S)

    async def __aexit__(self, *exc: object) -> None:
        self.master.close()
        self.bench.close()
        await self.app.stop()


async def compare() -> dict[str, Any]:
    """Before/after figures on the example machine (the demo's JSON shape)."""
    from sim.config import load_config as load_sim
    from sim.server import SimServer

    result: dict[str, Any] = {"axes": {}, "xy": {}}
    points = verification_points()
    async with SimServer(load_sim(SIM_EXAMPLE), tcp_port=0, time_scale=0) as sim:
        for phase, on in (("before", False), ("after", True)):
            data = gateway_config(sim.tcp_port, ALL_STAGES if on else frozenset())
            async with _Session(sim, data, CONFIG_DIR) as pc:
                for axis, travel in (("X", (0.0, 800.0)), ("Y", (0.0, 600.0))):
                    await pc.move("Y" if axis == "X" else "X", 0.0)
                    up, down = await bidirectional_runs(pc, axis, VERIFY_MM[axis], RUNS, travel)
                    iso = iso230_2(np.array(VERIFY_MM[axis]), up, down)
                    result["axes"].setdefault(axis, {})[phase] = {
                        "B_um": iso.B_um,
                        "E_um": iso.E_um,
                        "A_um": iso.A_um,
                        "M_um": iso.M_um,
                        "R_um": iso.R_um,
                    }
                errors = await xy_errors(pc, points)
                result["xy"][f"{phase}_max_um"] = float(np.hypot(*errors.T).max() * 1e3)
    for figures in result["axes"].values():
        before, after = figures["before"], figures["after"]
        figures["E_reduction_pct"] = 100.0 * (1 - after["E_um"] / before["E_um"])
        figures["A_reduction_pct"] = 100.0 * (1 - after["A_um"] / before["A_um"])
    xy = result["xy"]
    xy["reduction_pct"] = 100.0 * (1 - xy["after_max_um"] / xy["before_max_um"])
    return _rounded(result)


def _rounded(value: Any) -> Any:
    """Figures to 0.01 (µm or %): the instruments resolve 0.1 µm."""
    if isinstance(value, dict):
        return {key: _rounded(item) for key, item in value.items()}
    return round(value, 2) if isinstance(value, float) else value


async def identify(out_dir: Path, step_mm: float = 2.5, runs: int = 5) -> None:
    """Measure the example machine and write the tables the demo ships into ``out_dir``.

    Pitch: bidirectional runs every ``step_mm`` (a quarter of the 10 mm screw lead, so the
    once-per-lead error is followed), compensation off. XY: a 100 mm grid with the new
    pitch tables on and the planar model off, so the model holds what pitch cannot.
    """
    from sim.config import load_config as load_sim
    from sim.server import SimServer

    out_dir.mkdir(parents=True, exist_ok=True)
    files = {"X": "x_pitch.csv", "Y": "y_pitch.csv"}
    async with SimServer(load_sim(SIM_EXAMPLE), tcp_port=0, time_scale=0) as sim:
        data = gateway_config(sim.tcp_port, frozenset({"thermal"}))
        async with _Session(sim, data, CONFIG_DIR) as pc:
            for axis, travel in (("X", (0.0, 800.0)), ("Y", (0.0, 600.0))):
                await pc.move("Y" if axis == "X" else "X", 0.0)
                targets = list(np.arange(travel[0] + OVERRUN_MM, travel[1], step_mm))
                up, down = await bidirectional_runs(pc, axis, targets, runs, travel)
                # rounded to 1 nm: below the laser's resolution, and a readable file
                fwd, rev = (np.round(d.mean(axis=1), 6) for d in (up, down))
                table = PitchTable(np.array(targets), fwd, rev)
                write_pitch_csv(
                    out_dir / files[axis],
                    table,
                    comment=f"example machine, axis {axis}: {runs} bidirectional runs every "
                    f"{step_mm} mm, thermal correction only (compgw demo --identify)",
                )
        data = gateway_config(sim.tcp_port, frozenset({"pitch", "thermal"}))
        data = _apply_overrides(data, {a: str((out_dir / f).resolve()) for a, f in files.items()})
        async with _Session(sim, data, CONFIG_DIR) as pc:
            xs, ys = np.meshgrid(np.arange(0.0, 801.0, 100.0), np.arange(0.0, 601.0, 100.0))
            grid = np.column_stack([xs.ravel(), ys.ravel()])
            grid[:, 0] = np.clip(grid[:, 0], OVERRUN_MM, 800.0)
            grid[:, 1] = np.clip(grid[:, 1], OVERRUN_MM, 600.0)
            passes = [await xy_errors(pc, grid) for _ in range(GRID_PASSES)]
            errors = np.mean(passes, axis=0)
    # the calibration's own planar fit: grid or polynomial by cross-validation, pinned to
    # zero along the lines where the pitch tables were measured (X at Y = 0, Y at X = 0)
    data = gateway_config(0)
    data["planar"]["model"] = str((out_dir / "xy_model.yaml").resolve())
    result = fit_planar(
        PlanarMeasurement(grid, grid + np.round(errors, 6)),
        parse_config(data, "example.yaml"),
        CONFIG_DIR,
        pitch_lines={"X": 0.0, "Y": 0.0},
    )
    save_planar(result, comment="example machine: 100 mm grid, 3 passes (compgw demo --identify)")


def format_table(result: dict[str, Any]) -> str:
    lines = [
        "compgw demo: example machine (simulated), ISO 230-2 bidirectional runs "
        f"({RUNS} runs) between calibration points",
        f"{'axis':<6}{'':<8}{'B µm':>9}{'E µm':>9}{'A µm':>9}{'M µm':>9}{'R µm':>9}",
    ]
    for axis, figures in result["axes"].items():
        for phase in ("before", "after"):
            f = figures[phase]
            lines.append(
                f"{axis:<6}{phase:<8}{f['B_um']:>9.1f}{f['E_um']:>9.1f}{f['A_um']:>9.1f}"
                f"{f['M_um']:>9.1f}{f['R_um']:>9.1f}"
            )
        lines.append(
            f"{'':<6}{'cut':<8}{'':>9}{figures['E_reduction_pct']:>8.0f}%"
            f"{figures['A_reduction_pct']:>8.0f}%"
        )
    xy = result["xy"]
    lines.append(
        f"XY max vector error at {len(verification_points())} off-grid points: "
        f"{xy['before_max_um']:.1f} µm before, {xy['after_max_um']:.1f} µm after "
        f"({xy['reduction_pct']:.0f}% less)"
    )
    return "\n".join(lines)


def main(as_json: bool = False, identify_dir: str | None = None) -> int:
    if identify_dir is not None:
        asyncio.run(identify(Path(identify_dir)))
        print(f"tables written to {identify_dir}")
        return 0
    result = asyncio.run(compare())
    print(json.dumps(result, indent=2) if as_json else format_table(result))
    if not as_json:
        from .commission import saved

        print("\nCommissioning (a saved run of `compgw demo --commission`, which runs it live):")
        print(saved(), end="")
    return 0
