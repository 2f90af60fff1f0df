"""What every instrument kind shares: channels, units, the stable wait, retries, errors.

Calibration asks ``await instrument.read_mm(axes, near_mm)`` at a stop and gets each axis's
reading in mm (degrees for an angle); it never knows the kind. A kind implements
:meth:`Instrument._sample` (one reading of some channels, in its own unit, with its stable
flag) and, where it holds a connection, :meth:`Instrument._open` and
:meth:`Instrument._close`. The base turns axes into the instrument's channels, asks again
until the reading is stable, retries a transient failure, converts units, and words every
failure as one line naming the instrument.
"""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

log = logging.getLogger(__name__)

#: unit -> mm (lengths) or degrees (angles) per unit
UNITS: dict[str, float] = {
    "mm": 1.0, "um": 1e-3, "µm": 1e-3, "nm": 1e-6, "m": 1e3, "in": 25.4,
    "deg": 1.0, "mdeg": 1e-3, "udeg": 1e-6, "µdeg": 1e-6, "arcsec": 1.0 / 3600.0,
}
LENGTH_UNITS = frozenset({"mm", "um", "µm", "nm", "m", "in"})
ANGLE_UNITS = frozenset({"deg", "mdeg", "udeg", "µdeg", "arcsec"})


def to_mm(value: float, unit: str) -> float:
    """``value`` in ``unit`` as mm (a length) or degrees (an angle)."""
    return value * UNITS[unit]


def unit_of(text: str, what: str) -> str:
    """A unit name checked against :data:`UNITS`; ValueError naming ``what`` if unknown."""
    if text not in UNITS:
        raise ValueError(f"{what}: unit {text!r} is not one of {', '.join(UNITS)}")
    return text


class InstrumentError(RuntimeError):
    """An instrument did not give a reading; the message is one line naming it."""


class TransientError(InstrumentError):
    """A failure worth one more try (a dropped connection, a timeout)."""


@dataclass(frozen=True)
class Sample:
    """One reading of the channels asked, in the instrument's ``unit``, and whether the
    instrument calls it stable (its "capture when stable")."""

    values: tuple[float, ...]
    unit: str
    stable: bool = True


class Instrument:
    """Base of every kind (see the module docstring)."""

    #: the kind's name in messages and in the option syntax (``modbus``, ``bridge``, ...)
    kind = "instrument"

    def __init__(self, role: str, where: str, channels: Mapping[str, str] | None = None, *,
                 wait_stable: bool = True, stable_timeout_s: float = 30.0,
                 poll_s: float = 0.002, retries: int = 1) -> None:  # fmt: skip
        #: e.g. "laser (bridge 127.0.0.1:5001)": every message starts with it
        self.name = f"{role} ({self.kind} {where})"
        self.channels = dict(channels or {})
        self.wait_stable = wait_stable
        self.stable_timeout_s = stable_timeout_s
        self.poll_s = poll_s
        self.retries = retries
        self._open_done = False

    def channel(self, axis: str) -> str:
        """The instrument's channel for ``axis`` (the axis's own name unless mapped)."""
        return self.channels.get(axis, axis)

    async def open(self) -> None:
        if not self._open_done:
            await self._open()
            self._open_done = True

    async def close(self) -> None:
        if self._open_done:
            self._open_done = False
            await self._close()

    async def read_mm(self, axes: Sequence[str],
                      near_mm: Mapping[str, float] | None = None) -> dict[str, float]:
        """Each axis's reading in mm (degrees for angles), once stable. ``near_mm``: where
        the axes were sent (a kind may show it or check a reading against it)."""
        await self.open()
        channels = [self.channel(a) for a in axes]
        loop = asyncio.get_running_loop()
        deadline = loop.time() + self.stable_timeout_s
        failures = 0
        while True:
            try:
                sample = await self._sample(channels, axes, near_mm or {})
            except TransientError as exc:
                failures += 1
                if failures > self.retries:
                    raise InstrumentError(f"{self.name}: {exc}") from None
                log.warning("%s: %s; trying again", self.name, exc)
                await self._recover()
                continue
            except InstrumentError as exc:
                raise InstrumentError(f"{self.name}: {exc}") from None
            if len(sample.values) != len(channels):
                raise InstrumentError(f"{self.name}: {len(sample.values)} values for the "
                                      f"{len(channels)} channels {', '.join(channels)}")
            if sample.stable or not self.wait_stable:
                return {a: to_mm(v, sample.unit) for a, v in zip(axes, sample.values,
                                                                  strict=True)}
            if loop.time() > deadline:
                raise InstrumentError(f"{self.name}: {', '.join(channels)} not stable after "
                                      f"{self.stable_timeout_s:g} s (the axis still moving or "
                                      "ringing?)")
            await asyncio.sleep(self.poll_s)

    # -- the hooks a kind fills ---------------------------------------------------------------
    async def _open(self) -> None:
        """Connect (nothing by default)."""

    async def _close(self) -> None:
        """Disconnect (nothing by default)."""

    async def _recover(self) -> None:
        """After a transient failure, before the next try: reconnect by default."""
        await self._close()
        await self._open()

    async def _sample(self, channels: list[str], axes: Sequence[str],
                      near_mm: Mapping[str, float]) -> Sample:
        """One reading of ``channels`` (for ``axes``); raise :class:`InstrumentError`
        (:class:`TransientError` for a failure worth another try)."""
        raise NotImplementedError
