"""Accuracy of a calibration workflow on machines its authors never saw.

For each machine: ``compgw sim --random-machine SEED --roughness R`` (or ``--real-machine
NAME``) writes it; ``compgw sim`` and ``compgw run`` start as processes; the workflow
(``--workflow``, bench/workflows.py) calibrates it with ``compgw`` commands only; then the
independent evaluator (bench/evaluate.py) measures the same random targets with the
uncalibrated config (before) and the calibrated one (after), reading the truth from the
sim's instruments and computing ISO 230-2 itself.

Reported per machine and as median / worst per group (smooth, rough, real):
E cut (worst axis) and the most any correction could cut there (`max %`: 1 − E_floor / E
before, E_floor the range a perfect correction reads from the after-run's own scatter and
the drive's finest step),
A − R after (worst axis), XY maximum vector error cut at random points,
off-grid RMS after (random positions and short steps, worst axis), thermal change after a
warm-up cycle with compensation (largest axis; `-` for a machine without a thermal sensor:
then nothing can correct it and the figure shows the drift).

    python bench/accuracy.py                      # 20 random (10 smooth, 10 rough) + real
    python bench/accuracy.py --machines 4 --real none --jobs 2
    python bench/accuracy.py --json > accuracy.json
"""

from __future__ import annotations

import argparse
import asyncio
import concurrent.futures
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
import traceback
from pathlib import Path
from typing import Any

import numpy as np
import workflows
import yaml
from evaluate import e_floor_um, evaluate, evaluate_warm, plan, xy_floor_um
from workflows import WORKFLOWS, MachineRun, compgw_argv

REAL_MACHINES = ("slit-11358", "slit-11359", "slit-11361", "mcu1025", "slit-11360-iso",
                 "slit-11358-retest", "sdss-1396", "sdss-1597", "sdss-2130")  # fmt: skip


def machine_list(count: int, seed: int, real: str) -> list[tuple[str, list[str]]]:
    """(label, `compgw sim` arguments): half smooth, half rough on the same seeds, then real."""
    out = []
    for k in range(count):
        s, rough = seed + k // 2, k % 2 == 1
        roughness = "rough" if rough else "smooth"
        out.append((f"{roughness}-{s}", ["--random-machine", str(s), "--roughness", roughness]))
    names = REAL_MACHINES if real == "all" else () if real == "none" else real.split(",")
    out += [(f"real-{n}", ["--real-machine", n]) for n in names]
    return out


#: what ``--without`` can take out of every machine's truth (sim.yaml keys per axis)
ABLATIONS = {"thermal": ("thermal", "heat"), "settling": ("settling",),
             "stick_slip": ("stick_slip",), "takeup": ("lost_motion",), "cyclic": ("cyclic",)}


def ablate(sim_yaml: Path, without: list[str]) -> None:
    """Remove the named structures from a machine's truth (to see what each one costs).
    Thermal: the screw no longer heats (the sensors stay, reading nothing)."""
    data = yaml.safe_load(sim_yaml.read_text())
    for errs in data["sim"]["machine"].values():
        for name in without:
            for key in ABLATIONS[name]:
                if key in errs and name == "thermal":
                    errs[key]["heat_K_per_m" if key == "thermal" else "drag_torque_Nm"] = 0.0
                else:
                    errs.pop(key, None)
    sim_yaml.write_text(yaml.safe_dump(data, sort_keys=False))


def reseed(sim_yaml: Path, sim_seed: int) -> None:
    """Another draw of the machine's noise (scatter, stick-slip, the instruments): the same
    truth, the sim's ``seed`` set to ``sim_seed``."""
    data = yaml.safe_load(sim_yaml.read_text())
    data["sim"]["seed"] = sim_seed
    sim_yaml.write_text(yaml.safe_dump(data, sort_keys=False))


#: the first words of commission's verdict line, the first that fits a note is what it said
VERDICTS = ("NO VERDICT", "NOT within", "UNDECIDED", "WITHIN")


