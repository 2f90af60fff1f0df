"""Reads of an axis's registers: the target shadow and the feedback translation.

Given the router's state (:class:`.router_state.RouterState`) by :class:`gateway.router.Gateway`,
which routes to it: a read (FC03/04, and the
read half of FC23) touching the target pair returns the *shadow* of what the master wrote;
one touching the feedback pair returns the inverse-corrected (nominal) position; a read
touching half a pair is widened to cover it; a read covering the status word records it for
the homed check. The plan of a read (what goes to the drive, what rewrites its reply) is
the same on the coroutine path and the fast path (:meth:`Gateway.handle_fast`), and cached
per setup. Its own module and object because the read-back side (inverse chain, widening,
caching) is a concern apart from the routing and from the writes (:mod:`gateway.axis_writes`).
"""

from __future__ import annotations

import logging
from typing import TYPE_CHECKING

from .axis import overlap
from .compensation import AxisInput, CompensationError
from .config import Axis
from .modbus.downstream import Done
from .modbus.frames import (
    MAX_READ_REGISTERS,
    READ_HOLDING_REGISTERS,
    SERVER_DEVICE_FAILURE,
    ModbusError,
    Request,
    build_read_registers_response,
    build_read_request,
    is_exception,
    pack_int32,
    parse_read_registers_response,
    unpack_int32,
)
from .router_state import Finish, RouterState

if TYPE_CHECKING:
    from .router_state import Setup

# the router's logger (this code was split from it): log settings keep working
log = logging.getLogger("gateway.router")


#: read plans kept per setup (the cache is emptied when full: a master reading ever
#: new ranges costs a recomputation, never memory)
READ_PLANS_MAX = 1024


