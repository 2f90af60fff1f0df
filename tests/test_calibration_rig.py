"""The example sim and a gateway in a background thread, so `compgw calibrate` (which runs
its own event loop) can be called in the test thread as a user would call it.

Configs switch by reload (same listeners, buses and thermal sources), like SIGHUP.
"""

from __future__ import annotations

import asyncio
import contextlib
import copy
import io
import threading
import time
from pathlib import Path
from typing import Any

import yaml
from pymodbus.client import ModbusTcpClient

from gateway.app import GatewayApp, load
from gateway.cli import main as cli_main
from gateway.event_loop import new_loop
from gateway.sensors import ThermalState
from sim.config import load_config as load_sim_config
from sim.server import SimServer

ROOT = Path(__file__).resolve().parent.parent
SIM_EXAMPLE = ROOT / "config" / "example-sim.yaml"
GATEWAY_EXAMPLE = ROOT / "config" / "example.yaml"
CONTROL_UNIT, ADVANCE_CLOCK_S = 250, 0x0800
#: thermal polls (s of wall): the sim runs faster than real time. Each poll is a round trip
#: to the sim in this process, so the polls cost CPU by the wall second: at 2 ms the
#: calibration flow spent 42 s of CPU on 2 busy cores, at 10 ms 33 s, its figures the same
#: within the runs' own scatter (drift with compensation -0.4 µm either way)
POLL_S = 0.01


def example_config(sim_port: int) -> dict[str, Any]:
    """config/example.yaml on free ports, tables under ``tables/`` of the test directory."""
    data = yaml.safe_load(GATEWAY_EXAMPLE.read_text())
    data["upstream"]["tcp"]["port"] = 0
    for bus in data["buses"].values():
        bus["tcp"]["port"] = sim_port
    for source in data["thermal_sources"].values():
        source["poll_s"] = POLL_S
        source["smoothing"] = 1.0
        # the sim's clock runs thousands of times faster than the wall clock the rate check uses
        source["max_rate_mm_s"] = 1.0
    return data


def without(data: dict[str, Any], *stages: str) -> dict[str, Any]:
    """A copy with the given stages (pitch, backlash_mm, thermal, planar) removed."""
    data = copy.deepcopy(data)
    for axis in data["axes"].values():
        for stage in stages:
            axis["compensation"].pop(stage, None)
    if "planar" in stages:
        data.pop("planar", None)
    return data


def compgw(*args: object) -> tuple[int, str, str]:
    """``compgw ARGS`` in this process: (exit code, stdout, stderr)."""
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        rc = cli_main([str(a) for a in args])
    return rc, out.getvalue(), err.getvalue()


def ok(*args: object) -> str:
    """``compgw ARGS`` that must succeed; prints its duration; returns its stdout."""
    t0 = time.monotonic()
    rc, out, err = compgw(*args)
    print(f"  {time.monotonic() - t0:5.2f} s  compgw {' '.join(str(a) for a in args[:4])}")
    assert rc == 0, (args, out, err)
    return out


class Bench:
    """Sim + gateway running in a thread; methods are called from the test thread."""

    def __init__(self, directory: Path) -> None:
        self.dir = directory
        # the loop `compgw run` and `compgw sim` serve on: uvloop (asyncio's own spent about
        # twice the CPU on the flows' requests)
        self._loop = new_loop()
        self._ready = threading.Event()
        self._stop: asyncio.Event | None = None
        self._error: BaseException | None = None
        self.app: GatewayApp | None = None
        self.sim_port = 0
        self.gateway_port = 0
        self._thread = threading.Thread(target=self._main, name="bench", daemon=True)

    # -- thread side --------------------------------------------------------------------------
    def _main(self) -> None:
        asyncio.set_event_loop(self._loop)
        try:
            self._loop.run_until_complete(self._serve())
        except BaseException as exc:  # reported to the test thread
            self._error = exc
            self._ready.set()

    async def _serve(self) -> None:
        self._stop = asyncio.Event()
        async with SimServer(load_sim_config(SIM_EXAMPLE), tcp_port=0, time_scale=0) as sim:
            self.sim = sim
            self.sim_port = sim.tcp_port
            path = self.write_config("start.yaml", without(
                example_config(sim.tcp_port), "pitch", "thermal", "planar"))  # fmt: skip
            config, chain = load(path)
            async with GatewayApp(config, chain) as app:
                self.app = app
                self.gateway_port = app.tcp_port
                self._ready.set()
                await self._stop.wait()

    # -- test side ----------------------------------------------------------------------------
    def __enter__(self) -> Bench:
        self._thread.start()
        self._ready.wait(30)
        if self._error is not None:
            raise self._error
        return self

    def __exit__(self, *exc: object) -> None:
        assert self._stop is not None
        self._loop.call_soon_threadsafe(self._stop.set)
        self._thread.join(30)

    def call(self, coro_fn, timeout_s: float = 30.0):  # type: ignore[no-untyped-def]
        return asyncio.run_coroutine_threadsafe(coro_fn(), self._loop).result(timeout_s)

    def write_config(self, name: str, data: dict[str, Any]) -> Path:
        path = self.dir / name
        path.write_text(yaml.safe_dump(data, sort_keys=False))
        return path

    def use(self, path: Path) -> None:
        """Reload the gateway with the config at ``path`` (validated first, as SIGHUP)."""
        config, chain = load(path)

        async def reload() -> None:
            assert self.app is not None
            self.app.reload(config, chain)

        self.call(reload)

    def cool_down(self, seconds: int = 20_000) -> None:
        """Let the machine cool (sim clock), then wait until the sensors read cold again."""
        client = ModbusTcpClient("127.0.0.1", port=self.sim_port, timeout=2)
        assert client.connect()
        try:
            reply = client.write_register(ADVANCE_CLOCK_S, seconds, device_id=CONTROL_UNIT)
            assert not reply.isError()
        finally:
            client.close()

        async def settle() -> None:
            assert self.app is not None
            sensors = self.app.sensors
            loop = asyncio.get_running_loop()
            deadline = loop.time() + 10
            while not all(
                sensors[n].state == ThermalState.OK and abs(sensors[n].delta_a_mm or 0) < 5e-4
                for n in sensors
            ):
                assert loop.time() < deadline, "thermal sensors did not settle"
                await asyncio.sleep(POLL_S)

        self.call(settle)

    @property
    def gateway(self) -> str:
        return f"127.0.0.1:{self.gateway_port}"

    def instrument(self, unit: int, address: int | None = None) -> str:
        tail = "" if address is None else f":{address}"
        return f"127.0.0.1:{self.sim_port}:{unit}{tail}"
