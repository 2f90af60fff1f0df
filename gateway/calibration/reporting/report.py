"""`compgw report`: ISO 230-2 figures, plots and one self-contained HTML file.

``compgw report RAW.csv [--before RAW0.csv] [--out DIR] [--json]``

- axis runs (ISO 230-2 plans): per axis the figures A, B, B̄, E↑, E↓, E, M, R↑, R↓, R (µm),
  before and after when ``--before`` is given, the per-target table (x̄↑, x̄↓, s↑, s↓, Bi,
  Ri), and a plot of the deviation against position for both directions with ±2s bands;
- XY runs (``x_mm``, ``y_mm`` columns): max and RMS vector error and the error field as
  arrows (before and after);
- cyclic runs (``# kind: cyclic``, the dense scans of ``compgw calibrate --cyclic``): the
  harmonics fitted as ``compgw fit`` fits them (K by cross-validation, or ``--harmonics``),
  per station the amplitude A = √(a² + b²) and phase φ = atan2(b, a) (the term is
  A·sin(kθ + φ)) with their standard uncertainties (propagated from those of a and b), and a
  plot of the scans (deviation minus the fitted local trend and backlash step, both
  directions) with the fitted curve;
- rotary axes (the raw file's ``# unit: deg``, which ``compgw calibrate`` writes for them,
  or ``--unit deg``): targets in degrees, figures in arcseconds and degrees;
- ``DIR/report.html`` (PNGs embedded as base64: one file to mail) and ``DIR/*.png``.

``--json`` prints ``{"X": {"A_um": …, "B_um": …, …}}`` (:func:`..fitting.iso230.report_json`) of
RAW.csv (cyclic runs: ``{"X": {"cyclic": {"harmonics": K, "stations": [{"station_mm", "k",
"amplitude_um", "amplitude_sd_um", "phase_deg", "phase_sd_deg", …}]}}}``) and writes nothing
unless ``--out`` is given too.
"""

from __future__ import annotations

import argparse
import base64
import html
import io
import json
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ...compensation.errors import TableError
from ..fitting.fit import planar_measurement
from ..fitting.iso230 import ARCSEC_PER_MDEG, JSON_KEYS, Iso230Result, iso230_raw, report_json
from ..plans.rawdata import RawData, axis_deviations, read_raw_csv
from ..plans.runner import read_raw_meta

LABELS = {
    "A_um": "A accuracy", "B_um": "B reversal", "Bmean_um": "B̄ mean reversal",
    "E_up_um": "E↑ systematic", "E_down_um": "E↓ systematic", "E_um": "E systematic",
    "M_um": "M mean bidirectional", "R_up_um": "R↑ repeatability",
    "R_down_um": "R↓ repeatability", "R_um": "R repeatability",
}  # fmt: skip


@dataclass(frozen=True)
class Units:
    """How figures are shown: µm over mm positions, or arcseconds (and degrees) over
    degree positions. ``per_um``: display units per "µm" of :mod:`..fitting.iso230` (1000 × the
    position unit)."""

    name: str
    position: str
    per_um: float
    angular: bool = False

    def cell(self, value_um: float | None, digits: int = 2, named: bool = False) -> str:
        """A figure (µm, or millidegrees shown in arcsec and degrees), with ``named`` its
        unit beside it: "1.23 µm", "61.30 arcsec (0.01703°)"."""
        if value_um is None:
            return "–"
        text = f"{value_um * self.per_um:.{digits}f}" + (f" {self.name}" if named else "")
        return f"{text} ({value_um / 1000:.5f}°)" if self.angular else text


LINEAR = Units("µm", "mm", 1.0)
ANGULAR = Units("arcsec", "deg", ARCSEC_PER_MDEG, angular=True)


def is_planar(raw: RawData) -> bool:
    return "x_mm" in raw.extra and "y_mm" in raw.extra


@dataclass
class Figure:
    name: str
    png: bytes
    caption: str


# -- plots (matplotlib, Agg) -----------------------------------------------------------------
def _subplots(rows: int, cols: int, figsize: tuple[float, float]):  # type: ignore[no-untyped-def]
    """A figure and its panels (2-D), without pyplot: no figure manager to keep or close,
    and the PNG rendered by Agg all the same (savefig picks it for the format)."""
    from matplotlib.figure import Figure as MplFigure

    fig = MplFigure(figsize=figsize)
    return fig, fig.subplots(rows, cols, squeeze=False)


