"""Transport benchmark: latency and throughput through the pass-through forwarder
(TcpServer → TcpBus, one bus per drive) vs straight to the pymodbus drive, same run.

FC03×10 and FC16×2, 1 and 8 concurrent masters (master i talks to unit i, own connection).
Bounded: REQUESTS per master and TIME_LIMIT_S per case. Drive, forwarder and masters share
one process and event loop here, so ratios are indicative (bench/forwarding will use processes).
Run: .venv/bin/python bench/transport.py
"""

from __future__ import annotations

import argparse
import asyncio
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from gateway.modbus import frames as f
from gateway.modbus.downstream import TcpBus
from gateway.modbus.upstream import TcpServer
from tests.helpers_modbus import RawTcpMaster, tcp_drive

REQUESTS = 1000
TIME_LIMIT_S = 10.0
CASES = {"FC03x10": f.build_read_request(3, 0, 10),
         "FC16x2": f.build_write_multiple_registers(100, [1, 2])}


async def measure(port: int, pdu: bytes, masters: int) -> tuple[list[float], float]:
    latencies: list[float] = []
    deadline = time.monotonic() + TIME_LIMIT_S

    async def master(unit: int) -> None:
        m = await RawTcpMaster.connect(port)
        for _ in range(REQUESTS):
            if time.monotonic() > deadline:
                break
            t0 = time.perf_counter()
            await m.request(unit, pdu)
            latencies.append(time.perf_counter() - t0)
        await m.close()

    t0 = time.perf_counter()
    await asyncio.gather(*(master(u) for u in range(1, masters + 1)))
    return latencies, len(latencies) / (time.perf_counter() - t0)


def pct(values: list[float], q: float) -> float:
    return statistics.quantiles(values, n=100)[q - 1] * 1000 if len(values) > 1 else 0.0


async def main(requests: int) -> None:
    global REQUESTS
    REQUESTS = requests
    units = tuple(range(1, 9))
    print(f"{'case':<10}{'masters':>8}{'direct p50':>12}{'p99':>8}{'tx/s':>8}"
          f"{'fwd p50':>10}{'p99':>8}{'tx/s':>8}{'p50x':>7}{'p99x':>7}{'tx/s x':>8}")
    async with tcp_drive(units) as drive_port:
        buses = {u: TcpBus("127.0.0.1", drive_port, timeout_s=1.0, retries=0) for u in units}

        async def handler(unit_id: int, pdu: bytes) -> bytes | None:
            return await buses[unit_id].transact(unit_id, pdu)

        async with TcpServer(handler, "127.0.0.1", 0) as gw:
            for name, pdu in CASES.items():
                for masters in (1, 8):
                    d_lat, d_tps = await measure(drive_port, pdu, masters)
                    g_lat, g_tps = await measure(gw.port, pdu, masters)
                    d50, d99, g50, g99 = (pct(d_lat, 50), pct(d_lat, 99), pct(g_lat, 50),
                                          pct(g_lat, 99))
                    print(f"{name:<10}{masters:>8}{d50:>10.3f}ms{d99:>8.3f}{d_tps:>8.0f}"
                          f"{g50:>8.3f}ms{g99:>8.3f}{g_tps:>8.0f}{g50 / d50:>7.2f}"
                          f"{g99 / d99:>7.2f}{g_tps / d_tps:>8.2f}")
        for bus in buses.values():
            await bus.close()


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--requests", type=int, default=REQUESTS, help="per master and case")
    asyncio.run(main(parser.parse_args().requests))
