"""Truth from data: measured curves along an axis, the screw's turn-by-turn lead variation,
the play's take-up on reversal, the XY error field on a grid. Pure numpy/scipy, no I/O
beyond reading the CSV files once.

Written from the data and the physics, independently of ``gateway.compensation`` (never
import it): curves are modified-Akima through the measured points (C1, no overshoot on flat
stretches), the XY field is a bicubic Hermite surface with slopes taken from neighbouring
nodes, the take-up is a hysteresis state between the two contact flanks of the nut.
"""

from __future__ import annotations

import bisect
import csv
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from sim.config_truth import (
    CurveTable,
    CyclicScrew,
    DeviationTable,
    LostMotionConfig,
    PlaneField,
    TakeUp,
)


def resolve(path: str, base_dir: str | Path) -> Path:
    """``path`` relative to the config file's directory unless absolute."""
    p = Path(path)
    return p if p.is_absolute() else Path(base_dir) / p


def read_columns(path: Path, columns: list[str]) -> dict[str, np.ndarray]:
    """Numeric columns of a CSV file (``#`` lines skipped); NaN where a cell is blank."""
    with path.open(newline="", encoding="utf-8") as fh:
        lines = [line for line in fh if not line.lstrip().startswith("#")]
    reader = csv.DictReader(lines)
    for col in columns:
        if reader.fieldnames is None or col not in reader.fieldnames:
            raise ValueError(f"{path}: no column {col!r}")
    out: dict[str, list[float]] = {c: [] for c in columns}
    for n, row in enumerate(reader, start=2):
        for col in columns:
            cell = (row[col] or "").strip()
            try:
                out[col].append(float(cell) if cell else math.nan)
            except ValueError:
                raise ValueError(f"{path}: line {n}: {col} {cell!r} is not a number") from None
    return {c: np.asarray(v, dtype=float) for c, v in out.items()}


class Curve:
    """y(x) through measured points, held constant beyond the first and last point."""

    def __init__(self, x: np.ndarray, y: np.ndarray, kind: str = "akima") -> None:
        good = np.isfinite(x) & np.isfinite(y)
        x, y = x[good], y[good]
        order = np.argsort(x)
        x, y = x[order], y[order]
        if x.size < 2:
            raise ValueError("needs at least 2 rows with both values")
        if np.any(np.diff(x) <= 0):
            raise ValueError("positions must all differ")
        self.x, self.y = x, y
        self._akima = None
        if kind == "akima" and x.size >= 3:
            # imported here: a sim without measured curves starts 0.8 s sooner without it
            from scipy.interpolate import Akima1DInterpolator

            self._akima = Akima1DInterpolator(x, y, method="makima")
            # its cubic pieces as plain floats: one position at a time (the drives', a
            # recording's 500 samples a second) evaluated without scipy's per-call cost
            self._breaks = [float(v) for v in self._akima.x]
            self._pieces = [[float(v) for v in row] for row in self._akima.c]

    def __call__(self, x: np.ndarray | float) -> np.ndarray:
        if isinstance(x, float):  # the drives' one position at a time: no array to clip
            xc: np.ndarray | float = min(max(x, float(self.x[0])), float(self.x[-1]))
            if self._akima is not None:
                return np.float64(self._one(xc))  # type: ignore[return-value]
        else:
            xc = np.clip(np.asarray(x, dtype=float), self.x[0], self.x[-1])
        if self._akima is None:
            return np.interp(xc, self.x, self.y)
        return np.asarray(self._akima(xc))

    def _one(self, x: float) -> float:
        """The Akima curve at one position, by Horner on its piece (as scipy's PPoly)."""
        b = self._breaks
        i = min(max(bisect.bisect_right(b, x) - 1, 0), len(b) - 2)
        d = x - b[i]
        c3, c2, c1, c0 = self._pieces
        return ((c3[i] * d + c2[i]) * d + c1[i]) * d + c0[i]


def load_deviation(cfg: DeviationTable, base_dir: str | Path) -> tuple[Curve, Curve | None]:
    """(forward, reverse or None) deviation curves in mm."""
    path = resolve(cfg.path, base_dir)
    cols = [cfg.position_column, cfg.forward_column]
    if cfg.reverse_column is not None:
        cols.append(cfg.reverse_column)
    data = read_columns(path, cols)
    x = data[cfg.position_column]
    scale = cfg.scale / 1000.0
    try:
        fwd = Curve(x, data[cfg.forward_column] * scale, cfg.interpolation)
        rev = (
            Curve(x, data[cfg.reverse_column] * scale, cfg.interpolation)
            if cfg.reverse_column is not None
            else None
        )
    except ValueError as err:
        raise ValueError(f"{path}: {err}") from None
    return fwd, rev


