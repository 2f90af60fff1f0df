"""Fitted tables → the files a gateway config references, checked before anything is written.

A pitch table goes to ``axes.<A>.compensation.pitch`` (its ``format``: compgw CSV or
LinuxCNC 0/1); the cyclic term to ``axes.<A>.compensation.cyclic`` (YAML, with the standard
uncertainties); the planar model to ``planar.model`` (YAML) and the points CSV it names
(``xy_points.csv`` beside it when new). Every file is written atomically, and only after
the table passed the checks the gateway applies when it loads it (monotone map, every
correction within ``max_correction_mm``, the planar field's slope): a table that fails is
not written, and the error names the file and the point.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import yaml

from ...compensation import GridModel, PitchStage, PitchTable, PlanarMeasurement, PlanarStage
from ...compensation.cyclic import CyclicModel, CyclicStage
from ...compensation.errors import CompensationError, TableError
from ...config import GatewayConfig, PitchFile
from ...config_types import read_yaml
from ...formats import (
    atomic_write_text,
    read_cyclic,
    read_linkage,
    read_linuxcnc,
    read_pitch_csv,
    write_cyclic,
    write_linkage,
    write_linuxcnc,
    write_pitch_csv,
    write_planar_csv,
)
from ...formats.planar_file import load_planar_model
from ..plans.rawdata import RawData, axis_deviations
from .cyclic_fit import CyclicFit, fit_cyclic, net_of_cyclic, scans_from_raw
from .fit import (
    TURN_DEG,
    ReversalChoice,
    as_axis_table,
    bidirectional_table,
    bidirectional_table_reversal,
    bidirectional_table_smooth_reversal,
    choose_reversal,
    fold_backlash,
    fold_residual,
    one_way_split,
    unidirectional_table,
    with_one_way_points,
)
from .iso230 import iso230_axis
from .linkage_fit import LinkageFit, fit_linkage, mean_actual_deg, residual_deviations
from .models import PlanarChoice, choose_planar_model, pinned_measurement
from .table_cv import choose_interpolation


@dataclass(frozen=True, eq=False)
class PitchResult:
    """A fitted (or folded) table of one axis, where it goes, and the backlash to use."""

    axis: str
    path: Path
    table: PitchTable
    backlash_mm: float | None  # unidirectional mode: the backlash_mm to configure
    mode: str  # "bidirectional" or "unidirectional"
    folded: bool
    fmt: str = "csv"  # file format: csv, linuxcnc0, linuxcnc1
    #: a swing axis: the linkage fitted before the table (written with it), and its file
    linkage: LinkageFit | None = None
    linkage_path: Path | None = None
    #: rotary axes: the interpolation with the smallest leave-one-out RMS, and the scores
    interpolation_cv: tuple[str, dict[str, float]] | None = None
    #: a bidirectional table's reversal: per point or a curve, and why
    reversal: ReversalChoice | None = None


def pitch_spec(config: GatewayConfig, axis: str) -> PitchFile | None:
    if axis not in config.axes:
        raise TableError(f"axis {axis!r} is not in the gateway config")
    return config.axes[axis].compensation.pitch_file


def pitch_path(config: GatewayConfig, config_dir: Path, axis: str) -> tuple[Path, str]:
    """Where the axis's table goes and its format (default ``<axis>_pitch.csv``, csv)."""
    spec = pitch_spec(config, axis)
    if spec is None:
        return config_dir / f"{axis.lower()}_pitch.csv", "csv"
    return config_dir / spec.file, spec.format


def read_table(path: Path, fmt: str) -> PitchTable:
    return read_pitch_csv(path) if fmt == "csv" else read_linuxcnc(path, int(fmt[-1]))


def check_pitch(table: PitchTable, config: GatewayConfig, axis: str) -> None:
    """The gateway's load checks: monotone map with its interpolation, and the cap."""
    spec = pitch_spec(config, axis) or PitchFile(file=table.source)
    comp = config.axes[axis].compensation
    stage = PitchStage(table, spec.interpolation, spec.outside, spec.taper_mm,
                       config.axes[axis].wraps)  # fmt: skip
    stage.check_cap(comp.max_correction_mm)


