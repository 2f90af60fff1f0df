"""``state_file``: a restarted gateway carries on where the drives are (the nominal the
master wrote, the direction of approach), if the drive still holds the saved command; a
drive moved meanwhile, or a damaged file, means starting afresh. Real sim, real sockets."""

from __future__ import annotations

import contextlib
import json
import logging
import math
import threading
import time
from collections.abc import AsyncIterator
from pathlib import Path

import pytest
import yaml
from pymodbus.client import AsyncModbusTcpClient

from gateway.app import GatewayApp, load
from gateway.modbus.frames import pack_int32
from sim.server import SimServer
from tests.gateway_rig import FEEDBACK, TARGET, base_config
from tests.helpers_modbus import wait_for_condition
from tests.test_gateway_e2e import PITCH_X, move, read32, run
from tests.test_sim_support import config_from, example_dict

B_PULSES = 5  # half of Y's 0.01 mm backlash, in 1 µm pulses


def sim_config():
    return config_from(example_dict())  # 1 µm pulses, as base_config's axes


@contextlib.asynccontextmanager
async def gateway(
    tmp_path: Path, sim_port: int
) -> AsyncIterator[tuple[GatewayApp, AsyncModbusTcpClient]]:
    data = base_config(sim_port)
    data["axes"]["X"]["compensation"]["pitch"] = "x.csv"
    data["axes"]["Y"]["compensation"]["backlash_mm"] = 0.01
    data["state_file"] = "run/state.json"
    (tmp_path / "x.csv").write_text(PITCH_X)
    (tmp_path / "run").mkdir(exist_ok=True)
    path = tmp_path / "gw.yaml"
    path.write_text(yaml.safe_dump(data))
    config, chain = load(path)
    async with GatewayApp(config, chain, source=str(path)) as app:
        master = AsyncModbusTcpClient("127.0.0.1", port=app.tcp_port, timeout=2, retries=0)
        assert await master.connect()
        try:
            yield app, master
        finally:
            master.close()


def test_a_restarted_gateway_carries_on(tmp_path: Path, caplog: pytest.LogCaptureFixture):
    state = tmp_path / "run" / "state.json"

    async def body():
        async with SimServer(sim_config(), tcp_port=0, time_scale=0) as sim:
            direct = AsyncModbusTcpClient("127.0.0.1", port=sim.tcp_port, timeout=2, retries=0)
            assert await direct.connect()
            async with gateway(tmp_path, sim.tcp_port) as (app, master):
                await move(master, 1, 300_000)
                x_command = await read32(direct, 1, TARGET)
                assert x_command != 300_000  # corrected
                await move(master, 2, 100_000)
                await move(master, 2, 50_000)  # Y now approaches going −
                assert await read32(direct, 2, TARGET) == 50_000 - B_PULSES
                store = app.state_store
                assert store is not None
                await wait_for_condition(lambda: store.writes > 0)  # coalesced, soon
            saved = json.loads(state.read_text())["axes"]
            assert saved["X"]["last_command_units"] == x_command
            assert saved["Y"]["direction"] == -1 and saved["Y"]["last_nominal_pulses"] == 50_000

            # a new process: feedback is the nominal at once, Y keeps going −
            with caplog.at_level(logging.INFO, logger="gateway.router"):
                async with gateway(tmp_path, sim.tcp_port) as (app, master):
                    assert "axis X: carried on from the state file" in caplog.text
                    # the correction the drive holds, for status and metrics (it read 0)
                    pulse_mm = app.config.axes["X"].pulse_mm
                    assert app.gateway.last_correction_mm("X") == pytest.approx(
                        (x_command - 300_000) * pulse_mm)  # fmt: skip
                    assert await read32(master, 1, FEEDBACK) == 300_000
                    assert await read32(master, 1, TARGET) == 300_000
                    assert await read32(master, 2, FEEDBACK) == 50_000
                    await move(master, 2, 40_000)
                    assert await read32(direct, 2, TARGET) == 40_000 - B_PULSES

            # the drive moved while compgw was down: that axis starts afresh
            assert not (await direct.write_registers(TARGET, list(pack_int32(123_000)),
                                                     device_id=1)).isError()  # fmt: skip
            assert not (await direct.write_register(0x6002, 0x10, device_id=1)).isError()
            caplog.clear()
            with caplog.at_level(logging.INFO, logger="gateway.router"):
                async with gateway(tmp_path, sim.tcp_port) as (app, master):
                    assert "axis X: the drive holds target 123000" in caplog.text
                    assert await read32(master, 1, FEEDBACK) == 123_000  # raw: not applied
                    assert await read32(master, 2, FEEDBACK) == 40_000  # Y carried on

            # a damaged file: logged, fresh, serving
            state.write_text("{not json")
            caplog.clear()
            with caplog.at_level(logging.WARNING, logger="gateway.state_store"):
                async with gateway(tmp_path, sim.tcp_port) as (app, master):
                    assert "unreadable, starting afresh" in caplog.text
                    await move(master, 2, 60_000)  # the first move: home_direction (+)
                    assert await read32(direct, 2, TARGET) == 60_000 + B_PULSES
            assert json.loads(state.read_text())["axes"]["Y"]["last_nominal_pulses"] == 60_000
            direct.close()

    run(body())



