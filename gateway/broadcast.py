"""Broadcasts (unit 0): a write for every drive at once, never a nominal target to a drive.

Given the router's state and the write side (:class:`.axis_writes.AxisWrites`) by
:class:`gateway.router.Gateway`, which routes unit 0 to it: the rules are the unicast ones
(the write side's ``write``, ``commit`` and trigger verdicts), applied to every axis a
broadcast touches:

- touching an axis's target: expanded into what a unicast of the same request to each axis
  whose target or trigger it touches does (corrected target, planar commit rules, trigger
  after its target); nothing is broadcast;
- touching triggers, move modes or block selects only (a register, a 32-bit field or a
  coil, whatever the axis has): every axis is judged first (a relative start, a mode or
  block select compgw does not correct for: the whole broadcast refused, 0x03, nothing
  sent), then each fired axis's pending target is committed (one corrected unicast write
  each, its planar partner's too under ``on_trigger``), then the request is broadcast;
- a mask write (FC22) of any of those registers: refused (0x03): its result depends on
  each drive's own word;
- anything else: broadcast as it is.

Broadcast means one unit-0 frame on every RTU bus (serial or over TCP), and one unicast to
each known drive (axes and pass-through units) on every Modbus TCP bus. The reply (for a TCP
master; an RTU master gets none) is the normal write response once every bus has it.
"""

from __future__ import annotations

import asyncio
import logging
from typing import TYPE_CHECKING

from .axis import overlap
from .drive_model import touched, written_words
from .modbus.frames import (
    ILLEGAL_DATA_VALUE,
    ILLEGAL_FUNCTION,
    MASK_WRITE_REGISTER,
    WRITE_MULTIPLE_COILS,
    WRITE_MULTIPLE_REGISTERS,
    WRITE_SINGLE_COIL,
    WRITE_SINGLE_REGISTER,
    FrameError,
    ModbusError,
    Request,
    is_exception,
    parse_request,
    response_for_write,
)
from .triggers import COIL_WRITES, judge, writes_trigger

if TYPE_CHECKING:
    from .axis_writes import AxisWrites
    from .router_state import RouterState, Setup

log = logging.getLogger(__name__)

#: function codes a broadcast may carry (the spec allows writes only)
BROADCAST_WRITES = frozenset({WRITE_SINGLE_COIL, WRITE_SINGLE_REGISTER, WRITE_MULTIPLE_COILS,
                              WRITE_MULTIPLE_REGISTERS, MASK_WRITE_REGISTER})


