"""The calibration subcommands of `compgw`: calibrate, fit, report, export.

`gateway.cli` calls :func:`add_parsers`; each command returns an exit code
(0 ok, 1 bad input, 2 usage, 3 runtime fault).
"""

from __future__ import annotations

import argparse
import sys


def _not_yet(name: str) -> int:
    print(f"compgw {name}: not implemented yet (tracked in issue 5)", file=sys.stderr)
    return 3


def add_parsers(sub: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    """Register the calibration subcommands on the `compgw` parser."""
    for name in ("calibrate", "fit", "report", "export"):
        p = sub.add_parser(name, help=f"calibration: {name}")
        p.set_defaults(func=lambda a, n=name: _not_yet(n))
