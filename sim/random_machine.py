"""Random machines: ``compgw sim --random-machine SEED [--roughness smooth|rough] [--out DIR]``.

A 2-axis XY table drawn across what small machines show (ranges and their sources:
sim/README.md, "Random machines"): travel, screw lead, pulse size, ball-screw accuracy class
(mean travel deviation, variation over 300 mm, variation within a turn), nut play (preloaded,
clearance, worn), guideway straightness and squareness, repeatability, screw heating, and
an optional thermal sensor (a Δa displacement sensor, a screw temperature sensor, or none).
The same seed gives the same files byte for byte; ``smooth`` and ``rough`` of one seed share
the same base machine.

``smooth``: every error within shapes the gateway's stages can express (a straight slope
and a low-order bow, a constant once-per-turn term, a play varying linearly and taken up
completely, an XY field that is a degree-2 polynomial, uniform screw heating).
``rough`` adds what no stage models exactly: the once-per-turn amplitude and phase changing
along the travel, 2nd-4th harmonics, waviness of a few centimetres, a worn zone where the
play is larger, play taken up only partly by short reversals, stick-slip, ringing after a
stop, an XY field with non-polynomial shape, and heat where the nut works conducted along
the screw (growth not linear in position).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from sim.machine_files import AxisSpec, MachineSpec

ROUGHNESS = ("smooth", "rough")
#: ISO 3408-3 / JIS B1192 (THK 512E A15-11): ±ep, mean travel deviation over the thread
#: length (µm), precision grades; the lengths are the upper ends of the table's bands
EP_LENGTH_MM = (100, 200, 315, 400, 500, 630, 800, 1000, 1250)
EP_UM = {"C3": (8, 10, 12, 13, 15, 16, 18, 21, 24), "C5": (18, 20, 23, 25, 27, 30, 35, 40, 46)}
#: rolled grades: ±E per 300 mm of travel (µm)
E300_UM = {"C7": 50, "C10": 210}
#: variation within 300 mm (V300) and within one turn (V2π), µm; C7/C10 are not specified
#: by the standard: half of E300 and 12 / 20 µm are our assumptions (sim/README.md)
V300_UM = {"C3": 8, "C5": 18, "C7": 25, "C10": 100}
V2PI_UM = {"C3": 6, "C5": 8, "C7": 12, "C10": 20}
GRADES, GRADE_P = ("C3", "C5", "C7", "C10"), (0.1, 0.35, 0.4, 0.15)
LEADS_MM, LEAD_P = (4.0, 5.0, 10.0, 16.0, 20.0), (0.1, 0.3, 0.35, 0.15, 0.1)
STEEL_RHO_C = 7850.0 * 460.0  # J/(m³ K)
TABLE_STEP_MM = 2.0


def _fourier_shape(rng: np.random.Generator, t: np.ndarray, modes: int) -> np.ndarray:
    """A random smooth curve over t ∈ [0, 1] (amplitudes falling as 1/k), peak-to-peak 1."""
    out = np.zeros_like(t)
    for k in range(1, modes + 1):
        out += rng.normal(0, 1.0 / k) * np.sin(math.pi * k * t + rng.uniform(0, 2 * math.pi))
    return out / max(np.ptp(out), 1e-12)


def _ep_um(grade: str, length_mm: float) -> float:
    if grade in E300_UM:
        return E300_UM[grade] * length_mm / 300.0
    i = min(int(np.searchsorted(EP_LENGTH_MM, length_mm)), len(EP_LENGTH_MM) - 1)
    return float(EP_UM[grade][i])


def _axis(rng: np.random.Generator, rough_rng: np.random.Generator, rough: bool, name: str,
          unit: int, travel_mm: float, pulse_mm: float, scale: int) -> AxisSpec:
    """Draw one axis: screw, nut, motion; ``rough_rng`` draws only the rough extras."""
    lo, hi = 0.0, travel_mm
    lead = float(rng.choice(LEADS_MM, p=LEAD_P))
    grade = str(rng.choice(GRADES, p=GRADE_P))
    speed = float(round(rng.uniform(50, 200), -1))
    thread_mm = travel_mm + 100.0
    x = np.round(np.arange(lo, hi + 1e-9, TABLE_STEP_MM), 4)
    t = (x - lo) / (hi - lo)
    # mean travel deviation: a straight slope within ±ep (most screws well inside it)
    slope_um = rng.uniform(-0.8, 0.8) * _ep_um(grade, thread_mm)
    variation_um = rng.uniform(0.3, 1.0) * V300_UM[grade] * min(1.0, math.sqrt(thread_mm / 300))
    bow = rng.normal(0, 1) * (t * t - t) + rng.normal(0, 0.5) * (t**3 - 1.5 * t * t + 0.5 * t)
    bow = bow / max(np.ptp(bow), 1e-12)
    cyc_um = rng.uniform(0.15, 0.5) * V2PI_UM[grade] / 2.0  # amplitude, from peak to peak
    cyc_phase = rng.uniform(-180, 180)
    preloaded = rng.random() < 0.35
    if preloaded:
        play_um = rng.uniform(0.5, 2.0)
    else:
        play_um = rng.uniform(3, 15) if grade in ("C3", "C5") else rng.uniform(8, 40)
    worn = rng.random() < 0.3
    if worn:
        play_um *= rng.uniform(1.3, 2.0)
    play_gradient = rng.uniform(-0.4, 0.4)
    repeat_um = round(rng.uniform(0.1, 0.5), 2)
    fixed_at_low = rng.random() < 0.75
    heat_rise_K = rng.uniform(1.5, 6.0)  # steady rise of the screw in continuous motion
    diameter = float(rng.choice((12.0, 16.0, 20.0, 25.0)))
    h = rng.uniform(10, 25)
    nut_mm = round(rng.uniform(30, 60))

    forward = slope_um * t + variation_um * bow
    lost = play_um * (1 + play_gradient * (t - 0.5))
    info: dict[str, Any] = {"screw_grade": grade, "nut": "preloaded" if preloaded else
                            "clearance", "worn": worn, "repeatability_um": repeat_um}  # fmt: skip
    stations = np.array([lo, hi])
    amps = np.full((1, 2), cyc_um)
    phases = np.full((1, 2), cyc_phase)
    takeup = stick = settling = None
    extras: list[str] = []
    # rough: draw everything, always in the same order, from its own generator
    r_modes = _fourier_shape(rough_rng, t, 8)
    r_wave = np.zeros_like(t)
    for _ in range(int(rough_rng.integers(3, 7))):
        wl = rough_rng.uniform(15, 80)
        r_wave += rough_rng.normal(0, 1) * np.sin(2 * math.pi * x / wl + rough_rng.uniform(0, 6.3))
    wave_rms = rough_rng.uniform(0.3, 1.0) * V2PI_UM[grade] / 6.0
    r_wave *= wave_rms / max(float(np.sqrt(np.mean(r_wave**2))), 1e-12)
    n_st = 9
    r_stations = np.linspace(lo, hi, n_st)
    walk = np.cumsum(rough_rng.normal(0, 0.25, n_st))
    r_a1 = cyc_um * np.clip(np.exp(walk - walk.mean()), 0.4, 1.8)
    drift = np.linspace(0, rough_rng.uniform(-60, 60), n_st)
    r_p1 = cyc_phase + drift + rough_rng.normal(0, 5, n_st)
    k_max = int(rough_rng.integers(2, 5))
    r_amps, r_phases = [r_a1], [r_p1]
    for k in range(2, k_max + 1):
        rel = rough_rng.uniform(0.1, 0.5) / (k - 1)
        r_amps.append(r_a1 * rel * np.clip(1 + rough_rng.normal(0, 0.3, n_st), 0.3, 1.7))
        r_phases.append(rough_rng.uniform(-180, 180) + np.cumsum(rough_rng.normal(0, 8, n_st)))
    wear_w, wear_c, wear_s = rough_rng.uniform(0.3, 1.0), rough_rng.uniform(0.3, 0.7), \
        rough_rng.uniform(0.1, 0.25)  # fmt: skip
    takeup_factor = rough_rng.uniform(2.2, 4.0)
    stick_on = rough_rng.random() < 0.6
    stick_draw = {"probability": round(rough_rng.uniform(0.1, 0.4), 3),
                  "mean_um": round(rough_rng.uniform(0.2, 1.0), 3),
                  "band_um": round(rough_rng.uniform(1.0, 3.0), 3)}  # fmt: skip
    settle_on = rough_rng.random() < 0.5
    settle_draw = {"amplitude_um": round(rough_rng.uniform(0.3, 2.0), 3),
                   "time_constant_s": round(rough_rng.uniform(0.02, 0.15), 3),
                   "period_s": round(rough_rng.uniform(0.02, 0.08), 3)}  # fmt: skip
    if rough:
        forward = slope_um * t + variation_um * r_modes + r_wave
        lost = lost * (1 + wear_w * np.exp(-(((t - wear_c) / wear_s) ** 2)))
        stations, amps, phases = r_stations, np.array(r_amps), np.array(r_phases)
        takeup = {"curve": "smooth",
                  "distance_um": round(takeup_factor * 1.05 * float(lost.max()), 2)}  # fmt: skip
        extras += [f"once-per-turn amplitude {r_a1.min():.2f}-{r_a1.max():.2f} um along the "
                   f"travel, phase drifting {np.ptp(r_p1):.0f} deg",
                   f"harmonics 2..{k_max}", f"waviness {wave_rms:.2f} um RMS (15-80 mm)",
                   f"worn zone: play +{100 * wear_w:.0f} % at {wear_c * travel_mm:.0f} mm",
                   f"partial take-up over {takeup['distance_um']:g} um of reversal"]  # fmt: skip
        if stick_on:
            stick = stick_draw
            extras.append(f"stick-slip p={stick['probability']:g} mean {stick['mean_um']:g} um")
        if settle_on:
            settling = settle_draw
            extras.append(f"settling {settling['amplitude_um']:g} um, "
                          f"tau {settling['time_constant_s']:g} s")  # fmt: skip
    reverse = forward + lost
    info.update(play_um=[round(float(lost.min()), 2), round(float(lost.max()), 2)],
                once_per_turn_um=round(float(amps[0].max()), 3), harmonics=int(amps.shape[0]))
    if extras:
        info["beyond_the_gateway_models"] = extras
    area_m2 = math.pi * (diameter / 1000) ** 2 / 4
    screw = (lo - nut_mm, hi + nut_mm)
    # the nut's drag torque that warms the screw (lumped) by heat_rise_K at full duty:
    # rise = power · tau / heat capacity, power = 2π · torque · speed / lead
    tau_s = STEEL_RHO_C * diameter / 1000 / (4 * h)
    heat_cap = STEEL_RHO_C * area_m2 * (screw[1] - screw[0]) / 1000
    torque = heat_rise_K * heat_cap / tau_s / (2 * math.pi * speed / lead)
    fixed = screw[0] if fixed_at_low else screw[1]
    if rough:
        thermal = {"heat": {"lead_mm": lead, "drag_torque_Nm": round(torque, 5),
                            "diameter_mm": diameter, "nut_length_mm": float(nut_mm),
                            "h_W_m2K": round(h, 2), "screw_mm": list(screw),
                            "fixed_end_mm": fixed}}  # fmt: skip
    else:  # the same screw, lumped: one temperature, growth linear from the fixed end
        joule_per_m = 2 * math.pi * torque / (lead / 1000)
        thermal = {"thermal": {"alpha_per_K": 11.5e-6, "origin_mm": fixed,
                               "heat_K_per_m": round(joule_per_m / heat_cap, 5),
                               "ref_speed_mm_s": speed, "tau_s": round(tau_s, 1)}}
    info["thermal"] = ("heat profile along the screw" if rough else "uniform screw temperature")
    info["heat_rise_K"] = round(heat_rise_K, 2)
    return AxisSpec(
        name=name, unit=unit, travel_mm=(lo, hi), speed_mm_s=speed, pulse_mm=pulse_mm,
        command_scale=scale, positions_mm=x, forward_um=forward, reverse_um=reverse,
        lead_mm=lead, cyclic=(stations, amps, phases), takeup=takeup,
        repeatability_um=repeat_um, stick_slip=stick, settling=settling, thermal=thermal,
        fixed_end_mm=fixed, info=info,
    )  # fmt: skip


def _field(rng: np.random.Generator, rough_rng: np.random.Generator, rough: bool,
           x_axis: AxisSpec, y_axis: AxisSpec) -> tuple[tuple[np.ndarray, ...], dict[str, Any]]:
    """The XY field on a 17 x 13 grid of nodes."""
    xs = np.round(np.linspace(*x_axis.travel_mm, 17), 4)
    ys = np.round(np.linspace(*y_axis.travel_mm, 13), 4)
    gx, gy = np.meshgrid(xs, ys, indexing="ij")
    tx = (gx - xs[0]) / (xs[-1] - xs[0])
    ty = (gy - ys[0]) / (ys[-1] - ys[0])
    square_arcsec = rng.uniform(5, 60) * rng.choice((-1, 1))
    sx_um = rng.uniform(2, 25) * rng.choice((-1, 1))  # straightness of X's motion (in Y)
    sy_um = rng.uniform(2, 25) * rng.choice((-1, 1))  # straightness of Y's motion (in X)
    cross_um = rng.uniform(-8, 8)
    ex = (gy - ys[0]) * 1000 * math.tan(math.radians(square_arcsec / 3600))
    info = {"squareness_arcsec": round(square_arcsec, 2), "straightness_x_um": round(sx_um, 2),
            "straightness_y_um": round(sy_um, 2)}  # fmt: skip
    shape_x = _fourier_shape(rough_rng, np.linspace(0, 1, xs.size), 6)
    shape_y = _fourier_shape(rough_rng, np.linspace(0, 1, ys.size), 6)
    sag_um = rough_rng.uniform(2, 8) * rough_rng.choice((-1, 1))
    modes_um = rough_rng.uniform(1, 5)
    mode_ex = np.zeros_like(gx)
    mode_ey = np.zeros_like(gx)
    for k in range(1, 4):
        for m in range(1, 4):
            a, b = rough_rng.normal(0, 1, 2) / (k * m)
            phase = rough_rng.uniform(0, 2 * math.pi, 2)
            mode_ex += a * np.sin(math.pi * k * tx + phase[0]) * np.sin(math.pi * m * ty)
            mode_ey += b * np.sin(math.pi * k * tx) * np.sin(math.pi * m * ty + phase[1])
    if not rough:  # a degree-2 polynomial: squareness, parabolic bows, a bilinear twist
        ex = ex + sy_um * 4 * ty * (1 - ty) + cross_um * tx * ty
        ey = sx_um * 4 * tx * (1 - tx)
        info["field"] = "degree-2 polynomial"
    else:
        ex = ex + sy_um * shape_y[None, :] + sag_um * np.sin(math.pi * tx) * np.sin(math.pi * ty)
        ey = sx_um * np.broadcast_to(shape_x[:, None], gx.shape)
        scale = modes_um / max(np.ptp(mode_ex), np.ptp(mode_ey), 1e-12)
        ex, ey = ex + scale * mode_ex, ey + scale * mode_ey
        info["field"] = (f"not polynomial: guide shapes of 6 modes, a {sag_um:.1f} um sag, "
                         f"{modes_um:.1f} um of 2-D modes")  # fmt: skip
    return (xs, ys, np.asarray(ex), np.asarray(ey)), info


def random_machine(seed: int, roughness: str = "smooth") -> MachineSpec:
    """Draw the machine of ``seed`` (deterministic; ``roughness`` smooth or rough)."""
    if roughness not in ROUGHNESS:
        raise ValueError(f"roughness {roughness!r} is not one of {', '.join(ROUGHNESS)}")
    rough = roughness == "rough"
    rng = np.random.default_rng([seed, 14])
    rough_rng = np.random.default_rng([seed, 14, 1])
    travel_x = float(rng.choice(np.arange(200, 1001, 50)))
    travel_y = float(rng.choice(np.arange(150, min(travel_x, 800) + 1, 50)))
    pulse_mm = float(rng.choice((0.001, 0.0005, 0.002), p=(0.7, 0.2, 0.1)))
    scale = int(rng.choice((10, 5, 2, 1), p=(0.5, 0.2, 0.15, 0.15)))
    x_axis = _axis(rng, rough_rng, rough, "X", 1, travel_x, pulse_mm, scale)
    y_axis = _axis(rng, rough_rng, rough, "Y", 2, travel_y, pulse_mm, scale)
    field, field_info = _field(rng, rough_rng, rough, x_axis, y_axis)
    kind = str(rng.choice(("none", "delta_a", "temperature")))
    free_end = x_axis.thermal or {}
    sensor: dict[str, Any] | None = None
    if kind == "delta_a":  # at the screw's free end (rough) or the end of travel (smooth)
        heat = free_end.get("heat")
        if heat is not None:
            s0, s1 = heat["screw_mm"]
            a_mm = s1 if heat["fixed_end_mm"] == s0 else s0
        else:
            a_mm = x_axis.travel_mm[1] if x_axis.fixed_end_mm < 0 else x_axis.travel_mm[0]
        # mounted to read the elongation positive, whichever end is held
        direction = 1 if a_mm > x_axis.fixed_end_mm else -1
        sensor = {"kind": "delta_a", "axis": "X", "a_mm": float(a_mm), "direction": direction}
    elif kind == "temperature":
        spots = rng.uniform(0.2, 0.8, 2)
        positions = {ax.name: round(ax.travel_mm[0] + (f if rough else 0.5) *
                                    (ax.travel_mm[1] - ax.travel_mm[0]), 1)
                     for ax, f in zip((x_axis, y_axis), spots)}  # fmt: skip
        sensor = {"kind": "temperature", "positions_mm": positions}
    sample_s = round(float(rough_rng.uniform(0.02, 0.1)), 3) if rough else 0.0
    name = f"random-{seed}-{roughness}"
    header = (f"{name}: drawn by `compgw sim --random-machine {seed} --roughness {roughness}`\n"
              "(deterministic per seed; ranges and sources: sim/README.md, Random machines)")
    info = {"seed": seed, "roughness": roughness,
            "generator": f"compgw sim --random-machine {seed} --roughness {roughness}",
            "thermal_sensor": kind, "plane": field_info,
            "instrument_sample_s": sample_s}  # fmt: skip
    return MachineSpec(name=name, sim_seed=seed, axes=(x_axis, y_axis), field=field,
                       sensor=sensor, sample_s=sample_s, header=header, info=info)

