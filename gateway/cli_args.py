"""compgw's command-line parsing helpers (argparse only: every command imports them, the
daemon's start included)."""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable
from typing import Any


class Parser(argparse.ArgumentParser):
    """compgw's argument parser: a command line it does not understand is one line naming
    the option (not the usage text before it), exit 2."""

    def error(self, message: str) -> Any:  # type: ignore[override]
        self.exit(2, f"{self.prog}: {message} (see {self.prog} --help)\n")


def above(least: float, what: str, kind: type = float,
          most: float | None = None) -> Callable[[str], Any]:  # fmt: skip
    """An argparse type: a finite number above ``least`` (and at most ``most``; ``what``
    says its unit)."""

    def parse(text: str) -> Any:
        try:
            value = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not a number ({what})") from None
        if not (math.isfinite(value) and value > least):
            raise argparse.ArgumentTypeError(f"{text} must be above {least:g} ({what})")
        if most is not None and value > most:
            raise argparse.ArgumentTypeError(f"{text} must be at most {most:g} ({what})")
        return value

    return parse
