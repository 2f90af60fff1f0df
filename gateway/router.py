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
- unit 0 (broadcasts) is :mod:`gateway.broadcast`'s;
- everything else is forwarded byte for byte and the drive's reply relayed as it is.

:meth:`Gateway.handle_fast` is the same routing without a coroutine, for the requests that
need one drive transaction and a synchronous look at the reply (pass-through, reads, writes
of neither the target nor the trigger) when the bus can send at once; the read rewrite is
the same code (:meth:`.axis_reads.AxisReads.cached_read_plan`) on both paths.

This module holds the routing; the state the parts share is a
:class:`.router_state.RouterState` (setup, buses, axis runtimes, counters, heat hooks); the
rules are in three objects :class:`Gateway` builds on it, one concern each: reads (shadow,
feedback translation, :mod:`gateway.axis_reads`), writes (shadow, triggers, commits,
:mod:`gateway.axis_writes`: given the reads, for FC23) and broadcasts
(:mod:`gateway.broadcast`: given the writes). None of them imports this module.

The math is the chain's (``gateway.compensation``); this module moves words.
"""

from __future__ import annotations

import logging
import struct
from collections.abc import Awaitable, Callable

from .axis import AxisState, overlap
from .axis_reads import AxisReads, _finishing
from .axis_writes import AxisWrites
from .broadcast import Broadcasts
from .compensation import Chain
from .config import Axis, GatewayConfig
from .drive_model import touched
from .modbus.downstream import Bus, Done
from .modbus.frames import (
    GATEWAY_PATH_UNAVAILABLE,
    MASK_WRITE_REGISTER,
    MAX_READ_REGISTERS,
    MAX_WRITE_REGISTERS,
    READ_HOLDING_REGISTERS,
    READ_INPUT_REGISTERS,
    READ_WRITE_MULTIPLE_REGISTERS,
    WRITE_MULTIPLE_REGISTERS,
    WRITE_SINGLE_REGISTER,
    FrameError,
    ModbusError,
    parse_request,
    unpack_int32,
)
from .router_state import DeltaA, GatewayCounters, RouterState, Setup, no_move, no_thermal
from .triggers import COIL_WRITES, writes_trigger

log = logging.getLogger(__name__)


class Gateway:
    """The upstream handler: ``await gateway.handle(unit_id, pdu)``."""

    def __init__(
        self,
        config: GatewayConfig,
        chain: Chain,
        buses: dict[str, Bus],
        *,
        delta_a_mm: DeltaA = no_thermal,
        moved: Callable[[str, float], None] = no_move,
        status_handler: Callable[[bytes], Awaitable[bytes]] | None = None,
        clock: Callable[[], float] | None = None,
        before_correct: Callable[[], Awaitable[None]] | None = None,
    ) -> None:
        self.shared = RouterState(Setup.build(config, chain), buses, delta_a_mm=delta_a_mm,
                                 moved=moved, clock=clock, before_correct=before_correct)
        self.shared.adopt(config)
        self.status_handler = status_handler
        self.reads = AxisReads(self.shared)
        self.writes = AxisWrites(self.shared, self.reads)
        self.broadcasts = Broadcasts(self.shared, self.writes)

    @property
    def setup(self) -> Setup:
        """The config and chain in force."""
        return self.shared.setup

    @property
    def buses(self) -> dict[str, Bus]:
        return self.shared.buses

    @property
    def counters(self) -> GatewayCounters:
        return self.shared.counters

    @property
    def on_state_change(self) -> Callable[[], None]:
        """Called after axis state changed (a commit, a homing): the state file's hook."""
        return self.shared.on_state_change

    @on_state_change.setter
    def on_state_change(self, hook: Callable[[], None]) -> None:
        self.shared.on_state_change = hook

    @property
    def delta_a_mm(self) -> DeltaA:
        """Where each axis's Δa (mm) comes from."""
        return self.shared.delta_a_mm

    @delta_a_mm.setter
    def delta_a_mm(self, source: DeltaA) -> None:
        self.shared.delta_a_mm = source

    # -- reload ---------------------------------------------------------------------------
    def reload(self, config: GatewayConfig, chain: Chain) -> None:
        """Swap to a validated config; axis states (shadow, direction) survive."""
        self.shared.adopt(config)
        self.shared.setup = Setup.build(config, chain)

    def axis_state(self, name: str) -> AxisState:
        return self.shared.axes[name].state

    def saved_axes(self) -> dict[str, dict[str, object]]:
        """Per-axis state worth keeping across a restart: axes with a committed target."""
        out: dict[str, dict[str, object]] = {}
        for name, runtime in self.shared.axes.items():
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
                runtime = self.shared.axes[name]
                runtime.state.restore(saved)
                runtime.hold(axis, held, int(saved["last_nominal_pulses"]))  # (not 0)
            except (ModbusError, KeyError, TypeError, ValueError) as exc:
                log.warning("axis %s: saved state not used: %s", name, exc)
                continue
            log.info("axis %s: carried on from the state file: nominal %s, drive command %s",
                     name, saved["last_nominal_pulses"], held)  # fmt: skip

    def last_correction_mm(self, name: str) -> float:
        return self.shared.axes[name].last_correction_mm

    # -- routing --------------------------------------------------------------------------
    async def handle(self, unit_id: int, pdu: bytes) -> bytes | None:
        setup = self.setup
        if unit_id == 0:
            return await self.broadcasts.handle(setup, pdu)
        axis_name = setup.axis_by_unit.get(unit_id)
        if axis_name is not None:
            return await self._axis_request(setup, axis_name, pdu)
        route = setup.config.passthrough.get(unit_id)
        if route is not None:
            return await self.buses[route.bus].transact(route.unit, pdu)
        if unit_id == setup.config.status.upstream_unit and self.status_handler is not None:
            return await self.status_handler(pdu)
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
            request, finish = self.reads.cached_read_plan(setup, name, axis, fc, start, count, pdu)
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
                    or touched(setup.latched[name], start, count)
                    or (fc == WRITE_MULTIPLE_REGISTERS and count > axis.fc16_max_words)):
                return False
            return bus.submit(axis.unit, pdu, done)
        if fc in (READ_WRITE_MULTIPLE_REGISTERS, MASK_WRITE_REGISTER) or (
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
            if fc == MASK_WRITE_REGISTER:
                return await self.writes.mask_write(setup, name, axis, pdu)
            return await bus.transact(axis.unit, pdu)
        try:
            req = parse_request(pdu)
        except FrameError as exc:
            # never forwarded: a lenient drive might act on a malformed write of the target
            # (an uncorrected position), or answer a malformed read with raw feedback; the
            # code is the spec's (and a conforming drive's): 0x03 length, 0x02 range
            raise ModbusError(f"axis {name}: request refused: {exc}", exc.code) from None
        if fc in (READ_HOLDING_REGISTERS, READ_INPUT_REGISTERS):
            return await self.reads.read(setup, name, axis, req, pdu)
        if fc == READ_WRITE_MULTIPLE_REGISTERS:
            return await self.writes.read_write(setup, name, axis, req, pdu)
        return await self.writes.write(setup, name, axis, req, pdu)


def _coil_trigger(axis: Axis) -> bool:
    trigger = axis.registers.trigger
    return trigger is not None and trigger.table == "coils"


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
