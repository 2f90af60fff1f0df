"""Fuzzing the running daemon: more than 10,000 random and mutated frames on Modbus TCP and
as many on RTU (hypothesis, derandomized, bounded in examples and time); after each batch
and at the end the daemon still answers valid requests correctly, and never dies."""

from __future__ import annotations

import contextlib
import os
import select
import socket
import struct
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from gateway.modbus.frames import rtu_encode
from tests.gateway_rig import serial
from tests.helpers_modbus import PtyPair
from tests.test_service_helpers import (
    gateway_config,
    mbap,
    read_pdu,
    recv_mbap,
    rtu_drain,
    rtu_read_reply,
    start_gateway,
    start_sim,
)

BATCH = 250
EXAMPLES = 42  # 42 × 250 = 10,500 frames per transport
FUZZ_SETTINGS = settings(max_examples=EXAMPLES, derandomize=True, deadline=None,
                         database=None, print_blob=True,
                         suppress_health_check=list(HealthCheck))

PROBE_PDU = read_pdu(4, 0, 2)  # status unit: map version, N axes
PROBE_REPLY = b"\x04\x04\x00\x04\x00\x02"  # map version 4, 2 axes
SEEDS = [
    read_pdu(3, 0x6200, 4), read_pdu(3, 0x6201, 2), read_pdu(4, 0x602A, 2),
    read_pdu(3, 0x602A, 2), read_pdu(1, 0, 8), read_pdu(2, 0, 8),
    struct.pack(">BHH", 6, 0x6203, 50), struct.pack(">BHH", 6, 0x6201, 1),
    struct.pack(">BHHB2H", 0x10, 0x6201, 2, 4, 0, 5000),
    struct.pack(">BHHB3H", 0x10, 0x6200, 3, 6, 1, 0, 7000),
    struct.pack(">BHH", 5, 0, 0xFF00), struct.pack(">BHHBB", 0x0F, 0, 8, 1, 0x55),
    struct.pack(">BHHHHB2H", 0x17, 0x6200, 4, 0x6203, 2, 4, 1, 2),
    struct.pack(">BHHH", 0x16, 0x6203, 0xFFFF, 0), b"\x08\x00\x00\x12\x34", b"\x2b\x0e\x01\x00",
    b"\x11", b"\x07", PROBE_PDU,
]
UNITS = [1, 2, 20, 247, 0, 99, 250]


@st.composite
def pdus(draw) -> bytes:
    """A PDU: random bytes, or a valid request mutated (bytes flipped, cut, extended)."""
    if draw(st.integers(0, 3)) == 0:
        return draw(st.binary(min_size=1, max_size=40))
    pdu = bytearray(draw(st.sampled_from(SEEDS)))
    for _ in range(draw(st.integers(0, 3))):
        op = draw(st.integers(0, 3))
        if op == 0:
            pdu[draw(st.integers(0, len(pdu) - 1))] = draw(st.integers(0, 255))
        elif op == 1 and len(pdu) > 1:
            del pdu[draw(st.integers(1, len(pdu) - 1)):]
        elif op == 2:
            pdu += draw(st.binary(max_size=12))
        else:  # a count or address at its limits
            if len(pdu) >= 5:
                at = draw(st.sampled_from([1, 3]))
                pdu[at:at + 2] = draw(st.sampled_from([0, 1, 125, 126, 2000, 0xFFFF])).to_bytes(
                    2, "big")
    return bytes(pdu[:253])


units = st.one_of(st.sampled_from(UNITS), st.integers(0, 255))
tcp_frames = st.tuples(units, pdus(), st.integers(0, 39))  # header broken when the int is 0
rtu_frames = st.tuples(units, pdus(), st.integers(0, 9))  # CRC broken when 0, cut when 1


@pytest.fixture(scope="module")
def daemon(tmp_path_factory) -> Iterator[dict]:
    tmp_path: Path = tmp_path_factory.mktemp("fuzz")
    pair = PtyPair()
    sim, sim_port = start_sim(tmp_path)
    data = gateway_config(sim_port)
    data["upstream"]["rtu"] = serial(pair.path)
    data["upstream"]["tcp"]["max_connections"] = 64
    gw, port = start_gateway(tmp_path, data)
    try:
        yield {"gw": gw, "port": port, "pty": pair}
    finally:
        assert gw.stop() == 0
        sim.stop()
        pair.close()


