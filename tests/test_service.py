"""systemd integration: the unit files verify, READY/STATUS/STOPPING/WATCHDOG over a fake
notify socket, a blocked event loop stops the watchdog pings, graceful stop, and nothing
listens on an address that is not configured."""

from __future__ import annotations

import asyncio
import contextlib
import itertools
import re
import shutil
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml

from gateway.app import serve
from tests.test_service_helpers import (
    ROOT,
    NotifySocket,
    SimThread,
    gateway_config,
    listening_sockets,
    mbap,
    read_pdu,
    recv_mbap,
    sim_and_gateway,
    start_gateway,
    write_fault,
)

UNITS = ("compgw.service", "compgw@.service")


@pytest.mark.parametrize("unit", UNITS)
def test_systemd_analyze_verify(unit: str, tmp_path: Path):
    tool = shutil.which("systemd-analyze")
    if tool is None:
        pytest.skip("systemd-analyze not installed (Debian package systemd)")
    text = (ROOT / "systemd" / unit).read_text()
    assert "/opt/compgw/bin/compgw run -c /etc/compgw/" in text
    # verify checks that ExecStart exists: point it at this checkout's compgw
    compgw = Path(sys.executable).parent / "compgw"
    if not compgw.exists():
        pytest.skip(f"{compgw} not installed (pip install -e .)")
    (tmp_path / unit).write_text(text.replace("/opt/compgw/bin/compgw", str(compgw)))
    result = subprocess.run([tool, "verify", str(tmp_path / unit)], capture_output=True,
                            text=True, timeout=60, cwd=tmp_path)
    assert result.returncode == 0, result.stdout + result.stderr
    assert "compgw" not in result.stderr, result.stderr  # no warning about our unit


def test_unit_files_say_what_the_issue_asks():
    for unit in UNITS:
        text = (ROOT / "systemd" / unit).read_text()
        keys = dict(re.findall(r"^(\w+)=(.*)$", text, re.M))
        assert keys["Type"] == "notify" and keys["Restart"] == "on-failure"
        assert int(keys["WatchdogSec"]) > 0
        assert keys["DynamicUser"] == "yes" and keys["SupplementaryGroups"] == "dialout"
        assert keys["ProtectSystem"] == "strict" and keys["PrivateTmp"] == "yes"
        assert keys["NoNewPrivileges"] == "yes"
        assert keys["CapabilityBoundingSet"] == "" and keys["AmbientCapabilities"] == ""
        assert "CAP_NET_BIND_SERVICE" in text  # explained in a comment
        assert keys["ExecReload"] == "/bin/kill -HUP $MAINPID"
    assert "/etc/compgw/%i.yaml" in (ROOT / "systemd" / "compgw@.service").read_text()


