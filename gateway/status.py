"""The gateway's own Modbus unit (``status.upstream_unit``): state, counters, control.

Input registers (FC04), all read-only; 32-bit values are two registers, high word first,
signed unless noted:

=========  ==========================================================================
address    meaning
=========  ==========================================================================
0          register map version (3)
1          number of axes N (config order)
2          gateway flags: bit 0 a thermal source is in alarm, bit 1 a bus is down,
           bit 2 an axis's drive left its last request unanswered (a bus up, a drive silent)
3-4        targets committed (uint32)
5-6        targets refused: outside travel (uint32)
7-8        targets refused: correction above max_correction_mm (uint32)
9-10       feedback reads corrected (uint32)
11-12      config generation (uint32): 1 at start, +1 at each config reload that took
13         last reload: 0 none or taken, 1 refused (the old config stays; see the log)
14-15      CRC-32 of the config file's bytes as last loaded (uint32; 0 when not from a file):
           whoever writes a config and has it reloaded can tell it is the one running
16 + 8k    axis k: bit 0 compensation enabled, bit 1 last target corrected (homed and
           enabled when it was sent), bit 2 direction of the last move is −,
           bit 3 thermal correction active on this axis, bit 4 its drive left its last
           request unanswered, bit 5 the config gives it nothing to correct (no table,
           backlash, heat, plane: compensation "on" moves nothing)
17 + 8k    axis k: last correction (command − nominal), int32 in 0.1 µm (17-18)
19 + 8k    axis k: Δa used, int32 in 0.1 µm (19-20)
21 + 8k    axis k: C1/C − 1 (thermal pulse-equivalent change), int32 in 0.01 ppm (21-22)
23 + 8k    axis k: requests in a row its drive left unanswered (uint16, saturating; 0 at
           its next reply)
80 + 4s    thermal source s (config order): state 0 starting, 1 ok, 2 holding, 3 alarm
81 + 4s    source s: Δa (reference length), int32 in 0.1 µm (81-82)
83 + 4s    source s: failed reads (uint16, saturating)
120        the machine's clock (``machine_clock``): 0 none (the computer's is the
           machine's), 1 read, 2 its last read failed (it stands where it was)
121-122    the machine's clock, ms (uint32, wraps after 49.7 days), as read before the
           last corrected target; read for this read where no correction read it since
           the last read of it here (the first, a machine that stood), or after a failure
=========  ==========================================================================

Holding registers (FC03 read, FC06/FC16 write): address k = 1 to switch compensation of
axis k on, 0 off; address 100 (``RELOAD_REGISTER``) = 1 reloads the config file, as
SIGHUP does, and answers when it is done (exception 0x04 when the new config is refused:
the old one stays). Writes are refused with exception 0x01 unless
``status.remote_control`` is true: by default nobody on the network can switch correction
off or make the gateway reload.
"""

from __future__ import annotations

import logging
from collections.abc import Awaitable, Callable

from .config import corrects
from .machine_clock import MachineTime
from .modbus.frames import (
    ILLEGAL_DATA_ADDRESS,
    ILLEGAL_DATA_VALUE,
    ILLEGAL_FUNCTION,
    READ_HOLDING_REGISTERS,
    READ_INPUT_REGISTERS,
    SERVER_DEVICE_FAILURE,
    WRITE_MULTIPLE_REGISTERS,
    WRITE_SINGLE_REGISTER,
    FrameError,
    ModbusError,
    build_read_registers_response,
    pack_int32,
    parse_request,
    response_for_write,
)
from .router import Gateway
from .sensors import SensorSet

log = logging.getLogger(__name__)

MAP_VERSION = 4  # 2: the config's CRC-32 at 14-15; 3: silent drives, axes given nothing;
# 4: the machine's clock at 120-122
AXIS_BASE, AXIS_STRIDE = 16, 8
SOURCE_BASE, SOURCE_STRIDE = 80, 4
MACHINE_CLOCK_REGISTER = 120
INPUT_SIZE = MACHINE_CLOCK_REGISTER + 3  # one FC04 reads it all (at most 125 registers)
RELOAD_REGISTER = 100
GENERATION_REGISTER = 11
CONFIG_CRC_REGISTER = 14

#: reloads the config file; returns None when the new config was taken, else why not
Reloader = Callable[[], Awaitable[str | None]]


def _u32(value: int) -> list[int]:
    return list(pack_int32(max(0, min(value, 0xFFFFFFFF)), signed=False))


def _s32(value: float) -> list[int]:
    return list(pack_int32(max(-(1 << 31), min((1 << 31) - 1, round(value)))))


