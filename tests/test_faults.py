"""Faults against the real daemon (`compgw run`) and the sim (`compgw sim`), as processes:
a drive killed and restarted, a silent drive, RTU garbage and fragments upstream, a dead
thermal sensor, and 8 pipelining masters × 2,000 requests with no lost or mixed reply."""

from __future__ import annotations

import os
import random
import socket
import threading
import time
from pathlib import Path

from pymodbus.client import ModbusTcpClient

from gateway.modbus.frames import pack_int32, unpack_int32
from tests.gateway_rig import TARGET, TRIGGER, serial
from tests.helpers_modbus import PtyPair
from tests.test_service_helpers import (
    gateway_config,
    mbap,
    read_pdu,
    recv_mbap,
    rtu,
    rtu_drain,
    rtu_read_reply,
    sim_and_gateway,
    start_gateway,
    start_sim,
    write_fault,
)


def exception_or_ok(master: ModbusTcpClient, unit: int = 1) -> tuple[int, float]:
    """(exception code or 0, seconds) of one read through the gateway."""
    t0 = time.monotonic()
    rr = master.read_holding_registers(0x6200, count=1, device_id=unit)
    return (rr.exception_code if rr.isError() else 0), time.monotonic() - t0


def test_drive_killed_and_restarted_recovers_without_restart(tmp_path: Path):
    sim, sim_port = start_sim(tmp_path)
    gw = None
    try:
        data = gateway_config(sim_port)
        gw, port = start_gateway(tmp_path, data)
        master = ModbusTcpClient("127.0.0.1", port=port, timeout=3, retries=0)
        assert master.connect()
        try:
            assert exception_or_ok(master)[0] == 0
            # a silent drive: 0x0B after the bus timeout (0.2 s), never a hang
            write_fault(sim_port, 1, mode=1)
            code, took = exception_or_ok(master)
            assert code == 0x0B and took < 1.5
            write_fault(sim_port, 1, mode=0)
            assert exception_or_ok(master)[0] == 0
            # the drive side killed: 0x0A (connection down) or 0x0B, each answered quickly
            sim.kill()
            codes = set()
            for _ in range(5):
                code, took = exception_or_ok(master)
                codes.add(code)
                assert took < 1.5
            assert codes <= {0x0A, 0x0B} and codes, codes
            assert not master.read_input_registers(0, count=2, device_id=247).isError()
            sim, _ = start_sim(tmp_path, port=sim_port, name="sim2.yaml")
            deadline = time.monotonic() + 15  # reconnect backoff is at most 5 s
            while exception_or_ok(master)[0] != 0:
                assert time.monotonic() < deadline, "no recovery"
            assert gw.popen.poll() is None  # the same daemon, never restarted
            gw.wait_line(r"line1: open", start=1)  # reopened by the gateway
        finally:
            master.close()
    finally:
        if gw is not None:
            assert gw.stop() == 0
        sim.stop()


def test_rtu_garbage_and_fragments_upstream(tmp_path: Path):
    pair = PtyPair()
    sim, sim_port = start_sim(tmp_path)
    gw = None
    try:
        data = gateway_config(sim_port, upstream={"rtu": serial(pair.path)})
        gw, _ = start_gateway(tmp_path, data)
        fd = pair.master
        request = rtu(1, read_pdu(3, 0x6200, 2))

        def served() -> bool:
            for _ in range(3):  # the first may land in a buffer the server drops
                rtu_drain(fd)
                os.write(fd, request)
                reply = rtu_read_reply(fd, 1.0)
                if reply is not None:
                    assert reply[:3] == b"\x01\x03\x04", reply.hex()
                    return True
            return False

        assert served()
        rng = random.Random(6)
        for round_ in range(20):
            garbage = bytes(rng.randrange(256) for _ in range(rng.randrange(1, 300)))
            bad_crc = bytearray(request)
            bad_crc[-1] ^= 0xFF
            os.write(fd, garbage)
            os.write(fd, bytes(bad_crc))
            os.write(fd, request[: rng.randrange(1, len(request))])  # truncated
            assert served(), f"round {round_}"
        # a frame in fragments, byte by byte, is reassembled
        for byte in request:
            os.write(fd, bytes([byte]))
        reply = rtu_read_reply(fd, 2.0)
        assert reply is not None and reply[:3] == b"\x01\x03\x04"
        # a request for a unit that is not ours: silence (shared line)
        os.write(fd, rtu(99, read_pdu(3, 0, 1)))
        assert rtu_read_reply(fd, 0.3) is None
        assert served()
        assert gw.popen.poll() is None
    finally:
        if gw is not None:
            assert gw.stop() == 0
        sim.stop()
        pair.close()


def status_registers(master: ModbusTcpClient) -> list[int]:
    rr = master.read_input_registers(0, count=120, device_id=247)
    assert not rr.isError(), rr
    return rr.registers


def wait_status(master: ModbusTcpClient, check, timeout_s: float = 10.0) -> list[int]:
    deadline = time.monotonic() + timeout_s
    while True:
        regs = status_registers(master)
        if check(regs):
            return regs
        assert time.monotonic() < deadline, regs[:4] + regs[80:84]


