"""The Prometheus endpoint: off by default, loopback when on, counts after some traffic."""

from __future__ import annotations

import asyncio
import os
import re
from pathlib import Path

from gateway.modbus.frames import pack_int32
from tests.gateway_rig import TARGET, TRIGGER, rig
from tests.helpers_modbus import wait_for_condition

PITCH_X = "position_mm,error_um\n0,0\n200,12\n400,20\n600,8\n800,-15\n"


async def scrape(port: int, path: str = "/metrics") -> tuple[str, str]:
    reader, writer = await asyncio.open_connection("127.0.0.1", port)
    writer.write(f"GET {path} HTTP/1.1\r\nHost: x\r\n\r\n".encode())
    await writer.drain()
    data = await reader.read()
    writer.close()
    head, _, body = data.decode().partition("\r\n\r\n")
    return head.split("\r\n")[0], body


def value(body: str, name: str, **labels: str) -> float:
    want = ",".join(f'{k}="{v}"' for k, v in sorted(labels.items()))
    pattern = "^" + re.escape(name) + (r"\{" + re.escape(want) + r"\}" if want else "") + r" (\S+)$"
    match = re.search(pattern, body, re.M)
    assert match, f"{name}{{{want}}} not in:\n{body}"
    return float(match.group(1))


def metrics_on(data: dict) -> None:
    """Config edit: the Prometheus endpoint on a free loopback port."""
    data["metrics"] = {"port": 0}


def put_on_line(path: str, noise: bytes) -> None:
    """Write raw bytes at one end of a cable, as noise on the line."""
    fd = os.open(path, os.O_WRONLY | os.O_NOCTTY)
    try:
        os.write(fd, noise)
    finally:
        os.close(fd)


def test_metrics_are_off_by_default(tmp_path: Path):
    async def body():
        async with rig(tmp_path) as r:
            assert r["app"].metrics is None

    asyncio.run(asyncio.wait_for(body(), 30))


def test_scrape_after_traffic(tmp_path: Path):
    def edit(data):
        data["metrics"] = {"port": 0}
        data["axes"]["X"]["compensation"]["pitch"] = "x.csv"

    async def body():
        async with rig(tmp_path, edit, {"x.csv": PITCH_X}) as r:
            app, master = r["app"], r["master"]
            assert app.metrics.host == "127.0.0.1"
            for _ in range(5):
                assert not (await master.read_holding_registers(0x6200, count=1,
                                                                device_id=1)).isError()
            assert not (await master.write_registers(TARGET, list(pack_int32(300_000)),
                                                     device_id=1)).isError()
            assert not (await master.write_register(TRIGGER, 0x10, device_id=1)).isError()
            rr = await master.read_holding_registers(0, count=1, device_id=99)  # not routed
            assert rr.isError() and rr.exception_code == 0x0A
            rr = await master.write_register(TARGET, 1, device_id=1)  # half → held, ok
            status, text = await scrape(app.metrics.port)
            assert status == "HTTP/1.1 200 OK"
            assert value(text, "compgw_requests_total", function="3") == 6
            assert value(text, "compgw_requests_total", function="16") == 1
            assert value(text, "compgw_exceptions_total", function="3", code="0x0A") == 1
            assert value(text, "compgw_request_seconds_count", function="3") == 6
            assert value(text, "compgw_request_seconds_bucket", function="3", le="+Inf") == 6
            assert value(text, "compgw_bus_queue_depth", bus="line1") == 0
            assert value(text, "compgw_bus_connected", bus="line1") == 1
            assert value(text, "compgw_bus_transactions_total", bus="line1") >= 7
            correction = value(text, "compgw_axis_last_correction_mm", axis="X")
            assert abs(correction - app.gateway.last_correction_mm("X")) < 1e-9
            assert abs(correction) > 0.01  # the table's ≈ +16 µm at 300 mm
            assert value(text, "compgw_axis_delta_a_mm", axis="X") == 0
            assert value(text, "compgw_commits_total") == 1
            assert value(text, "compgw_upstream_connections_open", listener="tcp") == 1
            assert value(text, "compgw_thermal_alarm") == 0
            status, _ = await scrape(app.metrics.port, "/other")
            assert status.startswith("HTTP/1.1 404")

    asyncio.run(asyncio.wait_for(body(), 30))


def test_sensor_state_is_exported(tmp_path: Path):
    def edit(data):
        data["metrics"] = {"port": 0}
        data["thermal_sources"] = {"x_ref": {
            "bus": "line1", "unit": 10, "scale_mm": 1e-6, "poll_s": 0.05, "noise_mm": 0.0015,
            "register": {"address": 1, "table": "input", "words": 2, "order": "hi_lo"}}}
        data["axes"]["X"]["compensation"]["thermal"] = {"source": "x_ref", "length_mm": 800}

    async def body():
        async with rig(tmp_path, edit) as r:
            app = r["app"]
            sensor = app.sensors["x_ref"]
            while sensor.counters.accepted < 2:  # the poll loop's own pace (poll_s)
                await asyncio.sleep(0.05)
            _, text = await scrape(app.metrics.port)
            assert value(text, "compgw_thermal_source_state", source="x_ref") == int(sensor.state)
            assert int(sensor.state) in (0, 1)  # starting or ok
            assert value(text, "compgw_thermal_source_delta_a_mm", source="x_ref") == \
                (sensor.delta_a_mm or 0.0)
            assert value(text, "compgw_thermal_source_failures_total", source="x_ref") == 0

    asyncio.run(asyncio.wait_for(body(), 30))


def test_rtu_line_noise_is_counted(tmp_path: Path):
    """Bytes on the drives' line that belong to no reply are dropped and counted."""

    async def body():
        async with rig(tmp_path, metrics_on, drives="rtu") as r:
            app, master = r["app"], r["master"]
            assert not (await master.read_holding_registers(0x6200, count=1,
                                                            device_id=1)).isError()
            _, text = await scrape(app.metrics.port)
            assert value(text, "compgw_bus_line_garbage_bytes_total", bus="line1") == 0
            assert value(text, "compgw_bus_line_empty_wakeups_total", bus="line1") == 0
            put_on_line(r["drive_line"].a, b"\xff\x00\x55\x13")  # between two transactions
            line = app.buses["line1"].line
            await wait_for_condition(lambda: line.pending_bytes >= 4)  # at the gateway's end
            assert not (await master.read_holding_registers(0x6200, count=1,
                                                            device_id=1)).isError()
            _, text = await scrape(app.metrics.port)
            assert value(text, "compgw_bus_line_garbage_bytes_total", bus="line1") == 4

    asyncio.run(asyncio.wait_for(body(), 30))


def test_upstream_rtu_line_noise_is_counted(tmp_path: Path):
    """Noise on the masters' RTU line is skipped, counted, and the next request served."""

    async def body():
        async with rig(tmp_path, metrics_on, upstream="rtu") as r:
            app, master = r["app"], r["master"]
            put_on_line(r["upstream_line"].b, b"\xff\x00\x55")  # the masters' end
            # dropped once the line fell silent
            await wait_for_condition(lambda: app.rtu.line.garbage_bytes >= 3)
            assert not (await master.read_holding_registers(0x6200, count=1,
                                                            device_id=1)).isError()
            _, text = await scrape(app.metrics.port)
            assert value(text, "compgw_upstream_line_garbage_bytes_total", listener="rtu") == 3
            assert value(text, "compgw_upstream_line_empty_wakeups_total", listener="rtu") == 0
            assert value(text, "compgw_requests_total", function="3") == 1

    asyncio.run(asyncio.wait_for(body(), 30))
