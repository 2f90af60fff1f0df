"""bench/forwarding.py's load generator: raw Modbus masters (MBAP over asyncio streams, RTU
frames on a pty fd), each request timed and its reply checked; one short-lived process per
measurement (``forwarding.py --load JSON``). No project imports: it stays lean."""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import os
import struct
import sys
import time
import tty
from dataclasses import dataclass

UNITS = tuple(range(1, 9))
RTU_UPSTREAM_OFFSET = 10  # gateway upstream unit of RTU axis k = 10 + k
TARGET = 250_000  # pulses (250 mm) written in the warm-up: the axes then have applied=True

# -- Modbus helpers (no project imports: the load generator stays lean) ---------------------


def _crc16(data: bytes) -> bytes:
    crc = 0xFFFF
    for byte in data:
        crc ^= byte
        for _ in range(8):
            crc = (crc >> 1) ^ 0xA001 if crc & 1 else crc >> 1
    return struct.pack("<H", crc)


def rtu_frame(unit: int, pdu: bytes) -> bytes:
    body = bytes([unit]) + pdu
    return body + _crc16(body)


def read_pdu(address: int, count: int) -> bytes:
    return struct.pack(">BHH", 3, address, count)


def write_pdu(address: int, values: list[int]) -> bytes:
    return struct.pack(f">BHHB{len(values)}H", 16, address, len(values), 2 * len(values),
                       *values)


def reply_length(pdu: bytes) -> int:
    """Length of the normal RTU reply frame to ``pdu`` (unit + PDU + CRC)."""
    if pdu[0] in (3, 4):
        return 5 + 2 * struct.unpack(">H", pdu[3:5])[0]
    return 8  # FC06/FC16 echo


@dataclass(frozen=True)
class Case:
    name: str
    pdu: bytes
    what: str
    extra: bool = False  # not one of the two cases: full run only


CASES = (
    Case("FC03x10@6200", read_pdu(0x6200, 10), "read 0x6200..09, target pair shadowed"),
    Case("FC16x2@6204", write_pdu(0x6204, [0x1234, 0x5678]), "write 0x6204/05, pass-through"),
    Case("FC03x2@602A", read_pdu(0x602A, 2), "feedback pair, inverse chain", extra=True),
    Case("FC16x2@6201", write_pdu(0x6201, [TARGET >> 16, TARGET & 0xFFFF]),
         "target write: status read + corrected FC16", extra=True),
)

# -- the load generator (runs in its own process: --load JSON) ------------------------------


async def _tcp_masters(spec: dict) -> dict:
    pdu = bytes.fromhex(spec["pdu"])
    n, warm = spec["requests"], spec["warmup"]
    units = spec["units"]
    ctx = None
    if spec.get("tls"):  # Modbus/TCP Security: the handshakes happen before the timed part
        import ssl

        ctx = ssl.create_default_context(cafile=spec["tls"]["ca"])
        ctx.load_cert_chain(spec["tls"]["cert"], spec["tls"]["key"])
    conns = [await asyncio.open_connection(spec["host"], spec["port"], ssl=ctx) for _ in units]
    for _, w in conns:
        w.get_extra_info("socket").setsockopt(6, 1, 1)  # TCP_NODELAY
    lat: list[float] = []
    errors = [0]
    start = asyncio.Event()
    deadline = [0.0]

    async def master(unit: int, reader: asyncio.StreamReader, writer: asyncio.StreamWriter,
                     ready: asyncio.Future) -> None:
        tid = 0
        perf = time.perf_counter
        for i in range(warm + n):
            if i == warm:
                ready.set_result(None)
                await start.wait()
            elif i > warm and time.monotonic() > deadline[0]:
                break
            tid = tid % 0xFFFF + 1
            t0 = perf()
            writer.write(struct.pack(">HHHB", tid, 0, len(pdu) + 1, unit) + pdu)
            head = await reader.readexactly(7)
            r_tid, _, length, _ = struct.unpack(">HHHB", head)
            body = await reader.readexactly(length - 1)
            if i >= warm:
                lat.append(perf() - t0)
            if r_tid != tid or body[0] != pdu[0]:
                errors[0] += 1

    loop = asyncio.get_running_loop()
    readies = [loop.create_future() for _ in units]
    tasks = [asyncio.create_task(master(u, r, w, f))
             for u, (r, w), f in zip(units, conns, readies)]
    await asyncio.gather(*readies)
    deadline[0] = time.monotonic() + spec["time_cap"]
    cpu0, t0 = time.process_time(), time.perf_counter()
    start.set()
    await asyncio.gather(*tasks)
    wall = time.perf_counter() - t0
    for _, w in conns:
        w.close()
    return {"lat": lat, "wall": wall, "errors": errors[0], "cpu": time.process_time() - cpu0}


