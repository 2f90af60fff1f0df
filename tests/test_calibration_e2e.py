"""Issue 5 from scratch on the example sim: plan → run → fit → verify, with `compgw` itself.

The sim and a gateway run in a background thread (tests/test_calibration_rig.py); every
step is the command a user types (`compgw calibrate`, `compgw fit`, `compgw report`), with
configs switched by reload as SIGHUP would. The order is the workflow's:

1. warm-up with no compensation → thermal length (seed 002), drift without comp;
2. ISO 230-2 identification of X and Y (thermal on, pitch/planar off) → bidirectional tables;
3. XY grid with the pitch tables on → planar model (chosen by CV, pinned to the pitch lines);
4. verification plans (targets between the calibration targets; off-grid XY points) with
   everything off (before) and everything on (after); warm-up again with thermal comp.

The figures are printed (pytest -s) and asserted against issue 5's bars.
"""

from __future__ import annotations

import contextlib
import io
import json
import re
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from gateway.calibration.commands import calibrate
from gateway.calibration.fitting.iso230 import iso230_raw
from gateway.calibration.fitting.models import drift_um
from gateway.calibration.measuring.session import planar_figures
from gateway.calibration.plans.plans import (
    iso230_linear_plan,
    read_plan,
    resume_index,
    snap_to_pulses,
    write_plan,
)
from gateway.calibration.plans.rawdata import read_raw_csv
from gateway.calibration.plans.xy import xy_verification_plan
from gateway.cli import build_parser
from gateway.compensation import PitchTable
from gateway.formats import read_pitch_csv, write_pitch_csv
from tests.test_calibration_rig import Bench, compgw, example_config, ok, without

#: dense (a quarter of the 10 mm lead: the sim's once-per-lead error is followed), uneven
ISO_ID = ["--step-mm", "2.5", "--lead-mm", "10", "--overrun-mm", "1"]
#: identification runs per target: 3, as commissioning identifies (the verification, the
#: judge, keeps ISO 230-2's 5; with 5 here: flow 59 s, the same cuts within 1.2 points)
RUNS = {"X": "3", "Y": "3"}


def iso_figures(path: Path) -> dict[str, dict[str, float]]:
    return {a: {"E_um": r.E_um, "A_um": r.A_um, "B_um": r.B_um, "R_um": r.R_um}
            for a, r in iso230_raw(read_raw_csv(path)).items()}  # fmt: skip


class Interrupt(KeyboardInterrupt):
    pass


