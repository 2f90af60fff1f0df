"""An in-process rig for end-to-end tests: the example sim, the gateway, two masters.

``direct`` talks to the sim (what the drive really received, the truth instruments);
``master`` talks to the gateway (what an upper computer sees). Real sockets, port 0.
"""

from __future__ import annotations

import contextlib
import copy
from collections.abc import AsyncIterator
from pathlib import Path
from typing import Any

import yaml
from pymodbus.client import AsyncModbusSerialClient, AsyncModbusTcpClient

from gateway.app import GatewayApp, load
from sim.config import RtuConfig
from sim.config import parse_config as parse_sim_config
from sim.server import SimServer
from tests.conftest import PtyPair
from tests.test_sim_support import example_dict

ROOT = Path(__file__).resolve().parent.parent
SIM_EXAMPLE = ROOT / "config" / "example-sim.yaml"

TARGET = 0x6201
TRIGGER = 0x6002
FEEDBACK = 0x602A
STATUS = 0x1003
SPEED = 0x6203


def axis_config(unit: int, travel: list[float], **compensation: Any) -> dict[str, Any]:
    """A gateway axis on the sim's default (Leadshine-like) registers."""
    return {
        "bus": "line1",
        "unit": unit,
        "pulse_mm": 0.001,
        "travel_mm": travel,
        "registers": {
            "target": {"address": TARGET, "order": "hi_lo"},
            "feedback": {"address": FEEDBACK},
            "status": {"address": STATUS, "homed_bit": 6},
            "trigger": {"address": TRIGGER, "value": 0x10},
        },
        "compensation": {"max_correction_mm": 0.2, **compensation},
    }


def base_config(sim_port: int) -> dict[str, Any]:
    return {
        "upstream": {"tcp": {"host": "127.0.0.1", "port": 0}},
        "buses": {
            "line1": {"tcp": {"host": "127.0.0.1", "port": sim_port}, "timeout_s": 0.2,
                      "retries": 0}
        },
        "axes": {"X": axis_config(1, [0, 800]), "Y": axis_config(2, [0, 600])},
        "passthrough": {20: {"bus": "line1", "unit": 20}},
    }


def serial(port: str) -> dict[str, Any]:
    """Serial settings for a pty end (parity N: on this kernel a pty accepts parity
    settings only once, and pymodbus sets them twice; a pty ignores them anyway)."""
    return {"port": port, "baudrate": 115200, "parity": "N", "stopbits": 1}


@contextlib.asynccontextmanager
async def rig(
    tmp_path: Path,
    edit=None,
    files: dict[str, str] | None = None,
    *,
    drives: str = "tcp",
    upstream: str = "tcp",
    sim_edit=None,
) -> AsyncIterator[dict[str, Any]]:
    """Start sim + gateway; ``edit(config_dict)`` customises the gateway config and
    ``sim_edit(sim_dict)`` the simulated machine.

    ``drives="rtu"`` puts the gateway's bus on a pty to the sim's RTU server;
    ``drives="rtu_over_tcp"`` on a TCP connection carrying RTU frames (a serial device
    server's transparent mode) to the sim's RTU-over-TCP server;
    ``upstream="rtu"`` makes ``master`` an RTU client on a pty to the gateway.
    ``direct`` is always TCP to the sim (the drive's truth, the instruments).
    """
    sim_data = example_dict()  # 1 µm pulses, as the rig's gateway axes (axis_config)
    if sim_edit is not None:
        sim_edit(sim_data)
    sim_cfg = parse_sim_config(sim_data, SIM_EXAMPLE.parent)
    ptys: list[PtyPair] = []
    drive_line = upstream_line = None
    if drives == "rtu":
        drive_line = PtyPair()
        ptys.append(drive_line)
        rtu = RtuConfig(**serial(drive_line.a))
        sim_cfg = sim_cfg.model_copy(
            update={"sim": sim_cfg.sim.model_copy(update={"rtu": rtu})}
        )
    if upstream == "rtu":
        upstream_line = PtyPair()
        ptys.append(upstream_line)
    try:
        rot_port = 0 if drives == "rtu_over_tcp" else None
        async with SimServer(sim_cfg, tcp_port=0, time_scale=0,
                             rtu_over_tcp_port=rot_port) as sim:
            data = base_config(sim.tcp_port)
            if rot_port is not None:
                data["buses"]["line1"] = {
                    "rtu_over_tcp": {"host": "127.0.0.1", "port": sim.rtu_over_tcp_port,
                                     "baudrate": 115200, "parity": "N"},
                    "timeout_s": 0.2, "retries": 0}
            if drive_line is not None:
                data["buses"]["line1"] = {"rtu": serial(drive_line.b), "timeout_s": 0.2,
                                          "retries": 0}
            if upstream_line is not None:
                data["upstream"] = {"rtu": serial(upstream_line.a)}
            if edit is not None:
                edit(data)
            for name, text in (files or {}).items():
                (tmp_path / name).parent.mkdir(parents=True, exist_ok=True)
                (tmp_path / name).write_text(text)
            path = tmp_path / "gw.yaml"
            path.write_text(yaml.safe_dump(copy.deepcopy(data)))
            config, chain = load(path)
            async with GatewayApp(config, chain, source=str(path)) as app:
                if upstream_line is not None:
                    master = AsyncModbusSerialClient(
                        upstream_line.b, baudrate=115200, parity="N", stopbits=1, timeout=2,
                        retries=0,
                    )
                else:
                    master = AsyncModbusTcpClient(
                        "127.0.0.1", port=app.tcp_port, timeout=2, retries=0
                    )
                direct = AsyncModbusTcpClient("127.0.0.1", port=sim.tcp_port, timeout=2, retries=0)
                assert await master.connect() and await direct.connect()
                try:
                    yield {"sim": sim, "app": app, "master": master, "direct": direct,
                           "chain": chain, "config_path": path, "drive_line": drive_line,
                           "upstream_line": upstream_line}
                finally:
                    master.close()
                    direct.close()
    finally:
        for pair in ptys:
            pair.close()