def test_a_slow_disk_does_not_hold_the_requests(tmp_path: Path,
                                                monkeypatch: pytest.MonkeyPatch) -> None:
    """The state file's write (its fsync: tens of ms on an SD card, here made to take
    0.3 s) goes on beside the loop: reads are answered while it lasts, moves made during
    it are written after it, and the file at stop holds the last of them."""
    from gateway import state_store

    writing = threading.Event()
    real_write = state_store.atomic_write_text

    def slow_write(path: Path, text: str) -> None:
        writing.set()
        try:
            time.sleep(0.3)  # the disk, not the test's timing: nothing waits on it
            real_write(path, text)
        finally:
            writing.clear()

    monkeypatch.setattr(state_store, "atomic_write_text", slow_write)

    async def body():
        async with SimServer(sim_config(), tcp_port=0, time_scale=0) as sim:
            async with gateway(tmp_path, sim.tcp_port) as (_app, master):
                await move(master, 1, 300_000)  # a commit: a write soon
                await wait_for_condition(writing.is_set)
                answered = 0
                while writing.is_set() and answered < 10_000:  # bounded
                    await read32(master, 1, FEEDBACK)
                    answered += 1
                assert answered >= 5, f"{answered} reads answered during a write"
                await move(master, 1, 310_000)
                await move(master, 1, 320_000)
            saved = json.loads((tmp_path / "run" / "state.json").read_text())["axes"]
            assert saved["X"]["last_nominal_pulses"] == 320_000

    run(body())


def test_heat_from_motion_outlives_a_restart_and_cools_for_the_time_it_was_down(
        tmp_path: Path):
    """thermal.motion on Y: the screw's heat is in the state file; a restarted gateway takes
    it back (Δa unchanged), and one that was down for a tau takes back 1/e of it."""
    state = tmp_path / "run" / "state.json"
    (tmp_path / "run").mkdir()

    def app_for(sim_port: int) -> GatewayApp:
        data = base_config(sim_port)
        data["axes"]["Y"]["compensation"]["thermal"] = {
            "length_mm": 500, "motion": {"delta_a_um_per_m": 20.0, "tau_s": 3600.0,
                                         "speeds_mm_s": {"Y": 100}}}
        data["state_file"] = "run/state.json"
        path = tmp_path / "gw.yaml"
        path.write_text(yaml.safe_dump(data))
        config, chain = load(path)
        return GatewayApp(config, chain, source=str(path))

    async def body():
        async with SimServer(sim_config(), tcp_port=0, time_scale=0) as sim:
            async with app_for(sim.tcp_port) as app:
                master = AsyncModbusTcpClient("127.0.0.1", port=app.tcp_port, timeout=2,
                                              retries=0)  # fmt: skip
                assert await master.connect()
                for target in (0, 200_000, 0, 200_000, 0):
                    await move(master, 2, target)
                master.close()
                warm = app.sensors.axis_delta_a_mm("Y")
                assert warm is not None and warm > 0.005  # 0.8 m of travel: ~16 µm
            saved = json.loads(state.read_text())["heat"]["Y"]
            assert saved["heat_m"] == pytest.approx(warm / 20.0 * 1000, rel=1e-3)
            async with app_for(sim.tcp_port) as app:
                assert app.sensors.axis_delta_a_mm("Y") == pytest.approx(warm, rel=1e-3)
            data = json.loads(state.read_text())
            data["heat"]["Y"]["at_epoch_s"] -= 3600.0  # down for a tau
            state.write_text(json.dumps(data))
            async with app_for(sim.tcp_port) as app:
                assert app.sensors.axis_delta_a_mm("Y") == pytest.approx(warm / math.e, rel=1e-3)

    run(body())
