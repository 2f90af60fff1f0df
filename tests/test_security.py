"""Security: allowlist, connection limit, idle timeout, write protection, status-unit
control off by default (the daemon protects the drives; Modbus has no authentication)."""

from __future__ import annotations

import asyncio
import logging
import socket
from pathlib import Path

from gateway.modbus.frames import pack_int32
from tests.gateway_rig import SPEED, TARGET, rig
from tests.test_gateway_e2e import read32
from tests.test_service_helpers import mbap, read_pdu, sim_and_gateway


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
            with caplog.at_level(logging.WARNING, logger="gateway.modbus.upstream"):
                assert await raw_request(app.tcp_port, read_pdu(3, 0x6200, 1)) is None
            assert app.tcp.counters.refused == before + 1
            assert "not in the allowlist" in caplog.text
            reply = await raw_request(app.tcp_port, read_pdu(3, 0x6200, 1), source="127.0.0.2")
            assert reply is not None and reply[:2] == b"\x03\x02"

    run(body())


def _rss_kib(pid: int) -> int:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1])
    raise AssertionError("no VmRSS")


async def _closed_by_server(reader: asyncio.StreamReader, timeout_s: float = 5.0) -> bool:
    try:
        return await asyncio.wait_for(reader.read(100), timeout_s) == b""
    except ConnectionError:
        return True


def test_silent_and_dripping_clients_never_lock_out_a_master(tmp_path: Path):
    """2 × max_connections silent clients, then max_connections clients dripping a frame
    byte by byte: each newcomer closes the connection idle longest (first those that never
    sent a request), a real master is still served, every drip is closed frame_timeout_s
    after its first byte, and the gateway's memory stays flat over rounds of it."""
    limit, frame_timeout_s = 4, 0.6

    def edit(data):
        data["upstream"]["tcp"].update(max_connections=limit, idle_timeout_s=30,
                                       frame_timeout_s=frame_timeout_s)

    async def round_(port: int) -> None:
        silent = []
        for i in range(2 * limit):
            silent.append(await asyncio.open_connection("127.0.0.1", port))
            if i >= limit:  # full: this one closed the oldest silent connection, only it
                assert await _closed_by_server(silent[i - limit][0])
                assert not any(r.at_eof() for r, _ in silent[i - limit + 1:])
        drips = []
        loop = asyncio.get_running_loop()
        for _ in range(limit):
            reader, writer = await asyncio.open_connection("127.0.0.1", port)
            writer.write(bytes((0, 1, 0, 0, 0, 254, 1)))  # announces a 253-byte PDU ...
            drips.append((reader, writer, loop.time()))
        for reader, _ in silent:
            assert await _closed_by_server(reader)
        # a real master gets in (closing the oldest drip) and is served
        reply = await raw_request(port, read_pdu(3, 0x6200, 2))
        assert reply is not None and reply[:2] == b"\x03\x04"
        for k, (reader, writer, t0) in enumerate(drips):
            if k == 0:
                assert await _closed_by_server(reader)
                continue
            closed = False
            while not closed:  # ... and drips a byte every 0.1 s until the gateway closes it
                writer.write(b"\x03")
                try:
                    closed = await asyncio.wait_for(reader.read(100), 0.1) == b""
                except asyncio.TimeoutError:
                    pass
                except ConnectionError:  # a byte sent after the close is answered by a reset
                    closed = True
                assert loop.time() - t0 < 30.0, "drip client never closed"  # a bound, no timing
            assert loop.time() - t0 >= frame_timeout_s - 0.05
        for _, writer in silent:
            writer.close()
        for _, writer, _ in drips:
            writer.close()

    with sim_and_gateway(tmp_path, edit) as r:
        port, pid = r["port"], r["gw"].popen.pid

        async def body() -> list[int]:
            rss = []
            for _ in range(6):
                await round_(port)
                rss.append(_rss_kib(pid))
            return rss

        rss = asyncio.run(asyncio.wait_for(body(), 60))
        print(f"gateway RSS over the rounds: {rss} KiB")
        assert rss[-1] - rss[1] < 1024, f"gateway RSS grew {rss} KiB over the rounds"
        log = r["gw"].text()
        assert "closed to make room" in log and "no request yet" in log
        assert "frame incomplete" in log


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
            assert await raw_request(app.tcp_port, b"\x10\x62", unit=1) == b"\x90\x03"
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
