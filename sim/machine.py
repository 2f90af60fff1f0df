"""The true machine: commanded motor position -> true table position. Pure numpy, no I/O.

Written from the physics, independently of ``gateway.compensation`` (never import it):

* motor: moves at constant speed from its position to the target (no ramps); the drive's
  feedback is this motor-side position (semi-closed loop).
* backlash: a play (dead-band) between motor and nut. The nut coordinate ``u`` is kept in
  the band ``[m, m + B(m)]``: pushing forward drags it to ``u = m``, pushing back to
  ``u = m + B``; a reversal smaller than B leaves the table where it is. Convention: the
  forward approach is the reference (the machine starts as after a forward approach).
* pitch: error(u) = slope + polynomial over travel + periodic (once per lead) + table.
* thermal: one screw temperature per axis, heated by each move (per metre at a reference
  speed, scaled by speed) and cooling to ambient with a time constant; the screw grows
  ``alpha * (T - ambient) * (u - origin)`` from its fixed end.
* XY plane: squareness, straightness bows and a cross term (see :class:`PlaneConfig`).
* repeatability: a fresh normal offset (sigma ``repeatability_um``) on each stop.

Data-driven axes (issue 14, any of ``deviation``, ``lost_motion``, ``cyclic``): the table
sits at motor + forward deviation + s · lost motion, s the nut's state between its two
flanks (0 after moving +, 1 after moving −) moved by each reversal along its take-up curve
(:class:`sim.truth.TakeUpCurve`). On any axis: ``stick_slip`` (a stop short of the target),
``settling`` (ringing after the stop), ``heat`` (a temperature profile along the screw,
:mod:`sim.heat`), and the plane's measured ``field``.
Rotary axes (issue 16, ``swing`` or ``turntable``): positions are degrees; the truth in
:mod:`sim.rotary` gives the play (through the same play operator) and the table's angle.
All randomness comes from generators spawned from the seed, one per axis.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from sim.config import AxisConfig, AxisErrors, PitchConfig, PlaneConfig, SimSection, ThermalConfig
from sim.heat import ScrewHeatModel
from sim.rotary import RotaryTruth, rotary_truth
from sim.truth import ScrewTruth, XYField, load_screw

ARCSEC_RAD = math.pi / (180.0 * 3600.0)


class PitchModel:
    """Pitch error in mm as a function of the nut coordinate (vectorised)."""

    def __init__(
        self,
        cfg: PitchConfig,
        travel_mm: tuple[float, float],
        table: tuple[np.ndarray, np.ndarray] | None = None,
    ) -> None:
        self.cfg = cfg
        self.x0_mm, x1_mm = travel_mm
        self.length_mm = x1_mm - self.x0_mm
        self.table = table

    def error_mm(self, u_mm: np.ndarray | float) -> np.ndarray:
        """True minus commanded position caused by the screw, mm."""
        u = np.asarray(u_mm, dtype=float)
        err_um = self.cfg.slope_um_per_m * (u - self.x0_mm) / 1000.0
        if self.cfg.poly_um:
            t = (u - self.x0_mm) / self.length_mm
            # polyval wants the highest power first
            err_um = err_um + np.polyval(np.asarray(self.cfg.poly_um[::-1], dtype=float), t)
        for term in self.cfg.periodic:
            err_um = err_um + term.amplitude_um * np.sin(
                2.0 * np.pi * u / term.period_mm + np.deg2rad(term.phase_deg)
            )
        if self.table is not None:
            err_um = err_um + np.interp(u, self.table[0], self.table[1])
        return err_um / 1000.0


@dataclass
class ThermalState:
    """Screw temperature: a committed value plus the heating segment of the latest move."""

    cfg: ThermalConfig
    temp_C: float
    at_s: float = 0.0
    heat_from_s: float = 0.0
    heat_to_s: float = 0.0
    heat_rate_K_s: float = 0.0

    def temp_at(self, t_s: float) -> float:
        """Temperature at machine time ``t_s`` (>= the committed time)."""
        tau, amb = self.cfg.tau_s, self.cfg.ambient_C
        temp, now = self.temp_C, self.at_s
        # three pieces: cooling before the heating segment, heating, cooling after
        for start, end, rate in (
            (now, min(t_s, self.heat_from_s), 0.0),
            (max(now, self.heat_from_s), min(t_s, self.heat_to_s), self.heat_rate_K_s),
            (max(now, self.heat_to_s), t_s, 0.0),
        ):
            dt = end - start
            if dt <= 0:
                continue
            steady = amb + rate * tau
            temp = steady + (temp - steady) * math.exp(-dt / tau)
            now = end
        return temp

    def add_heat(self, t_s: float, duration_s: float, heat_K: float) -> None:
        """Commit the state at ``t_s`` and heat by ``heat_K`` spread over the move."""
        self.temp_C = self.temp_at(t_s)
        self.at_s = t_s
        if duration_s <= 0:
            self.temp_C += heat_K
            self.heat_from_s = self.heat_to_s = t_s
            self.heat_rate_K_s = 0.0
        else:
            self.heat_from_s, self.heat_to_s = t_s, t_s + duration_s
            self.heat_rate_K_s = heat_K / duration_s

    def growth_mm(self, u_mm: float, t_s: float) -> float:
        """Screw growth at nut coordinate ``u_mm``, from the fixed end ``origin_mm``."""
        d_temp = self.temp_at(t_s) - self.cfg.ambient_C
        return self.cfg.alpha_per_K * d_temp * (u_mm - self.cfg.origin_mm)


@dataclass
class AxisState:
    """One axis: motor motion, nut (backlash) state, stop noise, screw temperature."""

    name: str
    cfg: AxisConfig
    errors: AxisErrors
    pitch: PitchModel
    rng: np.random.Generator
    thermal: ThermalState | None
    start_pulses: float = 0.0
    target_pulses: float = 0.0
    start_s: float = 0.0
    end_s: float = 0.0
    nut_mm: float = 0.0  # nut coordinate at the start of the current move / when settled
    noise_mm: float = 0.0
    moving: bool = False
    stops: int = 0
    distance_mm: float = field(default=0.0)
    screw: ScrewTruth | None = None  # data-driven deviation and lost motion
    heat: ScrewHeatModel | None = None  # temperature profile along the screw
    takeup_s0: float = 0.0  # nut state at the start of the current move / at rest
    move_dir: int = 0  # +1 / -1 / 0 of the current (or last) move
    play_start_mm: float = 0.0  # lost motion where the current move started
    stop_s: float = -math.inf  # when the last real move ended (settling)
    stop_dir: int = 0
    stick_mm: float = 0.0  # how far the last stop stuck short (signed, mm)
    rotary: RotaryTruth | None = None  # swing or turntable truth (degrees)

    def takeup_at(self, t_s: float) -> float:
        """Nut state s at ``t_s`` (data-driven axes): 0 on the + flank, 1 on the − flank."""
        if self.screw is None or not self.moving:
            return self.takeup_s0
        r_mm = abs(self.motor_pulses(t_s) - self.start_pulses) * self.cfg.pulse_mm
        return self.screw.takeup.after(self.takeup_s0, self.move_dir, r_mm, self.play_start_mm)

    def after_stop_mm(self, t_s: float) -> float:
        """Stick-slip shortfall plus the settling ringing of the last stop, mm."""
        out = self.stick_mm
        st = self.errors.settling
        if st is not None and not self.moving and self.stop_dir != 0:
            dt = t_s - self.stop_s
            ring = math.cos(2.0 * math.pi * dt / st.period_s) if st.period_s else 1.0
            decay = math.exp(-dt / st.time_constant_s)
            out += self.stop_dir * st.amplitude_um / 1000.0 * decay * ring
        return out

    def ringing_um(self, t_s: float) -> float:
        """Envelope of the settling ringing now (µm; inf while moving)."""
        if self.moving:
            return math.inf
        st = self.errors.settling
        if st is None or self.stop_dir == 0:
            return 0.0
        return abs(st.amplitude_um) * math.exp(-(t_s - self.stop_s) / st.time_constant_s)

    def backlash_mm(self, motor_mm: float) -> float:
        """Play between motor and nut at this motor position (never negative)."""
        if self.rotary is not None:
            return self.rotary.play_deg(motor_mm)
        x_m = (motor_mm - self.cfg.travel_mm[0]) / 1000.0
        return max(0.0, self.errors.backlash_um + self.errors.backlash_um_per_m * x_m) / 1000.0

    def motor_pulses(self, t_s: float) -> float:
        """Motor position in pulses at time ``t_s`` (linear during a move)."""
        if not self.moving or t_s >= self.end_s:
            return self.target_pulses
        frac = (t_s - self.start_s) / (self.end_s - self.start_s)
        return self.start_pulses + frac * (self.target_pulses - self.start_pulses)

    def nut_at(self, t_s: float) -> float:
        """Nut coordinate (mm) after the play operator at the motor's current position."""
        motor_mm = self.motor_pulses(t_s) * self.cfg.pulse_mm
        return min(max(float(self.nut_mm), motor_mm), motor_mm + self.backlash_mm(motor_mm))


