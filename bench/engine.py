"""Engine speed: the full chain (pitch + backlash + planar + thermal), scalar and batch.

Prints the median µs per command on the scalar (per-transaction) path, forward and inverse,
and points per second on a vectorised batch. Targets: ≤ 20 µs/command, ≥ 1,000,000 points/s.
Bounded: fixed counts, a few seconds in all.
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np

from gateway.compensation import (
    AxisChain,
    AxisInput,
    BacklashStage,
    Chain,
    GridModel,
    PitchStage,
    PitchTable,
    PlanarMeasurement,
    PlanarStage,
    ThermalStage,
)

PULSE_MM = 0.001


def example_chain(interpolation: str = "linear") -> Chain:
    rng = np.random.default_rng(2)
    axes = {}
    for name, travel in (("X", 800.0), ("Y", 600.0)):
        pos = np.linspace(0.0, travel, 41)
        dev = 25e-6 * pos + 0.004 * np.sin(pos / 37.0) + rng.normal(0, 0.0005, pos.size)
        axes[name] = AxisChain(
            name,
            PULSE_MM,
            pitch=PitchStage(PitchTable(pos, dev), interpolation),
            backlash=BacklashStage(0.012),
            thermal=ThermalStage(length_mm=travel),
            travel_mm=(0.0, travel),
            max_correction_mm=0.2,
        )
    gx, gy = np.meshgrid(np.linspace(0, 800, 9), np.linspace(0, 600, 7))
    cmd = np.column_stack([gx.ravel(), gy.ravel()])
    err = np.column_stack([30 / 206265 * cmd[:, 1], 2e-5 * cmd[:, 0] + 3e-6 * cmd[:, 1]])
    planar = PlanarStage(GridModel.from_measurement(PlanarMeasurement(cmd, cmd + err), "cubic"))
    return Chain(axes, planar)


def bench_scalar(chain: Chain, count: int) -> tuple[float, float]:
    rng = np.random.default_rng(1)
    xs = rng.integers(0, 800_000, count).tolist()
    ys = rng.integers(0, 600_000, count).tolist()
    dirs = rng.choice([1, -1], count).tolist()
    fwd_us: list[float] = []
    inv_us: list[float] = []
    clock = time.perf_counter_ns
    for x, y, d in zip(xs, ys, dirs):
        inputs = {"X": AxisInput(x, d, 0.015), "Y": AxisInput(y, d, 0.01)}
        t0 = clock()
        cx = chain.command_pulses("X", inputs)
        t1 = clock()
        back = {"X": AxisInput(cx, d, 0.015), "Y": AxisInput(y, d, 0.01)}
        chain.nominal_pulses("X", back)
        t2 = clock()
        fwd_us.append((t1 - t0) / 1000)
        inv_us.append((t2 - t1) / 1000)
    return statistics.median(fwd_us), statistics.median(inv_us)


def bench_batch(chain: Chain, points: int, repeats: int) -> tuple[float, float]:
    rng = np.random.default_rng(3)
    nominal = {"X": rng.uniform(0, 800_000, points), "Y": rng.uniform(0, 600_000, points)}
    direction = {"X": rng.choice([1, -1], points), "Y": rng.choice([1, -1], points)}
    delta = {"X": 0.015, "Y": 0.01}
    best_fwd = best_inv = float("inf")
    for _ in range(repeats):
        t0 = time.perf_counter()
        cmd = chain.command_pulses_batch(nominal, direction, delta)
        t1 = time.perf_counter()
        chain.nominal_pulses_batch(cmd, direction, delta)
        t2 = time.perf_counter()
        best_fwd, best_inv = min(best_fwd, t1 - t0), min(best_inv, t2 - t1)
    # one "point" is one axis position: an XY pair counts as two
    return 2 * points / best_fwd, 2 * points / best_inv


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--count", type=int, default=20_000, help="scalar commands")
    parser.add_argument("--points", type=int, default=500_000, help="XY pairs per batch")
    args = parser.parse_args()
    print(f"{'chain':<28}{'scalar fwd µs':>14}{'scalar inv µs':>14}{'batch fwd pts/s':>17}"
          f"{'batch inv pts/s':>17}")
    for interpolation in ("linear", "smooth"):
        chain = example_chain(interpolation)
        fwd, inv = bench_scalar(chain, args.count)
        bfwd, binv = bench_batch(chain, args.points, 3)
        label = f"pitch({interpolation})+bl+xy+th"
        print(f"{label:<28}{fwd:>14.2f}{inv:>14.2f}{bfwd:>17,.0f}{binv:>17,.0f}")
    print("targets: scalar ≤ 20 µs per command; batch ≥ 1,000,000 points/s")


if __name__ == "__main__":
    main()