def _png(fig) -> bytes:  # type: ignore[no-untyped-def]
    """The figure, laid out by tight_layout, as PNG bytes: one render. (tight_layout leaves
    a placeholder layout engine behind, and savefig would draw the whole figure once more,
    unrendered, for it before the render: the layout is done, so the engine goes.)"""
    fig.tight_layout()
    fig.set_layout_engine(None)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110)
    return buf.getvalue()


def plot_axis(axis: str, results: dict[str, tuple[RawData, Iso230Result]],
              units: Units = LINEAR) -> bytes:  # fmt: skip
    """Deviation vs position, both directions, ±2s bands; one panel per phase."""
    k = units.per_um
    fig, panels = _subplots(len(results), 1, figsize=(8, 3.2 * len(results)))
    for ax, (phase, (raw, iso)) in zip(panels[:, 0], results.items()):
        dev = axis_deviations(raw, axis)
        t = iso.target_mm
        for stats, runs, colour, label in ((iso.up, dev.up_mm, "tab:blue", "↑ (+)"),
                                           (iso.down, dev.down_mm, "tab:red", "↓ (−)")):
            if stats is None or runs is None:
                continue
            for j in range(runs.shape[1]):
                ax.plot(t, runs[:, j] * 1e3 * k, ".", color=colour, alpha=0.3, ms=3)
            ax.plot(t, stats.mean_um * k, "-", color=colour, label=f"x̄ {label}")
            ax.fill_between(t, (stats.mean_um - 2 * stats.s_um) * k,
                            (stats.mean_um + 2 * stats.s_um) * k,
                            color=colour, alpha=0.2, label=f"±2s {label}")  # fmt: skip
        ax.axhline(0, color="0.5", lw=0.5)
        ax.set_title(f"axis {axis}, {phase}: E {units.cell(iso.E_um, named=True)}, "
                     f"A {units.cell(iso.A_um, named=True)}")  # fmt: skip
        ax.set_xlabel(f"target position ({units.position})")
        ax.set_ylabel(f"deviation actual − target ({units.name})")
        ax.legend(fontsize=7, ncol=2)
        ax.grid(alpha=0.3)
    return _png(fig)


def plot_xy(results: dict[str, RawData], axes: tuple[str, str]) -> tuple[bytes, dict[str, Any]]:
    """XY error field as arrows (one panel per phase) and the vector figures per phase."""
    fig, panels = _subplots(1, len(results), figsize=(6.5 * len(results), 5))
    figures: dict[str, Any] = {}
    for ax, (phase, raw) in zip(panels[0], results.items()):
        meas = planar_measurement(raw, axes)
        err_um = meas.error_mm * 1e3
        norm = np.hypot(*err_um.T)
        figures[phase] = {"max_um": float(norm.max()), "rms_um": float(np.sqrt(np.mean(norm**2))),
                          "points": int(norm.size)}  # fmt: skip
        q = ax.quiver(meas.command_mm[:, 0], meas.command_mm[:, 1], err_um[:, 0], err_um[:, 1],
                      norm, cmap="viridis", angles="xy")  # fmt: skip
        fig.colorbar(q, ax=ax, label="vector error (µm)")
        ax.set_title(f"XY {phase}: max {norm.max():.2f} µm, RMS {figures[phase]['rms_um']:.2f} µm")
        ax.set_xlabel(f"{axes[0]} (mm)")
        ax.set_ylabel(f"{axes[1]} (mm)")
        ax.set_aspect("equal", adjustable="datalim")
    return _png(fig), figures


def _f(value: float | None, digits: int = 2) -> str:
    return "–" if value is None else f"{value:.{digits}f}"


def change_text(before: float, after: float) -> str:
    """"31 % less" (or "12 % more": a figure that grew says so) from ``before`` to
    ``after`` (magnitudes)."""
    pct = round(100 * (1 - abs(after) / abs(before)))
    return f"{pct} % less" if pct >= 0 else f"{-pct} % more"


