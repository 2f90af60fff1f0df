"""Helpers for the simulator tests (no tests here): configs, a small Modbus master.

The master speaks to the sim only through real pymodbus clients; expectations in the tests
are computed from the raw YAML numbers, never by calling sim code.
"""

from __future__ import annotations

import asyncio
import copy
import time
from collections.abc import Awaitable, Callable
from pathlib import Path
from typing import Any, TypeVar

import yaml
from pymodbus.client import AsyncModbusSerialClient, AsyncModbusTcpClient

from sim.config import SimConfig, parse_config

T = TypeVar("T")
ROOT = Path(__file__).resolve().parent.parent
EXAMPLE = ROOT / "config" / "example-sim.yaml"
FAULTS_UNIT = 250


def example_dict() -> dict[str, Any]:
    """The example machine as plain YAML data (a fresh copy each call), at 1 µm per pulse
    and with instant moves (time_scale 0; shipped: real time): the sim's tests command in
    pulses and read their numbers as µm."""
    data = copy.deepcopy(yaml.safe_load(EXAMPLE.read_text()))
    data["sim"]["time_scale"] = 0
    for axis in data["sim"]["axes"].values():
        axis["pulse_mm"] = 0.001
    return data


def with_rtu(data: dict[str, Any]) -> dict[str, Any]:
    """Add an RTU section (port filled in by SimServer(rtu_port=...)).

    Parity N: on this kernel a pty configured with parity accepts tcsetattr only once, and
    pymodbus's serial transport sets it twice; a pty ignores line settings anyway.
    """
    data["sim"]["rtu"] = {"port": "unset", "baudrate": 115200, "parity": "N", "stopbits": 1}
    return data


def config_from(data: dict[str, Any]) -> SimConfig:
    """Validate a dict (paths relative to the config directory)."""
    return parse_config(data, EXAMPLE.parent)


def run(coro: Awaitable[T], timeout_s: float = 30.0) -> T:
    """Run a test coroutine with a hard time bound."""

    async def bounded() -> T:
        return await asyncio.wait_for(coro, timeout_s)

    return asyncio.run(bounded())


async def wait_until(check: Callable[[], Awaitable[bool]], timeout_s: float = 10.0) -> float:
    """Poll an async condition until true; return the wall time it took."""
    t0 = time.monotonic()
    while not await check():
        if time.monotonic() - t0 > timeout_s:
            raise AssertionError("condition not met in time")
        await asyncio.sleep(0.01)
    return time.monotonic() - t0


def s32(hi: int, lo: int) -> int:
    """Signed 32-bit from two registers."""
    raw = (hi << 16) | lo
    return raw - (1 << 32) if raw & 0x80000000 else raw


def words(value: int, order: str = "hi_lo") -> list[int]:
    """Signed 32-bit to two registers."""
    raw = value & 0xFFFFFFFF
    hi, lo = raw >> 16, raw & 0xFFFF
    return [hi, lo] if order == "hi_lo" else [lo, hi]


class Master:
    """A scripted upper computer talking to the sim (default Leadshine-like registers)."""

    def __init__(self, client: AsyncModbusTcpClient | AsyncModbusSerialClient, data: dict) -> None:
        self.client = client
        self.sim = data["sim"]
        self.axes = list(self.sim["axes"])

    async def check(self, rr: Any) -> Any:
        assert not rr.isError(), rr
        return rr

    async def move_pulses(self, axis: str, pulses: int) -> None:
        """Write the target (one FC16) and the trigger; the sim must be at time_scale 0."""
        unit = self.sim["axes"][axis]["unit"]
        await self.check(await self.client.write_registers(0x6201, words(pulses), device_id=unit))
        await self.check(await self.client.write_register(0x6002, 0x10, device_id=unit))

    async def move_mm(self, axis: str, pos_mm: float) -> None:
        """Move to a position in mm (pulse_mm from the config)."""
        pulse_mm = self.sim["axes"][axis].get("pulse_mm", 0.001)
        await self.move_pulses(axis, round(pos_mm / pulse_mm))

    async def laser_um(self, axis: str) -> float:
        """Laser reading of ``axis`` in micrometres."""
        unit = self.sim["instruments"]["laser"]["unit"]
        k = self.axes.index(axis)
        rr = await self.check(
            await self.client.read_input_registers(2 * k, count=2, device_id=unit)
        )
        return s32(*rr.registers) / 1000.0

    async def xy_um(self) -> tuple[float, float]:
        """2-D device reading (X, Y) in micrometres."""
        unit = self.sim["instruments"]["xy"]["unit"]
        rr = await self.check(await self.client.read_input_registers(0, count=4, device_id=unit))
        r = rr.registers
        return s32(r[0], r[1]) / 1000.0, s32(r[2], r[3]) / 1000.0

    async def status(self, axis: str) -> int:
        unit = self.sim["axes"][axis]["unit"]
        rr = await self.check(await self.client.read_holding_registers(0x1003, device_id=unit))
        return rr.registers[0]

    async def feedback(self, axis: str) -> int:
        unit = self.sim["axes"][axis]["unit"]
        rr = await self.check(
            await self.client.read_holding_registers(0x602A, count=2, device_id=unit)
        )
        return s32(*rr.registers)

    async def control(self, address: int, values: list[int]) -> None:
        """Write the fault/control block."""
        await self.check(await self.client.write_registers(address, values, device_id=FAULTS_UNIT))


async def tcp_client(port: int, timeout_s: float = 1.0) -> AsyncModbusTcpClient:
    """A connected TCP client with short timeouts and no retries."""
    client = AsyncModbusTcpClient("127.0.0.1", port=port, timeout=timeout_s, retries=0)
    assert await client.connect()
    return client


async def rtu_client(
    port: str, timeout_s: float = 1.0, trace_packet: Any = None
) -> AsyncModbusSerialClient:
    """A connected RTU client on a serial device (a pty); open each pty end only once."""
    client = AsyncModbusSerialClient(
        port,
        baudrate=115200,
        parity="N",
        stopbits=1,
        timeout=timeout_s,
        retries=0,
        trace_packet=trace_packet,
    )
    assert await client.connect()
    return client
