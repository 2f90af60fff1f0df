"""Soak: the sim and `compgw run` as processes, masters at full rate for a bounded time.

    python bench/soak.py               # 10 minutes
    python bench/soak.py --minutes 3

Masters (threads, raw Modbus TCP, several requests in flight each) mix what an upper
computer does: reads of drive registers, feedback reads, moves (target FC16 + trigger
FC06) inside travel, status-unit reads. Every reply is checked (transaction id, function,
no exception). Reports transactions, rate, errors, and the gateway's RSS after warm-up,
at the end and the growth (target: <= 5 MB).
"""

from __future__ import annotations

import argparse
import json
import os
import re
import signal
import socket
import struct
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))


def rss_kib(pid: int) -> int:
    with open(f"/proc/{pid}/status") as fh:
        for line in fh:
            if line.startswith("VmRSS:"):
                return int(line.split()[1])
    return 0


def start(args: list[str], pattern: str) -> tuple[subprocess.Popen[str], int]:
    proc = subprocess.Popen([sys.executable, "-m", "gateway.cli", *args], cwd=ROOT,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                            env={**os.environ, "PYTHONUNBUFFERED": "1"})
    assert proc.stdout is not None
    for line in proc.stdout:
        match = re.search(pattern, line)
        if match:
            # keep draining the output so the child never blocks on a full pipe
            threading.Thread(target=lambda: [None for _ in proc.stdout], daemon=True).start()
            return proc, int(match.group(1))
    raise SystemExit(f"{args[0]} did not start: exit {proc.wait()}")


def mbap(tid: int, unit: int, pdu: bytes) -> bytes:
    return struct.pack(">HHHB", tid, 0, len(pdu) + 1, unit) + pdu


