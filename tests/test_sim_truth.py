"""The data-driven truth of the sim (issue 14), measured back through Modbus as a technician
would: moves through the simulated drive, readings from the simulated laser, XY device and
sensors, over real loopback sockets. Expectations come from the CSV numbers written here and
closed-form physics, never from sim code.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from sim.server import SimServer
from tests.test_sim_support import Master, config_from, example_dict, run, s32, tcp_client

ADVANCE_S, ADVANCE_MS = 0x0800, 0x0801


def quiet_machine(**x_errors: object) -> dict:
    """The example machine, X's errors replaced, no noise anywhere, no thermal on Y."""
    data = example_dict()
    sim = data["sim"]
    sim["time_scale"] = 0  # moves are instant, the clock moves only when told
    sim["machine"]["X"] = {"repeatability_um": 0.0, **x_errors}
    sim["machine"]["Y"] = {"repeatability_um": 0.0}
    sim["plane"] = {"axes": ["X", "Y"]}
    sim["instruments"]["laser"]["noise_um"] = 0.0
    sim["instruments"]["laser"]["resolution_um"] = 0.001
    sim["instruments"]["xy"]["noise_um"] = 0.0
    sim["instruments"]["xy"]["resolution_um"] = 0.001
    sim["instruments"].pop("delta_a")
    sim["instruments"].pop("temperature")
    return data


def write_csv(path: Path, header: str, rows: list[tuple[float, ...]]) -> str:
    path.write_text(header + "\n" + "".join(",".join(f"{v:g}" for v in r) + "\n" for r in rows))
    return str(path)


async def approach(m: Master, axis: str, pos_mm: float, direction: int, takeup_mm: float = 5.0
                   ) -> float:  # fmt: skip
    """Deviation (µm) at ``pos_mm`` approached moving ``direction`` after a long take-up."""
    await m.move_mm(axis, pos_mm - direction * takeup_mm)
    await m.move_mm(axis, pos_mm)
    return await m.laser_um(axis) - pos_mm * 1000


def test_deviation_table_both_directions_at_its_points_and_linear_between(tmp_path):
    rows = [(0, 0.0, 12.0), (200, 8.5, 19.0), (400, -6.0, 7.5), (600, 3.0, 15.5), (800, 10.0, 20.0)]
    table = write_csv(tmp_path / "x.csv", "position_mm,fwd,rev", rows)
    data = quiet_machine(deviation={"path": table, "forward_column": "fwd",
                                    "reverse_column": "rev", "interpolation": "linear"})

    async def script() -> list[tuple[float, int, float]]:
        async with SimServer(config_from(data), tcp_port=0) as server:
            m = Master(await tcp_client(server.tcp_port), data)
            out = []
            for pos in (200.0, 400.0, 600.0, 300.0, 513.0):
                for d in (1, -1):
                    out.append((pos, d, await approach(m, "X", pos, d)))
            m.client.close()
            return out

    xs = np.array([r[0] for r in rows])
    for pos, d, measured in run(script()):
        column = np.array([r[1] if d > 0 else r[2] for r in rows])
        assert measured == pytest.approx(float(np.interp(pos, xs, column)), abs=0.002), (pos, d)


def test_akima_table_passes_through_its_points_and_is_smooth_between(tmp_path):
    xs = np.arange(0.0, 801.0, 50.0)
    fwd = 15 * np.sin(xs / 130.0) + 0.01 * xs
    table = write_csv(tmp_path / "x.csv", "position_mm,forward_um,reverse_um",
                      [(x, f, f + 9) for x, f in zip(xs, fwd)])  # fmt: skip
    data = quiet_machine(deviation={"path": table, "reverse_column": "reverse_um"})

    async def script() -> tuple[list[float], list[float]]:
        async with SimServer(config_from(data), tcp_port=0) as server:
            m = Master(await tcp_client(server.tcp_port), data)
            nodes = [await approach(m, "X", float(x), 1) for x in xs[2:6]]
            dense = [await approach(m, "X", 200.0 + k, 1) for k in range(0, 101, 2)]
            m.client.close()
            return nodes, dense

    nodes, dense = run(script())
    assert nodes == pytest.approx(fwd[2:6].tolist(), abs=0.002)
    # C1: the slope changes gradually through the nodes at 250 and 300 mm (no kink)
    slope = np.diff(dense) / 2.0
    assert np.abs(np.diff(slope)).max() < 0.02, np.abs(np.diff(slope)).max()


