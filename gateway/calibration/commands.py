"""The calibration subcommands of `compgw`: calibrate, fit, report, export.

`gateway.cli` calls :func:`add_parsers`; each command returns an exit code
(0 ok, 1 bad input, 2 usage, 3 runtime fault). The work is done by the modules beside this
one; here are only argument handling and printing.
"""

from __future__ import annotations

import argparse
import asyncio
import os
import shlex
import signal
import subprocess
import sys
from collections.abc import Awaitable, Callable
from pathlib import Path
from typing import Any

from ..cli_args import above
from ..compensation.errors import CompensationError, TableError
from ..config import ConfigError, GatewayConfig
from ..event_loop import run_loop
from .cli_common import (
    EXIT_BAD_INPUT,
    EXIT_OK,
    EXIT_RUNTIME,
    FROM_CONFIG,
    err,
    load,
    progress_bar,
    refuse_eeprom_wear,
    until_stopped,
)

CALIBRATE_HELP = """\
Run a calibration plan through a running gateway and append the readings to a raw CSV.

Compensation off (identification) means the gateway runs an identification config:
write one with --identify-config OUT.yaml (the config without pitch, backlash, cyclic and
planar; thermal kept) and start `compgw run -c OUT.yaml`; or point --gateway at the drives
themselves. Compensation on means the gateway runs the config whose tables you verify.
--verify --iterate N re-runs the plan with compensation on, folds the residual into the
tables the config references, has the gateway reload them (--reload-pid PID sends
SIGHUP, --reload-cmd runs a command), up to N times or until within --tolerance-um, then
measures the verification plan (targets between the calibration targets).
--cyclic AXIS --lead-mm L: dense scans for the once-per-lead screw error (issue 7); fit the
raw file together with the axis's ISO raw file (`compgw fit X_id.csv X_cyclic.csv`).
Interrupted runs resume when the same command is run again; Ctrl-C loses nothing measured.
Instruments (--laser, --angle, --xy-device): KIND:ARGS, one syntax for every kind: a
Modbus device in compgw's register layout (HOST:PORT:UNIT, as the sim's laser), a bridge
around your laser's SDK (bridge:tcp:HOST:PORT, bridge:cmd:COMMAND), a gauge typed at the
prompt (manual[:UNIT][:deviation]), or your laser software's own recording or capture,
read after the moves (recording:DIR[:UNIT[:-1]], capture:MAPPING.yaml:DIR): compgw stands
--dwell-s at each stop, then waits for the file: docs/instruments.md."""


# -- calibrate ----------------------------------------------------------------------------------
def _targets_said(plan: Any, config: Any) -> str:
    """A plan's measured targets in words, for entering them into a laser's software."""
    unit = "°" if all(a in config.axes and config.axes[a].rotary for a in plan.axes) else " mm"
    targets = list(dict.fromkeys(float(m.target_mm[0]) for m in plan.moves if m.measured))
    said = (", ".join(f"{t:g}" for t in targets) if len(targets) <= 24 else
            f"{len(targets)} targets from {min(targets):g} to {max(targets):g}")  # fmt: skip
    return (f"{sum(m.measured for m in plan.moves)} readings of {', '.join(plan.axes)} at "
            f"{said}{unit}")


def _join_capture(plan: Any, export: str, layout_path: str, raw: Path,
                  meta: dict[str, str]) -> Any:  # fmt: skip
    """Join a capture export laid out as ``layout_path`` says: every reading matched with
    the plan's, row by row (a missing or added one refused, never shifted)."""
    from ..instruments.capture import CaptureError, PlanStop, load_layout, read_export
    from .plans.runner import join_values

    if len(plan.axes) != 1:
        raise TableError(f"--join-layout: a capture export reads one axis; the plan moves "
                         f"{', '.join(plan.axes)}")  # fmt: skip
    stops = [PlanStop(m.target_mm[0], m.run, m.direction) for m in plan.moves if m.measured]
    try:
        values = read_export(export, load_layout(layout_path), stops)
    except CaptureError as exc:
        raise TableError(str(exc)) from None
    axis = plan.axes[0]
    return join_values(plan, [{axis: float(v)} for v in values], export, raw, meta)