class _RtuPort:
    """The master end of a pty, raw, read with loop.add_reader."""

    def __init__(self, path: str | None = None, fd: int | None = None) -> None:
        if fd is None:
            assert path is not None
            fd = os.open(path, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
            tty.setraw(fd)
        else:  # the terminal end of a pty, inherited from the orchestrator
            os.set_blocking(fd, False)
        self.fd = fd
        self.buf = bytearray()
        self.event = asyncio.Event()
        self.last_rx = 0.0
        asyncio.get_running_loop().add_reader(self.fd, self._readable)

    def _readable(self) -> None:
        with contextlib.suppress(BlockingIOError):
            self.buf += os.read(self.fd, 4096)
            self.last_rx = time.perf_counter()
            self.event.set()

    async def transact(self, frame: bytes, want: int, timeout_s: float = 1.0) -> bytes:
        self.buf.clear()
        os.write(self.fd, frame)
        end = time.perf_counter() + timeout_s
        while True:
            n = len(self.buf)
            if n >= 2 and self.buf[1] & 0x80 and n >= 5:
                return bytes(self.buf[:5])
            if n >= want:
                return bytes(self.buf[:want])
            self.event.clear()
            left = end - time.perf_counter()
            if left <= 0:
                return b""
            with contextlib.suppress(asyncio.TimeoutError):
                await asyncio.wait_for(self.event.wait(), left)

    def close(self) -> None:
        asyncio.get_running_loop().remove_reader(self.fd)
        os.close(self.fd)


async def _rtu_masters(spec: dict) -> dict:
    """Masters sharing one RTU line: each waits t3.5 after its own reply (think time),
    then queues for the line (lock), waits for t3.5 of line silence, sends, receives."""
    pdu = bytes.fromhex(spec["pdu"])
    n, warm, gap = spec["requests"], spec["warmup"], spec["gap_s"]
    want = reply_length(pdu)
    port = _RtuPort(spec.get("device"), spec.get("fd"))
    line = asyncio.Lock()
    lat: list[float] = []
    errors = [0]
    start = asyncio.Event()
    deadline = [0.0]

    async def quiet() -> None:
        # time.sleep, not asyncio.sleep: the loop's epoll timeout has 1 ms granularity and
        # would stretch 1.75 ms to 2+ ms. Blocking is harmless here: the line is held.
        wait = gap - (time.perf_counter() - port.last_rx)
        if wait > 0:
            time.sleep(wait)

    async def master(unit: int, ready: asyncio.Future) -> None:
        frame = rtu_frame(unit, pdu)
        perf = time.perf_counter
        for i in range(warm + n):
            if i == warm:
                ready.set_result(None)
                await start.wait()
            elif i > warm and time.monotonic() > deadline[0]:
                break
            if len(spec["units"]) == 1:
                await quiet()  # think time of a lone master: not in its latency
            t0 = perf()
            async with line:
                await quiet()
                reply = await port.transact(frame, want)
            if i >= warm:
                lat.append(perf() - t0)
            if len(reply) != want or reply[0] != unit or reply[1] != pdu[0] \
                    or _crc16(reply[:-2]) != reply[-2:]:
                errors[0] += 1
            await asyncio.sleep(0)  # let the other masters queue

    loop = asyncio.get_running_loop()
    readies = [loop.create_future() for _ in spec["units"]]
    tasks = [asyncio.create_task(master(u, f)) for u, f in zip(spec["units"], readies)]
    await asyncio.gather(*readies)
    deadline[0] = time.monotonic() + spec["time_cap"]
    cpu0, t0 = time.process_time(), time.perf_counter()
    start.set()
    await asyncio.gather(*tasks)
    wall = time.perf_counter() - t0
    port.close()
    return {"lat": lat, "wall": wall, "errors": errors[0], "cpu": time.process_time() - cpu0}


#: ``--pin``: the CPUs of the world (upper computer + drives: load generator and sims) and
#: of the gateway, as in a deployment where the gateway has its own box
PIN_WORLD, PIN_GATEWAY = {0}, {1}


def load_main(spec_json: str) -> int:
    spec = json.loads(spec_json)
    if spec.get("pin"):
        os.sched_setaffinity(0, PIN_WORLD)
    run = _rtu_masters if spec["kind"] == "rtu" else _tcp_masters
    result = asyncio.run(asyncio.wait_for(run(spec), spec["time_cap"] + 30))
    sys.stdout.write(json.dumps(result))
    return 0


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description="bench/forwarding.py's load generator: one "
                                 "measurement, its spec as JSON, the result as JSON on stdout")
    ap.add_argument("spec", help="the measurement (written by forwarding.py's run_load)")
    return load_main(ap.parse_args(argv).spec)


if __name__ == "__main__":
    sys.exit(main())