def tcp_probe(sock: socket.socket, buf: bytearray, timeout_s: float = 3.0) -> bool:
    """Send the probe (tid 0xFFFF) and read replies until its answer; False on EOF/timeout."""
    sock.settimeout(timeout_s)
    try:
        sock.sendall(mbap(0xFFFF, 247, PROBE_PDU))
        while True:
            got = recv_mbap(sock, buf)
            if got is None:
                return False
            tid, unit, pdu = got
            if tid == 0xFFFF:
                assert (unit, pdu) == (247, PROBE_REPLY), (unit, pdu.hex())
                return True
    except (TimeoutError, ConnectionError):
        return False


def test_fuzz_tcp(daemon):
    port, gw = daemon["port"], daemon["gw"]
    sent = [0]
    t0 = time.monotonic()

    @FUZZ_SETTINGS
    @given(st.lists(tcp_frames, min_size=BATCH, max_size=BATCH))
    def batch(frames):
        stream = bytearray()
        for i, (unit, pdu, header) in enumerate(frames):
            frame = bytearray(mbap(i, unit, pdu))
            if header == 0:  # a broken header: protocol id or length
                frame[2 + (i % 2) * 2] ^= 0x5A
            stream += frame
        with socket.create_connection(("127.0.0.1", port), timeout=5) as sock:
            # write and read together: the replies of 250 requests fill the buffers
            sock.setblocking(False)
            view = memoryview(bytes(stream))
            while view:
                _, writable, _ = select.select([sock], [sock], [], 5)
                with contextlib.suppress(BlockingIOError):
                    sock.recv(1 << 20)
                if writable:
                    try:
                        view = view[sock.send(view[:4096]):]
                    except (BlockingIOError, ConnectionError):
                        break
            sent[0] += len(frames)
            ok = tcp_probe(sock, bytearray())
        if not ok:  # the gateway closed that connection (broken header): a new one works
            with socket.create_connection(("127.0.0.1", port), timeout=5) as sock:
                assert tcp_probe(sock, bytearray()), gw.text()[-2000:]
        assert gw.popen.poll() is None

    batch()
    assert sent[0] >= 10_000
    assert time.monotonic() - t0 < 60
    with socket.create_connection(("127.0.0.1", port), timeout=5) as sock:  # drive path too
        sock.sendall(mbap(1, 1, read_pdu(3, 0x6200, 2)))
        reply = recv_mbap(sock, bytearray())
        assert reply is not None and reply[2][:2] == b"\x03\x04", reply
        assert tcp_probe(sock, bytearray())
    assert "Traceback" not in gw.text()


def rtu_probe(fd: int) -> bool:
    """Send the probe until answered; late replies to fuzzed requests (a drive that timed
    out answers 0x0B after the bus timeout) are skipped."""
    for _ in range(4):
        rtu_drain(fd, 0.03)
        os.write(fd, rtu_encode(247, PROBE_PDU))
        deadline = time.monotonic() + 1.0
        while time.monotonic() < deadline:
            reply = rtu_read_reply(fd, max(0.0, deadline - time.monotonic()))
            if reply is None:
                break
            if reply == rtu_encode(247, PROBE_REPLY):  # others: late replies to fuzz
                return True
    return False


def test_fuzz_rtu(daemon):
    fd, gw = daemon["pty"].master, daemon["gw"]
    sent = [0]
    t0 = time.monotonic()

    @FUZZ_SETTINGS
    @given(st.lists(rtu_frames, min_size=BATCH, max_size=BATCH))
    def batch(frames):
        for unit, pdu, mode in frames:
            frame = bytearray(rtu_encode(unit, pdu))
            if mode == 0:
                frame[-1] ^= 0xA5
            elif mode == 1:
                del frame[len(frame) // 2:]
            view = memoryview(bytes(frame))
            while view:
                try:
                    view = view[os.write(fd, view):]
                except BlockingIOError:
                    select.select([fd], [fd], [], 1.0)
                with contextlib.suppress(BlockingIOError, OSError):
                    os.read(fd, 65536)  # replies: read and drop
            sent[0] += 1
        assert rtu_probe(fd), gw.text()[-2000:]
        assert gw.popen.poll() is None

    batch()
    assert sent[0] >= 10_000
    assert time.monotonic() - t0 < 60
    rtu_drain(fd, 0.03)
    os.write(fd, rtu_encode(1, read_pdu(3, 0x6200, 2)))
    reply = rtu_read_reply(fd, 2.0)
    assert reply is not None and reply[:3] == b"\x01\x03\x04", reply
    assert "Traceback" not in gw.text()
