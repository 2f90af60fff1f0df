"""Real measured errors as machines: ``compgw sim --real-machine NAME [--out DIR]``.

Each machine is a 2-axis XY table whose truth is a set from ``../shared/data/real`` (or
``$COMPGW_REAL_DATA``): per axis the measured deviation approached moving + and moving −
(the lost motion with it) through the measured points, repeatability from the repeated
readings; or an XY error field from CMM-measured hole positions. The data files are read
where they are and the truth written into DIR (their licences allow internal testing, not
redistribution: nothing is copied into the repository). Sets and caveats: sim/README.md,
"Real-data machines"; each folder's SOURCE.txt.
"""

from __future__ import annotations

import csv
import os
from collections import defaultdict
from pathlib import Path
from typing import Any

import numpy as np

from sim.machine_files import AxisSpec, MachineSpec

#: BIFROST slit SAT tables: (accuracy CSV, repeatability CSV) per axis
SLITS = {
    "slit-11358": ("bifrost_slit_11358_axis1/accuracy_bidirectional.csv",
                   "bifrost_slit_11358_axis1/repeatability.csv",
                   "bifrost_slit_11358_axis2/accuracy_bidirectional.csv",
                   "bifrost_slit_11358_axis2/repeatability.csv"),
    "slit-11359": ("bifrost_slit_11359_axis1/accuracy_bidirectional_run2.csv",
                   "bifrost_slit_11359_axis1/repeatability_run2.csv",
                   "bifrost_slit_11359_axis2/accuracy_bidirectional.csv",
                   "bifrost_slit_11359_axis2/repeatability.csv"),
    "slit-11361": ("bifrost_slit_11361_axis1/accuracy_bidirectional.csv",
                   "bifrost_slit_11361_axis1/repeatability.csv",
                   "bifrost_slit_11361_axis2/accuracy_bidirectional.csv",
                   "bifrost_slit_11361_axis2/repeatability.csv"),
}  # fmt: skip
#: ISO 230-2 runs (5 targets x 5 cycles x 2 directions); "forward" as labelled is +
ISO = {
    "mcu1025": ("ecmc_iso230_ess_mcu1025/mcu1025_axis1_run_2021-11-10a_isodat.csv",
                "ecmc_iso230_ess_mcu1025/mcu1025_axis1_run_2021-11-10b_isodat.csv"),
    "slit-11360-iso": ("ecmc_iso230_bifrost_11360_11358/slit11360_axis1_230_2_3_isodat.csv",
                       "ecmc_iso230_bifrost_11360_11358/"
                       "slit11360_axis2_230_2_step_10_only230_report.csv"),
    "slit-11358-retest": ("ecmc_iso230_bifrost_11360_11358/slit11358_axis1_2023retest_report.csv",
                          "ecmc_iso230_bifrost_11360_11358/"
                          "slit11360_axis1_230_2_slower_rate_report.csv"),
}  # fmt: skip
#: SDSS plug plates drilled on one CNC machine, holes measured on a CMM: the XY field
PLATES = {"sdss-1396": "D1396A1.txt", "sdss-1597": "D1597A6.txt", "sdss-2130": "D2130A1.txt"}
NAMES = (*SLITS, *ISO, *PLATES)
#: the SDSS field is evaluated on the square inside the measured disc, every 25 mm
PLATE_HALF_MM, PLATE_NODE_MM = 225.0, 25.0
#: thin-plate smoothing (µm²-like units of scipy's RBFInterpolator): on held-out holes it
#: predicts at the holes' own scatter (3.4-3.9 µm RMS on D1396A1)
PLATE_SMOOTHING = 1000.0


def data_root() -> Path:
    """``$COMPGW_REAL_DATA``, else ``../shared/data/real`` beside the repository."""
    env = os.environ.get("COMPGW_REAL_DATA")
    return Path(env) if env else Path(__file__).resolve().parents[2] / "shared" / "data" / "real"


def _rows(path: Path) -> list[dict[str, str]]:
    with path.open(newline="", encoding="utf-8") as fh:
        return list(csv.DictReader(fh))


def _slit_axis(root: Path, name: str, unit: int, table: str, repeat: str) -> AxisSpec:
    """A SAT table (one pass per direction) and its repeatability readings."""
    rows = [r for r in _rows(root / table) if r["dev_fwd_um"].strip() and r["dev_rev_um"].strip()]
    x = np.array([float(r["target_mm"]) for r in rows])
    fwd = np.array([float(r["dev_fwd_um"]) for r in rows])
    rev = np.array([float(r["dev_rev_um"]) for r in rows])
    # repeatability: scatter of successive repeats (the slow drift between repeats removed)
    by_target: dict[tuple[str, str], list[float]] = defaultdict(list)
    for r in _rows(root / repeat):
        for col in ("ild2300_fwd_mm", "ild2300_rev_mm"):
            if r[col].strip():
                by_target[(r["target_mm"], col)].append(float(r[col]) * 1000)
    sds = [np.std(np.diff(v), ddof=1) / np.sqrt(2) for v in by_target.values() if len(v) > 2]
    sigma = float(np.median(sds)) if sds else 0.5
    return _data_axis(name, unit, x, fwd, rev, sigma, {"source": table, "repeatability_from":
                      repeat, "reference": "ILD2300 laser triangulation on the blade"})  # fmt: skip


