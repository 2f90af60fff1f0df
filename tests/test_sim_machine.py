"""The simulated machine measured back through Modbus, as a technician would.

Drive the sim directly (no gateway), read the simulated laser / XY device / sensors, and
compare with values computed here from the YAML numbers (never by calling sim code).
"""

from __future__ import annotations

import math

import numpy as np

from sim.server import SimServer
from tests.test_sim_support import Master, config_from, example_dict, run, tcp_client


def pitch_um(errs: dict, x_mm: float, travel: list[float]) -> float:
    """The configured pitch error at x, written out from the config keys."""
    p = errs["pitch"]
    t = (x_mm - travel[0]) / (travel[1] - travel[0])
    e = p.get("slope_um_per_m", 0.0) * (x_mm - travel[0]) / 1000.0
    e += sum(c * t**k for k, c in enumerate(p.get("poly_um", [])))
    for term in p.get("periodic", []):
        e += term["amplitude_um"] * math.sin(
            2 * math.pi * x_mm / term["period_mm"] + math.radians(term.get("phase_deg", 0.0))
        )
    return e


def without_thermal(data: dict) -> dict:
    for errs in data["sim"]["machine"].values():
        errs.pop("thermal", None)
    data["sim"]["instruments"].pop("delta_a", None)
    return data


def test_pitch_profile_measured_by_laser() -> None:
    """Forward approach to 17 targets on X and 13 on Y: laser - target = configured pitch."""
    data = without_thermal(example_dict())
    sim = data["sim"]
    noise_um = math.hypot(
        sim["machine"]["X"]["repeatability_um"], sim["instruments"]["laser"]["noise_um"]
    )
    tol_um = 4 * noise_um + sim["instruments"]["laser"]["resolution_um"]

    async def script() -> dict[str, list[tuple[float, float, float]]]:
        async with SimServer(config_from(data), tcp_port=0) as server:
            m = Master(await tcp_client(server.tcp_port), data)
            out: dict[str, list[tuple[float, float, float]]] = {"X": [], "Y": []}
            for axis, end_mm, step_mm in (("X", 800, 50), ("Y", 600, 50)):
                travel = sim["axes"][axis]["travel_mm"]
                for x_mm in np.arange(0.0, end_mm + 1, step_mm):
                    await m.move_mm(axis, float(x_mm))
                    measured_um = await m.laser_um(axis) - x_mm * 1000
                    expected_um = pitch_um(sim["machine"][axis], float(x_mm), travel)
                    out[axis].append((float(x_mm), measured_um, expected_um))
            m.client.close()
            return out

    result = run(script())
    for axis, rows in result.items():
        arr = np.array(rows)
        worst = np.max(np.abs(arr[:, 1] - arr[:, 2]))
        assert worst < tol_um, (axis, worst, rows)
        # the profile is real: tens of micrometres peak to peak over the travel
        assert np.ptp(arr[:, 1]) > 5.0
    p2p = {a: round(float(np.ptp(np.array(r)[:, 1])), 2) for a, r in result.items()}
    print("pitch p2p um:", p2p)


def test_backlash_measured_like_seed_000() -> None:
    """Approach a point from below and from above, 7 times, at 3 places: mean difference = B."""
    data = without_thermal(example_dict())
    x_errs = data["sim"]["machine"]["X"]
    travel = data["sim"]["axes"]["X"]["travel_mm"]
    repeats = 7

    async def script() -> list[tuple[float, float]]:
        async with SimServer(config_from(data), tcp_port=0) as server:
            m = Master(await tcp_client(server.tcp_port), data)
            out = []
            for x_mm in (100.0, 400.0, 700.0):
                diffs = []
                for _ in range(repeats):
                    await m.move_mm("X", x_mm - 5)
                    await m.move_mm("X", x_mm)
                    up = await m.laser_um("X")
                    await m.move_mm("X", x_mm + 5)
                    await m.move_mm("X", x_mm)
                    down = await m.laser_um("X")
                    diffs.append(down - up)
                out.append((x_mm, float(np.mean(diffs))))
            m.client.close()
            return out

    rows = run(script())
    sigma_mean = x_errs["repeatability_um"] * math.sqrt(2) / math.sqrt(repeats)
    for x_mm, measured_um in rows:
        b_um = x_errs["backlash_um"] + x_errs["backlash_um_per_m"] * x_mm / 1000.0
        # reverse approach: the nut stays B ahead, so the pitch is read at x + B
        expected = (
            b_um + pitch_um(x_errs, x_mm + b_um / 1000, travel) - pitch_um(x_errs, x_mm, travel)
        )
        assert abs(measured_um - expected) < 4 * sigma_mean + 0.1, (x_mm, measured_um, expected)
    print("backlash um (x, measured):", [(x, round(b, 2)) for x, b in rows])


