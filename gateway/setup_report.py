"""The resolved setup `compgw check` prints: what will be intercepted and corrected."""

from __future__ import annotations

from .compensation import Chain
from .config import AxisThermal, GatewayConfig, TlsRole


def describe(config: GatewayConfig, chain: Chain) -> str:
    lines = ["upstream:"]
    if config.upstream.tcp is not None:
        tcp = config.upstream.tcp
        lines.append(f"  tcp {tcp.host}:{tcp.port} allow {', '.join(tcp.allow)}")
    if config.upstream.tls is not None:
        tls = config.upstream.tls
        roles = "; ".join(f"{name} ({_role(role)})" for name, role in tls.roles.items())
        lines.append(f"  tls {tls.host}:{tls.port} allow {', '.join(tls.allow)}, roles "
                     f"{roles or '(none)'}, no_role {tls.no_role}")
    if config.upstream.rtu is not None:
        rtu = config.upstream.rtu
        lines.append(f"  rtu {rtu.port} {rtu.baudrate} {rtu.bytesize}{rtu.parity}{rtu.stopbits}")
    lines.append("buses:")
    for name, bus in config.buses.items():
        line = bus.rtu or bus.rtu_over_tcp
        settings = "" if line is None else (
            f"{line.baudrate} {line.bytesize}{line.parity}{line.stopbits}")
        if bus.rtu is not None:
            where = f"rtu {bus.rtu.port} {settings}"
        elif bus.rtu_over_tcp is not None:
            where = f"rtu over tcp {bus.rtu_over_tcp.host}:{bus.rtu_over_tcp.port} {settings}"
        else:
            where = f"tcp {bus.tcp.host}:{bus.tcp.port}"  # type: ignore[union-attr]
        lines.append(f"  {name}: {where}, timeout {bus.timeout_s:g} s, retries {bus.retries}")
    lines.append("axes:")
    for name, axis in config.axes.items():
        regs = axis.registers
        stages = chain.axes[name]
        lines.append(
            f"  {name}: upstream unit {axis.upstream} -> {axis.bus} unit {axis.unit}, "
            f"{axis.pulse_mm:g} {'deg' if axis.rotary else 'mm'}/pulse, "
            f"travel [{axis.travel_mm[0]:g}, {axis.travel_mm[1]:g}]"
            + ("" if not axis.rotary else ", turntable (modulo 360 deg)" if axis.wraps
                else ", swing axis")
        )
        small, unit = (3600.0, '"') if axis.rotary else (1e3, " µm")
        if axis.command_scale == 1:
            counts = f"{regs.feedback.counts_per_pulse:g} counts/pulse"
        else:
            counts = (f"{regs.feedback.counts_per_pulse:g} counts/drive unit, "
                      f"{axis.upstream_counts_per_pulse:g} counts/pulse upstream")  # fmt: skip
        lines.append(
            f"    target 0x{regs.target.address:04X} ({regs.target.order}), feedback "
            f"0x{regs.feedback.address:04X} {regs.feedback.table} ({regs.feedback.order}, "
            f"{counts})"
        )
        if axis.command_scale > 1:
            lines.append(
                f"    drive geared {axis.command_scale}x finer: targets in units of "
                f"{axis.pulse_mm / axis.command_scale:g} {'deg' if axis.rotary else 'mm'}"
            )
        if regs.trigger is not None:
            trigger = regs.trigger
            rule = (
                f"value {_hex(trigger.value)}"
                if trigger.value is not None
                else f"rising bit {trigger.rising_bit}"
                if trigger.rising_bit is not None
                else "any write"
            )
            home = ("" if trigger.home_value is None
                    else f", homing on value {_hex(trigger.home_value)}")  # fmt: skip
            kind = ("coil " if trigger.table == "coils" else
                    f"32-bit ({trigger.order}) " if trigger.words == 2 else "")  # fmt: skip
            lines.append(f"    trigger {kind}0x{trigger.address:04X} on {rule}{home}")
        parts = []
        if stages.pitch is not None:
            table = stages.pitch.table
            parts.append(
                f"pitch {table.source} ({table.position_mm.size} points, "
                f"{'bi' if table.bidirectional else 'uni'}directional, "
                f"{stages.pitch.interpolation}, "
                f"max {stages.pitch.max_abs_correction_mm() * small:.1f}{unit})"
            )
        if stages.linkage is not None:
            link = stages.linkage.model
            parts.append(
                f"linkage {link.source} (arm {link.arm_mm:g} mm, base {link.base_mm:g} mm, "
                f"phi0 {link.phi0_deg:g} deg, {link.mm_per_deg:g} mm/deg, "
                f"max {stages.linkage.max_abs_correction_mm():.4f} deg)"
            )
        if stages.cyclic is not None:
            model = stages.cyclic.model
            parts.append(
                f"cyclic {model.source} (lead {model.lead_mm:g} "
                f"{'deg' if axis.rotary else 'mm'}, {model.harmonics} "
                f"harmonic(s), {model.station_mm.size} station(s), "
                f"peak {model.peak_mm() * small:.1f}{unit})"
            )
        if stages.backlash is not None:
            parts.append(
                f"backlash {stages.backlash.backlash_mm * small:.1f}{unit} "
                f"({stages.backlash.table_direction})"
            )
        if stages.takeup is not None:
            curve = stages.takeup
            parts.append(f"take-up curve ({curve.reversal_mm.size} points, all of the lost "
                         f"motion by {float(curve.reversal_mm.max()) * small:.1f}{unit} of "
                         "reversal)")  # fmt: skip
        if stages.thermal is not None:
            parts.append(
                f"thermal from {_thermal_source(axis.compensation.thermal)} "  # type: ignore[arg-type]
                f"(a = {stages.thermal.length_mm:g} mm, origin {stages.thermal.origin_mm:g} mm)"
            )
        lines.append("    compensation: " + ("; ".join(parts) if parts else "none"))
        lines.append(f"    max_correction_mm {axis.compensation.max_correction_mm:g}")
    if chain.planar is not None and config.planar is not None:
        model = chain.planar.model
        degree = getattr(model, "degree", None)
        detail = f"degree {degree}" if degree is not None else getattr(model, "method", "")
        lines.append(
            f"planar: {'/'.join(config.planar.axes)} {model.kind} {detail}, commit "
            f"{config.planar.commit}, max {chain.planar.max_abs_correction_mm() * 1e3:.1f} µm"
        )
    lines.append(
        f"status: upstream unit {config.status.upstream_unit}, remote control "
        f"{'on' if config.status.remote_control else 'off'}"
    )
    if config.passthrough:
        lines.append("passthrough: " + ", ".join(
            f"upstream unit {u} -> {p.bus} unit {p.unit}"
            for u, p in sorted(config.passthrough.items())))  # fmt: skip
    metrics = config.metrics
    lines.append(f"metrics: {metrics.host}:{metrics.port}" if metrics.port is not None
                 else "metrics: off")  # fmt: skip
    lines.append(f"state file: {config.state_file}" if config.state_file else
                 "state file: none (a restart starts every axis afresh)")  # fmt: skip
    clock = config.machine_clock
    if clock is not None:  # a simulator's: on a real machine the computer's clock is it
        reg = clock.source_register
        lines.append(f"machine clock: {clock.bus} unit {clock.unit} {reg.table} "
                     f"{_hex(reg.address)}, {clock.scale_s:g} s per count (a simulator's; "
                     "heat from motion counts it)")  # fmt: skip
    return "\n".join(lines)


def _hex(value: int) -> str:
    return f"0x{value:X}" if value >= 0 else str(value)


def _role(role: TlsRole) -> str:
    """``units 1,2, read, write 0x6201-0x6202``: what a TLS role may do, in one phrase."""
    units = "all" if role.units == "all" else ",".join(map(str, role.units))
    if isinstance(role.write, bool):
        write = "write" if role.write else "no write"
    else:
        write = "write " + ",".join(f"0x{a:04X}-0x{b:04X}" for a, b in role.write)
    return f"units {units}, {'read' if role.read else 'no read'}, {write}"


def _thermal_source(thermal: AxisThermal) -> str:
    """Where an axis's Δa comes from, in words."""
    m = thermal.motion
    if m is None:
        return str(thermal.source)
    return f"its own motion ({m.delta_a_um_per_m:g} µm per m of heat, tau {m.tau_s:g} s)"