# -- HTML ---------------------------------------------------------------------------------------
def _figures_table(axis: str, results: dict[str, Iso230Result], units: Units = LINEAR) -> str:
    phases = list(results)
    head = "".join(f"<th>{html.escape(p)}</th>" for p in phases)
    if len(phases) == 2:
        head += "<th>change</th>"
    rows = []
    for key in JSON_KEYS:
        vals = [getattr(r, key) for r in results.values()]
        cells = "".join(f"<td>{units.cell(v)}</td>" for v in vals)
        if len(vals) == 2:
            a, b = vals
            cut = "–" if not a or b is None else change_text(a, b)
            cells += f"<td>{cut}</td>"
        rows.append(f"<tr><th>{html.escape(LABELS[key])}</th>{cells}</tr>")
    return (f"<table class='fig' id='figures-{axis}'><tr><th>axis {axis} ({units.name})</th>"
            f"{head}</tr>"
            + "".join(rows) + "</table>")  # fmt: skip


def _target_table(axis: str, phase: str, iso: Iso230Result, units: Units = LINEAR) -> str:
    cols = ("target_mm", "mean_up_um", "mean_down_um", "s_up_um", "s_down_um", "B_i_um",
            "R_up_i_um", "R_down_i_um", "R_i_um")  # fmt: skip
    u = units.name
    names = (f"target {units.position}", f"x̄↑ {u}", f"x̄↓ {u}", f"s↑ {u}", f"s↓ {u}",
             f"Bi {u}", f"Ri↑ {u}", f"Ri↓ {u}", f"Ri {u}")  # fmt: skip

    def cell(c: str, v: float | None) -> str:
        return _f(v, 4 if units.angular else 3) if c == "target_mm" or v is None \
            else f"{v * units.per_um:.3f}"  # fmt: skip

    head = "".join(f"<th>{n}</th>" for n in names)
    body = "".join(
        "<tr>" + "".join(f"<td>{cell(c, row[c])}</td>" for c in cols) + "</tr>"
        for row in iso.per_target_rows()
    )
    return (f"<details><summary>axis {axis}, {html.escape(phase)}: per target</summary>"
            f"<table class='targets'><tr>{head}</tr>{body}</table></details>")  # fmt: skip


def _img(fig: Figure) -> str:
    data = base64.b64encode(fig.png).decode("ascii")
    return (f"<figure id='{fig.name}'><img alt='{html.escape(fig.caption)}' "
            f"src='data:image/png;base64,{data}'><figcaption>{html.escape(fig.caption)}"
            "</figcaption></figure>")  # fmt: skip


STYLE = """body{font-family:sans-serif;max-width:60em;margin:2em auto;color:#222}
table{border-collapse:collapse;margin:1em 0}td,th{border:1px solid #bbb;padding:2px 8px;
text-align:right}th{background:#eee}img{max-width:100%}figcaption{font-size:90%;color:#555}"""


#: Marks the body with how many figures decoded (a headless browser's DOM dump shows it).
LOADED_SCRIPT = ("window.addEventListener('load',function(){var n=0;"
                 "document.querySelectorAll('img').forEach(function(i){"
                 "if(i.complete&&i.naturalWidth>0){n++;}});"
                 "document.body.setAttribute('data-images-loaded',String(n));});")