def test_small_reversal_stays_inside_the_play() -> None:
    """Reversing by less than the backlash does not move the table (a dead band)."""
    data = without_thermal(example_dict())
    data["sim"]["machine"]["X"]["repeatability_um"] = 0.0
    data["sim"]["instruments"]["laser"]["noise_um"] = 0.0

    async def script() -> list[float]:
        async with SimServer(config_from(data), tcp_port=0) as server:
            m = Master(await tcp_client(server.tcp_port), data)
            readings = []
            for pulses in (300_000, 299_995, 299_990, 300_000, 300_010):
                await m.move_pulses("X", pulses)
                readings.append(await m.laser_um("X"))
            m.client.close()
            return readings

    r = run(script())
    assert abs(r[1] - r[0]) < 0.15 and abs(r[2] - r[0]) < 0.15  # 5 and 10 um back: no motion
    assert abs(r[3] - r[0]) < 0.15  # forward again inside the play: still no motion
    assert abs(r[4] - r[0] - 10.0) < 0.3  # 10 um forward after re-engaging: moves 10 um


def test_squareness_by_the_xy_device() -> None:
    """At X = 400, step Y over its travel: X drifts by y tan(squareness) + bows + cross."""
    data = without_thermal(example_dict())
    sim = data["sim"]
    plane = sim["plane"]
    x_travel, y_travel = sim["axes"]["X"]["travel_mm"], sim["axes"]["Y"]["travel_mm"]
    x_mm = 400.0
    tx = (x_mm - x_travel[0]) / (x_travel[1] - x_travel[0])

    def expected_dx_um(y_mm: float) -> float:
        ty = (y_mm - y_travel[0]) / (y_travel[1] - y_travel[0])
        angle = math.radians(plane["squareness_arcsec"] / 3600.0)
        return (
            y_mm * 1000 * math.tan(angle)
            + plane["straightness_y_um"] * 4 * ty * (1 - ty)
            + plane["cross_um"] * tx * ty
        )

    async def script() -> list[tuple[float, float]]:
        async with SimServer(config_from(data), tcp_port=0) as server:
            m = Master(await tcp_client(server.tcp_port), data)
            await m.move_mm("X", x_mm)
            out = []
            for y_mm in range(0, 601, 100):
                await m.move_mm("Y", float(y_mm))
                x_um, _ = await m.xy_um()
                out.append((float(y_mm), x_um))
            m.client.close()
            return out

    rows = run(script())
    x0 = rows[0][1]
    tol_um = 4 * math.sqrt(2) * sim["instruments"]["xy"]["noise_um"] + 0.2
    for y_mm, x_um in rows:
        assert abs((x_um - x0) - expected_dx_um(y_mm)) < tol_um, (y_mm, x_um - x0)
    # the squareness itself from a line fit with the known bows removed
    ys = np.array([r[0] for r in rows])
    ty = ys / (y_travel[1] - y_travel[0])
    dx = np.array([r[1] - x0 for r in rows]) - plane["straightness_y_um"] * 4 * ty * (1 - ty)
    dx -= plane["cross_um"] * tx * ty
    slope = np.polyfit(ys * 1000, dx, 1)[0]
    arcsec = math.degrees(math.atan(slope)) * 3600
    assert abs(arcsec - plane["squareness_arcsec"]) < 0.5, arcsec
    print(f"squareness measured {arcsec:.2f} arcsec (configured {plane['squareness_arcsec']})")


