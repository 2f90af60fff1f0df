"""`compgw commission` and its budget (sim, gateway and the command as real processes,
time_scale 0): a budget too small ends with an honest report, one spent in the
identification still fits every axis and lets the after-run judge, a finished
commissioning carried on only when asked for more (its after-run measured again) and
rechecked later, tables that make the plane worse not left loaded, the dry run, and a
config compensated already said in the plan."""


from __future__ import annotations

import json
import re
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import yaml

from gateway.calibration.commissioning.commission import Commission
from gateway.calibration.commissioning.short import SWITCH_READINGS
from gateway.calibration.commissioning.steps import Settings
from gateway.calibration.measuring.session import Instruments
from tests.commission_rig import TRAVEL_MM, commissioned, running, small_machine

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def template(tmp_path_factory: pytest.TempPathFactory) -> Path:
    directory = tmp_path_factory.mktemp("machine") / "m"
    small_machine(directory, seed=7)
    return directory


def test_a_finished_commissioning_is_carried_on_only_for_more(template: Path,
                                                              tmp_path: Path) -> None:  # fmt: skip
    """Pure (the state of a finished run, no machine): the same command, a smaller budget,
    a looser tolerance or a tolerance that judges none of its axes (arcseconds on linear
    axes) find it finished; a larger budget, a tighter tolerance or more rounds carry it
    on. Other axes or another plane are refused: that directory's readings, references and
    tables are the first one's (carried on, a turntable's after a swing axis crashed)."""
    out = tmp_path / "commission"
    config = template / "gateway.yaml"

    def job(**kw: object) -> Commission:
        base: dict[str, object] = {"axes": ("X", "Y"), "planar": ("X", "Y"),
                                   "budget_s": 7200.0, "tolerance_um": 2.0}  # fmt: skip
        base.update(kw)
        return Commission(Settings(config, out, None, Instruments(), **base),  # type: ignore[arg-type]
                          reload=None)  # type: ignore[arg-type]

    first = job()
    first.record.state["finished"] = {"outcome": "within", "asked": first.command.asked(),
                                      "what": first.command.what()}  # fmt: skip
    first.record.save()
    (out / "summary.json").write_text(json.dumps({"outcome": "within", "machine_h": 1.5}))
    for same in ({}, {"budget_s": 3600.0}, {"tolerance_um": 3.0}, {"max_rounds": 2},
                 {"tolerance_arcsec": 0.5}):  # fmt: skip
        assert job(**same).command.finished() == {"outcome": "within", "machine_h": 1.5}, same
        assert job(**same).command.other() is None
    for more in ({"budget_s": 9000.0}, {"tolerance_um": 1.0}, {"max_rounds": 9}):
        assert job(**more).command.finished() is None, more
    for other in ({"axes": ("X",)}, {"planar": None}):
        why = job(**other).command.other()
        assert why is not None and why.startswith(f"{out} holds the commissioning of X, Y and "
                                                  "the plane X/Y; this command asks for ")
        assert "give --out DIR for another commissioning" in why


def test_a_budget_too_small_ends_with_an_honest_report(template: Path, tmp_path: Path) -> None:
    with running(template, tmp_path / "m") as rig:
        original = rig.config.read_text()
        proc = rig.commission("--budget-h", "0.05")
        assert proc.popen.wait(timeout=120) == 1, proc.text()
        out = rig.dir / "commission"
        summary = json.loads((out / "summary.json").read_text())
        assert summary["outcome"] == "budget"
        assert summary["machine_h"] <= 0.05
        assert any("budget spent" in n for n in summary["notes"])
        report = (out / "report" / "report.html").read_text()
        assert "budget" in report and "No round ran" in report  # not an empty table
        # a plain calibration's least still fits: X's ISO runs at 5 targets, no drift
        # references (they fitted nothing here before), the user's config kept aside
        final = yaml.safe_load(rig.config.read_text())
        assert "pitch" in final["axes"]["X"]["compensation"], final["axes"]["X"]
        assert (out / "original.yaml").read_text() == original
        assert "outcome: budget" in proc.text()
        assert "does not hold these first steps" in proc.text()  # said before it moved