class Master(threading.Thread):
    def __init__(self, index: int, port: int, stop_at: float, window: int) -> None:
        super().__init__(daemon=True)
        self.index, self.port, self.stop_at, self.window = index, port, stop_at, window
        self.done = 0
        self.errors: dict[str, int] = {}

    def requests(self):
        unit = 1 + self.index % 2
        position = 100_000
        i = 0
        while True:
            i += 1
            kind = i % 10
            if kind < 5:
                yield unit, struct.pack(">BHH", 3, 0x6200, 8)
            elif kind < 7:
                yield unit, struct.pack(">BHH", 3, 0x602A, 2)
            elif kind == 7:
                yield 247, struct.pack(">BHH", 4, 0, 40)
            elif kind == 8:
                position = 100_000 + (i * 7919) % 400_000
                yield unit, struct.pack(">BHHBi", 0x10, 0x6201, 2, 4, position)
            else:
                yield unit, struct.pack(">BHH", 6, 0x6002, 0x10)

    def error(self, what: str) -> None:
        self.errors[what] = self.errors.get(what, 0) + 1

    def run(self) -> None:
        while time.monotonic() < self.stop_at:
            try:
                self._session()
            except OSError as exc:
                self.error(type(exc).__name__)

    def _session(self) -> None:
        gen = self.requests()
        with socket.create_connection(("127.0.0.1", self.port), timeout=10) as sock:
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            pending: dict[int, int] = {}
            buf = bytearray()
            tid = 0
            while True:
                if time.monotonic() < self.stop_at:
                    while len(pending) < self.window:
                        unit, pdu = next(gen)
                        tid = (tid + 1) & 0xFFFF
                        pending[tid] = pdu[0]
                        sock.sendall(mbap(tid, unit, pdu))
                elif not pending:
                    return
                while len(buf) < 6 or len(buf) < 6 + int.from_bytes(buf[4:6], "big"):
                    data = sock.recv(65536)
                    if not data:
                        self.error("closed")
                        return
                    buf += data
                size = 6 + int.from_bytes(buf[4:6], "big")
                r_tid = int.from_bytes(buf[0:2], "big")
                fc = buf[7]
                del buf[:size]
                want = pending.pop(r_tid, None)
                if want is None:
                    self.error("unknown tid")
                elif fc == want | 0x80:
                    self.error(f"exception FC{want:02d}")
                elif fc != want:
                    self.error("mismatched function")
                self.done += 1


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--minutes", type=float, default=10.0)
    parser.add_argument("--masters", type=int, default=4)
    parser.add_argument("--window", type=int, default=4, help="requests in flight per master")
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    tmp = Path(tempfile.mkdtemp(prefix="compgw-soak-"))
    sim_cfg = yaml.safe_load((ROOT / "config" / "example-sim.yaml").read_text())
    sim_cfg["sim"]["tcp"]["port"] = 0
    sim_cfg["sim"]["time_scale"] = 0
    (tmp / "sim.yaml").write_text(yaml.safe_dump(sim_cfg))
    gw_cfg = yaml.safe_load((ROOT / "config" / "example.yaml").read_text())
    sim, sim_port = start(["sim", "-c", str(tmp / "sim.yaml")], r"modbus tcp on [\d.]+:(\d+)")
    gw = None
    try:
        gw_cfg["upstream"]["tcp"]["port"] = 0
        gw_cfg["buses"]["line1"]["tcp"]["port"] = sim_port
        for axis in gw_cfg["axes"].values():
            axis["compensation"]["pitch"]["file"] = str(ROOT / "config" /
                                                        axis["compensation"]["pitch"]["file"])
        gw_cfg["planar"]["commit"] = "immediate"
        gw_cfg["planar"]["model"] = str(ROOT / "config" / gw_cfg["planar"]["model"])
        gw_cfg["metrics"] = {"port": 0}  # counted too, as in production
        (tmp / "gw.yaml").write_text(yaml.safe_dump(gw_cfg))
        gw, port = start(["run", "-c", str(tmp / "gw.yaml")],
                         r"compgw running: Modbus TCP [\d.]+:(\d+)")
        duration_s = args.minutes * 60
        t0 = time.monotonic()
        masters = [Master(i, port, t0 + duration_s, args.window) for i in range(args.masters)]
        for m in masters:
            m.start()
        warmup_s = min(30.0, duration_s * 0.1)
        time.sleep(warmup_s)
        rss_start = rss_kib(gw.pid)
        done_warm = sum(m.done for m in masters)
        samples = [rss_start]
        while time.monotonic() < t0 + duration_s:
            time.sleep(min(10.0, max(0.0, t0 + duration_s - time.monotonic())))
            samples.append(rss_kib(gw.pid))
        for m in masters:
            m.join(timeout=30)
        took = time.monotonic() - t0
        rss_end = rss_kib(gw.pid)
        total = sum(m.done for m in masters)
        errors: dict[str, int] = {}
        for m in masters:
            for key, n in m.errors.items():
                errors[key] = errors.get(key, 0) + n
        result = {
            "minutes": round(took / 60, 2), "masters": args.masters, "window": args.window,
            "transactions": total, "per_s": round(total / took),
            "per_s_after_warmup": round((total - done_warm) / (took - warmup_s)),
            "errors": sum(errors.values()), "error_kinds": errors,
            "rss_after_warmup_mib": round(rss_start / 1024, 1),
            "rss_end_mib": round(rss_end / 1024, 1),
            "rss_max_mib": round(max([*samples, rss_end]) / 1024, 1),
            "rss_growth_mib": round((rss_end - rss_start) / 1024, 2),
            "gateway_alive": gw.poll() is None,
        }
        if args.json:
            print(json.dumps(result))
        else:
            for key, value in result.items():
                print(f"{key:22} {value}")
            verdict = "ok" if result["rss_growth_mib"] <= 5 and not result["errors"] else "CHECK"
            print(f"{'verdict':22} {verdict} (target: RSS growth <= 5 MB, no errors)")
        return 0 if result["rss_growth_mib"] <= 5 and not result["errors"] else 1
    finally:
        for proc in (gw, sim):
            if proc is not None and proc.poll() is None:
                proc.send_signal(signal.SIGTERM)
                proc.wait(timeout=30)


if __name__ == "__main__":
    sys.exit(main())
