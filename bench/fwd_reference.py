"""bench/forwarding.py's reference forwarders: a minimal asyncio TCP proxy and a minimal
RTU relay between two ptys, no interception: the floor for what CPython costs on this
machine (``forwarding.py --proxy PORT`` / ``--relay UP DOWN``). Not the product."""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import os
import signal
import sys
import tty
from collections import deque

from fwd_load import RTU_UPSTREAM_OFFSET, UNITS, reply_length, rtu_frame

# -- a reference forwarder (a floor for what CPython asyncio costs; not the product) ----------


class _RefBus(asyncio.Protocol):
    """One downstream connection, one transaction in flight, FIFO; a timeout per request."""

    def __init__(self) -> None:
        self.transport: asyncio.Transport | None = None
        self.buf = bytearray()
        self.queue: deque = deque()  # (frame, upstream transport, upstream tid bytes)
        self.current: tuple | None = None
        self.timer: asyncio.TimerHandle | None = None
        self.tid = 0

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        self.transport = transport  # type: ignore[assignment]
        transport.get_extra_info("socket").setsockopt(6, 1, 1)

    def submit(self, item: tuple) -> None:
        self.queue.append(item)
        if self.current is None:
            self._next()

    def _next(self) -> None:
        if not self.queue:
            self.current = None
            return
        self.current = self.queue.popleft()
        self.tid = self.tid % 0xFFFF + 1
        assert self.transport is not None
        self.transport.write(self.tid.to_bytes(2, "big") + self.current[0][2:])
        self.timer = asyncio.get_running_loop().call_later(0.2, self._timeout)

    def _timeout(self) -> None:
        if self.current is not None:  # 0x0B
            frame, up, up_tid = self.current
            up.write(up_tid + b"\x00\x00\x00\x03" + frame[6:8] + bytes([frame[7] | 0x80, 11]))
        self._next()

    def data_received(self, data: bytes) -> None:
        self.buf += data
        while len(self.buf) >= 6:
            size = 6 + int.from_bytes(self.buf[4:6], "big")
            if len(self.buf) < size:
                return
            frame = bytes(self.buf[:size])
            del self.buf[:size]
            if self.current is None or int.from_bytes(frame[:2], "big") != self.tid:
                continue  # late reply: dropped
            assert self.timer is not None
            self.timer.cancel()
            _, up, up_tid = self.current
            up.write(up_tid + frame[2:])
            self._next()


class _RefUpstream(asyncio.Protocol):
    def __init__(self, buses: dict[int, _RefBus]) -> None:
        self.buses = buses
        self.buf = bytearray()
        self.transport: asyncio.Transport | None = None

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        self.transport = transport  # type: ignore[assignment]
        transport.get_extra_info("socket").setsockopt(6, 1, 1)

    def data_received(self, data: bytes) -> None:
        self.buf += data
        while len(self.buf) >= 6:
            size = 6 + int.from_bytes(self.buf[4:6], "big")
            if len(self.buf) < size:
                return
            frame = bytes(self.buf[:size])
            del self.buf[:size]
            self.buses[frame[6]].submit((frame, self.transport, frame[:2]))


async def reference_proxy(sim_port: int) -> None:
    loop = asyncio.get_running_loop()
    buses: dict[int, _RefBus] = {}
    for unit in UNITS:
        _, buses[unit] = await loop.create_connection(_RefBus, "127.0.0.1", sim_port)
    server = await loop.create_server(lambda: _RefUpstream(buses), "127.0.0.1", 0)
    print(f"reference proxy listening on 127.0.0.1:{server.sockets[0].getsockname()[1]}",
          flush=True)
    stop = asyncio.Event()
    loop.add_signal_handler(signal.SIGTERM, stop.set)
    await stop.wait()


class _RefRtuRelay:
    """RTU master line to RTU drive line, one frame at a time, by length (FC03/FC16 only),
    no CRC check, no timing rules (the bench's drives keep t3.5 themselves), no unit
    mapping but the offset: the floor for a CPython relay between two ptys."""

    def __init__(self, upstream: str, downstream: str) -> None:
        self.up = os.open(upstream, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
        self.down = os.open(downstream, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
        for fd in (self.up, self.down):
            tty.setraw(fd)
        self.up_buf, self.down_buf = bytearray(), bytearray()
        self.want = 0  # length of the reply awaited from the drive; 0: none
        loop = asyncio.get_running_loop()
        loop.add_reader(self.up, self._from_master)
        loop.add_reader(self.down, self._from_drive)

    def _from_master(self) -> None:
        with contextlib.suppress(BlockingIOError):
            self.up_buf += os.read(self.up, 4096)
        buf = self.up_buf
        if len(buf) < 7 or self.want:
            return
        size = 9 + buf[6] if buf[1] == 16 else 8
        if len(buf) < size:
            return
        unit = buf[0] - RTU_UPSTREAM_OFFSET
        pdu = bytes(buf[1:size - 2])
        del buf[:size]
        self.want = reply_length(pdu)
        os.write(self.down, rtu_frame(unit, pdu))

    def _from_drive(self) -> None:
        with contextlib.suppress(BlockingIOError):
            self.down_buf += os.read(self.down, 4096)
        if not self.want or len(self.down_buf) < self.want:
            return
        reply = self.down_buf[:self.want]
        del self.down_buf[:self.want]
        self.want = 0
        os.write(self.up, rtu_frame(reply[0] + RTU_UPSTREAM_OFFSET, bytes(reply[1:-2])))


async def reference_rtu_relay(upstream: str, downstream: str) -> None:
    _RefRtuRelay(upstream, downstream)
    print(f"reference relay on {upstream} -> {downstream}", flush=True)
    stop = asyncio.Event()
    asyncio.get_running_loop().add_signal_handler(signal.SIGTERM, stop.set)
    await stop.wait()


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description="bench/forwarding.py's CPython floors: a minimal "
                                 "TCP proxy to the sim, or a minimal RTU relay between ptys")
    ap.add_argument("--proxy", type=int, metavar="SIM_PORT", help="a TCP proxy to this port")
    ap.add_argument("--relay", nargs=2, metavar=("UP", "DOWN"), help="an RTU relay")
    a = ap.parse_args(argv)
    if a.proxy:
        asyncio.run(reference_proxy(a.proxy))
    elif a.relay:
        asyncio.run(reference_rtu_relay(*a.relay))
    else:
        ap.error("--proxy or --relay")
    return 0


if __name__ == "__main__":
    sys.exit(main())
