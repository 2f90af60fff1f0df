"""What the calibration subcommands share: exit codes, the one-line error, the config.

:mod:`.commands` (calibrate, report, export), :mod:`.commands_fit` (fit) and
:mod:`.commission_cli` (commission) use these; none imports another.
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


def progress_bar(enabled: bool):  # type: ignore[no-untyped-def]
    """A rich progress bar (moves, ETA) as a ``progress(done, total)`` callable + context."""
    import contextlib

    if not enabled:
        return contextlib.nullcontext(None)
    from rich.progress import (
        BarColumn,
        MofNCompleteColumn,
        Progress,
        TextColumn,
        TimeElapsedColumn,
        TimeRemainingColumn,
    )

    progress = Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(),
                        TimeElapsedColumn(), TextColumn("ETA"), TimeRemainingColumn(),
                        transient=False)  # fmt: skip
    return progress