class AxisReads:
    """The read side of the axis request handler (see the module docstring)."""

    def __init__(self, shared: RouterState) -> None:
        self.shared = shared

    def _pairs_read_by(self, axis: Axis, table: str) -> list[int]:
        """Base addresses of intercepted pairs a read of ``table`` may touch."""
        regs = axis.registers
        bases = []
        if table == "holding":
            bases.append(regs.target.address)
        if regs.feedback.table == table:
            bases.append(regs.feedback.address)
        return bases

    async def read(self, setup: Setup, name: str, axis: Axis, req: Request, pdu: bytes) -> bytes:
        request, finish = self.cached_read_plan(setup, name, axis, req.function,
                                                 req.read_address or 0, req.read_count, pdu)
        reply = await self.shared.buses[axis.bus].transact(axis.unit, request)
        return reply if finish is None else finish(reply)

    def cached_read_plan(self, setup: Setup, name: str, axis: Axis, fc: int, start: int,
                          count: int, pdu: bytes) -> tuple[bytes, Finish | None]:
        """:meth:`_read_plan`, cached per setup (a new setup on reload starts empty)."""
        key = (name, fc, start, count)
        plan = setup.read_plans.get(key)
        if plan is None:
            plan = self._read_plan(setup, name, axis, fc, start, count, pdu)
            if len(setup.read_plans) >= READ_PLANS_MAX:
                setup.read_plans.clear()
            setup.read_plans[key] = plan
        return plan

    def _read_plan(self, setup: Setup, name: str, axis: Axis, fc: int, start: int, count: int,
                   pdu: bytes) -> tuple[bytes, Finish | None]:
        """What to send the drive for the read ``pdu`` (FC03/04 of ``count`` registers at
        ``start``), and what turns its reply into the master's (None: relayed as it is).
        Reads touching an intercepted pair are widened to cover it and rewritten; a read
        covering the status word records it for the homed check. Depends on the setup and
        the read only (the axis state is looked at in the reply's turn), so it is cached
        per setup by :meth:`cached_read_plan`."""
        table = "holding" if fc == READ_HOLDING_REGISTERS else "input"
        bases = [b for b in self._pairs_read_by(axis, table) if overlap(start, count, b)]
        if not bases:
            status = axis.registers.status
            if status is None or status.table != table \
                    or not start <= status.address < start + count:
                return pdu, None
            index = status.address - start

            def saw_status(reply: bytes) -> bytes:
                if not is_exception(reply):
                    self.shared.saw_status(name, parse_read_registers_response(reply)[index])
                return reply

            return pdu, saw_status
        lo = min([start, *bases])
        hi = max([start + count, *(b + 2 for b in bases)])
        if hi - lo > MAX_READ_REGISTERS:
            return pdu, None  # cannot widen: raw
        # the same 5 bytes as build_read_request when the read already covers the pairs
        request = pdu if lo == start and hi - lo == count else build_read_request(fc, lo, hi - lo)

        def rewrite(reply: bytes) -> bytes:
            if is_exception(reply):
                return reply
            words = parse_read_registers_response(reply)
            if len(words) != hi - lo:
                raise ModbusError(
                    f"axis {name}: drive answered {len(words)} words", SERVER_DEVICE_FAILURE
                )
            self.rewrite_read(setup, name, axis, table, lo, words)
            return build_read_registers_response(fc, words[start - lo : start - lo + count])

        return request, rewrite

    def rewrite_read(
        self, setup: Setup, name: str, axis: Axis, table: str, lo: int, words: list[int]
    ) -> None:
        """Replace drive words of intercepted pairs inside ``words`` (which start at ``lo``)."""
        regs = axis.registers
        runtime = self.shared.axes[name]
        state = runtime.state
        if table == "holding" and regs.target.address - lo in range(len(words) - 1):
            i = regs.target.address - lo
            if state.shadow_known or state.halves_written:
                words[i : i + 2] = state.shadow
            else:
                units = unpack_int32(words[i : i + 2], regs.target.order)
                nominal = self._nominal(setup, name, axis, units / axis.command_scale)
                words[i : i + 2] = pack_int32(round(nominal), regs.target.order)
        if regs.feedback.table == table and regs.feedback.address - lo in range(len(words) - 1):
            i = regs.feedback.address - lo
            counts = unpack_int32(words[i : i + 2], regs.feedback.order)
            units = counts / regs.feedback.counts_per_pulse  # where the drive is, its units
            self.shared.counters.feedback_reads += 1
            exact = self._nominal(setup, name, axis, units / axis.command_scale)
            nominal = state.reported_feedback(round(units), exact)
            nominal_counts = round(nominal * axis.upstream_counts_per_pulse)
            words[i : i + 2] = pack_int32(_clamp_int32(nominal_counts), regs.feedback.order)

    def _nominal(self, setup: Setup, name: str, axis: Axis, command_pulses: float) -> float:
        """Nominal position (pulses) of a drive at ``command_pulses``; identity when the
        last target was sent uncorrected (compensation off or not homed)."""
        state = self.shared.axes[name].state
        if not state.applied:
            return command_pulses
        inputs = {name: AxisInput(command_pulses, state.motion.engagement,
                                  self.shared.delta_a(name, command_pulses))}
        partner = setup.planar_partner(name)
        if partner is not None:
            other = self.shared.axes[partner].state
            if other.last_command_units is not None and other.applied:
                scale = setup.config.axes[partner].command_scale
                inputs[partner] = AxisInput(
                    other.last_command_units / scale, other.motion.engagement,
                    self.shared.delta_a(partner, other.last_command_units / scale),
                )  # fmt: skip
        try:
            return setup.chain.nominal_pulses(name, inputs)
        except CompensationError as exc:
            log.warning("axis %s: feedback not corrected: %s", name, exc)
            return command_pulses


def _finishing(finish: Finish, done: Done) -> Done:
    """``done`` called with ``finish(reply)``, or with the error ``finish`` raised."""

    def finished(reply: bytes | None, exc: BaseException | None) -> None:
        if exc is None and reply is not None:
            try:
                reply = finish(reply)
            except Exception as err:
                reply, exc = None, err
        done(reply, exc)

    return finished


def _clamp_int32(value: int) -> int:
    return max(-(1 << 31), min((1 << 31) - 1, value))