def load_curve(cfg: CurveTable, base_dir: str | Path) -> Curve:
    """A value (mm) along the travel."""
    path = resolve(cfg.path, base_dir)
    data = read_columns(path, [cfg.position_column, cfg.value_column])
    try:
        return Curve(data[cfg.position_column], data[cfg.value_column] * cfg.scale / 1000.0)
    except ValueError as err:
        raise ValueError(f"{path}: {err}") from None


class CyclicTruth:
    """Σ_k a_k(x) sin(2πk(x − origin)/lead + φ_k(x)), a and φ carried along the travel."""

    def __init__(self, cfg: CyclicScrew, base_dir: str | Path) -> None:
        path = resolve(cfg.path, base_dir)
        with path.open(newline="", encoding="utf-8") as fh:
            header = next(csv.reader(line for line in fh if not line.lstrip().startswith("#")))
        names = [h.strip() for h in header]
        ks = sorted(int(n[1:-3]) for n in names if n.startswith("a") and n.endswith("_um"))
        if not ks:
            raise ValueError(f"{path}: no harmonic columns (a1_um, phi1_deg, ...)")
        cols = ["position_mm"] + [c for k in ks for c in (f"a{k}_um", f"phi{k}_deg")]
        data = read_columns(path, cols)
        x = data["position_mm"]
        self.lead_mm, self.origin_mm = cfg.lead_mm, cfg.origin_mm
        self.terms: list[tuple[int, Curve, Curve]] = []
        try:
            for k in ks:
                amp = Curve(x, data[f"a{k}_um"] / 1000.0)
                phase = Curve(x, np.unwrap(np.deg2rad(data[f"phi{k}_deg"])))
                self.terms.append((k, amp, phase))
        except ValueError as err:
            raise ValueError(f"{path}: {err}") from None

    def error_mm(self, x_mm: np.ndarray | float) -> np.ndarray:
        """The turn-by-turn lead variation at x, mm."""
        if isinstance(x_mm, float):  # one position (a drive, a recording's sample)
            th = 2.0 * math.pi * (x_mm - self.origin_mm) / self.lead_mm
            return np.float64(sum(max(float(amp(x_mm)), 0.0) * math.sin(k * th + float(phase(x_mm)))
                                  for k, amp, phase in self.terms))  # type: ignore[return-value]
        x = np.asarray(x_mm, dtype=float)
        theta = 2.0 * np.pi * (x - self.origin_mm) / self.lead_mm
        out = np.zeros_like(x)
        for k, amp, phase in self.terms:
            out = out + np.maximum(amp(x), 0.0) * np.sin(k * theta + phase(x))
        return out


class TakeUpCurve:
    """The nut between its two flanks: state s = 0 after moving +, 1 after moving −.

    A reversal of r mm moves s along G(q), q = r/D (D the take-up distance): ``linear``
    G(q) = q (a dead band when D equals the play), ``smooth`` G(q) = 1 − (1 − q)² (soft
    engagement). The state carries over, so a partial reversal then a move back unwinds
    only what it took up (a hysteresis, not a switch).
    """

    def __init__(self, cfg: TakeUp) -> None:
        self.curve = cfg.curve
        self.factor = 1.0 if cfg.curve == "linear" else 2.0
        self.distance_mm = cfg.distance_um / 1000.0 if cfg.distance_um is not None else None

    def _g(self, q: float) -> float:
        q = min(max(q, 0.0), 1.0)
        return q if self.curve == "linear" else 1.0 - (1.0 - q) ** 2

    def _g_inv(self, s: float) -> float:
        s = min(max(s, 0.0), 1.0)
        return s if self.curve == "linear" else 1.0 - math.sqrt(1.0 - s)

    def distance(self, play_mm: float) -> float:
        """The reversal that takes up the whole play (mm)."""
        if self.distance_mm is not None:
            return self.distance_mm
        return max(self.factor * abs(play_mm), 1e-9)

    def after(self, s0: float, direction: int, r_mm: float, play_mm: float) -> float:
        """State after moving ``r_mm`` in ``direction`` from state ``s0``."""
        if direction == 0 or r_mm <= 0:
            return s0
        d = self.distance(play_mm)
        if direction < 0:
            return self._g(self._g_inv(s0) + r_mm / d)
        return 1.0 - self._g(self._g_inv(1.0 - s0) + r_mm / d)