class Broadcasts:
    """The unit-0 side of the request handler (see the module docstring)."""

    def __init__(self, shared: RouterState, writes: AxisWrites) -> None:
        self.shared = shared
        self.writes = writes

    async def handle(self, setup: Setup, pdu: bytes) -> bytes:
        """Handle a unit-0 request ``pdu``; the reply a TCP master gets."""
        fc = pdu[0]
        if fc not in BROADCAST_WRITES:
            raise ModbusError(f"broadcast of FC{fc:02d}: only writes can be broadcast",
                              ILLEGAL_FUNCTION)
        try:
            req = parse_request(pdu) if fc != MASK_WRITE_REGISTER else None
        except FrameError as exc:
            raise ModbusError(f"broadcast refused: {exc}", exc.code) from None
        if req is None:
            self._mask_write_allowed(setup, pdu)
            self.shared.counters.broadcasts += 1
            await self._broadcast_raw(setup, pdu)
            return pdu[:5]
        self.shared.counters.broadcasts += 1
        reply = response_for_write(req)
        start, count = req.write_address or 0, req.write_count
        targets, triggers, modes = [], [], []
        for name, axis in setup.config.axes.items():
            regs = axis.registers
            if fc not in COIL_WRITES and overlap(start, count, regs.target.address):
                targets.append(name)
            elif writes_trigger(regs.trigger, fc, start, count):
                triggers.append(name)
            elif fc not in COIL_WRITES and touched(setup.latched[name], start, count):
                modes.append(name)
        if targets:
            self.shared.counters.broadcasts_expanded += 1
            log.info("broadcast FC%02d at 0x%04X touches the target of %s: sent to each axis "
                     "corrected", fc, start, ", ".join(targets))  # fmt: skip
            failure: ModbusError | None = None
            for name in [*targets, *triggers, *modes]:  # one axis refused: the others go
                try:
                    answer = await self.writes.write(setup, name, setup.config.axes[name], req, pdu)
                except ModbusError as exc:
                    failure = failure or exc
                    continue
                if is_exception(answer) and failure is None:
                    failure = ModbusError(f"axis {name} refused the broadcast", answer[1])
            if failure is not None:
                raise failure
            return reply
        if triggers or modes:
            await self._broadcast_trigger(setup, triggers, modes, req, pdu)
        else:
            await self._broadcast_raw(setup, pdu)
        return reply

    def _mask_write_allowed(self, setup: Setup, pdu: bytes) -> None:
        """A broadcast mask write (FC22) to a register that decides a move (a target, a
        trigger, a move mode, a block select) is refused (0x03): its result depends on
        each drive's word, which a broadcast does not read."""
        if len(pdu) != 7:
            raise ModbusError(f"broadcast refused: FC22: PDU is {len(pdu)} bytes, expected 7",
                              ILLEGAL_DATA_VALUE)  # fmt: skip
        address = int.from_bytes(pdu[1:3], "big")
        for name, axis in setup.config.axes.items():
            regs = axis.registers
            if (overlap(address, 1, regs.target.address)
                    or writes_trigger(regs.trigger, WRITE_SINGLE_REGISTER, address, 1)
                    or touched(setup.latched[name], address, 1)):
                raise ModbusError(f"broadcast mask write (FC22) at {address:#06x} refused: it "
                                  f"decides axis {name}'s moves; write it to each drive",
                                  ILLEGAL_DATA_VALUE)  # fmt: skip

    async def _broadcast_trigger(self, setup: Setup, names: list[str], modes: list[str],
                                 req: Request, pdu: bytes) -> None:
        """Judge every axis first (a relative start, a move mode or block select that is
        not what compgw corrects for: the whole broadcast refused, nothing sent); then
        commit each fired axis's target (unicast, corrected) and broadcast the write; every
        axis involved stays locked until it is out."""
        involved = set(names) | set(modes)
        for name in names:
            partner = setup.planar_partner(name)
            if partner is not None:
                involved.add(partner)
        start = req.write_address or 0
        verdicts = {}
        written: dict[str, dict[int, int]] = {}
        async with self.shared.locks(involved):
            for name in [*names, *modes]:
                axis = setup.config.axes[name]
                fields = setup.latched[name]
                hit = touched(fields, start, req.write_count) if req.function not in \
                    COIL_WRITES else []  # fmt: skip
                written[name] = written_words(hit, start, req.values)
                latched = {**self.shared.axes[name].latched, **written[name]}
                if hit:
                    await self.writes.judge_latched(name, axis, hit, latched, "a broadcast write")
                if name not in names:
                    continue
                rule = axis.registers.trigger
                assert rule is not None
                verdicts[name] = verdict = judge(rule, self.shared.axes[name].trigger, req)
                if verdict.relative:
                    raise ModbusError(f"axis {name}: a broadcast relative start (trigger bit "
                                      f"{rule.relative_bit}) is refused: compgw corrects "
                                      "positions, not distances", ILLEGAL_DATA_VALUE)
                if verdict.fires and fields:
                    await self.writes.judge_latched(name, axis, fields, latched,
                                                    "a broadcast start")  # fmt: skip
            for name, verdict in verdicts.items():
                if not verdict.fires:
                    continue
                partner = setup.planar_partner(name)
                partners = ([partner] if partner is not None and setup.hold_until_trigger(name)
                            else [])  # fmt: skip
                await self.writes.commit(setup, name, partners, None)
            await self._broadcast_raw(setup, pdu)
            for name, words in written.items():
                self.shared.axes[name].latched.update(words)
            homed = False
            for name, verdict in verdicts.items():  # the drives have the trigger write
                self.shared.axes[name].trigger = verdict.shadow
                if verdict.homes:
                    self.shared.axes[name].state.homing_started(
                        setup.config.axes[name].home_direction)
                    homed = True
            if homed:
                self.shared.on_state_change()

    async def _broadcast_raw(self, setup: Setup, pdu: bytes) -> None:
        """``pdu`` to every drive: all buses at once."""
        units: dict[str, set[int]] = {name: set() for name in self.shared.buses}
        for axis in setup.config.axes.values():
            units[axis.bus].add(axis.unit)
        for route in setup.config.passthrough.values():
            units[route.bus].add(route.unit)
        results = await asyncio.gather(
            *(bus.broadcast(pdu, sorted(units[name])) for name, bus in self.shared.buses.items()),
            return_exceptions=True)
        for name, result in zip(self.shared.buses, results):
            if isinstance(result, BaseException):
                log.warning("broadcast FC%02d on bus %s failed: %s", pdu[0], name, result)
        for result in results:
            if isinstance(result, BaseException):
                raise result