def build_report(
    raw: RawData, before: RawData | None = None, title: str = "compgw calibration report",
    angular: bool = False,
) -> tuple[str, list[Figure], dict[str, Any]]:
    """HTML text, the figures, and the figures as data (µm; ``angular``, a rotary axis in
    degrees: arcseconds and degrees), from raw data (pure)."""
    units = ANGULAR if angular else LINEAR
    phases = {"before": before, "after": raw} if before is not None else {"run": raw}
    what = ("in arcseconds (and degrees) over targets in degrees" if angular else "in µm")
    parts = [f"<h1>{html.escape(title)}</h1>",
             f"<p>ISO 230-2 figures {what}; deviations are actual − target. Sources: "
             + ", ".join(html.escape(f"{k}: {v.source}") for k, v in phases.items() if v)
             + "</p>"]  # fmt: skip
    figures: list[Figure] = []
    data: dict[str, Any] = {}
    if is_planar(raw):
        axes = tuple(a for a in raw.axes)[:2]
        if len(axes) != 2:
            raise TableError(f"{raw.source}: an XY run needs two axes")
        png, xy = plot_xy({k: v for k, v in phases.items() if v is not None}, axes)  # type: ignore[arg-type]
        figures.append(Figure("xy-field", png, "XY error field (arrows: actual − commanded)"))
        data["XY"] = xy
        rows = "".join(f"<tr><th>{k}</th><td>{_f(v['max_um'])}</td><td>{_f(v['rms_um'])}</td>"
                       f"<td>{v['points']}</td></tr>" for k, v in xy.items())  # fmt: skip
        parts.append("<h2>XY plane</h2><table id='figures-XY'><tr><th></th><th>max µm</th>"
                     f"<th>RMS µm</th><th>points</th></tr>{rows}</table>")  # fmt: skip
        parts.append(_img(figures[-1]))
    else:
        iso = {k: iso230_raw(v) for k, v in phases.items() if v is not None}
        for axis in raw.axes:
            per = {k: r[axis] for k, r in iso.items() if axis in r}
            data[axis] = {k: r.to_json_dict(angular) for k, r in per.items()}
            parts.append(f"<h2>Axis {html.escape(axis)}</h2>")
            parts.append(_figures_table(axis, per, units))
            png = plot_axis(axis, {k: (phases[k], r) for k, r in per.items()}, units)  # type: ignore[misc]
            figures.append(Figure(f"axis-{axis}", png,
                                  f"axis {axis}: deviation vs position, both directions, ±2s"))
            parts.append(_img(figures[-1]))
            for k, r in per.items():
                parts.append(_target_table(axis, k, r, units))
    body = "\n".join(parts)
    text = (f"<!DOCTYPE html><html lang='en'><head><meta charset='utf-8'><title>"
            f"{html.escape(title)}</title><style>{STYLE}</style></head><body>{body}"
            f"<script>{LOADED_SCRIPT}</script></body></html>\n")  # fmt: skip
    return text, figures, data


# -- cyclic runs (issue 7) --------------------------------------------------------------------
def cyclic_results(
    raw: RawData, meta: dict[str, str], harmonics: int | None = None,
    lead_mm: float | None = None,
) -> dict[str, tuple[Any, list[Any], Any]]:  # fmt: skip
    """Per axis: (the fit, the station scans, the data for JSON), fitted as `compgw fit` does."""
    from ..fitting.cyclic_fit import fit_cyclic, harmonics_table, scans_from_raw
    from ..fitting.outputs import cyclic_meta

    if lead_mm is not None:
        meta = {**meta, "lead_mm": f"{lead_mm:g}"}
    lead, stations, origin = cyclic_meta(meta, raw.source)
    out = {}
    for axis in raw.axes:
        where, scans = scans_from_raw(raw, axis, lead, stations)
        fit = fit_cyclic(where, scans, lead, origin, harmonics)
        data = {
            "lead_mm": lead, "origin_mm": origin, "harmonics": fit.harmonics,
            "cv_rms_um": {str(k): v for k, v in fit.cv_rms_um.items()},
            "residual_rms_um": fit.residual_rms_um,
            "readings": int(sum(s.deviation_mm.size for s in scans)),
            "stations": [h.to_json_dict() for h in harmonics_table(fit)],
        }  # fmt: skip
        out[axis] = (fit, list(zip(where, scans)), data)
    return out


def plot_cyclic(axis: str, fit: Any, scans: list[Any], lead_mm: float, origin_mm: float,
                units: Units = LINEAR) -> bytes:  # fmt: skip
    """Per station: the scan minus the fitted local trend vs position, both directions,
    with the fitted cyclic curve."""
    from ..fitting.cyclic_fit import station_fit_curves

    small = 1e3 * units.per_um  # table units → µm or arcsec
    fig, panels = _subplots(len(scans), 1, figsize=(8, 2.6 * len(scans)))
    k = fit.harmonics
    for ax, (station, scan) in zip(panels[:, 0], scans):
        detrended, _ = station_fit_curves(scan, lead_mm, origin_mm, k)
        for sign, colour, label in ((1, "tab:blue", "↑ (+)"), (-1, "tab:red", "↓ (−)")):
            sel = scan.direction == sign
            ax.plot(scan.position_mm[sel], detrended[sel] * small, ".", color=colour, ms=4,
                    label=f"scan {label}")  # fmt: skip
        title = f"axis {axis}, station {station:g} {units.position}"
        if fit.model is not None:
            i = int(np.argmin(np.abs(fit.model.station_mm - station)))
            x = np.linspace(scan.position_mm.min(), scan.position_mm.max(), 400)
            theta = 2 * np.pi * (x - origin_mm) / lead_mm
            h = np.arange(1, k + 1)
            curve = (np.sin(theta[:, None] * h) @ fit.model.sin_mm[i]
                     + np.cos(theta[:, None] * h) @ fit.model.cos_mm[i])  # fmt: skip
            ax.plot(x, curve * small, "-", color="k", lw=1.2, label=f"fit ({k} harmonic(s))")
            amp = np.hypot(fit.model.sin_mm[i, 0], fit.model.cos_mm[i, 0]) * small
            title += f": first harmonic {amp:.2f} {units.name}"
        else:
            title += ": no cyclic error found (nothing added)"
        ax.axhline(0, color="0.5", lw=0.5)
        ax.set_title(title)
        ax.set_xlabel(f"target position ({units.position})")
        ax.set_ylabel(f"deviation − local trend ({units.name})")
        ax.legend(fontsize=7, ncol=3)
        ax.grid(alpha=0.3)
    return _png(fig)


