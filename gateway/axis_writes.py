"""Writes to an axis: the target shadow, triggers, commits of the corrected target.

Given the router's shared state (:class:`.router_state.RouterState`) and the read side
(:class:`.axis_reads.AxisReads`, for FC23) by :class:`gateway.router.Gateway`, which routes to
it: writes of the target pair (one FC16, the pair inside a longer FC16 block, or two
single-register writes in either order) update the shadow of what the master wrote; the drive
only ever receives a whole, corrected value (:meth:`AxisWrites.commit`, the chain's forward
correction); a trigger write that fires commits the pending target first (and the planar
partner's under ``commit: on_trigger``); blocks longer than the drive accepts go out in
pieces, never splitting a pair, the trigger's piece last. Its own module and object because
the commit rules are a concern apart from the routing and from the read-back
(:mod:`gateway.axis_reads`).
"""

from __future__ import annotations

import logging
import struct
import time
from typing import TYPE_CHECKING

from .axis import overlap
from .compensation import (
    AxisInput,
    CompensationError,
    CorrectionLimitError,
    MotionState,
    TravelError,
    command_on_flank,
)
from .config import Axis
from .drive_model import (
    LatchedField,
    first_refusal,
    mask_write,
    missing,
    touched,
    written_words,
)
from .modbus.frames import (
    GATEWAY_PATH_UNAVAILABLE,
    GATEWAY_TARGET_NO_RESPONSE,
    ILLEGAL_DATA_VALUE,
    SERVER_DEVICE_FAILURE,
    WRITE_MULTIPLE_REGISTERS,
    WRITE_SINGLE_REGISTER,
    ModbusError,
    Request,
    build_read_registers_response,
    build_write_multiple_registers,
    build_write_single_register,
    is_exception,
    pack_int32,
    parse_read_registers_response,
    response_for_write,
    unpack_int32,
)
from .triggers import COIL_WRITES, Verdict, judge, writes_trigger

if TYPE_CHECKING:
    from .axis_reads import AxisReads
    from .router_state import AxisRuntime, RouterState, Setup

# the router's logger (this code was split from it): log settings keep working
log = logging.getLogger("gateway.router")

_NO_TRIGGER = Verdict(fires=False, homes=False)


