"""A reading is kept only while every measured axis still stands where it was sent: a PLC
on the gateway's other port that moves an axis during a commissioning is named, and the
reading taken there is not kept (one 70 mm off its target was, and every resume's fit then
refused the tables). The example sim and a gateway in process, two masters on it."""

from __future__ import annotations

import asyncio

import pytest

from gateway.app import GatewayApp
from gateway.calibration.measuring.machine import Link, MachineDriver, MachineError
from gateway.config import parse_config
from gateway.tables import build_chain
from sim.config import load_config as load_sim
from sim.server import SimServer
from tests.test_calibration_rig import ROOT, SIM_EXAMPLE, example_config


def test_an_axis_another_master_moved_is_named_and_its_reading_not_kept() -> None:
    async def body() -> None:
        async with SimServer(load_sim(SIM_EXAMPLE), tcp_port=0, time_scale=0) as sim:
            config = parse_config(example_config(sim.tcp_port), "example.yaml")
            async with GatewayApp(config, build_chain(config, ROOT / "config")) as app:
                ours, plc = Link("127.0.0.1", app.tcp_port), Link("127.0.0.1", app.tcp_port)
                await ours.connect()
                await plc.connect()
                try:
                    driver = MachineDriver(ours, config)
                    await driver.move({"X": 100.0, "Y": 50.0})
                    await driver.still_at({"X": 100.0, "Y": 50.0})  # nobody moved it
                    await MachineDriver(plc, config).move({"X": 150.0})
                    with pytest.raises(MachineError) as caught:
                        await driver.still_at({"X": 100.0, "Y": 50.0})
                    assert str(caught.value) == (
                        "axis X: at 150 mm when read, not at 100 mm where it was sent: "
                        "another master (a PLC, an HMI) moved it? Commissioning needs the "
                        "machine to itself; that reading is not kept")  # fmt: skip
                finally:
                    ours.close()
                    plc.close()

    asyncio.run(asyncio.wait_for(body(), 60))