def test_lost_motion_table_full_and_partial_take_up(tmp_path):
    """A play of 10 µm at 0 growing to 14 µm at 800 (a 2-row table: linear), taken up over
    40 µm of reversal along G(q) = 1 − (1 − q)²: a short reversal leaves part of the play."""
    table = write_csv(tmp_path / "lm.csv", "position_mm,lost_motion_um", [(0, 10.0), (800, 14.0)])
    d_um = 40.0
    data = quiet_machine(lost_motion={"table": {"path": table},
                                      "takeup": {"curve": "smooth", "distance_um": d_um}})

    def play(x_mm: float) -> float:
        return 10.0 + 4.0 * x_mm / 800

    async def script() -> dict[str, list[float]]:
        async with SimServer(config_from(data), tcp_port=0) as server:
            m = Master(await tcp_client(server.tcp_port), data)
            full = [await approach(m, "X", x, -1) for x in (100.0, 400.0, 700.0)]
            fwd = [await approach(m, "X", x, 1) for x in (100.0, 400.0)]
            partial = []
            for r_um in (5.0, 10.0, 20.0, 30.0):
                await approach(m, "X", 400.0, 1)  # on the + flank at 400
                target = 400.0 - r_um / 1000
                await m.move_mm("X", target)
                partial.append(await m.laser_um("X") - target * 1000)
            m.client.close()
            return {"full": full, "fwd": fwd, "partial": partial}

    out = run(script())
    assert out["full"] == pytest.approx([play(100), play(400), play(700)], abs=0.002)
    assert out["fwd"] == pytest.approx([0.0, 0.0], abs=0.002)
    for r_um, measured in zip((5.0, 10.0, 20.0, 30.0), out["partial"]):
        q = r_um / d_um
        assert measured == pytest.approx(play(400) * (1 - (1 - q) ** 2), abs=0.003), r_um
        assert measured < play(400)  # only part of the play is taken up


def test_linear_take_up_is_a_dead_band(tmp_path):
    """The classic play: reversing by less than it leaves the table where it was."""
    data = quiet_machine(lost_motion={"um": 12.0})

    async def script() -> list[float]:
        async with SimServer(config_from(data), tcp_port=0) as server:
            m = Master(await tcp_client(server.tcp_port), data)
            await approach(m, "X", 300.0, 1)
            out = []
            for back_um in (3.0, 8.0, 12.0, 20.0):
                await approach(m, "X", 300.0, 1)
                await m.move_mm("X", 300.0 - back_um / 1000)
                out.append(await m.laser_um("X") - 300_000)
            m.client.close()
            return out

    # the table stays at 300 mm until the play is crossed, then follows 8 µm behind (20-12)
    assert run(script()) == pytest.approx([0.0, 0.0, 0.0, -8.0], abs=0.002)


def test_cyclic_term_with_varying_amplitude_phase_and_four_harmonics(tmp_path):
    lead, origin = 10.0, 0.0
    stations = [(0, 1.0, 0, 0.3, 40, 0.2, -30, 0.1, 90), (800, 2.0, 60, 0.6, 10, 0.1, 20, 0.2, 0)]
    table = write_csv(tmp_path / "cyc.csv", "position_mm,a1_um,phi1_deg,a2_um,phi2_deg,a3_um,"
                      "phi3_deg,a4_um,phi4_deg", stations)  # fmt: skip
    data = quiet_machine(cyclic={"lead_mm": lead, "origin_mm": origin, "path": table})

    def expected(x: float) -> float:
        t = x / 800
        total = 0.0
        for k in range(4):
            a = stations[0][1 + 2 * k] * (1 - t) + stations[1][1 + 2 * k] * t
            phi = stations[0][2 + 2 * k] * (1 - t) + stations[1][2 + 2 * k] * t
            total += a * math.sin(2 * math.pi * (k + 1) * (x - origin) / lead + math.radians(phi))
        return total

    points = [101.3, 102.6, 250.0, 405.7, 407.1, 688.8]

    async def script() -> list[tuple[float, float, float]]:
        async with SimServer(config_from(data), tcp_port=0) as server:
            m = Master(await tcp_client(server.tcp_port), data)
            out = [(x, await approach(m, "X", x, 1), await approach(m, "X", x, -1))
                   for x in points]  # fmt: skip
            m.client.close()
            return out

    for x, up, down in run(script()):
        assert up == pytest.approx(expected(x), abs=0.002), x
        assert down == pytest.approx(expected(x), abs=0.002), x  # no play: both ways alike


