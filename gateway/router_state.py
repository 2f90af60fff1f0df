"""The router's state, shared by the request handler's halves (:mod:`.router`,
:mod:`.axis_reads`, :mod:`.axis_writes`, :mod:`.modbus.broadcast`): one consistent setup
(config and chain, swapped whole on reload), the counters, each axis's runtime. Kept
apart so that the halves import it and not the router that combines them."""

from __future__ import annotations

import asyncio
from collections.abc import Callable
from dataclasses import dataclass, field

from .axis import AxisState
from .compensation import Chain
from .config import Axis, GatewayConfig
from .drive_model import LatchedField, latched_fields
from .triggers import TriggerShadow

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