@pytest.mark.timeout(300)  # five commands on one machine (about 60 s alone, more when the
# other worker is busy): the short budget, its recheck twice, the carry-on, its report again
def test_a_budget_spent_in_the_identification_still_fits_every_axis(
        template: Path, tmp_path: Path) -> None:  # fmt: skip
    """A budget short of the first steps and the before- and after-runs: a plain ISO 230-2
    calibration's steps first (every axis's ISO runs, their cyclic scans where the plane's
    grid still fits beside them, up to 5 runs, the plane's grid with those tables on), then
    the before-runs that judge them, the backlash tests last; so when it is spent each axis
    has the table a plain calibration would give it, cyclic term included, said to be
    unverified, the plane its model, and the report its before and after. (Axis by axis, X
    had a verified table, Y none, and the plane none; with the scans last, Y had none.) No
    round's verification fits: the after-run, at random targets no fit used, judges the
    tables instead, and within the tolerance (10 µm here) it is the outcome. (A random
    machine at 2 h ended "budget" with its after-run within 2 µm everywhere.)"""
    with running(template, tmp_path / "m") as rig:
        proc, summary, state = commissioned(rig, "--budget-h", "1.1", "--tolerance-um", "10")
        out = rig.dir / "commission"
        assert summary["outcome"] == "within" and summary["machine_h"] <= 1.1
        assert "budget spent: backlash-" in proc.text() and not summary["rounds"]
        judged = next(n for n in summary["notes"] if "the after-run judged the tables" in n)
        assert all(f"{n} " in judged for n in ("X E", "Y E", "XY max")), judged
        assert state["short"]
        done = list(state["steps"])
        # a plain calibration's steps, then what judges them, then the backlash tests
        order = ["iso-Y", "cyclic-X", "cyclic-Y", "xy-grid", "after-X"]
        assert [done.index(s) for s in order] == sorted(done.index(s) for s in order), done
        # each axis judged by its after-run alone, against its ISO runs read with the
        # tables off: no before-run's machine time
        assert not {"before-X", "before-Y"} & set(done), done
        assert {"after-X", "after-Y"} <= set(done), done
        assert (out / "plans" / "alone-X.plan").exists()
        assert "X, Y: no before-run; the figures before are the ISO runs'" in proc.text()
        assert "backlash-Y" not in done
        # Y's table (of known lead) misses between its points, net of its once-per-lead
        # error, more than twice its scatter along straight lines, but not along the curve
        # it is read along: no midpoints (they were read before session 56)
        mid = state["identify"]["midpoints-Y"]
        assert not mid["measured"] and mid["misses_x_scatter"] <= 2, mid
        assert "iso-mid-Y" not in done, done
        # no round will refine the plane: its first grid is at least a plain calibration's
        # (9 nodes along the longer travel: a square plane's 9 x 9), denser with what the
        # verdict and the backlash tests leave
        nx, ny = state["grid"]
        assert nx == ny >= 9, state["grid"]
        note = next(n for n in summary["notes"] if "identification's runs only" in n)
        assert note.startswith("X, Y: fitted") and "no cyclic term" not in note, note
        final = yaml.safe_load(rig.config.read_text())["axes"]
        for a in ("X", "Y"):
            assert {"pitch", "cyclic"} <= set(final[a]["compensation"]), final[a]
        for a in ("X", "Y"):  # no round measures between the points: leave-one-out chooses
            chosen = state["identify"][f"interpolation-{a}"]
            assert chosen["why"] == "leave-one-out" and len(chosen["loo_rms_um"]) == 3, chosen
            assert final[a]["compensation"]["pitch"]["interpolation"] == chosen["method"]
        assert "planar" in yaml.safe_load(rig.config.read_text())
        xy = summary["xy"]
        assert xy["after"]["max_um"] < 0.5 * xy["before"]["max_um"], xy
        for a in ("X", "Y"):  # judged after at random targets, before by the ISO runs
            e = summary["axes"][a]
            assert e["before"]["read_at"] == "iso", e
            assert e["after"]["E_um"] < 0.5 * e["before"]["E_um"], (a, e)
        assert "no round verified them" in proc.text()
        assert ("a short budget: a plain calibration's steps first: every axis's ISO runs"
                in proc.text())
        assert "WITHIN 10 µm as the laser reads it on every commissioned axis and the plane" \
            in proc.text()
        def after_x(where: Path) -> list[str]:
            return [f.read_text() for f in sorted(where.glob("after-X*.csv"))]

        first_after = after_x(out / "raw")
        assert first_after
        # months later: the same command with --recheck measures the random targets again
        # with the tables loaded, fits nothing and says whether they still hold
        tables = {f: f.read_text() for f in (out / "tables").iterdir()}
        check = rig.commission("--budget-h", "1.1", "--tolerance-um", "10", "--recheck")
        assert check.popen.wait(timeout=120) == 0, check.text()
        assert "the tables still hold" in check.text()
        assert "now (both as read): within 10 µm" in check.text()
        rechecked = json.loads(next((out / "recheck").glob("*/recheck.json")).read_text())
        assert set(rechecked["items"]) == {"X", "Y", "xy"} and rechecked["within"], rechecked
        x = rechecked["items"]["X"]
        # both as read (the summary's E takes the machine's drift off; E_read does not)
        assert x["then"] == summary["axes"]["X"]["after"]["E_read_um"] and x["now"] < 10.0, x
        assert {f: f.read_text() for f in (out / "tables").iterdir()} == tables
        # X's table skewed by 30 µm over the travel (the machine changed, as it reads):
        # not within on X, exit 1, and what to do
        x_table = rig.dir / yaml.safe_load(rig.config.read_text())["axes"]["X"][
            "compensation"]["pitch"]["file"]  # fmt: skip
        rows = x_table.read_text().splitlines()
        data = [i for i, r in enumerate(rows) if r[:1].isdigit() or r[:1] == "-"]
        for k, i in enumerate(data):
            cols = rows[i].split(",")
            cols[1:] = [f"{float(c) + 30.0 * k / (len(data) - 1):.4f}" for c in cols[1:]]
            rows[i] = ",".join(cols)
        x_table.write_text("\n".join(rows) + "\n")
        mark = rig.gw.mark()
        rig.gw.signal(signal.SIGHUP)
        rig.gw.wait_line(r"reloaded ", start=mark)
        check = rig.commission("--budget-h", "1.1", "--tolerance-um", "10", "--recheck")
        assert check.popen.wait(timeout=120) == 1, check.text()
        assert "NOT within on X, XY: the machine has changed since" in check.text(), check.text()
        assert re.search(r"X: E [\d.]+ µm at the after-run, [\d.]+ µm now \(both as read\): "
                         r"NOT within 10 µm",
                         check.text()), check.text()
        x_table.write_text(tables[x_table])
        mark = rig.gw.mark()
        rig.gw.signal(signal.SIGHUP)
        rig.gw.wait_line(r"reloaded ", start=mark)
        # the same command with more budget carries on: the backlash tests, the fit again,
        # the plane and the rounds
        more = rig.commission("--budget-h", "2", "--tolerance-um", "5")
        assert more.popen.wait(timeout=300) in (0, 1), more.text()
        final = yaml.safe_load(rig.config.read_text())["axes"]
        assert all("cyclic" in final[a]["compensation"] for a in ("X", "Y")), final
        again = json.loads((out / "summary.json").read_text())
        assert again["axes"]["Y"]["after"]
        # the after-run measured again with the tables now loaded, the first one's kept
        # aside; what the first ending said is gone, and where it carried on from said
        assert "after-X: " in more.text() and "after-xy: " in more.text()
        state = json.loads((out / "commission.json").read_text())
        if state["steps"]["after-X"].get("carried"):  # X's tables as the first run left them
            assert after_x(out / "raw") == first_after
            assert "after-X: its tables as the run before left them: its after-run stands" \
                in more.text()
        else:
            assert after_x(out / "raw" / "superseded") == first_after
            assert after_x(out / "raw") and after_x(out / "raw") != first_after
        assert not any("the after-run judged the tables" in n or "budget spent" in n
                       for n in again["notes"]), again["notes"]  # fmt: skip
        assert "carried on after 'within' at 1.0" in " ".join(again["notes"])
        # each figure set against the run before's, as read, and whether its tables changed
        was = again["run_before"]
        assert set(was) == {"X", "Y", "XY"}, was
        assert was["X"]["before_um"] == summary["axes"]["X"]["after"]["E_read_um"], was
        assert was["X"]["now_um"] == again["axes"]["X"]["after"]["E_read_um"], was
        assert all(isinstance(r["same_tables"], bool) for r in was.values()), was
        # no figure worse than the run before: tables it left as they were keep their
        # reading; tables it changed that read worse are put back, with theirs
        assert all(r["now_um"] <= r["before_um"] + 0.005 for r in was.values()), was
        for n, r in was.items():
            carried = (again["xy"] if n == "XY" else again["axes"][n])["after"].get("carried")
            assert bool(carried) == (r["now_um"] == r["before_um"]), (n, r, carried)
        after = again["axes"]["X"]["after"]  # and how far a target's mean scatters there
        assert was["X"]["scatter_um"] == pytest.approx(
            2 * after["s_pooled_um"] / after["runs"] ** 0.5), was  # fmt: skip
        lines = more.text().strip().splitlines()
        verdict = lines[lines.index(next(n for n in lines if n.startswith("report: "))) - 1]
        assert verdict.startswith(("WITHIN 5 µm", "NOT within 5 µm")), verdict
        assert lines[-1].startswith("status.remote_control is still on in "), lines[-1]
        # a power loss between the summary and the report: the same command writes it
        shutil.rmtree(out / "report")
        last = rig.commission("--budget-h", "2", "--tolerance-um", "5")
        assert last.popen.wait(timeout=60) in (0, 1), last.text()
        assert "nothing moves" in last.text() and "the report was missing" in last.text()
        assert (out / "report" / "report.html").exists()


