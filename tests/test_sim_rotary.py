"""The sim's rotary axes (issue 16) against independent computations, over Modbus.

The swing head's angle is checked against the linkage's triangle built from vectors (pivot
A at the origin, the block's pivot N on the x axis, the nut's joint M on the arm) and solved
for the angle numerically, not with the law of cosines the sim uses; the turntable against
its harmonics written out; the angle instrument's registers (int32 µdeg, modulo 360 for a
turntable, stable flags) read through a real socket.
"""

from __future__ import annotations

import copy
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml
from scipy.optimize import brentq

from gateway.calibration.measuring.machine import Link
from gateway.modbus.frames import pack_int32, unpack_int32
from sim.config import SimConfigError, parse_config
from sim.server import SimServer
from tests.helpers_modbus import run

ROOT = Path(__file__).resolve().parent.parent
ROTARY = ROOT / "config" / "rotary-sim.yaml"
UNIT_DEG = 1e-5  # the sim drives' unit
ANGLE_UNIT = 24


def rotary_dict() -> dict[str, Any]:
    return copy.deepcopy(yaml.safe_load(ROTARY.read_text()))


def perfect_screw(data: dict[str, Any]) -> dict[str, Any]:
    """The swing head with a perfect screw, no play, no spread; a noiseless instrument."""
    swing = data["sim"]["machine"]["A"]["swing"]
    swing.update(slope_um_per_m=0, poly_um=[], periodic_um=0, backlash_um=0,
                 repeatability_arcsec=0)  # fmt: skip
    data["sim"]["machine"]["C"]["turntable"]["repeatability_arcsec"] = 0
    data["sim"]["instruments"]["angle"]["noise_udeg"] = 0
    return data


# -- the independent geometry ---------------------------------------------------------------
def nut_by_vectors(angle_deg: float, arm: float, base: float, offset: float, phi0: float) -> float:
    """Nut distance along the screw: |MN| from coordinates, less the offset (Pythagoras)."""
    phi = math.radians(phi0 + angle_deg)
    m = np.array([arm * math.cos(phi), arm * math.sin(phi)])
    n = np.array([base, 0.0])
    return math.sqrt(float(np.dot(m - n, m - n)) - offset**2)


def angle_by_root(nut_mm: float, geo: dict[str, float]) -> float:
    """The head's angle for a nut position, found by root finding on the vector form."""
    return brentq(lambda t: nut_by_vectors(t, **geo) - nut_mm, -60.0, 60.0, xtol=1e-13)


def geometry(data: dict[str, Any]) -> dict[str, float]:
    s = data["sim"]["machine"]["A"]["swing"]
    return {"arm": s["arm_mm"], "base": s["base_mm"], "offset": s["offset_mm"],
            "phi0": s["phi0_deg"]}  # fmt: skip


def commanded_to_angle(c_deg: float, geo: dict[str, float]) -> float:
    """The control's linear scale: the chord's slope over -14..13 through the zero."""
    slope = (nut_by_vectors(13.0, **geo) - nut_by_vectors(-14.0, **geo)) / 27.0
    return angle_by_root(nut_by_vectors(0.0, **geo) + slope * c_deg, geo)


def test_default_geometry_has_the_seeds_nonlinearity():
    """Straight lines between whole degrees leave 5.9e-4 deg of the linkage (seed 003)."""
    geo = geometry(rotary_dict())
    c = np.linspace(-14.0, 13.0, 1081)
    theta = np.array([commanded_to_angle(v, geo) for v in c])
    whole = np.arange(-14.0, 14.0)
    lines = np.interp(c, whole, np.interp(whole, c, theta))
    assert 5.7e-4 < np.abs(theta - lines).max() < 6.1e-4
    assert 0.05 < np.abs(theta - c).max() < 0.15  # the control's linear map is that far off
    assert abs(commanded_to_angle(0.0, geo)) < 1e-12


async def _read_angles(link: Link) -> tuple[float, float, list[int]]:
    words = await link.read(ANGLE_UNIT, 0, 6, "input")
    return (unpack_int32(words[0:2], "hi_lo") * 1e-6, unpack_int32(words[2:4], "hi_lo") * 1e-6,
            words[4:6])  # fmt: skip


async def _move(link: Link, unit: int, target_deg: float) -> None:
    await link.write(unit, 0x6201, list(pack_int32(round(target_deg / UNIT_DEG), "hi_lo")))
    await link.write(unit, 0x6002, [0x10])


