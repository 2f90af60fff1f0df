"""Manual entry: a gauge read by eye, typed at the terminal.

compgw moves, then asks for the reading of each axis at the stop. The technician types the
gauge's value: the position (``manual:mm``) or, reading a dial gauge against a step gauge,
the deviation from the target (``manual:deviation:um``). A value that is not a number is
asked again; one farther from the target than an error can be (``max_error_mm``) is asked
again unless typed twice; after each value compgw shows what it took and Enter accepts it,
``r`` reads the point again. A USB input tool that types the reading and Enter works as it
is. Ctrl-C stops the run; the same command carries on from the last point taken.
"""

from __future__ import annotations

import asyncio
import sys
from collections.abc import Callable, Mapping, Sequence
from typing import TextIO

from .base import Instrument, InstrumentError, Sample, to_mm

#: a reading farther than this from where the axis was sent is asked again (mm)
DEFAULT_MAX_ERROR_MM = 0.5


class Manual(Instrument):
    """The manual kind (see the module docstring)."""

    kind = "manual"

    def __init__(self, role: str, unit: str = "mm", deviation: bool = False, *,
                 max_error_mm: float = DEFAULT_MAX_ERROR_MM, stdin: TextIO | None = None,
                 say: Callable[[str], None] | None = None, **kw) -> None:  # type: ignore[no-untyped-def]  # fmt: skip
        what = f"deviation in {unit}" if deviation else f"position in {unit}"
        super().__init__(role, what, **kw)
        self.unit = unit
        self.deviation = deviation
        self.max_error_mm = max_error_mm
        self.stdin = stdin
        self.say = say or _prompt

    async def _line(self, prompt: str) -> str:
        self.say(prompt)
        stream = self.stdin or sys.stdin
        line = await asyncio.get_running_loop().run_in_executor(None, stream.readline)
        if not line:
            raise InstrumentError("no more input (end of file) at the prompt")
        return line.strip()

    async def _value(self, axis: str, near: float | None) -> float:
        """One axis's reading in mm, validated."""
        at = f" at {near:.4f} mm" if near is not None else ""
        asked = "deviation" if self.deviation else "reading"
        doubted: float | None = None
        while True:
            text = await self._line(f"{axis}{at}: the gauge's {asked} in {self.unit}? ")
            try:
                value = float(text.replace(",", "."))
            except ValueError:
                self.say(f"  {text!r} is not a number: type the {asked} in {self.unit} "
                         "(e.g. 12.5 or -0.8)\n")
                continue
            mm = to_mm(value, self.unit)
            position = (near or 0.0) + mm if self.deviation else mm
            off = abs(mm) if self.deviation else (abs(mm - near) if near is not None else 0.0)
            if off > self.max_error_mm and doubted != value:
                self.say(f"  {value:g} {self.unit} is {off:.3f} mm from the target, more than "
                         f"the {self.max_error_mm:g} mm an error can be: type it again to keep "
                         "it, or the right value\n")
                doubted = value
                continue
            shown = f"{position:.4f} mm" + (f" ({value:+g} {self.unit})" if self.deviation
                                            else "")  # fmt: skip
            again = await self._line(f"  {axis}: {shown}; Enter to take it, r to read again: ")
            if again.lower().startswith("r"):
                doubted = None
                continue
            return position

    async def _sample(self, channels: list[str], axes: Sequence[str],
                      near_mm: Mapping[str, float]) -> Sample:
        values = [await self._value(a, near_mm.get(a)) for a in axes]
        return Sample(tuple(values), "mm", True)


def _prompt(text: str) -> None:
    print(text, end="", flush=True)