def test_a_short_budget_reads_the_plane_s_grid_before_cyclic_scans_that_gave_way_to_it(
        tmp_path: Path) -> None:  # fmt: skip
    """Issue 54: a plane that is not made of the axes' own errors (each axis's straightness
    and scale change sign across the other axis) and 0.07 h: the ISO runs at 7 targets, the
    cyclic scans give way to the plane's grid. The grid then no longer gives way to them
    (before, it did: neither was read, the plane's random points read the tables alone
    worse than none, 30.4 → 44.1 µm RMS, and the user's config stayed loaded with no
    table): the grid is read, and the tables and the plane's model are left loaded."""
    small_machine(tmp_path / "t", seed=7)
    x = np.linspace(*TRAVEL_MM, 10)
    gx, gy = np.meshgrid(x, x, indexing="ij")
    u, v = np.pi * (gx - TRAVEL_MM[0]) / 90.0, np.pi * (gy - TRAVEL_MM[0]) / 90.0
    ex, ey = 40.0 * np.sin(u) * np.cos(v), 40.0 * np.cos(u) * np.sin(v)
    (tmp_path / "t" / "truth" / "xy_field.csv").write_text("x_mm,y_mm,ex_um,ey_um\n" + "".join(
        f"{a:.4f},{b:.4f},{c:.4f},{d:.4f}\n"
        for a, b, c, d in zip(gx.ravel(), gy.ravel(), ex.ravel(), ey.ravel())))  # fmt: skip
    with running(tmp_path / "t", tmp_path / "m") as rig:
        proc = rig.commission("--budget-h", "0.07")
        assert proc.popen.wait(timeout=300) == 1, proc.text()
        state = json.loads((rig.dir / "commission" / "commission.json").read_text())
        assert state["scans_after_grid"] == ["X", "Y"], state.get("scans_after_grid")
        assert [s for s in state["steps"] if not s.startswith("iso-")] == ["xy-grid"]
        final = yaml.safe_load(rig.config.read_text())
        assert "planar" in final
        assert all("pitch" in final["axes"][a]["compensation"] for a in ("X", "Y"))
        assert "worse with the tables than without" not in proc.text()