def test_watchdog_pings_stop_while_the_event_loop_is_blocked(tmp_path: Path, monkeypatch):
    """In-process daemon, fake notify socket, WATCHDOG_USEC=0.2 s: pings every 0.1 s;
    the loop blocked for 0.8 s sends none (systemd would see a gap above WatchdogSec)."""
    notify = NotifySocket(tmp_path)
    monkeypatch.setenv("NOTIFY_SOCKET", notify.path)
    monkeypatch.setenv("WATCHDOG_USEC", "200000")
    monkeypatch.delenv("WATCHDOG_PID", raising=False)
    interval_s = 0.1
    sim = SimThread()
    path = tmp_path / "gw.yaml"
    path.write_text(yaml.safe_dump(gateway_config(sim.port)))

    async def body() -> None:
        stop = asyncio.Event()
        ready: list = []
        task = asyncio.create_task(serve(path, stop=stop, on_ready=ready.append))
        loop = asyncio.get_running_loop()
        t_ready, msg = await loop.run_in_executor(None, notify.wait_for, "READY=1")
        port = int(re.search(r"Modbus TCP 127\.0\.0\.1:(\d+)", msg).group(1))
        assert "buses: line1 up" in msg
        # listening already when READY=1 was sent
        _, writer = await asyncio.open_connection("127.0.0.1", port)
        writer.close()
        # a few pings at the interval
        for _ in range(3):
            last = notify.times("WATCHDOG=1")[-1] if notify.times("WATCHDOG=1") else 0.0
            await loop.run_in_executor(None, notify.wait_for, "WATCHDOG=1", 5.0, last)
        # now block the loop (a hung handler would do the same)
        t_block = time.monotonic()
        time.sleep(8 * interval_s)
        t_unblock = time.monotonic()
        await loop.run_in_executor(None, notify.wait_for, "WATCHDOG=1", 5.0, t_unblock)
        stop.set()
        assert await asyncio.wait_for(task, 20) == 0
        pings = notify.times("WATCHDOG=1")
        during = [t for t in pings if t_block + 0.01 < t < t_unblock]
        assert during == [], "a blocked loop must not ping"
        before = [t for t in pings if t_ready <= t <= t_block]
        gaps = [b - a for a, b in itertools.pairwise(before)]
        assert len(before) >= 3 and max(gaps) < 2 * interval_s * 3  # regular when healthy
        # detection as systemd sees it: no ping within 2 × interval while blocked
        worst = max(b - a for a, b in itertools.pairwise(pings))
        assert worst >= 2 * interval_s and worst >= (t_unblock - t_block) - interval_s
        assert notify.wait_for("STOPPING=1", 1.0)

    try:
        asyncio.run(asyncio.wait_for(body(), 60))
    finally:
        sim.close()
        notify.close()


def test_process_ready_status_and_stopping(tmp_path: Path):
    """`compgw run` as a process: READY=1 with the listener and bus state, pings at half
    WATCHDOG_USEC, STOPPING=1 and exit 0 on SIGTERM; a bus that is down at start is
    reported (READY is not held back by it)."""
    notify = NotifySocket(tmp_path)
    env = {"NOTIFY_SOCKET": notify.path, "WATCHDOG_USEC": "300000"}
    dead = socket.socket()
    dead.bind(("127.0.0.1", 0))  # bound, not listening: connection refused
    try:
        with sim_and_gateway(tmp_path, env=env) as r:
            _, msg = notify.wait_for("READY=1")
            assert f"Modbus TCP 127.0.0.1:{r['port']}" in msg and "line1 up" in msg
            t0 = notify.wait_for("WATCHDOG=1")[0]
            notify.wait_for("WATCHDOG=1", after=t0)
            r["gw"].signal(signal.SIGTERM)
            assert r["gw"].popen.wait(timeout=20) == 0
            notify.wait_for("STOPPING=1", 1.0)
            data = gateway_config(dead.getsockname()[1])
            gw, port = start_gateway(tmp_path, data, env, name="down.yaml")
            try:
                _, msg = notify.wait_for("READY=1", after=notify.times("STOPPING=1")[-1])
                assert "line1 DOWN" in msg
                gw.wait_line(r"line1: cannot open")
                # the bus comes up (a request opens it): STATUS= follows with a ping
                dead.listen()
                t_up = time.monotonic()
                assert port is not None
                with socket.create_connection(("127.0.0.1", port), timeout=10) as master:
                    for tid in range(9, 49):  # until its reconnect back-off lets one through
                        master.sendall(mbap(tid, 1, read_pdu(3, 0x6200, 1)))
                        with contextlib.suppress(AssertionError):
                            gw.wait_line(r"line1: open", timeout_s=0.5)
                            break
                    gw.wait_line(r"line1: open", timeout_s=1.0)
                    t, msg = notify.wait_for("WATCHDOG=1", after=t_up, timeout_s=20)
                    while "STATUS=" not in msg:  # the ping after the bus opened
                        t, msg = notify.wait_for("WATCHDOG=1", after=t, timeout_s=20)
                    assert "line1 up" in msg, msg
            finally:
                assert gw.stop() == 0
    finally:
        dead.close()
        notify.close()


