"""``compgw fit``: raw files → the tables, models and values the config references.

Each raw file's kind comes from its ``# kind:`` line (else its columns); the fits are
:mod:`.fitting.outputs`'s, written only once every file of the call has fitted (nothing half
written), then a faded plane is re-expressed against tables written in the same call
(:mod:`.fitting.plane_frame`).
"""

from __future__ import annotations

import argparse
import json
from collections.abc import Callable
from pathlib import Path
from typing import Any

from ..compensation.errors import CompensationError, TableError
from ..config import ConfigError, GatewayConfig
from .cli_common import EXIT_BAD_INPUT, EXIT_OK, err, load


def raw_kind(path: str) -> str:
    """pitch, backlash, takeup, cyclic, planar or thermal: from the raw file's meta, else its
    columns. An ISO run is a pitch run whatever columns it carries beside (commissioning
    records the sensors' Δa or temperature at every stop)."""
    from .plans.rawdata import read_raw_csv
    from .plans.runner import read_raw_meta

    kind = read_raw_meta(path).get("kind", "")
    if kind in ("backlash", "cyclic", "takeup"):
        return kind
    if kind.startswith("xy"):
        return "planar"
    if kind == "warmup":
        return "thermal"
    if kind.startswith("iso230"):
        return "pitch"
    raw = read_raw_csv(path)
    if "x_mm" in raw.extra and "y_mm" in raw.extra:
        return "planar"
    if "delta_a_mm" in raw.extra:
        return "thermal"
    return "pitch"