class AxisWrites:
    """The write side of the axis request handler (see the module docstring)."""

    def __init__(self, shared: RouterState, reads: AxisReads) -> None:
        self.shared = shared
        self.reads = reads

    async def write(self, setup: Setup, name: str, axis: Axis, req: Request, pdu: bytes) -> bytes:
        """A register write (FC06/16), or a coil write (FC05/15) to an axis whose trigger
        is a coil."""
        regs = axis.registers
        start, count = req.write_address or 0, req.write_count
        coils = req.function in COIL_WRITES
        target_offsets = range(0) if coils else overlap(start, count, regs.target.address)
        trigger_hit = writes_trigger(regs.trigger, req.function, start, count)
        mode_hit = [] if coils else touched(setup.latched[name], start, count)
        if not target_offsets and not trigger_hit and not mode_hit:
            return await self._forward_write(name, axis, req, pdu)
        if target_offsets and count > 1 and len(target_offsets) == 1:
            raise ModbusError(
                f"axis {name}: a register block must hold both words of the target",
                ILLEGAL_DATA_VALUE,
            )
        async with self.shared.locks([name, setup.planar_partner(name)]):
            return await self._write_locked(setup, name, axis, req, pdu, mode_hit)

    async def _write_locked(self, setup: Setup, name: str, axis: Axis, req: Request,
                            pdu: bytes, mode_hit: list[LatchedField]) -> bytes:
        """:meth:`write` under the axis locks: judge what the drive would do, then send.
        Refused (an exception raised): nothing of the write is sent or kept."""
        regs = axis.registers
        start, count = req.write_address or 0, req.write_count
        coils = req.function in COIL_WRITES
        target_offsets = range(0) if coils else overlap(start, count, regs.target.address)
        trigger_hit = writes_trigger(regs.trigger, req.function, start, count)
        runtime = self.shared.axes[name]
        fields = setup.latched[name]
        written = written_words(mode_hit, start, req.values)
        latched = {**runtime.latched, **written}  # what the drive's fields hold after it
        if mode_hit:
            await self.judge_latched(name, axis, mode_hit, latched, "a write")
        verdict = self._judge(runtime, axis, req) if trigger_hit else _NO_TRIGGER
        if verdict.relative:
            assert regs.trigger is not None
            why = (f"axis {name}: a relative move (trigger bit {regs.trigger.relative_bit}) "
                   "is refused: compgw corrects positions, not distances; use absolute moves")
            log.warning("%s", why)
            raise ModbusError(why, ILLEGAL_DATA_VALUE)
        starts = verdict.fires or (regs.trigger is None and bool(target_offsets))
        if starts and fields:  # the move goes where the drive's latched fields say
            await self.judge_latched(name, axis, fields, latched, "a start")
        hold = False
        if target_offsets and not verdict.fires:
            hold = await self._hold_for_mode(setup, name, axis, latched)
        state = runtime.state
        before = (list(state.shadow), set(state.halves_written))
        if target_offsets:
            first = target_offsets[0]
            index = regs.target.address + first - start
            state.write_words(first, list(req.values[index : index + len(target_offsets)]))
        try:
            if verdict.fires:
                reply = await self._trigger_write(setup, name, axis, req, pdu)
            elif target_offsets:
                reply = await self._target_write(setup, name, axis, req, hold)
            else:
                reply = await self._forward_write(name, axis, req, pdu)
        except ModbusError as exc:
            if exc.code not in (GATEWAY_PATH_UNAVAILABLE, GATEWAY_TARGET_NO_RESPONSE):
                state.shadow, state.halves_written = before  # nothing of a refusal kept
                raise
            for address in written:  # the drive may or may not have them
                runtime.latched.pop(address, None)
            # a move the master asked for that the drive did not get: in the log (the
            # target stays pending: a start once the line is back commits it)
            log.warning("axis %s: %s to target %d not delivered: %s", name,
                        "trigger" if verdict.fires else "write",
                        state.nominal_target(axis.registers.target.order), exc)  # fmt: skip
            raise
        if is_exception(reply):  # the drive refused it: nothing of it is in the drive
            state.shadow, state.halves_written = before
            return reply
        runtime.latched.update(written)
        if trigger_hit:  # the drive has the trigger write
            runtime.trigger = verdict.shadow
            if verdict.homes:
                state.homing_started(axis.home_direction)
                self.shared.on_state_change()
        return reply

    async def judge_latched(self, name: str, axis: Axis, fields: list[LatchedField]
                            | tuple[LatchedField, ...], latched: dict[int, int],
                            when: str) -> None:  # fmt: skip
        """Refuse (0x03) ``when`` (a write, a start) unless every field of ``fields`` holds
        its expected value in ``latched`` (the drive's words after the write); a word not
        known is read from the drive first (and kept), never guessed."""
        await self._learn_latched(name, axis, fields, latched)
        why = first_refusal(fields, latched, name, when)
        if why is not None:
            log.warning("%s", why)
            raise ModbusError(why, ILLEGAL_DATA_VALUE)

    async def _learn_latched(self, name: str, axis: Axis, fields: list[LatchedField]
                             | tuple[LatchedField, ...], latched: dict[int, int]) -> None:
        """Read the words of ``fields`` that neither the master wrote nor compgw read
        (into ``latched`` and the axis's runtime). A drive that cannot say leaves them
        unknown: the caller refuses (:func:`~gateway.drive_model.first_refusal`)."""
        bus = self.shared.buses[axis.bus]
        runtime = self.shared.axes[name]
        for address in missing(fields, latched):
            try:
                word = (await bus.read_registers(axis.unit, "holding", address, 1))[0]
            except ModbusError as exc:
                if exc.code in (GATEWAY_PATH_UNAVAILABLE, GATEWAY_TARGET_NO_RESPONSE):
                    raise
                log.warning("axis %s: register %#06x not readable (%s): its move is refused "
                            "until the master writes it", name, address, exc)  # fmt: skip
                continue
            runtime.latched[address] = latched[address] = word

    async def _hold_for_mode(self, setup: Setup, name: str, axis: Axis,
                             latched: dict[int, int]) -> bool:
        """Whether a target written without a start waits for the start in the shadow,
        because only the start tells what the drive will do with it: a relative bit in the
        trigger word (Kinco), or a move mode or block select that is not known to hold
        (a distance written to the target is never sent as a corrected position)."""
        if axis.registers.trigger is None or not setup.holds_on_its_mode(name):
            return False
        trigger = axis.registers.trigger
        if trigger.relative_bit is not None:
            return True
        fields = setup.latched[name]
        try:
            await self._learn_latched(name, axis, fields, latched)
        except ModbusError:
            return True
        return first_refusal(fields, latched, name, "a write") is not None

    async def mask_write(self, setup: Setup, name: str, axis: Axis, pdu: bytes) -> bytes:
        """FC22 (mask write): on a register that decides a move (the trigger, a move mode,
        a block select) it is done as the drive would do it: the register read, the masks
        applied, the result judged and written as FC06; on the target refused (a position
        is written whole); anything else forwarded as it is."""
        if len(pdu) != 7:
            raise ModbusError(f"axis {name}: request refused: FC22: PDU is {len(pdu)} bytes, "
                              "expected 7", ILLEGAL_DATA_VALUE)  # fmt: skip
        address, and_mask, or_mask = struct.unpack(">HHH", pdu[1:7])
        regs = axis.registers
        if overlap(address, 1, regs.target.address):
            why = (f"axis {name}: a mask write (FC22) to the target at {address:#06x} is "
                   "refused: compgw corrects whole positions; write both words")
            log.warning("%s", why)
            raise ModbusError(why, ILLEGAL_DATA_VALUE)
        mode_hit = touched(setup.latched[name], address, 1)
        if not mode_hit and not writes_trigger(regs.trigger, WRITE_SINGLE_REGISTER, address, 1):
            return await self.shared.buses[axis.bus].transact(axis.unit, pdu)
        async with self.shared.locks([name, setup.planar_partner(name)]):
            bus = self.shared.buses[axis.bus]
            current = (await bus.read_registers(axis.unit, "holding", address, 1))[0]
            value = mask_write(current, and_mask, or_mask)
            single = build_write_single_register(address, value)
            req = Request(WRITE_SINGLE_REGISTER, write_address=address, values=(value,))
            reply = await self._write_locked(setup, name, axis, req, single, mode_hit)
        return reply if is_exception(reply) else pdu

    async def read_write(self, setup: Setup, name: str, axis: Axis, req: Request,
                          pdu: bytes) -> bytes:
        """FC23: a write touching the target or trigger is refused (they need the split
        and commit rules); one touching a move mode or block select is judged as any
        write of it; reads of intercepted pairs are rewritten when fully covered."""
        regs = axis.registers
        w_start, w_count = req.write_address or 0, req.write_count
        if overlap(w_start, w_count, regs.target.address) \
                or writes_trigger(regs.trigger, req.function, w_start, w_count):
            raise ModbusError(
                f"axis {name}: FC23 writing the target or trigger is not supported",
                ILLEGAL_DATA_VALUE,
            )
        mode_hit = touched(setup.latched[name], w_start, w_count)
        runtime = self.shared.axes[name]
        async with self.shared.locks([name]):
            written = written_words(mode_hit, w_start, req.values)
            if mode_hit:
                latched = {**runtime.latched, **written}
                await self.judge_latched(name, axis, mode_hit, latched, "a write")
            try:
                reply = await self.shared.buses[axis.bus].transact(axis.unit, pdu)
            except ModbusError as exc:
                if exc.code in (GATEWAY_PATH_UNAVAILABLE, GATEWAY_TARGET_NO_RESPONSE):
                    for address in written:
                        runtime.latched.pop(address, None)
                raise
            if is_exception(reply):
                return reply
            runtime.latched.update(written)
        words = parse_read_registers_response(reply)
        start = req.read_address or 0
        self.reads.rewrite_read(setup, name, axis, "holding", start, words)
        return build_read_registers_response(req.function, words)

    async def _forward_write(self, name: str, axis: Axis, req: Request, pdu: bytes) -> bytes:
        """A write the gateway does not rewrite: byte for byte, unless the block is longer
        than the drive accepts (``fc16_max_words``): then in pieces, answered as one."""
        if req.function == WRITE_MULTIPLE_REGISTERS and req.write_count > axis.fc16_max_words:
            await self._send_block(name, axis, req.write_address or 0, list(req.values))
            return response_for_write(req)
        return await self.shared.buses[axis.bus].transact(axis.unit, pdu)

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
            reply = await self.shared.buses[axis.bus].transact(axis.unit, pdu)
            if is_exception(reply):
                raise ModbusError(f"axis {name}: drive refused a register block", reply[1])

    def _judge(self, runtime: AxisRuntime, axis: Axis, req: Request) -> Verdict:
        """What this write of the trigger does (the shadow to take once the drive has it)."""
        rule = axis.registers.trigger
        assert rule is not None
        return judge(rule, runtime.trigger, req)

    async def _target_write(self, setup: Setup, name: str, axis: Axis, req: Request,
                            hold_for_mode: bool = False) -> bytes:
        """Target words written, no trigger fired: commit now, or hold (half a pair, a
        planar axis with ``commit: on_trigger``, or ``hold_for_mode``: only the start
        tells whether the drive takes it as a position, :meth:`_hold_for_mode`). A held
        whole pair outside travel is refused at once (0x03)."""
        state = self.shared.axes[name].state
        hold = (setup.hold_until_trigger(name) or hold_for_mode) \
            and axis.registers.trigger is not None
        if not state.pair_complete() or hold:
            if state.pair_complete():
                self._check_travel(setup, name, state.nominal_target(
                    axis.registers.target.order))  # fmt: skip
            if req.function == WRITE_MULTIPLE_REGISTERS and req.write_count > 2:
                await self._forward_around_target(name, axis, req)
            return response_for_write(req)
        block = req if req.write_count > 1 else None
        await self.commit(setup, name, [], block)
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
        await self.commit(setup, name, partners, block)
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

    async def commit(
        self, setup: Setup, owner: str, partners: list[str], block: Request | None
    ) -> None:
        """Correct and write the targets of ``partners`` then ``owner``.

        ``block``, when given, is the owner's register block holding its target (and maybe
        its trigger): it goes out whole with the target words corrected. Every correction
        is computed before anything is written, so a refused target (outside travel,
        correction above the cap) sends nothing at all.
        """
        plans: list[tuple[str, int, int, bool, MotionState]] = []
        before = self.shared.before_correct  # (once, and only where a target is corrected)
        for name in [*partners, owner]:
            state = self.shared.axes[name].state
            if not (state.shadow_known or state.halves_written):
                continue
            nominal = state.nominal_target(setup.config.axes[name].registers.target.order)
            pending = bool(state.halves_written) or state.last_nominal_pulses != nominal
            if not pending and not (block is not None and name == owner):
                continue
            if before is not None:
                await before()
                before = None
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
            runtime = self.shared.axes[name]
            runtime.state.committed(nominal, command, motion)
            runtime.state.applied = applied
            runtime.hold(axis, command, nominal)
            self.shared.counters.commits += 1
        if plans:
            self.shared.on_state_change()

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
        runtime = self.shared.axes[name]
        if time.monotonic() - runtime.status_at_s > status.max_age_s or runtime.status_word is None:
            bus = self.shared.buses[axis.bus]
            words = await bus.read_registers(axis.unit, status.table, status.address, 1)
            self.shared.saw_status(name, words[0])
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
        other = self.shared.axes[partner].state
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
        words = await self.shared.buses[axis.bus].read_registers(axis.unit, fb.table, fb.address, 2)
        counts = unpack_int32(words, fb.order)
        return round(counts / fb.counts_per_pulse / axis.command_scale)

    def _check_travel(self, setup: Setup, name: str, nominal: int) -> None:
        """Refuse (0x03) a nominal target (pulses) outside the axis's travel."""
        try:
            setup.chain.axes[name].check_travel(nominal * setup.config.axes[name].pulse_mm)
        except TravelError as exc:
            self.shared.counters.refused_travel += 1
            log.warning("%s", exc)
            raise ModbusError(str(exc), ILLEGAL_DATA_VALUE) from None

    def _correct(self, setup: Setup, name: str, nominal: int, homed: bool,
                 partner_seen: int | None = None, own_seen: int | None = None
                 ) -> tuple[int, bool, MotionState]:  # fmt: skip
        """Command for ``name`` in drive units (``command_scale`` per pulse), whether
        compensation was applied, and the axis's motion state once it is there (found once,
        kept at the commit); ``partner_seen``: where the planar partner stands when no
        target of it is known (:meth:`_partner_seen`); ``own_seen``: where the axis stands
        before its first target (:meth:`_own_seen`)."""
        axis_cfg = setup.config.axes[name]
        state = self.shared.axes[name].state
        start = state.motion if own_seen is None else MotionState(
            state.motion.direction, own_seen, state.motion.engagement)  # fmt: skip
        self._check_travel(setup, name, nominal)
        motion = setup.chain.axes[name].approach(start, nominal)  # the nut moves either way
        if not (state.enabled and homed):  # sent as written, but the screw heats all the same
            self.shared.swept(name, nominal)
            return nominal * axis_cfg.command_scale, False, motion
        delta_a = self.shared.delta_a(name, nominal)
        inputs = {name: AxisInput(nominal, motion.engagement, delta_a)}
        partner = setup.planar_partner(name)
        if partner is not None:
            other = self.shared.axes[partner].state
            if other.shadow_known or other.halves_written:
                order = setup.config.axes[partner].registers.target.order
                other_nominal = other.nominal_target(order)
                inputs[partner] = AxisInput(
                    other_nominal,
                    setup.chain.axes[partner].approach(other.motion, other_nominal).engagement,
                    self.shared.delta_a(partner, other_nominal),
                )
            elif partner_seen is not None:
                inputs[partner] = AxisInput(partner_seen)
        scale = axis_cfg.command_scale
        try:
            command, motion = command_on_flank(setup.chain, name, inputs, start, motion,
                                               state.flank_for(motion.direction), scale)
            self.shared.swept(name, nominal)  # after: this move heats what comes next
            return command, True, motion
        except CorrectionLimitError as exc:
            self.shared.counters.refused_correction += 1
            log.error("%s: target refused", exc)
            raise ModbusError(str(exc), SERVER_DEVICE_FAILURE) from None
        except CompensationError as exc:
            log.error("axis %s: target refused: %s", name, exc)
            raise ModbusError(str(exc), SERVER_DEVICE_FAILURE) from None
