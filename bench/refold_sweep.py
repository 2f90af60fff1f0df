"""A/B of the sweep's fold on kept machines, noise-free: the same sweep readings folded two
ways, each judged by ``static_chain`` (the sim's quiet truth through the gateway's chain).

For a machine kept by ``bench/accuracy.py --keep DIR`` whose commissioning swept an axis:
the sweep's readings are folded again (``RefineSteps.fold_sweep``, the commissioning's own
fold, drift taken off as it took it) into the tables kept just before the sweep, once with
``--margin`` 0 (the lost motion's change bends as GCV likes) and once with each given margin
(``sweep.LINE_MARGIN``: a line unless bending scores that much lower), smoothed as the
commissioning smooths; each result replaces that axis's table and cyclic term in the final
config (``work/refold*-AXIS.yaml``) and is judged noise-free at random parks. The
commissioning's own later rounds are left out on purpose: both folds are judged in the
same place.

    python bench/refold_sweep.py /tmp/keep/smooth-2 [/tmp/keep/rough-7 ...] [--margin 0.95]

A diagnostic: it imports both ``sim`` and ``gateway`` (the judge does not).
"""

from __future__ import annotations

import argparse
import json
import shutil
from pathlib import Path

import numpy as np
import yaml
from static_chain import machine_static

from gateway.calibration.commissioning.commission import Commission
from gateway.calibration.commissioning.steps import Settings
from gateway.calibration.fitting.outputs import write_table
from gateway.calibration.fitting.sweep import LINE_MARGIN
from gateway.formats import read_pitch_csv
from gateway.formats.cyclic_file import read_cyclic, write_cyclic


def _job(work: Path, axes: tuple[str, ...]) -> Commission:
    """The kept commissioning, read-only, as it was configured when it ran (the user's
    config: what decides whether drift was taken off its readings)."""
    orig = work / ".refold-original.yaml"
    shutil.copyfile(work / "commission" / "original.yaml", orig)
    settings = Settings(config_path=orig, out_dir=work / "commission", gateway=None,
                        instruments=None, axes=axes)  # fmt: skip
    return Commission(settings, None, lambda *a: None)  # type: ignore[arg-type]


def refold(machine: Path, margins: list[float], parks: int, targets: int, seed: int
           ) -> dict[str, dict[float, dict[str, float]]]:  # fmt: skip
    """Per swept axis, per margin: static E on the pitch line and at parks (µm)."""
    work = machine / "work"
    state = json.loads((work / "commission" / "commission.json").read_text())
    tables = state["tables"]
    job = _job(work, tuple(tables["pitch"]))
    out: dict[str, dict[float, dict[str, float]]] = {}
    for axis in tables["pitch"]:
        record = state.get("identify", {}).get(f"sweep-{axis}")
        if record is None:
            continue
        name = f"sweep{record['round']}-{axis}"
        keep = work / "commission" / "tables" / name
        table = read_pitch_csv(keep / Path(tables["pitch"][axis]).name)
        cyclic_path = tables["cyclic"].get(axis)
        model = read_cyclic(keep / Path(cyclic_path).name) if cyclic_path else None
        method = state.get("sweep_interpolation", {}).get(axis, "linear")
        config, _ = job.stager.staged(job.record.tables_phase)
        for margin in margins:
            ref, _ = job.refine.fold_sweep(name, axis, table, model, method, record["step_mm"],
                                            margin)
            fit = ref.fit
            tag = f"refold{margin:g}"
            (work / tag).mkdir(exist_ok=True)
            write_table(work / tag / f"{axis}_pitch.csv", "csv",
                        job.refine.smoothed(axis, ref.table, config), "refold")  # fmt: skip
            gw = yaml.safe_load((work / "gw.yaml").read_text())
            comp = gw["axes"][axis]["compensation"]
            comp["pitch"]["file"] = f"{tag}/{axis}_pitch.csv"
            if ref.cyclic is not None and "cyclic" in comp:
                write_cyclic(work / tag / f"{axis}_cyclic.yaml", ref.cyclic, {"fitted": "refold"})
                comp["cyclic"] = f"{tag}/{axis}_cyclic.yaml"
            path = work / f"{tag}-{axis}.yaml"
            path.write_text(yaml.safe_dump(gw, sort_keys=False))
            b_um = (fit.down_mm - fit.up_mm) * 1e3
            print(f"{machine.name} {axis} margin {margin:g}: penalties "
                  f"{', '.join(f'{v:g}' for v in fit.lambdas)}, hold {fit.hold:.3g}, the lost "
                  f"motion's change {np.ptp(b_um):.2f} µm peak to peak", flush=True)  # fmt: skip
            got = machine_static(machine, path, parks, targets, seed, 0.0)[axis]
            out.setdefault(axis, {})[margin] = got
        print(f"{machine.name} {axis}: " + "; ".join(
            f"margin {m:g}: E {v['line']:.2f} on the line, {v['parks']:.2f} at parks"
            for m, v in out[axis].items()), flush=True)  # fmt: skip
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("machines", type=Path, nargs="+", help="machine directories kept")
    parser.add_argument("--margin", type=float, action="append",
                        help=f"a line margin to try beside 0 (default {LINE_MARGIN})")
    parser.add_argument("--parks", type=int, default=10)
    parser.add_argument("--targets", type=int, default=12)
    parser.add_argument("--seed", type=int, default=7)
    args = parser.parse_args()
    margins = [0.0, *(args.margin or [LINE_MARGIN])]
    totals = {m: [0.0, 0.0] for m in margins}
    for machine in args.machines:
        for per in refold(machine, margins, args.parks, args.targets, args.seed).values():
            for m, v in per.items():
                totals[m][0] += v["line"]
                totals[m][1] += v["parks"]
    print("summed over the swept axes (µm): " + "; ".join(
        f"margin {m:g}: E {t[0]:.2f} on the line, {t[1]:.2f} at parks"
        for m, t in totals.items()))  # fmt: skip


if __name__ == "__main__":
    main()
