"""`compgw commission`: argument handling, the gateway reload, progress and printing (the
work is :mod:`.commission`)."""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import math
import os
import re
import shlex
import signal
import subprocess
import sys
import traceback
from collections.abc import Awaitable, Callable, Sequence
from pathlib import Path
from typing import Any

from ...cli_args import above
from ...compensation.errors import CompensationError, TableError
from ...config import ConfigError, GatewayConfig, config_crc, load_config
from ...event_loop import run_loop
from ..cli_common import (
    FROM_CONFIG,
    progress_bar,
    refuse_eeprom_wear,
    until_stopped,
)

EXIT_OK, EXIT_NOT_MET, EXIT_USAGE, EXIT_RUNTIME = 0, 1, 2, 3

HELP = """\
Commission a machine with one command: identification, fit, verification between the
points, refinement where the verification misses, until --tolerance-um is met there or the
--budget-h of machine time is spent; then the report. The gateway must be running the
config given with -c: commissioning writes its own configs over that file (yours is kept
in DIR/original.yaml) and makes the gateway reload each: through the status unit's reload
register (needs status.remote_control: true), or --reload-pid PID (SIGHUP) or
--reload-cmd CMD. An abort puts your config back. Run the same command again to resume.
Rotary axes (rotary: true) are measured with the angle instrument (--angle) in degrees: a
turntable over a whole turn (its table modulo 360), a swing axis over its range (its
linkage fitted when the config has one); --lead-mm C=5 gives a worm period in degrees,
--tolerance-arcsec their tolerance; they get no drift references.
Exit 0: within tolerance; 1: not met (budget, rounds, repeatability: see the report) or
bad input; 2: an option out of range; 3: the machine or gateway failed."""