def test_tables_that_make_the_plane_worse_are_not_left_loaded() -> None:
    """The plane's random points read with the tables worse than without (RMS vector
    error, beyond the margin a plane's refinement is kept by): why, said, and the
    commissioning then leaves the user's own config loaded; not so where they read better
    or were not read."""
    from types import SimpleNamespace

    from gateway.calibration.commissioning.after import AfterSteps

    after = AfterSteps.__new__(AfterSteps)
    done = {"before-xy", "after-xy"}
    after.s = SimpleNamespace(planar=("X", "Y"))
    after.record = SimpleNamespace(done=lambda name: name in done,
                                   tables=SimpleNamespace(planar_model=None))
    rms = {"before-xy": 30.4, "after-xy": 44.1}
    after.xy_figures = lambda name: {"rms_um": rms[name]}  # type: ignore[method-assign]
    why = after.plane_worse()
    assert why is not None and why.startswith("XY: worse with the tables than without")
    assert "30.4" in why and "44.1" in why and "the plane was not measured" in why
    rms["after-xy"] = 12.0
    assert after.plane_worse() is None
    rms["after-xy"] = 44.1
    done.discard("after-xy")
    assert after.plane_worse() is None


def test_dry_run_prints_the_plan_and_moves_nothing(template: Path, tmp_path: Path) -> None:
    with running(template, tmp_path / "m") as rig:
        proc = rig.commission("--dry-run")
        assert proc.popen.wait(timeout=60) == 0, proc.text()
        text = proc.text()
        for step in ("backlash-X", "iso-X", "cyclic-X", "iso-Y", "xy-grid"):
            assert step in text
        assert not (rig.dir / "commission" / "raw").exists()
        assert "then verification rounds" in text