def write_table(path: Path, fmt: str, table: PitchTable, comment: str = "") -> None:
    if fmt == "csv":
        write_pitch_csv(path, table, comment)
    else:
        write_linuxcnc(path, table, int(fmt[-1]))


def fit_pitch(
    raw: RawData,
    config: GatewayConfig,
    config_dir: Path,
    axis: str,
    *,
    mode: str = "auto",
    residual: bool = False,
    backlash_mm: float | None = None,
    reversal: str = "auto",
    reversal_degree: int = 2,
) -> PitchResult:
    """Table of ``axis`` from an identification run, or folded with a residual run.

    ``mode``: ``bidirectional``, ``unidirectional`` (mean table + backlash), or ``auto``
    (unidirectional when the config gives the axis a backlash_mm, else bidirectional).
    ``residual``: ``raw`` was measured with the current table applied (the calibration plan
    re-run with compensation on): the table is folded (seed 001). ``backlash_mm``: a value
    measured by the backlash plan, used instead of the ISO reversal B̄.
    ``reversal``: bidirectional tables take the reversal as a polynomial of
    ``reversal_degree`` in position (``smooth``,
    :func:`.fit.bidirectional_table_smooth_reversal`), ``per-point``, or whichever the
    readings' scatter says predicts better (``auto``, :func:`.fit.choose_reversal`).
    Rotary axes: the table in degrees (a turntable's modulo 360), its interpolation scored
    by cross-validation; a swing axis with ``compensation.linkage``: the linkage fitted first
    (from the file's values) and the table made of what it leaves.
    """
    path, fmt = pitch_path(config, config_dir, axis)
    ax = config.axes[axis]
    comp = ax.compensation
    if mode == "auto":
        mode = "unidirectional" if comp.backlash_mm > 0 else "bidirectional"
    if mode not in ("bidirectional", "unidirectional"):
        raise TableError(f"mode {mode!r} is not auto, bidirectional or unidirectional")
    dev = axis_deviations(raw, axis)
    link: LinkageFit | None = None
    link_path = config_dir / comp.linkage if comp.linkage is not None else None
    if link_path is not None and not residual:
        link = fit_linkage(dev.target_mm, mean_actual_deg(dev), read_linkage(link_path))
        dev = residual_deviations(dev, link.model)
    if residual:
        current = read_table(path, fmt)
        resid = bidirectional_table(dev) if dev.up_mm is not None and dev.down_mm is not None \
            else unidirectional_table(dev).table  # fmt: skip
        table = fold_residual(current, resid)
        lash = None
        if not table.bidirectional and resid.bidirectional:
            b_mean = float(np.mean(resid.forward_mm - resid.reverse_mm))
            lash = fold_backlash(comp.backlash_mm, b_mean)
        table = PitchTable(table.position_mm, table.forward_mm, table.reverse_mm,
                           table.rotary, str(path))  # fmt: skip
        kind = "bidirectional" if current.bidirectional else "unidirectional"
        result = PitchResult(axis, path, table, lash, kind, True, fmt)
    elif mode == "bidirectional":
        if reversal not in ("auto", "smooth", "per-point"):
            raise TableError(f"reversal {reversal!r} is not auto, smooth or per-point")
        dev, one_way = one_way_split(dev)  # points read one way: their reversal the table's
        choice = choose_reversal(dev, reversal_degree)
        if reversal != "auto":
            choice = replace(choice, per_point=reversal == "per-point", reversal_mm=None)
        if choice.per_point:
            table = bidirectional_table(dev, str(path))
        elif choice.reversal_mm is not None:  # smoothed between the two
            table = bidirectional_table_reversal(dev, choice.reversal_mm, str(path))
        else:
            table = bidirectional_table_smooth_reversal(dev, reversal_degree, str(path))
        if one_way is not None:
            table = with_one_way_points(table, one_way)
        result = PitchResult(axis, path, table, None, mode, False, fmt, reversal=choice)
    else:
        uni = unidirectional_table(dev, str(path))
        lash = backlash_mm if backlash_mm is not None else uni.backlash_mm
        result = PitchResult(axis, path, uni.table, lash, mode, False, fmt)
    if ax.rotary:
        table = as_axis_table(result.table, True, ax.wraps)
        cv = choose_interpolation(table, ax.wraps) if table.position_mm.size >= 5 else None
        result = replace(result, table=table, linkage=link, linkage_path=link_path,
                         interpolation_cv=cv)  # fmt: skip
    check_pitch(result.table, config, axis)
    return result


