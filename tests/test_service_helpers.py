"""Helpers for the service tests: the sim and `compgw run` as real processes, a fake
systemd notify socket, raw Modbus TCP/RTU frames. (No tests here.)"""

from __future__ import annotations

import contextlib
import os
import re
import signal
import socket
import struct
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import yaml

from gateway.modbus.frames import rtu_encode
from tests.gateway_rig import SIM_EXAMPLE, base_config

ROOT = Path(__file__).resolve().parent.parent
FAULTS_UNIT = 250


class Proc:
    """A child process whose merged stdout/stderr is collected line by line by a thread;
    :meth:`wait_line` waits (on a condition, no polling) for a line matching a pattern."""

    def __init__(self, args: list[str], env: dict[str, str] | None = None) -> None:
        full_env = {**os.environ, "PYTHONUNBUFFERED": "1", **(env or {})}
        self.popen = subprocess.Popen(
            [sys.executable, *args], stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
            text=True, cwd=ROOT, env=full_env)
        self.lines: list[str] = []
        self._cond = threading.Condition()
        self._eof = False
        self._thread = threading.Thread(target=self._collect, daemon=True)
        self._thread.start()

    @property
    def pid(self) -> int:
        return self.popen.pid

    def _collect(self) -> None:
        assert self.popen.stdout is not None
        for line in self.popen.stdout:
            with self._cond:
                self.lines.append(line.rstrip("\n"))
                self._cond.notify_all()
        with self._cond:
            self._eof = True
            self._cond.notify_all()

    def wait_line(self, pattern: str, timeout_s: float = 20.0, start: int = 0) -> re.Match[str]:
        """First line (from index ``start``) matching ``pattern``."""
        regex = re.compile(pattern)
        deadline = time.monotonic() + timeout_s
        seen = start
        with self._cond:
            while True:
                for i in range(seen, len(self.lines)):
                    match = regex.search(self.lines[i])
                    if match:
                        return match
                seen = len(self.lines)
                remaining = deadline - time.monotonic()
                if self._eof or remaining <= 0:
                    raise AssertionError(f"no line matching {pattern!r}; output:\n"
                                         + "\n".join(self.lines[-40:]))
                self._cond.wait(remaining)

    def mark(self) -> int:
        with self._cond:
            return len(self.lines)

    def text(self) -> str:
        with self._cond:
            return "\n".join(self.lines)

    def signal(self, sig: int) -> None:
        self.popen.send_signal(sig)

    def stop(self, timeout_s: float = 20.0) -> int:
        if self.popen.poll() is None:
            self.popen.send_signal(signal.SIGTERM)
        try:
            return self.popen.wait(timeout=timeout_s)
        finally:
            if self.popen.poll() is None:
                self.popen.kill()
                self.popen.wait()
            self._thread.join(timeout=5)

    def kill(self) -> None:
        self.popen.kill()
        self.popen.wait()
        self._thread.join(timeout=5)


def start_sim(tmp_path: Path, port: int = 0, name: str = "sim.yaml") -> tuple[Proc, int]:
    """`compgw sim` with the example machine, instant moves; returns (process, tcp port)."""
    cfg = yaml.safe_load(SIM_EXAMPLE.read_text())
    cfg["sim"]["tcp"]["port"] = port
    cfg["sim"]["time_scale"] = 0
    path = tmp_path / name
    path.write_text(yaml.safe_dump(cfg))
    proc = Proc(["-m", "gateway.cli", "sim", "-c", str(path)])
    bound = int(proc.wait_line(r"modbus tcp on 127\.0\.0\.1:(\d+)").group(1))
    return proc, bound


def gateway_config(sim_port: int, **sections: Any) -> dict[str, Any]:
    """The rig's two-axis gateway (TCP upstream on port 0) with ``sections`` replaced."""
    data = base_config(sim_port)
    data.update(sections)
    return data


