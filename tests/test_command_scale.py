"""A drive geared finer than the upper computer's pulse (``command_scale``): the master keeps
its 1 µm pulses, the drive gets targets in 0.1 µm units, so corrections land to 0.1 µm;
feedback and the target read back in the master's units (TCP → TCP, real sim)."""

from __future__ import annotations

from pathlib import Path

import pytest

from gateway.app import GatewayApp
from gateway.compensation import AxisInput
from gateway.config import ConfigError, load_config
from tests.gateway_rig import FEEDBACK, TARGET, rig
from tests.test_gateway_e2e import (
    PITCH_X,
    XY_FILES,
    move,
    read32,
    run,
    with_pitch,
    with_planar,
)

SCALE = 10


def finer(edit):
    """``edit``, then X's drive geared 10x finer (feedback counts the drive's units)."""

    def both(data):
        edit(data)
        data["axes"]["X"]["command_scale"] = SCALE
        data["axes"]["X"]["registers"]["feedback"]["upstream_counts_per_pulse"] = 1

    return both


def sim_at_tenth_um(sim):
    sim["sim"]["axes"]["X"]["pulse_mm"] = 0.0001


def test_corrections_reach_the_drive_at_a_tenth_of_a_pulse(tmp_path: Path):
    async def body():
        async with rig(tmp_path, finer(with_pitch), {"x.csv": PITCH_X},
                       sim_edit=sim_at_tenth_um) as r:  # fmt: skip
            master, direct, chain = r["master"], r["direct"], r["chain"]
            for nominal in (300_000, 123_457, 700_001):
                await move(master, 1, nominal)
                own = {"X": AxisInput(nominal, 1 if nominal != 123_457 else -1)}
                units = chain.command_pulses("X", own, SCALE)
                whole = chain.command_pulses("X", own)
                on_drive = await read32(direct, 1, TARGET)
                assert on_drive == units  # 0.1 µm units
                assert abs(on_drive - SCALE * whole) <= SCALE // 2  # the same correction
                assert on_drive % SCALE != 0 or units % SCALE == 0
                assert await read32(direct, 1, FEEDBACK) == units  # the drive got there
                assert await read32(master, 1, FEEDBACK) == nominal  # the master's units
                assert await read32(master, 1, TARGET) == nominal
            # the status unit's last correction: in mm, not in drive units
            correction_mm = r["app"].gateway.last_correction_mm("X")
            assert correction_mm == pytest.approx((units / SCALE - 700_001) * 0.001, abs=1e-9)
            assert abs(correction_mm) < 0.05

    run(body())


def test_uncorrected_targets_are_scaled_too(tmp_path: Path):
    """Not homed: the drive gets the master's target, in its own units (× 10)."""

    def not_homed(data):
        finer(with_pitch)(data)
        data["axes"]["X"]["registers"]["status"]["homed_bit"] = 5  # the sim never sets bit 5

    async def body():
        async with rig(tmp_path, not_homed, {"x.csv": PITCH_X},
                       sim_edit=sim_at_tenth_um) as r:  # fmt: skip
            master, direct = r["master"], r["direct"]
            await move(master, 1, 300_000)
            assert await read32(direct, 1, TARGET) == 3_000_000
            assert await read32(master, 1, FEEDBACK) == 300_000

    run(body())


def test_planar_partner_feedback_uses_the_partners_scale(tmp_path: Path):
    """Y's feedback inversion takes X's last command (in X's drive units) back to pulses."""

    async def body():
        async with rig(tmp_path, finer(with_planar("immediate")), XY_FILES,
                       sim_edit=sim_at_tenth_um) as r:  # fmt: skip
            master, direct, chain = r["master"], r["direct"], r["chain"]
            await move(master, 2, 300_000)
            await move(master, 1, 500_000)
            inputs = {"X": AxisInput(500_000, 1), "Y": AxisInput(300_000, 1)}
            assert await read32(direct, 1, TARGET) == chain.command_pulses("X", inputs, SCALE)
            assert await read32(master, 1, FEEDBACK) == 500_000
            # Y away from its last command (as in motion): the inverse chain needs X's
            # command in pulses (500 mm), not in X's drive units (5000 mm)
            gw = r["app"].gateway
            gw.axis_state("Y").last_command_units = None
            y_drive = await read32(direct, 2, FEEDBACK)
            x_units = await read32(direct, 1, TARGET)
            right = chain.nominal_pulses("Y", {"Y": AxisInput(y_drive, 1),
                                               "X": AxisInput(x_units / SCALE, 1)})
            wrong = chain.nominal_pulses("Y", {"Y": AxisInput(y_drive, 1),
                                               "X": AxisInput(x_units, 1)})
            assert await read32(master, 2, FEEDBACK) == round(right)
            assert abs(right - wrong) > 5  # the test can tell the two apart

    run(body())


def test_command_scale_cannot_change_on_reload(tmp_path: Path):
    async def body():
        async with rig(tmp_path, finer(with_pitch), {"x.csv": PITCH_X},
                       sim_edit=sim_at_tenth_um) as r:  # fmt: skip
            app: GatewayApp = r["app"]
            path = r["config_path"]
            text = path.read_text()
            assert "command_scale: 10" in text
            path.write_text(text.replace("command_scale: 10", "command_scale: 100"))
            new = load_config(path)
            with pytest.raises(ConfigError, match=r"axes\.X\.command_scale cannot change"):
                app.reload(new, r["chain"])
            assert app.config.axes["X"].command_scale == SCALE

    run(body())
