"""Thermal pulse-equivalent correction (seed 002).

A reference point A on the screw, at length ``a`` from the screw's fixed end, moves by Δa as
the screw grows. With growth proportional along the screw, the pulse equivalent becomes
``C1 = C·(a + Δa)/a`` and the pulses for a travel y are ``n1 = y / C1``. Positions are
measured from ``origin_mm``, the fixed end of the screw in axis coordinates.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .errors import CompensationError

STEEL_ALPHA_PER_K = 11.5e-6


def pulse_equivalent_mm(pulse_mm: float, length_mm: float, delta_a_mm: float) -> float:
    """Current pulse equivalent ``C1 = C·(a + Δa)/a`` (mm per pulse)."""
    return pulse_mm * (length_mm + delta_a_mm) / length_mm


def pulses_for_travel(travel_mm: ArrayLike, pulse_equivalent_now_mm: float) -> NDArray[np.float64]:
    """Pulses ``n1 = y / C1`` that move the (grown) screw by ``travel_mm``."""
    return np.asarray(travel_mm, dtype=np.float64) / pulse_equivalent_now_mm


def delta_a_from_temperature(
    alpha_per_k: float, length_mm: float, temperature_c: float, reference_c: float
) -> float:
    """Δa (mm) of a screw of length ``a`` at temperature T: ``α·a·(T − T0)``."""
    return alpha_per_k * length_mm * (temperature_c - reference_c)


@dataclass(frozen=True)
class ThermalStage:
    """Scale positions about ``origin_mm`` by the screw's growth ratio ``(a + Δa)/a``."""

    length_mm: float
    origin_mm: float = 0.0

    def __post_init__(self) -> None:
        if not np.isfinite(self.length_mm) or self.length_mm <= 0:
            raise CompensationError(f"thermal length_mm: {self.length_mm!r} must be > 0")
        if not np.isfinite(self.origin_mm):
            raise CompensationError(f"thermal origin_mm: {self.origin_mm!r} must be finite")

    def growth_ratio(self, delta_a_mm: float) -> float:
        """``C1 / C``: how much farther each pulse moves now than when cold."""
        ratio = (self.length_mm + delta_a_mm) / self.length_mm
        if not np.isfinite(ratio) or ratio <= 0:
            raise CompensationError(f"thermal: Δa {delta_a_mm!r} mm is not plausible")
        return ratio

    def forward(self, target_mm: ArrayLike, delta_a_mm: float) -> NDArray[np.float64]:
        """Cold-screw command (mm) that lands on ``target_mm`` on the grown screw."""
        p = np.asarray(target_mm, dtype=np.float64)
        return self.origin_mm + (p - self.origin_mm) / self.growth_ratio(delta_a_mm)

    def inverse(self, command_mm: ArrayLike, delta_a_mm: float) -> NDArray[np.float64]:
        c = np.asarray(command_mm, dtype=np.float64)
        return self.origin_mm + (c - self.origin_mm) * self.growth_ratio(delta_a_mm)

    def forward_scalar(self, target_mm: float, delta_a_mm: float) -> float:
        return self.origin_mm + (target_mm - self.origin_mm) * self.length_mm / (
            self.length_mm + delta_a_mm
        )

    def inverse_scalar(self, command_mm: float, delta_a_mm: float) -> float:
        return self.origin_mm + (command_mm - self.origin_mm) * (
            self.length_mm + delta_a_mm
        ) / self.length_mm


