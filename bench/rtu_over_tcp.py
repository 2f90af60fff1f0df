"""RTU over TCP bench: the gateway's ``rtu_over_tcp`` bus against its ``tcp`` bus, same run.

Processes (all on 127.0.0.1, every port bound as 0 and read back from the output):

- sim: ``compgw sim`` with 8 drives, serving Modbus TCP and RTU over TCP (RTU frames with
  CRC in a TCP stream, as a serial device server in transparent mode passes them; each
  connection is a line of its own);
- gateway: ``compgw run`` with upstream TCP and three buses to the same drives: ``tcp``
  (Modbus TCP), ``rot`` (``rtu_over_tcp``, 115200 baud, ``t35: spec``: the Modbus 1.75 ms
  of silence before each request) and ``rot_exact`` (``t35: exact``: 0.30 ms at 115200);
  axes T1..T8, R1..R8 and E1..E8 (upstream units 1-8, 11-18, 21-28) on them.

Load (in this process, raw frames over asyncio streams, no pymodbus): 1 TCP master per
row on the gateway (each axis's drive through one bus); the direct floors are a Modbus
TCP master on the sim's TCP port and an RTU-over-TCP master on the sim's RTU-over-TCP
port (which sends again at once, as a TCP master does). Direct and gateway runs alternate
(D G G D, half the requests each). Every reply is checked (tid or CRC, function code, no
exception). tx/s is 1 / mean latency (one master: no overlap). When ``socat`` is installed,
a C byte pump between the RTU-over-TCP master and the sim is measured too (the floor of
anything that forwards those bytes, with no Modbus at all).

Cases: ``FC03x10@6200`` (covers the target pair: the gateway answers with its shadow) and
``FC16x2@6204`` (plain parameters, pass-through). No wire time anywhere (TCP loopback).

Run:  .venv/bin/python bench/rtu_over_tcp.py            (1000 requests per row, ~1 min)
      .venv/bin/python bench/rtu_over_tcp.py --quick    (200 per row)
"""

from __future__ import annotations

import argparse
import asyncio
import shutil
import statistics
import struct
import sys
import tempfile
import time
from collections.abc import Awaitable, Callable
from pathlib import Path

# the gateway bench's process and frame helpers (bench/ is first on sys.path)
from forwarding import Proc, compgw
from fwd_load import reply_length, rtu_frame

UNITS = tuple(range(1, 9))
BUSES = {"tcp": 0, "rot": 10, "rot_exact": 20}  # bus -> upstream unit offset
CASES = {
    "FC03x10@6200": struct.pack(">BHH", 3, 0x6200, 10),
    "FC16x2@6204": struct.pack(">BHHBHH", 16, 0x6204, 2, 4, 0x1234, 0x5678),
}
def configs(tmp: Path) -> tuple[Path, Callable[[int, int], Path]]:
    import yaml

    regs = {"memory": [{"address": 0x6200, "count": 16}]}
    sim = {"sim": {"seed": 1, "time_scale": 0, "tcp": {"host": "127.0.0.1", "port": 0},
                   "rtu_over_tcp": {"host": "127.0.0.1", "port": 0},
                   "axes": {f"A{u}": {"unit": u, "travel_mm": [0, 800], "registers": regs}
                            for u in UNITS}}}
    sim_path = tmp / "sim.yaml"
    sim_path.write_text(yaml.safe_dump(sim))

    def gateway(tcp_port: int, rot_port: int) -> Path:
        line = {"host": "127.0.0.1", "port": rot_port, "baudrate": 115200, "parity": "N"}
        buses = {"tcp": {"tcp": {"host": "127.0.0.1", "port": tcp_port}},
                 "rot": {"rtu_over_tcp": line},
                 "rot_exact": {"rtu_over_tcp": {**line, "t35": "exact"}}}
        for bus in buses.values():
            bus.update(timeout_s=0.2, retries=1)
        axes = {f"{bus[0].upper()}{'X' if bus == 'rot_exact' else ''}{u}": {
            "bus": bus, "unit": u, "upstream_unit": offset + u, "pulse_mm": 0.001,
            "travel_mm": [0, 800],
            "registers": {"target": {"address": 0x6201}, "feedback": {"address": 0x602A},
                          "status": {"address": 0x1003, "homed_bit": 6},
                          "trigger": {"address": 0x6002, "value": 0x10}}}
            for bus, offset in BUSES.items() for u in UNITS}
        cfg = {"upstream": {"tcp": {"host": "127.0.0.1", "port": 0}}, "buses": buses,
               "axes": axes}
        path = tmp / "gw.yaml"
        path.write_text(yaml.safe_dump(cfg))
        return path

    return sim_path, gateway


Request = Callable[[int, bytes], Awaitable[bytes]]


async def tcp_master(port: int) -> tuple[Request, Callable[[], None]]:
    reader, writer = await asyncio.open_connection("127.0.0.1", port)
    writer.get_extra_info("socket").setsockopt(6, 1, 1)  # TCP_NODELAY
    tid = [0]

    async def request(unit: int, pdu: bytes) -> bytes:
        tid[0] = tid[0] % 0xFFFF + 1
        writer.write(struct.pack(">HHHB", tid[0], 0, len(pdu) + 1, unit) + pdu)
        head = await reader.readexactly(7)
        body = await reader.readexactly(struct.unpack(">H", head[4:6])[0] - 1)
        if struct.unpack(">H", head[:2])[0] != tid[0]:
            raise RuntimeError("wrong transaction id")
        return body

    return request, writer.close