def _floats(text: str) -> list[float]:
    return [float(v) for v in text.replace(",", " ").split()]


def _range(text: str) -> tuple[float, float]:
    lo, _, hi = text.partition(",")
    return float(lo), float(hi)


def _overrun(args: argparse.Namespace, rotary: bool = False) -> float:
    """--overrun-mm as given, else 3 mm (a rotary axis's ISO runs: ROTARY_OVERRUN_DEG; a
    swing head's 3° is a ninth of it)."""
    if args.overrun_mm is not None:
        return float(args.overrun_mm)
    from .plans.plans import ROTARY_OVERRUN_DEG

    return ROTARY_OVERRUN_DEG if rotary else 3.0


def make_plan(args: argparse.Namespace, config: GatewayConfig, verification: bool = False):  # type: ignore[no-untyped-def]
    """The plan the options describe (``verification``: its verification variant), its
    targets on each axis' pulse grid when the machine is driven (not for ``--join``)."""
    from .plans.plans import Plan, snap_to_pulses

    plan = _described_plan(args, config, verification)
    if plan is None:
        return plan
    if all(a in config.axes and config.axes[a].rotary for a in plan.axes) \
            and "unit" not in dict(plan.meta):  # fmt: skip
        plan = Plan(plan.kind, plan.axes, plan.moves, (*plan.meta, ("unit", "deg")))
    if getattr(args, "join", None):
        return plan
    return snap_to_pulses(plan, {name: axis.pulse_mm for name, axis in config.axes.items()})


def _described_plan(args: argparse.Namespace, config: GatewayConfig, verification: bool):  # type: ignore[no-untyped-def]
    from .fitting.plans_scans import cyclic_plan, warmup_plan
    from .fitting.takeup_fit import takeup_plan
    from .plans.plans import backlash_plan, iso230_linear_plan, read_plan
    from .plans.xy import xy_grid_plan, xy_verification_plan

    def travel(axis: str) -> tuple[float, float]:
        if axis not in config.axes:
            raise TableError(f"axis {axis!r} is not in the gateway config")
        return config.axes[axis].travel_mm

    if args.plan:
        return read_plan(args.plan) if not verification else (
            read_plan(args.verify_plan) if args.verify_plan else None
        )
    if args.iso:
        rotary = args.iso in config.axes and config.axes[args.iso].rotary
        return iso230_linear_plan(
            args.iso, travel(args.iso), step_mm=args.step_mm, runs=args.runs, seed=args.seed,
            lead_mm=args.lead_mm, overrun_mm=_overrun(args, rotary), verification=verification,
        )  # fmt: skip
    if args.backlash:
        if verification:
            return None
        lo, hi = travel(args.backlash)
        if config.axes[args.backlash].rotary:
            # seed 000 in angle: 1° take-up, 1° on and back, 1° from the ends
            return backlash_plan(args.backlash, (lo, hi), takeup_mm=1.0, away_mm=1.0,
                                 margin_mm=1.0)  # fmt: skip
        return backlash_plan(args.backlash, (lo, hi))
    if args.takeup:
        if verification:
            return None
        lo, hi = travel(args.takeup)
        if config.axes[args.takeup].rotary:
            raise TableError(f"--takeup {args.takeup}: a linear axis only (in mm)")
        return takeup_plan(args.takeup, (lo, hi))
    if args.cyclic:
        if verification:
            return None
        if args.lead_mm is None:
            raise TableError("--cyclic needs --lead-mm (the screw lead: the error's period)")
        return cyclic_plan(args.cyclic, travel(args.cyclic), args.lead_mm, args.stations,
                           args.per_lead, args.leads, args.takeup_mm)  # fmt: skip
    if args.xy:
        if config.planar is None:
            raise TableError("--xy needs a planar section in the gateway config")
        ax, ay = config.planar.axes
        xr = args.x_range or _inset(travel(ax), _overrun(args))
        yr = args.y_range or _inset(travel(ay), _overrun(args))
        nx, ny = args.grid
        low = (travel(ax)[0], travel(ay)[0])
        approach = args.approach_mm or None
        if verification:
            return xy_verification_plan(xr, yr, nx, ny, (ax, ay), approach_mm=approach,
                                        lower_mm=low)  # fmt: skip
        return xy_grid_plan(xr, yr, nx, ny, (ax, ay), runs=args.grid_runs,
                            approach_mm=approach, lower_mm=low)  # fmt: skip
    if args.warmup:
        if verification:
            return None
        lo, hi = travel(args.warmup)
        ref = args.reference_mm if args.reference_mm is not None else hi - _overrun(args)
        return warmup_plan(args.warmup, (lo, hi), args.speed_mm_s, args.duration_s, ref,
                           args.measure_every, dwell_s=args.dwell_s)  # fmt: skip
    raise TableError("give a plan: --plan FILE, --iso AXIS, --backlash AXIS, --takeup AXIS, "
                     "--cyclic AXIS, --xy or --warmup AXIS")


