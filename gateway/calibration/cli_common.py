"""What the calibration subcommands share: exit codes, the one-line error, the config.

:mod:`.commands` (calibrate, report, export) and :mod:`.commands_fit` (fit) both use these;
neither imports the other.
"""

from __future__ import annotations

import sys
from pathlib import Path

from ..config import GatewayConfig, load_config

EXIT_OK, EXIT_BAD_INPUT, EXIT_USAGE, EXIT_RUNTIME = 0, 1, 2, 3


def err(cmd: str, message: object) -> None:
    """``compgw CMD: message`` on standard error."""
    print(f"compgw {cmd}: {message}", file=sys.stderr)


def load(path: str) -> tuple[GatewayConfig, Path]:
    """The config and the directory its relative paths start from."""
    return load_config(path), Path(path).resolve().parent
