"""The judge's zone test replayed offline, in seconds: a commissioned machine's fitted
thermal section against the sim's heat equation, on the zone `bench/evaluate.py` strokes
and on zones at both ends of the travel.

`bench/accuracy.py --warm-judge` reads the zone test on the running sim through the
gateway: minutes a machine, the readings' scatter in it. Here the same 30 minutes of
strokes are replayed on the sim's own screw model (sim/heat.py: the truth) and on the
gateway's own heat from motion and travel profile (gateway/thermal_travel.py, on a machine
clock), noise-free. It printed rough-9 X 2.44 and 1.62 µm where the bench read 2.69 and
1.63, rough-4 X 0.46 / 0.55, rough-2 X 4.03 / 4.02 (session 55). For a thermal model
change: refit a kept warm-up with the new code, replay, and only then run the bench.

    python bench/accuracy.py --only rough-9 --real none --warm-judge --keep /tmp/k
    python bench/zone_replay.py /tmp/k/rough-9 X
    python bench/zone_replay.py /tmp/k/rough-9 X --thermal '{"origin_mm": ...}'
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from evaluate import plan, zone_strokes

from gateway.compensation.thermal import ThermalStage
from gateway.config import AxisThermal
from gateway.thermal_travel import HeatFromMotion, TravelHistory
from sim.config_truth import ScrewHeat
from sim.heat import ScrewHeatModel

Move = tuple[float, float, float, float]  # start s, end s, from mm, to mm


def strokes(z0_mm: float, z1_mm: float, speed_mm_s: float) -> tuple[list[Move], float]:
    """The judge's zone work: its strokes over [z0, z1] (bench/evaluate.py) as timed moves."""
    t_s, pos, moves = 0.0, z0_mm, []
    for k in range(zone_strokes(z0_mm, z1_mm, speed_mm_s)):
        to = z1_mm if k % 2 == 0 else z0_mm
        dt = abs(to - pos) / speed_mm_s
        moves.append((t_s, t_s + dt, pos, to))
        t_s, pos = t_s + dt, to
    return moves, t_s


def truth_um(heat: dict[str, Any], travel_mm: tuple[float, float], moves: list[Move],
             end_s: float, places_mm: np.ndarray, speed_mm_s: float) -> np.ndarray:
    """The sim's growth at ``places_mm`` after ``moves`` (µm)."""
    model = ScrewHeatModel(ScrewHeat(**heat), travel_mm)
    for a, b, f, to in moves:
        model.add_move(a, b, f, to, speed_mm_s)
    return np.array([model.growth_mm(p, end_s) for p in places_mm]) * 1000.0


def model_um(section: dict[str, Any], axis: str, travel_mm: tuple[float, float],
             moves: list[Move], end_s: float, places_mm: np.ndarray) -> np.ndarray:
    """The gateway's correction at ``places_mm`` after ``moves`` (µm), as it counts them."""
    th = AxisThermal.model_validate(section)
    if th.motion is None:
        raise SystemExit("zone_replay: the section has no thermal.motion (a sensor's model "
                         "needs the sensor's readings: not replayed here)")
    now = [0.0]
    heat = HeatFromMotion(axis, th.motion, clock=lambda: now[0])
    history = TravelHistory(th, th.profile, travel_mm, clock=lambda: now[0]) \
        if th.profile else None  # fmt: skip
    stage = ThermalStage(th.length_mm, th.origin_mm)
    for k, (_, b, f, to) in enumerate(moves):
        if k == 0:
            heat.moved(axis, f)
            if history:
                history.move_to(f)
        now[0] = b
        heat.moved(axis, to)
        if history:
            history.move_to(to)
    now[0] = end_s
    da = heat.delta_a_mm()
    return np.array([stage.inverse_scalar(p, history.delta_a_mm(da, p) if history else da) - p
                     for p in places_mm]) * 1000.0  # fmt: skip


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("machine", type=Path, help="a machine's directory kept by --keep")
    parser.add_argument("axis")
    parser.add_argument("--thermal", help="a thermal section (JSON) in place of the one "
                        "commissioning wrote to work/gw.yaml")
    args = parser.parse_args()
    sim = yaml.safe_load((args.machine / "sim.yaml").read_text())["sim"]
    machine = json.loads((args.machine / "machine.json").read_text())
    axis = args.axis
    section = (json.loads(args.thermal) if args.thermal else yaml.safe_load(
        (args.machine / "work" / "gw.yaml").read_text())["axes"][axis]["compensation"]["thermal"])
    lo, hi = (float(v) for v in sim["axes"][axis]["travel_mm"])
    speed = float(sim["axes"][axis]["speed_mm_s"])
    judged = plan(machine, {}, 0)["axes"][axis]  # the bench's judge plan (seed 0)
    places = np.array(judged["thermal_points"])
    z0, z1 = judged["zone"]
    width = z1 - z0
    print(f"{args.machine.name} {axis}: {json.dumps(section)}")
    for name, (a, b) in (("judge's", (z0, z1)), ("low end", (lo, lo + width)),
                         ("high end", (hi - width, hi))):
        moves, end_s = strokes(a, b, speed)
        real = truth_um(sim["machine"][axis]["heat"], (lo, hi), moves, end_s, places, speed)
        pred = model_um(section, axis, (lo, hi), moves, end_s, places)
        left = np.abs(pred - real).max()
        print(f"  {name:8s} zone {a:7.1f}-{b:7.1f} mm: sim {np.round(real, 1)} µm, model "
              f"{np.round(pred, 1)}: left {left:.2f} µm ({100 * left / np.abs(real).max():.1f} %)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