def test_dead_sensor_sets_the_alarm_bit_and_falls_back(tmp_path: Path):
    def edit(data):
        data["thermal_sources"] = {"x_ref": {
            "bus": "line1", "unit": 10, "scale_mm": 1e-6, "poll_s": 0.05, "noise_mm": 0.0015,
            "hold_s": 0.2, "fallback": "zero",
            "register": {"address": 1, "table": "input", "words": 2, "order": "hi_lo"}}}
        data["axes"]["X"]["compensation"]["thermal"] = {"source": "x_ref", "length_mm": 800}

    with sim_and_gateway(tmp_path, edit) as r:
        master = ModbusTcpClient("127.0.0.1", port=r["port"], timeout=3, retries=0)
        assert master.connect()
        try:
            regs = wait_status(master, lambda g: g[80] == 1)  # source ok
            assert regs[2] & 1 == 0
            write_fault(r["sim_port"], 10, mode=1)  # the sensor goes silent
            regs = wait_status(master, lambda g: g[80] == 3)  # alarm after hold_s
            assert regs[2] & 1 == 1  # gateway flag: thermal alarm
            assert regs[83] > 0  # failed reads counted
            assert unpack_int32(regs[81:83], "hi_lo") == 0  # fallback: zero
            assert unpack_int32(regs[19:21], "hi_lo") == 0  # the axis uses Δa = 0
            # moves still go through, corrected without thermal
            assert not master.write_registers(TARGET, list(pack_int32(200_000)),
                                              device_id=1).isError()
            assert not master.write_register(TRIGGER, 0x10, device_id=1).isError()
            assert r["gw"].popen.poll() is None
            r["gw"].wait_line(r"WARNING gateway\.sensors: .*x_ref.*|ERROR gateway\.sensors")
            write_fault(r["sim_port"], 10, mode=0)  # back: the alarm clears
            regs = wait_status(master, lambda g: g[80] == 1)
            assert regs[2] & 1 == 0
        finally:
            master.close()


def test_eight_pipelining_masters_lose_and_mix_nothing(tmp_path: Path):
    """8 connections × 2,000 requests, 8 in flight on each: every reply comes back once,
    with its own transaction id and the data of its own request."""
    masters, per_master, window = 8, 2000, 8

    def edit(data):
        data["upstream"]["tcp"]["max_connections"] = 16

    with sim_and_gateway(tmp_path, edit) as r:
        port = r["port"]
        # distinct words in 0x6200..0x6207 of both drives (0x6201/2 is the target pair)
        setup = ModbusTcpClient("127.0.0.1", port=port, timeout=3, retries=0)
        assert setup.connect()
        truth = {}
        for unit in (1, 2):
            words = [unit * 100, 0, 1000 * unit, *(unit * 100 + k for k in range(3, 8))]
            assert not setup.write_registers(0x6200, words, device_id=unit).isError()
            truth[unit] = setup.read_holding_registers(0x6200, count=8,
                                                       device_id=unit).registers
            assert len(truth[unit]) == 8
        setup.close()
        errors: list[str] = []
        counts = [0] * masters

        def expected(m: int, i: int) -> tuple[int, bytes, bytes]:
            unit = 1 + (m + i) % 2
            start, count = (i * 7 + m) % 5, 1 + (i + m) % 4
            if i % 10 == 9:  # some to the status unit: no bus involved
                pdu = read_pdu(4, 0, 2)
                return 247, pdu, b"\x04\x04\x00\x04\x00\x02"  # map version 4, 2 axes
            words = truth[unit][start : start + count]
            body = bytes([3, 2 * count]) + b"".join(w.to_bytes(2, "big") for w in words)
            return unit, read_pdu(3, 0x6200 + start, count), body

        def master(m: int) -> None:
            try:
                sock = socket.create_connection(("127.0.0.1", port), timeout=20)
                buf = bytearray()
                pending: dict[int, bytes] = {}
                sent = 0
                with sock:
                    while counts[m] < per_master:
                        while sent < per_master and len(pending) < window:
                            unit, pdu, body = expected(m, sent)
                            tid = (m * 4096 + sent) & 0xFFFF
                            pending[tid] = bytes([unit]) + body
                            sock.sendall(mbap(tid, unit, pdu))
                            sent += 1
                        got = recv_mbap(sock, buf)
                        if got is None:
                            errors.append(f"master {m}: closed after {counts[m]}")
                            return
                        tid, unit, pdu = got
                        want = pending.pop(tid, None)
                        if want != bytes([unit]) + pdu:
                            errors.append(f"master {m}: tid {tid} {pdu.hex()} != {want}")
                            return
                        counts[m] += 1
            except Exception as exc:  # reported below
                errors.append(f"master {m}: {exc!r}")

        t0 = time.monotonic()
        threads = [threading.Thread(target=master, args=(m,)) for m in range(masters)]
        for t in threads:
            t.start()
        for t in threads:
            t.join(timeout=120)
        took = time.monotonic() - t0
        assert not errors, errors[:5]
        assert counts == [per_master] * masters
        assert took < 60, took
        print(f"8 x 2000 pipelined requests in {took:.1f} s")