def test_xy_field_at_nodes_and_between_them(tmp_path):
    """A field sampled at nodes every 100 mm; bilinear plus linear fields are reproduced
    exactly between the nodes by the C1 surface (its slopes are exact for them)."""
    def ex_um(x: float, y: float) -> float:
        return 4e-5 * x * y + 0.01 * y

    def ey_um(x: float, y: float) -> float:
        return -3e-5 * x * y + 0.02 * x - 5

    nodes = [(x, y) for x in range(0, 801, 100) for y in range(0, 601, 100)]
    rows = [(x, y, ex_um(x, y), ey_um(x, y)) for x, y in nodes]
    field = write_csv(tmp_path / "field.csv", "x_mm,y_mm,ex_um,ey_um", rows)
    data = quiet_machine()
    data["sim"]["plane"]["field"] = {"path": field}
    points = [(100.0, 200.0), (700.0, 500.0), (333.3, 47.1), (512.9, 588.2), (799.0, 1.0)]

    async def script() -> list[tuple[float, float]]:
        async with SimServer(config_from(data), tcp_port=0) as server:
            m = Master(await tcp_client(server.tcp_port), data)
            out = []
            for x, y in points:
                for d in (1, -1):
                    await m.move_mm("X", x - d)
                    await m.move_mm("Y", y - d)
                    await m.move_mm("X", x)
                    await m.move_mm("Y", y)
                    tx, ty = await m.xy_um()
                    out.append((tx - x * 1000, ty - y * 1000))
            m.client.close()
            return out

    measured = run(script())
    for k, (dx, dy) in enumerate(measured):
        x, y = points[k // 2]
        assert dx == pytest.approx(ex_um(x, y), abs=0.003), (x, y)
        assert dy == pytest.approx(ey_um(x, y), abs=0.003), (x, y)


def heated(sensor_mm: float, a_mm: float = 800.0) -> dict:
    data = quiet_machine(heat={"lead_mm": 10, "drag_torque_Nm": 0.08, "diameter_mm": 16,
                               "screw_mm": [-40, 840], "fixed_end_mm": -40})  # fmt: skip
    sim = data["sim"]
    sim["instruments"]["delta_a"] = {"unit": 10, "axis": "X", "a_mm": a_mm, "resolution_um": 0.01}
    sim["instruments"]["temperature"] = {"unit": 23, "channels": ["X", "ambient"],
                                         "positions_mm": {"X": sensor_mm}}  # fmt: skip
    return data


def test_heat_where_the_nut_works_growth_not_linear_and_sensors_where_mounted():
    """Working 30 min between 0 and 200 mm heats that end of the screw: the table grows
    nearly as much at 400 as at 800 mm, the Δa sensor at 800 reads the laser's growth
    there, a temperature sensor in the zone reads hotter than one at 700 mm."""

    async def script(data: dict) -> dict[str, float]:
        async with SimServer(config_from(data), tcp_port=0) as server:
            m = Master(await tcp_client(server.tcp_port), data)
            cold = {x: await approach(m, "X", x, 1) for x in (400.0, 800.0 - 5)}
            for _ in range(450):  # 2 s per stroke at 100 mm/s: 30 min
                await m.move_mm("X", 200.0)
                await m.move_mm("X", 0.0)
            warm = {x: await approach(m, "X", x, 1) for x in cold}
            rr = await m.client.read_input_registers(1, count=2, device_id=10)
            t = await m.client.read_input_registers(0, count=2, device_id=23)
            await m.control(ADVANCE_S, [30000])
            t_cold = await m.client.read_input_registers(0, count=1, device_id=23)
            m.client.close()
            return {"g400": warm[400.0] - cold[400.0], "g795": warm[795.0] - cold[795.0],
                    "delta_a": s32(*rr.registers) / 1000, "t": t.registers[0] / 100,
                    "ambient": t.registers[1] / 100, "t_cold": t_cold.registers[0] / 100}

    near = run(script(heated(100.0)), timeout_s=60)
    far = run(script(heated(700.0)), timeout_s=60)
    assert near["g795"] > 3.0  # a few K over a few hundred mm: micrometres
    assert near["g400"] > 0.9 * near["g795"]  # the growth is made where it is warm
    # Δa at 800 mm = the table's growth at 795 mm + the last 5 mm of warm-ish screw
    assert near["delta_a"] == pytest.approx(near["g795"], abs=0.05 * near["g795"] + 0.01)
    assert near["t"] > near["ambient"] + 1.0 and near["t"] > far["t"] + 0.5
    assert near["t_cold"] == pytest.approx(near["ambient"], abs=0.02)


def test_stick_slip_stops_short_on_one_side_only():
    data = quiet_machine(stick_slip={"probability": 0.5, "mean_um": 0.8, "band_um": 2.0})
    n = 150

    async def script() -> tuple[list[float], list[float]]:
        async with SimServer(config_from(data), tcp_port=0) as server:
            m = Master(await tcp_client(server.tcp_port), data)
            up = [await approach(m, "X", 300.0, 1, 1.0) for _ in range(n)]
            down = [await approach(m, "X", 300.0, -1, 1.0) for _ in range(n)]
            m.client.close()
            return up, down

    up, down = (np.array(v) for v in run(script()))
    for dev, sign in ((up, 1), (down, -1)):
        short = -sign * dev  # how far short of the target, in the direction of the move
        assert short.min() >= -0.002 and short.max() <= 2.0 + 0.002
        stuck = short[short > 0.002]
        assert 0.35 * n < stuck.size < 0.65 * n  # about half the stops
        assert 0.5 < stuck.mean() < 1.0  # an exponential of mean 0.8 cut at 2 µm: 0.69


def test_settling_reading_decays_and_the_stable_flag_says_when():
    data = quiet_machine(settling={"amplitude_um": 2.0, "time_constant_s": 0.05})

    async def script() -> list[tuple[float, int]]:
        async with SimServer(config_from(data), tcp_port=0) as server:
            m = Master(await tcp_client(server.tcp_port), data)
            await m.move_mm("X", 100.0)
            await m.move_mm("X", 300.0)
            out, before_ms = [], 0
            for at_ms in (0, 50, 100, 250):
                if at_ms > before_ms:  # let the machine clock run (time_scale 0)
                    await m.control(ADVANCE_MS, [at_ms - before_ms])
                    before_ms = at_ms
                rr = await m.client.read_input_registers(0, count=6, device_id=20)
                out.append((s32(*rr.registers[:2]) / 1000 - 300_000, rr.registers[4]))
            m.client.close()
            return out

    readings = run(script())
    elapsed_s = [0.0, 0.05, 0.1, 0.25]
    for t, (dev, flag) in zip(elapsed_s, readings):
        assert dev == pytest.approx(2.0 * math.exp(-t / 0.05), abs=0.002), t
        assert flag == (2.0 * math.exp(-t / 0.05) <= 0.1), t  # stable_band_um 0.1


def test_a_careful_master_reading_until_stable_gets_the_settled_position():
    """With sample_s, every laser reading takes machine time: reading until the stable flag
    is set lets the axis settle; a reading taken at once is off by the ringing."""
    data = quiet_machine(settling={"amplitude_um": 1.5, "time_constant_s": 0.08,
                                   "period_s": 0.05})  # fmt: skip
    data["sim"]["instruments"]["laser"]["sample_s"] = 0.02

    async def script() -> tuple[float, float, int]:
        async with SimServer(config_from(data), tcp_port=0) as server:
            m = Master(await tcp_client(server.tcp_port), data)
            await m.move_mm("X", 500.0)
            await m.move_mm("X", 200.0)
            first = await m.laser_um("X") - 200_000
            reads = 1
            while True:
                rr = await m.client.read_input_registers(0, count=6, device_id=20)
                reads += 1
                if rr.registers[4]:
                    break
                assert reads < 100
            m.client.close()
            return first, s32(*rr.registers[:2]) / 1000 - 200_000, reads

    first, settled, reads = run(script())
    # moving −: the ringing starts 1.5 µm below; the first reading ends 20 ms after the stop
    t = 0.02
    assert first == pytest.approx(-1.5 * math.exp(-t / 0.08) * math.cos(2 * math.pi * t / 0.05),
                                  abs=0.002)  # fmt: skip
    assert abs(settled) <= 0.1 and reads > 5
