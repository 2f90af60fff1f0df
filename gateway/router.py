"""The request handler: route by unit id, intercept targets and feedback, pass the rest.

Every upstream request arrives here as ``(unit_id, pdu)``. The unit id picks a route: an
axis's drive (intercepted), a pass-through unit (forwarded untouched), or the status unit;
anything else is refused with 0x0A. On an axis:

- writes of the target pair (one FC16, the pair inside a longer FC16 block, or two
  single-register writes in either order) update the *shadow* of what the master wrote;
  the drive only ever receives a whole, corrected value (one FC16 of the pair or the
  rewritten block);
- a trigger (:mod:`gateway.triggers`: a register, a 32-bit field or a coil written by
  FC05/15) that fires first commits the pending target, then goes out; a block holding
  both target and trigger goes out as one write with the target words corrected; a block
  split for the drive sends the trigger's piece last;
- ``commit: on_trigger`` (planar axes) holds targets until a trigger write, then writes
  every planar axis's corrected target and forwards the trigger; ``immediate`` corrects
  at once with the partner's latest target;
- reads of the target pair return the shadow; reads of the feedback pair return the
  inverse-corrected (nominal) position; reads touching half a pair are widened;
- a malformed FC03/04/06/16/23 PDU to an axis (and FC05/15 when its trigger is a coil) is
  answered 0x03 and never forwarded (a lenient drive could act on a malformed target
  write: an uncorrected position);
- unit 0 (broadcasts) is :mod:`gateway.modbus.broadcast`'s;
- everything else is forwarded byte for byte and the drive's reply relayed as it is.

:meth:`Gateway.handle_fast` is the same routing without a coroutine, for the requests that
need one drive transaction and a synchronous look at the reply (pass-through, reads, writes
of neither the target nor the trigger) when the bus can send at once; the read rewrite is
the same code (:meth:`Gateway._read_plan`) on both paths.

The math is the chain's (``gateway.compensation``); this module moves words.
"""

from __future__ import annotations

import asyncio
import logging
import struct
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field

from .axis import AxisState, overlap
from .compensation import (
    AxisInput,
    Chain,
    CompensationError,
    CorrectionLimitError,
    MotionState,
    TravelError,
)
from .config import Axis, GatewayConfig
from .modbus.broadcast import Broadcasts
from .modbus.downstream import Bus, Done
from .modbus.frames import (
    GATEWAY_PATH_UNAVAILABLE,
    ILLEGAL_DATA_VALUE,
    MAX_READ_REGISTERS,
    MAX_WRITE_REGISTERS,
    READ_HOLDING_REGISTERS,
    READ_INPUT_REGISTERS,
    READ_WRITE_MULTIPLE_REGISTERS,
    SERVER_DEVICE_FAILURE,
    WRITE_MULTIPLE_REGISTERS,
    WRITE_SINGLE_REGISTER,
    FrameError,
    ModbusError,
    Request,
    build_read_registers_response,
    build_read_request,
    build_write_multiple_registers,
    is_exception,
    pack_int32,
    parse_read_registers_response,
    parse_request,
    response_for_write,
    unpack_int32,
)
from .triggers import COIL_WRITES, TriggerShadow, Verdict, judge, writes_trigger

log = logging.getLogger(__name__)

DeltaA = Callable[[str], float | None]
Finish = Callable[[bytes], bytes]  # the drive's reply -> the reply to the master

#: read plans kept per setup (the cache is emptied when full: a master reading ever
#: new ranges costs a recomputation, never memory)
READ_PLANS_MAX = 1024


def _no_thermal(_axis: str) -> float | None:
    return None


@dataclass(frozen=True)
class Setup:
    """One consistent view of config + chain; swapped whole on reload, between requests."""

    config: GatewayConfig
    chain: Chain
    axis_by_unit: dict[int, str]
    #: (axis, FC, start, count) -> what _read_plan gives for it (it depends on nothing else)
    read_plans: dict[tuple[str, int, int, int], tuple[bytes, Finish | None]] = field(
        default_factory=dict, compare=False, repr=False)

    @classmethod
    def build(cls, config: GatewayConfig, chain: Chain) -> Setup:
        return cls(config, chain, {axis.upstream: name for name, axis in config.axes.items()})

    def hold_until_trigger(self, axis: str) -> bool:
        planar = self.config.planar
        return planar is not None and planar.commit == "on_trigger" and axis in planar.axes

    def planar_partner(self, axis: str) -> str | None:
        return self.chain.partner(axis)