# -- where the heat is: a growth profile from the axis's own travel -----------------------
def travel_swept(centres_mm: ArrayLike, bin_mm: float, from_mm: ArrayLike, to_mm: ArrayLike
                 ) -> NDArray[np.float64]:  # fmt: skip
    """How much of each bin (centred at ``centres_mm``, ``bin_mm`` wide) one move from
    ``from_mm`` to ``to_mm`` sweeps: 1 for a bin crossed whole, a share at the ends (moves
    as arrays: broadcast against the centres)."""
    c = np.asarray(centres_mm, dtype=np.float64)
    if np.ndim(from_mm) == 0 and np.ndim(to_mm) == 0:  # one move: scalars (faster)
        lo, hi = sorted((float(from_mm), float(to_mm)))  # type: ignore[arg-type]
    else:
        lo, hi = np.minimum(from_mm, to_mm), np.maximum(from_mm, to_mm)
    half = bin_mm / 2.0
    return np.clip(np.minimum(c + half, hi) - np.maximum(c - half, lo), 0.0, None) / bin_mm


def _spread_kernel(bin_mm: float, spread_mm: float) -> NDArray[np.float64]:
    """The Gaussian (``spread_mm``) sampled every ``bin_mm`` out to 3 σ, summing to 1."""
    half = max(1, int(np.ceil(3.0 * spread_mm / bin_mm)))
    u = np.arange(-half, half + 1) * bin_mm
    kernel = np.exp(-0.5 * (u / spread_mm) ** 2)
    return kernel / kernel.sum()


def travel_weights(swept: ArrayLike, bin_mm: float, spread_mm: float) -> NDArray[np.float64]:
    """Heat weight per bin: the travel swept over each bin, spread along the screw by a
    Gaussian of ``spread_mm`` (conduction over a thermal time constant, about √(κτ))."""
    s = np.asarray(swept, dtype=np.float64)
    return np.convolve(s, _spread_kernel(bin_mm, spread_mm), mode="same")


def fold_at_ends(centres_mm: ArrayLike, weights: ArrayLike, ends_mm: tuple[float, float]
                 ) -> NDArray[np.float64]:  # fmt: skip
    """Heat weights with what lies beyond the screw's ends (``ends_mm``) mirrored back onto
    it: the steel ends there, so heat conducted towards an end stays in the screw and warms
    that end (an insulated end). Weights on evenly spaced ``centres_mm``; what a mirror
    puts between two centres is shared between them; the total on the screw is kept."""
    return EndFold.of(centres_mm, ends_mm)(weights)


@dataclass(frozen=True)
class EndFold:
    """:func:`fold_at_ends` for one grid and one screw, made once: a history folds its
    weights at every reading (a zone warm-up's fit: hundreds of readings a profile)."""

    inside: NDArray[np.bool_]
    #: per end: the bins beyond it, the bin left of each mirror image, its share to the right
    beyond: tuple[tuple[NDArray[np.bool_], NDArray[np.int64], NDArray[np.float64]], ...]

    @classmethod
    def of(cls, centres_mm: ArrayLike, ends_mm: tuple[float, float]) -> EndFold:
        x = np.asarray(centres_mm, dtype=np.float64)
        lo, hi = ends_mm
        step = x[1] - x[0] if x.size > 1 else 1.0
        beyond = []
        for mask, mirrored in ((x < lo, 2.0 * lo - x), (x > hi, 2.0 * hi - x)):
            at = np.clip(mirrored[mask], lo, hi)  # (beyond both ends at once: kept at the end)
            k = np.clip((at - x[0]) / step, 0.0, x.size - 1.0)
            i = (np.minimum(np.floor(k).astype(np.int64), x.size - 2) if x.size > 1
                 else np.zeros(k.shape, np.int64))  # fmt: skip
            beyond.append((mask, i, k - i))
        return cls((x >= lo) & (x <= hi), tuple(beyond))

    def adjoint(self, rows: ArrayLike) -> NDArray[np.float64]:
        """``rows @ M`` (one row a read-out, shape (k, n)), M the fold's matrix
        (``M @ w`` is ``self(w)``): what each bin's weight adds to each read-out."""
        r = np.atleast_2d(np.asarray(rows, dtype=np.float64))
        out = np.where(self.inside, r, 0.0)
        for mask, i, share in self.beyond:
            if not i.size:
                continue
            pulled = r[:, i] * (1.0 - share)
            if r.shape[1] > 1:
                pulled += r[:, i + 1] * share
            out[:, mask] += pulled
        return out

    def __call__(self, weights: ArrayLike) -> NDArray[np.float64]:
        w = np.asarray(weights, dtype=np.float64)
        out = np.where(self.inside, w, 0.0)
        n = out.size
        for mask, i, share in self.beyond:
            if not i.size:
                continue
            moved = w[mask]
            out += np.bincount(i, moved * (1.0 - share), minlength=n)[:n]
            if n > 1:
                out += np.bincount(i + 1, moved * share, minlength=n)[:n]
        return out