def _cyclic_table(axis: str, data: dict[str, Any], units: Units = LINEAR) -> str:
    u, pos, f = units.name, units.position, units.per_um
    names = (f"station {pos}", "k", f"amplitude {u}", "phase °", f"sin a {u}", f"cos b {u}")
    head = "".join(f"<th>{n}</th>" for n in names)
    rows = "".join(
        f"<tr><td>{h['station_mm']:g}</td><td>{h['k']}</td>"
        f"<td>{h['amplitude_um'] * f:.3f} ± {h['amplitude_sd_um'] * f:.3f}</td>"
        f"<td>{h['phase_deg']:.1f} ± {h['phase_sd_deg']:.1f}</td>"
        f"<td>{h['sin_um'] * f:.3f} ± {h['sin_sd_um'] * f:.3f}</td>"
        f"<td>{h['cos_um'] * f:.3f} ± {h['cos_sd_um'] * f:.3f}</td></tr>"
        for h in data["stations"]
    )
    cv = ", ".join(f"K={k}: {v * f:.3f}" for k, v in data["cv_rms_um"].items())
    summary = (f"<p>lead {data['lead_mm']:g} {pos}, {data['readings']} readings; harmonics "
               f"chosen: {data['harmonics']} (cross-validated RMS {u} {cv}); residual RMS "
               f"{data['residual_rms_um'] * f:.3f} {u}. ± = one standard uncertainty; the term "
               "is A·sin(kθ + φ), θ = 2π·(x − origin)/lead.</p>")  # fmt: skip
    if not data["stations"]:
        return summary + "<p>No cyclic error found: the fit adds nothing.</p>"
    return (summary + f"<table class='fig' id='cyclic-{axis}-harmonics'><tr>{head}</tr>"
            f"{rows}</table>")  # fmt: skip


def build_cyclic_report(
    raw: RawData, meta: dict[str, str], title: str = "compgw calibration report",
    harmonics: int | None = None, lead_mm: float | None = None, angular: bool = False,
) -> tuple[str, list[Figure], dict[str, Any]]:  # fmt: skip
    """The report of a cyclic run: harmonics table and scan plot per axis (pure); a rotary
    axis's (``angular``: a worm's period in degrees) in arcseconds, its data keyed so."""
    units = ANGULAR if angular else LINEAR
    parts = [f"<h1>{html.escape(title)}</h1>",
             f"<p>Cyclic (once-per-lead) screw error from dense scans. Source: "
             f"{html.escape(raw.source)}</p>"]  # fmt: skip
    figures: list[Figure] = []
    data: dict[str, Any] = {}
    for axis, (fit, scans, d) in cyclic_results(raw, meta, harmonics, lead_mm).items():
        data[axis] = {"cyclic": _in_arcsec(d) if angular else d}
        parts.append(f"<h2>Axis {html.escape(axis)}: cyclic error</h2>")
        parts.append(_cyclic_table(axis, d, units))
        png = plot_cyclic(axis, fit, scans, d["lead_mm"], d["origin_mm"], units)
        figures.append(Figure(f"cyclic-{axis}", png, f"axis {axis}: dense scans minus the "
                              "fitted local trend, both directions, with the fitted curve"))
        parts.append(_img(figures[-1]))
    return _page(title, "\n".join(parts)), figures, data


