"""The Modbus kind: compgw's own register layout (the simulator's instruments).

- laser / angle instrument: channel k at input registers 2k, 2k+1 (int32, high word first,
  nm or µdeg), then per channel a stable flag at 2N + k (N channels);
- XY device: 0-1 X, 2-3 Y (int32 nm), stable flags 4 and 5.

The register reads are the caller's (``read``: unit, address, count, table → words), so
this kind holds no connection of its own: calibration passes its shared Modbus links.
"""

from __future__ import annotations

from collections.abc import Awaitable, Callable, Mapping, Sequence

from ..modbus.frames import unpack_int32
from .base import Instrument, InstrumentError, Sample

Read = Callable[[int, int, int, str], Awaitable[list[int]]]


class ModbusChannels(Instrument):
    """A laser (or angle instrument, ``unit="udeg"``): one int32 per channel and a stable
    flag per channel; ``order``: the channels in register order."""

    kind = "modbus"

    def __init__(self, role: str, where: str, read: Read, unit_id: int, order: Sequence[str],
                 *, unit: str = "nm", **kw) -> None:  # type: ignore[no-untyped-def]  # fmt: skip
        super().__init__(role, where, **kw)
        self.read = read
        self.unit_id = unit_id
        self.order = list(order)
        self.unit = unit

    async def _sample(self, channels: list[str], axes: Sequence[str],
                      near_mm: Mapping[str, float]) -> Sample:
        missing = [c for c in channels if c not in self.order]
        if missing:
            raise InstrumentError(f"no channel for {missing[0]} ({', '.join(self.order)})")
        n = len(self.order)
        count = 3 * n if self.wait_stable else 2 * n
        words = await self.read(self.unit_id, 0, count, "input")  # one read: value and flag
        index = [self.order.index(c) for c in channels]
        values = tuple(float(unpack_int32(words[2 * k : 2 * k + 2], "hi_lo")) for k in index)
        stable = not self.wait_stable or all(words[2 * n + k] == 1 for k in index)
        return Sample(values, self.unit, stable)


class ModbusXY(Instrument):
    """A 2-D device: X and Y of the plane (``order``: its two axes) and their flags."""

    kind = "modbus"

    def __init__(self, role: str, where: str, read: Read, unit_id: int,
                 order: tuple[str, str], **kw) -> None:  # type: ignore[no-untyped-def]  # fmt: skip
        super().__init__(role, where, **kw)
        self.read = read
        self.unit_id = unit_id
        self.order = order

    async def _sample(self, channels: list[str], axes: Sequence[str],
                      near_mm: Mapping[str, float]) -> Sample:
        missing = [c for c in channels if c not in self.order]
        if missing:
            raise InstrumentError(f"measures {', '.join(self.order)}, not {missing[0]}")
        words = await self.read(self.unit_id, 0, 6 if self.wait_stable else 4, "input")
        both = (float(unpack_int32(words[:2], "hi_lo")), float(unpack_int32(words[2:4],
                                                                             "hi_lo")))
        stable = not self.wait_stable or (words[4] == 1 and words[5] == 1)
        return Sample(tuple(both[self.order.index(c)] for c in channels), "nm", stable)
