"""A device slow to answer costs a commissioning nothing: the calibration's Modbus link tries
a request again on exception 0x0B ("gateway target device failed to respond", what a gateway
answers when its bus timed out) or 0x06 (busy), and on nothing else. Against the real sim,
its fault block answering the drive's requests with the exception until cleared."""

from __future__ import annotations

from typing import Any

import pytest

from gateway.calibration.measuring.machine import TRANSIENT_RETRIES, Link, MachineError
from sim.server import SimServer
from tests.test_sim_faults import CODE, MODE, fault_address
from tests.test_sim_support import Master, config_from, example_dict, run, tcp_client

STATUS = 0x1003


async def _read_with(code: int, clear_after: int | None) -> tuple[Any, int, int]:
    """Unit 1 answering exception ``code``, cleared after ``clear_after`` answers (never if
    None): (the registers read or the error, requests sent, link.retried)."""
    data = example_dict()
    async with SimServer(config_from(data), tcp_port=0) as server:
        control = await tcp_client(server.tcp_port, timeout_s=1.0)
        m = Master(control, data)
        await m.control(fault_address(1, MODE), [2])
        await m.control(fault_address(1, CODE), [code])
        link = Link("127.0.0.1", server.tcp_port)
        await link.connect()
        calls = 0
        original = link.client.read_holding_registers

        async def counted(*args: Any, **kw: Any) -> Any:
            nonlocal calls
            calls += 1
            reply = await original(*args, **kw)
            if calls == clear_after:
                await m.control(0x0804, [1])  # every fault cleared: the device answers again
            return reply

        link.client.read_holding_registers = counted  # type: ignore[method-assign]
        try:
            result: Any = await link.read(1, STATUS, 1, "holding")
        except MachineError as exc:
            result = exc
        finally:
            link.close()
            control.close()
        return result, calls, link.retried


@pytest.mark.parametrize("code", [0x0B, 0x06])
def test_a_device_slow_to_answer_is_asked_again(code: int) -> None:
    result, calls, retried = run(_read_with(code, clear_after=2))
    assert isinstance(result, list) and len(result) == 1, result
    assert calls == 3 and retried == 1


def test_a_device_that_never_answers_ends_in_an_error_naming_the_tries() -> None:
    result, calls, retried = run(_read_with(0x0B, clear_after=None))
    assert isinstance(result, MachineError)
    assert calls == TRANSIENT_RETRIES + 1 and retried == 0
    text = str(result)
    assert text.endswith("unit 1 read holding 0x1003+1: exception 0x0b (gateway target device "
                         "failed to respond: no answer from that device on its line: its "
                         f"wiring, baud rate and unit id) ({TRANSIENT_RETRIES + 1} tries)"), text
    assert f"({TRANSIENT_RETRIES + 1} tries)" in text, text


def test_a_device_failure_is_not_asked_again() -> None:
    result, calls, _ = run(_read_with(0x04, clear_after=None))
    assert isinstance(result, MachineError) and calls == 1
    assert str(result).endswith("exception 0x04 (device failure)"), result