def run_machine(label: str, gen_args: list[str], workflow: str, root: Path, seed: int,
                without: list[str] | None = None, judge_repeats: int = 1,
                sim_seed: int | None = None, oracle: bool = False, warm: bool = False,
                judge_seeds: int = 1) -> dict[str, Any]:
    """Generate, calibrate and evaluate one machine; a dict of its figures (or its error);
    with ``oracle`` also judge a perfect pitch table in place of the calibrated one; with
    ``warm`` also the calibrated machine as read after the judge's own warm-up; with
    ``judge_seeds`` > 1 also before and after at that many judges' targets and parks in all
    (``seed`` + 1, ...), each with its own draw (``judgings``)."""
    t0 = time.monotonic()
    mdir = root / label
    shutil.rmtree(mdir, ignore_errors=True)
    subprocess.run([*compgw_argv(), "sim", *gen_args, "--out", str(mdir)], check=True,
                   capture_output=True, text=True)  # fmt: skip
    if without:
        ablate(mdir / "sim.yaml", without)
    if sim_seed is not None:
        reseed(mdir / "sim.yaml", sim_seed)
    out: dict[str, Any] = {"machine": label, "group": label.split("-")[0]}
    run = None
    try:
        run = MachineRun.start(mdir, mdir / "work", workflows.LASER_KIND,
                               (workflows.COMMISSION_AXES or [None])[0])  # fmt: skip
        result = WORKFLOWS[workflow](run)
        out["workflow_s"] = round(time.monotonic() - t0, 1)
        out["notes"] = result.notes
        plans = [plan(run.machine, result.calibration_targets_mm, seed + k)
                 for k in range(max(1, judge_seeds))]  # fmt: skip
        the_plan = plans[0]

        async def cool() -> None:
            await asyncio.to_thread(run.cool_down)

        judgings = []  # each judge's targets, parks and zone, before and after
        for k, each in enumerate(plans):
            phases = {"seed": seed + k}
            for phase, config in (("before", run.base_config()), ("after", result.config)):
                run.use(config)
                phases[phase] = asyncio.run(
                    evaluate(run.machine, each, run.sim_port, run.gateway_port, cool))
            judgings.append(phases)
        out.update({p: judgings[0][p] for p in ("before", "after")}, judge_seed=seed)
        out["judgings"] = judgings[1:]  # (the first judge's are before and after)
        # the judge again on the same tables and targets (fresh stops, a cool-down first):
        # how much of a figure's run-to-run spread is the judge's own
        out["after_repeats"] = [out["after"]] + [
            asyncio.run(evaluate(run.machine, the_plan, run.sim_port, run.gateway_port, cool))
            for _ in range(judge_repeats - 1)]  # fmt: skip
        if oracle:  # a perfect pitch table judged at the same targets, in the same run
            from static_chain import oracle_config  # imports sim and gateway: only here

            calibrated = run.write_config("gw.calibrated.yaml", result.config)
            run.use(oracle_config(mdir, calibrated, run.work / "oracle"))
            out["oracle_repeats"] = [
                asyncio.run(evaluate(run.machine, the_plan, run.sim_port, run.gateway_port, cool))
                for _ in range(judge_repeats)]  # fmt: skip
            out["oracle"] = out["oracle_repeats"][0]
            run.use(result.config)
        if warm:  # last: the calibrated config, after the judge's own mixed work
            out["after_warm"] = asyncio.run(evaluate_warm(run.machine, the_plan, run.sim_port,
                                                          run.gateway_port, cool))  # fmt: skip
        out["said"] = next((w for n in result.notes for w in VERDICTS if w in n), None)
        out["said_figures"] = result.said  # (its after-run: what the verdict rests on)
        # the sensor given to the workflow (--no-sensors: none, whatever the machine has)
        out["sensor"] = ("none" if workflows.NO_SENSORS
                         else run.machine.get("thermal_sensor", "none"))  # fmt: skip
        thermal = {a: ax.get("compensation", {}).get("thermal") or {}
                   for a, ax in result.config["axes"].items()}  # fmt: skip
        out["sensor_axes"] = [a for a, th in thermal.items() if th.get("source")]
        out["model_axes"] = [a for a, th in thermal.items() if th.get("motion")]
        out["commands"] = len(run.commands)
        if workflow == "commission" and workflows.COMMISSION_AXES:  # judged on these alone
            out["judged_axes"] = list(workflows.COMMISSION_AXES)
        out["machine_h"] = (result.machine_time_s or run.machine_s) / 3600
        if run.manual_s is not None:
            out["manual_h"] = run.manual_s / 3600
    except Exception as exc:  # reported, the other machines go on
        out["error"] = f"{type(exc).__name__}: {exc}"
        out["traceback"] = traceback.format_exc(limit=3)
    finally:
        if run is not None:
            run.stop()
            out["unsynced"] = run.unsynced
    out["wall_s"] = round(time.monotonic() - t0, 1)
    return out


