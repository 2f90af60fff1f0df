"""The sim's laser on the bridge line protocol (docs/instruments-bridge.md), over TCP, and
examples/bridge_template.py as a child process against the sim's Modbus laser.

Expectations come from the YAML numbers and from the sim's Modbus laser (the same truth),
never from the bridge's own code."""

from __future__ import annotations

import asyncio
import math
import os
import signal
import subprocess
import sys
from pathlib import Path
from typing import Any

import yaml

from sim.server import SimServer
from tests.test_sim_support import ROOT, Master, config_from, example_dict, run, tcp_client

TEMPLATE = ROOT / "examples" / "bridge_template.py"
LASER_UNIT = 20


def bridge_dict(**bridge: Any) -> dict[str, Any]:
    """The example machine (time_scale 0, 1 µm pulses) with the laser's bridge on port 0."""
    data = example_dict()
    data["sim"]["tcp"]["port"] = 0
    data["sim"]["instruments"]["laser"]["bridge"] = {"host": "127.0.0.1", "port": 0, **bridge}
    return data


class Line:
    """A TCP client of the bridge: one request line, one answer line."""

    def __init__(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        self.reader, self.writer = reader, writer

    @classmethod
    async def open(cls, port: int) -> Line:
        return cls(*await asyncio.open_connection("127.0.0.1", port))

    async def send(self, request: str) -> None:
        self.writer.write(f"{request}\n".encode())
        await self.writer.drain()

    async def ask(self, request: str, timeout_s: float = 5.0) -> str:
        await self.send(request)
        raw = await asyncio.wait_for(self.reader.readline(), timeout_s)
        assert raw.endswith(b"\n"), raw
        return raw.decode("utf-8").rstrip("\n")

    def close(self) -> None:
        self.writer.close()


def read_values(answer: str) -> tuple[list[float], str, str]:
    """``OK V [V ...] UNIT STATE`` → (values, unit, state)."""
    fields = answer.split(" ")
    assert fields[0] == "OK" and len(fields) >= 4, answer
    return [float(v) for v in fields[1:-2]], fields[-2], fields[-1]


def test_hello_read_bye_answer_the_protocol() -> None:
    data = bridge_dict()

    async def body() -> None:
        async with SimServer(config_from(data)) as server:
            assert server.laser_bridge_port and server.laser_bridge_port > 0
            client = await tcp_client(server.tcp_port)
            master = Master(client, data)
            await master.move_mm("X", 321.0)
            await master.move_mm("Y", 45.5)
            line = await Line.open(server.laser_bridge_port)
            assert await line.ask("HELLO 1") == "OK sim-laser channels=X,Y unit=um"
            (x_um, y_um), unit, state = read_values(await line.ask("READ X Y"))
            assert (unit, state) == ("um", "STABLE")
            # the Modbus laser reads the same truth (noise 0.05 µm, resolution 0.1 µm)
            assert abs(x_um - await master.laser_um("X")) <= 0.5
            assert abs(y_um - await master.laser_um("Y")) <= 0.5
            assert abs(x_um - 321_000) < 200 and abs(y_um - 45_500) < 200  # errors: tens of µm
            (y_only,), _, _ = read_values(await line.ask("READ Y"))
            assert abs(y_only - y_um) <= 0.5
            # \r\n is accepted as a line end
            assert (await line.ask("HELLO 1\r")).startswith("OK sim-laser ")
            assert await line.ask("BYE") == "OK"
            assert await asyncio.wait_for(line.reader.read(), 5.0) == b""  # closed after BYE
            line.close()
            client.close()

    run(body())


def test_read_until_stable_lets_the_axis_settle_at_time_scale_0() -> None:
    data = bridge_dict()
    # rings 5 µm, tau 50 ms; each reading takes 10 ms of machine time; stable band 0.1 µm
    data["sim"]["machine"]["X"]["settling"] = {"amplitude_um": 5.0, "time_constant_s": 0.05,
                                               "period_s": 0.03}  # fmt: skip
    data["sim"]["instruments"]["laser"].update(sample_s=0.01, stable_band_um=0.1)
    # the envelope 5·e^(−t/0.05) is within 0.1 µm from t = 0.05·ln 50 = 0.196 s: reading 20
    first_stable = math.ceil(0.05 * math.log(5.0 / 0.1) / 0.01)

    async def body() -> None:
        async with SimServer(config_from(data)) as server:
            client = await tcp_client(server.tcp_port)
            master = Master(client, data)
            await master.move_mm("X", 200.0)
            line = await Line.open(server.laser_bridge_port)
            states: list[str] = []
            values: list[float] = []
            while not states or states[-1] != "STABLE":
                (value,), _, state = read_values(await line.ask("READ X"))
                states.append(state)
                values.append(value)
                assert len(states) < 100, "never stable"
            assert states[0] == "MOVING"
            assert len(states) == first_stable, states
            assert abs(values[-1] - await master.laser_um("X")) <= 0.5
            line.close()
            client.close()

    run(body())


def test_errors_are_err_lines_and_the_line_stays_usable() -> None:
    async def body() -> None:
        async with SimServer(config_from(bridge_dict())) as server:
            line = await Line.open(server.laser_bridge_port)
            for request in ("READ Z", "READ X Z", "READ", "HELLO 2", "HELLO", "NOPE 1",
                            "read X", "READ  X", "BYE now"):  # fmt: skip
                answer = await line.ask(request)
                assert answer.startswith("ERR ") and len(answer) > 4, (request, answer)
            assert "Z" in await line.ask("READ Z")  # the unknown channel is named
            await line.send("")
            assert (await line.reader.readline()).startswith(b"ERR ")
            line.writer.write(b"\xff\xfe READ\n")
            assert (await line.reader.readline()).startswith(b"ERR ")
            assert read_values(await line.ask("READ X"))[1] == "um"
            line.close()

    run(body())


def test_hang_after_n_requests_answers_nothing_more() -> None:
    async def body() -> None:
        async with SimServer(config_from(bridge_dict(hang_after=2))) as server:
            bridge = server.laser_bridge
            assert bridge is not None
            line = await Line.open(server.laser_bridge_port)
            assert (await line.ask("HELLO 1")).startswith("OK sim-laser")
            assert read_values(await line.ask("READ X"))[2] == "STABLE"
            await line.send("READ X")
            await line.send("BYE")
            while bridge.requests < 4:  # both were received ...
                await asyncio.sleep(0.01)
            try:  # ... and neither is answered; the connection stays open
                got = await asyncio.wait_for(line.reader.readline(), 0.3)
            except asyncio.TimeoutError:
                got = None
            assert got is None, got
            assert not line.reader.at_eof()
            line.close()

    run(body())


def test_garbage_after_n_requests_answers_banana() -> None:
    async def body() -> None:
        async with SimServer(config_from(bridge_dict(garbage_after=1))) as server:
            line = await Line.open(server.laser_bridge_port)
            assert (await line.ask("HELLO 1")).startswith("OK sim-laser")
            assert await line.ask("READ X") == "OK banana"
            assert await line.ask("BYE") == "OK banana"  # and the line stays open
            assert await line.ask("READ Z") == "OK banana"
            line.close()

    run(body())


def test_template_bridge_answers_as_the_sims_bridge() -> None:
    data = bridge_dict()

    async def body() -> None:
        async with SimServer(config_from(data)) as server:
            client = await tcp_client(server.tcp_port)
            master = Master(client, data)
            await master.move_mm("X", 456.0)
            child = await asyncio.create_subprocess_exec(
                sys.executable, str(TEMPLATE),
                "--modbus", f"127.0.0.1:{server.tcp_port}:{LASER_UNIT}", "--channels", "X,Y",
                stdin=asyncio.subprocess.PIPE, stdout=asyncio.subprocess.PIPE,
                stderr=asyncio.subprocess.PIPE)  # fmt: skip
            assert child.stdin is not None and child.stdout is not None

            async def ask(request: str) -> str:
                child.stdin.write(f"{request}\n".encode())
                await child.stdin.drain()
                raw = await asyncio.wait_for(child.stdout.readline(), 20.0)
                return raw.decode().rstrip("\n")

            try:
                hello = await ask("HELLO 1")
                assert hello.startswith("OK ") and "channels=X,Y" in hello, hello
                (tpl_x,), unit, state = read_values(await ask("READ X"))
                assert (unit, state) == ("um", "STABLE")
                line = await Line.open(server.laser_bridge_port)
                (sim_x,), _, _ = read_values(await line.ask("READ X"))
                line.close()
                assert abs(tpl_x - sim_x) <= 0.5  # noise 0.05 µm, resolution 0.1 µm
                tpl_xy, _, _ = read_values(await ask("READ X Y"))
                assert len(tpl_xy) == 2
                assert (await ask("READ Q")).startswith("ERR ")
                assert await ask("BYE") == "OK"
                assert await asyncio.wait_for(child.wait(), 20.0) == 0
            finally:
                if child.returncode is None:
                    child.kill()
                    await child.wait()
            client.close()

    run(body(), timeout_s=60.0)


def test_template_answers_err_when_the_instrument_is_gone() -> None:
    # port 1 on loopback: nothing listens there
    proc = subprocess.run(
        [sys.executable, str(TEMPLATE), "--modbus", "127.0.0.1:1:20", "--channels", "X"],
        input="HELLO 1\nREAD X\nBYE\n", capture_output=True, text=True, timeout=60)  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    lines = proc.stdout.splitlines()
    assert lines[0].startswith("OK ") and lines[2] == "OK", lines
    assert lines[1].startswith("ERR ") and "Traceback" not in proc.stdout, lines


def test_compgw_sim_prints_the_bridge_and_serves_it(tmp_path: Path) -> None:
    cfg = tmp_path / "sim.yaml"
    cfg.write_text(yaml.safe_dump(bridge_dict()))
    proc = subprocess.Popen(
        [sys.executable, "-m", "gateway.cli", "sim", "-c", str(cfg)], cwd=ROOT,
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        env={**os.environ, "PYTHONUNBUFFERED": "1"})  # fmt: skip
    try:
        assert proc.stdout is not None
        port = None
        for _ in range(10):
            line = proc.stdout.readline()
            if "laser bridge on" in line:
                assert line.startswith("compgw sim: laser bridge on 127.0.0.1:"), line
                port = int(line.rsplit(":", 1)[1])
                break
        assert port, "no 'laser bridge on' line"

        async def hello() -> str:
            line = await Line.open(port)
            try:
                return await line.ask("HELLO 1")
            finally:
                line.close()

        assert run(hello()) == "OK sim-laser channels=X,Y unit=um"
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(timeout=30) == 0
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
