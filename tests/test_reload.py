"""SIGHUP reload of `compgw run` as a process: a valid reload changes the tables between
two moves, an invalid one is refused with a log line and the old tables stay; axis state
(shadow target, direction) survives; no per-transaction log lines at INFO."""

from __future__ import annotations

import signal
from pathlib import Path

from pymodbus.client import ModbusTcpClient

from gateway.app import load
from gateway.compensation import AxisInput
from gateway.frames import pack_int32, unpack_int32
from tests.gateway_rig import TARGET, TRIGGER
from tests.test_service_helpers import sim_and_gateway

PITCH_A = "position_mm,error_um\n0,0\n200,12\n400,20\n600,8\n800,-15\n"
PITCH_B = "position_mm,error_um\n0,0\n200,-30\n400,-40\n600,-10\n800,5\n"


def move(master: ModbusTcpClient, unit: int, pulses: int) -> None:
    assert not master.write_registers(TARGET, list(pack_int32(pulses)), device_id=unit).isError()
    assert not master.write_register(TRIGGER, 0x10, device_id=unit).isError()


def read32(client: ModbusTcpClient, unit: int, address: int) -> int:
    rr = client.read_holding_registers(address, count=2, device_id=unit)
    assert not rr.isError(), rr
    return unpack_int32(rr.registers, "hi_lo")


def expected(path: Path, axis: str, nominal: int, direction: int) -> int:
    _, chain = load(path)
    return chain.command_pulses(axis, {axis: AxisInput(nominal, direction)})


def reload(gw, pattern: str) -> None:
    mark = gw.mark()
    gw.signal(signal.SIGHUP)
    gw.wait_line(pattern, start=mark)


def test_sighup_reload_valid_then_invalid(tmp_path: Path):
    (tmp_path / "x.csv").write_text(PITCH_A)

    def edit(data):
        data["axes"]["X"]["compensation"]["pitch"] = "x.csv"
        data["axes"]["Y"]["compensation"]["backlash_mm"] = 0.01

    with sim_and_gateway(tmp_path, edit) as r:
        gw, path = r["gw"], r["path"]
        master = ModbusTcpClient("127.0.0.1", port=r["port"], timeout=3, retries=0)
        direct = ModbusTcpClient("127.0.0.1", port=r["sim_port"], timeout=3, retries=0)
        assert master.connect() and direct.connect()
        try:
            move(master, 1, 300_000)
            first = read32(direct, 1, TARGET)
            assert first == expected(path, "X", 300_000, 1) != 300_000
            move(master, 1, 100_000)
            move(master, 2, 100_000)
            move(master, 2, 50_000)  # Y now moving −
            assert read32(direct, 2, TARGET) == 49_995

            quiet = gw.mark()
            for _ in range(50):  # no per-transaction line at INFO
                assert not master.read_holding_registers(0x6200, count=2,
                                                         device_id=1).isError()
            assert gw.mark() == quiet, gw.lines[quiet:]

            # valid reload: another table and another backlash
            (tmp_path / "x.csv").write_text(PITCH_B)
            text = path.read_text().replace("backlash_mm: 0.01", "backlash_mm: 0.02")
            path.write_text(text)
            reload(gw, r"INFO gateway\.app: reloaded ")
            assert read32(master, 1, TARGET) == 100_000  # the shadow survived
            move(master, 1, 300_000)
            second = read32(direct, 1, TARGET)
            assert second == expected(path, "X", 300_000, 1)
            assert abs(second - first) > 40  # +16 µm before, −35 µm now at 300 mm
            move(master, 2, 50_000)  # same target: the direction stays − (state survived)
            assert read32(direct, 2, TARGET) == 49_990

            # invalid reload: a broken table → refused, logged, the valid one stays
            (tmp_path / "x.csv").write_text("position_mm,error_um\n0,zero\n")
            reload(gw, r"ERROR gateway\.app: reload refused, old config kept: .*x\.csv")
            move(master, 1, 100_000)
            move(master, 1, 300_000)
            assert read32(direct, 1, TARGET) == second
            # a section that needs a restart is refused the same way
            (tmp_path / "x.csv").write_text(PITCH_B)
            path.write_text(text.replace("timeout_s: 0.2", "timeout_s: 0.3"))
            reload(gw, r"reload refused, old config kept: buses cannot change on reload")
            assert gw.popen.poll() is None
        finally:
            master.close()
            direct.close()
        assert gw.stop() == 0