def print_unrepeatable(results: list[dict[str, Any]], say: Any = print) -> None:
    """Machines whose figures a second run need not repeat: a write through the gateway that
    went on before its thermal sources had read the machine's instant (bench/lockstep.py),
    or a request the judge asked again (it may have reached the machine twice)."""
    for r in results:
        judgings = [r[k] for k in ("before", "after", "oracle") if k in r]
        judgings += r.get("after_repeats", [])[1:] + r.get("oracle_repeats", [])[1:]
        judgings += [j[p] for j in r.get("judgings", []) for p in ("before", "after")]
        retries = sum(j.get("retries", 0) for j in judgings)
        if r.get("unsynced") or retries:
            say(f"{r['machine']}: not repeatable as run: {r.get('unsynced', 0)} write(s) "
                f"unsynced, {retries} judge request(s) asked again")


def _floor(fig: dict[str, Any]) -> float:
    if "s_um" not in fig:
        return float("nan")
    return e_floor_um(fig["s_um"], fig["targets"], fig["runs"], fig.get("step_um", 0.0))


def _xy_floor(after: dict[str, Any]) -> float:
    s = [after["axes"][n].get("s_um", float("nan")) for n in list(after["axes"])[:2]]
    if len(s) < 2 or not np.all(np.isfinite(s)):
        return float("nan")
    return xy_floor_um(s, after["xy"].get("points", 40))


def sensed_axes(r: dict[str, Any], axes: list[str]) -> list[str]:
    """The axes of ``axes`` the machine's sensor was given for (its ``sensor``: a Δa sensor
    reads X, temperature sensors sit on every screw), whatever the final config made of it."""
    return {"delta_a": ["X"], "temperature": list(axes)}.get(r.get("sensor", "none"), [])


def beyond_tolerance(r: dict[str, Any], tolerance_um: float) -> list[str]:
    """The axes whose E as the judge read it, cold (the after-run) or warm (``after_warm``,
    with --warm-judge), is beyond ``tolerance_um``."""
    axes = r.get("judged_axes") or list(r["after"]["axes"])
    warm = r.get("after_warm") or r["after"]
    return [n for n in axes
            if max(r["after"]["axes"][n]["E_um"], warm["axes"][n]["E_um"]) > tolerance_um]


