"""How often a light warm-up read at the noise is refused (issue 52's smooth-2 Y): a
screw growing about 3 µm in a 30-minute zone warm-up, each stop read with 0.45 µm of
scatter, fitted as heat from motion over many draws of the noise and two sets of places.
tests/test_thermal_shape.py runs a dozen of these draws; this counts the rate.

A refusal leaves the axis's heat in (no thermal model); the rule refuses a fit only where
it leaves more than half the growth and more than the references' scatter explains, the
growth standing out of that (86c3f5c: 5 of 80 draws refused before it, 1 after).

    python bench/light_growth.py              # 40 draws per place set
    python bench/light_growth.py --draws 100
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from gateway.calibration.fitting.plans_scans import warmup_plan
from gateway.calibration.thermal.warmup_motion import warmup_motion_fit
from gateway.compensation.errors import TableError


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--draws", type=int, default=40, help="noise draws per place set")
    args = ap.parse_args()
    from tests.test_thermal_shape import FIVE, SEVEN, _raw, _ShortScrew  # the test's machine

    t0, total, refused = time.monotonic(), 0, []
    for places in (FIVE, SEVEN):
        plan = warmup_plan("X", (45.0, 105.0), 50.0, 1800.0, 132.0, places_mm=places,
                           also_mm=18.0, sensor=False)  # fmt: skip
        for seed in range(1, args.draws + 1):
            total += 1
            try:
                warmup_motion_fit(_raw(plan, _ShortScrew(), 0.45, seed), plan, "X", (0.0, 150.0))
            except TableError as exc:
                refused.append((len(places), seed, str(exc)))
    for n, seed, why in refused:
        print(f"refused: {n} places, seed {seed}: {why}")
    print(f"{len(refused)} of {total} draws refused ({time.monotonic() - t0:.0f} s)")


if __name__ == "__main__":
    main()