def travel_integral(centres_mm: ArrayLike, weights: ArrayLike) -> NDArray[np.float64]:
    """W(x): the integral of the heat weights along the screw, at ``centres_mm``."""
    x = np.asarray(centres_mm, dtype=np.float64)
    w = np.asarray(weights, dtype=np.float64)
    return np.concatenate([[0.0], np.cumsum((w[1:] + w[:-1]) / 2.0 * np.diff(x))])


def travel_integral_rows(centres_mm: ArrayLike, bin_mm: float, spread_mm: float,
                         fold: EndFold | None, at_mm: ArrayLike
                         ) -> NDArray[np.float64]:  # fmt: skip
    """W at each of ``at_mm`` as a linear read-out of the swept travel: row i · swept is
    ``np.interp(at_mm[i], centres_mm, W)``, W made from swept by :func:`travel_weights`,
    ``fold`` and :func:`travel_integral`. All three are linear, so a fit replaying a
    warm-up reads every stop's W with one product instead of a convolution a stop (each
    step below is the adjoint of one of theirs, taken in reverse order)."""
    x = np.asarray(centres_mm, dtype=np.float64)
    at = np.atleast_1d(np.asarray(at_mm, dtype=np.float64))
    n = x.size
    rows = np.zeros((at.size, n))
    if n < 2:
        return rows
    # np.interp's weights, clamped at the ends
    j = np.clip(np.searchsorted(x, at, side="right") - 1, 0, n - 2)
    t = np.clip((at - x[j]) / (x[j + 1] - x[j]), 0.0, 1.0)
    rows[np.arange(at.size), j] = 1.0 - t
    rows[np.arange(at.size), j + 1] += t
    # W = cumulative trapezoids of the weights
    reach = np.cumsum(rows[:, :0:-1], axis=1)[:, ::-1] * (np.diff(x) / 2.0)
    rows = np.zeros((at.size, n))
    rows[:, :-1] += reach
    rows[:, 1:] += reach
    if fold is not None:
        rows = fold.adjoint(rows)
    # the spread: a symmetric kernel is its own adjoint
    return np.array([travel_weights(row, bin_mm, spread_mm) for row in rows]).reshape(at.size, n)


def travel_delta_a_mm(delta_a_mm: float, at_mm: float, centres_mm: ArrayLike,
                      integral: ArrayLike, stage: ThermalStage, toward: int) -> float:
    """The Δa that makes the linear stage grow the screw at ``at_mm`` as much as a screw
    warm where the weights say: growth(x) = Δa · s · (W(x) − W(o)) / (W(A) − W(o)), W the
    integral of the weights (:func:`travel_integral`), o the fixed end
    (``stage.origin_mm``), A the Δa point at ``stage.length_mm`` from it on the side
    ``toward`` (±1) of the travel. Equal weights give back ``delta_a_mm``; so do no weights
    at all and a place at the fixed end."""
    x = np.asarray(centres_mm, dtype=np.float64)
    cum = np.asarray(integral, dtype=np.float64)
    lever = at_mm - stage.origin_mm
    if abs(lever) < 1.0 or cum.size < 2 or not cum[-1] > 0:
        return delta_a_mm
    o = float(np.interp(stage.origin_mm, x, cum))
    a_point = stage.origin_mm + toward * stage.length_mm
    whole = float(np.interp(a_point, x, cum)) - o
    if abs(whole) < 1e-12:
        return delta_a_mm
    fraction = toward * (float(np.interp(at_mm, x, cum)) - o) / whole
    return delta_a_mm * fraction * stage.length_mm / lever