def summary(r: dict[str, Any]) -> dict[str, float]:
    """The headline figures of one machine."""
    b, a = r["before"], r["after"]
    axes = r.get("judged_axes") or list(a["axes"])
    worst = min(axes, key=lambda n: 1 - a["axes"][n]["E_um"] / b["axes"][n]["E_um"])
    # the machine's sensors (machine.json), and the axes given heat from motion (none:
    # older runs listed those as sensor axes)
    sensed = sensed_axes(r, axes)
    modelled = r.get("model_axes", [n for n in r.get("sensor_axes", []) if n not in sensed])
    floor = _floor(a["axes"][worst])
    return {
        "E_axis": worst,  # the axis whose E fell least
        "E_before_um": b["axes"][worst]["E_um"],
        "E_after_um": a["axes"][worst]["E_um"],
        "E_cut_pct": 100 * (1 - a["axes"][worst]["E_um"] / b["axes"][worst]["E_um"]),
        # the most any correction could cut on that axis: E after a perfect one is the range
        # of its mean deviations' scatter (the after-run's own pooled s; nan for older runs)
        "E_floor_um": floor,
        "E_cut_max_pct": 100 * (1 - floor / b["axes"][worst]["E_um"]),
        "A_minus_R_um": max(a["axes"][n]["A_um"] - a["axes"][n]["R_um"] for n in axes),
        "R_um": max(a["axes"][n]["R_um"] for n in axes),
        "xy_before_um": b["xy"]["max_um"], "xy_after_um": a["xy"]["max_um"],
        "xy_cut_pct": 100 * (1 - a["xy"]["max_um"] / b["xy"]["max_um"]),
        # the most any correction could cut there: the largest of the points' scatter
        "xy_cut_max_pct": 100 * (1 - _xy_floor(a) / b["xy"]["max_um"]),
        "offgrid_rms_um": max(a["axes"][n]["offgrid_rms_um"] for n in axes),
        # as a laser zeroed at the first stop reads them (the truth's error there off)
        "offgrid_zeroed_rms_um": max(a["axes"][n].get("offgrid_zeroed_rms_um", np.nan)
                                     for n in axes),
        "xy_zeroed_after_um": a["xy"].get("max_zeroed_um", np.nan),
        # the plane's shape: its mean offset off (the constant a home and work offset take)
        "xy_centred_after_um": a["xy"].get("max_centred_um", np.nan),
        # a column and a row, the held axis's target sent again at every stop
        "xy_paths_after_um": max(a["xy"].get("paths_max_um") or [np.nan]),
        # thermal: on the axes with a sensor (all axes when there is none: the drift)
        "thermal_off_um": max(b["axes"][n]["thermal_um"] for n in sensed or axes),
        "thermal_on_um": max(a["axes"][n]["thermal_um"] for n in sensed or axes),
        "thermal_unsensed_um": max([a["axes"][n]["thermal_um"] for n in axes
                                    if n not in sensed] or [0.0]),
        # heat from motion (no sensor): its axes' drift after the warm-up, before and after
        "model_off_um": max([b["axes"][n]["thermal_um"] for n in modelled] or [np.nan]),
        "model_on_um": max([a["axes"][n]["thermal_um"] for n in modelled] or [np.nan]),
        "machine_h": r.get("machine_h", float("nan")),  # the workflow's plans, as estimated
        # against the manual workflow's plans on the same machine (when measured)
        "vs_manual": r.get("machine_h", float("nan")) / r.get("manual_h", float("nan")),
    }  # fmt: skip


HEAD = (f"{'machine':<24}{'E  before':>11}{'after':>7}{'cut %':>7}{'max':>6}{'A-R':>6}"
        f"{'XY before':>10}{'after':>7}{'cut %':>7}{'max':>6}{'offgrid':>8}{'therm off':>10}"
        f"{'on':>6}{'model':>7}{'mach h':>7}{'×ref':>6}{'off0':>6}{'XY0':>6}{'XYc':>6}  sensor")