def _inset(travel: tuple[float, float], margin: float) -> tuple[float, float]:
    return travel[0] + margin, travel[1] - margin


def _reload_fn(args: argparse.Namespace) -> Callable[[], Awaitable[None]]:
    async def reload() -> None:
        if args.reload_pid:
            os.kill(args.reload_pid, signal.SIGHUP)
        elif args.reload_cmd:
            subprocess.run(shlex.split(args.reload_cmd), check=True)
        else:
            raise TableError("--iterate needs --reload-pid PID or --reload-cmd CMD "
                             "so the gateway loads the folded tables")  # fmt: skip
        if args.reload_wait_s:
            await asyncio.sleep(args.reload_wait_s)

    return reload


def calibrate(
    args: argparse.Namespace, reload: Callable[[], Awaitable[None]] | None = None
) -> int:
    """``compgw calibrate``; ``reload`` overrides --reload-pid/--reload-cmd (tests)."""
    from .measuring.devices import device_option, given_kinds
    from .measuring.machine import Endpoint, MachineError, MotionSettings
    from .measuring.session import (
        Instruments,
        Session,
        format_figures,
        identify_config_text,
        within,
    )
    from .measuring.session import iterate as iterate_rounds
    from .plans.plans import write_plan
    from .plans.runner import join_readings

    try:
        config, config_dir = load(args.config)
        moved = [a for a in (args.iso, args.backlash, args.takeup, args.cyclic, args.warmup)
                 if isinstance(a, str) and a in config.axes]  # fmt: skip
        if args.xy or args.plan:
            moved = list(config.axes)
        refuse_eeprom_wear(config, moved, "a calibration")
        if args.identify_config:
            from ..formats import atomic_write_text

            atomic_write_text(args.identify_config, identify_config_text(Path(args.config)))
            print(f"identification config written to {args.identify_config}")
            if not (args.plan or args.iso or args.backlash or args.takeup or args.cyclic
                    or args.xy or args.warmup):
                return EXIT_OK
        rotary = [a for a in (args.iso, args.backlash, args.cyclic) if a and a in config.axes
                  and config.axes[a].rotary]  # fmt: skip
        if args.verify and rotary:  # its figures are millidegrees, its tolerance µm
            raise TableError(f"--verify judges in µm: axis {rotary[0]} is rotary; commission "
                             "it (compgw commission --tolerance-arcsec), or judge its runs with "
                             "compgw report, in arcseconds")  # fmt: skip
        plan = make_plan(args, config)
        if args.verify and args.iterate > 0 and len(plan.axes) == 1:
            _check_foldable(config, config_dir, plan.axes[0])
        if args.save_plan:
            write_plan(args.save_plan, plan)
        if not args.join:  # how long the machine will be busy, before it starts
            from .plans.plans import plan_time_s

            minutes = plan_time_s(plan, args.estimate_speed_mm_s, args.estimate_stop_s) / 60
            where = (f" at stations {dict(plan.meta)['stations_mm']} mm"
                     if plan.kind == "cyclic" else "")  # fmt: skip
            turning = all(a in config.axes and config.axes[a].rotary for a in plan.axes)
            speed = f"{args.estimate_speed_mm_s:g} {'deg/s' if turning else 'mm/s'}"
            print(f"{plan.kind} plan: {sum(m.measured for m in plan.moves)} readings{where} "
                  f"in {len(plan.moves)} moves; about {minutes:.1f} min of machine time at "
                  f"{speed} and {args.estimate_stop_s:g} s per reading")  # fmt: skip
        if args.save_plan and args.gateway is None and not args.join:
            print(f"wrote {args.save_plan}: {_targets_said(plan, config)}")  # for another
            return EXIT_OK  # software (a laser's capture), nothing runs
        if args.raw is None:
            raise TableError("--raw FILE is required (where the readings go)")
        raw = Path(args.raw)
        if args.join:
            meta = {"compensation": args.compensation}
            if args.join_layout:
                summary = _join_capture(plan, args.join, args.join_layout, raw, meta)
            else:
                summary = join_readings(plan, args.join, raw, meta)
            print(f"joined {args.join}: {raw} ({summary.measured_now} new points)")
            return EXIT_OK
        if args.gateway is None:
            raise TableError("--gateway HOST:PORT is required (or --join FILE offline)")
        if rotary and args.angle is None:
            raise TableError(f"axis {rotary[0]} is rotary: its readings come from the angle "
                             "instrument, --angle HOST:PORT:UNIT (the laser reads linear "
                             "axes)")  # fmt: skip
        park = {}
        for item in args.park or []:
            name, _, value = item.partition("=")
            park[name] = float(value)
        laser, laser_kind = device_option("--laser", args.laser)
        angle, angle_kind = device_option("--angle", args.angle)
        xy, xy_kind = device_option("--xy-device", args.xy_device)
        delta_a, delta_a_kind = device_option("--delta-a", args.delta_a)
        if delta_a_kind is not None and delta_a_kind.reads_later:
            raise ValueError(f"--delta-a {delta_a_kind.text}: a Δa sensor is read at each "
                             "stop: Modbus, a bridge or manual")  # fmt: skip
        session = Session(
            config, config_dir, Endpoint.parse(args.gateway),
            Instruments(
                laser=laser,
                laser_axes=args.laser_axes.split(",") if args.laser_axes else None,
                xy=xy,
                delta_a=delta_a,
                angle=angle,
                angle_axes=args.angle_axes.split(",") if args.angle_axes else None,
                wait_stable=not args.no_wait_stable,
                kinds=given_kinds(laser=laser_kind, angle=angle_kind, xy=xy_kind,
                                  delta_a=delta_a_kind),
                dwell_s=args.dwell_s or 3.0,
                wait_start=sys.stdin.isatty() if args.wait_start is None else args.wait_start,
            ),
            MotionSettings(args.in_position_bit, args.moving_bit, args.alarm_bit,
                           args.in_position_pulses, args.timeout_s,
                           request_timeout_s=args.request_timeout_s),
            park,
        )  # fmt: skip
    except (ConfigError, TableError, CompensationError, ValueError, OSError) as exc:
        err("calibrate", exc)
        return EXIT_BAD_INPUT

    async def body() -> int:
        bar = progress_bar((not args.no_progress and sys.stderr.isatty()) or args.progress)
        with bar as progress:
            task = None
            if progress is not None:
                task = progress.add_task(plan.kind, total=len(plan.moves))

                def update(done: int, total: int) -> None:
                    progress.update(task, completed=done, total=total)

                session.progress = update
            if not args.verify:
                summary = await session.run(plan, raw, args.compensation)
                if progress is not None:
                    progress.stop()
                print(f"{raw}: {summary.total_moves} moves, resumed at move "
                      f"{summary.resumed_at}, {summary.measured_now} points measured now")
                return EXIT_OK
            vplan = make_plan(args, config, verification=True)
            if vplan is not None and not args.verify_plan:  # for a before-run (README)
                vpath = raw.with_name(f"{raw.stem}.verify.plan")
                write_plan(vpath, vplan)
                print(f"verification plan: {vpath} (for a before-run at the same targets: "
                      f"calibrate --plan {vpath.name} --compensation off)")  # fmt: skip
            rounds = await iterate_rounds(
                session, plan, raw, args.iterate, args.tolerance_um,
                reload or _reload_fn(args), print, verification=vplan,
            )  # fmt: skip
            last = rounds[-1]
            print(f"{len(rounds)} round(s); last verification: "
                  f"{last.verify_path or last.raw_path}")  # fmt: skip
            if not within(last.judged, args.tolerance_um):
                where = "between the calibration targets" if vplan is not None else \
                    "at the calibration targets"
                err("calibrate", f"tolerance {args.tolerance_um:g} µm not met {where}: "
                     f"{format_figures(last.judged)}")  # fmt: skip
                return EXIT_BAD_INPUT
            return EXIT_OK

    try:
        return run_loop(until_stopped(body()))
    except KeyboardInterrupt:
        err("calibrate", f"interrupted; every reading so far is in {args.raw}: run the same "
             "command again to resume")  # fmt: skip
        return EXIT_RUNTIME
    except (TableError, CompensationError, ConfigError) as exc:
        err("calibrate", exc)
        return EXIT_BAD_INPUT
    except (MachineError, OSError, subprocess.CalledProcessError) as exc:
        err("calibrate", exc)
        return EXIT_RUNTIME


