"""From the command line's instrument options to instruments of the one interface.

``--laser``, ``--angle``, ``--xy-device`` and ``--delta-a`` take one syntax
(:mod:`gateway.instruments.spec`): the Modbus kind keeps its :class:`.machine.Endpoint`
(the shared links, the checks before anything moves); every other kind is kept as its
spec. :func:`open_device` gives calibration an :class:`~gateway.instruments.base.Instrument`
whatever the kind: above this module nothing knows which kind it reads.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

from ...instruments.base import Instrument
from ...instruments.bridge import CommandBridge, TcpBridge
from ...instruments.manual import Manual
from ...instruments.modbus import ModbusChannels, ModbusXY
from ...instruments.spec import InstrumentSpec, parse_instrument
from .machine import Endpoint, Links, MachineError

#: the roles of instruments and their options
OPTIONS = {"laser": "--laser", "angle": "--angle", "xy": "--xy-device", "delta_a": "--delta-a"}
#: the channel a Δa sensor of another kind than Modbus is asked for (a bridge's ``READ``)
DELTA_A_CHANNEL = "delta_a"
#: what each role is called in messages
ROLE_NAMES = {"laser": "laser", "angle": "angle instrument", "xy": "XY device",
              "delta_a": "Δa sensor"}


def device_option(option: str, text: str | None
                  ) -> tuple[Endpoint | None, InstrumentSpec | None]:  # fmt: skip
    """``text`` given as ``option``: (its Endpoint, None) for the Modbus kind, (None, its
    spec) for any other, (None, None) when not given; ValueError naming the option."""
    if text is None:
        return None, None
    spec = parse_instrument(option, text)
    if spec.kind != "modbus":
        return None, spec
    return Endpoint(spec.host, spec.port, spec.unit_id, spec.address), None


async def open_device(role: str, endpoint: Endpoint | None, spec: InstrumentSpec | None,
                      links: Links, *, order: Sequence[str], unit: str = "nm",
                      wait_stable: bool = True,
                      xy_axes: tuple[str, str] = ("X", "Y")) -> Instrument:  # fmt: skip
    """The instrument of ``role``: ``order`` its channels (a Modbus laser's register
    order), ``unit`` what a Modbus reading counts in (nm, or µdeg for angles)."""
    name = ROLE_NAMES.get(role, role)
    if spec is None:
        if endpoint is None:
            raise MachineError(f"no {name}: give {OPTIONS.get(role, role)}")
        link = await links.get(*endpoint.key)
        where = f"{endpoint.host}:{endpoint.port} unit {endpoint.unit}"
        if role == "xy":
            return ModbusXY(name, where, link.read, endpoint.unit, xy_axes,
                            wait_stable=wait_stable)  # fmt: skip
        return ModbusChannels(name, where, link.read, endpoint.unit, order, unit=unit,
                              wait_stable=wait_stable)  # fmt: skip
    if spec.kind == "bridge":
        if spec.transport == "tcp":
            return TcpBridge(name, spec.host, spec.port, wait_stable=wait_stable)
        return CommandBridge(name, spec.command, wait_stable=wait_stable)
    if spec.kind == "manual":
        return Manual(name, spec.unit, spec.deviation)
    raise MachineError(f"{OPTIONS.get(role, role)} {spec.text}: a {spec.kind} gives its "
                       "readings from a file after the moves; this step reads at each stop")


def given_kinds(**specs: InstrumentSpec | None) -> Mapping[str, InstrumentSpec]:
    """The non-Modbus specs among ``specs`` (role -> spec)."""
    return {role: spec for role, spec in specs.items() if spec is not None}