def add_parser(sub: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    p = sub.add_parser("commission", help="identify, fit, verify and refine until within "
                       "tolerance: one command", description=HELP,
                       formatter_class=argparse.RawDescriptionHelpFormatter)  # fmt: skip
    p.add_argument("-c", "--config", required=True, help="the config the gateway runs")
    p.add_argument("--gateway", metavar="HOST:PORT",
                   help="the running gateway (default: the config's upstream.tcp)")
    p.add_argument("--laser", metavar="KIND:ARGS", help="laser interferometer: HOST:PORT:UNIT "
                   "(Modbus), bridge:tcp:HOST:PORT, bridge:cmd:COMMAND, manual, "
                   "recording:DIR[:UNIT[:SIGN]], capture:MAPPING.yaml:DIR (one axis at a "
                   "time; docs/instruments.md)")
    p.add_argument("--dwell-s", type=above(0, "s"), default=3.0,
                   help="with a recording or capture: the stand at each stop (s, 3); the "
                   "machine-time estimates count it as the stop when it is longer")
    p.add_argument("--wait-start", action=argparse.BooleanOptionalAction, default=None,
                   help="with a recording or capture: before each step's moves, wait for "
                   "Enter (the laser records) (default: at a terminal)")
    p.add_argument("--laser-axes", metavar="X,Y", help="laser channel order")
    p.add_argument("--angle", metavar="KIND:ARGS", help="angle instrument of rotary "
                   "axes: int32 µdeg at 2k (axis k), as calibrate --angle")  # fmt: skip
    p.add_argument("--angle-axes", metavar="A,C", help="its channel order (default: the "
                   "config's rotary axes)")  # fmt: skip
    p.add_argument("--xy-device", metavar="KIND:ARGS", help="XY measuring device: "
                   "the plane is commissioned too")  # fmt: skip
    p.add_argument("--delta-a", metavar="KIND:ARGS",
                   help="Δa sensor: a warm-up fits the thermal length of axes with a "
                   "thermal source; HOST:PORT:UNIT[:ADDRESS] (Modbus, int32 nm), a bridge "
                   "(channel delta_a) or manual")  # fmt: skip
    p.add_argument("--temperature", metavar="HOST:PORT:UNIT",
                   help="where the screw temperature sensors answer (their registers: the "
                   "config's thermal sources): a warm-up fits the gain of axes with a "
                   "temperature source")  # fmt: skip
    p.add_argument("--no-wait-stable", action="store_true", help="read the instruments at "
                   "once (they have no stable flag)")  # fmt: skip
    p.add_argument("--axes", metavar="X,Y", help="axes to commission (default: all)")
    p.add_argument("--plane", metavar="X,Y", help="the plane's axes (default: the planar "
                   "section's, else the first two axes) when --xy-device is given")
    p.add_argument("--lead-mm", metavar="L or X=L,Y=L",
                   help="screw lead: the cyclic stage's period (default: searched for by a "
                   "dense scan; none found, no cyclic stage); a rotary axis's: the worm "
                   "period in degrees (360/teeth; not searched for)")  # fmt: skip
    p.add_argument("--no-lead-search", action="store_true",
                   help="axes without --lead-mm get no cyclic stage (no search scan)")
    p.add_argument("--tolerance-um", type=above(0, "µm"), default=2.0, metavar="T",
                   help="ISO 230-2 E (XY: max vector error) between the points (2)")
    p.add_argument("--plane-points", type=above(3, "points", int), metavar="N",
                   help="the plane's random points the verdict reads, each from both sides: "
                   "as many as the customer's acceptance reads (40)")
    p.add_argument("--tolerance-arcsec", type=above(0, "arcseconds"), default=3.0, metavar="T",
                   help="rotary axes: ISO 230-2 E between the points, arcseconds (3)")
    p.add_argument("--budget-h", type=above(0, "hours of machine time"), default=8.0, metavar="H",
                   help="machine time at most (8 h, plan estimate)")
    p.add_argument("--out", metavar="DIR", help="working directory (default: "
                   "commission/ beside the config)")  # fmt: skip
    p.add_argument("--max-rounds", type=above(0, "verification rounds", int), default=6,
                   help="verification rounds at most (default 6)")
    p.add_argument("--warmup-min", type=above(0, "minutes"), default=30.0,
                   help="warm-up length (30)")
    p.add_argument("--no-heat-warmup", action="store_true",
                   help="an axis with no thermal sensor: no zone warm-up; its heat from motion "
                        "is fitted to the drift references alone (less machine time, a "
                        "less certain cooling time)")
    p.add_argument("--seed", type=int, default=0, help="random verification targets")
    p.add_argument("--dry-run", action="store_true", help="print the plan and stop")
    p.add_argument("--recheck", action="store_true",
                   help="a finished commissioning: measure its random targets again with the "
                        "tables loaded now and say whether they still hold (fits nothing)")
    p.add_argument("--finish", action="store_true",
                   help="a stopped commissioning (Ctrl-C, the machine needed back): measure "
                        "nothing more; fit the tables from what it has read, load them and "
                        "read the after-run (its budget becomes the machine time spent and "
                        "the after-run's)")
    p.add_argument("--reload-pid", type=int, metavar="PID", help="reload by SIGHUP")
    p.add_argument("--reload-cmd", metavar="CMD", help="reload by a command")
    p.add_argument("--estimate-speed-mm-s", type=above(0, "mm/s"), default=100.0,
                   help="the axes' speed, for the machine-time estimates (100)")
    p.add_argument("--estimate-stop-s", type=above(0, "s per reading"), default=2.0,
                   help="the plan's estimate of a stop per reading, settling and the "
                   "instrument's read (s, default 2)")
    p.add_argument("--in-position-bit", type=int, default=FROM_CONFIG,
                   help="the drive status word's in-position bit (default: each axis's "
                   "registers.status.in_position_bit; none there: 4, or the feedback alone "
                   "with a drive profile)")
    p.add_argument("--moving-bit", type=int, default=FROM_CONFIG,
                   help="the status word's moving bit (default: registers.status.moving_bit, "
                   "as above: 2)")
    p.add_argument("--alarm-bit", type=int, default=FROM_CONFIG,
                   help="the status word's alarm bit: set, the run stops and your config "
                   "is put back (default: registers.status.alarm_bit, as above: 0)")
    p.add_argument("--in-position-pulses", type=float, default=2.0,
                   help="arrived when the feedback is within this of the target, and the "
                   "status bits (where the axis has a status word) agree (pulses, default 2)")
    p.add_argument("--timeout-s", type=above(0, "s"), default=120.0,
                   help="a move not in position this long after it was sent stops the run "
                   "(s, default 120)")
    p.add_argument("--request-timeout-s", type=above(0, "s"), default=2.0,
                   help="how long one request to the gateway or an instrument waits for its "
                   "answer (s, default 2): longer for a gateway on a slow serial line")
    p.add_argument("--progress", action="store_true", help="progress bar even off a terminal")
    p.add_argument("--no-progress", action="store_true")
    p.set_defaults(func=main)


def _err(message: object) -> None:
    print(f"compgw commission: {message}", file=sys.stderr)


def gateway_endpoint(args: argparse.Namespace, config: GatewayConfig):  # type: ignore[no-untyped-def]
    from ..measuring.machine import Endpoint

    if args.gateway:
        return Endpoint.parse(args.gateway)
    tcp = config.upstream.tcp
    if tcp is None:
        raise TableError("the config has no upstream.tcp, and commissioning talks to the "
                         "gateway over Modbus/TCP: add one on loopback beside your serial "
                         "upstream (upstream.tcp: {host: 127.0.0.1, port: 1502}), restart the "
                         "gateway, then run this again (README, Commissioning a machine)")
    if not tcp.port:
        raise TableError("--gateway HOST:PORT is needed: the config's upstream.tcp.port is 0 "
                         "(the gateway chose a free port: its log says \"listening on\")")
    host = {"0.0.0.0": "127.0.0.1", "::": "::1"}.get(tcp.host, tcp.host)
    return Endpoint.parse(f"{host}:{tcp.port}")


#: how long a reload may take the gateway (s): tables rebuilt, on a busy machine
RELOAD_TIMEOUT_S = 30.0


async def _modbus(call: Awaitable[Any], what: str) -> Any:
    """``call``, with pymodbus's exceptions (a timeout, a lost connection) as MachineError."""
    from pymodbus.exceptions import ModbusException

    from ..measuring.machine import MachineError, reraise_cancel

    try:
        reply = await call
    except ModbusException as exc:
        reraise_cancel()
        raise MachineError(f"the gateway: {what}: {exc}") from exc
    reraise_cancel()
    return reply


def make_reload(args: argparse.Namespace, config: GatewayConfig, gateway
                ) -> Callable[[], Awaitable[None]]:  # type: ignore[no-untyped-def]
    """How the gateway is made to load its config file again, checked by the status
    unit's config generation (a refused config is an error naming why to look)."""
    from pymodbus.client import AsyncModbusTcpClient
    from pymodbus.exceptions import ModbusException

    from ...modbus.frames import unpack_int32
    from ...status import GENERATION_REGISTER, RELOAD_REGISTER
    from ..measuring.machine import ConfigMismatch, MachineError, SetupError, reraise_cancel

    unit = config.status.upstream_unit

    async def generation(client: AsyncModbusTcpClient) -> tuple[int, int, int]:
        """The config generation, whether the last reload was refused, the loaded file's
        CRC-32 (0 from a gateway that does not show it)."""
        rr = await client.read_input_registers(GENERATION_REGISTER, count=5, device_id=unit)
        if rr.isError():
            raise MachineError(f"the gateway's status unit {unit} answered {rr}")
        regs = rr.registers
        return (unpack_int32(regs[:2], "hi_lo", signed=False), regs[2],
                unpack_int32(regs[3:5], "hi_lo", signed=False))  # fmt: skip

    async def reload() -> None:
        # the gateway answers the reload write once it has loaded the tables: on a loaded
        # machine that can take seconds; a lost reply is judged by the generation after it
        client = AsyncModbusTcpClient(gateway.host, port=gateway.port, timeout=RELOAD_TIMEOUT_S,
                                      retries=1)  # fmt: skip
        connected = await client.connect()
        reraise_cancel()
        if not connected:
            raise MachineError(f"no gateway at {gateway.host}:{gateway.port}")
        try:
            before, _, _ = await _modbus(generation(client), "reading its config generation")
            want = config_crc(args.config)  # the file just written, that it is to load
            if args.reload_pid or args.reload_cmd:
                if args.reload_pid:
                    os.kill(args.reload_pid, signal.SIGHUP)
                else:
                    subprocess.run(shlex.split(args.reload_cmd), check=True)
            else:
                try:
                    rr = await client.write_register(RELOAD_REGISTER, 1, device_id=unit)
                except ModbusException:
                    rr = None  # the generation says whether it was taken
                reraise_cancel()
                if rr is not None and rr.isError() and rr.exception_code == 0x01:
                    raise SetupError("the gateway refuses to reload over Modbus: set "
                                     "status.remote_control: true in its config (then restart "
                                     "it or send it SIGHUP), or give --reload-pid or "
                                     "--reload-cmd")  # fmt: skip
            for _ in range(int(RELOAD_TIMEOUT_S / 0.05)):
                now, refused, crc = await _modbus(generation(client),
                                                  "reading its config generation")  # fmt: skip
                if now != before or refused:
                    break
                await asyncio.sleep(0.05)
            if now == before:
                why = "refused the config (see its log)" if refused else "did not reload"
                raise MachineError(f"the gateway {why}")
            if crc and crc != want:
                raise ConfigMismatch(
                    f"the gateway at {gateway.host}:{gateway.port} runs another config file "
                    f"than {args.config} (it reloaded a file of CRC-32 {crc:08x}, not the "
                    f"{want:08x} written here): give -c the file the gateway was started with "
                    "(`compgw run -c FILE`; `compgw status -c FILE` says whether it is)")
        finally:
            client.close()

    return reload


def main(args: argparse.Namespace) -> int:
    from pymodbus.exceptions import ModbusException

    from ..measuring.devices import device_option, given_kinds
    from ..measuring.machine import Endpoint, MachineError, MotionSettings, SetupError
    from ..measuring.session import Instruments
    from .commission import Commission
    from .report import summary_lines
    from .report import write as write_report
    from .settings import VERDICT_XY_POINTS
    from .steps import CommissionAborted, Settings

    try:
        config_path = Path(args.config)
        config = load_config(config_path)
        _loads_whole(config, config_path)
        axes = tuple(args.axes.split(",")) if args.axes else tuple(config.axes)
        refuse_eeprom_wear(config, [a for a in axes if a in config.axes], "commissioning")
        for a in axes:
            if a not in config.axes:
                raise TableError(f"--axes: {a!r} is not an axis of {config_path} "
                             f"({', '.join(config.axes)})")  # fmt: skip
            if config.axes[a].rotary and args.angle is None:
                raise TableError(f"axis {a} is rotary: give its angle instrument, --angle "
                                 "HOST:PORT:UNIT (or leave it out with --axes)")  # fmt: skip
        plane = None
        linear = [a for a in axes if not config.axes[a].rotary]
        if args.xy_device:
            plane = _plane_axes(args.plane, config, config_path, linear)
        for option, given, kind in (("--laser-axes", args.laser_axes, False),
                                    ("--angle-axes", args.angle_axes, True)):  # fmt: skip
            if not given:
                continue
            names = given.split(",")
            fits = [a for a, c in config.axes.items() if c.rotary == kind]
            bad = [n for n in names if n in config.axes and n not in fits]
            if bad or len(set(names)) < len(names):
                raise TableError(f"{option} {given}: the instrument's channels in order, each "
                                 f"named once, a {'rotary' if kind else 'linear'} axis of "
                                 f"{config_path} ({', '.join(fits) or 'none'}) or another "
                                 "name for a channel no axis of it uses")  # fmt: skip
            missing = [a for a in axes if config.axes[a].rotary == kind and a not in names]
            if missing:
                raise TableError(f"{option} {given}: no channel for axis {missing[0]}, which "
                                 "is commissioned")  # fmt: skip
        if args.laser is None and not all(config.axes[a].rotary for a in axes):
            raise TableError("--laser HOST:PORT:UNIT is required (the axes' instrument)")
        laser, laser_kind = device_option("--laser", args.laser)
        angle, angle_kind = device_option("--angle", args.angle)
        xy, xy_kind = device_option("--xy-device", args.xy_device)
        delta_a, delta_a_kind = device_option("--delta-a", args.delta_a)
        for option, spec in (("--laser", laser_kind), ("--angle", angle_kind),
                             ("--xy-device", xy_kind), ("--delta-a", delta_a_kind)):
            if spec is not None and spec.reads_later and (
                    option != "--laser" or len(axes) != 1 or config.axes[axes[0]].rotary):
                raise TableError(f"{option} {spec.text}: a recording or capture reads one linear "
                                 "axis, the one the laser is set up on: commission one axis "
                                 "at a time (--axes X, then --axes Y with the laser moved and "
                                 "--xy-device for the plane); or use a bridge "
                                 "(docs/instruments.md)")  # fmt: skip
        gateway = gateway_endpoint(args, config)
        settings = Settings(
            config_path=config_path,
            out_dir=Path(args.out) if args.out else config_path.resolve().parent / "commission",
            gateway=gateway,
            instruments=Instruments(
                laser=laser,
                laser_axes=args.laser_axes.split(",") if args.laser_axes else None,
                angle=angle,
                angle_axes=args.angle_axes.split(",") if args.angle_axes else None,
                xy=xy,
                delta_a=delta_a,
                temperature=Endpoint.device("--temperature", args.temperature),
                wait_stable=not args.no_wait_stable,
                kinds=given_kinds(laser=laser_kind, angle=angle_kind, xy=xy_kind,
                                  delta_a=delta_a_kind),
                dwell_s=args.dwell_s,
                wait_start=sys.stdin.isatty() if args.wait_start is None else args.wait_start,
            ),
            axes=axes, planar=plane, lead_mm=parse_leads(args.lead_mm, axes),
            tolerance_um=args.tolerance_um, tolerance_arcsec=args.tolerance_arcsec,
            plane_points=args.plane_points or VERDICT_XY_POINTS,
            budget_s=args.budget_h * 3600.0,
            speed_mm_s=args.estimate_speed_mm_s,
            stop_s=max(args.estimate_stop_s, args.dwell_s) if laser_kind is not None
            and laser_kind.reads_later else args.estimate_stop_s,
            motion=MotionSettings(args.in_position_bit, args.moving_bit, args.alarm_bit,
                                  args.in_position_pulses, args.timeout_s,
                                  request_timeout_s=args.request_timeout_s),
            seed=args.seed, max_rounds=args.max_rounds, warmup_s=args.warmup_min * 60.0,
            no_lead_search=args.no_lead_search, heat_warmup=not args.no_heat_warmup,
            finish=args.finish,
        )  # fmt: skip
        reload = make_reload(args, config, gateway)
        job = Commission(settings, reload, print, None)
        other = job.command.other()
        if other is not None:
            raise ValueError(other)
        if args.recheck:
            return _recheck(job, settings, config, config_path)
        if args.finish:
            print(job.command.finish_now(job.budget))
        finished = job.command.finished()
        if finished is None:
            if not (config.status.remote_control or args.reload_pid or args.reload_cmd):
                raise TableError(  # (a dry run passed, then the run aborted: issue 52)
                    f"{config_path}: status.remote_control is false, so the gateway refuses to "
                    "reload over Modbus: set status.remote_control: true in its config (then "
                    "restart it or send it SIGHUP), or give --reload-pid or --reload-cmd")
            short = job.command.too_short()  # (None on a resume: --finish's)
            if short is not None:  # nothing asked or moved: no plan that ends with no table
                raise TableError(short)
            if not args.dry_run:
                run_loop(_answering(settings, config, config_path))
                job.stager.adopt_edits()  # (refused here, before anything would put a config back)
            if not args.finish:
                job.command.print_plan()
    except (ConfigError, TableError, CompensationError, ValueError, OSError) as exc:
        _err(exc)
        return EXIT_NOT_MET
    if finished is not None:
        when = f", finished {finished['finished_at']}" if "finished_at" in finished else ""
        print(f"commissioned already in {settings.out_dir} ({finished['outcome']}, "
              f"{finished['machine_h']:.2f} h of machine time{when}): nothing moves. It "
              "re-measures nothing: to check the tables still hold, see the README's "
              "\"Checking the tables later\". For more, give "
              f"a larger --budget-h, a tighter {' or '.join(_tolerances(job))} or more "
              "--max-rounds; to start "
              "over, remove that directory or give --out")  # fmt: skip
        print("\n".join(summary_lines(finished)))
        report = settings.out_dir / "report" / "report.html"
        if not report.exists():  # a power loss between the summary and the report
            report = write_report(settings.out_dir, finished, _loader(job))
            print("the report was missing (an interruption as it was written): written again")
        print(f"report: {report.resolve()}")
        return EXIT_OK if args.dry_run or finished["outcome"] == "within" else EXIT_NOT_MET
    if args.dry_run:
        return EXIT_OK

    async def body() -> dict:  # type: ignore[type-arg]
        bar = progress_bar((not args.no_progress and sys.stderr.isatty()) or args.progress)
        with bar as progress:
            if progress is not None:
                tasks: dict[str, object] = {}

                def update(name: str, done: int, total: int) -> None:
                    if name not in tasks:
                        tasks[name] = progress.add_task(name, total=total)
                    progress.update(tasks[name], completed=done, total=total)  # type: ignore[arg-type]

                job.runner.progress = update
            return await job.run()

    try:
        summary = run_loop(until_stopped(body()))
    except KeyboardInterrupt:
        where = run_loop(_restore(job))
        _err(f"interrupted: every reading so far is kept in {settings.out_dir}; {where}; run "
             "the same command again to resume")  # fmt: skip
        return EXIT_RUNTIME
    except CommissionAborted as exc:
        if isinstance(exc.__cause__, SetupError):  # the command line, not the machine
            _err(f"aborted: {exc}")
            return EXIT_NOT_MET
        _err(f"aborted: {exc}{_options_at(str(exc.__cause__ or exc), settings)}; run the same "
             "command again to resume")  # fmt: skip
        return EXIT_RUNTIME
    except (TableError, CompensationError, ConfigError) as exc:
        where = run_loop(_restore(job))
        _err(f"{exc}; {where}")
        return EXIT_NOT_MET
    except (MachineError, OSError, ModbusException) as exc:  # a timeout, a lost link
        where = run_loop(_restore(job))
        _err(f"{exc}{_options_at(str(exc), settings)}; {where}; run the same command again to "
             "resume")  # fmt: skip
        return EXIT_RUNTIME
    except Exception as exc:  # a fault of compgw's own: the machine left on your config
        where = run_loop(_restore(job))
        log_path = settings.out_dir / "error.log"
        with contextlib.suppress(OSError):
            log_path.write_text(traceback.format_exc())
        _err(f"internal error ({type(exc).__name__}: {exc}); {where}; please report it with "
             f"{log_path} and {settings.out_dir / 'commission.json'}")  # fmt: skip
        return EXIT_RUNTIME

    report = write_report(settings.out_dir, summary, _loader(job))
    print("\n".join(summary_lines(summary)))
    print(f"report: {report.resolve()}")
    if config.status.remote_control and not (args.reload_pid or args.reload_cmd):
        print(f"status.remote_control is still on in {config_path}: any master may make the "
              "gateway reload; set it false once commissioning is done (README, Safety)")
    return EXIT_OK if summary["outcome"] == "within" else EXIT_NOT_MET


async def _answering(settings: Any, config: GatewayConfig, config_path: Path) -> None:
    """Before anything is written or moved: the gateway answers at its status unit and the
    laser, angle, XY, Δa and temperature instruments at theirs (one read of their first
    registers, a temperature sensor's as the config's first temperature source reads it,
    over the calibration's own :class:`..measuring.machine.Link`); a TableError naming the option
    otherwise. (A wrong unit, a port nothing listens on or no gateway running were found at
    the first reading, after the plan and a commission directory, as an abort; a --delta-a
    at a unit the gateway does not route, after a 44-minute warm-up.)"""
    from ...modbus.frames import exception_words
    from ...status import GENERATION_REGISTER
    from ..measuring.machine import Link, MachineError

    ins = settings.instruments
    devices = [("--gateway", settings.gateway, config.status.upstream_unit,
                GENERATION_REGISTER, "input", 2)] + [
        (option, ep, ep.unit, ep.address or default, "input", 2)
        for option, ep, default in (("--laser", ins.laser, 0), ("--angle", ins.angle, 0),
                                    ("--xy-device", ins.xy, 0), ("--delta-a", ins.delta_a, 1))
        if ep is not None]  # fmt: skip
    if ins.temperature is not None:
        source = next((s for s in config.thermal_sources.values()
                       if s.kind == "temperature"), None)  # fmt: skip
        if source is not None:
            reg = source.source_register
            devices.append(("--temperature", ins.temperature, ins.temperature.unit,
                            reg.address, reg.table, reg.words))  # fmt: skip
    for option, ep, unit, address, table, count in devices:
        gateway = option == "--gateway"
        named = f"{option} {ep.host}:{ep.port}" + ("" if gateway else f":{ep.unit}")
        link = Link(ep.host, ep.port)
        try:
            try:
                await link.connect()
            except MachineError:
                raise TableError(f"{named}: nothing answers there" + (
                    f"; start the gateway first (compgw run -c {config_path})" if gateway
                    else "")) from None  # fmt: skip
            try:
                await link.read(unit, address, count, table)
            except MachineError as exc:
                if exc.code is None:  # a timeout, a dropped connection
                    raise TableError(f"{named}: unit {unit} gives no reply ({exc})") from None
                what = f"its status unit {unit}" if gateway else f"unit {unit}"
                hint = ("is it compgw, and status.upstream_unit its status unit?" if gateway
                        else "is that the instrument's unit id?")  # fmt: skip
                raise TableError(f"{named}: {what} answered {exception_words(exc.code)}: "
                                 f"{hint}") from None  # fmt: skip
        finally:
            link.close()
    await _kinds_answering(settings)


async def _kinds_answering(settings: Any) -> None:
    """A bridge given for an instrument answers its greeting before anything moves (a
    TableError naming the option otherwise); a gauge at the prompt has nothing to ask."""
    from ...instruments.base import InstrumentError
    from ..measuring.devices import OPTIONS, open_device
    from ..measuring.machine import Links

    for role, spec in settings.instruments.kinds.items():
        if spec.kind != "bridge":
            continue
        links = Links()
        device = await open_device(role, None, spec, links, order=())
        try:
            await device.open()
        except InstrumentError as exc:
            raise TableError(f"{OPTIONS.get(role, role)} {spec.text}: {exc}") from None
        finally:
            await device.close()
            links.close()


def _plane_axes(given: str | None, config: GatewayConfig, config_path: Path,
                linear: list[str]) -> tuple[str, str]:
    """The plane's two axes for --xy-device: two linear axes, at least one commissioned
    here; one that is not must have its table in the config already (commissioned before:
    one laser set up on one axis at a time, the plane with the last)."""
    every = [a for a, c in config.axes.items() if not c.rotary]
    names = (given.split(",") if given else list(config.planar.axes) if config.planar
             else linear[:2] if len(linear) > 1 else every[:2])  # fmt: skip
    if len(names) != 2 or any(n not in every for n in names) or not set(names) & set(linear):
        raise TableError(f"--xy-device: the plane needs two linear axes, at least one of them "
                         f"commissioned (--plane {','.join(names) or '–'}; commissioned: "
                         f"{', '.join(linear) or 'none'})")  # fmt: skip
    for n in names:
        if n not in linear and config.axes[n].compensation.pitch is None:
            raise TableError(f"--xy-device: the plane's axis {n} is not commissioned here and "
                             f"has no pitch table in {config_path}: commission it first "
                             f"(--axes {n}), or give it with --axes")  # fmt: skip
    return names[0], names[1]


def _loads_whole(config: GatewayConfig, path: Path) -> None:
    """The config commissioning starts from loads with its tables, as the gateway would
    load it: it is what an abort or the end puts back. (Started over as the README says,
    by removing commission/, a config naming that directory's tables was put back on an
    abort and the gateway refused it, left on the identification config.)"""
    from ...tables import build_chain

    try:
        build_chain(config, path.resolve().parent)
    except (ConfigError, TableError, CompensationError) as exc:
        raise TableError(f"{path} does not load as it is ({exc}); commissioning puts it back "
                         "at the end or on an abort, so it must: restore the files it names, "
                         "or the config you had before them") from None


def _recheck(job: Any, settings: Any, config: GatewayConfig, config_path: Path) -> int:
    """``--recheck``: :mod:`.recheck`; exit 0 when everything still holds."""
    from ..measuring.machine import MachineError
    from .recheck import finished_summary, recheck, verdict_line

    summary = finished_summary(settings.out_dir, job.record.state)
    if summary is None:
        raise TableError(f"--recheck: no finished commissioning in {settings.out_dir} (give "
                         "--out for another directory)")  # fmt: skip
    if summary.get("xy") and settings.planar is None:
        print("the plane is not rechecked: give --xy-device to measure it too")
    run_loop(_answering(settings, config, config_path))
    try:
        result = run_loop(until_stopped(recheck(job, summary)))
    except KeyboardInterrupt:
        _err("interrupted: the recheck measured part of its targets; run it again")
        return EXIT_RUNTIME
    except (MachineError, OSError) as exc:
        _err(f"{exc}{_options_at(str(exc), settings)}")
        return EXIT_RUNTIME
    print(verdict_line(result))
    print(f"recheck: {result['dir']}")
    return EXIT_OK if result["within"] else EXIT_NOT_MET


def _loader(job: Any) -> Any:
    """A step's raw data as commissioning judged it, None where it was not measured."""

    def load(step: str):  # type: ignore[no-untyped-def]
        return job.runner.raw(step) if job.record.done(step) else None

    return load


def _tolerances(job: Any) -> list[str]:
    """The tolerance options that judge this commissioning's axes and plane."""
    asked = job.command.asked()
    return [o for k, o in (("tolerance_um", "--tolerance-um"),
                           ("tolerance_arcsec", "--tolerance-arcsec")) if k in asked]  # fmt: skip


def _options_at(message: str, settings: Any) -> str:
    """Which of the command line's devices a Modbus error names (by HOST:PORT, and unit
    where it says one), so a wrong --laser reads as one: " (that is --laser …)"."""
    ins = settings.instruments
    named = []
    for option, ep in (("--laser", ins.laser), ("--xy-device", ins.xy), ("--angle", ins.angle),
                       ("--delta-a", ins.delta_a), ("--temperature", ins.temperature),
                       ("--gateway", settings.gateway)):  # fmt: skip
        if ep is None or not re.search(rf"{re.escape(ep.host)}:{ep.port}\b", message):
            continue
        if option != "--gateway" and "unit " in message and not re.search(
                rf"\bunit {ep.unit}\b", message):  # fmt: skip
            continue
        named.append(f"{option} {ep.host}:{ep.port}" + (f":{ep.unit}" if option != "--gateway"
                                                         else ""))  # fmt: skip
        if option != "--gateway" and "unit " in message:
            break  # the instrument of that unit: not also the gateway it may be reached through
    return f" (that is {', '.join(named)})" if named else ""


async def _restore(job) -> str:  # type: ignore[no-untyped-def]
    try:
        return await job.stager.restore()
    except Exception as exc:  # never hide the first error behind a second
        return f"your config could not be put back ({exc}): copy {job.record.original_path} over " \
               f"{job.s.config_path}"


def parse_leads(text: str | None, axes: Sequence[str]) -> dict[str, float]:
    """``10`` (every axis) or ``X=10,Y=5`` → {axis: lead mm}."""
    if not text:
        return {}
    if "=" not in text:
        return dict.fromkeys(axes, _lead(text, text))
    out = {}
    for item in text.split(","):
        name, _, value = item.partition("=")
        if name.strip() not in axes:
            raise ValueError(f"--lead-mm {item!r}: {name.strip()!r} is not a commissioned axis "
                             f"({', '.join(axes)})")  # fmt: skip
        out[name.strip()] = _lead(value, item)
    return out


def _lead(value: str, item: str) -> float:
    try:
        lead = float(value)
    except ValueError:
        lead = math.nan
    if not (math.isfinite(lead) and lead > 0):
        raise ValueError(f"--lead-mm {item!r}: the lead in mm above 0, as 10 (every axis) or "
                         "X=10,Y=5")  # fmt: skip
    return lead