def start_gateway(tmp_path: Path, data: dict[str, Any], env: dict[str, str] | None = None,
                  name: str = "gw.yaml", wait: bool = True) -> tuple[Proc, int | None]:
    """`compgw run` on ``data``; returns (process, upstream TCP port or None)."""
    path = tmp_path / name
    path.write_text(yaml.safe_dump(data))
    proc = Proc(["-m", "gateway.cli", "run", "-c", str(path)], env=env)
    port = None
    if wait:
        match = proc.wait_line(r"compgw running: (?:Modbus TCP 127\.0\.0\.1:(\d+))?")
        port = int(match.group(1)) if match.group(1) else None
    return proc, port


@contextlib.contextmanager
def sim_and_gateway(tmp_path: Path, edit=None, env: dict[str, str] | None = None
                    ) -> Iterator[dict[str, Any]]:
    sim, sim_port = start_sim(tmp_path)
    gw = None
    try:
        data = gateway_config(sim_port)
        if edit is not None:
            edit(data)
        gw, port = start_gateway(tmp_path, data, env)
        yield {"sim": sim, "sim_port": sim_port, "gw": gw, "port": port, "data": data,
               "path": tmp_path / "gw.yaml"}
    finally:
        if gw is not None:
            gw.stop()
        sim.stop()


class NotifySocket:
    """A fake systemd notify socket: a unix datagram socket; a thread timestamps messages."""

    def __init__(self, tmp_path: Path) -> None:
        self.path = str(tmp_path / "notify.sock")
        self.sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        self.sock.bind(self.path)
        self.messages: list[tuple[float, str]] = []
        self._cond = threading.Condition()
        self._thread = threading.Thread(target=self._collect, daemon=True)
        self._thread.start()

    def _collect(self) -> None:
        while True:
            try:
                data = self.sock.recv(4096)
            except OSError:
                return
            if data == b"\0close":
                return
            with self._cond:
                self.messages.append((time.monotonic(), data.decode()))
                self._cond.notify_all()

    def wait_for(self, field: str, timeout_s: float = 20.0, after: float = 0.0
                 ) -> tuple[float, str]:
        """First message holding the line ``field`` (e.g. READY=1) received after ``after``."""
        deadline = time.monotonic() + timeout_s
        with self._cond:
            while True:
                for t, msg in self.messages:
                    if t > after and field in msg.split("\n"):
                        return t, msg
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    raise AssertionError(f"no {field} in {self.messages!r}")
                self._cond.wait(remaining)

    def times(self, field: str) -> list[float]:
        with self._cond:
            return [t for t, msg in self.messages if field in msg.split("\n")]

    def close(self) -> None:
        with contextlib.suppress(OSError):
            closer = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
            closer.sendto(b"\0close", self.path)
            closer.close()
        self._thread.join(timeout=5)
        self.sock.close()


# -- raw frames -------------------------------------------------------------------------------
def mbap(tid: int, unit: int, pdu: bytes) -> bytes:
    return struct.pack(">HHHB", tid, 0, len(pdu) + 1, unit) + pdu


def read_pdu(fc: int, address: int, count: int) -> bytes:
    return struct.pack(">BHH", fc, address, count)


def recv_mbap(sock: socket.socket, buf: bytearray) -> tuple[int, int, bytes] | None:
    """Next (tid, unit, pdu) from a TCP socket (``buf`` keeps leftovers); None at EOF."""
    while True:
        if len(buf) >= 6:
            size = 6 + int.from_bytes(buf[4:6], "big")
            if len(buf) >= size:
                tid, _, _, unit = struct.unpack(">HHHB", bytes(buf[:7]))
                pdu = bytes(buf[7:size])
                del buf[:size]
                return tid, unit, pdu
        data = sock.recv(65536)
        if not data:
            return None
        buf += data


def rtu(unit: int, pdu: bytes) -> bytes:
    return rtu_encode(unit, pdu)