def fit(args: argparse.Namespace) -> int:
    """``compgw fit``: raw files → the tables and values the config references.

    Order (whatever the order of the files): backlash runs first (their B serves the
    unidirectional tables, their lost motion per place the take-up ladder's fractions), then
    take-up and cyclic runs, then the rest. An ISO table of an axis whose
    cyclic run is in the same call is written net of the cyclic term at its targets (the
    joint fit: the coarse points do not count the cyclic error a second time).
    """
    from .fitting.cyclic_fit import harmonics_table
    from .fitting.fit import planar_measurement
    from .fitting.models import thermal_fit
    from .fitting.outputs import (
        fit_cyclic_raw,
        fit_pitch,
        fit_planar,
        net_pitch,
        save_cyclic,
        save_pitch,
        save_planar,
    )
    from .fitting.plane_frame import fitted_frame, reframe_plane, save_frame
    from .plans.plans import backlash_from_raw
    from .plans.rawdata import read_raw_csv
    from .plans.runner import read_raw_meta

    report: dict[str, Any] = {}
    try:
        config, config_dir = load(args.config)
        kinds = {path: raw_kind(path) for path in args.raw}
        backlash: dict[str, float] = {}
        places: dict[str, Any] = {}  # axis → the seed 000 result (lost motion per place)
        for path, kind in kinds.items():
            if kind == "backlash":
                raw = read_raw_csv(path)
                for a in raw.axes:
                    res = backlash_from_raw(raw, a)
                    backlash[a], places[a] = res.backlash_mm, res
                    angular = a in config.axes and config.axes[a].rotary
                    key, scale = ("backlash_arcsec", 3600.0) if angular else ("backlash_um", 1e3)
                    report.setdefault(a, {})[key] = res.backlash_mm * scale
                    report[a]["backlash_places"] = {
                        f"{p:g}": m * scale for p, m in zip(res.place_mm, res.mean_mm)
                    }
        for path, kind in kinds.items():
            if kind == "takeup":
                _fit_takeup(path, places, report)
        pending: list[Callable[[], None]] = []
        cyclic: dict[str, Any] = {}  # axis → the cyclic model written (for the joint fit)
        for path, kind in kinds.items():
            if kind != "cyclic":
                continue
            meta = read_raw_meta(path)
            residual = args.residual or meta.get("compensation") == "on"
            raw = read_raw_csv(path)
            for a in raw.axes:
                if a in cyclic:
                    raise TableError(f"{path}: a second cyclic run of axis {a} in one call")
                cr = fit_cyclic_raw(raw, meta, config, config_dir, a,
                                    harmonics=args.harmonics, residual=residual)  # fmt: skip
                comment = f"compgw fit from {Path(path).name}"
                pending.append(lambda cr=cr, c=comment: save_cyclic(cr, c))
                cyclic[a] = cr.model
                report.setdefault(a, {})["cyclic"] = {
                    "file": str(cr.path), "lead_mm": cr.model.lead_mm,
                    "harmonics": cr.fit.harmonics, "folded": cr.folded,
                    "cv_rms_um": {str(k): v for k, v in cr.fit.cv_rms_um.items()},
                    "residual_rms_um": cr.fit.residual_rms_um,
                    "peak_um": cr.model.peak_mm() * 1e3,
                    "unit": "deg" if config.axes[a].rotary else "mm",
                    "stations": [h.to_json_dict() for h in harmonics_table(cr.fit)],
                }  # fmt: skip
        for path, kind in kinds.items():
            residual = args.residual or read_raw_meta(path).get("compensation") == "on"
            comment = f"fitted by compgw fit from {Path(path).name}"
            if kind == "pitch":
                raw = read_raw_csv(path)
                for a in raw.axes:
                    r = fit_pitch(raw, config, config_dir, a, mode=args.mode, residual=residual,
                                  backlash_mm=backlash.get(a), reversal=args.reversal,
                                  reversal_degree=args.reversal_degree)  # fmt: skip
                    netted = a in cyclic and not residual
                    if netted:
                        r = net_pitch(r, cyclic[a], config)
                        comment += " net of the cyclic term (joint fit)"
                    entry = report.setdefault(a, {})
                    if args.smooth and r.reversal is not None and not residual \
                            and not config.axes[a].rotary:
                        r = _smoothed(r, raw, config, entry)
                    pending.append(lambda r=r, c=comment: save_pitch(r, c))
                    entry["net_of_cyclic"] = netted
                    entry.update(table=str(r.path), mode=r.mode, folded=r.folded,
                                 points=int(r.table.position_mm.size))  # fmt: skip
                    if r.backlash_mm is not None:
                        entry["backlash_mm"] = r.backlash_mm
                    if r.reversal is not None:
                        entry["reversal"] = r.reversal.summary()
                    entry.update(_rotary_entry(r, config, a))
            elif kind == "planar":
                if config.planar is None:
                    raise TableError(f"{path}: an XY run, but the config has no planar section")
                meas = planar_measurement(read_raw_csv(path), tuple(config.planar.axes))  # type: ignore[arg-type]
                lines = _pitch_lines(args.pitch_lines)
                pr = fit_planar(meas, config, config_dir, args.planar_model, residual, lines)
                pending.append(lambda pr=pr, c=comment: save_planar(pr, c))
                # the tables it was read with (on disk now), where the pin fades
                frame = fitted_frame(pr.choice.pinned, meas, config, config_dir,
                                     tuple(config.planar.axes), lines)  # type: ignore[arg-type]
                pending.append(lambda p=pr.points_path, f=frame: save_frame(p, f))
                ch = pr.choice
                report["planar"] = {
                    "model": str(pr.model_path), "points": str(pr.points_path), "kind": ch.kind,
                    "degree": ch.degree, "loo_rms_um": ch.loo_rms_um,
                    "residual_rms_um": ch.residual_rms_um, "residual_max_um": ch.residual_max_um,
                    "folded": pr.folded, "pinned": ch.pinned,
                }  # fmt: skip
            elif kind == "thermal":
                raw = read_raw_csv(path)
                for a in raw.axes:
                    th = config.axes[a].compensation.thermal if a in config.axes else None
                    tf = thermal_fit(raw, a, th.origin_mm if th else 0.0,
                                     th.length_mm if th else None)  # fmt: skip
                    report.setdefault(a, {})["thermal"] = {
                        "length_mm": tf.length_mm, "gain": tf.gain, "origin_mm": tf.origin_mm,
                        "reference_mm": tf.reference_mm, "growth_max_um": tf.growth_max_um,
                        "residual_rms_um": tf.residual_rms_um,
                        "residual_max_um": tf.residual_max_um, "readings": tf.points,
                    }  # fmt: skip
        for a, entry in report.items():
            if "cyclic" in entry and "table" not in entry and a in config.axes \
                    and config.axes[a].compensation.pitch is not None:  # fmt: skip
                entry["cyclic"]["note"] = (
                    f"the pitch table of {a} was not re-fitted: give its ISO raw file in the "
                    "same call so the table is taken net of the cyclic term (else the cyclic "
                    "error at the table's points is counted twice)")  # fmt: skip
        if not args.dry_run:
            for save in pending:
                save()
            if reframe_plane(config, config_dir):
                report.setdefault("planar", {})["reframed"] = True
    except (ConfigError, TableError, CompensationError, ValueError) as exc:
        err("fit", exc)
        return EXIT_BAD_INPUT
    if args.json:
        print(json.dumps(report, indent=2))
    else:
        print(format_fit(report, args.dry_run))
    return EXIT_OK


