"""The shipped pair agrees on thermal: config/example-sim.yaml heats its screws at real
rates (time_scale 1) and config/example.yaml's plausibility limit for the Δa sensor
(max_rate_mm_s) accepts the fastest growth that machine can show, while a fast clock
(time_scale 0, as the demo and the tests run) outruns it — why those raise the limit."""

from __future__ import annotations

import asyncio
import itertools

from pymodbus.client import AsyncModbusTcpClient

from gateway.config import load_config
from gateway.modbus.frames import pack_int32, unpack_int32
from sim.config import load_config as load_sim_config
from sim.server import SimServer
from tests.gateway_rig import ROOT, SIM_EXAMPLE, TRIGGER
from tests.helpers_modbus import run

MOVES = 60  # end to end at full speed: about 8 machine-seconds each


def test_shipped_thermal_limits_accept_the_shipped_machine_heating_in_real_time() -> None:
    gw = load_config(ROOT / "config" / "example.yaml")
    limit_mm_s = gw.thermal_sources["x_ref"].max_rate_mm_s
    sim_cfg = load_sim_config(SIM_EXAMPLE)
    assert sim_cfg.sim.time_scale == 1  # as shipped: the machine clock is the wall clock

    async def body() -> list[tuple[float, float, float]]:
        samples = []  # (machine s, wall s, Δa mm)
        async with SimServer(sim_cfg, tcp_port=0, time_scale=0) as sim:  # fast, measured
            c = AsyncModbusTcpClient("127.0.0.1", port=sim.tcp_port, timeout=2, retries=0)
            assert await c.connect()
            loop = asyncio.get_running_loop()
            try:
                for i in range(MOVES):
                    units = 0 if i % 2 else 7_900_000  # 0 / 790 mm in 0.1 µm units
                    assert not (await c.write_registers(0x6201, list(pack_int32(units)),
                                                        device_id=1)).isError()
                    assert not (await c.write_register(TRIGGER, 0x10, device_id=1)).isError()
                    clock = await c.read_holding_registers(0x0802, count=2, device_id=250)
                    da = await c.read_input_registers(1, count=2, device_id=10)
                    samples.append((unpack_int32(clock.registers, "hi_lo") / 1000,
                                    loop.time(), unpack_int32(da.registers, "hi_lo") * 1e-6))
            finally:
                c.close()
        return samples

    s = run(body(), 60)
    growth_mm = s[-1][2] - s[0][2]
    assert growth_mm > 0.003, f"the warm-up should grow the screw: {growth_mm * 1e3:.1f} µm"
    machine_rate = max((b[2] - a[2]) / (b[0] - a[0])
                       for a, b in itertools.pairwise(s) if b[0] > a[0])
    assert machine_rate < limit_mm_s / 10, (machine_rate, limit_mm_s)  # real time: accepted
    wall_s = s[-1][1] - s[0][1]
    assert growth_mm / wall_s > limit_mm_s, "at time_scale 0 the same growth outruns the limit"