def write_fault(sim_port: int, unit: int, mode: int = 0, delay_ms: int = 0, code: int = 0
                ) -> None:
    """Set a fault of ``unit`` in the sim's fault unit (direct to the sim)."""
    with socket.create_connection(("127.0.0.1", sim_port), timeout=5) as sock:
        pdu = struct.pack(">BHHB3H", 0x10, unit * 8, 3, 6, mode, delay_ms, code)
        sock.sendall(mbap(1, FAULTS_UNIT, pdu))
        reply = recv_mbap(sock, bytearray())
        assert reply is not None and reply[2][0] == 0x10, reply


def listening_sockets(pid: int) -> set[tuple[str, int]]:
    """(address, port) of every TCP socket the process ``pid`` listens on (from /proc)."""
    inodes = set()
    for fd in os.listdir(f"/proc/{pid}/fd"):
        with contextlib.suppress(OSError):
            target = os.readlink(f"/proc/{pid}/fd/{fd}")
            if target.startswith("socket:["):
                inodes.add(target[8:-1])
    found = set()
    for table, family in (("tcp", socket.AF_INET), ("tcp6", socket.AF_INET6)):
        with open(f"/proc/{pid}/net/{table}") as fh:
            next(fh)
            for line in fh:
                fields = line.split()
                local, state, inode = fields[1], fields[3], fields[9]
                if state != "0A" or inode not in inodes:
                    continue
                hex_addr, hex_port = local.split(":")
                raw = bytes.fromhex(hex_addr)
                if family == socket.AF_INET:
                    raw = raw[::-1]
                else:
                    raw = b"".join(raw[i:i + 4][::-1] for i in range(0, 16, 4))
                found.add((socket.inet_ntop(family, raw), int(hex_port, 16)))
    return found


class SimThread:
    """The example sim served from a thread of the test process (its own event loop), so a
    test can watch what reaches the drives: ``arrivals`` gets (unit, pdu) of each request
    and ``arrived`` is set at each one."""

    def __init__(self) -> None:
        import asyncio

        from sim.config import load_config
        from sim.server import SimServer

        self._asyncio = asyncio
        self.arrivals: list[tuple[int, bytes]] = []
        self.arrived = threading.Event()
        self._ready = threading.Event()
        self._loop = asyncio.new_event_loop()
        self.server = SimServer(load_config(SIM_EXAMPLE), tcp_port=0, time_scale=0)
        original = self.server.sim.respond

        def respond(unit: int, pdu: bytes):
            self.arrivals.append((unit, pdu))
            self.arrived.set()
            return original(unit, pdu)

        self.server.sim.respond = respond  # type: ignore[method-assign]
        self._stop: Any = None
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()
        assert self._ready.wait(20), "sim thread did not start"
        self.port: int = self.server.tcp_port  # type: ignore[assignment]

    def _run(self) -> None:
        asyncio = self._asyncio
        asyncio.set_event_loop(self._loop)

        async def main() -> None:
            self._stop = asyncio.Event()
            async with self.server:
                self._ready.set()
                await self._stop.wait()

        self._loop.run_until_complete(main())
        self._loop.close()

    def close(self) -> None:
        self._loop.call_soon_threadsafe(self._stop.set)
        self._thread.join(timeout=10)


def rtu_read_reply(fd: int, timeout_s: float = 2.0) -> bytes | None:
    """Collect bytes from a pty master until one whole RTU response frame (or None)."""
    import select

    from gateway.modbus.frames import find_rtu_frame, rtu_response_length

    buf = b""
    deadline = time.monotonic() + timeout_s
    while True:
        remaining = deadline - time.monotonic()
        if remaining <= 0:
            return None
        ready, _, _ = select.select([fd], [], [], remaining)
        if not ready:
            return None
        with contextlib.suppress(BlockingIOError):
            buf += os.read(fd, 4096)
        scan = find_rtu_frame(buf, rtu_response_length)
        if scan.frame is not None:
            return scan.frame


def rtu_drain(fd: int, quiet_s: float = 0.05) -> bytes:
    """Read until the line has been quiet for ``quiet_s`` (a silence condition)."""
    import select

    got = b""
    while select.select([fd], [], [], quiet_s)[0]:
        try:
            got += os.read(fd, 4096)
        except BlockingIOError:
            continue
        except OSError:
            break
    return got
