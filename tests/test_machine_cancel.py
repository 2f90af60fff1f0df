"""Ctrl-C reaches the calibration even when it lands as a reply arrives.

On Python 3.11 ``asyncio.wait_for`` (which pymodbus awaits every reply with) returns the
reply and drops a cancellation that comes in the same loop turn: a commissioning run
signalled with SIGINT then went on to the end (seen once in a full suite). The race is made
deterministic here: the task is cancelled from a callback on the reply's own future, after
wait_for's waiter was released, against a real pymodbus drive on loopback.
"""

from __future__ import annotations

import asyncio

import pytest

from gateway.calibration.measuring.machine import Link
from tests.helpers_modbus import DRIVE_UNIT, run, tcp_drive


async def _cancel_as_the_reply_lands(cancel_on_reply: bool) -> str:
    async with tcp_drive() as port:
        link = Link("127.0.0.1", port)
        await link.connect()
        try:
            task = asyncio.current_task()
            assert task is not None
            client = link.client
            armed = cancel_on_reply
            original = client.ctx.pdu_send

            def send(pdu, addr=None):  # type: ignore[no-untyped-def]
                nonlocal armed
                original(pdu, addr)
                if armed:
                    armed = False
                    # runs after wait_for's own callback on the same future: the waiter is
                    # already released, so task.cancel() can only mark the task
                    client.ctx.response_future.add_done_callback(lambda _f: task.cancel())

            client.ctx.pdu_send = send
            try:
                await link.read(DRIVE_UNIT, 0, 2, "holding")
            except asyncio.CancelledError:
                task.uncancel()
                return "cancelled"
            return "answered"
        finally:
            link.close()


@pytest.mark.parametrize("cancel", [True, False])
def test_a_cancel_that_lands_with_the_reply_is_not_lost(cancel: bool) -> None:
    assert run(_cancel_as_the_reply_lands(cancel)) == ("cancelled" if cancel else "answered")