def test_graceful_stop_finishes_the_transaction_in_flight(tmp_path: Path):
    """SIGTERM while a slow drive (sim fault delay) is answering: that reply still reaches
    the master with its transaction id, later requests get none, new connections are
    refused, exit 0."""
    sim = SimThread()
    try:
        write_fault(sim.port, 1, delay_ms=1500)
        data = gateway_config(sim.port)
        data["buses"]["line1"]["timeout_s"] = 4.0
        gw, port = start_gateway(tmp_path, data)
        try:
            with socket.create_connection(("127.0.0.1", port), timeout=10) as master:
                sim.arrived.clear()
                master.sendall(mbap(7, 1, read_pdu(3, 0x6200, 1)))
                assert sim.arrived.wait(10)  # the request is at the drive
                mark = gw.mark()
                gw.signal(signal.SIGTERM)
                gw.wait_line(r"stopping: finishing transactions in flight", start=mark)
                assert _refused_soon(port)
                master.sendall(mbap(8, 1, read_pdu(3, 0x6200, 1)))  # too late
                buf = bytearray()
                reply = recv_mbap(master, buf)
                assert reply is not None, gw.text()
                assert reply[0] == 7 and reply[2][:2] == b"\x03\x02"
                with contextlib.suppress(ConnectionResetError):
                    assert recv_mbap(master, buf) is None  # closed, nothing for tid 8
            assert gw.popen.wait(timeout=20) == 0
            assert sum(1 for unit, _ in sim.arrivals if unit == 1) == 1  # tid 8 never sent
        finally:
            gw.stop()
    finally:
        sim.close()


def _refused_soon(port: int, timeout_s: float = 5.0) -> bool:
    """True once a connection to ``port`` is refused (the listener closes right after
    the "stopping" line)."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        try:
            socket.create_connection(("127.0.0.1", port), timeout=2).close()
        except ConnectionRefusedError:
            return True
        except ConnectionResetError:  # accepted into the backlog as the listener closed
            continue
    return False


@pytest.mark.parametrize("metrics", [False, True])
def test_nothing_listens_on_an_address_not_configured(tmp_path: Path, metrics: bool):
    def edit(data):
        if metrics:
            data["metrics"] = {"port": 0}

    with sim_and_gateway(tmp_path, edit) as r:
        found = listening_sockets(r["gw"].pid)
        if not metrics:
            assert found == {("127.0.0.1", r["port"])}
        else:
            mport = int(r["gw"].wait_line(r"metrics on http://127\.0\.0\.1:(\d+)").group(1))
            assert found == {("127.0.0.1", r["port"]), ("127.0.0.1", mport)}


def test_a_second_gateway_on_a_taken_port_touches_no_drive_and_no_state(tmp_path: Path):
    """`compgw run` again beside the running service (its port taken): it fails at once,
    before opening a drive's bus (a drive may serve one connection) or writing the state
    file (the running gateway's), exit 3."""
    sim = SimThread()
    try:
        data = gateway_config(sim.port, state_file=str(tmp_path / "state.json"))
        first, port = start_gateway(tmp_path, data)
        try:
            assert port is not None
            first.wait_line(r"compgw running")
            (tmp_path / "state.json").write_text('{"format": 1, "axes": {}, "mine": 1}\n')
            before = (tmp_path / "state.json").read_bytes()
            data["upstream"]["tcp"]["port"] = port
            second, _ = start_gateway(tmp_path, data, name="again.yaml", wait=False)
            assert second.popen.wait(timeout=30) == 3
            text = "\n".join(second.lines)
            assert "cannot listen" in text and "already in use" in text.lower(), text
            assert "line1" not in text, text  # no bus opened
            assert (tmp_path / "state.json").read_bytes() == before
        finally:
            assert first.stop() == 0
    finally:
        sim.close()