@dataclass
class GatewayCounters:
    """Monotonic counters for the status unit and metrics."""

    commits: int = 0
    broadcasts: int = 0  # unit-0 writes handled
    broadcasts_expanded: int = 0  # of those, sent as corrected unicast writes (a target)
    refused_travel: int = 0
    refused_correction: int = 0
    feedback_reads: int = 0


@dataclass
class _AxisRuntime:
    state: AxisState
    lock: asyncio.Lock = field(default_factory=asyncio.Lock)
    trigger: TriggerShadow = field(default_factory=TriggerShadow)
    status_word: int | None = None  # the drive's status word, as last read
    status_at_s: float = -1e9  # when (monotonic)
    last_correction_mm: float = 0.0


class Gateway(Broadcasts):
    """The upstream handler: ``await gateway.handle(unit_id, pdu)``."""

    def __init__(
        self,
        config: GatewayConfig,
        chain: Chain,
        buses: dict[str, Bus],
        *,
        delta_a_mm: DeltaA = _no_thermal,
        status_handler: Callable[[bytes], bytes] | None = None,
    ) -> None:
        self.buses = buses
        self.delta_a_mm = delta_a_mm
        self.status_handler = status_handler
        self.counters = GatewayCounters()
        #: called after axis state changed (a commit, a homing): the state file's hook
        self.on_state_change: Callable[[], None] = _nothing
        self._axes: dict[str, _AxisRuntime] = {}
        self.setup = Setup.build(config, chain)
        self._adopt_axes(config)

    # -- reload ---------------------------------------------------------------------------
    def reload(self, config: GatewayConfig, chain: Chain) -> None:
        """Swap to a validated config; axis states (shadow, direction) survive."""
        self._adopt_axes(config)
        self.setup = Setup.build(config, chain)

    def _adopt_axes(self, config: GatewayConfig) -> None:
        for name, axis in config.axes.items():
            if name not in self._axes:
                state = AxisState(MotionState(axis.home_direction))
                state.enabled = axis.compensation.enabled
                self._axes[name] = _AxisRuntime(state)

    def axis_state(self, name: str) -> AxisState:
        return self._axes[name].state

    def saved_axes(self) -> dict[str, dict[str, object]]:
        """Per-axis state worth keeping across a restart: axes with a committed target."""
        out: dict[str, dict[str, object]] = {}
        for name, runtime in self._axes.items():
            state = runtime.state
            if state.last_command_units is None or state.last_nominal_pulses is None:
                continue
            scale = self.setup.config.axes[name].command_scale
            out[name] = {**state.saved(), "command_scale": scale}
        return out

    async def carry_on(self, saved_axes: dict[str, dict[str, object]]) -> None:
        """Take back each saved axis (:meth:`saved_axes` of an earlier process) whose drive
        still holds the saved command; any other axis starts afresh (its drive was moved
        or rewritten while compgw was down, or the entry is unusable). Logged per axis."""
        for name, saved in saved_axes.items():
            axis = self.setup.config.axes.get(name)
            if axis is None:
                continue
            try:
                if saved.get("command_scale") != axis.command_scale:
                    log.info("axis %s: saved state has another command_scale: starting afresh",
                             name)  # fmt: skip
                    continue
                target = axis.registers.target
                words = await self.buses[axis.bus].read_registers(
                    axis.unit, "holding", target.address, 2)
                held = unpack_int32(words, target.order)
                if held != saved["last_command_units"]:
                    log.info("axis %s: the drive holds target %d, not the saved %s: starting "
                             "afresh", name, held, saved["last_command_units"])  # fmt: skip
                    continue
                self._axes[name].state.restore(saved)
            except (ModbusError, KeyError, TypeError, ValueError) as exc:
                log.warning("axis %s: saved state not used: %s", name, exc)
                continue
            log.info("axis %s: carried on from the state file: nominal %s, drive command %s",
                     name, saved["last_nominal_pulses"], held)  # fmt: skip

    def last_correction_mm(self, name: str) -> float:
        return self._axes[name].last_correction_mm

    # -- routing --------------------------------------------------------------------------
    async def handle(self, unit_id: int, pdu: bytes) -> bytes | None:
        setup = self.setup
        if unit_id == 0:
            return await self._broadcast(setup, pdu)
        axis_name = setup.axis_by_unit.get(unit_id)
        if axis_name is not None:
            return await self._axis_request(setup, axis_name, pdu)
        route = setup.config.passthrough.get(unit_id)
        if route is not None:
            return await self.buses[route.bus].transact(route.unit, pdu)
        if unit_id == setup.config.status.upstream_unit and self.status_handler is not None:
            return self.status_handler(pdu)
        raise ModbusError(f"unit {unit_id} is not routed", GATEWAY_PATH_UNAVAILABLE)

    def handle_fast(self, unit_id: int, pdu: bytes, done: Done) -> bool:
        """:meth:`handle` without a coroutine, when the request needs exactly one drive
        transaction and a synchronous look at the reply, and its bus can send at once
        (:meth:`Bus.submit`): then True, and ``done`` gets what :meth:`handle` would have
        returned or raised. False (nothing done) for everything else: target and trigger
        writes (locks, status reads, commits), FC23, split blocks, the status unit,
        unrouted units, a busy or down bus."""
        setup = self.setup
        name = setup.axis_by_unit.get(unit_id)
        if name is None:
            route = setup.config.passthrough.get(unit_id)
            if route is None:
                return False
            return self.buses[route.bus].submit(route.unit, pdu, done)
        axis = setup.config.axes[name]
        bus = self.buses[axis.bus]
        fc = pdu[0]
        if fc in (READ_HOLDING_REGISTERS, READ_INPUT_REGISTERS):
            if len(pdu) != 5:
                return False  # malformed: refused by the coroutine path
            start, count = struct.unpack_from(">HH", pdu, 1)
            if not 1 <= count <= MAX_READ_REGISTERS or start + count > 0x10000:
                return False
            request, finish = self._cached_read_plan(setup, name, axis, fc, start, count, pdu)
            if finish is None:
                return bus.submit(axis.unit, request, done)
            return bus.submit(axis.unit, request, _finishing(finish, done))
        if fc in (WRITE_MULTIPLE_REGISTERS, WRITE_SINGLE_REGISTER):
            span = _write_span(pdu)
            if span is None:
                return False  # malformed: refused by the coroutine path
            start, count = span
            regs = axis.registers
            if (overlap(start, count, regs.target.address)
                    or writes_trigger(regs.trigger, fc, start, count)
                    or (fc == WRITE_MULTIPLE_REGISTERS and count > axis.fc16_max_words)):
                return False
            return bus.submit(axis.unit, pdu, done)
        if fc == READ_WRITE_MULTIPLE_REGISTERS or (
                fc in COIL_WRITES and _coil_trigger(axis)):
            return False
        return bus.submit(axis.unit, pdu, done)

    async def _axis_request(self, setup: Setup, name: str, pdu: bytes) -> bytes:
        axis = setup.config.axes[name]
        bus = self.buses[axis.bus]
        fc = pdu[0]
        if fc not in (
            READ_HOLDING_REGISTERS,
            READ_INPUT_REGISTERS,
            WRITE_SINGLE_REGISTER,
            WRITE_MULTIPLE_REGISTERS,
            READ_WRITE_MULTIPLE_REGISTERS,
        ) and not (fc in COIL_WRITES and _coil_trigger(axis)):
            return await bus.transact(axis.unit, pdu)
        try:
            req = parse_request(pdu)
        except FrameError as exc:
            # never forwarded: a lenient drive might act on a malformed write of the target
            # (an uncorrected position), or answer a malformed read with raw feedback; the
            # code is the spec's (and a conforming drive's): 0x03 length, 0x02 range
            raise ModbusError(f"axis {name}: request refused: {exc}", exc.code) from None
        if fc in (READ_HOLDING_REGISTERS, READ_INPUT_REGISTERS):
            return await self._read(setup, name, axis, req, pdu)
        if fc == READ_WRITE_MULTIPLE_REGISTERS:
            return await self._read_write(setup, name, axis, req, pdu)
        return await self._write(setup, name, axis, req, pdu)

    # -- reads ----------------------------------------------------------------------------
    def _pairs_read_by(self, axis: Axis, table: str) -> list[int]:
        """Base addresses of intercepted pairs a read of ``table`` may touch."""
        regs = axis.registers
        bases = []
        if table == "holding":
            bases.append(regs.target.address)
        if regs.feedback.table == table:
            bases.append(regs.feedback.address)
        return bases

    async def _read(self, setup: Setup, name: str, axis: Axis, req: Request, pdu: bytes) -> bytes:
        request, finish = self._cached_read_plan(setup, name, axis, req.function,
                                                 req.read_address or 0, req.read_count, pdu)
        reply = await self.buses[axis.bus].transact(axis.unit, request)
        return reply if finish is None else finish(reply)

    def _cached_read_plan(self, setup: Setup, name: str, axis: Axis, fc: int, start: int,
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
        per setup by :meth:`_cached_read_plan`."""
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
                    self._saw_status(name, parse_read_registers_response(reply)[index])
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
            self._rewrite_read(setup, name, axis, table, lo, words)
            return build_read_registers_response(fc, words[start - lo : start - lo + count])

        return request, rewrite

    def _rewrite_read(
        self, setup: Setup, name: str, axis: Axis, table: str, lo: int, words: list[int]
    ) -> None:
        """Replace drive words of intercepted pairs inside ``words`` (which start at ``lo``)."""
        regs = axis.registers
        runtime = self._axes[name]
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
            self.counters.feedback_reads += 1
            exact = self._nominal(setup, name, axis, units / axis.command_scale)
            nominal = state.reported_feedback(round(units), exact)
            nominal_counts = round(nominal * axis.upstream_counts_per_pulse)
            words[i : i + 2] = pack_int32(_clamp_int32(nominal_counts), regs.feedback.order)

    def _nominal(self, setup: Setup, name: str, axis: Axis, command_pulses: float) -> float:
        """Nominal position (pulses) of a drive at ``command_pulses``; identity when the
        last target was sent uncorrected (compensation off or not homed)."""
        state = self._axes[name].state
        if not state.applied:
            return command_pulses
        inputs = {name: AxisInput(command_pulses, state.motion.direction, self._delta_a(name))}
        partner = setup.planar_partner(name)
        if partner is not None:
            other = self._axes[partner].state
            if other.last_command_units is not None and other.applied:
                scale = setup.config.axes[partner].command_scale
                inputs[partner] = AxisInput(
                    other.last_command_units / scale, other.motion.direction,
                    self._delta_a(partner),
                )  # fmt: skip
        try:
            return setup.chain.nominal_pulses(name, inputs)
        except CompensationError as exc:
            log.warning("axis %s: feedback not corrected: %s", name, exc)
            return command_pulses

    async def _read_write(
        self, setup: Setup, name: str, axis: Axis, req: Request, pdu: bytes
    ) -> bytes:
        """FC23: writes touching the target or trigger are refused (they need the split
        and commit rules); reads of intercepted pairs are rewritten when fully covered."""
        regs = axis.registers
        w_start, w_count = req.write_address or 0, req.write_count
        if overlap(w_start, w_count, regs.target.address) \
                or writes_trigger(regs.trigger, req.function, w_start, w_count):
            raise ModbusError(
                f"axis {name}: FC23 writing the target or trigger is not supported",
                ILLEGAL_DATA_VALUE,
            )
        reply = await self.buses[axis.bus].transact(axis.unit, pdu)
        if is_exception(reply):
            return reply
        words = parse_read_registers_response(reply)
        start = req.read_address or 0
        self._rewrite_read(setup, name, axis, "holding", start, words)
        return build_read_registers_response(req.function, words)

    # -- writes ---------------------------------------------------------------------------
    async def _write(self, setup: Setup, name: str, axis: Axis, req: Request, pdu: bytes) -> bytes:
        """A register write (FC06/16), or a coil write (FC05/15) to an axis whose trigger
        is a coil."""
        regs = axis.registers
        start, count = req.write_address or 0, req.write_count
        coils = req.function in COIL_WRITES
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
            if verdict.fires:
                reply = await self._trigger_write(setup, name, axis, req, pdu)
            elif target_offsets:
                reply = await self._target_write(setup, name, axis, req)
            else:
                reply = await self._forward_write(name, axis, req, pdu)
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

    def _axis_locks(self, names: Iterable[str | None]) -> _all:
        """The locks of these axes (None: no axis), taken in a fixed order (no deadlock)."""
        locks = {id(lock): lock for lock in (self._axes[n].lock for n in names if n)}
        return _all([locks[key] for key in sorted(locks)])

    def _judge(self, runtime: _AxisRuntime, axis: Axis, req: Request) -> Verdict:
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
        plans: list[tuple[str, int, int, bool]] = []
        for name in [*partners, owner]:
            state = self._axes[name].state
            if not (state.shadow_known or state.halves_written):
                continue
            nominal = state.nominal_target(setup.config.axes[name].registers.target.order)
            pending = bool(state.halves_written) or state.last_nominal_pulses != nominal
            if not pending and not (block is not None and name == owner):
                continue
            homed = await self._homed(name, setup.config.axes[name])
            plans.append((name, nominal, *self._correct(setup, name, nominal, homed)))
        for name, nominal, command, applied in plans:
            axis = setup.config.axes[name]
            words = list(pack_int32(command, axis.registers.target.order))
            address, values = axis.registers.target.address, words
            if block is not None and name == owner:
                address, values = block.write_address or 0, list(block.values)
                offset = axis.registers.target.address - address
                values[offset : offset + 2] = words
            await self._send_block(name, axis, address, values)
            runtime = self._axes[name]
            runtime.state.committed(nominal, command)
            runtime.state.applied = applied
            runtime.last_correction_mm = (command / axis.command_scale - nominal) * axis.pulse_mm
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

    def _saw_status(self, name: str, word: int) -> None:
        runtime = self._axes[name]
        runtime.status_word = word
        runtime.status_at_s = time.monotonic()

    def _correct(self, setup: Setup, name: str, nominal: int, homed: bool) -> tuple[int, bool]:
        """Command for ``name`` in drive units (``command_scale`` per pulse) and whether
        compensation was applied."""
        axis_cfg = setup.config.axes[name]
        state = self._axes[name].state
        chain_axis = setup.chain.axes[name]
        try:
            chain_axis.check_travel(nominal * axis_cfg.pulse_mm)
        except TravelError as exc:
            self.counters.refused_travel += 1
            log.warning("%s", exc)
            raise ModbusError(str(exc), ILLEGAL_DATA_VALUE) from None
        if not (state.enabled and homed):
            return nominal * axis_cfg.command_scale, False
        direction = state.motion.approach(nominal).direction
        inputs = {name: AxisInput(nominal, direction, self._delta_a(name))}
        partner = setup.planar_partner(name)
        if partner is not None:
            other = self._axes[partner].state
            if other.shadow_known or other.halves_written:
                order = setup.config.axes[partner].registers.target.order
                other_nominal = other.nominal_target(order)
                inputs[partner] = AxisInput(
                    other_nominal,
                    other.motion.approach(other_nominal).direction,
                    self._delta_a(partner),
                )
        try:
            return setup.chain.command_pulses(name, inputs, axis_cfg.command_scale), True
        except CorrectionLimitError as exc:
            self.counters.refused_correction += 1
            log.error("%s: target refused", exc)
            raise ModbusError(str(exc), SERVER_DEVICE_FAILURE) from None
        except CompensationError as exc:
            log.error("axis %s: target refused: %s", name, exc)
            raise ModbusError(str(exc), SERVER_DEVICE_FAILURE) from None

    def _delta_a(self, name: str) -> float:
        value = self.delta_a_mm(name)
        return 0.0 if value is None else value


def _nothing() -> None:
    pass


_NO_TRIGGER = Verdict(fires=False, homes=False)


def _coil_trigger(axis: Axis) -> bool:
    trigger = axis.registers.trigger
    return trigger is not None and trigger.table == "coils"


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


def _write_span(pdu: bytes) -> tuple[int, int] | None:
    """(first register, count) of an FC06 or FC16 request; None when malformed (where
    :func:`gateway.modbus.frames.parse_request` raises FrameError)."""
    if pdu[0] == WRITE_SINGLE_REGISTER:
        return (((pdu[1] << 8) | pdu[2]), 1) if len(pdu) == 5 else None
    if len(pdu) < 6:
        return None
    address, count, byte_count = struct.unpack_from(">HHB", pdu, 1)
    if (not 1 <= count <= MAX_WRITE_REGISTERS or byte_count != 2 * count
            or len(pdu) != 6 + byte_count or address + count > 0x10000):
        return None
    return address, count


def _clamp_int32(value: int) -> int:
    return max(-(1 << 31), min((1 << 31) - 1, value))


class _all:
    """Acquire several asyncio locks in the given order (a fixed order avoids deadlock)."""

    def __init__(self, locks: list[asyncio.Lock]) -> None:
        self.locks = locks

    async def __aenter__(self) -> None:
        for lock in self.locks:
            await lock.acquire()

    async def __aexit__(self, *exc: object) -> None:
        for lock in reversed(self.locks):
            lock.release()
