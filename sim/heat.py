"""The screw's temperature along its length: a 1-D heat equation on a grid. Pure numpy.

    ∂θ/∂t = κ ∂²θ/∂x² − θ/τ + q(x, t)/(ρ c A)

θ = T − ambient (K); κ = k/(ρc) conduction along the steel; τ = ρ c d/(4h) loss to the air
through the surface; q the friction heat of the nut (W/m), deposited along the stretch it
sweeps while it moves (spread over the nut's length). Ends insulated (the bearings carry
little heat). Backward Euler in time (unconditionally stable, so the step follows accuracy
alone: 2 s while a move heats, 10 s when only cooling), second-order central differences
in space, one tridiagonal solve per step.

The table's growth at x is α ∫ θ dξ from the axially fixed end to x: not linear in x when
the screw is warm only where the nut works.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from sim.config_truth import ScrewHeat

HEATING_STEP_S = 2.0
COOLING_STEP_S = 10.0


@dataclass(frozen=True)
class HeatSource:
    """The nut moving from ``from_mm`` to ``to_mm`` during [start_s, end_s] at ``power_W``."""

    start_s: float
    end_s: float
    from_mm: float
    to_mm: float
    power_W: float

    def at(self, t_s: float) -> float:
        frac = (t_s - self.start_s) / (self.end_s - self.start_s)
        return self.from_mm + (self.to_mm - self.from_mm) * min(max(frac, 0.0), 1.0)


class ScrewHeatModel:
    """Temperature profile of one screw, stepped forward in machine time on demand."""

    def __init__(self, cfg: ScrewHeat, travel_mm: tuple[float, float]) -> None:
        self.cfg = cfg
        nut = cfg.nut_length_mm
        lo, hi = cfg.screw_mm or (travel_mm[0] - nut, travel_mm[1] + nut)
        self.x_mm = np.linspace(lo, hi, cfg.nodes)
        self.dx_mm = (hi - lo) / (cfg.nodes - 1)
        self.fixed_mm = cfg.fixed_end_mm if cfg.fixed_end_mm is not None else lo
        d_m = cfg.diameter_mm / 1000.0
        rho_c = cfg.density_kg_m3 * cfg.heat_capacity_J_kgK
        self.kappa_m2_s = cfg.conductivity_W_mK / rho_c
        self.loss_per_s = 4.0 * cfg.h_W_m2K / (rho_c * d_m)
        self.heat_cap_J_K_per_mm = rho_c * math.pi * d_m * d_m / 4.0 / 1000.0
        # control volume of each node (half cells at the insulated ends)
        self._edges_mm = (np.maximum(self.x_mm - self.dx_mm / 2.0, lo),
                          np.minimum(self.x_mm + self.dx_mm / 2.0, hi))  # fmt: skip
        self.cell_mm = self._edges_mm[1] - self._edges_mm[0]
        self.theta_K = np.zeros(cfg.nodes)
        self.t_s = 0.0
        self.sources: list[HeatSource] = []
        self._matrices: dict[float, np.ndarray] = {}
        self._cumulative: np.ndarray | None = None

    # ------------------------------------------------------------ heat in
    def power_W(self, speed_mm_s: float) -> float:
        """Friction power of the nut at this speed: 2π · torque · turns per second."""
        return 2.0 * math.pi * self.cfg.drag_torque_Nm * speed_mm_s / self.cfg.lead_mm

    def add_move(self, start_s: float, end_s: float, from_mm: float, to_mm: float,
                 speed_mm_s: float) -> None:
        """A move heats the stretch the nut sweeps, at the power of its speed."""
        self.advance(start_s)
        if end_s > start_s and from_mm != to_mm and self.cfg.drag_torque_Nm > 0:
            self.sources.append(HeatSource(start_s, end_s, from_mm, to_mm,
                                           self.power_W(speed_mm_s)))  # fmt: skip

    def _deposit_K(self, t0_s: float, t1_s: float) -> np.ndarray:
        """Temperature rise per node from the sources' energy in [t0, t1]."""
        out = np.zeros_like(self.theta_K)
        half = self.cfg.nut_length_mm / 2.0
        edges_lo, edges_hi = self._edges_mm
        for src in self.sources:
            a, b = max(t0_s, src.start_s), min(t1_s, src.end_s)
            if b <= a:
                continue
            p0, p1 = sorted((src.at(a), src.at(b)))
            lo, hi = p0 - half, p1 + half
            overlap = np.clip(np.minimum(edges_hi, hi) - np.maximum(edges_lo, lo), 0.0, None)
            total = overlap.sum()
            if total <= 0:
                continue
            energy_J = src.power_W * (b - a)
            out += energy_J * overlap / total / (self.heat_cap_J_K_per_mm * self.cell_mm)
        return out

    # ------------------------------------------------------------ time stepping
    def _matrix(self, dt_s: float) -> np.ndarray:
        key = round(dt_s, 9)
        ab = self._matrices.get(key)
        if ab is None:
            n = self.x_mm.size
            r = self.kappa_m2_s * dt_s / (self.dx_mm / 1000.0) ** 2
            ab = np.zeros((3, n))
            ab[0, 1:] = -r
            ab[0, 1] = -2.0 * r  # mirror node at the insulated low end
            ab[1, :] = 1.0 + 2.0 * r + dt_s * self.loss_per_s
            ab[2, :-1] = -r
            ab[2, -2] = -2.0 * r  # and at the high end
            if len(self._matrices) > 64:
                self._matrices.clear()
            self._matrices[key] = ab
        return ab

    def advance(self, t_s: float) -> None:
        """Step the profile forward to machine time ``t_s`` (never backwards)."""
        # scipy.linalg is most of the sim's start (0.4-0.7 s): imported once heat is stepped
        from scipy.linalg import solve_banded

        while self.t_s < t_s - 1e-12:
            heating = any(s.end_s > self.t_s for s in self.sources)
            step = HEATING_STEP_S if heating else COOLING_STEP_S
            t1 = min(t_s, self.t_s + step)
            for s in self.sources:  # land on the ends of heating, so steps stay short there
                if self.t_s < s.end_s < t1:
                    t1 = s.end_s
            rhs = self.theta_K + self._deposit_K(self.t_s, t1)
            self.theta_K = solve_banded((1, 1), self._matrix(t1 - self.t_s), rhs)
            self.t_s = t1
            self.sources = [s for s in self.sources if s.end_s > self.t_s]
            self._cumulative = None

    # ------------------------------------------------------------ what sensors see
    def temperature_rise_K(self, at_mm: float, t_s: float) -> float:
        """Screw temperature above ambient at a point of the screw."""
        self.advance(t_s)
        return float(np.interp(at_mm, self.x_mm, self.theta_K))

    def growth_mm(self, at_mm: float, t_s: float) -> float:
        """Thermal displacement of the screw at ``at_mm`` relative to its fixed end."""
        self.advance(t_s)
        if self._cumulative is None:
            mid = (self.theta_K[1:] + self.theta_K[:-1]) / 2.0 * self.dx_mm
            self._cumulative = np.concatenate(([0.0], np.cumsum(mid)))
        c = self._cumulative
        integral = np.interp(at_mm, self.x_mm, c) - np.interp(self.fixed_mm, self.x_mm, c)
        return self.cfg.alpha_per_K * float(integral)