def expected_temp_rise_K(thermal: dict, moves: list[tuple[float, float]], idle_s: float) -> float:
    """Screw temperature rise by explicit Euler steps over a move script (distance_mm, speed)."""
    tau = thermal["tau_s"]
    ref = thermal.get("ref_speed_mm_s", 100.0)
    rise, dt = 0.0, 0.01
    for dist_mm, speed in moves:
        dur = dist_mm / speed
        rate = thermal["heat_K_per_m"] * (dist_mm / 1000) * (speed / ref) / dur if dur else 0
        n = max(1, round(dur / dt))
        h = dur / n
        for _ in range(n):
            # midpoint (RK2) step of dT/dt = rate - T/tau
            mid = rise + 0.5 * h * (rate - rise / tau)
            rise += h * (rate - mid / tau)
    return rise * math.exp(-idle_s / tau)


def test_thermal_growth_after_warm_up_and_cooling() -> None:
    """20 round trips 0-800 mm at 100 mm/s, then the laser, delta-a and temperature agree."""
    data = example_dict()
    sim = data["sim"]
    thermal = sim["machine"]["X"]["thermal"]
    ins = sim["instruments"]
    a_mm = ins["delta_a"]["a_mm"]
    speed = sim["axes"]["X"]["speed_mm_s"]
    probe_mm, repeats = 800.0, 5
    script_moves: list[tuple[float, float]] = []

    async def approach(m: Master, n: int) -> float:
        vals = []
        for _ in range(n):
            await m.move_mm("X", probe_mm - 10)
            await m.move_mm("X", probe_mm)
            script_moves.extend([(10.0, speed), (10.0, speed)])
            vals.append(await m.laser_um("X"))
        return float(np.mean(vals))

    async def sensors(m: Master) -> tuple[float, float]:
        rr = await m.client.read_input_registers(0, count=1, device_id=ins["delta_a"]["unit"])
        da = rr.registers[0] - (1 << 16 if rr.registers[0] & 0x8000 else 0)
        rr = await m.client.read_input_registers(0, count=1, device_id=ins["temperature"]["unit"])
        return da * ins["delta_a"]["resolution_um"], rr.registers[0] / 100.0

    async def script() -> dict[str, float]:
        async with SimServer(config_from(data), tcp_port=0) as server:
            m = Master(await tcp_client(server.tcp_port), data)
            await m.move_mm("X", probe_mm - 10)
            script_moves.append((probe_mm - 10, speed))
            cold = await approach(m, repeats)
            da_cold, t_cold = await sensors(m)
            for _ in range(20):
                await m.move_mm("X", 0)
                await m.move_mm("X", probe_mm - 10)
                script_moves.extend([(probe_mm - 10, speed), (probe_mm - 10, speed)])
            warm = await approach(m, repeats)
            da_warm, t_warm = await sensors(m)
            await m.control(0x0800, [int(thermal["tau_s"])])  # advance the clock by one tau
            da_cool, t_cool = await sensors(m)
            m.client.close()
            return dict(
                cold=cold, warm=warm, da_cold=da_cold, da_warm=da_warm, da_cool=da_cool,
                t_cold=t_cold, t_warm=t_warm, t_cool=t_cool,
            )  # fmt: skip

    r = run(script())
    rise_K = expected_temp_rise_K(thermal, script_moves, 0.0)
    growth_um = thermal["alpha_per_K"] * rise_K * (probe_mm - thermal["origin_mm"]) * 1000
    sigma_mean = math.hypot(0.5, 0.05) * math.sqrt(2 / repeats)
    measured_um = r["warm"] - r["cold"]
    assert 10.0 < growth_um < 30.0  # the example machine warms up realistically
    assert abs(measured_um - growth_um) < 4 * sigma_mean + 0.3, (measured_um, growth_um)
    da_expected = thermal["alpha_per_K"] * rise_K * (a_mm - thermal["origin_mm"]) * 1000
    res = ins["delta_a"]["resolution_um"]
    assert abs(r["da_warm"] - da_expected) <= res + 0.5, (r["da_warm"], da_expected)
    assert abs(r["da_cold"]) <= res
    assert abs(r["t_warm"] - thermal["ambient_C"] - rise_K) < 0.05
    assert abs(r["t_cool"] - thermal["ambient_C"] - rise_K / math.e) < 0.05
    assert abs(r["da_cool"] - da_expected / math.e) <= res + 0.5
    print(
        f"thermal: rise {rise_K:.3f} K, growth expected {growth_um:.2f} um, "
        f"measured {measured_um:.2f} um, delta-a {r['da_warm']:.1f} um, "
        f"after one tau {r['da_cool']:.1f} um / {r['t_cool']:.2f} C"
    )