def row(label: str, s: dict[str, Any], sensor: str) -> str:
    on = f"{s['thermal_on_um']:6.1f}" if sensor != "none" and "thermal_on_um" in s else f"{'-':>6}"
    return (f"{label:<24}{s.get('E_axis', ' '):>2}{s['E_before_um']:9.1f}{s['E_after_um']:7.2f}"
            f"{s['E_cut_pct']:7.1f}{s.get('E_cut_max_pct', float('nan')):6.1f}"
            f"{s['A_minus_R_um']:6.2f}{s['xy_before_um']:10.1f}{s['xy_after_um']:7.2f}"
            f"{s['xy_cut_pct']:7.1f}{s.get('xy_cut_max_pct', float('nan')):6.1f}"
            f"{s['offgrid_rms_um']:8.2f}{s['thermal_off_um']:10.1f}{on}"
            f"{s.get('model_on_um', float('nan')):7.1f}"
            f"{s.get('machine_h', float('nan')):7.2f}{s.get('vs_manual', float('nan')):6.2f}"
            f"{s.get('offgrid_zeroed_rms_um', float('nan')):6.2f}"
            f"{s.get('xy_zeroed_after_um', float('nan')):6.2f}"
            f"{s.get('xy_centred_after_um', float('nan')):6.2f}  {sensor}")  # fmt: skip


def group_stats(results: list[dict[str, Any]]) -> dict[str, dict[str, dict[str, float]]]:
    """Median and worst of each headline figure per group."""
    worst_is_min = {"E_cut_pct", "E_cut_max_pct", "xy_cut_pct", "xy_cut_max_pct"}
    out: dict[str, dict[str, dict[str, float]]] = {}
    for group in ("smooth", "rough", "real"):
        rows = [r for r in results if r["group"] == group and "summary" in r]
        if not rows:
            continue
        stats: dict[str, dict[str, float]] = {"median": {}, "worst": {}}
        for key in rows[0]["summary"]:
            if key == "E_axis":
                continue
            values = [r["summary"][key] for r in rows
                      if not (key == "thermal_on_um" and r["sensor"] == "none")
                      and not np.isnan(r["summary"][key])]  # fmt: skip
            if not values:
                continue
            stats["median"][key] = float(np.median(values))
            stats["worst"][key] = float(min(values) if key in worst_is_min else max(values))
        out[group] = stats
    return out


def print_repeats(results: list[dict[str, Any]], say: Any = print) -> None:
    """E cut and A − R of every judging of the same calibration (``--judge-repeats``)."""
    rows = [r for r in results if len(r.get("after_repeats", [])) > 1]
    if not rows:
        return
    say("\nthe judge again on the same tables (E cut % / A − R µm per judging):")
    for r in rows:
        figs = [summary({**r, "after": a}) for a in r["after_repeats"]]
        say(f"{r['machine']:<24}" + "  ".join(f"{f['E_cut_pct']:5.1f} / {f['A_minus_R_um']:4.2f}"
                                              for f in figs))  # fmt: skip
    for group in ("smooth", "rough", "real"):
        grp = [r for r in rows if r["group"] == group]
        if grp:
            n = min(len(r["after_repeats"]) for r in grp)
            med = [np.median([summary({**r, "after": r["after_repeats"][k]})["A_minus_R_um"]
                              for r in grp]) for k in range(n)]  # fmt: skip
            say(f"{group + ' median A − R':<24}" + "  ".join(f"{m:4.2f}" for m in med))


def print_warm(results: list[dict[str, Any]], tolerance_um: float, say: Any = print) -> None:
    """Per machine, each axis as the customer's laser reads it cold (the after-run) and
    after the judge's own 30 minutes of mixed work (``--warm-judge``), and whether what
    the workflow said agrees: never WITHIN where the judge reads beyond the tolerance."""
    rows = [r for r in results if "after_warm" in r]
    if not rows:
        return
    say("")
    say(f"as read, cold → after the judge's 30 min of mixed work (E, A µm); tolerance "
        f"{tolerance_um:g} µm")  # fmt: skip
    for r in rows:
        axes = r.get("judged_axes") or list(r["after"]["axes"])
        parts, beyond = [], beyond_tolerance(r, tolerance_um)
        for n in axes:
            cold, warm = r["after"]["axes"][n], r["after_warm"]["axes"][n]
            parts.append(f"{n} E {cold['E_um']:.2f} → {warm['E_um']:.2f}, A {cold['A_um']:.2f} "
                         f"→ {warm['A_um']:.2f} (R {warm['R_um']:.2f})")  # fmt: skip
        said = r.get("said")
        agree = "" if said is None else (
            f"; it said {said}" + (": the judge reads beyond on " + ", ".join(beyond)
                                   if said == "WITHIN" and beyond else ""))  # fmt: skip
        say(f"{r['machine']:<24}" + "; ".join(parts) + agree)


