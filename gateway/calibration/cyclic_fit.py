"""Identify the cyclic screw error from short dense scans (issue 7), and net it out of tables.

A dense scan measures the deviation every ≤ lead/16 over ≥ 2 leads at a station, in both
directions. At each station the deviation is fitted by least squares as

    d(x) = c0 + c1·u + c2·u² + β·[direction is −] + Σ_{k≤K} a_k sin(kθ) + b_k cos(kθ)

(a local trend that belongs to the coarse table and the backlash, plus the harmonics). The
number of harmonics K (0..3, the same at every station) is chosen by cross-validation with
the one-standard-error rule, so a machine without cyclic error gets K = 0 and nothing is
added. The coarse table is then taken net of the cyclic term at its targets, so nothing is
counted twice.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from ..compensation.cyclic import CyclicModel
from ..compensation.errors import TableError
from ..compensation.pitch import PitchTable

MAX_FIT_HARMONICS = 3
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


def dense_scan_targets(
    station_mm: float, lead_mm: float, *, per_lead: int = 16, leads: float = 2.0
) -> NDArray[np.float64]:
    """Targets of one dense scan centred on ``station_mm``: ``per_lead`` points per lead
    (≥ 16) over ``leads`` leads (≥ 2)."""
    if per_lead < 16 or leads < 2:
        raise TableError("a dense scan needs ≥ 16 points per lead over ≥ 2 leads")
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


def net_of_cyclic(table: PitchTable, model: CyclicModel | None) -> PitchTable:
    """The coarse table with the cyclic term at its targets taken out (the joint fit)."""
    if model is None:
        return table
    cyc = model.error_mm(table.position_mm)
    reverse = None if table.reverse_mm is None else table.reverse_mm - cyc
    return PitchTable(
        table.position_mm,
        table.forward_mm - cyc,
        reverse,
        rotary=table.rotary,
        source=table.source,
        lines=table.lines,
    )
