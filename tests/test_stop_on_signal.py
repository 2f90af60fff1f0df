"""Ctrl-C and SIGTERM stop `compgw calibrate` and `compgw commission` even when a library
swallows the cancellation: :func:`until_stopped` cancels the task again until it stops.
(A commissioning signalled with SIGINT once ran on to its end in a full test suite.)
Real signals to this process, on its own event loop's handlers."""

from __future__ import annotations

import asyncio
import contextlib
import os
import signal

import pytest

from gateway.calibration.cli_common import until_stopped


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_a_swallowed_cancel_is_sent_again(sig: int, capsys: pytest.CaptureFixture[str]) -> None:
    seen: list[str] = []

    async def work() -> str:
        os.kill(os.getpid(), sig)
        try:
            await asyncio.sleep(30)
        except asyncio.CancelledError:
            seen.append("swallowed")
        try:
            await asyncio.sleep(30)
        except asyncio.CancelledError:
            seen.append("raised")
            raise
        return "ran to its end"

    with pytest.raises(KeyboardInterrupt):
        asyncio.run(until_stopped(work()))
    assert seen == ["swallowed", "raised"]
    assert f"{signal.Signals(sig).name}: stopping at the next reading" in capsys.readouterr().err
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler  # handed back


def test_work_that_swallows_the_cancel_and_ends_is_still_interrupted() -> None:
    """The job's last request swallowed the cancel and the job ended: what it ended with
    was not judged to its end, so it is an interrupt, not a result."""

    async def work() -> str:
        os.kill(os.getpid(), signal.SIGINT)
        with contextlib.suppress(asyncio.CancelledError):
            await asyncio.sleep(30)
        return "done"

    with pytest.raises(KeyboardInterrupt):
        asyncio.run(until_stopped(work()))