@pytest.fixture(scope="module")
def flow(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    d = tmp_path_factory.mktemp("calibration")
    (d / "tables").mkdir()
    t0 = time.monotonic()
    out: dict[str, Any] = {"dir": d}
    with Bench(d) as b:
        full = example_config(b.sim_port)
        out["config"] = full
        full["axes"]["X"]["compensation"]["pitch"]["file"] = "tables/x_pitch.csv"
        full["axes"]["Y"]["compensation"]["pitch"]["file"] = "tables/y_pitch.csv"
        full["planar"]["model"] = "tables/xy_model.yaml"
        nothing = b.write_config("nothing.yaml", without(full, "pitch", "thermal", "planar"))
        gw = b.write_config("gw.yaml", full)
        laser, xy, delta_a = b.instrument(20), b.instrument(21), b.instrument(10, 1)
        common = ["-c", gw, "--gateway", b.gateway]

        # 1. warm-up, nothing on: the thermal length, and the drift without compensation
        b.use(nothing)
        b.cool_down()
        ok("calibrate", *common, "--warmup", "X", "--laser", laser, "--delta-a", delta_a,
           "--park", "Y=0", "--measure-every", "2", "--raw", d / "warm_off.csv")  # fmt: skip
        fit = json.loads(ok("fit", d / "warm_off.csv", "-c", gw, "--json"))
        out["thermal_fit"] = fit["X"]["thermal"]
        full["axes"]["X"]["compensation"]["thermal"]["length_mm"] = round(
            fit["X"]["thermal"]["length_mm"], 1)  # fmt: skip
        gw = b.write_config("gw.yaml", full)
        ident = d / "ident.yaml"
        ok("calibrate", "-c", gw, "--identify-config", ident)
        pitch_only = b.write_config("pitch_only.yaml", without(full, "planar"))

        # 2. identification of the pitch tables, thermal on
        b.use(ident)
        b.cool_down()
        for axis, other in (("X", "Y"), ("Y", "X")):
            out[f"{axis}_id_output"] = ok(
                "calibrate", *common, "--iso", axis, *ISO_ID, "--runs", RUNS[axis], "--laser",
                laser, "--park", f"{other}=0", "--raw", d / f"{axis}_id.csv")  # fmt: skip
        out["fit_pitch"] = ok("fit", d / "X_id.csv", d / "Y_id.csv", "-c", gw)

        # 3. the XY grid with the pitch tables on
        b.use(pitch_only)
        b.cool_down()
        ok("calibrate", *common, "--xy", "--grid", "9", "7", "--grid-runs", "3",
           "--overrun-mm", "1", "--xy-device", xy, "--raw", d / "xy_id.csv")  # fmt: skip
        out["fit_planar"] = json.loads(ok("fit", d / "xy_id.csv", "-c", gw, "--json",
                                          "--pitch-line", "X@Y=0", "--pitch-line", "Y@X=0"))

        # 4. verification: targets between the calibration targets, before and after
        for axis in ("X", "Y"):
            travel = full["axes"][axis]["travel_mm"]
            write_plan(d / f"{axis}_verify.plan", iso230_linear_plan(
                axis, travel, step_mm=25, runs=5, overrun_mm=1, verification=True))  # fmt: skip
        write_plan(d / "xy_verify.plan", xy_verification_plan(
            (1, 799), (1, 599), 9, 7, approach_mm=1, lower_mm=(0, 0)))  # fmt: skip
        for phase, config, comp in (("before", nothing, "off"), ("after", gw, "on")):
            b.use(config)
            b.cool_down()
            for axis, other in (("X", "Y"), ("Y", "X")):
                ok("calibrate", *common, "--plan", d / f"{axis}_verify.plan", "--laser", laser,
                   "--park", f"{other}=0", "--compensation", comp,
                   "--raw", d / f"{axis}_{phase}.csv")  # fmt: skip
            ok("calibrate", *common, "--plan", d / "xy_verify.plan", "--xy-device", xy,
               "--compensation", comp, "--raw", d / f"xy_{phase}.csv")  # fmt: skip
        b.cool_down()
        ok("calibrate", *common, "--warmup", "X", "--laser", laser, "--delta-a", delta_a,
           "--park", "Y=0", "--measure-every", "2", "--compensation", "on",
           "--raw", d / "warm_on.csv")  # fmt: skip

        # a run interrupted half-way (Ctrl-C while measuring) and resumed by the same command
        from gateway.instruments.base import Instrument

        calls = {"n": 0}
        real = Instrument.read_mm

        async def flaky(self, axes, near_mm=None):  # type: ignore[no-untyped-def]
            calls["n"] += 1
            if calls["n"] == 100:
                raise Interrupt
            return await real(self, axes, near_mm)

        args = ["calibrate", *common, "--plan", d / "X_verify.plan", "--laser", laser,
                "--compensation", "on", "--raw", d / "X_resumed.csv"]  # fmt: skip
        Instrument.read_mm = flaky  # type: ignore[method-assign]
        try:
            out["interrupted_rc"] = compgw(*args)[0]
        finally:
            Instrument.read_mm = real  # type: ignore[method-assign]
        out["rows_after_interrupt"] = len(read_raw_csv(d / "X_resumed.csv"))
        out["resume_output"] = ok(*args)

        # seed 001: a table 30 % off (as if identified warm), iterated with compensation on
        # (uneven 2.5 mm spacing: the 10 mm lead's error is followed, not aliased)
        iter_plan = {"step_mm": 2.5, "lead_mm": 10, "runs": 2, "overrun_mm": 1}
        plan = iso230_linear_plan("X", (0, 100), **iter_plan)
        write_plan(d / "X_iter.plan", plan)
        write_plan(d / "X_iter_verify.plan",
                   iso230_linear_plan("X", (0, 100), **iter_plan, verification=True))  # fmt: skip
        fitted = read_pitch_csv(d / "tables" / "x_pitch.csv")
        t = plan.targets_mm()[: len(plan.targets_mm()) // 4]  # the targets of run 1, going up
        off = PitchTable(t, 0.7 * np.interp(t, fitted.position_mm, fitted.forward_mm),
                         0.7 * np.interp(t, fitted.position_mm, fitted.reverse_mm))  # fmt: skip
        write_pitch_csv(d / "tables" / "x_iter.csv", off)
        it = without(full, "planar")
        it["axes"]["X"]["compensation"]["pitch"]["file"] = "tables/x_iter.csv"
        it_path = b.write_config("iter.yaml", it)
        b.use(it_path)
        b.cool_down()

        async def reload() -> None:
            b.use(it_path)

        args = build_parser().parse_args([str(a) for a in (
            "calibrate", "-c", it_path, "--gateway", b.gateway, "--plan", d / "X_iter.plan",
            "--verify-plan", d / "X_iter_verify.plan", "--verify", "--iterate", "2",
            "--tolerance-um", "2", "--laser", laser, "--park", "Y=0", "--compensation", "on",
            "--raw", d / "X_iter.csv")])  # fmt: skip
        text = io.StringIO()
        with contextlib.redirect_stdout(text):
            out["iterate_rc"] = calibrate(args, reload=reload)
        out["iterate_output"] = text.getvalue()
        print(out["iterate_output"])
    out["seconds"] = time.monotonic() - t0

    for phase in ("before", "after"):
        for axis in ("X", "Y"):
            out[f"{axis}_{phase}"] = iso_figures(d / f"{axis}_{phase}.csv")[axis]
        out[f"xy_{phase}"] = planar_figures(d / f"xy_{phase}.csv", ("X", "Y"))
    out["drift_off_um"] = drift_um(read_raw_csv(d / "warm_off.csv"), "X")
    out["drift_on_um"] = drift_um(read_raw_csv(d / "warm_on.csv"), "X")
    print_figures(out)
    return out


def print_figures(out: dict[str, Any]) -> None:
    print(f"\ncalibration flow on the example sim: {out['seconds']:.1f} s")
    for axis in ("X", "Y"):
        b, a = out[f"{axis}_before"], out[f"{axis}_after"]
        print(f"{axis}: E {b['E_um']:.2f} → {a['E_um']:.2f} µm "
              f"({100 * (1 - a['E_um'] / b['E_um']):.1f} % less); A {b['A_um']:.2f} → "
              f"{a['A_um']:.2f} µm ({100 * (1 - a['A_um'] / b['A_um']):.1f} % less); "
              f"R {b['R_um']:.2f} → {a['R_um']:.2f} µm")  # fmt: skip
    b, a = out["xy_before"], out["xy_after"]
    print(f"XY max vector error {b['max_um']:.2f} → {a['max_um']:.2f} µm "
          f"({100 * (1 - a['max_um'] / b['max_um']):.1f} % less)")  # fmt: skip
    print(f"thermal: drift after warm-up (mean of last 5) {np.mean(out['drift_off_um'][-5:]):.1f}"
          f" µm without, {np.mean(out['drift_on_um'][-5:]):.1f} µm with compensation (largest "
          f"single reading {np.abs(out['drift_on_um']).max():.1f} µm); fitted length "
          f"{out['thermal_fit']['length_mm']:.1f} mm (sensor at 800)")  # fmt: skip


@pytest.mark.parametrize("axis", ["X", "Y"])
def test_verification_cuts_systematic_error_by_90_percent(flow, axis):
    before, after = flow[f"{axis}_before"], flow[f"{axis}_after"]
    assert before["E_um"] > 15.0
    assert after["E_um"] <= 0.1 * before["E_um"], (before, after)


@pytest.mark.parametrize("axis", ["X", "Y"])
def test_verification_cuts_accuracy_by_90_percent(flow, axis):
    """A is E widened by the ±2s bands: what is left after compensation is mostly the
    machine's repeatability (0.3 µm per stop here, measured 91.6-93.2 % cut over sim seeds
    1-3 at 0.1 µm per pulse; at 1 µm per pulse the rounding alone keeps it near 89 %)."""
    before, after = flow[f"{axis}_before"], flow[f"{axis}_after"]
    assert before["A_um"] > 25.0
    assert after["A_um"] <= 0.1 * before["A_um"], (before, after)
    assert after["A_um"] - after["E_um"] <= after["R_um"] + 0.5


def test_xy_max_vector_error_at_off_grid_points_cut_by_90_percent(flow):
    before, after = flow["xy_before"], flow["xy_after"]
    assert before["max_um"] > 50.0
    assert after["max_um"] <= 0.1 * before["max_um"], (before, after)


def test_thermal_drift_within_2um_with_compensation_tens_without(flow):
    """Drift after the warm-up = mean of the last 5 readings at the reference against the cold
    reading (single readings carry the sim's 0.5 µm repeatability and the Δa sensor's 1 µm
    steps; the largest single reading is printed too)."""
    assert np.mean(flow["drift_off_um"][-5:]) > 20.0
    assert abs(np.mean(flow["drift_on_um"][-5:])) <= 2.0
    assert np.abs(flow["drift_on_um"]).max() <= 4.0
    assert flow["thermal_fit"]["length_mm"] == pytest.approx(800.0, rel=0.05)


def test_calibrate_says_how_long_the_machine_will_be_busy(flow):
    text = flow["X_id_output"]
    found = re.search(r"iso230-linear plan: (\d+) readings in (\d+) moves; about ([\d.]+) min "
                      r"of machine time at 100 mm/s and 2 s per reading", text)
    assert found is not None, text
    readings, minutes = int(found.group(1)), float(found.group(3))
    assert readings == len(read_raw_csv(flow["dir"] / "X_id.csv").target_mm)  # all measured
    assert minutes > readings * 2 / 60  # at least the 2 s per reading


def test_tables_and_model_written_where_the_config_points(flow):
    d = flow["dir"]
    for name in ("x_pitch.csv", "y_pitch.csv", "xy_model.yaml", "xy_points.csv"):
        assert (d / "tables" / name).is_file(), name
    assert "bidirectional" in flow["fit_pitch"]
    planar = flow["fit_planar"]["planar"]
    assert planar["pinned"] and planar["loo_rms_um"]  # CV scores reported
    assert planar["residual_rms_um"] < 2.0


def test_interrupted_run_resumes_and_loses_nothing(flow):
    d = flow["dir"]
    assert flow["interrupted_rc"] == 3
    assert flow["rows_after_interrupt"] == 99  # every reading before the interruption
    pulse_mm = {"X": flow["config"]["axes"]["X"]["pulse_mm"]}
    plan = snap_to_pulses(read_plan(d / "X_verify.plan"), pulse_mm)  # as calibrate runs it
    raw = read_raw_csv(d / "X_resumed.csv")
    assert resume_index(plan, raw) == len(plan.moves)
    assert "resumed at move" in flow["resume_output"]
    resumed = iso_figures(d / "X_resumed.csv")["X"]
    assert resumed["E_um"] == pytest.approx(flow["X_after"]["E_um"], abs=1.5)


def test_report_of_before_and_after(flow, tmp_path):
    d = flow["dir"]
    rc, out, _ = compgw("report", d / "X_after.csv", "--json")
    assert rc == 0
    data = json.loads(out)
    assert data["X"]["E_um"] == pytest.approx(flow["X_after"]["E_um"])
    ok("report", d / "X_after.csv", "--before", d / "X_before.csv", "--out", tmp_path / "x")
    text = (tmp_path / "x" / "report.html").read_text()
    assert text.count("data:image/png;base64,") == 1 and "figures-X" in text
    ok("report", d / "xy_after.csv", "--before", d / "xy_before.csv", "--out", tmp_path / "xy")
    assert (tmp_path / "xy" / "xy-field.png").stat().st_size > 1000


def test_iteration_folds_the_residual_until_within_tolerance(flow):
    """Seed 001 with `compgw calibrate --verify --iterate`: each round's figures printed at
    the calibration targets and between them, the residual folded into the table and the
    gateway reloaded, stopping when the targets *between* the points are within tolerance
    (exit 0 only then)."""
    d, text = flow["dir"], flow["iterate_output"]
    rounds = [float(m) for m in re.findall(r"round \d+ at the calibration targets: X: E ([\d.]+)",
                                           text)]  # fmt: skip
    between = [float(m) for m in re.findall(r"round \d+ between them \(verification\): X: E "
                                            r"([\d.]+)", text)]  # fmt: skip
    assert len(rounds) >= 2 and rounds[0] > 3.0, text  # a 30 % table error shows
    assert len(between) == len(rounds) and between[0] > 3.0, text
    assert rounds[-1] < 0.5 * rounds[0] and between[-1] < 0.5 * between[0], text
    assert "folded into" in text
    assert (d / "X_iter.round0.csv").exists() and (d / "X_iter.round0.verify.csv").exists()
    if flow["iterate_rc"] == 0:
        assert between[-1] <= 2.0 and "within 2 µm: done" in text, text
    else:  # judged between the points, honestly: not met is said and exits 1
        assert (between[-1] > 2.0 and "not within" in text) or "too coarse" in text, text
