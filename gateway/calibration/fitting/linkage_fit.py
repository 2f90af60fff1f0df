"""A swing axis's linkage fitted to measured angles, and the table for what it leaves (pure).

Seed 003's head is driven through a rocking block, so the angle is a smooth nonlinear
function of the command (:mod:`gateway.compensation.linkage`). From an identification run
(compensation off: commanded angle c_i, measured angle θ_ij) :func:`fit_linkage` refines a
few geometric parameters of the drawing's model by least squares
(``scipy.optimize.least_squares``; by default ``base_mm``, ``phi0_deg``, ``mm_per_deg`` and
``zero_deg``: the arm length fixes the scale, which the angles alone cannot). What the
kinematics leave (the screw's own error, the play) goes into a pitch table *before* the
linkage stage in the chain: its positions are the model's angles h(c_i), its values
θ_ij − h(c_i) (:func:`residual_deviations`), so the chain target → table → linkage →
command reproduces the measurements exactly at the points.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from ...compensation.errors import TableError
from ...compensation.linkage import PARAMETERS, LinkageModel
from ..plans.rawdata import AxisDeviations

#: the parameters fitted by default (the arm and the offset come from the drawing)
FREE = ("base_mm", "phi0_deg", "mm_per_deg", "zero_deg")


@dataclass(frozen=True, eq=False)
class LinkageFit:
    """The fitted model, how well it fits, and where it started (degrees)."""

    model: LinkageModel
    start: LinkageModel
    free: tuple[str, ...]
    rms_deg: float
    max_deg: float
    start_rms_deg: float
    points: int


def _actual(values: dict[str, float], command_deg: NDArray[np.float64]) -> NDArray[np.float64]:
    """θ(c) of the closed form, without the model's validation (the solver may wander)."""
    a, b, e = values["arm_mm"], values["base_mm"], values["offset_mm"]
    phi0, k, zero = values["phi0_deg"], values["mm_per_deg"], values["zero_deg"]
    s0 = np.sqrt(max(a * a + b * b - e * e - 2 * a * b * np.cos(np.radians(phi0 + zero)), 0.0))
    s = s0 + k * command_deg
    cos_man = np.clip((a * a + b * b - e * e - s * s) / (2 * a * b), -1.0, 1.0)
    return np.degrees(np.arccos(cos_man)) - phi0


def fit_linkage(
    command_deg: NDArray[np.float64], actual_deg: NDArray[np.float64], start: LinkageModel,
    free: tuple[str, ...] = FREE,
) -> LinkageFit:  # fmt: skip
    """Least-squares fit of ``free`` parameters of ``start`` to angles measured at commands."""
    c = np.asarray(command_deg, dtype=np.float64).reshape(-1)
    y = np.asarray(actual_deg, dtype=np.float64).reshape(-1)
    ok = np.isfinite(c) & np.isfinite(y)
    c, y = c[ok], y[ok]
    unknown = [p for p in free if p not in PARAMETERS]
    if unknown:
        raise TableError(f"{start.source}: cannot fit {unknown[0]!r} (one of {PARAMETERS})")
    if c.size < len(free) + 2:
        raise TableError(f"{start.source}: {c.size} measured angles are too few to fit "
                         f"{len(free)} linkage parameters")  # fmt: skip
    base = start.values()
    x0 = np.array([base[p] for p in free])

    def residual(x: NDArray[np.float64]) -> NDArray[np.float64]:
        return _actual({**base, **dict(zip(free, x))}, c) - y

    start_rms = float(np.sqrt(np.mean(residual(x0) ** 2)))
    from scipy.optimize import least_squares  # (0.3 s to import: not on every start)

    sol = least_squares(residual, x0, x_scale="jac", method="trf", xtol=1e-15, ftol=1e-15,
                        gtol=1e-15, max_nfev=2000)  # fmt: skip
    try:
        model = start.with_values(**dict(zip(free, (float(v) for v in sol.x))))
    except TableError as exc:
        raise TableError(f"{start.source}: the fitted linkage is not a valid geometry ({exc}): "
                         "check the drawing's values and the raw data") from None
    r = residual(sol.x)
    return LinkageFit(model, start, tuple(free), float(np.sqrt(np.mean(r**2))),
                      float(np.abs(r).max()), start_rms, int(c.size))  # fmt: skip


def mean_actual_deg(dev: AxisDeviations) -> NDArray[np.float64]:
    """Measured angle per target, the mean over runs and both directions (the reversal
    cancels where both were measured)."""
    rows = [x for x in (dev.up_mm, dev.down_mm) if x is not None]
    return dev.target_mm + np.nanmean(np.concatenate(rows, axis=1), axis=1)


def residual_deviations(dev: AxisDeviations, model: LinkageModel) -> AxisDeviations:
    """What the linkage leaves, arranged as deviations of the table before it: targets the
    model's angles h(c_i), deviations θ_ij − h(c_i) per run and direction."""
    h = model.actual_deg(dev.target_mm)
    if not np.all(np.isfinite(h)) or np.any(np.diff(h) <= 0):
        raise TableError(f"{model.source}: the linkage does not map the measured commands "
                         "to rising angles")  # fmt: skip
    shift = (dev.target_mm - h)[:, None]

    def moved(x: NDArray[np.float64] | None) -> NDArray[np.float64] | None:
        return None if x is None else x + shift

    return AxisDeviations(dev.axis, h, dev.runs, moved(dev.up_mm), moved(dev.down_mm),
                          dev.source)  # fmt: skip