def save_pitch(result: PitchResult, comment: str = "") -> None:
    """Write the table (already checked by :func:`fit_pitch`) to its file, atomically; a
    fitted linkage first (the table is what it leaves)."""
    if result.linkage is not None and result.linkage_path is not None:
        fit = result.linkage
        note = (f"{comment}\nfitted {', '.join(fit.free)} to {fit.points} targets: residual "
                f"RMS {fit.rms_deg:.6f} deg (drawing's values: {fit.start_rms_deg:.6f} deg)")
        write_linkage(result.linkage_path, fit.model, note.strip())
    write_table(result.path, result.fmt, result.table, comment)


def residual_figures(raw: RawData, axis: str) -> dict[str, float | None]:
    """ISO 230-2 figures (µm) of a run, for the per-round lines of an iteration."""
    iso = iso230_axis(axis_deviations(raw, axis))
    return {"E_um": iso.E_um, "A_um": iso.A_um, "B_um": iso.B_um, "R_um": iso.R_um,
            "M_um": iso.M_um}  # fmt: skip


# -- planar -------------------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class PlanarResult:
    model_path: Path
    points_path: Path
    choice: PlanarChoice
    folded: bool


def planar_paths(config: GatewayConfig, config_dir: Path) -> tuple[Path, Path]:
    """The model YAML and the points CSV it names (``xy_points.csv`` beside it if new)."""
    if config.planar is None:
        raise TableError("the gateway config has no planar section (planar: {axes, model})")
    model = config_dir / config.planar.model
    points = model.parent / "xy_points.csv"
    if model.exists():
        spec = read_yaml(model, TableError)
        if isinstance(spec, dict) and "points" in spec:
            points = model.parent / str(spec["points"])
    return model, points


def fit_planar(
    meas: PlanarMeasurement,
    config: GatewayConfig,
    config_dir: Path,
    kind: str = "auto",
    residual: bool = False,
    pitch_lines: dict[str, float] | None = None,
) -> PlanarResult:
    """Choose and check the planar model; ``residual``: ``meas`` was taken with the current
    model on, and its errors are added to the current model's at the commanded points.
    ``pitch_lines`` (axis → where the other axis stood for that axis's table): the chosen
    model is pinned to zero there (:func:`.models.pinned_measurement`) and written as a
    cubic grid of its values."""
    model_path, points_path = planar_paths(config, config_dir)
    if residual:
        current = load_planar_model(model_path)
        err = current.error_mm(meas.command_mm) + meas.error_mm
        meas = PlanarMeasurement(meas.command_mm, meas.command_mm + err, meas.source)
    choice = choose_planar_model(meas, kind)
    assert config.planar is not None
    axes = tuple(config.planar.axes)
    if pitch_lines:
        xs, ys = (np.unique(choice.points.command_mm[:, k]) for k in range(2))
        pinned = pinned_measurement(choice.model, axes, pitch_lines, nodes=(xs, ys))  # type: ignore[arg-type]
        grid = GridModel.from_measurement(pinned)
        choice = replace(choice, model=grid, pinned=f"{choice.kind}"
                         f"{'' if choice.degree is None else f' degree {choice.degree}'}",
                         kind="grid", degree=None, points=pinned)  # fmt: skip
    try:
        stage = PlanarStage(choice.model, axes, source=str(model_path))  # type: ignore[arg-type]
    except CompensationError as exc:
        raise TableError(str(exc)) from None
    field = np.abs(stage.field_.values)
    for k, name in enumerate(axes):
        cap = config.axes[name].compensation.max_correction_mm
        worst = float(field[..., k].max())
        if worst > cap:
            j, i = np.unravel_index(int(np.argmax(field[..., k])), field.shape[:2])
            x, y = stage.field_.gx[i], stage.field_.gy[j]
            raise TableError(
                f"{model_path}: point ({x:g}, {y:g}) mm: {name} correction {worst:.6g} mm "
                f"exceeds max_correction_mm {cap:g}"
            )
    return PlanarResult(model_path, points_path, choice, residual)