def _in_arcsec(value: Any) -> Any:
    """A rotary axis's cyclic data: ``*_um`` (millidegrees) as ``*_arcsec``, ``*_mm``
    positions as ``*_deg``."""
    if isinstance(value, list):
        return [_in_arcsec(v) for v in value]
    if not isinstance(value, dict):
        return value
    out: dict[str, Any] = {}
    for key, v in value.items():
        if key.endswith("_um"):
            out[key[:-3] + "_arcsec"] = ({k: x * ARCSEC_PER_MDEG for k, x in v.items()}
                                         if isinstance(v, dict) else v * ARCSEC_PER_MDEG)
        elif key.endswith("_mm"):
            out[key[:-3] + "_deg"] = v
        else:
            out[key] = _in_arcsec(v)
    return out


def _page(title: str, body: str) -> str:
    return (f"<!DOCTYPE html><html lang='en'><head><meta charset='utf-8'><title>"
            f"{html.escape(title)}</title><style>{STYLE}</style></head><body>{body}"
            f"<script>{LOADED_SCRIPT}</script></body></html>\n")  # fmt: skip


def write_report(out_dir: Path, text: str, figures: list[Figure]) -> Path:
    from ...formats import atomic_write_text

    out_dir.mkdir(parents=True, exist_ok=True)
    for fig in figures:
        tmp = out_dir / f".{fig.name}.png.tmp"
        tmp.write_bytes(fig.png)
        tmp.replace(out_dir / f"{fig.name}.png")
    path = out_dir / "report.html"
    atomic_write_text(path, text)
    return path


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("raw", help="raw CSV (after, or the only run)")
    p.add_argument("--before", metavar="RAW0", help="raw CSV of the same test before")
    p.add_argument("--out", metavar="DIR", help="where report.html and the PNGs go (report/)")
    p.add_argument("--json", action="store_true", help="print the ISO 230-2 figures as JSON")
    p.add_argument("--title", default="compgw calibration report")
    p.add_argument("--harmonics", type=int, metavar="K",
                   help="cyclic runs: K harmonics (default: by cross-validation, as fit)")
    p.add_argument("--lead-mm", type=float, help="cyclic runs: the lead, if the file lacks it")
    p.add_argument("--unit", choices=["mm", "deg"],
                   help="positions in mm (µm figures) or deg (arcsec and degrees); default: "
                        "the raw file's '# unit:' line, else mm")  # fmt: skip


def _other_targets(before: RawData, after: RawData) -> str:
    """How the targets of two runs differ, per axis (nothing when each axis was read at
    the same targets, to 1 µm)."""
    def targets(raw: RawData, axis: str) -> set[float]:
        mask = np.asarray(raw.axis) == axis
        return set(np.round(raw.target_mm[mask], 3).tolist())

    out = []
    for axis in after.axes:
        a, b = targets(after, axis), targets(before, axis)
        if a != b:
            out.append(f"axis {axis}: {len(a - b)} of {len(a)} targets not in the before-run")
    return "; ".join(out)


def main(args: argparse.Namespace) -> int:
    try:
        raw = read_raw_csv(args.raw)
        meta = read_raw_meta(args.raw)
        if meta.get("kind") == "cyclic":
            if args.before:
                raise TableError("--before: a cyclic run is reported on its own")
            angular = (args.unit or meta.get("unit", "mm")) == "deg"
            text, figures, data = build_cyclic_report(raw, meta, args.title, args.harmonics,
                                                      args.lead_mm, angular)  # fmt: skip
            if args.json:
                print(json.dumps(data))
                if not args.out:
                    return 0
            path = write_report(Path(args.out or "report"), text, figures)
            if not args.json:
                print(f"report written to {path}")
            return 0
        before = read_raw_csv(args.before) if args.before else None
        if before is not None and not is_planar(raw):
            moved = _other_targets(before, raw)
            if moved:
                print(f"compgw report: warning: --before {args.before} was measured at other "
                      f"targets than {args.raw} ({moved}): not a before-and-after of the same "
                      "points", file=sys.stderr)  # fmt: skip
        angular = (args.unit or meta.get("unit", "mm")) == "deg"
        if args.json:
            if is_planar(raw):
                _, _, data = build_report(raw, before, args.title)
                print(json.dumps(data))
            else:
                print(json.dumps(report_json(raw, angular)))
            if not args.out:
                return 0
        text, figures, _ = build_report(raw, before, args.title, angular)
        path = write_report(Path(args.out or "report"), text, figures)
    except TableError as exc:
        print(f"compgw report: {exc}", file=sys.stderr)
        return 1
    if not args.json:
        print(f"report written to {path}")
    return 0