def print_oracle(results: list[dict[str, Any]], say: Any = print) -> None:
    """E cut on each machine's worst axis, the calibration's and a perfect table's, judged at
    the same targets in the same run (``--oracle``)."""
    rows = [r for r in results if "oracle" in r and "summary" in r]
    if not rows:
        return
    say("\na perfect pitch table at the same targets (E cut % on the axis that fell least, "
        "each judging, calibrated / perfect; XY cut %):")
    for r in rows:
        axis = r["summary"]["E_axis"]
        before = r["before"]["axes"][axis]["E_um"]

        def cuts(judgings: list[dict[str, Any]], axis: str = axis, before: float = before
                 ) -> str:  # fmt: skip
            return " ".join(f"{100 * (1 - j['axes'][axis]['E_um'] / before):5.1f}"
                            for j in judgings)  # fmt: skip

        xy = 100 * (1 - r["oracle"]["xy"]["max_um"] / r["before"]["xy"]["max_um"])
        say(f"{r['machine']:<24}{axis} {cuts(r.get('after_repeats', [r['after']]))} / "
            f"{cuts(r.get('oracle_repeats', [r['oracle']]))}   "
            f"XY {r['summary']['xy_cut_pct']:5.1f} / {xy:5.1f}")


def print_table(data: dict[str, Any]) -> int:
    """The table of a saved ``--json`` output (figures recomputed from the raw phases)."""
    print(HEAD)
    results = data["machines"]
    for r in results:
        if "error" in r:
            print(f"{r['machine']:<24}failed: {r['error']}")
            continue
        r["summary"] = summary(r)
        print(row(r["machine"], r["summary"], r["sensor"]))
    print_repeats(results)
    print_oracle(results)
    print_warm(data["machines"], data.get("tolerance_um", 2.0))
    print()
    for group, st in group_stats(results).items():
        for which in ("median", "worst"):
            print(row(f"{group} {which}", st[which], "any"))
    print(f"wall time {data['wall_s'] / 60:.1f} min")
    return 0


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter,
                                     epilog=__doc__.split("\n\n", 1)[1])  # fmt: skip
    parser.add_argument("--workflow", choices=sorted(WORKFLOWS), default="manual")
    parser.add_argument("--machines", type=int, default=20,
                        help="random machines, half smooth and half rough (20)")
    parser.add_argument("--seed", type=int, default=0, help="first random machine seed (0)")
    parser.add_argument("--real", default="all",
                        help="real-data machines: all, none, or NAME[,NAME...] (all)")
    parser.add_argument("--jobs", type=int, default=1, help="machines in parallel (1)")
    parser.add_argument("--keep", type=Path, help="keep every machine's files in this directory")
    parser.add_argument("--only", metavar="LABEL[,LABEL...]",
                        help="run only these machines (labels as printed, e.g. rough-3)")
    parser.add_argument("--sim-seed", type=int, default=None, metavar="N",
                        help="the sim's seed for every machine: another draw of its noise on "
                             "the same truth (default: the machine's own)")
    parser.add_argument("--without", metavar="WHAT[,WHAT...]",
                        help="take structure out of every machine's truth to see what it costs: "
                             + ", ".join(ABLATIONS))
    parser.add_argument("--tolerance-um", type=float, default=workflows.TOLERANCE_UM,
                        help="the tolerance given to `compgw commission` (µm, "
                             f"{workflows.TOLERANCE_UM:g})")
    parser.add_argument("--budget-vs-manual", type=float, metavar="F",
                        help="give `compgw commission` F times the machine time the manual "
                             "workflow's plans take on each machine (default: its own 8 h)")
    parser.add_argument("--budget-vs-plain", type=float, metavar="F",
                        help="give `compgw commission` F times the machine time the plain "
                             "workflow's plans take on each machine (ISO runs every 25 mm, 5 "
                             "runs, cyclic scans, a 9 x 7 grid: issue 54)")
    parser.add_argument("--budget-h", type=float, metavar="H",
                        help="give `compgw commission` H hours of machine time on every "
                             "machine (docs/commissioning.md's command: 4)")
    parser.add_argument("--thermal-profile", action="store_true",
                        help="Δa axes get compensation.thermal.profile (the Δa spread where "
                             "the axis has travelled)")
    parser.add_argument("--no-sensors", action="store_true",
                        help="the workflow is not given the machine's Δa or temperature "
                             "sensors (issue 54): its axes have no thermal setting")
    parser.add_argument("--laser-kind", choices=workflows.LASER_KINDS, default="modbus",
                        help="how `compgw commission` reads the sim's laser: its Modbus "
                             "registers, the bridge line protocol over TCP "
                             "(docs/instruments-bridge.md), the laser software's own "
                             "recording (.rtx or CSV) or capture on stationary (exported as "
                             "config/capture-generic.yaml has it) of the axis the laser is "
                             "set up on, or a gauge read at the prompt (manual), "
                             "by a scripted technician (sim/technician.py) (modbus)")
    parser.add_argument("--commission-axes", metavar="X[,Y]",
                        help="the axes `compgw commission` is given, no plane (default: all "
                             "and the plane; with a recording or capture, one command per "
                             "axis, the laser moved between them, the plane with the last)")
    parser.add_argument("--then-tolerance-um", type=float, metavar="T",
                        help="after `compgw commission`, the same command with --tolerance-um T "
                             "(its own advice, issue 52); the notes set both runs' figures as "
                             "read side by side")
    parser.add_argument("--per-axis", action="store_true",
                        help="one `compgw commission` per axis, the plane with the last, as a "
                             "recording or capture has it, whatever --laser-kind")
    parser.add_argument("--judge-repeats", type=int, default=1, metavar="N",
                        help="judge the calibrated machine N times (same targets, a cool-down "
                             "before each): the judge's own spread of E cut and A − R")
    parser.add_argument("--judge-seeds", type=int, default=1, metavar="K",
                        help="judge before and after at K judges' targets and parks (seeds "
                             "--seed, --seed + 1, ...): the spread of a figure over where "
                             "the judge happened to read (bench/judgings.py compares two runs "
                             "so)")
    parser.add_argument("--oracle", action="store_true",
                        help="also judge, at the same targets, each machine's calibrated config "
                             "with its pitch tables replaced by perfect ones read from the "
                             "quiet sim (bench/static_chain.py): what no table could cut")
    parser.add_argument("--warm-judge", action="store_true",
                        help="also judge each calibrated machine as read after 30 minutes of "
                             "the judge's own mixed work at random zones (issue 52), beside "
                             "what the workflow said")
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    parser.add_argument("--table", type=Path, metavar="JSON",
                        help="print the table of an earlier run's --json output and exit")
    args = parser.parse_args()
    if args.table:
        return print_table(json.loads(args.table.read_text()))
    workflows.TOLERANCE_UM = args.tolerance_um
    workflows.BUDGET_VS_MANUAL = args.budget_vs_manual
    workflows.BUDGET_VS_PLAIN = args.budget_vs_plain
    workflows.BUDGET_H = args.budget_h
    if sum(v is not None for v in (args.budget_vs_manual, args.budget_vs_plain,
                                   args.budget_h)) > 1:  # fmt: skip
        parser.error("--budget-vs-manual, --budget-vs-plain and --budget-h: give one")
    commission_only = {"--budget-vs-manual": args.budget_vs_manual,
                       "--budget-vs-plain": args.budget_vs_plain, "--budget-h": args.budget_h,
                       "--then-tolerance-um": args.then_tolerance_um}  # fmt: skip
    given = [k for k, v in commission_only.items() if v is not None]
    if given and args.workflow != "commission":  # (silently the manual workflow's, before)
        parser.error(f"{', '.join(given)}: only with --workflow commission "
                     f"(given: {args.workflow})")
    workflows.THERMAL_PROFILE = args.thermal_profile
    workflows.NO_SENSORS = args.no_sensors
    workflows.LASER_KIND = args.laser_kind
    workflows.PER_AXIS = args.per_axis
    workflows.THEN_TOLERANCE_UM = args.then_tolerance_um
    workflows.COMMISSION_AXES = args.commission_axes.split(",") if args.commission_axes else None
    if workflows.reads_later() and len(workflows.COMMISSION_AXES or ()) > 1:
        parser.error(f"--laser-kind {args.laser_kind}: give one --commission-axes AXIS, or none "
                     "(one command per axis, the laser moved between them)")
    machines = machine_list(args.machines, args.seed, args.real)
    if args.only:
        machines = [m for m in machines if m[0] in args.only.split(",")]
    without = args.without.split(",") if args.without else []
    for name in without:
        if name not in ABLATIONS:
            parser.error(f"--without {name}: not one of {', '.join(ABLATIONS)}")
    root = args.keep or Path(tempfile.mkdtemp(prefix="compgw-accuracy-"))
    root.mkdir(parents=True, exist_ok=True)
    t0 = time.monotonic()
    results: list[dict[str, Any]] = []
    say = (lambda *a: print(*a, file=sys.stderr)) if args.json else print
    say(f"{len(machines)} machines, workflow {args.workflow}, {args.jobs} job(s)"
        + (f", laser through the {args.laser_kind}" if args.laser_kind != "modbus" else ""))
    say(HEAD)
    if args.jobs > 1:  # a commissioning per core: one BLAS thread each (tests/conftest.py)
        os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    with concurrent.futures.ThreadPoolExecutor(max_workers=max(1, args.jobs)) as pool:
        futures = [pool.submit(run_machine, label, gen, args.workflow, root, args.seed, without,
                               args.judge_repeats, args.sim_seed, args.oracle,
                               args.warm_judge, args.judge_seeds)
                   for label, gen in machines]  # fmt: skip
        for fut in futures:
            r = fut.result()
            if "error" in r:
                say(f"{r['machine']:<24}failed: {r['error']}")
            else:
                r["summary"] = summary(r)
                say(row(r["machine"], r["summary"], r["sensor"]))
            results.append(r)
    stats = group_stats(results)
    wall = time.monotonic() - t0
    say("")
    for group, st in stats.items():
        for which in ("median", "worst"):
            say(row(f"{group} {which}", st[which], "any"))
    print_repeats(results, say)
    print_oracle(results, say)
    print_warm(results, args.tolerance_um, say)
    print_unrepeatable(results, say)
    say(f"wall time {wall / 60:.1f} min; machine files in {root}")
    if args.json:
        print(json.dumps({"workflow": args.workflow, "without": without,
                          "tolerance_um": args.tolerance_um,
                          "budget_vs_manual": args.budget_vs_manual,
                          "budget_vs_plain": args.budget_vs_plain,
                          "budget_h": args.budget_h,
                          "laser_kind": args.laser_kind, "no_sensors": args.no_sensors,
                          "wall_s": round(wall, 1), "groups": stats,
                          "machines": results}, indent=2))  # fmt: skip
    if not args.keep:
        shutil.rmtree(root, ignore_errors=True)
    return 1 if any("error" in r for r in results) else 0


if __name__ == "__main__":
    sys.exit(main())