def test_a_config_compensated_already_is_said_in_the_plan(template: Path,
                                                          tmp_path: Path) -> None:
    """Commissioning a machine whose config has tables from an earlier calibration: the
    plan says they are measured without and replaced, and where the user's config stays."""
    data = yaml.safe_load((template / "gateway.yaml").read_text())
    data["axes"]["Y"].setdefault("compensation", {})["backlash_mm"] = 0.002
    config = tmp_path / "gateway.yaml"
    config.write_text(yaml.safe_dump(data, sort_keys=False))
    said: list[str] = []
    job = Commission(Settings(config, tmp_path / "commission", None, Instruments(),  # type: ignore[arg-type]
                              axes=("X", "Y"), budget_s=7200.0), reload=None,  # type: ignore[arg-type]
                     say=said.append)  # fmt: skip
    job.command.print_plan()
    line = next(s for s in said if "compensates" in s)
    assert line.startswith("  your config compensates Y already (tables from an earlier "
                           "calibration): the identification measures without them"), line
    assert line.endswith(f"yours is kept in {tmp_path / 'commission' / 'original.yaml'}")


def test_a_short_budget_without_the_plane_says_nothing_of_it(template: Path,
                                                             tmp_path: Path) -> None:
    """No --xy-device: the short budget's line names no plane grid (it did)."""
    said: list[str] = []
    job = Commission(Settings(template / "gateway.yaml", tmp_path / "commission", None,  # type: ignore[arg-type]
                              Instruments(), axes=("X", "Y"), budget_s=1800.0),
                     reload=None, say=said.append)  # type: ignore[arg-type]  # fmt: skip
    job.command.print_plan()
    line = next(s for s in said if "a short budget" in s)
    assert "plane" not in line and line.endswith("the lead searches"), line



