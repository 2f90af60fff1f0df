"""Leave-one-out prediction error of pitch tables on real measured axes.

For every bidirectional data set in ``../shared/data/real`` (BIFROST slit SAT tables and
the ecmc ISO 230-2 runs), each direction separately: the mean deviation per target is the
table; each interior target in turn is left out, the table is rebuilt from the others, and
the deviation it predicts there is compared with the measured one. Printed per set and
method (``linear``, ``smooth``, ``pchip``): RMS and max |error| in µm.
"""

from __future__ import annotations

import argparse
import csv
from collections import defaultdict
from pathlib import Path

import numpy as np

from gateway.compensation import PitchStage, PitchTable

DATA = Path(__file__).resolve().parent.parent.parent / "shared" / "data" / "real"
METHODS = ("linear", "smooth", "pchip")


def slit_sets(root: Path) -> dict[str, dict[str, tuple[np.ndarray, np.ndarray]]]:
    """BIFROST SAT tables: one pass per direction; rows without a reading are skipped."""
    sets = {}
    for path in sorted(root.glob("bifrost_slit_*/accuracy_bidirectional*.csv")):
        directions: dict[str, tuple[np.ndarray, np.ndarray]] = {}
        with path.open() as handle:
            rows = list(csv.DictReader(handle))
        for label, column in (("fwd", "dev_fwd_um"), ("rev", "dev_rev_um")):
            good = [r for r in rows if r[column].strip()]
            directions[label] = (
                np.array([float(r["target_mm"]) for r in good]),
                np.array([float(r[column]) for r in good]),
            )
        sets[f"{path.parent.name}/{path.stem}"] = directions
    return sets


def iso_sets(root: Path) -> dict[str, dict[str, tuple[np.ndarray, np.ndarray]]]:
    """ecmc ISO 230-2 runs: mean deviation over the cycles at each target, per direction."""
    sets = {}
    for folder in ("ecmc_iso230_ess_mcu1025", "ecmc_iso230_bifrost_11360_11358"):
        for path in sorted((root / folder).glob("*.csv")):
            samples: dict[str, dict[float, list[float]]] = defaultdict(lambda: defaultdict(list))
            with path.open() as handle:
                for row in csv.DictReader(handle):
                    direction = row["direction_as_labelled_in_source"]
                    samples[direction][float(row["target_mm"])].append(float(row["deviation_um"]))
            directions = {}
            for direction, by_target in samples.items():
                targets = np.array(sorted(by_target))
                means = np.array([np.mean(by_target[t]) for t in targets])
                directions[direction] = (targets, means)
            sets[f"{folder}/{path.stem}"] = directions
    return sets


def loo_errors_um(targets: np.ndarray, dev_um: np.ndarray, method: str) -> np.ndarray:
    """Prediction error (µm) at each interior target when it is left out of the table."""
    errors = []
    for i in range(1, targets.size - 1):
        keep = np.arange(targets.size) != i
        table = PitchTable(targets[keep], dev_um[keep] * 1e-3)
        stage = PitchStage(table, method)
        predicted_um = (float(stage.inverse(targets[i], 1)) - targets[i]) * 1e3
        errors.append(predicted_um - dev_um[i])
    return np.array(errors)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--data", type=Path, default=DATA, help="the shared real-data folder")
    args = parser.parse_args()
    sets = {**slit_sets(args.data), **iso_sets(args.data)}
    if not sets:
        raise SystemExit(f"no data sets found under {args.data}")
    header = f"{'data set / direction':<76}{'n':>3}"
    for method in METHODS:
        header += f"{method + ' rms':>13}{'max':>7}"
    print(header)
    totals: dict[str, list[np.ndarray]] = defaultdict(list)
    for name, directions in sets.items():
        for direction, (targets, dev_um) in directions.items():
            if targets.size < 4:
                continue
            line = f"{name + ' ' + direction:<76}{targets.size - 2:>3}"
            for method in METHODS:
                err = loo_errors_um(targets, dev_um, method)
                totals[method].append(err)
                line += f"{np.sqrt(np.mean(err**2)):>13.2f}{np.abs(err).max():>7.1f}"
            print(line)
    line = f"{'ALL (pooled)':<76}{sum(e.size for e in totals['linear']):>3}"
    for method in METHODS:
        err = np.concatenate(totals[method])
        line += f"{np.sqrt(np.mean(err**2)):>13.2f}{np.abs(err).max():>7.1f}"
    print(line)
    print("µm; interior targets only (leaving out an end point would test extrapolation)")


if __name__ == "__main__":
    main()
