"""Modbus clients toward the drives: one :class:`Bus` per RS-485 line or TCP drive endpoint.

The import path of the downstream buses, split by concern so that no module grows past the
project's size rule (this one was 778 lines):

- :mod:`gateway.modbus.bus`: the :class:`Bus` interface (fair queue, retry/timeout loop,
  reply checks, transport hooks), its errors (:class:`DriveTimeout` → 0x0B upstream,
  :class:`BusUnavailable` → 0x0A), :data:`Done` and :data:`current_caller`;
- :mod:`gateway.modbus.tcp_bus`: :class:`TcpBus`, Modbus TCP to a drive or converter;
- :mod:`gateway.modbus.rtu_bus`: :class:`RtuBus`, Modbus RTU on a serial line.

Everything is re-exported here, so ``from gateway.modbus.downstream import ...`` keeps
working. The transports import :mod:`gateway.modbus.bus`, never this module (no cycle).
"""

from __future__ import annotations

from .bus import (
    Bus,
    BusCounters,
    BusError,
    BusUnavailable,
    Done,
    DriveTimeout,
    FairQueue,
    current_caller,
)
from .rtu_bus import RtuBus
from .tcp_bus import TcpBus

__all__ = [
    "Bus",
    "BusCounters",
    "BusError",
    "BusUnavailable",
    "Done",
    "DriveTimeout",
    "FairQueue",
    "RtuBus",
    "TcpBus",
    "current_caller",
]