def test_the_plan_says_what_each_step_is_for_and_what_a_short_budget_buys(
        template: Path, tmp_path: Path) -> None:  # fmt: skip
    """Every first step of the printed plan says what it is for, and a budget short of
    them says what it buys and what the rest needs (issue 54: "with 0.9 h: pitch tables
    and plane; thermal identification needs 1.0 h more"), before anything moves."""
    said: list[str] = []
    job = Commission(Settings(template / "gateway.yaml", tmp_path / "commission", None,  # type: ignore[arg-type]
                              Instruments(), axes=("X", "Y"), planar=("X", "Y"),
                              budget_s=1200.0), reload=None, say=said.append)  # type: ignore[arg-type]  # fmt: skip
    job.command.print_plan()
    steps = [s for s in said if " readings " in s and " moves " in s]
    assert steps and all(s.rstrip().endswith(("(ISO 230-2)", "three places", "(XY grid)",
                                              "(if lost motion)", "(periodic error)",
                                              "once-per-lead error", "(no sensor)"))
               for s in steps), steps  # fmt: skip
    bought = next(s for s in said if s.startswith("  with 0.33 h: "))
    assert bought.startswith("  with 0.33 h: pitch tables, plane"), bought
    assert "needs" in bought and "h more" in bought, bought
    # a plain calibration's tables (5 runs) and grid come first, the verdict after them
    assert "verdict needs" in bought, bought
    # and the steps it reads instead, each with its machine time and what it is for
    at = said.index("  where it holds them, it reads instead of the lines above:")
    instead = said[at + 1:at + 4]
    assert [s.split()[0] for s in instead] == ["iso-X", "iso-Y", "xy-grid"], instead


def test_a_budget_that_would_end_with_no_table_is_refused_before_anything_moves(
        template: Path, tmp_path: Path) -> None:  # fmt: skip
    """Issue 54: "never a plan that ends with no table". A budget short of even one axis's
    ISO runs at 2 runs per target is refused before anything is asked or moved, naming the
    least budget that gives a table (no gateway runs here: a dry run and a real one both
    stop there)."""
    config = template / "gateway.yaml"
    for extra in (["--dry-run"], []):
        out = subprocess.run(
            [sys.executable, "-m", "gateway.cli", "commission", "-c", str(config),
             "--laser", "127.0.0.1:1:20", "--gateway", "127.0.0.1:1", "--budget-h", "0.01",
             "--out",
             str(tmp_path / "c"), *extra], cwd=ROOT, capture_output=True, text=True,
            timeout=60)  # fmt: skip
        assert out.returncode == 1, out.stdout + out.stderr
        assert "the commissioning would end with no table; give at least" in out.stderr
        assert not (tmp_path / "c" / "commission.json").exists()


def test_a_budget_that_holds_a_plain_calibration_only_without_references_reads_none(
        template: Path, tmp_path: Path) -> None:  # fmt: skip
    """Issue 54: at the plain calibration's machine time the random machines' drift
    references left no room for Y's cyclic scans (Y E cut 65 % against the plain
    calibration's 94 %), and held beside a table of 3 runs left rough-3's 2. A short
    budget reads them only where it holds a plain calibration's steps (every axis's ISO
    runs at 5 runs and cyclic scans, the plane's grid of 9 nodes along its longer travel)
    with them; else none, said so (pure: the decision, before anything moves)."""
    leads = {a: v["lead_mm"] for a, v in json.loads((template / "machine.json").read_text())[
        "axes"].items()}  # fmt: skip

    def job(budget_h: float, out: str) -> tuple[Commission, list[str]]:
        said: list[str] = []
        commission = Commission(Settings(template / "gateway.yaml", tmp_path / out, None,  # type: ignore[arg-type]
                                         Instruments(), axes=("X", "Y"), planar=("X", "Y"),
                                         lead_mm=dict(leads), budget_s=budget_h * 3600.0),
                                reload=None, say=said.append)  # type: ignore[arg-type]  # fmt: skip
        return commission, said

    probe, _ = job(0.45, "probe")
    plain = [p for _, p in probe.short.plain_steps(["X", "Y"])]
    assert sorted(p.kind for p in plain).count("iso230-linear") == 2, plain
    bare_h = sum(probe.axes.estimate_s(p) for p in plain) / 3600.0
    refs_h = (sum(probe.short.budget.refs_worst_s(p) for p in plain)
              + SWITCH_READINGS * probe.short.budget.refs_once_s()) / 3600.0  # fmt: skip
    for budget_h, held in ((bare_h + 0.5 * refs_h, "min) the budget does not hold"),  # (bare)
                           (0.6 * bare_h, "does not hold even")):  # not even a plain one's
        short, said = job(budget_h, f"a{budget_h:.3f}")
        assert short.short.applies() and not short.short.refs_affordable(), budget_h
        assert any(f"{held} a plain calibration's steps (ISO runs, cyclic scans" in s
                   for s in said), said  # fmt: skip
    for budget_h in (bare_h + refs_h + 0.01, 5.0):  # a plain calibration's with them; long
        other, _ = job(budget_h, f"b{budget_h:.3f}")
        assert other.short.refs_affordable(), budget_h