# -- without a sensor: the heat the axis's own motion puts into its screw -----------------
def motion_heat_m(heat_m: ArrayLike, travel_m: ArrayLike, elapsed_s: ArrayLike,
                  tau_s: ArrayLike) -> NDArray[np.float64]:
    """The screw's heat after ``elapsed_s`` in which its nut travelled ``travel_m``, in
    metres of travel (m); elementwise over arrays.

    A ball screw warms by its nut's friction, about the same energy per metre travelled at
    any speed, and loses heat to the air in proportion to how warm it is (time constant
    ``tau_s``): ``heat_m`` is the travel whose heat is still in the screw. The stretch's own
    travel is deposited evenly over it and decays with it."""
    d = np.asarray(travel_m, dtype=np.float64)
    t = np.asarray(elapsed_s, dtype=np.float64)
    tau = np.asarray(tau_s, dtype=np.float64)
    if np.any(d < 0) or np.any(t < 0) or np.any(tau <= 0):
        raise CompensationError("motion heat: travel and time must be >= 0, tau > 0")
    x = t / tau
    small = x < 1e-12
    share = np.where(small, 1.0, -np.expm1(-x) / np.where(small, 1.0, x))  # (1 − e^-x)/x
    return np.asarray(heat_m, dtype=np.float64) * np.exp(-x) + d * share


def motion_heat_one_m(heat_m: float, travel_m: float, elapsed_s: float, tau_s: float) -> float:
    """:func:`motion_heat_m` for one screw and one stretch, in plain floats: the gateway
    asks it at every request of an axis without a sensor, where numpy's per-call cost is
    most of the arithmetic."""
    if travel_m < 0 or elapsed_s < 0 or tau_s <= 0:
        raise CompensationError("motion heat: travel and time must be >= 0, tau > 0")
    x = elapsed_s / tau_s
    share = 1.0 if x < 1e-12 else -math.expm1(-x) / x  # (1 − e^-x)/x
    return heat_m * math.exp(-x) + travel_m * share


def motion_heat_after_m(travel_m: ArrayLike, elapsed_s: ArrayLike, tau_s: float) -> float:
    """Heat (m of travel) after a sequence of stretches from a cold screw: the last of
    :func:`motion_heat_series_m`, at once: each stretch's own deposit, cooled for the time
    of the stretches after it. The gateway counts a model loaded mid-run from hundreds of
    thousands of moves at a reload (:class:`~gateway.thermal_travel.MoveLog`)."""
    t = np.asarray(elapsed_s, dtype=np.float64)
    own = motion_heat_m(0.0, travel_m, t, tau_s)
    after_s = np.cumsum(t[::-1])[::-1] - t
    return float(np.sum(own * np.exp(-after_s / tau_s)))


def motion_heat_series_m(travel_m: ArrayLike, elapsed_s: ArrayLike,
                         tau_s: ArrayLike) -> NDArray[np.float64]:
    """Heat (m of travel, see :func:`motion_heat_m`) after each of a sequence of stretches
    (axis 0), from a cold screw; ``elapsed_s`` and ``tau_s`` broadcast over further axes
    (a grid of time constants or time scales to try)."""
    d = np.asarray(travel_m, dtype=np.float64)
    t = np.asarray(elapsed_s, dtype=np.float64)
    shape = np.broadcast_shapes(t.shape[1:] if t.ndim > 1 else (), np.shape(tau_s))
    out = np.empty((d.shape[0], *shape))
    heat = np.zeros(shape)
    for k in range(d.shape[0]):
        heat = motion_heat_m(heat, d[k], t[k], tau_s)
        out[k] = heat
    return out