class Machine:
    """All axes plus the XY plane; the single source of truth for where the table is."""

    def __init__(
        self,
        cfg: SimSection,
        pitch_tables: dict[str, tuple[np.ndarray, np.ndarray]] | None = None,
        base_dir: str = ".",
    ) -> None:
        pitch_tables = pitch_tables or {}
        self.cfg = cfg
        self.plane: PlaneConfig | None = cfg.plane
        self.field = (
            XYField(cfg.plane.field, base_dir)
            if cfg.plane is not None and cfg.plane.field is not None
            else None
        )
        seeds = np.random.SeedSequence(cfg.seed).spawn(len(cfg.axes))
        self.axes: dict[str, AxisState] = {}
        for (name, axis_cfg), seq in zip(cfg.axes.items(), seeds, strict=True):
            errs = cfg.machine.get(name, AxisErrors())
            thermal = ThermalState(errs.thermal, errs.thermal.ambient_C) if errs.thermal else None
            self.axes[name] = AxisState(
                name=name,
                cfg=axis_cfg,
                errors=errs,
                pitch=PitchModel(errs.pitch, axis_cfg.travel_mm, pitch_tables.get(name)),
                rng=np.random.default_rng(seq),
                thermal=thermal,
                screw=load_screw(errs.deviation, errs.lost_motion, errs.cyclic,
                                 errs.backlash_um, base_dir) if errs.data_driven else None,
                heat=ScrewHeatModel(errs.heat, axis_cfg.travel_mm) if errs.heat else None,
                rotary=rotary_truth(errs.swing, errs.turntable),
            )  # fmt: skip

    # ------------------------------------------------------------ motion
    def begin_move(self, name: str, target_pulses: int, speed_mm_s: float, now_s: float) -> float:
        """Start a move from wherever the motor is now; return its duration in seconds."""
        ax = self.axes[name]
        self.update(now_s)
        here_pulses = ax.motor_pulses(now_s)
        ax.nut_mm = ax.nut_at(now_s)
        ax.takeup_s0 = ax.takeup_at(now_s)
        distance_mm = abs(target_pulses - here_pulses) * ax.cfg.pulse_mm
        duration_s = distance_mm / speed_mm_s
        here_mm = here_pulses * ax.cfg.pulse_mm
        ax.move_dir = int(np.sign(target_pulses - here_pulses))
        if ax.screw is not None:
            ax.play_start_mm = ax.screw.lost_motion_mm(here_mm)
        if ax.heat is not None:
            ax.heat.add_move(now_s, now_s + duration_s, here_mm,
                             target_pulses * ax.cfg.pulse_mm, speed_mm_s)  # fmt: skip
        ax.start_pulses, ax.target_pulses = here_pulses, float(target_pulses)
        ax.start_s, ax.end_s = now_s, now_s + duration_s
        ax.moving = True
        ax.noise_mm = 0.0
        ax.stick_mm = 0.0
        ax.distance_mm += distance_mm
        if ax.thermal is not None:
            th = ax.thermal.cfg
            heat_K = th.heat_K_per_m * distance_mm / 1000.0 * speed_mm_s / th.ref_speed_mm_s
            ax.thermal.add_heat(now_s, duration_s, heat_K)
        return duration_s

    def update(self, now_s: float) -> None:
        """Settle every move that has ended by ``now_s`` (draws its stop noise)."""
        for ax in self.axes.values():
            if ax.moving and now_s >= ax.end_s:
                ax.nut_mm = ax.nut_at(ax.end_s)
                ax.takeup_s0 = ax.takeup_at(ax.end_s)
                ax.moving = False
                ax.stops += 1
                sigma_mm = ax.errors.repeatability_um / 1000.0
                if ax.rotary is not None:
                    sigma_mm = ax.rotary.repeatability_deg
                ax.noise_mm = float(ax.rng.normal(0.0, sigma_mm)) if sigma_mm > 0 else 0.0
                if ax.move_dir != 0:
                    ax.stop_s, ax.stop_dir = ax.end_s, ax.move_dir
                    ax.stick_mm = self._stick_mm(ax)

    @staticmethod
    def _stick_mm(ax: AxisState) -> float:
        """Draw how far this stop sticks short (against the move's direction), mm."""
        st = ax.errors.stick_slip
        if st is None or ax.rng.random() >= st.probability:
            return 0.0
        short_um = min(float(ax.rng.exponential(st.mean_um)), st.band_um)
        return -ax.move_dir * short_um / 1000.0

    def is_moving(self, name: str, now_s: float) -> bool:
        """True while the axis' motor is moving."""
        self.update(now_s)
        return self.axes[name].moving

    def motor_pulses(self, name: str, now_s: float) -> int:
        """Motor position in whole pulses (what the encoder counts)."""
        self.update(now_s)
        return round(self.axes[name].motor_pulses(now_s))

    # ------------------------------------------------------------ truth
    def _axis_true_mm(self, ax: AxisState, now_s: float) -> tuple[float, float]:
        """(true position along the axis without plane terms, nut coordinate)."""
        if ax.rotary is not None:
            nut_mm = ax.nut_at(now_s)
            true_mm = ax.rotary.true_deg(nut_mm) + ax.noise_mm
        elif ax.screw is None:
            nut_mm = ax.nut_at(now_s)
            true_mm = nut_mm + float(ax.pitch.error_mm(nut_mm)) + ax.noise_mm
        else:  # data-driven: motor + forward deviation + s · lost motion
            nut_mm = ax.motor_pulses(now_s) * ax.cfg.pulse_mm
            true_mm = nut_mm + float(ax.pitch.error_mm(nut_mm)) + ax.noise_mm
            true_mm += ax.screw.forward_mm(nut_mm)
            true_mm += ax.takeup_at(now_s) * ax.screw.lost_motion_mm(nut_mm)
        if ax.thermal is not None:
            true_mm += ax.thermal.growth_mm(nut_mm, now_s)
        if ax.heat is not None:
            true_mm += ax.heat.growth_mm(nut_mm, now_s)
        if ax.stick_mm or ax.errors.settling is not None:
            true_mm += ax.after_stop_mm(now_s)
        return true_mm, nut_mm

    def table_xy_mm(self, now_s: float) -> tuple[float, float]:
        """True (X, Y) of the table in the plane's axes, with all plane errors."""
        if self.plane is None:
            raise ValueError("no plane configured")
        self.update(now_s)
        ax_x, ax_y = (self.axes[n] for n in self.plane.axes)
        x_mm, ux_mm = self._axis_true_mm(ax_x, now_s)
        y_mm, uy_mm = self._axis_true_mm(ax_y, now_s)
        tx = (ux_mm - ax_x.cfg.travel_mm[0]) / (ax_x.cfg.travel_mm[1] - ax_x.cfg.travel_mm[0])
        ty = (uy_mm - ax_y.cfg.travel_mm[0]) / (ax_y.cfg.travel_mm[1] - ax_y.cfg.travel_mm[0])
        p = self.plane
        x_mm += (uy_mm - ax_y.cfg.travel_mm[0]) * math.tan(p.squareness_arcsec * ARCSEC_RAD)
        x_mm += (p.straightness_y_um * 4.0 * ty * (1.0 - ty) + p.cross_um * tx * ty) / 1000.0
        y_mm += p.straightness_x_um * 4.0 * tx * (1.0 - tx) / 1000.0
        if self.field is not None:
            ex_mm, ey_mm = self.field.error_mm(ux_mm, uy_mm)
            x_mm, y_mm = x_mm + ex_mm, y_mm + ey_mm
        return x_mm, y_mm

    def table_mm(self, name: str, now_s: float) -> float:
        """True table position along one axis (plane terms included for plane axes)."""
        self.update(now_s)
        if self.plane is not None and name in self.plane.axes:
            return self.table_xy_mm(now_s)[self.plane.axes.index(name)]
        return self._axis_true_mm(self.axes[name], now_s)[0]

    def screw_temp_C(self, name: str, now_s: float, at_mm: float | None = None) -> float:
        """Screw temperature (ambient when the axis has no thermal model); with a ``heat``
        profile, where the sensor sits (``at_mm``, default mid-travel)."""
        ax = self.axes[name]
        if ax.heat is not None:
            lo, hi = ax.cfg.travel_mm
            where = at_mm if at_mm is not None else (lo + hi) / 2.0
            return ax.heat.cfg.ambient_C + ax.heat.temperature_rise_K(where, now_s)
        th = ax.thermal
        return th.temp_at(now_s) if th is not None else self.ambient_C()

    def ambient_C(self) -> float:
        """Ambient temperature (of the first thermal model; 20 degC without one)."""
        for ax in self.axes.values():
            if ax.thermal is not None:
                return ax.thermal.cfg.ambient_C
            if ax.heat is not None:
                return ax.heat.cfg.ambient_C
        return 20.0

    def delta_a_mm(self, name: str, a_mm: float, now_s: float) -> float:
        """Growth of the screw at reference point A since the cold state (seed 002)."""
        ax = self.axes[name]
        if ax.heat is not None:
            return ax.heat.growth_mm(a_mm, now_s)
        th = ax.thermal
        return th.growth_mm(a_mm, now_s) if th is not None else 0.0

    def ringing_um(self, name: str, now_s: float) -> float:
        """How far the axis still rings after its last stop (inf while it moves)."""
        self.update(now_s)
        return self.axes[name].ringing_um(now_s)