async def rtu_over_tcp_master(port: int) -> tuple[Request, Callable[[], None]]:
    reader, writer = await asyncio.open_connection("127.0.0.1", port)
    writer.get_extra_info("socket").setsockopt(6, 1, 1)

    async def request(unit: int, pdu: bytes) -> bytes:
        writer.write(rtu_frame(unit, pdu))
        frame = await reader.readexactly(reply_length(pdu))
        if rtu_frame(frame[0], frame[1:-2]) != frame:
            raise RuntimeError(f"bad RTU reply {frame.hex()}")
        return frame[1:-2]

    return request, writer.close


async def measure(request: Request, unit: int, pdu: bytes, n: int, cap_s: float
                  ) -> tuple[list[float], int]:
    """Latencies (s) of ``n`` requests (after 20 untimed) and the error count."""
    lat, errors = [], 0
    deadline = time.monotonic() + cap_s
    for i in range(n + 20):
        t0 = time.perf_counter()
        reply = await request(unit, pdu)
        if i >= 20:
            lat.append(time.perf_counter() - t0)
        if reply[0] != pdu[0]:
            errors += 1
        if time.monotonic() > deadline:
            break
    return lat, errors


def pct(values: list[float], q: float) -> float:
    s = sorted(values)
    return s[min(len(s) - 1, int(q / 100 * len(s)))] * 1000


async def bench(args: argparse.Namespace, sim: Proc, gw: Proc, ports: dict[str, int],
                pump: Proc | None) -> None:
    n = args.requests or (200 if args.quick else 1000)
    direct = {"tcp": await tcp_master(ports["sim_tcp"]),
              "rot": await rtu_over_tcp_master(ports["sim_rot"])}
    through = await tcp_master(ports["gw"])
    rows = [(case, bus) for case in CASES for bus in BUSES]
    if pump is not None:
        rows += [(case, "socat") for case in CASES]
        pumped = await rtu_over_tcp_master(ports["socat"])
    print(f"{n} requests per row, 1 master; p50/p99 in ms; added = gateway p50 - direct p50;"
          " cpu = gateway CPU per transaction (schedstat)\n")
    print("| case | bus | direct | d p50 | d p99 | gw p50 | gw p99 | p50 x | added | "
          "tx/s d | tx/s gw | cpu µs | err |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    label = {"tcp": "tcp", "rot": "rtu_over_tcp", "rot_exact": "rtu_over_tcp exact",
             "socat": "socat pump (C), not the gateway"}
    for case, bus in rows:
        pdu = CASES[case]
        floor = "tcp" if bus == "tcp" else "rot"
        forward, unit, proc = (pumped[0], 1, pump) if bus == "socat" else (
            through[0], BUSES[bus] + 1, gw)
        d_lat: list[float] = []
        g_lat: list[float] = []
        errors, cpu = 0, 0.0
        half = max(n // 2, 1)
        for side in ("d", "g", "g", "d"):
            if side == "d":
                lat, err = await measure(direct[floor][0], 1, pdu, half, args.time_cap)
                d_lat += lat
            else:
                assert proc is not None
                cpu0 = proc.cpu_s()
                lat, err = await measure(forward, unit, pdu, half, args.time_cap)
                cpu += proc.cpu_s() - cpu0
                g_lat += lat
            errors += err
        d50, g50 = pct(d_lat, 50), pct(g_lat, 50)
        print(f"| {case} | {label[bus]} | {'tcp' if floor == 'tcp' else 'rtu/tcp'} | "
              f"{d50:.3f} | {pct(d_lat, 99):.3f} | {g50:.3f} | {pct(g_lat, 99):.3f} | "
              f"{g50 / d50:.2f} | {g50 - d50:+.3f} | {1 / statistics.fmean(d_lat):.0f} | "
              f"{1 / statistics.fmean(g_lat):.0f} | {cpu / len(g_lat) * 1e6:.0f} | "
              f"{errors} |", flush=True)
    for _, close in (*direct.values(), through, *([pumped] if pump is not None else [])):
        close()


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="200 requests per row")
    ap.add_argument("--requests", type=int, help="requests per row (default 1000)")
    ap.add_argument("--time-cap", type=float, default=30.0, help="seconds per measurement")
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory(prefix="compgw-rot-") as tmp:
        sim_cfg, gateway_cfg = configs(Path(tmp))
        sim = Proc("sim", compgw("sim", sim_cfg))
        gw = pump = None
        try:
            ports = {"sim_tcp": int(sim.wait_for(r"modbus tcp on 127\.0\.0\.1:(\d+)")[1]),
                     "sim_rot": int(sim.wait_for(r"rtu over tcp on 127\.0\.0\.1:(\d+)")[1])}
            gw = Proc("gateway", compgw("run", gateway_cfg(ports["sim_tcp"], ports["sim_rot"])))
            ports["gw"] = int(gw.wait_for(r"listening on 127\.0\.0\.1:(\d+)")[1])
            socat = shutil.which("socat")
            if socat:  # one connection, served by the listening process itself (no fork)
                pump = Proc("socat", [socat, "-d", "-d", "TCP-LISTEN:0,bind=127.0.0.1,reuseaddr",
                                      f"TCP:127.0.0.1:{ports['sim_rot']},nodelay"])
                ports["socat"] = int(pump.wait_for(r"listening on .*:(\d+)")[1])
            asyncio.run(asyncio.wait_for(bench(args, sim, gw, ports, pump),
                                         args.time_cap * 4 * 8 + 60))
        finally:
            for proc in (pump, gw, sim):
                if proc is not None:
                    proc.stop()
    return 0


if __name__ == "__main__":
    sys.exit(main())