def save_planar(result: PlanarResult, comment: str = "") -> None:
    """Write the points CSV, then the model YAML that references it."""
    choice = result.choice
    write_planar_csv(result.points_path, choice.points)
    same_dir = result.points_path.parent == result.model_path.parent
    rel = result.points_path.name if same_dir else str(result.points_path)
    spec: dict[str, object] = {"points": str(rel), "model": choice.kind}
    if choice.kind == "grid":
        spec["method"] = "cubic"
    else:
        spec["degree"] = int(choice.degree or 0)
    scores = ", ".join(f"{k} {v:.3f}" for k, v in choice.loo_rms_um.items())
    head = [f"# {line}" for line in comment.splitlines()]
    head.append(f"# chosen by leave-one-out cross-validation (RMS µm: {scores})")
    if choice.pinned:
        head.append(f"# the {choice.pinned} model pinned to zero along the pitch tables' "
                    "lines (fading within a grid step of them), as a cubic grid of its "
                    "values")  # fmt: skip
    head.append(f"# residual at the points: RMS {choice.residual_rms_um:.3f} µm, "
                f"max {choice.residual_max_um:.3f} µm")  # fmt: skip
    atomic_write_text(result.model_path, "\n".join(head) + "\n" + yaml.safe_dump(spec))


# -- cyclic screw error (issue 7) ----------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class CyclicResult:
    """The fitted cyclic term of one axis, where it goes, and how it was chosen."""

    axis: str
    path: Path
    fit: CyclicFit
    model: CyclicModel  # what is written (all zero when nothing was found)
    folded: bool


def cyclic_path(config: GatewayConfig, config_dir: Path, axis: str) -> Path:
    """``axes.<A>.compensation.cyclic``; refused when the config has none."""
    if axis not in config.axes:
        raise TableError(f"axis {axis!r} is not in the gateway config")
    name = config.axes[axis].compensation.cyclic
    if not name:
        raise TableError(f"axes.{axis}.compensation.cyclic is not set: no file to write the "
                         f"cyclic fit to (add e.g. cyclic: tables/{axis.lower()}_cyclic.yaml)")
    return config_dir / name


def fit_cyclic_raw(
    raw: RawData,
    meta: dict[str, str],
    config: GatewayConfig,
    config_dir: Path,
    axis: str,
    *,
    harmonics: int | None = None,
    residual: bool = False,
) -> CyclicResult:
    """The cyclic term of ``axis`` from a cyclic plan's raw file (lead and stations from its
    ``# lead_mm:``/``# stations_mm:`` lines), checked as the gateway checks it.

    ``residual``: the scans were measured with the current cyclic file applied; the fit is
    added to it (amplitudes of the current file interpolated at the new stations).
    """
    path = cyclic_path(config, config_dir, axis)
    lead, stations, origin = cyclic_meta(meta, raw.source, path)
    where, scans = scans_from_raw(raw, axis, lead, stations)
    fit = fit_cyclic(where, scans, lead, origin, harmonics)
    k = max(fit.harmonics, 1)
    st = np.asarray(where, dtype=np.float64)
    order = np.argsort(st)
    sin = np.zeros((st.size, k))
    cos = np.zeros((st.size, k))
    if fit.model is not None:
        sin, cos = fit.model.sin_mm.copy(), fit.model.cos_mm.copy()
    if residual:
        current = read_cyclic(path)
        a, b = current.amplitudes_mm(st[order])
        kk = max(k, current.harmonics)
        sin, cos = _pad(sin, kk), _pad(cos, kk)
        sin[:, : current.harmonics] += a
        cos[:, : current.harmonics] += b
    model = CyclicModel(lead, st[order], sin, cos, origin, source=str(path))
    check_cyclic(model, config, axis)
    return CyclicResult(axis, path, fit, model, residual)


