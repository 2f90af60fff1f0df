"""Identify the cyclic screw error from short dense scans (issue 7), and net it out of tables.

A dense scan measures the deviation every ≤ lead/16 over ≥ 2 leads at a station, in both
directions. At each station the deviation is fitted by least squares as

    d(x) = c0 + c1·u + c2·u² + β·[direction is −] + Σ_{k≤K} a_k sin(kθ) + b_k cos(kθ)

(a local trend that belongs to the coarse table and the backlash, plus the harmonics). The
number of harmonics K (0..4, the same at every station) is chosen by cross-validation with
the one-standard-error rule, so a machine without cyclic error gets K = 0 and nothing is
added. The coarse table is then taken net of the cyclic term at its targets, so nothing is
counted twice.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from ...compensation.cyclic import CyclicModel
from ...compensation.errors import TableError
from ...compensation.pitch import PitchTable
from ..plans.rawdata import RawData

#: the most harmonics a fit tries: a scan's 16 readings a lead resolve 7; the random rough
#: screws carry up to 4 (at 3 their fourth stayed in the tables: rough-6's Y, lead 5 mm,
#: 7.9 µm of range left along its travel on the quiet machine, 7.2 at 4)
MAX_FIT_HARMONICS = 4
FOLDS = 8


@dataclass(frozen=True)
class StationScan:
    """One dense scan: positions (mm), deviations actual − commanded (mm), directions ±1."""

    position_mm: NDArray[np.float64]
    deviation_mm: NDArray[np.float64]
    direction: NDArray[np.int64]


@dataclass(frozen=True)
class CyclicFit:
    model: CyclicModel | None  # None: no cyclic error found (K = 0)
    harmonics: int
    cv_rms_um: dict[int, float]  # cross-validated RMS per K (all stations pooled)
    sd_mm: tuple[NDArray[np.float64], NDArray[np.float64]] | None  # standard uncertainties
    residual_rms_um: float  # at the chosen K


#: the fewest points per lead a dense scan reads (``compgw plan cyclic --per-lead``)
DENSE_LEAST_PER_LEAD = 16


def dense_scan_targets(
    station_mm: float,
    lead_mm: float,
    *,
    per_lead: int = 16,
    leads: float = 2.0,
    least_per_lead: int = DENSE_LEAST_PER_LEAD,
) -> NDArray[np.float64]:
    """Targets of one dense scan centred on ``station_mm``: ``per_lead`` points per lead
    (≥ ``least_per_lead``) over ``leads`` leads (≥ 2)."""
    if per_lead < least_per_lead or leads < 2:
        raise TableError(f"a dense scan needs ≥ {least_per_lead} points per lead over ≥ 2 "
                         "leads")  # fmt: skip
    n = round(per_lead * leads) + 1
    half = 0.5 * leads * lead_mm
    return np.linspace(station_mm - half, station_mm + half, n)


def _design(scan: StationScan, lead_mm: float, origin_mm: float, k: int) -> NDArray[np.float64]:
    x = scan.position_mm
    u = (x - x.mean()) / max(np.ptp(x), 1e-9)
    theta = 2 * np.pi * (x - origin_mm) / lead_mm
    cols = [np.ones_like(x), u, u**2]
    if np.any(scan.direction < 0) and np.any(scan.direction > 0):
        cols.append((scan.direction < 0).astype(np.float64))
    for h in range(1, k + 1):
        cols += [np.sin(h * theta), np.cos(h * theta)]
    return np.column_stack(cols)


def _harmonic_columns(a: NDArray[np.float64], k: int) -> slice:
    return slice(a.shape[1] - 2 * k, a.shape[1])


def _cv_rms(scans: list[StationScan], lead_mm: float, origin_mm: float, k: int) -> float:
    """Pooled k-fold (interleaved folds) prediction RMS of the station fits."""
    errors = []
    for scan in scans:
        a = _design(scan, lead_mm, origin_mm, k)
        d = scan.deviation_mm
        idx = np.arange(d.size)
        for fold in range(FOLDS):
            test = idx % FOLDS == fold
            coef, *_ = np.linalg.lstsq(a[~test], d[~test], rcond=None)
            errors.append(d[test] - a[test] @ coef)
    e = np.concatenate(errors)
    return float(np.sqrt(np.mean(e**2)))


def fit_cyclic(
    stations_mm: list[float],
    scans: list[StationScan],
    lead_mm: float,
    origin_mm: float = 0.0,
    harmonics: int | None = None,
) -> CyclicFit:
    """Fit the cyclic term at each station; K by cross-validation unless given."""
    if len(stations_mm) != len(scans) or not scans:
        raise TableError("one dense scan per station is needed")
    for scan in scans:
        if np.ptp(scan.position_mm) < 2 * lead_mm * 0.99:
            raise TableError("each dense scan must span at least two leads")
    candidates = [harmonics] if harmonics is not None else list(range(MAX_FIT_HARMONICS + 1))
    cv = {k: _cv_rms(scans, lead_mm, origin_mm, k) for k in candidates}
    if harmonics is None:
        # one-standard-error rule: the smallest K whose CV RMS is within the noise of the best
        best = min(cv, key=cv.get)  # type: ignore[arg-type]
        n = sum(s.deviation_mm.size for s in scans)
        tolerance = cv[best] * (1 + 1 / np.sqrt(2 * n))
        chosen = min(k for k in cv if cv[k] <= tolerance)
    else:
        chosen = harmonics
    residuals = []
    if chosen == 0:
        for scan in scans:
            a = _design(scan, lead_mm, origin_mm, 0)
            coef, *_ = np.linalg.lstsq(a, scan.deviation_mm, rcond=None)
            residuals.append(scan.deviation_mm - a @ coef)
        rms = float(np.sqrt(np.mean(np.concatenate(residuals) ** 2)) * 1e3)
        return CyclicFit(None, 0, {k: v * 1e3 for k, v in cv.items()}, None, rms)
    sin = np.zeros((len(scans), chosen))
    cos = np.zeros((len(scans), chosen))
    sin_sd = np.zeros_like(sin)
    cos_sd = np.zeros_like(cos)
    for i, scan in enumerate(scans):
        a = _design(scan, lead_mm, origin_mm, chosen)
        d = scan.deviation_mm
        coef, *_ = np.linalg.lstsq(a, d, rcond=None)
        resid = d - a @ coef
        residuals.append(resid)
        dof = max(d.size - a.shape[1], 1)
        cov = np.linalg.pinv(a.T @ a) * (resid @ resid / dof)
        cols = _harmonic_columns(a, chosen)
        h = coef[cols]
        sd = np.sqrt(np.diag(cov)[cols])
        sin[i], cos[i] = h[0::2], h[1::2]
        sin_sd[i], cos_sd[i] = sd[0::2], sd[1::2]
    order = np.argsort(stations_mm)
    model = CyclicModel(
        lead_mm,
        np.asarray(stations_mm, dtype=np.float64)[order],
        sin[order],
        cos[order],
        origin_mm,
        source="fitted",
    )
    rms = float(np.sqrt(np.mean(np.concatenate(residuals) ** 2)) * 1e3)
    return CyclicFit(
        model, chosen, {k: v * 1e3 for k, v in cv.items()}, (sin_sd[order], cos_sd[order]), rms
    )


def net_of_cyclic(
    table: PitchTable, model: CyclicModel | None, period_mm: float | None = None
) -> PitchTable:
    """The coarse table with the cyclic term at its targets taken out (the joint fit);
    ``period_mm``: a turntable's (amplitudes interpolated around the circle, as its stage)."""
    if model is None:
        return table
    cyc = model.error_mm(table.position_mm, period_mm)
    reverse = None if table.reverse_mm is None else table.reverse_mm - cyc
    return PitchTable(
        table.position_mm,
        table.forward_mm - cyc,
        reverse,
        rotary=table.rotary,
        source=table.source,
        lines=table.lines,
    )


