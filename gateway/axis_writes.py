"""Writes to an axis: the target shadow, triggers, commits of the corrected target.

A mixin of :class:`gateway.router.Gateway` (the routing is there): writes of the target pair
(one FC16, the pair inside a longer FC16 block, or two single-register writes in either
order) update the shadow of what the master wrote; the drive only ever receives a whole,
corrected value (:meth:`AxisWrites._commit`, the chain's forward correction); a trigger
write that fires commits the pending target first (and the planar partner's under
``commit: on_trigger``); blocks longer than the drive accepts go out in pieces, never
splitting a pair, the trigger's piece last. Its own module because the commit rules are a
concern apart from the routing and from the read-back (:mod:`gateway.axis_reads`).
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Iterable
from contextlib import AbstractAsyncContextManager
from typing import TYPE_CHECKING

from .axis import overlap
from .compensation import (
    AxisInput,
    CompensationError,
    CorrectionLimitError,
    MotionState,
    TravelError,
)
from .config import Axis
from .modbus.downstream import Bus
from .modbus.frames import (
    GATEWAY_PATH_UNAVAILABLE,
    GATEWAY_TARGET_NO_RESPONSE,
    ILLEGAL_DATA_VALUE,
    SERVER_DEVICE_FAILURE,
    WRITE_MULTIPLE_REGISTERS,
    ModbusError,
    Request,
    build_write_multiple_registers,
    is_exception,
    pack_int32,
    response_for_write,
    unpack_int32,
)
from .triggers import COIL_WRITES, Verdict, check_mode, judge, writes_trigger

if TYPE_CHECKING:
    from .router_state import AxisRuntime, GatewayCounters, Setup

# the router's logger (this code was split from it): log settings keep working
log = logging.getLogger("gateway.router")

_NO_TRIGGER = Verdict(fires=False, homes=False)

#: a command going back against its move by no more than this (mm, or degrees) stays on its
#: flank: the table does not follow inside the play, an error of at most that; crossing
#: the whole play for less would make the axis hunt by its lost motion each time a master
#: sends the same target again while a Δa sensor's reading wanders by a fraction of a µm
TURN_DEADBAND_MM = 0.002


class AxisWrites:
    """The write half of the axis request handler (see the module docstring)."""

    buses: dict[str, Bus]
    counters: GatewayCounters
    _axes: dict[str, AxisRuntime]
    on_state_change: Callable[[], None]

    if TYPE_CHECKING:  # provided by the Gateway
        def _axis_locks(self, names: Iterable[str | None]
                        ) -> AbstractAsyncContextManager[None]: ...

        def _saw_status(self, name: str, word: int) -> None: ...

        def _delta_a(self, name: str, at_pulses: float | None = None) -> float: ...

        def _swept(self, name: str, to_pulses: float) -> None: ...

    async def _write(self, setup: Setup, name: str, axis: Axis, req: Request, pdu: bytes) -> bytes:
        """A register write (FC06/16), or a coil write (FC05/15) to an axis whose trigger
        is a coil."""
        regs = axis.registers
        start, count = req.write_address or 0, req.write_count
        coils = req.function in COIL_WRITES
        if regs.mode is not None and not coils:
            check_mode(name, regs.mode, req)
        target_offsets = range(0) if coils else overlap(start, count, regs.target.address)
        trigger_hit = writes_trigger(regs.trigger, req.function, start, count)
        if not target_offsets and not trigger_hit:
            return await self._forward_write(name, axis, req, pdu)
        if target_offsets and count > 1 and len(target_offsets) == 1:
            raise ModbusError(
                f"axis {name}: a register block must hold both words of the target",
                ILLEGAL_DATA_VALUE,
            )
        runtime = self._axes[name]
        async with self._axis_locks([name, setup.planar_partner(name)]):
            if target_offsets:
                first = target_offsets[0]
                index = regs.target.address + first - start
                words = req.values[index : index + len(target_offsets)]
                runtime.state.write_words(first, list(words))
            verdict = self._judge(runtime, axis, req) if trigger_hit else _NO_TRIGGER
            if verdict.relative:
                assert regs.trigger is not None
                why = (f"axis {name}: a relative move (trigger bit {regs.trigger.relative_bit}) "
                       "is refused: compgw corrects positions, not distances; use absolute moves")
                log.warning("%s", why)
                raise ModbusError(why, ILLEGAL_DATA_VALUE)
            try:
                if verdict.fires:
                    reply = await self._trigger_write(setup, name, axis, req, pdu)
                elif target_offsets:
                    reply = await self._target_write(setup, name, axis, req)
                else:
                    reply = await self._forward_write(name, axis, req, pdu)
            except ModbusError as exc:
                if exc.code in (GATEWAY_PATH_UNAVAILABLE, GATEWAY_TARGET_NO_RESPONSE):
                    # a move the master asked for that the drive did not get: in the log
                    log.warning("axis %s: %s to target %d not delivered: %s", name,
                                "trigger" if verdict.fires else "write",
                                runtime.state.nominal_target(axis.registers.target.order),
                                exc)  # fmt: skip
                raise
            if trigger_hit and not is_exception(reply):  # the drive has the trigger write
                runtime.trigger = verdict.shadow
                if verdict.homes:
                    runtime.state.homing_started(axis.home_direction)
                    self.on_state_change()
            return reply

    async def _forward_write(self, name: str, axis: Axis, req: Request, pdu: bytes) -> bytes:
        """A write the gateway does not rewrite: byte for byte, unless the block is longer
        than the drive accepts (``fc16_max_words``): then in pieces, answered as one."""
        if req.function == WRITE_MULTIPLE_REGISTERS and req.write_count > axis.fc16_max_words:
            await self._send_block(name, axis, req.write_address or 0, list(req.values))
            return response_for_write(req)
        return await self.buses[axis.bus].transact(axis.unit, pdu)

    async def _send_block(self, name: str, axis: Axis, address: int, values: list[int]) -> None:
        """Write ``values`` at ``address`` in FC16 pieces of at most ``fc16_max_words``,
        never splitting the target pair or a two-word trigger; a piece holding trigger
        words goes last (never a trigger before the target it starts); an exception from
        the drive is raised."""
        limit = axis.fc16_max_words
        regs = axis.registers
        pairs = {regs.target.address}
        trigger = range(0)
        if regs.trigger is not None and regs.trigger.table == "holding":
            trigger = regs.trigger.span
            if regs.trigger.words == 2:
                pairs.add(regs.trigger.address)
        pieces: list[tuple[int, int]] = []
        start = 0
        while start < len(values):
            end = min(start + limit, len(values))
            if end < len(values) and address + end - 1 in pairs:
                end -= 1  # the cut would fall between the two words of a pair
            pieces.append((start, end))
            start = end
        pieces.sort(key=lambda p: any(address + i in trigger for i in range(*p)))
        for start, end in pieces:
            pdu = build_write_multiple_registers(address + start, values[start:end])
            reply = await self.buses[axis.bus].transact(axis.unit, pdu)
            if is_exception(reply):
                raise ModbusError(f"axis {name}: drive refused a register block", reply[1])

    def _judge(self, runtime: AxisRuntime, axis: Axis, req: Request) -> Verdict:
        """What this write of the trigger does (the shadow to take once the drive has it)."""
        rule = axis.registers.trigger
        assert rule is not None
        return judge(rule, runtime.trigger, req)

    async def _target_write(self, setup: Setup, name: str, axis: Axis, req: Request) -> bytes:
        """Target words written, no trigger fired: commit now, or hold (half a pair, or a
        planar axis with ``commit: on_trigger``)."""
        state = self._axes[name].state
        hold = setup.hold_until_trigger(name) and axis.registers.trigger is not None
        if not state.pair_complete() or hold:
            if req.function == WRITE_MULTIPLE_REGISTERS and req.write_count > 2:
                await self._forward_around_target(name, axis, req)
            return response_for_write(req)
        block = req if req.write_count > 1 else None
        await self._commit(setup, name, [], block)
        return response_for_write(req)

    async def _trigger_write(self, setup: Setup, name: str, axis: Axis, req: Request,
                             pdu: bytes) -> bytes:
        """A trigger write that fires: commit pending targets (the planar partner's too
        when ``on_trigger``), then forward the trigger (or the block that holds it, its
        target words corrected: one write)."""
        partner = setup.planar_partner(name)
        partners = [partner] if partner is not None and setup.hold_until_trigger(name) else []
        target = axis.registers.target.address
        block = None
        if req.function not in COIL_WRITES and overlap(req.write_address or 0,
                                                       req.write_count, target):
            block = req
        await self._commit(setup, name, partners, block)
        if block is not None:
            return response_for_write(req)
        return await self._forward_write(name, axis, req, pdu)

    async def _forward_around_target(self, name: str, axis: Axis, req: Request) -> None:
        """Forward the words of a held block that are not the target, as sub-blocks."""
        start = req.write_address or 0
        target = axis.registers.target.address
        before = req.values[: target - start]
        after = req.values[target + 2 - start :]
        for address, values in ((start, before), (target + 2, after)):
            if values:
                await self._send_block(name, axis, address, list(values))

    async def _commit(
        self, setup: Setup, owner: str, partners: list[str], block: Request | None
    ) -> None:
        """Correct and write the targets of ``partners`` then ``owner``.

        ``block``, when given, is the owner's register block holding its target (and maybe
        its trigger): it goes out whole with the target words corrected. Every correction
        is computed before anything is written, so a refused target (outside travel,
        correction above the cap) sends nothing at all.
        """
        plans: list[tuple[str, int, int, bool, MotionState]] = []
        for name in [*partners, owner]:
            state = self._axes[name].state
            if not (state.shadow_known or state.halves_written):
                continue
            nominal = state.nominal_target(setup.config.axes[name].registers.target.order)
            pending = bool(state.halves_written) or state.last_nominal_pulses != nominal
            if not pending and not (block is not None and name == owner):
                continue
            homed = await self._homed(name, setup.config.axes[name])
            seen = own = None
            if state.enabled and homed:
                seen = await self._partner_seen(setup, name)
                if state.motion.last_target_pulses is None:
                    own = await self._own_seen(setup, name)
            plans.append((name, nominal, *self._correct(setup, name, nominal, homed, seen,
                                                        own)))  # fmt: skip
        for name, nominal, command, applied, motion in plans:
            axis = setup.config.axes[name]
            words = list(pack_int32(command, axis.registers.target.order))
            address, values = axis.registers.target.address, words
            if block is not None and name == owner:
                address, values = block.write_address or 0, list(block.values)
                offset = axis.registers.target.address - address
                values[offset : offset + 2] = words
            await self._send_block(name, axis, address, values)
            runtime = self._axes[name]
            runtime.state.committed(nominal, command, motion)
            runtime.state.applied = applied
            runtime.hold(axis, command, nominal)
            self.counters.commits += 1
        if plans:
            self.on_state_change()

    async def _homed(self, name: str, axis: Axis) -> bool:
        """Whether the drive reports homed (True when no homed bit is configured).

        The status word is taken from the master's own status reads (a master polls it to
        see a move end) or the gateway's last read when not older than the status
        register's ``max_age_s`` (0.5 s), otherwise read from the drive now: no extra
        transaction on a busy line, and never an answer older than that.
        """
        status = axis.registers.status
        if status is None or status.homed_bit is None:
            return True
        runtime = self._axes[name]
        if time.monotonic() - runtime.status_at_s > status.max_age_s or runtime.status_word is None:
            bus = self.buses[axis.bus]
            words = await bus.read_registers(axis.unit, status.table, status.address, 1)
            self._saw_status(name, words[0])
        assert runtime.status_word is not None
        return bool(runtime.status_word >> status.homed_bit & 1)

    async def _partner_seen(self, setup: Setup, name: str) -> int | None:
        """Where the planar partner of ``name`` stands (pulses), read from its drive's
        feedback, when the gateway knows no target of it: after a start without a state
        file, before the master moved it. Without it the plane's term is left out and the
        axis lands off by the plane's error there (trial 8: X 79-88 µm off with Y at
        495 mm, 38″ of squareness). The drive's units hold its correction too (at most
        ``max_correction_mm``): the plane's error changes by far less over that. None
        when the partner's target is known or there is no partner; an error (the
        master's write is refused with it) when its drive cannot be read."""
        partner = setup.planar_partner(name)
        if partner is None:
            return None
        other = self._axes[partner].state
        if other.shadow_known or other.halves_written:
            return None
        try:
            return await self._stands_at(setup, partner)
        except ModbusError as exc:
            raise ModbusError(f"axis {name}: target not sent: where its planar partner "
                              f"{partner} stands could not be read ({exc}); the plane's "
                              "correction needs it", exc.code) from None  # fmt: skip

    async def _own_seen(self, setup: Setup, name: str) -> int | None:
        """Where axis ``name`` stands (pulses, its drive's feedback) before its first target
        since the start or a homing: the direction of that move, so its flank of the play
        is the one it arrives on (it was taken as ``home_direction``: after a restart
        without a state file, a − move was corrected as a + one, off by the play; trial
        9: 8.7 µm). None, and ``home_direction`` as before, when the drive does not say."""
        try:
            return await self._stands_at(setup, name)
        except ModbusError as exc:
            log.warning("axis %s: its position not read before its first move (%s): the "
                        "move is taken as approached in home_direction", name, exc)
            return None

    async def _stands_at(self, setup: Setup, name: str) -> int:
        """Where axis ``name``'s drive says it stands, in the master's pulses (its correction
        included: at most ``max_correction_mm``)."""
        axis = setup.config.axes[name]
        fb = axis.registers.feedback
        words = await self.buses[axis.bus].read_registers(axis.unit, fb.table, fb.address, 2)
        counts = unpack_int32(words, fb.order)
        return round(counts / fb.counts_per_pulse / axis.command_scale)

    def _correct(self, setup: Setup, name: str, nominal: int, homed: bool,
                 partner_seen: int | None = None, own_seen: int | None = None
                 ) -> tuple[int, bool, MotionState]:  # fmt: skip
        """Command for ``name`` in drive units (``command_scale`` per pulse), whether
        compensation was applied, and the axis's motion state once it is there (found once,
        kept at the commit); ``partner_seen``: where the planar partner stands when no
        target of it is known (:meth:`_partner_seen`); ``own_seen``: where the axis stands
        before its first target (:meth:`_own_seen`)."""
        axis_cfg = setup.config.axes[name]
        state = self._axes[name].state
        start = state.motion if own_seen is None else MotionState(
            state.motion.direction, own_seen, state.motion.engagement)  # fmt: skip
        chain_axis = setup.chain.axes[name]
        try:
            chain_axis.check_travel(nominal * axis_cfg.pulse_mm)
        except TravelError as exc:
            self.counters.refused_travel += 1
            log.warning("%s", exc)
            raise ModbusError(str(exc), ILLEGAL_DATA_VALUE) from None
        motion = chain_axis.approach(start, nominal)  # the nut moves either way
        if not (state.enabled and homed):  # sent as written, but the screw heats all the same
            self._swept(name, nominal)
            return nominal * axis_cfg.command_scale, False, motion
        delta_a = self._delta_a(name, nominal)
        inputs = {name: AxisInput(nominal, motion.engagement, delta_a)}
        partner = setup.planar_partner(name)
        if partner is not None:
            other = self._axes[partner].state
            if other.shadow_known or other.halves_written:
                order = setup.config.axes[partner].registers.target.order
                other_nominal = other.nominal_target(order)
                inputs[partner] = AxisInput(
                    other_nominal,
                    setup.chain.axes[partner].approach(other.motion, other_nominal).engagement,
                    self._delta_a(partner, other_nominal),
                )
            elif partner_seen is not None:
                inputs[partner] = AxisInput(partner_seen)
        scale = axis_cfg.command_scale
        try:
            command = setup.chain.command_pulses(name, inputs, scale)
            last = state.last_command_units
            back_mm = 0.0 if last is None else abs(command - last) * axis_cfg.pulse_mm / scale
            if (last is not None and back_mm > TURN_DEADBAND_MM
                    and (command > last) != (motion.direction > 0)):
                # the motor turns against the nominal move (a target sent again whose
                # correction went back: the partner moved, the screw grew): the nut turns
                # through its play, corrected as a reversal (trial 9: Y sent 400 again
                # after X moved, 7.2 µm back in command, stayed 7.1 µm off in the play)
                turned = chain_axis.turned(start, nominal, -motion.direction, back_mm)
                inputs[name] = AxisInput(nominal, turned.engagement, delta_a)
                again = setup.chain.command_pulses(name, inputs, scale)
                if again != last and (again > last) == (turned.direction > 0):
                    command, motion = again, turned
            self._swept(name, nominal)  # after: this move heats what comes next
            return command, True, motion
        except CorrectionLimitError as exc:
            self.counters.refused_correction += 1
            log.error("%s: target refused", exc)
            raise ModbusError(str(exc), SERVER_DEVICE_FAILURE) from None
        except CompensationError as exc:
            log.error("axis %s: target refused: %s", name, exc)
            raise ModbusError(str(exc), SERVER_DEVICE_FAILURE) from None
