"""What the calibration subcommands share: exit codes, the one-line error, the config.

:mod:`.commands` (calibrate, report, export), :mod:`.commands_fit` (fit) and
:mod:`.commissioning.cli` (commission) use these; none imports another.
"""

from __future__ import annotations

import asyncio
import signal
import sys
from collections.abc import Awaitable, Sequence
from pathlib import Path
from typing import TypeVar

from ..config import GatewayConfig, load_config

#: a drive status bit the command line did not give: the axis's config says (or the default)
FROM_CONFIG = -1

EXIT_OK, EXIT_BAD_INPUT, EXIT_USAGE, EXIT_RUNTIME = 0, 1, 2, 3

T = TypeVar("T")


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


class StopOnSignal:
    """Ctrl-C or SIGTERM: says so, cancels the task measuring, and cancels it again every
    :attr:`AGAIN_S` s until it has stopped. The cancellation is raised at the next reading
    (``reraise_cancel`` after every Modbus request); sent again, one swallowed by a library
    (a reply and the cancel arriving together) cannot leave a commissioning running on to
    its end, as one did twice in full test suites with only asyncio's own SIGINT handler."""

    AGAIN_S = 0.5

    def __init__(self, task: asyncio.Task) -> None:  # type: ignore[type-arg]
        self.task = task
        self.asked = False

    def __call__(self, sig: int) -> None:
        if not self.asked:
            self.asked = True
            print(f"{signal.Signals(sig).name}: stopping at the next reading (every reading "
                  "so far is kept)", file=sys.stderr, flush=True)  # fmt: skip
        self._cancel()

    def _cancel(self) -> None:
        if not self.task.done():
            self.task.cancel()
            asyncio.get_running_loop().call_later(self.AGAIN_S, self._cancel)


async def until_stopped(work: Awaitable[T]) -> T:
    """``await work`` in the running task, Ctrl-C or SIGTERM stopping it (see
    :class:`StopOnSignal`) as KeyboardInterrupt, also when the work ended just as the
    signal came (what it ended with is not kept half-judged)."""
    task = asyncio.current_task()
    assert task is not None
    stop = StopOnSignal(task)
    loop = asyncio.get_running_loop()
    for sig in (signal.SIGINT, signal.SIGTERM):
        loop.add_signal_handler(sig, stop, sig)
    try:
        result = await work
    except asyncio.CancelledError:
        raise KeyboardInterrupt from None
    finally:
        for sig in (signal.SIGINT, signal.SIGTERM):
            loop.remove_signal_handler(sig)
    if stop.asked:
        raise KeyboardInterrupt
    return result


def refuse_eeprom_wear(config: GatewayConfig, axes: Sequence[str], who: str) -> None:
    """A drive that writes every bus write to EEPROM by default, not declared set to RAM
    (``ram_setting_applied``), is refused (a TableError naming the axis): ``who``
    (commissioning, a calibration) writes thousands of targets (trial 9: 1849 and 2014 EEPROM
    writes on two Inovance drives in one commissioning)."""
    from ..compensation.errors import TableError
    from ..profiles import PROFILES

    for a in axes:
        axis = config.axes[a]
        if axis.profile is None or axis.ram_setting_applied:
            continue
        eeprom = PROFILES[axis.profile].eeprom
        if eeprom.writes_eeprom_by_default:
            raise TableError(f"axes.{a}: the {axis.profile} drive writes every bus write to "
                             f"EEPROM by default, and {who} writes thousands of targets: "
                             f"keep them in RAM on the drive ({eeprom.ram_setting}), then set "
                             "ram_setting_applied: true in the config")  # fmt: skip