# -- from raw files, and what the report shows ----------------------------------------------
def station_fit_curves(
    scan: StationScan, lead_mm: float, origin_mm: float, harmonics: int
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The scan's deviations minus the fitted local trend (and backlash step), and the
    fitted cyclic term at the same positions (mm), for the report's plot."""
    a = _design(scan, lead_mm, origin_mm, harmonics)
    coef, *_ = np.linalg.lstsq(a, scan.deviation_mm, rcond=None)
    cut = a.shape[1] - 2 * harmonics
    trend = a[:, :cut] @ coef[:cut]
    return scan.deviation_mm - trend, a[:, cut:] @ coef[cut:]


def scans_from_raw(
    raw: RawData, axis: str, lead_mm: float, stations_mm: list[float] | None = None
) -> tuple[list[float], list[StationScan]]:
    """The dense scans of ``axis`` in a raw file, grouped by station.

    With ``stations_mm`` (the plan's ``# stations_mm:`` line) the rows of run j are station
    j's (the cyclic plan numbers runs by station), or, if the runs do not say, each row goes
    to the nearest station; without, rows are split where consecutive targets are more than a
    lead apart, and each group's station is its centre.
    """
    rows = np.flatnonzero(np.array(raw.axis) == axis)
    if rows.size == 0:
        raise TableError(f"{raw.source}: no rows for axis {axis!r}")
    x = raw.target_mm[rows]
    if stations_mm:
        centres = np.asarray(stations_mm, dtype=np.float64)
        runs = raw.run[rows]
        if set(np.unique(runs).tolist()) <= set(range(1, centres.size + 1)):
            group = runs - 1
        else:
            group = np.argmin(np.abs(x[:, None] - centres[None, :]), axis=1)
    else:
        order = np.sort(np.unique(x))
        edges = order[np.flatnonzero(np.diff(order) > lead_mm)]
        group = np.searchsorted(edges, x, side="left")
        centres = np.array([0.5 * (x[group == g].min() + x[group == g].max())
                            for g in range(edges.size + 1)])  # fmt: skip
    stations, scans = [], []
    for g, centre in enumerate(centres):
        sel = rows[group == g]
        if sel.size == 0:
            continue
        stations.append(float(centre))
        scans.append(StationScan(raw.target_mm[sel], raw.deviation_mm[sel],
                                 raw.direction[sel].astype(np.int64)))  # fmt: skip
    return stations, scans


@dataclass(frozen=True)
class Harmonic:
    """One harmonic at one station: sin/cos amplitudes, magnitude and phase, with their
    standard uncertainties (µm, degrees)."""

    station_mm: float
    k: int
    sin_um: float
    cos_um: float
    sin_sd_um: float
    cos_sd_um: float

    @property
    def amplitude_um(self) -> float:
        return float(np.hypot(self.sin_um, self.cos_um))

    @property
    def amplitude_sd_um(self) -> float:
        """u(A) = √((a·u_a)² + (b·u_b)²)/A (first order; a, b nearly uncorrelated over whole
        leads); √(u_a² + u_b²)/√2 when A = 0."""
        amp = self.amplitude_um
        if amp == 0:
            return float(np.hypot(self.sin_sd_um, self.cos_sd_um) / np.sqrt(2))
        return float(np.hypot(self.sin_um * self.sin_sd_um, self.cos_um * self.cos_sd_um) / amp)

    @property
    def phase_deg(self) -> float:
        """φ = atan2(b, a): the term is A·sin(kθ + φ)."""
        return float(np.degrees(np.arctan2(self.cos_um, self.sin_um)))

    @property
    def phase_sd_deg(self) -> float:
        """u(φ) = √((a·u_b)² + (b·u_a)²)/A² (first order; 180° when A = 0)."""
        amp2 = self.sin_um**2 + self.cos_um**2
        if amp2 == 0:
            return 180.0
        rad = np.hypot(self.sin_um * self.cos_sd_um, self.cos_um * self.sin_sd_um) / amp2
        return float(min(180.0, np.degrees(rad)))

    def to_json_dict(self) -> dict[str, float]:
        return {
            "station_mm": self.station_mm, "k": self.k,
            "amplitude_um": self.amplitude_um, "amplitude_sd_um": self.amplitude_sd_um,
            "phase_deg": self.phase_deg, "phase_sd_deg": self.phase_sd_deg,
            "sin_um": self.sin_um, "cos_um": self.cos_um,
            "sin_sd_um": self.sin_sd_um, "cos_sd_um": self.cos_sd_um,
        }  # fmt: skip


def harmonics_table(fit: CyclicFit) -> list[Harmonic]:
    """Every fitted harmonic at every station (empty when nothing was fitted)."""
    if fit.model is None or fit.sd_mm is None:
        return []
    m, (sin_sd, cos_sd) = fit.model, fit.sd_mm
    return [
        Harmonic(float(m.station_mm[i]), k + 1, float(m.sin_mm[i, k] * 1e3),
                 float(m.cos_mm[i, k] * 1e3), float(sin_sd[i, k] * 1e3),
                 float(cos_sd[i, k] * 1e3))
        for i in range(m.station_mm.size)
        for k in range(m.harmonics)
    ]