def _rotary_entry(r: Any, config: GatewayConfig, axis: str) -> dict[str, Any]:
    """What a rotary axis's fit adds to the report: the interpolation chosen by
    cross-validation (scores in arcseconds) and a swing axis's fitted linkage."""
    out: dict[str, Any] = {}
    if r.interpolation_cv is not None:
        best, scores = r.interpolation_cv
        spec = config.axes[axis].compensation.pitch_file
        out["interpolation_cv"] = {
            "best": best, "configured": spec.interpolation if spec else "linear",
            "loo_rms_arcsec": {k: v * 3600.0 for k, v in scores.items()}}  # fmt: skip
    if r.linkage is not None:
        fit = r.linkage
        out["linkage"] = {"file": str(r.linkage_path), "fitted": list(fit.free),
                          "values": fit.model.values(), "rms_deg": fit.rms_deg,
                          "max_deg": fit.max_deg, "drawing_rms_deg": fit.start_rms_deg}
    return out


def _smoothed(r: Any, raw: Any, config: GatewayConfig, entry: dict[str, Any]) -> Any:
    """``--smooth``: an identification's table smoothed by its own leave-one-out, its
    points moved by no more than their standard error (the runs' scatter over √runs, as
    ``compgw commission`` does; :func:`.fitting.fit.smoothed_table`), checked again."""
    from dataclasses import replace

    from .fitting.fit import smoothed_table
    from .fitting.outputs import check_pitch
    from .plans.rawdata import axis_deviations

    runs = len(axis_deviations(raw, r.axis).runs)  # the runs' numbers
    fit = smoothed_table(r.table, r.reversal.scatter_um * 1e-3, runs)
    check_pitch(fit.table, config, r.axis)
    entry["smoothed"] = {"change_rms_um": fit.change_rms_mm * 1e3, "cap_um": fit.cap_mm * 1e3}
    return replace(r, table=fit.table)


def _pitch_lines(items: list[str] | None) -> dict[str, float] | None:
    """``X@Y=0`` → {"X": 0.0}: X's table was measured with Y at 0."""
    if not items:
        return None
    out = {}
    for item in items:
        axis, at, rest = item.partition("@")
        _, eq, value = rest.partition("=")
        if not (axis and at and eq):
            raise ValueError(f"--pitch-line {item!r} is not AXIS@OTHER=MM (e.g. X@Y=0)")
        out[axis] = float(value)
    return out


