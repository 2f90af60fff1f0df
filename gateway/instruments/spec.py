"""One option syntax for every instrument: ``KIND:ARGS`` (``--laser``, ``--angle``,
``--xy-device``, ``--delta-a``).

========================================  =====================================================
``HOST:PORT:UNIT[:ADDRESS]``              Modbus TCP in compgw's register layout (as before)
``modbus:HOST:PORT:UNIT[:ADDRESS]``       the same, the kind said
``bridge:tcp:HOST:PORT``                  a bridge listening on TCP (docs/instruments-bridge.md)
``bridge:cmd:COMMAND``                    a bridge run as a child process (the rest is the
                                          command line, colons and all)
``recording:DIR[:UNIT[:-1]]``             the laser software records continuously; compgw waits
                                          for each step's recording in ``DIR`` (samples in
                                          ``UNIT``, µm by default; ``-1``: it counts the other
                                          way)
``capture:MAPPING.yaml:DIR``              the software captures a reading per stop and exports
                                          them; the mapping file says the layout
``manual[:UNIT][:deviation]``             a gauge read by eye, typed at the prompt (a position
                                          in ``UNIT``, mm by default; ``deviation``: the
                                          gauge's deviation from the target)
========================================  =====================================================
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from .base import unit_of

KINDS = ("modbus", "bridge", "recording", "capture", "manual")


@dataclass(frozen=True)
class InstrumentSpec:
    """What an instrument option said: the kind and its arguments."""

    kind: str
    text: str  # as given
    host: str = ""
    port: int = 0
    unit_id: int = 0
    address: int | None = None
    transport: str = ""  # bridge: "tcp" or "cmd"
    command: str = ""
    directory: Path | None = None
    mapping: Path | None = None
    unit: str = ""
    sign: int = 1
    deviation: bool = False

    @property
    def reads_later(self) -> bool:
        """Whether the readings come from a file after the moves (recording, capture)."""
        return self.kind in ("recording", "capture")


def parse_instrument(option: str, text: str) -> InstrumentSpec:
    """``text`` given as ``option``; ValueError naming both, with the rule, if malformed."""
    kind, _, rest = text.partition(":")
    if kind not in KINDS:  # today's HOST:PORT:UNIT
        return _modbus(option, text, text)
    try:
        if kind == "modbus":
            return _modbus(option, text, rest)
        if kind == "bridge":
            transport, _, where = rest.partition(":")
            if transport == "tcp":
                host, _, port = where.rpartition(":")
                if not host or not port.isdigit() or not 0 < int(port) < 65536:
                    raise ValueError("give bridge:tcp:HOST:PORT")
                return InstrumentSpec("bridge", text, host=host, port=int(port),
                                      transport="tcp")  # fmt: skip
            if transport == "cmd" and where.strip():
                return InstrumentSpec("bridge", text, transport="cmd", command=where)
            raise ValueError("give bridge:tcp:HOST:PORT or bridge:cmd:COMMAND")
        if kind == "recording":
            parts = rest.split(":")
            if not parts[0]:
                raise ValueError("give recording:DIR[:UNIT[:-1]]")
            unit = unit_of(parts[1], "recording") if len(parts) > 1 and parts[1] else "um"
            sign = _sign(parts[2]) if len(parts) > 2 else 1
            if len(parts) > 3:
                raise ValueError("give recording:DIR[:UNIT[:-1]]")
            return InstrumentSpec("recording", text, directory=Path(parts[0]), unit=unit,
                                  sign=sign)  # fmt: skip
        if kind == "capture":
            mapping, _, directory = rest.partition(":")
            if not mapping or not directory:
                raise ValueError("give capture:MAPPING.yaml:DIR")
            return InstrumentSpec("capture", text, mapping=Path(mapping),
                                  directory=Path(directory))  # fmt: skip
        parts = [p for p in rest.split(":") if p]  # manual
        deviation = "deviation" in parts
        units = [p for p in parts if p != "deviation"]
        if len(units) > 1:
            raise ValueError("give manual[:UNIT][:deviation]")
        unit = unit_of(units[0], "manual") if units else ("um" if deviation else "mm")
        return InstrumentSpec("manual", text, unit=unit, deviation=deviation)
    except ValueError as exc:
        raise ValueError(f"{option} {text!r}: {exc}") from None


def _sign(text: str) -> int:
    if text not in ("1", "+1", "-1"):
        raise ValueError(f"sign {text!r} is not 1 or -1")
    return -1 if text == "-1" else 1


def _modbus(option: str, text: str, rest: str) -> InstrumentSpec:
    parts = rest.split(":")
    if len(parts) < 3 or not parts[0]:
        raise ValueError(f"{option} {text!r}: give HOST:PORT:UNIT (the instrument's unit "
                         "id), or KIND:... with KIND one of " + ", ".join(KINDS))
    try:
        numbers = [int(p, 0) for p in parts[1:]]
    except ValueError:
        raise ValueError(f"{option} {text!r}: port, unit and address must be integers") \
            from None  # fmt: skip
    if len(numbers) > 3 or not (0 < numbers[0] < 65536 and 0 <= numbers[1] <= 247):
        raise ValueError(f"{option} {text!r}: give HOST:PORT:UNIT[:ADDRESS], port 1..65535, "
                         "unit 0..247")
    return InstrumentSpec("modbus", text, host=parts[0], port=numbers[0], unit_id=numbers[1],
                          address=numbers[2] if len(numbers) > 2 else None)