def _add_calibrate(sub: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    p = sub.add_parser("calibrate", help="calibration: run a plan, measure, iterate",
                       description=CALIBRATE_HELP,
                       formatter_class=argparse.RawDescriptionHelpFormatter)  # fmt: skip
    p.add_argument("-c", "--config", required=True, help="gateway YAML config")
    p.add_argument("--gateway", metavar="HOST:PORT", help="the running gateway (or the drives)")
    p.add_argument("--raw", metavar="FILE", help="raw CSV to append to (resumed if present)")
    g = p.add_argument_group("plan (one of)")
    g.add_argument("--plan", metavar="FILE",
                   help="a plan CSV (see gateway/calibration/plans/plans.py)")
    g.add_argument("--iso", metavar="AXIS", help="ISO 230-2 linear test of AXIS")
    g.add_argument("--backlash", metavar="AXIS", help="seed 000 backlash procedure on AXIS")
    g.add_argument("--takeup", metavar="AXIS",
                   help="the reversal ladder at seed 000's places: how much of the lost "
                        "motion a short reversal shows (fit it with the --backlash run)")
    g.add_argument("--cyclic", metavar="AXIS",
                   help="dense scans of AXIS for the once-per-lead screw error (needs "
                        "--lead-mm; issue 7)")  # fmt: skip
    g.add_argument("--xy", action="store_true", help="XY grid of the config's planar axes")
    g.add_argument("--warmup", metavar="AXIS", help="warm-up run of AXIS (thermal)")
    g.add_argument("--save-plan", metavar="FILE", help="also write the plan used")
    g.add_argument("--verify-plan", metavar="FILE", help="verification plan for --plan --verify")
    o = p.add_argument_group("plan parameters")
    o.add_argument("--step-mm", type=above(0, "mm"), default=25.0, help="ISO target spacing (25)")
    o.add_argument("--runs", type=above(0, "runs", int), default=5,
                   help="ISO bidirectional runs (5)")
    o.add_argument("--seed", type=int, default=0, help="seed of the uneven target offsets")
    o.add_argument("--lead-mm", type=float,
                   help="screw lead: ISO spacings kept off its multiples; --cyclic's period")
    o.add_argument("--stations", type=_floats, metavar="MM[,MM...]",
                   help="--cyclic: scan centres (default 15 %%, 50 %%, 85 %% of the travel)")
    o.add_argument("--per-lead", type=above(0, "points", int), default=16,
                   help="--cyclic: points per lead (16)")
    o.add_argument("--leads", type=above(0, "leads"), default=2.0,
                   help="--cyclic: leads per scan (2)")
    o.add_argument("--takeup-mm", type=float, default=1.0,
                   help="--cyclic: take-up move before each scan direction (1; > backlash)")
    o.add_argument("--estimate-speed-mm-s", type=float, default=100.0,
                   help="speed for the machine-time estimate printed before a run (100)")
    o.add_argument("--estimate-stop-s", type=float, default=2.0,
                   help="settling + reading per point for the estimate (2)")
    o.add_argument("--overrun-mm", type=float, default=None,
                   help="overrun / margin (3 mm; a rotary axis's ISO runs: 0.5°)")
    o.add_argument("--grid", type=int, nargs=2, default=(9, 7), metavar=("NX", "NY"))
    o.add_argument("--grid-runs", type=above(0, "passes", int), default=1,
                   help="passes over the XY grid (1)")
    o.add_argument("--approach-mm", type=float, default=1.0,
                   help="XY: approach each point in + from this far below (0: serpentine)")
    o.add_argument("--x-range", type=_range, metavar="LO,HI")
    o.add_argument("--y-range", type=_range, metavar="LO,HI")
    o.add_argument("--speed-mm-s", type=float, default=100.0, help="warm-up speed (plan info)")
    o.add_argument("--duration-s", type=float, default=1800.0, help="warm-up duration (1800)")
    o.add_argument("--reference-mm", type=float, help="warm-up measuring position")
    o.add_argument("--measure-every", type=int, default=5, help="warm-up cycles per reading")
    o.add_argument("--dwell-s", type=float, default=0.0, help="warm-up dwell before reading; "
                   "with a recording or capture, the stand at each stop (default 3 s)")
    i = p.add_argument_group("instruments")
    i.add_argument("--wait-start", action=argparse.BooleanOptionalAction, default=None,
                   help="with a recording or capture: before the moves, wait for Enter (the "
                   "laser records) (default: at a terminal)")
    i.add_argument("--laser", metavar="KIND:ARGS", help="laser: HOST:PORT:UNIT (Modbus, int32 "
                   "nm at 2k for axis k), bridge:tcp:HOST:PORT, bridge:cmd:COMMAND, manual")
    i.add_argument("--laser-axes", metavar="X,Y", help="laser channel order (config order)")
    i.add_argument("--xy-device", metavar="KIND:ARGS", help="XY device: HOST:PORT:UNIT (X at "
                   "0, Y at 2), or a bridge")
    i.add_argument("--delta-a", metavar="KIND:ARGS", help="Δa sensor: HOST:PORT:UNIT[:ADDR] "
                   "(Modbus, int32 nm), a bridge (channel delta_a) or manual")
    i.add_argument("--angle", metavar="KIND:ARGS",
                   help="angle instrument of rotary axes: int32 µdeg at 2k (axis k)")
    i.add_argument("--angle-axes", metavar="A,C", help="its channel order (the rotary axes)")
    i.add_argument("--no-wait-stable", action="store_true", help="read the laser / XY device "
                   "at once (default: wait for their stable flags, 2N+k / 4-5)")  # fmt: skip
    i.add_argument("--join", metavar="FILE", help="offline: join a laser system's CSV export")
    i.add_argument("--join-layout", metavar="MAPPING.yaml",
                   help="the export's layout (columns, units, sign): your laser software's "
                   "capture export as it is (config/capture-generic.yaml)")
    m = p.add_argument_group("motion")
    m.add_argument("--compensation", choices=["off", "on"], default="off",
                   help="what the gateway applies (recorded in the raw file; see above)")
    m.add_argument("--identify-config", metavar="OUT", help="write the identification config")
    m.add_argument("--park", action="append", metavar="AXIS=MM", help="move there first")
    m.add_argument("--in-position-bit", type=int, default=FROM_CONFIG,
                   help="the drive status word's in-position bit (default: the axis's "
                   "registers.status.in_position_bit, else 4)")
    m.add_argument("--moving-bit", type=int, default=FROM_CONFIG,
                   help="its moving bit (default: registers.status.moving_bit, else 2)")
    m.add_argument("--alarm-bit", type=int, default=FROM_CONFIG,
                   help="its alarm bit (default: registers.status.alarm_bit, else 0)")
    m.add_argument("--in-position-pulses", type=float, default=2.0)
    m.add_argument("--timeout-s", type=above(0, "s"), default=120.0, help="per move")
    m.add_argument("--request-timeout-s", type=above(0, "s"), default=2.0,
                   help="per request to the gateway or an instrument (s, default 2)")
    m.add_argument("--no-progress", action="store_true")
    m.add_argument("--progress", action="store_true", help="progress bar even without a tty")
    v = p.add_argument_group("verify and iterate (seed 001)")
    v.add_argument("--verify", action="store_true", help="compensation on: iterate, verify")
    v.add_argument("--iterate", type=above(-1, "folds", int), default=0, metavar="N",
                   help="fold at most N times")
    v.add_argument("--tolerance-um", type=above(0, "µm"), default=2.0, metavar="T")
    v.add_argument("--reload-pid", type=int, help="gateway pid: SIGHUP after writing tables")
    v.add_argument("--reload-cmd", help="command that makes the gateway reload")
    v.add_argument("--reload-wait-s", type=float, default=0.0, help="pause after reloading")
    p.set_defaults(func=calibrate)


def _cmd_report(args: argparse.Namespace) -> int:
    from .reporting.report import main as report_main

    return report_main(args)


def _cmd_export(args: argparse.Namespace) -> int:
    from .reporting.export import main as export_main

    return export_main(args)


def add_parsers(sub: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    """Register the calibration subcommands on the `compgw` parser."""
    _add_calibrate(sub)
    from .commands_fit import add_parser as add_fit

    add_fit(sub)
    from .commissioning.cli import add_parser as add_commission

    add_commission(sub)
    from .reporting.export import add_arguments as export_args
    from .reporting.report import add_arguments as report_args

    p = sub.add_parser("report", help="calibration: ISO 230-2 report (HTML, PNG, JSON)")
    report_args(p)
    p.set_defaults(func=_cmd_report)
    p = sub.add_parser("export", help="calibration: tables to/from LinuxCNC, CSV, FANUC")
    export_args(p)
    p.set_defaults(func=_cmd_export)


def _check_foldable(config: GatewayConfig, config_dir: Path, axis: str) -> None:
    """``--verify --iterate`` folds each round's residual into the axis's own pitch table:
    it must name one, and it must exist (before anything moves, not after the first
    round)."""
    from .fitting.outputs import pitch_path, pitch_spec

    if pitch_spec(config, axis) is None:
        raise TableError(f"--verify --iterate folds into axis {axis}'s pitch table, and "
                         f"axes.{axis}.compensation.pitch names none: fit one first (compgw "
                         "fit) and name it in the config, or verify without --iterate")
    path, _ = pitch_path(config, config_dir, axis)
    if not path.exists():
        raise TableError(f"axes.{axis}.compensation.pitch.file: {path}: file not found")