def test_swing_head_over_modbus_matches_the_vector_geometry():
    data = perfect_screw(rotary_dict())
    geo = geometry(data)
    cfg = parse_config(data, ROTARY.parent)

    async def body() -> None:
        async with SimServer(cfg, tcp_port=0, time_scale=0) as sim:
            link = Link("127.0.0.1", sim.tcp_port)
            await link.connect()
            try:
                for c in (-14.3, -14.0, -7.25, -0.5, 0.0, 3.3333, 12.9, 13.4):
                    await _move(link, 1, c)
                    angle, _, flags = await _read_angles(link)
                    want = commanded_to_angle(round(c / UNIT_DEG) * UNIT_DEG, geo)
                    assert abs(angle - want) <= 1e-6, (c, angle, want)
                    assert flags == [1, 1]
            finally:
                link.close()

    run(body())


def test_swing_screw_error_and_play_move_the_nut_before_the_triangle():
    """The screw's error (µm along its length) and its play act on the nut: the angle is
    the triangle's at the nut's true position; approached from above, the play is ahead."""
    data = perfect_screw(rotary_dict())
    swing = data["sim"]["machine"]["A"]["swing"]
    swing.update(periodic_um=1.0, periodic_phase_deg=30.0, backlash_um=2.0, lead_mm=5.0)
    geo = geometry(data)
    cfg = parse_config(data, ROTARY.parent)
    s_lo, s_hi = nut_by_vectors(-14.0, **geo), nut_by_vectors(13.0, **geo)
    slope = (s_hi - s_lo) / 27.0
    s0 = nut_by_vectors(0.0, **geo)

    def truth(c: float, ahead_um: float) -> float:
        s = s0 + slope * c + ahead_um / 1000
        s += 1.0e-3 * math.sin(2 * math.pi * (s - s_lo) / 5.0 + math.radians(30.0))
        return angle_by_root(s, geo)

    async def body() -> None:
        async with SimServer(cfg, tcp_port=0, time_scale=0) as sim:
            link = Link("127.0.0.1", sim.tcp_port)
            await link.connect()
            try:
                await _move(link, 1, -5.0)
                await _move(link, 1, 2.0)  # approached in +: the reference flank
                up = (await _read_angles(link))[0]
                await _move(link, 1, 6.0)
                await _move(link, 1, 2.0)  # approached in -: the nut 2 µm ahead
                down = (await _read_angles(link))[0]
            finally:
                link.close()
        assert abs(up - truth(2.0, 0.0)) <= 1e-6
        assert abs(down - truth(2.0, 2.0)) <= 1e-6
        assert 6e-4 < down - up < 9e-4  # 2 µm of play is about 0.00077 deg here

    run(body())


def test_turntable_reads_modulo_360_with_its_errors_in_any_turn():
    data = perfect_screw(rotary_dict())
    table = data["sim"]["machine"]["C"]["turntable"]
    cfg = parse_config(data, ROTARY.parent)

    def error_arcsec(deg: float) -> float:
        out = sum(h["amplitude_arcsec"] * math.sin(h["order"] * math.radians(deg)
                                                   + math.radians(h["phase_deg"]))
                  for h in table["harmonics"])  # fmt: skip
        worm = table["worm"]
        return out + worm["amplitude_arcsec"] * math.sin(
            worm["teeth"] * math.radians(deg) + math.radians(worm["phase_deg"]))

    async def body() -> None:
        async with SimServer(cfg, tcp_port=0, time_scale=0) as sim:
            link = Link("127.0.0.1", sim.tcp_port)
            await link.connect()
            try:
                for motor in (5.0, 365.0, 725.0, -355.0, 359.99, -0.004):
                    await _move(link, 2, motor - 1.0)
                    await _move(link, 2, motor)  # approached in +
                    angle = (await _read_angles(link))[1]
                    want = (motor + error_arcsec(motor) / 3600) % 360
                    assert 0 <= angle < 360
                    assert abs(angle - want) <= 1.5e-6, (motor, angle, want)
                await _move(link, 2, 725.5)
                await _move(link, 2, 725.0)  # approached in -: 12" of play ahead
                play = 12 / 3600
                angle = (await _read_angles(link))[1]
                assert abs(angle - (5.0 + play + error_arcsec(725.0 + play) / 3600)) <= 1.5e-6
            finally:
                link.close()

    run(body())


@pytest.mark.parametrize(("edit", "message"), [
    (lambda d: d["sim"]["machine"]["A"].update(backlash_um=3),
     "sim.machine.A.swing: a rotary truth carries its own errors"),
    (lambda d: d["sim"]["instruments"]["angle"].update(axes=["A", "B"]),
     "instruments.angle.axes: 'B' is not an axis"),
    (lambda d: d["sim"]["machine"]["A"]["swing"].update(phi0_deg=170),
     "phi0_deg: the angle MAN must stay within 0..180 deg"),
])  # fmt: skip
def test_rotary_config_errors_name_the_key(edit, message):
    data = rotary_dict()
    edit(data)
    with pytest.raises(SimConfigError, match=message.replace(".", r"\.")):
        parse_config(data, ROTARY.parent)