def format_fit(report: dict[str, Any], dry_run: bool = False) -> str:
    lines = []
    verb = "would write" if dry_run else "wrote"
    for name, entry in report.items():
        if name == "planar" and "model" not in entry:  # only re-expressed
            lines.append(f"planar: {verb} its points re-expressed against the new tables "
                         "(faded off the pitch lines: see xy_frame.json)")  # fmt: skip
            continue
        if name == "planar":
            if entry.get("reframed"):
                lines.append("planar: re-expressed against the tables written with it")
            loo = ", ".join(f"{k} {v:.2f}" for k, v in entry["loo_rms_um"].items())
            pin = f", {entry['pinned']} pinned to the pitch lines" if entry.get("pinned") else ""
            lines.append(f"planar: {verb} {entry['model']} ({entry['kind']}{pin}"
                         f"{'' if entry['degree'] is None else ' degree ' + str(entry['degree'])}"
                         f"); LOO RMS µm: {loo}; residual RMS {entry['residual_rms_um']:.2f} "
                         f"max {entry['residual_max_um']:.2f} µm")  # fmt: skip
            continue
        if "cyclic" in entry:
            c = entry["cyclic"]
            # a rotary axis's (a worm's) figures: mdeg in the _um keys, shown in arcsec
            pos, u, f = ("deg", "arcsec", 3.6) if c.get("unit") == "deg" else ("mm", "µm", 1.0)
            cv = ", ".join(f"K={k} {v * f:.3f}" for k, v in c["cv_rms_um"].items())
            lines.append(f"{name}: {verb} {c['file']} (cyclic, lead {c['lead_mm']:g} {pos}, "
                         f"{c['harmonics']} harmonic(s){', folded' if c['folded'] else ''}; "
                         f"CV RMS {u}: {cv}; residual RMS {c['residual_rms_um'] * f:.3f} {u})")
            for h in c["stations"]:
                lines.append(f"{name}:   at {h['station_mm']:g} {pos}, k={h['k']}: "
                             f"{h['amplitude_um'] * f:.3f} ± {h['amplitude_sd_um'] * f:.3f} {u}, "
                             f"phase {h['phase_deg']:.1f} ± {h['phase_sd_deg']:.1f}°")
            if c["harmonics"] == 0:
                lines.append(f"{name}:   no cyclic error found: the file adds nothing")
            if "note" in c:
                lines.append(f"{name}: note: {c['note']}")
        if "table" in entry:
            net = ", net of the cyclic term" if entry.get("net_of_cyclic") else ""
            lines.append(f"{name}: {verb} {entry['table']} ({entry['mode']}, "
                         f"{entry['points']} points{', folded' if entry['folded'] else ''}"
                         f"{net})")
        if "reversal" in entry:
            rv = entry["reversal"]
            why = "" if rv["ratio"] != rv["ratio"] else (
                f": a curve misses the points' reversals by {rv['ratio']:.2f}× what the "
                f"readings' scatter ({rv['scatter_um']:.2f} µm) alone leaves")
            how = "per point" if rv["per_point"] else (
                f"smoothed ({rv['edf']:.1f} parameters)" if rv.get("smoothed") else "as a curve")
            lines.append(f"{name}: reversal {how}{why}")
        if "smoothed" in entry:
            sm = entry["smoothed"]
            lines.append(f"{name}: smoothed by its own leave-one-out: its points moved "
                         f"{sm['change_rms_um']:.3f} µm RMS (at most {sm['cap_um']:.3f}, "
                         "a point's standard error)")
        if "linkage" in entry:
            lk = entry["linkage"]
            fitted = ", ".join(f"{k} {lk['values'][k]:.6g}" for k in lk["fitted"])
            lines.append(f"{name}: {verb} {lk['file']} (linkage: {fitted}; residual RMS "
                         f"{lk['rms_deg']:.6f} deg, max {lk['max_deg']:.6f} deg; drawing's "
                         f"values {lk['drawing_rms_deg']:.6f} deg); the table holds the rest")
        if "interpolation_cv" in entry:
            cv = entry["interpolation_cv"]
            scores = ", ".join(f"{k} {v:.3f}" for k, v in cv["loo_rms_arcsec"].items())
            line = (f"{name}: interpolation by leave-one-out: {cv['best']} (RMS arcsec: "
                    f"{scores})")
            if cv["best"] != cv["configured"]:
                line += f"; set axes.{name}.compensation.pitch.interpolation: {cv['best']}"
            lines.append(line)
        if "backlash_mm" in entry:
            lines.append(f"{name}: set axes.{name}.compensation.backlash_mm: "
                         f"{entry['backlash_mm']:.6g}")  # fmt: skip
        if "backlash_um" in entry:
            lines.append(f"{name}: backlash (seed 000) {entry['backlash_um']:.2f} µm")
        if "backlash_arcsec" in entry:
            lines.append(f"{name}: backlash (seed 000) {entry['backlash_arcsec']:.2f} arcsec "
                         f"({entry['backlash_arcsec'] / 3600:.6f} deg)")
        if "takeup" in entry:
            t = entry["takeup"]
            if t["config"] is None:
                lines.append(f"{name}: take-up: keep the switch ({t['why']})")
            else:
                c = t["config"]
                lines.append(f"{name}: take-up: {t['why']}; set axes.{name}.compensation.takeup: "
                             f"{{reversal_um: {c['reversal_um']}, fraction: {c['fraction']}}}")
        if "thermal" in entry:
            t = entry["thermal"]
            lines.append(f"{name}: thermal length_mm {t['length_mm']:.1f} (set axes.{name}."
                         f"compensation.thermal.length_mm), growth {t['growth_max_um']:.1f} µm, "
                         f"residual RMS {t['residual_rms_um']:.2f} µm")  # fmt: skip
    return "\n".join(lines)