def scanned_cyclic(raw: RawData, meta: dict[str, str], axis: str) -> CyclicModel | None:
    """The once-per-lead term of ``axis`` a cyclic plan's raw file reads, fitted as
    :func:`fit_cyclic_raw` fits it (no file beside it, unchecked); None where the scans show
    none. For what a coarse table's points read net of it."""
    lead, stations, origin = cyclic_meta(meta, raw.source)
    where, scans = scans_from_raw(raw, axis, lead, stations)
    return fit_cyclic(where, scans, lead, origin).model


def check_cyclic(model: CyclicModel, config: GatewayConfig, axis: str) -> None:
    """The gateway's load checks of a cyclic term: its stage builds, and the cap."""
    comp = config.axes[axis].compensation
    try:
        CyclicStage(model, config.axes[axis].travel_mm, TURN_DEG if config.axes[axis].wraps
                    else None)  # fmt: skip
    except CompensationError as exc:
        raise TableError(str(exc)) from None
    if model.peak_mm() > comp.max_correction_mm:
        raise TableError(f"{model.source}: cyclic peak {model.peak_mm():.6g} mm exceeds "
                         f"max_correction_mm {comp.max_correction_mm:g}")  # fmt: skip


def _pad(values: np.ndarray, k: int) -> np.ndarray:
    return np.pad(values, ((0, 0), (0, k - values.shape[1])))


def cyclic_meta(
    meta: dict[str, str], source: str, existing: Path | None = None
) -> tuple[float, list[float] | None, float]:
    """(lead_mm, stations_mm or None, origin_mm) from a raw file's meta lines; the lead and
    origin of an existing cyclic file when the raw file does not say."""
    try:
        stations = [float(v) for v in meta["stations_mm"].split()] if "stations_mm" in meta \
            else None  # fmt: skip
        if "lead_mm" in meta:
            return float(meta["lead_mm"]), stations, float(meta.get("origin_mm", 0.0))
    except ValueError:
        raise TableError(f"{source}: lead_mm/stations_mm/origin_mm lines are not numbers") \
            from None  # fmt: skip
    if existing is not None and existing.exists():
        current = read_cyclic(existing)
        return current.lead_mm, stations, current.origin_mm
    raise TableError(f"{source}: no '# lead_mm:' line (a cyclic plan's raw file has one)")


def save_cyclic(result: CyclicResult, comment: str = "") -> None:
    """Write the cyclic file atomically, with the standard uncertainties per station."""
    fit = result.fit
    extra: dict[str, object] = {
        "harmonics": fit.harmonics,
        "fitted": comment or "compgw fit",
        "cv_rms_um": {int(k): round(v, 4) for k, v in fit.cv_rms_um.items()},
        "residual_rms_um": round(fit.residual_rms_um, 4),
    }
    if result.folded:
        extra["folded"] = True
    sd = None
    if fit.sd_mm is not None and not result.folded:
        sd = fit.sd_mm
    elif fit.sd_mm is not None:  # folded: the uncertainty is the residual fit's
        k = result.model.harmonics
        sd = (_pad(fit.sd_mm[0], k), _pad(fit.sd_mm[1], k))
    write_cyclic(result.path, result.model, extra, sd)


def net_pitch(result: PitchResult, model: CyclicModel, config: GatewayConfig) -> PitchResult:
    """The joint fit: the pitch table net of the cyclic term at its targets, re-checked."""
    table = net_of_cyclic(result.table, model,
                          TURN_DEG if config.axes[result.axis].wraps else None)
    check_pitch(table, config, result.axis)
    return replace(result, table=table)
