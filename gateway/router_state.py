"""The router's state, shared by the request handler's parts (:mod:`.router` routes,
:mod:`.axis_reads`, :mod:`.axis_writes` and :mod:`.broadcast` handle): one consistent setup
(config and chain, swapped whole on reload), the counters, each axis's runtime, the heat
hooks (:class:`RouterState`). Kept apart so that the parts are given it and do not import
the router that combines them."""

from __future__ import annotations

import asyncio
import time
from collections.abc import Awaitable, Callable, Iterable
from dataclasses import dataclass, field

from .axis import AxisState
from .compensation import Chain, MotionState
from .config import Axis, GatewayConfig
from .drive_model import LatchedField, latched_fields
from .modbus.downstream import Bus
from .thermal_travel import TravelHistory
from .triggers import TriggerShadow

#: Δa of an axis's screw (mm), None where it has no thermal source
DeltaA = Callable[[str], float | None]

Finish = Callable[[bytes], bytes]  # the drive's reply -> the reply to the master


@dataclass(frozen=True)
class Setup:
    """One consistent view of config + chain; swapped whole on reload, between requests."""

    config: GatewayConfig
    chain: Chain
    axis_by_unit: dict[int, str]
    #: axis -> the fields besides target and trigger that decide what a start does
    latched: dict[str, tuple[LatchedField, ...]] = field(default_factory=dict)
    #: (axis, FC, start, count) -> what _read_plan gives for it (it depends on nothing else)
    read_plans: dict[tuple[str, int, int, int], tuple[bytes, Finish | None]] = field(
        default_factory=dict, compare=False, repr=False)

    @classmethod
    def build(cls, config: GatewayConfig, chain: Chain) -> Setup:
        return cls(config, chain, {axis.upstream: name for name, axis in config.axes.items()},
                   {name: latched_fields(axis.registers) for name, axis in config.axes.items()})

    def holds_on_its_mode(self, axis: str) -> bool:
        """Whether what a start of ``axis`` does depends on more than its target: a move
        mode, a block select or a relative bit in the trigger word."""
        trigger = self.config.axes[axis].registers.trigger
        return bool(self.latched[axis]) or (trigger is not None
                                            and trigger.relative_bit is not None)

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
class AxisRuntime:
    """One axis's state in the router: its position state, the lock its requests take,
    the trigger's shadow, the drive's status word as last read."""

    state: AxisState
    lock: asyncio.Lock = field(default_factory=asyncio.Lock)
    trigger: TriggerShadow = field(default_factory=TriggerShadow)
    #: the words of the latched fields (move mode, block select) the drive holds, as
    #: written through compgw or read from it: address -> word; missing: not known
    latched: dict[int, int] = field(default_factory=dict)
    status_word: int | None = None  # the drive's status word, as last read
    status_at_s: float = -1e9  # when (monotonic)
    last_correction_mm: float = 0.0

    def hold(self, axis: Axis, command_units: int, nominal_pulses: int) -> None:
        """The drive holds ``command_units`` for the master's ``nominal_pulses``: the
        correction status and metrics report (mm)."""
        self.last_correction_mm = (command_units / axis.command_scale
                                   - nominal_pulses) * axis.pulse_mm  # fmt: skip


def no_move(name: str, x_mm: float) -> None:
    pass


def no_thermal(_axis: str) -> float | None:
    return None


def _nothing() -> None:
    pass


class RouterState:
    """What the gateway's reads, writes and broadcasts share: the setup in force, the
    buses, each axis's runtime and lock, the counters, and the heat hooks (where Δa comes
    from, who is told of each move, the travel profiles)."""

    def __init__(
        self,
        setup: Setup,
        buses: dict[str, Bus],
        *,
        delta_a_mm: DeltaA = no_thermal,
        moved: Callable[[str, float], None] = no_move,
        clock: Callable[[], float] | None = None,
        before_correct: Callable[[], Awaitable[None]] | None = None,
    ) -> None:
        self.setup = setup
        self.buses = buses
        self.delta_a_mm = delta_a_mm
        #: told of every target sent on (axis, mm): heat from motion counts it
        self.moved = moved
        #: times the travel profiles (the machine's clock, :mod:`gateway.machine_clock`;
        #: None: TravelHistory's own default, the computer's)
        self.clock = clock
        #: awaited before targets are corrected (the machine's clock is read)
        self.before_correct = before_correct
        self.counters = GatewayCounters()
        #: called after axis state changed (a commit, a homing): the state file's hook
        self.on_state_change: Callable[[], None] = _nothing
        self.axes: dict[str, AxisRuntime] = {}
        #: the swept travel of axes whose thermal stage has a profile (thermal.profile)
        self.travel: dict[str, TravelHistory] = {}

    def adopt(self, config: GatewayConfig) -> None:
        """A runtime for each axis new in ``config`` (the others keep theirs: shadow,
        direction), a travel history for each profile (the same screw keeps its own)."""
        for name, axis in config.axes.items():
            if name not in self.axes:
                state = AxisState(MotionState(axis.home_direction))
                state.enabled = axis.compensation.enabled
                self.axes[name] = AxisRuntime(state)
        travel = {}
        for name, axis in config.axes.items():
            th = axis.compensation.thermal
            if th is None or th.profile is None:
                continue
            span = (float(axis.travel_mm[0]), float(axis.travel_mm[1]))
            kept = self.travel.get(name)
            travel[name] = kept if kept is not None and kept.same_screw(th, span) else \
                TravelHistory(th, th.profile, span, **({} if self.clock is None
                                                      else {"clock": self.clock}))  # fmt: skip
        self.travel = travel

    def locks(self, names: Iterable[str | None]) -> AllLocks:
        """The locks of these axes (None: no axis), taken in a fixed order (no deadlock)."""
        locks = {id(lock): lock for lock in (self.axes[n].lock for n in names if n)}
        return AllLocks([locks[key] for key in sorted(locks)])

    def saw_status(self, name: str, word: int) -> None:
        """The drive of ``name`` reported status ``word`` now."""
        runtime = self.axes[name]
        runtime.status_word = word
        runtime.status_at_s = time.monotonic()

    def delta_a(self, name: str, at_pulses: float | None = None) -> float:
        """Δa (mm) for axis ``name``; with a travel profile, the Δa for the place
        ``at_pulses``."""
        value = self.delta_a_mm(name)
        if value is None:
            return 0.0
        travel = self.travel.get(name)
        if travel is None or at_pulses is None:
            return value
        return travel.delta_a_mm(value, at_pulses * self.setup.config.axes[name].pulse_mm)

    def swept(self, name: str, to_pulses: float) -> None:
        """Axis ``name`` is sent to ``to_pulses``: its travel profile counts the stretch."""
        travel = self.travel.get(name)
        x_mm = to_pulses * self.setup.config.axes[name].pulse_mm
        if travel is not None:
            travel.move_to(x_mm)
        self.moved(name, x_mm)


class AllLocks:
    """Acquire several asyncio locks in the given order (a fixed order avoids deadlock)."""

    def __init__(self, locks: list[asyncio.Lock]) -> None:
        self.locks = locks

    async def __aenter__(self) -> None:
        for lock in self.locks:
            await lock.acquire()

    async def __aexit__(self, *exc: object) -> None:
        for lock in reversed(self.locks):
            lock.release()