def _fit_takeup(path: str, places: dict[str, Any], report: dict[str, Any]) -> None:
    """The take-up curve of each axis of a ``--takeup`` run, against the lost motion its
    ``--backlash`` run (in the same call) read at the same places."""
    from .fitting.takeup_fit import fit_takeup_raw
    from .plans.rawdata import read_raw_csv

    raw = read_raw_csv(path)
    for a in raw.axes:
        if a not in places:
            raise TableError(f"{path}: axis {a}: fit the take-up ladder together with the "
                             f"axis's --backlash run (its lost motion at the same places)")
        fit = fit_takeup_raw(raw, a, places[a])
        report.setdefault(a, {})["takeup"] = {"config": fit.config(), "why": fit.why,
                                              "lost_um": fit.lost_um, "miss_um": fit.miss_um}


def add_parser(sub: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    p = sub.add_parser("fit", help="calibration: raw data → tables the config references")
    p.add_argument("raw", nargs="+", help="raw CSV files (kind from their '# kind:' line)")
    p.add_argument("-c", "--config", required=True, help="gateway YAML config")
    p.add_argument("--mode", choices=["auto", "bidirectional", "unidirectional"], default="auto",
                   help="pitch tables (auto: unidirectional if the axis has backlash_mm)")
    p.add_argument("--reversal", choices=["auto", "smooth", "per-point"], default="auto",
                   help="bidirectional tables: reversal as a polynomial in position (both "
                        "directions' readings serve every point), per point (a worn zone), or "
                        "whichever of those or a curve through the points between them the "
                        "readings' own scatter says predicts best (auto, Mallows' Cp)")
    p.add_argument("--reversal-degree", type=int, default=2)
    p.add_argument("--smooth", action="store_true",
                   help="bidirectional identification tables: smoothed by their own "
                        "leave-one-out, each point moved by no more than its standard error "
                        "(the runs' scatter over √runs), as compgw commission does")
    p.add_argument("--planar-model", choices=["auto", "grid", "poly"], default="auto")
    p.add_argument("--pitch-line", dest="pitch_lines", action="append", metavar="A@B=MM",
                   help="X@Y=0: X's table was measured with Y at 0; the planar model is "
                        "pinned to zero there, the pin fading within a grid step (repeat per "
                        "axis)")
    p.add_argument("--harmonics", type=int, metavar="K",
                   help="cyclic runs: fit K harmonics (default: 0..4 by cross-validation)")
    p.add_argument("--residual", action="store_true",
                   help="fold into the current tables (automatic for '# compensation: on')")
    p.add_argument("--dry-run", action="store_true", help="fit and check, write nothing")
    p.add_argument("--json", action="store_true")
    p.set_defaults(func=fit)


# -- report / export ----------------------------------------------------------------------------