class StatusUnit:
    """Answers requests addressed to the gateway itself."""

    def __init__(
        self, gateway: Gateway, sensors: SensorSet, buses_down: Callable[[], bool] = lambda: False,
        *, machine_time: MachineTime | None = None,
    ) -> None:
        self.gateway = gateway
        self.machine_time = machine_time
        #: the machine clock's reads when a master last read it here: none since, and
        #: this read asks for a fresh one (commissioning carried on after the machine
        #: stood 3 h read "it has stood 0 minutes": nothing had moved to read it)
        self._clock_reads_shown = -1
        self.sensors = sensors
        self.buses_down = buses_down
        self.reloader: Reloader | None = None  # set by whoever knows the config file
        self.generation = 1
        self.last_reload_refused = False
        self.config_crc = 0  # set by whoever knows the config file

    def input_registers(self) -> list[int]:
        """The whole input-register image, computed from the live state."""
        gw = self.gateway
        config = gw.setup.config
        regs = [0] * INPUT_SIZE
        regs[0] = MAP_VERSION
        regs[1] = len(config.axes)
        silent = [gw.buses[a.bus].silent.get(a.unit, 0) for a in config.axes.values()]
        regs[2] = int(self.sensors.alarm) | int(self.buses_down()) << 1 | int(any(silent)) << 2
        c = gw.counters
        regs[3:5] = _u32(c.commits)
        regs[5:7] = _u32(c.refused_travel)
        regs[7:9] = _u32(c.refused_correction)
        regs[9:11] = _u32(c.feedback_reads)
        regs[11:13] = _u32(self.generation)
        regs[13] = int(self.last_reload_refused)
        regs[CONFIG_CRC_REGISTER : CONFIG_CRC_REGISTER + 2] = _u32(self.config_crc)
        for k, (name, axis) in enumerate(config.axes.items()):
            base = AXIS_BASE + AXIS_STRIDE * k
            if base + AXIS_STRIDE > SOURCE_BASE:
                break
            state = gw.axis_state(name)
            thermal = axis.compensation.thermal
            delta_a = self.sensors.axis_delta_a_mm(name) if thermal is not None else None
            regs[base] = (
                int(state.enabled)
                | int(state.applied) << 1
                | int(state.motion.direction < 0) << 2
                | int(delta_a is not None) << 3
                | int(silent[k] > 0) << 4
                | int(not corrects(config, name)) << 5
            )
            regs[base + 1 : base + 3] = _s32(gw.last_correction_mm(name) * 1e4)
            regs[base + 3 : base + 5] = _s32((delta_a or 0.0) * 1e4)
            ratio_ppm = (delta_a or 0.0) / thermal.length_mm * 1e6 if thermal else 0.0
            regs[base + 5 : base + 7] = _s32(ratio_ppm * 100)
            regs[base + 7] = min(silent[k], 0xFFFF)
        for s, name in enumerate(self.sensors):
            base = SOURCE_BASE + SOURCE_STRIDE * s
            if base + SOURCE_STRIDE > MACHINE_CLOCK_REGISTER:
                break
            sensor = self.sensors[name]
            regs[base] = int(sensor.state)
            regs[base + 1 : base + 3] = _s32((sensor.delta_a_mm or 0.0) * 1e4)
            regs[base + 3] = min(sensor.counters.failures, 0xFFFF)
        clock = self.machine_time
        if clock is not None:
            regs[MACHINE_CLOCK_REGISTER] = 1 if clock.ok else 2
            regs[MACHINE_CLOCK_REGISTER + 1 : MACHINE_CLOCK_REGISTER + 3] = \
                _u32(round(clock.now_s() * 1000.0) & 0xFFFFFFFF)  # fmt: skip
        return regs

    def holding_registers(self) -> list[int]:
        gw = self.gateway
        regs = [int(gw.axis_state(name).enabled) for name in gw.setup.config.axes]
        return regs + [0] * (RELOAD_REGISTER + 1 - len(regs))

    def reloaded(self, refused: str | None) -> None:
        """Count a reload (from SIGHUP or the control register): ``refused`` says why not."""
        self.last_reload_refused = refused is not None
        if refused is None:
            self.generation += 1

    async def handle(self, pdu: bytes) -> bytes:
        try:
            req = parse_request(pdu)
        except FrameError as exc:
            raise ModbusError(str(exc), ILLEGAL_DATA_VALUE) from None
        if req.function in (READ_INPUT_REGISTERS, READ_HOLDING_REGISTERS):
            start, count = req.read_address or 0, req.read_count
            clock = self.machine_time
            if (clock is not None and req.function == READ_INPUT_REGISTERS
                    and start + count > MACHINE_CLOCK_REGISTER):
                if not clock.ok or clock.reads == self._clock_reads_shown:
                    await clock.refresh()  # (else as the last correction read it)
                self._clock_reads_shown = clock.reads
            image = (
                self.input_registers()
                if req.function == READ_INPUT_REGISTERS
                else self.holding_registers()
            )
            if start + count > len(image):
                raise ModbusError("beyond the status map", ILLEGAL_DATA_ADDRESS)
            return build_read_registers_response(req.function, image[start : start + count])
        if req.function in (WRITE_SINGLE_REGISTER, WRITE_MULTIPLE_REGISTERS):
            return await self._control(req)
        raise ModbusError(f"FC{req.function:02d} not served by the status unit", ILLEGAL_FUNCTION)

    async def _control(self, req) -> bytes:  # type: ignore[no-untyped-def]
        config = self.gateway.setup.config
        if not config.status.remote_control:
            log.warning("status unit: control write refused (status.remote_control is false)")
            raise ModbusError("remote control is off", ILLEGAL_FUNCTION)
        names = list(config.axes)
        start = req.write_address or 0
        if start == RELOAD_REGISTER and req.write_count == 1:
            return await self._reload(req)
        if start + req.write_count > len(names):
            raise ModbusError("no such axis", ILLEGAL_DATA_ADDRESS)
        if any(v not in (0, 1) for v in req.values):
            raise ModbusError("write 1 (on) or 0 (off)", ILLEGAL_DATA_VALUE)
        for offset, value in enumerate(req.values):
            name = names[start + offset]
            state = self.gateway.axis_state(name)
            if state.enabled != bool(value):
                log.warning("axis %s: compensation switched %s remotely", name,
                            "on" if value else "off")
            state.enabled = bool(value)
        return response_for_write(req)


    async def _reload(self, req) -> bytes:  # type: ignore[no-untyped-def]
        if req.values[0] != 1:
            raise ModbusError("write 1 to reload", ILLEGAL_DATA_VALUE)
        if self.reloader is None:
            raise ModbusError("this gateway has no config file to reload", ILLEGAL_FUNCTION)
        log.warning("config reload requested over Modbus (status unit)")
        refused = await self.reloader()
        if refused is not None:
            raise ModbusError(f"reload refused: {refused}", SERVER_DEVICE_FAILURE)
        return response_for_write(req)


