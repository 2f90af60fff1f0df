"""Security: allowlist, connection limit, idle timeout, write protection, status-unit
control off by default (the daemon protects the drives; Modbus has no authentication)."""

from __future__ import annotations

import asyncio
import logging
import socket
from pathlib import Path

from gateway.frames import pack_int32
from tests.gateway_rig import SPEED, TARGET, rig
from tests.test_gateway_e2e import read32
from tests.test_service_helpers import mbap, read_pdu


def run(coro, timeout_s: float = 30.0):
    return asyncio.run(asyncio.wait_for(coro, timeout_s))


async def raw_request(port: int, pdu: bytes, unit: int = 1, source: str | None = None
                      ) -> bytes | None:
    """One request on a fresh connection (from ``source`` address); the reply PDU, or None
    when the gateway closes the connection without answering."""
    sock = socket.socket()
    sock.setblocking(False)
    if source is not None:
        sock.bind((source, 0))
    await asyncio.get_running_loop().sock_connect(sock, ("127.0.0.1", port))
    reader, writer = await asyncio.open_connection(sock=sock)
    try:
        writer.write(mbap(0x1234, unit, pdu))
        await writer.drain()
        header = await reader.readexactly(7)
        body = await reader.readexactly(int.from_bytes(header[4:6], "big") - 1)
        assert header[:2] == b"\x12\x34"
        return body
    except (asyncio.IncompleteReadError, ConnectionError):
        return None
    finally:
        writer.close()


def test_client_outside_the_allowlist_is_refused_and_logged(tmp_path: Path, caplog):
    def edit(data):
        data["upstream"]["tcp"]["allow"] = ["127.0.0.2/32"]

    async def body():
        async with rig(tmp_path, edit) as r:
            app = r["app"]
            before = app.tcp.counters.refused  # the rig's own master (127.0.0.1) included
            with caplog.at_level(logging.WARNING, logger="gateway.upstream"):
                assert await raw_request(app.tcp_port, read_pdu(3, 0x6200, 1)) is None
            assert app.tcp.counters.refused == before + 1
            assert "not in the allowlist" in caplog.text
            reply = await raw_request(app.tcp_port, read_pdu(3, 0x6200, 1), source="127.0.0.2")
            assert reply is not None and reply[:2] == b"\x03\x02"

    run(body())


def test_connection_limit_and_idle_timeout(tmp_path: Path):
    def edit(data):
        data["upstream"]["tcp"].update(max_connections=2, idle_timeout_s=0.3)

    async def body():
        async with rig(tmp_path, edit) as r:
            app, master = r["app"], r["master"]
            port = app.tcp_port
            assert app.tcp.connection_count == 1  # the rig's master
            reader, writer = await asyncio.open_connection("127.0.0.1", port)
            # the third is closed at accept
            assert await raw_request(port, read_pdu(3, 0x6200, 1)) is None
            assert app.tcp.counters.refused >= 1
            # an idle connection is closed by the gateway after idle_timeout_s
            t0 = asyncio.get_running_loop().time()
            assert await asyncio.wait_for(reader.read(), 5) == b""
            assert asyncio.get_running_loop().time() - t0 >= 0.25
            writer.close()
            master.close()
            while app.tcp.connection_count:  # both idle ones gone: room again
                await asyncio.sleep(0.02)
            reply = await raw_request(port, read_pdu(3, 0x6200, 1))
            assert reply is not None and reply[0] == 3

    run(body())


def test_write_to_a_protected_range_gets_0x02_and_reaches_no_drive(tmp_path: Path):
    def edit(data):
        data["write_protect"] = [
            {"unit": 1, "address": 0x6200, "count": 4},  # target pair and speed of X
            {"unit": 20, "table": "coils"},  # every coil of the pass-through unit
        ]

    async def body():
        async with rig(tmp_path, edit) as r:
            app, master, direct = r["app"], r["master"], r["direct"]
            bus = app.buses["line1"]
            drive_target = await read32(direct, 1, TARGET)
            sent = bus.counters.transactions
            rr = await master.write_registers(TARGET, list(pack_int32(123_456)), device_id=1)
            assert rr.isError() and rr.exception_code == 0x02
            rr = await master.write_register(SPEED, 5, device_id=1)
            assert rr.isError() and rr.exception_code == 0x02
            rr = await master.write_registers(0x61FF, [1, 2], device_id=1)  # overlaps 0x6200
            assert rr.isError() and rr.exception_code == 0x02
            rr = await master.write_coil(0, True, device_id=20)
            assert rr.isError() and rr.exception_code == 0x02
            # a short (malformed) write PDU to a protected unit is refused too
            assert await raw_request(app.tcp_port, b"\x10\x62", unit=1) == b"\x90\x02"
            assert bus.counters.transactions == sent  # nothing reached a drive
            assert await read32(direct, 1, TARGET) == drive_target
            assert app.write_guard.refused == 5
            # outside the range, other units, and reads pass
            assert not (await master.write_register(0x6204, 0, device_id=1)).isError()
            assert not (await master.write_registers(TARGET, list(pack_int32(1000)),
                                                     device_id=2)).isError()
            assert not (await master.read_holding_registers(0x6200, count=4,
                                                            device_id=1)).isError()

    run(body())


def test_status_unit_refuses_control_writes_by_default(tmp_path: Path):
    async def body():
        async with rig(tmp_path) as r:
            app, master = r["app"], r["master"]
            rr = await master.write_register(0, 0, device_id=247)
            assert rr.isError() and rr.exception_code == 0x01
            rr = await master.write_registers(0, [0, 0], device_id=247)
            assert rr.isError() and rr.exception_code == 0x01
            assert app.gateway.axis_state("X").enabled and app.gateway.axis_state("Y").enabled

    run(body())