def _iso_axis(root: Path, name: str, unit: int, table: str) -> AxisSpec:
    """ISO 230-2 runs: the median over the cycles per target and direction (the first
    approach after start of mcu1025 run a is an 80-100 µm outlier: the median keeps it out)."""
    samples: dict[str, dict[float, list[float]]] = defaultdict(lambda: defaultdict(list))
    for r in _rows(root / table):
        samples[r["direction_as_labelled_in_source"]][float(r["target_mm"])].append(
            float(r["deviation_um"]))  # fmt: skip
    x = np.array(sorted(samples["forward"]))
    fwd = np.array([np.median(samples["forward"][t]) for t in x])
    rev = np.array([np.median(samples["backward"][t]) for t in x])
    sds = [np.std(v, ddof=1) for d in samples.values() for v in d.values() if len(v) > 2]
    return _data_axis(name, unit, x, fwd, rev, float(np.median(sds)),
                      {"source": table, "directions": "forward as labelled = +"})  # fmt: skip


def _data_axis(name: str, unit: int, x: np.ndarray, fwd: np.ndarray, rev: np.ndarray,
               sigma_um: float, info: dict[str, Any]) -> AxisSpec:
    info = {**info, "points": int(x.size), "data_spacing_mm": float(np.median(np.diff(x))),
            "repeatability_um": round(sigma_um, 2),
            "lost_motion_um": [round(float((rev - fwd).min()), 1),
                               round(float((rev - fwd).max()), 1)]}  # fmt: skip
    # the travel: the measured range rounded out to whole millimetres (end values held)
    travel = (float(np.floor(x[0])), float(np.ceil(x[-1])))
    return AxisSpec(name=name, unit=unit, travel_mm=travel,
                    speed_mm_s=20.0, pulse_mm=0.001, command_scale=10, positions_mm=x,
                    forward_um=fwd, reverse_um=rev, repeatability_um=round(sigma_um, 3),
                    info=info)  # fmt: skip


def _plate(root: Path, name: str, file: str) -> MachineSpec:
    """The XY field of one plate's holes (offset removed), on the square inside the disc."""
    path = root / "xy_sdss_plugplate_cmm" / file
    values = []
    for line in path.read_text(encoding="utf-8").splitlines():
        parts = line.split()
        try:
            values.append([float(p) for p in parts[:6]])
        except ValueError:
            continue
    data = np.array([v for v in values if len(v) == 6])
    nominal, err_um = data[:, 2:4], data[:, 4:6] * 1000.0
    err_um = err_um - err_um.mean(axis=0)  # where the plate sat on the CMM: not the machine
    from scipy.interpolate import RBFInterpolator  # (a plate's machine only: the sim's start)

    surface = RBFInterpolator(nominal, err_um, kernel="thin_plate_spline",
                              smoothing=PLATE_SMOOTHING)  # fmt: skip
    nodes = np.arange(-PLATE_HALF_MM, PLATE_HALF_MM + 1e-9, PLATE_NODE_MM)
    gx, gy = np.meshgrid(nodes, nodes, indexing="ij")
    field = surface(np.column_stack([gx.ravel(), gy.ravel()])).reshape(*gx.shape, 2)
    travel = (0.0, 2 * PLATE_HALF_MM)
    axes = []
    for k, axis in enumerate(("X", "Y")):
        axes.append(AxisSpec(name=axis, unit=k + 1, travel_mm=travel, speed_mm_s=100.0,
                             pulse_mm=0.001, command_scale=10, positions_mm=np.array(travel),
                             forward_um=np.zeros(2), reverse_um=np.zeros(2),
                             repeatability_um=1.0, info={"data_spacing_mm": 20.0}))  # fmt: skip
    shifted = nodes + PLATE_HALF_MM
    info = {"source": f"xy_sdss_plugplate_cmm/{file}", "holes": len(data),
            "field": f"thin-plate surface through the holes' errors (smoothing "
                     f"{PLATE_SMOOTHING:g}), nodes every {PLATE_NODE_MM:g} mm on the "
                     f"{2 * PLATE_HALF_MM:g} mm square inside the plate",
            "note": "no per-axis data: the field holds the axes' own errors along its lines; "
                    "repeatability 1 um assumed (the holes' 3-4 um scatter is drilling and "
                    "CMM, not the table)"}  # fmt: skip
    header = (f"{name}: the XY error field of SDSS plate {file} (CMM-measured holes drilled on "
              "one CNC machine), from ../shared/data/real (sim/README.md, Real-data machines)")
    return MachineSpec(name=name, sim_seed=1, axes=(axes[0], axes[1]),
                       field=(shifted, shifted, field[..., 0], field[..., 1]),
                       header=header, info=info)  # fmt: skip


def real_machine(name: str, root: Path | None = None) -> MachineSpec:
    """The machine ``name`` (one of :data:`NAMES`) from the real data under ``root``."""
    root = root or data_root()
    if name in PLATES:
        return _plate(root, name, PLATES[name])
    if name in SLITS:
        tx, rx, ty, ry = SLITS[name]
        axes = (_slit_axis(root, "X", 1, tx, rx), _slit_axis(root, "Y", 2, ty, ry))
    elif name in ISO:
        tx, ty = ISO[name]
        axes = (_iso_axis(root, "X", 1, tx), _iso_axis(root, "Y", 2, ty))
    else:
        raise ValueError(f"no real machine {name!r} (one of {', '.join(NAMES)})")
    header = (f"{name}: measured axis errors as truth, X <- {axes[0].info['source']},\n"
              f"Y <- {axes[1].info['source']} (../shared/data/real; sim/README.md)")
    return MachineSpec(name=name, sim_seed=1, axes=axes, header=header,
                       info={"real_data": str(root)})  # fmt: skip

