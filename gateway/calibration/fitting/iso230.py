"""ISO 230-2:2014 positioning accuracy and repeatability of a linear axis.

From the deviations ``x_ij = actual − target`` (mm) at targets i, runs j, approached in +
(↑) and − (↓), the standard's figures in µm (clause 3 definitions):

- x̄i↑, x̄i↓ mean unidirectional positional deviation; si↑, si↓ estimator of the standard
  uncertainty (sample standard deviation, n − 1);
- Bi = x̄i↑ − x̄i↓ reversal value; B = max |Bi|; B̄ = mean of Bi;
- Ri↑ = 4 si↑ (↓ likewise); Ri = max(2si↑ + 2si↓ + |Bi|, Ri↑, Ri↓); R↑ = max Ri↑, R = max Ri;
- E↑ = max x̄i↑ − min x̄i↑ (↓ likewise); E = max(x̄i↑, x̄i↓) − min(x̄i↑, x̄i↓) over all i;
- M = max x̄i − min x̄i with x̄i = (x̄i↑ + x̄i↓)/2;
- A↑ = max(x̄i↑ + 2si↑) − min(x̄i↑ − 2si↑) (↓ likewise);
  A = max(x̄i↑ + 2si↑, x̄i↓ + 2si↓) − min(x̄i↑ − 2si↑, x̄i↓ − 2si↓).

Rotary axes (ISO 230-2 clause 3 applies to them too): positions and deviations in degrees,
the "µm" figures are then millidegrees; :meth:`Iso230Result.to_json_dict` with ``angular``
gives them in arcseconds and degrees.

Missing measurements (NaN) are left out per target. With a single run s is undefined: it is
taken as 0 and ``s_defined`` is False. With one direction only, the figures that need both
(B, B̄, R, E, M, A) are ``None``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ...compensation.errors import TableError
from ..plans.rawdata import AxisDeviations, RawData, deviations_by_axis

UM_PER_MM = 1000.0
#: a rotary axis's figures: arcseconds per millidegree (the "µm" of a degree axis)
ARCSEC_PER_MDEG = 3.6
#: Keys of :meth:`Iso230Result.to_json_dict` that ``compgw report --json`` promises.
JSON_KEYS = (
    "A_um",
    "B_um",
    "Bmean_um",
    "E_up_um",
    "E_down_um",
    "E_um",
    "M_um",
    "R_up_um",
    "R_down_um",
    "R_um",
)


@dataclass(frozen=True, eq=False)
class DirectionStats:
    """Per-target statistics of one direction of approach (µm) and its axis figures."""

    mean_um: NDArray[np.float64]  # x̄i
    s_um: NDArray[np.float64]  # si (0 where fewer than 2 runs)
    n: NDArray[np.int64]  # runs measured at each target
    R_i_um: NDArray[np.float64]  # 4 si
    E_um: float
    R_um: float
    A_um: float

    @property
    def s_defined(self) -> bool:
        return bool(np.all(self.n >= 2))


def direction_stats(x_mm: NDArray[np.float64], label: str = "") -> DirectionStats:
    """Statistics of deviations ``x_mm[i, j]`` (mm; NaN = not measured) of one direction."""
    x_um = np.asarray(x_mm, dtype=np.float64) * UM_PER_MM
    if x_um.ndim != 2 or x_um.shape[0] < 1:
        raise TableError(f"{label}deviations must be an array [target, run]")
    n = np.sum(np.isfinite(x_um), axis=1)
    if np.any(n == 0):
        i = int(np.flatnonzero(n == 0)[0])
        raise TableError(f"{label}target {i + 1} has no measurement")
    mean = np.nanmean(x_um, axis=1)
    s = np.zeros_like(mean)
    many = n >= 2
    if many.any():
        s[many] = np.nanstd(x_um[many], axis=1, ddof=1)
    return DirectionStats(
        mean_um=mean,
        s_um=s,
        n=n.astype(np.int64),
        R_i_um=4.0 * s,
        E_um=float(mean.max() - mean.min()),
        R_um=float((4.0 * s).max()),
        A_um=float((mean + 2 * s).max() - (mean - 2 * s).min()),
    )


@dataclass(frozen=True, eq=False)
class Iso230Result:
    """ISO 230-2 per-target arrays and axis figures of one axis (µm)."""

    target_mm: NDArray[np.float64]
    up: DirectionStats | None
    down: DirectionStats | None
    mean_um: NDArray[np.float64] | None  # x̄i, bidirectional
    B_i_um: NDArray[np.float64] | None
    R_i_um: NDArray[np.float64] | None
    B_um: float | None
    Bmean_um: float | None
    E_um: float | None
    M_um: float | None
    R_um: float | None
    A_um: float | None

    @property
    def s_defined(self) -> bool:
        """False if some target has fewer than 2 runs (s taken as 0 there)."""
        return all(d.s_defined for d in (self.up, self.down) if d is not None)

    @property
    def runs(self) -> int:
        """Largest number of runs at any target and direction."""
        return int(max(d.n.max() for d in (self.up, self.down) if d is not None))

    def _dir(self, d: DirectionStats | None, name: str) -> float | None:
        return None if d is None else getattr(d, name)

    @property
    def E_up_um(self) -> float | None:
        return self._dir(self.up, "E_um")

    @property
    def E_down_um(self) -> float | None:
        return self._dir(self.down, "E_um")

    @property
    def R_up_um(self) -> float | None:
        return self._dir(self.up, "R_um")

    @property
    def R_down_um(self) -> float | None:
        return self._dir(self.down, "R_um")

    @property
    def A_up_um(self) -> float | None:
        return self._dir(self.up, "A_um")

    @property
    def A_down_um(self) -> float | None:
        return self._dir(self.down, "A_um")

    def to_json_dict(self, angular: bool = False) -> dict[str, Any]:
        """Axis figures for ``compgw report --json`` (µm; None where undefined); a rotary
        axis (``angular``) in arcseconds and degrees (``A_arcsec``, ``A_deg``, …)."""
        out: dict[str, Any] = {key: getattr(self, key) for key in JSON_KEYS}
        out.update(A_up_um=self.A_up_um, A_down_um=self.A_down_um)
        if angular:
            out = {f"{k[:-3]}_{unit}": None if v is None else v * scale
                   for k, v in out.items()
                   for unit, scale in (("arcsec", ARCSEC_PER_MDEG), ("deg", 1e-3))}  # fmt: skip
            out["unit"] = "deg"
        out.update(targets=int(self.target_mm.size), runs=self.runs, s_defined=self.s_defined)
        return out

    def per_target_rows(self) -> list[dict[str, float | None]]:
        """One dict per target (µm), for report tables."""

        def val(a: NDArray[np.float64] | None, i: int) -> float | None:
            return None if a is None else float(a[i])

        up, down = self.up, self.down
        return [
            {
                "target_mm": float(t),
                "mean_up_um": val(up.mean_um if up else None, i),
                "mean_down_um": val(down.mean_um if down else None, i),
                "s_up_um": val(up.s_um if up else None, i),
                "s_down_um": val(down.s_um if down else None, i),
                "mean_um": val(self.mean_um, i),
                "B_i_um": val(self.B_i_um, i),
                "R_up_i_um": val(up.R_i_um if up else None, i),
                "R_down_i_um": val(down.R_i_um if down else None, i),
                "R_i_um": val(self.R_i_um, i),
            }
            for i, t in enumerate(self.target_mm)
        ]


def iso230_2(
    target_mm: NDArray[np.float64],
    up_mm: NDArray[np.float64] | None,
    down_mm: NDArray[np.float64] | None,
    label: str = "",
) -> Iso230Result:
    """ISO 230-2 figures from deviations ``[target i, run j]`` (mm) approached in + and −."""
    target = np.asarray(target_mm, dtype=np.float64).reshape(-1)
    if up_mm is None and down_mm is None:
        raise TableError(f"{label}no deviations in either direction")
    stats = []
    for name, x in (("+", up_mm), ("-", down_mm)):
        if x is None:
            stats.append(None)
            continue
        x = np.asarray(x, dtype=np.float64)
        if x.ndim != 2 or x.shape[0] != target.size:
            raise TableError(
                f"{label}direction {name}: {x.shape} deviations for {target.size} targets"
            )
        stats.append(direction_stats(x, f"{label}direction {name}: "))
    up, down = stats
    if up is None or down is None:
        return Iso230Result(target, up, down, *([None] * 9))
    b_i = up.mean_um - down.mean_um
    r_i = np.maximum.reduce([2 * up.s_um + 2 * down.s_um + np.abs(b_i), up.R_i_um, down.R_i_um])
    both_means = np.concatenate([up.mean_um, down.mean_um])
    mean_i = 0.5 * (up.mean_um + down.mean_um)
    high = np.concatenate([up.mean_um + 2 * up.s_um, down.mean_um + 2 * down.s_um])
    low = np.concatenate([up.mean_um - 2 * up.s_um, down.mean_um - 2 * down.s_um])
    return Iso230Result(
        target_mm=target,
        up=up,
        down=down,
        mean_um=mean_i,
        B_i_um=b_i,
        R_i_um=r_i,
        B_um=float(np.abs(b_i).max()),
        Bmean_um=float(b_i.mean()),
        E_um=float(both_means.max() - both_means.min()),
        M_um=float(mean_i.max() - mean_i.min()),
        R_um=float(r_i.max()),
        A_um=float(high.max() - low.min()),
    )


def pooled_s_um(result: Iso230Result) -> float:
    """The scatter of one stop (µm), pooled over every target and direction: with few runs
    per target ISO's R, the largest of many per-target estimates, reads well above it (the
    commissioning's after-runs, 2 runs: R 2-5 µm on drives that scatter 0.2-0.45 µm)."""
    parts = [d for d in (result.up, result.down) if d is not None]
    s2 = [d.s_um[d.n >= 2] ** 2 for d in parts]
    values = np.concatenate(s2) if s2 else np.zeros(0)
    return float(np.sqrt(values.mean())) if values.size else 0.0


def iso230_axis(dev: AxisDeviations) -> Iso230Result:
    """ISO 230-2 figures of one axis from its arranged raw deviations."""
    return iso230_2(dev.target_mm, dev.up_mm, dev.down_mm, f"{dev.source}: axis {dev.axis}: ")


def iso230_raw(raw: RawData) -> dict[str, Iso230Result]:
    """ISO 230-2 figures of every axis in a raw-data file."""
    return {name: iso230_axis(dev) for name, dev in deviations_by_axis(raw).items()}


def report_json(raw: RawData, angular: bool = False) -> dict[str, dict[str, Any]]:
    """``{"X": {"A_um": …, …}}``: what ``compgw report RAW.csv --json`` prints (rotary
    axes, ``angular``: ``{"A": {"A_arcsec": …, "A_deg": …, …}}``)."""
    return {name: result.to_json_dict(angular) for name, result in iso230_raw(raw).items()}