def format_status(names: list[str], sources: list[str], regs: list[int],
                  config: tuple[str, int] | None = None,
                  rotary: frozenset[str] = frozenset()) -> str:  # fmt: skip
    """Human-readable lines from an input-register image (for `compgw status`); with
    ``config`` (a file and its CRC-32), whether that file is the one the gateway runs. A
    ``rotary`` axis's correction (the registers' 0.1 millidegrees) in arcseconds."""
    from .modbus.frames import unpack_int32

    def s32(at: int) -> int:
        return unpack_int32(regs[at : at + 2], "hi_lo")

    def u32(at: int) -> int:
        return unpack_int32(regs[at : at + 2], "hi_lo", signed=False)

    flags = regs[2]
    v3 = regs[0] >= 3
    lines = [
        f"status map v{regs[0]}, {regs[1]} axes; thermal alarm: {'YES' if flags & 1 else 'no'}; "
        f"bus down: {'YES' if flags & 2 else 'no'}"
        + (f"; drive not answering: {'YES' if flags & 4 else 'no'}" if v3 else ""),
        f"targets committed {u32(3)}, refused (travel) {u32(5)}, refused (cap) {u32(7)}, "
        f"feedback reads {u32(9)}",
        f"config generation {u32(GENERATION_REGISTER)}"
        f"{', last reload REFUSED' if regs[13] else ''}",
    ]
    running = u32(CONFIG_CRC_REGISTER) if regs[0] >= 2 else 0
    if config is not None and running:
        path, crc = config
        lines.append(f"config: {path} is what it loaded" if crc == running else
                     f"config: NOT {path} (the gateway loaded another file or an older "
                     f"version of it, CRC-32 {running:08x} against {crc:08x}; after an edit, "
                     "reload it: SIGHUP)")  # fmt: skip
    for k, name in enumerate(names):
        base = AXIS_BASE + AXIS_STRIDE * k
        bits = regs[base]
        if v3 and bits & 16:
            lines.append(f"axis {name}: its DRIVE IS NOT ANSWERING: the last {regs[base + 7]} "
                         "request(s) to it timed out (wiring, power, unit id, baud rate)")
        given = " (the config gives it nothing to correct)" if v3 and bits & 32 else ""
        head = (f"axis {name}: compensation {'on' if bits & 1 else 'OFF'}{given}, last target "
                f"{'corrected' if bits & 2 else 'sent as written'}, direction "
                f"{'-' if bits & 4 else '+'}, last correction ")  # fmt: skip
        if name in rotary:
            lines.append(head + f"{s32(base + 1) / 10 * 3.6:.1f}″")
            continue
        lines.append(head + f"{s32(base + 1) / 10:.1f} µm, Δa {s32(base + 3) / 10:.1f} µm, "
                     f"C1/C-1 {s32(base + 5) / 100:.2f} ppm")  # fmt: skip
    states = ["starting", "ok", "holding", "ALARM"]
    for s, name in enumerate(sources):
        base = SOURCE_BASE + SOURCE_STRIDE * s
        state = states[regs[base]] if regs[base] < len(states) else str(regs[base])
        lines.append(
            f"thermal source {name}: {state}, Δa {s32(base + 1) / 10:.1f} µm, "
            f"failed reads {regs[base + 3]}"
        )
    if len(regs) > MACHINE_CLOCK_REGISTER + 2 and regs[MACHINE_CLOCK_REGISTER]:
        read = "read" if regs[MACHINE_CLOCK_REGISTER] == 1 else "its LAST READ FAILED"
        lines.append(f"machine clock: {u32(MACHINE_CLOCK_REGISTER + 1) / 3.6e6:.3f} h "
                     f"({read})")  # fmt: skip
    return "\n".join(lines)