def test_a_stopped_run_finishes_with_the_tables_it_has_read(
        template: Path, tmp_path: Path) -> None:  # fmt: skip
    """The machine is needed back half-way (Ctrl-C once X's before-run is read; every
    axis's ISO runs come first): ``--finish`` measures nothing more, fits the tables from
    what was read, loads them and reads the after-run: at the before-run's targets where it
    was made, at new random ones where not (Y here; its figures before are then its ISO
    runs', read with the tables off). Given before anything was read, it says so and
    writes nothing."""
    with running(template, tmp_path / "m") as rig:
        out = rig.dir / "commission"
        nothing = rig.commission("--finish")
        assert nothing.popen.wait(timeout=120) == 1, nothing.text()
        assert "--finish: nothing has been read in" in nothing.text()
        assert not out.exists()  # nothing written
        proc = rig.commission()
        state = out / "commission.json"
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline:
            assert proc.popen.poll() is None, proc.text()
            steps = json.loads(state.read_text())["steps"] if state.exists() else {}
            if "before-X" in steps:
                break
            time.sleep(0.02)
        proc.signal(signal.SIGINT)
        assert proc.popen.wait(timeout=60) == 3, proc.text()
        read = list(json.loads(state.read_text())["steps"])
        assert read.index("iso-Y") < read.index("before-X"), read  # both tables first
        done = rig.commission("--finish")
        code = done.popen.wait(timeout=300)
        assert code in (0, 1), done.text()
        assert "--finish: nothing more is measured" in done.text()
        after = json.loads(state.read_text())
        new = [s for s in after["steps"] if s not in read]
        assert all(s.startswith("after-") for s in new), new  # nothing but the after-run
        summary = json.loads((out / "summary.json").read_text())
        assert summary["outcome"] in ("budget", "within", "after"), summary["outcome"]
        final = yaml.safe_load(rig.config.read_text())["axes"]
        for a in ("X", "Y"):  # both tables fitted from their ISO runs and loaded
            assert "pitch" in final[a]["compensation"], final[a]
        # Y's before-run and the plane's were not read: their after-runs alone, at random
        # targets, judge them
        assert sorted(new) == ["after-X", "after-Y", "after-xy"], new
        judged = summary["axes"]["X"]
        assert judged["after"]["E_um"] < 0.5 * judged["before"]["E_um"], judged
        judged = summary["axes"]["Y"]  # its figures before: its ISO runs, the tables off
        assert judged["before"]["read_at"] == "iso", judged
        assert judged["after"]["E_um"] < 0.5 * judged["before"]["E_um"], judged
        assert "(Y: no before-run; the figures before are the ISO runs'" in done.text()
        assert re.search(r"XY max vector error [\d.]+ µm as read; no before-run", done.text())
        assert re.search(r"within 2 µm \(.*Y E", done.text()), done.text()  # judged on Y
        assert re.search(r"--finish: \S+ and the steps after it are not read", done.text())