@dataclass
class ScrewTruth:
    """Forward deviation (besides the parametric pitch) and lost motion of one axis, mm."""

    forward: Curve | None
    reverse: Curve | None
    lost_table: Curve | None
    lost_const_mm: float
    cyclic: CyclicTruth | None
    takeup: TakeUpCurve

    def forward_mm(self, m_mm: float) -> float:
        """Deviation approached moving +, from the data (parametric pitch not included)."""
        out = float(self.forward(m_mm)) if self.forward is not None else 0.0
        if self.cyclic is not None:
            out += float(self.cyclic.error_mm(m_mm))
        return out

    def lost_motion_mm(self, m_mm: float) -> float:
        """Reverse minus forward deviation with the play fully taken up."""
        if self.reverse is not None:
            assert self.forward is not None
            return float(self.reverse(m_mm) - self.forward(m_mm))
        out = self.lost_const_mm
        if self.lost_table is not None:
            out += float(self.lost_table(m_mm))
        return out

    def largest_play_mm(self, lo_mm: float, hi_mm: float) -> float:
        xs = np.linspace(lo_mm, hi_mm, 2001)
        return max(abs(self.lost_motion_mm(float(x))) for x in xs)


def load_screw(
    deviation: DeviationTable | None,
    lost_motion: LostMotionConfig | None,
    cyclic: CyclicScrew | None,
    backlash_um: float,
    base_dir: str | Path,
) -> ScrewTruth:
    """Read the data of one axis; ``backlash_um`` is the play when nothing else gives it."""
    fwd = rev = None
    if deviation is not None:
        fwd, rev = load_deviation(deviation, base_dir)
    lm = lost_motion or LostMotionConfig(um=backlash_um)
    table = load_curve(lm.table, base_dir) if lm.table is not None else None
    cyc = CyclicTruth(cyclic, base_dir) if cyclic is not None else None
    return ScrewTruth(fwd, rev, table, lm.um / 1000.0, cyc, TakeUpCurve(lm.takeup))


class XYField:
    """(ex, ey) in mm at any (x, y): C1 bicubic Hermite between grid nodes, edges held."""

    def __init__(self, cfg: PlaneField, base_dir: str | Path) -> None:
        path = resolve(cfg.path, base_dir)
        data = read_columns(path, [cfg.x_column, cfg.y_column, cfg.ex_column, cfg.ey_column])
        x, y = data[cfg.x_column], data[cfg.y_column]
        xs, ys = np.unique(x), np.unique(y)
        if xs.size < 2 or ys.size < 2 or x.size != xs.size * ys.size:
            raise ValueError(f"{path}: needs a full rectangular grid (every x with every y once)")
        ix, iy = np.searchsorted(xs, x), np.searchsorted(ys, y)
        if len(set(zip(ix.tolist(), iy.tolist()))) != x.size:
            raise ValueError(f"{path}: a grid node appears twice")
        self.xs, self.ys = xs, ys
        self.nodes: list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]] = []
        for col in (cfg.ex_column, cfg.ey_column):
            f = np.full((xs.size, ys.size), np.nan)
            f[ix, iy] = data[col] * cfg.scale / 1000.0
            if not np.all(np.isfinite(f)):
                raise ValueError(f"{path}: {col} has a blank cell")
            fx = np.gradient(f, xs, axis=0)
            fy = np.gradient(f, ys, axis=1)
            fxy = np.gradient(fx, ys, axis=1)
            self.nodes.append((f, fx, fy, fxy))

    @staticmethod
    def _basis(t: float, h: float) -> np.ndarray:
        t2, t3 = t * t, t * t * t
        return np.array(
            [2 * t3 - 3 * t2 + 1, -2 * t3 + 3 * t2, (t3 - 2 * t2 + t) * h, (t3 - t2) * h]
        )

    def error_mm(self, x_mm: float, y_mm: float) -> tuple[float, float]:
        """(ex, ey) at the table position (x, y), mm."""
        xs, ys = self.xs, self.ys
        x = min(max(x_mm, xs[0]), xs[-1])
        y = min(max(y_mm, ys[0]), ys[-1])
        i = min(int(np.searchsorted(xs, x, side="right")) - 1, xs.size - 2)
        j = min(int(np.searchsorted(ys, y, side="right")) - 1, ys.size - 2)
        hx, hy = xs[i + 1] - xs[i], ys[j + 1] - ys[j]
        bu = self._basis((x - xs[i]) / hx, hx)
        bv = self._basis((y - ys[j]) / hy, hy)
        out = []
        for f, fx, fy, fxy in self.nodes:
            m = np.array([
                [f[i, j], f[i, j + 1], fy[i, j], fy[i, j + 1]],
                [f[i + 1, j], f[i + 1, j + 1], fy[i + 1, j], fy[i + 1, j + 1]],
                [fx[i, j], fx[i, j + 1], fxy[i, j], fxy[i, j + 1]],
                [fx[i + 1, j], fx[i + 1, j + 1], fxy[i + 1, j], fxy[i + 1, j + 1]],
            ])  # fmt: skip
            out.append(float(bu @ m @ bv))
        return out[0], out[1]
