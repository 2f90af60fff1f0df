"""One dense sweep of the whole travel, folded into the table and the cyclic model (pure).

A rough screw's error has structure no coarse table and three cyclic stations capture: a
waviness of a few centimetres and a once-per-turn term (with harmonics) whose amplitude
and phase change along the travel. Refining span by span follows it only where the
verification happened to land, a short scan per point. One sweep measures it everywhere
instead: one reading every 0.12 lead (``SWEEP_STEPS_LEADS``; the phases walk, so harmonics
1-4 are resolved), up the whole travel and down again, with the table and cyclic term on.
Its residual is fitted as

    r(x, ±) = L(x) ∓ D(x)/2 + Σ_k a_k(x)·sin(kθ) + b_k(x)·cos(kθ)

with L (the level) and D (the lost motion's change) piecewise linear between knots at
every target read and at the table's own points (the table's own interpolation, so the
gateway reproduces the sum exactly, between the readings too) and the amplitudes
piecewise linear between stations that include the cyclic term's own (its own
interpolation). Each part is held smooth by a second-difference penalty whose weight is
chosen by generalised cross-validation, so a sweep of noise adds nothing and a wavy screw
is followed; the level's penalty is on the table the fold makes (the old points plus L),
so the noise of the identification's fewer readings is smoothed with the sweep's, and the
change is held to the table as it was by a fourth weight (0 for not at all): how much the
table's own points are worth against the sweep's readings, cross-validation decides. The fit is
robust: a stick-slip axis stops short now and then (a one-sided tail of up to a few µm),
and those readings are weighted down (Tukey's biweight, each reading judged by how far it
lies from what the others say) instead of bending the table; how often the axis stops
short, on average, is put back as a constant per direction. Positions and deviations are mm
unless the name says µm.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.linalg import cho_factor, cho_solve, solve_triangular

from ...compensation import PitchStage, PitchTable
from ...compensation.cyclic import CyclicModel
from .adaptive import MIN_SPACING_MM

#: a reading every this many leads: 8.33 per lead, the phase moving 0.12 turn per step;
#: coarser steps where the budget is short (harmonics up to ``harmonics_for_step``)
SWEEP_STEPS_LEADS = (0.12, 0.16, 0.24)
#: the step (mm) of an axis without a known lead, and what the budget may make of it
SWEEP_STEPS_MM = (1.0, 1.5, 2.5)
#: ... and before those, for such an axis whose single stops scatter more than the
#: tolerance: its table is a smoothed mean of the readings, whose error falls as
#: 1/√readings, and no lead ties its step to the phase of a harmonic
NOISY_STEPS_MM = (0.25, 0.5)
#: the level's knots: one per target read, at most this far apart (mm) and at most this
#: many over the travel (the fit's cost grows as their cube); the smoothing penalty, chosen
#: by cross-validation, decides how much of that resolution the readings support
LEVEL_KNOT_MM = 5.0
LEVEL_KNOTS_MAX = 200
#: the amplitudes' stations: at least this many leads apart, about this many over the travel
STATION_LEADS = 4.0
STATIONS = 17
#: harmonics of the lead fitted (a rough screw shows up to the 4th)
SWEEP_HARMONICS = 4
#: the penalty weights tried, relative to the data's own weight per knot
_LAMBDAS = tuple(10.0 ** e for e in np.arange(-3.0, 7.01, 1.0))
#: the weights tried for holding the change to the table as it was (0: not at all)
_RIDGES = (0.0, *(10.0 ** e for e in np.arange(-3.0, 3.01, 0.5)))
#: the lost motion's change is held to a straight line along the travel (the largest
#: penalty) unless bending between knots scores a GCV this much lower (the plane's margin
#: of grid over polynomial): the sweep reads each target once each way, so a change per
#: knot is mostly noise unless the play really changes within the travel (a worn zone)
LINE_MARGIN = 0.95
#: reweighting passes of the robust fit, and Tukey's biweight constant (in robust sigmas)
ROBUST_ITERATIONS = 6
BIWEIGHT_C = 4.685


def _biweight(e: NDArray[np.float64]) -> NDArray[np.float64]:
    """Tukey's biweight of residuals ``e`` (any unit), their scale from the median absolute
    deviation: 1 at zero, falling to 0 at ``BIWEIGHT_C`` robust sigmas."""
    scale = 1.4826 * float(np.median(np.abs(e)))
    if scale <= 0:
        return np.ones_like(e)
    u = e / (BIWEIGHT_C * scale)
    return np.where(np.abs(u) < 1, (1 - u * u) ** 2, 0.0)


def sweep_steps_mm(lead_mm: float | None, noisy: bool = False) -> tuple[float, ...]:
    """The distances between readings a sweep may take (mm), densest first:
    ``SWEEP_STEPS_LEADS`` of the lead, else ``SWEEP_STEPS_MM``, after ``NOISY_STEPS_MM``
    when the axis is ``noisy`` (its stops scatter more than the tolerance)."""
    if lead_mm:
        return tuple(f * lead_mm for f in SWEEP_STEPS_LEADS)
    return (*NOISY_STEPS_MM, *SWEEP_STEPS_MM) if noisy else SWEEP_STEPS_MM


def sweep_step_mm(lead_mm: float | None, coarser: int = 0, noisy: bool = False) -> float:
    """The distance between readings of a sweep (mm): the densest, or ``coarser`` steps
    down :func:`sweep_steps_mm`."""
    return sweep_steps_mm(lead_mm, noisy)[coarser]


def harmonics_for_step(step_mm: float, lead_mm: float | None) -> int:
    """The harmonics a sweep with readings ``step_mm`` apart resolves: their phase must
    move clearly less than half a turn per reading (0.12 lead: 4; 0.16: 3; 0.24: 2)."""
    if not lead_mm:
        return 0
    return max(0, min(SWEEP_HARMONICS, math.floor(0.5 * lead_mm / step_mm - 0.05)))


def sweep_targets_mm(travel_mm: Sequence[float], lead_mm: float | None,
                     margin_mm: float = 2.0, coarser: int = 0, noisy: bool = False,
                     step_mm: float | None = None) -> NDArray[np.float64]:  # fmt: skip
    """The sweep's targets over the travel less ``margin_mm`` at each end, ``step_mm``
    apart (default :func:`sweep_step_mm`'s)."""
    lo, hi = float(travel_mm[0]) + margin_mm, float(travel_mm[1]) - margin_mm
    step = step_mm if step_mm is not None else sweep_step_mm(lead_mm, coarser, noisy)
    n = max(2, math.floor((hi - lo) / step) + 1)
    return np.round(lo + step * np.arange(n), 4)


def knots_mm(lo_mm: float, hi_mm: float, spacing_mm: float) -> NDArray[np.float64]:
    """Evenly spaced knots from ``lo_mm`` to ``hi_mm``, about ``spacing_mm`` apart."""
    n = max(2, math.ceil((hi_mm - lo_mm) / spacing_mm) + 1)
    return np.round(np.linspace(lo_mm, hi_mm, n), 4)


def merged_mm(own_mm: NDArray[np.float64], kept_mm: ArrayLike, gap_mm: float
              ) -> NDArray[np.float64]:  # fmt: skip
    """``kept_mm`` (every one) and those of ``own_mm`` at least ``gap_mm`` from all of them,
    sorted: the break points of a piecewise-linear fit that is added to a piecewise-linear
    function breaking at ``kept_mm``, so that the sum breaks only where both are known."""
    kept = np.unique(np.round(np.asarray(kept_mm, dtype=np.float64).reshape(-1), 4))
    if kept.size == 0:
        return own_mm
    far = np.array([np.min(np.abs(kept - p)) >= gap_mm for p in own_mm], dtype=bool)
    return np.unique(np.concatenate([kept, own_mm[far]]))


def _curvature(t: NDArray[np.float64]) -> NDArray[np.float64]:
    """Second divided differences over the break points ``t`` (scaled to their mean
    spacing: ``[1, -2, 1]`` where they are even), the smoothing penalty's rows."""
    n = t.size
    d = np.zeros((max(0, n - 2), n))
    if n < 3:
        return d
    h = np.diff(t)
    mean = float(np.mean(h))
    for i in range(n - 2):
        d[i, i], d[i, i + 2] = mean / h[i], mean / h[i + 1]
        d[i, i + 1] = -(d[i, i] + d[i, i + 2])
    return d


def _hats(x: NDArray[np.float64], knots: NDArray[np.float64]) -> NDArray[np.float64]:
    """Design columns of piecewise-linear interpolation between ``knots`` (held outside)."""
    xc = np.clip(x, knots[0], knots[-1])
    i = np.clip(np.searchsorted(knots, xc, side="right") - 1, 0, knots.size - 2)
    w = (xc - knots[i]) / (knots[i + 1] - knots[i])
    out = np.zeros((x.size, knots.size))
    rows = np.arange(x.size)
    out[rows, i] = 1.0 - w
    out[rows, i + 1] += w
    return out


def _residual_spread(cols: NDArray[np.float64], a: NDArray[np.float64],
                     w: NDArray[np.float64] | None) -> NDArray[np.float64]:  # fmt: skip
    """Each reading's residual scale (in units of the scatter), so that the biweight
    judges every reading by how far it lies from what the others say, at that distance's
    own spread: with g = xᵢᵀA⁻¹xᵢ (A the fit's penalised normal matrix, weights ``w``) the
    residual rᵢ over 1 − wᵢg is the reading's leave-one-out residual, whose variance is
    1 + g/(1 − wᵢg) scatters; hence √((1 − wᵢg)(1 − wᵢg + g)): √(1 − g) for a reading
    fully in (the studentised residual), √(1 + g) for one weighted out.

    A fit with nearly a parameter per reading (knots at every target, both ways) bends to
    each one, so its raw residuals understate the scatter; judged raw, ordinary readings
    look like outliers, the biweight weights them out, the fit bends further and ends up
    through the rest (seen on a slit stage: 12 of 78 readings at weight 0, 0.007 µm RMS
    left of 0.37 µm of scatter)."""
    g = np.einsum("ij,ji->i", cols, np.linalg.solve(a, cols.T))
    wg = g if w is None else g * w
    return np.sqrt(np.clip(1.0 - wg, 0.05, 1.0) * (1.0 - wg + g))


@dataclass(frozen=True)
class SweepFit:
    """What a sweep's residual holds (mm): the level per direction at the knots, the
    harmonic amplitudes at the stations."""

    knot_mm: NDArray[np.float64]
    up_mm: NDArray[np.float64]
    down_mm: NDArray[np.float64]
    station_mm: NDArray[np.float64]
    sin_mm: NDArray[np.float64]  # (stations, K); K = 0 without a lead
    cos_mm: NDArray[np.float64]
    lead_mm: float | None
    origin_mm: float
    #: penalty weights chosen (level, lost motion, amplitudes), relative
    lambdas: tuple[float, float, float]
    #: RMS of the readings about the fit (robust weights applied), the fit's level range (µm)
    residual_rms_um: float
    level_ptp_um: float
    #: how firmly the change was held to the table it was read with (relative; 0: not)
    hold: float = 0.0
    #: readings the robust fit left out entirely (weight 0: stops short, stick-slip)
    weighted_out: int = 0

    def level_mm(self, x_mm: NDArray[np.float64], direction: int) -> NDArray[np.float64]:
        return np.interp(x_mm, self.knot_mm, self.up_mm if direction > 0 else self.down_mm)


def fit_sweep(x_mm: NDArray[np.float64], deviation_mm: NDArray[np.float64],
              direction: NDArray[np.int64], lead_mm: float | None, origin_mm: float = 0.0,
              harmonics: int = SWEEP_HARMONICS, robust: bool = True,
              table: PitchTable | None = None, stations_mm: ArrayLike = (),
              line_margin: float = LINE_MARGIN, gap_mm: float = MIN_SPACING_MM
              ) -> SweepFit:  # fmt: skip
    """Fit a sweep's residual (see the module's docstring). The number of harmonics (up to
    ``harmonics``) and the four penalty weights are those of the smallest generalised
    cross-validation score: a harmonic the readings do not show is not added.

    ``table`` and ``stations_mm``: the table and the stations of the cyclic term the sweep
    was read with. The level breaks at every table point and the amplitudes at every
    station too, so the fit added to them is exactly what the gateway then interpolates
    (:func:`sweep_refinement`), between the readings as at them. The smoothing penalty is
    on the table the fold makes (the table's own points plus the level): the sweep reads
    the whole error every step, so the noise of the fewer readings the table's points came
    from is smoothed out with its own, as far as cross-validation says the sweep allows;
    and a ridge holds the level to the table as it was (its weight ``hold`` chosen the same
    way, 0 among the choices), so what those readings knew is weighed, not dropped.
    ``gap_mm``: how near a table point the level's own knots may lie (a swing axis's, in
    degrees, nearer than a linear axis's)."""
    x = np.asarray(x_mm, dtype=np.float64)
    y = np.asarray(deviation_mm, dtype=np.float64) * 1e3  # µm: a well-scaled system
    s = np.where(np.asarray(direction) < 0, 0.5, -0.5)  # −D/2 going up, +D/2 down
    lo, hi = float(np.min(x)), float(np.max(x))
    k = harmonics if lead_mm else 0
    targets = np.unique(np.round(x, 4))
    step = float(np.median(np.diff(targets))) if targets.size > 1 else LEVEL_KNOT_MM
    knot_spacing = min(LEVEL_KNOT_MM, max(step, (hi - lo) / (LEVEL_KNOTS_MAX - 1)))
    kn = merged_mm(knots_mm(lo, hi, knot_spacing),
                   () if table is None else table.position_mm, gap_mm)  # fmt: skip
    h = _hats(x, kn)
    blocks = [h, h * s[:, None]]
    if k:
        spacing = max(STATION_LEADS * lead_mm, (hi - lo) / (STATIONS - 1))  # type: ignore[operator]
        st = merged_mm(knots_mm(lo, hi, spacing), stations_mm, lead_mm)  # type: ignore[arg-type]
        g = _hats(x, st)
        theta = 2 * np.pi * (x - origin_mm) / lead_mm  # type: ignore[operator]
        for j in range(1, k + 1):
            blocks += [g * np.sin(j * theta)[:, None], g * np.cos(j * theta)[:, None]]
    else:
        st = np.array([lo, hi])
    design = np.hstack(blocks)
    sizes = [kn.size, kn.size] + [st.size] * (2 * k)
    # each part's penalty, scaled to the data's weight per parameter of that part
    xtx_all = design.T @ design
    groups_all = [np.zeros_like(xtx_all) for _ in range(4)]
    start = 0
    for part, (n, t) in enumerate(zip(sizes, [kn, kn] + [st] * (2 * k))):
        d = _curvature(t)  # no penalty on a line
        block = slice(start, start + n)
        weight = float(np.trace(xtx_all[block, block])) / n
        groups_all[min(part, 2)][block, block] = weight * (d.T @ d)
        if part < 2 and table is not None:  # the change itself, towards the table as it was
            groups_all[3][block, block] = weight * np.eye(n)
        start += n

    # the table as it was, at the knots (µm): the penalty holds it plus the level smooth
    prior = np.zeros(design.shape[1])
    if table is not None:
        fwd = np.interp(kn, table.position_mm, table.forward_mm) * 1e3
        rev = fwd if table.reverse_mm is None else \
            np.interp(kn, table.position_mm, table.reverse_mm) * 1e3  # fmt: skip
        prior[: kn.size] = 0.5 * (fwd + rev)
        prior[kn.size : 2 * kn.size] = rev - fwd
    pulls = [g_ @ prior for g_ in groups_all[:3]] + [np.zeros_like(prior)]

    def normal(w: NDArray[np.float64] | None) -> tuple[NDArray[np.float64], ...]:
        """The weighted normal equations' matrix and right side, all columns, and R of
        the weighted design's QR (RᵀR the matrix, any columns' R their columns of it)."""
        dw = design if w is None else design * w[:, None]
        half = design if w is None else design * np.sqrt(w)[:, None]
        return (xtx_all if w is None else dw.T @ design), dw.T @ y, \
            np.linalg.qr(half, mode="r")  # fmt: skip

    # (GCV score, coefficients, RSS, the penalised normal matrix)
    Fit = tuple[float, NDArray[np.float64], float, NDArray[np.float64]]

    def solve(kk: int, lams: Sequence[float], w: NDArray[np.float64] | None,
              eqs: tuple[NDArray[np.float64], ...]) -> Fit:  # fmt: skip
        cols = slice(0, 2 * kn.size + 2 * kk * st.size)
        xtx = eqs[0][cols, cols]
        a = xtx + sum(lam * g_[cols, cols] for lam, g_ in zip(lams, groups_all))
        a = a + 1e-9 * float(np.trace(xtx)) / xtx.shape[0] * np.eye(xtx.shape[0])
        rhs = eqs[1][cols] - sum(lam * p[cols] for lam, p in zip(lams, pulls))
        try:  # A = LLᵀ: the coefficients, and tr(A⁻¹XᵀX) = ‖L⁻¹Rᵀ‖² (a third of the work
            # of solving for A⁻¹XᵀX, and this runs a few hundred times a fit)
            low = cho_factor(a, lower=True, check_finite=False)
            beta = cho_solve(low, rhs, check_finite=False)
            z = solve_triangular(low[0], eqs[2][:, cols].T, lower=True, check_finite=False)
            edf = float(np.sum(z * z))
        except np.linalg.LinAlgError:  # not positive definite in floating point
            beta = np.linalg.solve(a, rhs)
            edf = float(np.trace(np.linalg.solve(a, xtx)))
        e = y - design[:, cols] @ beta
        rss = float(np.sum(e * e if w is None else w * e * e))
        return y.size * rss / max(y.size - edf, 1.0) ** 2, beta, rss, a

    def search(w: NDArray[np.float64] | None, lams: list[float], ks: Sequence[int],
               eqs: tuple[NDArray[np.float64], ...] | None = None, held: int | None = None,
               ) -> tuple[Fit, list[float], int]:  # fmt: skip
        """Of the harmonics ``ks``, and the three weights, those of the smallest GCV, each
        weight searched over the grid in turn (twice round without harmonics, then once
        from the weights of one harmonic fewer), but weight ``held`` kept as given.
        ``eqs``: ``normal(w)`` when built."""
        eqs = normal(w) if eqs is None else eqs
        best, chosen = solve(ks[0], lams, w, eqs), ks[0]
        for kk in ks:
            here_lams = list(lams)
            here = solve(kk, here_lams, w, eqs)
            for _ in range(1 if kk else 2):
                for gi in ((2, 0, 1) if kk else (0, 1)) + ((3,) if table is not None else ()):
                    if gi == held:
                        continue
                    for lam in (_RIDGES if gi == 3 else _LAMBDAS):
                        trial = list(here_lams)
                        trial[gi] = lam
                        got = solve(kk, trial, w, eqs)
                        if got[0] < here[0]:
                            here, here_lams = got, trial
            if here[0] < best[0] or kk == ks[0]:
                best, lams, chosen = here, here_lams, kk
        return best, lams, chosen

    best, lams, chosen = search(None, [1.0, 1.0, 1.0, 0.0], range(k + 1))
    w, eqs = None, None
    if robust:
        # stick-slip stops short, now and then, by up to a few µm: a heavy one-sided tail
        # that least squares follows. Tukey's biweight on each residual over its own spread
        # (the scale from their median absolute deviation) takes those stops out. The
        # weights are found with the least-squares smoothing, then the smoothing is chosen
        # again with them (the harmonics stay those least squares chose)
        beta, a = best[1], best[3]
        cols = design[:, : beta.size]
        for _ in range(ROBUST_ITERATIONS):
            e = (y - cols @ beta) / _residual_spread(cols, a, w)
            for way in (s < 0, s > 0):  # centred per direction: the tail is one-sided
                e[way] -= np.median(e[way])
            w = _biweight(e)
            eqs = normal(w)
            _, beta, _, a = solve(chosen, lams, w, eqs)
        best, lams, chosen = search(w, lams, [chosen], eqs)
    if line_margin > 0 and lams[1] < _LAMBDAS[-1]:  # the change bends: does it pay?
        line, line_lams, _ = search(w, [lams[0], _LAMBDAS[-1], *lams[2:]], [chosen], eqs,
                                    held=1)  # fmt: skip
        if not best[0] < line_margin * line[0]:
            best, lams = line, line_lams
    k = chosen
    beta = best[1]
    level, lost = beta[: kn.size].copy(), beta[kn.size : 2 * kn.size].copy()
    if w is not None:
        # what was left out is the machine too (a stop that sticks is a stop it makes):
        # each direction's mean residual goes back into its level, a constant per direction
        e = y - design[:, : 2 * kn.size + 2 * k * st.size] @ beta
        up, down = float(np.mean(e[s < 0])), float(np.mean(e[s > 0]))
        level += 0.5 * (up + down)
        lost += down - up
    amps = beta[2 * kn.size :].reshape(2 * k, st.size) if k else np.zeros((0, st.size))
    sin = amps[0::2].T * 1e-3 if k else np.zeros((st.size, 0))
    cos = amps[1::2].T * 1e-3 if k else np.zeros((st.size, 0))
    return SweepFit(kn, (level - 0.5 * lost) * 1e-3, (level + 0.5 * lost) * 1e-3, st,
                    sin, cos, lead_mm, origin_mm, (lams[0], lams[1], lams[2]),
                    math.sqrt(best[2] / y.size), float(np.ptp(level)),
                    float(lams[3]), 0 if w is None else int(np.sum(w == 0)))  # fmt: skip


@dataclass(frozen=True)
class SweepRefinement:
    table: PitchTable
    cyclic: CyclicModel | None
    fit: SweepFit


def sweep_refinement(
    table: PitchTable, stage: PitchStage, cyclic: CyclicModel | None, fit: SweepFit,
) -> SweepRefinement:  # fmt: skip
    """``table`` (and ``cyclic``) with the sweep's fit added: the table gets the level's
    knots and every point the level there; the cyclic model gets the sweep's stations,
    each with the fitted amplitudes added (harmonics it lacked start from zero). Exact
    between the points too when the fit broke at the table's points and the model's
    stations (``fit_sweep``'s ``table`` and ``stations_mm``)."""
    pos = np.unique(np.round(np.concatenate([table.position_mm, fit.knot_mm]), 4))
    own_up = stage.inverse(pos, np.ones(pos.size, dtype=np.int64)) - pos
    own_dn = stage.inverse(pos, -np.ones(pos.size, dtype=np.int64)) - pos
    fwd = own_up + fit.level_mm(pos, +1)
    rev = own_dn + fit.level_mm(pos, -1)
    if table.reverse_mm is None:  # a one-direction table: the mean of both
        fwd, rev_out = 0.5 * (fwd + rev), None
    else:
        rev_out = rev
    new_table = PitchTable(pos, fwd, rev_out, table.rotary, table.source)
    model = cyclic
    if cyclic is not None and fit.sin_mm.shape[1]:
        k = max(cyclic.harmonics, fit.sin_mm.shape[1])
        a0, b0 = cyclic.amplitudes_mm(fit.station_mm)
        a = np.zeros((fit.station_mm.size, k))
        b = np.zeros_like(a)
        a[:, : a0.shape[1]] += a0
        b[:, : b0.shape[1]] += b0
        a[:, : fit.sin_mm.shape[1]] += fit.sin_mm
        b[:, : fit.cos_mm.shape[1]] += fit.cos_mm
        model = CyclicModel(cyclic.lead_mm, fit.station_mm, a, b, cyclic.origin_mm,
                            cyclic.source)  # fmt: skip
    return SweepRefinement(new_table, model, fit)
