"""Lost motion taken up over a reversal (a soft nut): measured through the gateway with seed
000's backlash places and the reversal ladder, fitted, and judged on short steps either way
(5 µm-2 mm, as a drilling pattern moves), over real sockets against the sim; and the pure
parts: the curve, the nut's state, the chain's blend, the config's errors.

The sim's truth is its own (a quadratic engagement over the motor's reversal); the gateway
only ever sees the laser's readings.
"""

from __future__ import annotations

import asyncio
import json
from pathlib import Path

import numpy as np
import pytest
import yaml

from gateway.app import GatewayApp
from gateway.calibration.commands import make_plan
from gateway.calibration.fitting.fit import planar_measurement
from gateway.calibration.fitting.takeup_fit import (
    RUNGS_MM,
    fit_takeup,
    fit_takeup_raw,
    full_takeup_um,
    short_steps_plan,
    takeup_plan,
)
from gateway.calibration.measuring.machine import Endpoint
from gateway.calibration.measuring.session import Instruments, Session
from gateway.calibration.plans.plans import (
    Move,
    Plan,
    backlash_from_raw,
    backlash_plan,
    snap_to_pulses,
)
from gateway.calibration.plans.rawdata import read_raw_csv
from gateway.cli import build_parser
from gateway.compensation import (
    AxisChain,
    BacklashStage,
    CompensationError,
    MotionState,
    PitchStage,
    PitchTable,
    TakeUpCurve,
)
from gateway.config import ConfigError, parse_config
from gateway.tables import build_chain
from sim.server import SimServer
from tests.commission_rig import running, small_machine
from tests.test_calibration_rig import compgw, example_config, without
from tests.test_service_helpers import Proc
from tests.test_sim_support import config_from, example_dict

LOST_UM, TAKEUP_UM = 40.0, 300.0  # the sim's soft nut: 40 µm taken up over 0.3 mm
SQUARE_ARCSEC = 30.0


# ---------------------------------------------------------------------- pure parts


def test_the_curve_and_the_nut_state_it_drives():
    curve = TakeUpCurve([0.002, 0.05, 0.2], [0.1, 0.5, 1.0])
    assert curve.shown(0.0) == 0.0 and curve.shown(0.001) == pytest.approx(0.1)
    assert curve.shown(0.125) == pytest.approx(0.75) and curve.shown(5.0) == 1.0
    assert curve.reached(0.5) == pytest.approx(0.05) and curve.reached(0.05) == 0.0
    # from + fully engaged, 50 µm in −: half the play; 150 µm more: all of it
    e = curve.advance(1.0, -1, 0.05)
    assert e == pytest.approx(0.0)
    assert curve.advance(e, -1, 0.15) == pytest.approx(-1.0)
    # back in + from half way: it carries on from where the nut is (a hysteresis)
    assert curve.advance(e, +1, 0.05) == pytest.approx(2 * curve.shown(0.1) - 1)
    # moving on in the direction the nut already sits: nothing changes
    assert curve.advance(1.0, +1, 0.3) == 1.0
    state = MotionState(1, 1000)
    after = state.approach(950, curve, 0.001)  # 50 µm back
    assert after.direction == -1 and after.engagement == pytest.approx(0.0)
    assert state.approach(950).engagement == -1.0  # no curve: the classic switch
    assert after.approach(950, curve, 0.001).engagement == after.engagement


@pytest.mark.parametrize("reversal, fraction, why", [
    ([0.0], [1.0], "at least 2"),
    ([0.0, 0.1], [0.5], "same number"),
    ([0.1, 0.05], [0.5, 1.0], "strictly increasing"),
    ([0.0, 0.1], [0.6, 0.5], "never decrease"),
    ([0.0, 0.1], [0.2, 0.9], "end at 1"),
    ([0.0, float("nan")], [0.2, 1.0], "a number"),
])
def test_a_bad_curve_is_refused_with_what_is_wrong(reversal, fraction, why):
    with pytest.raises(CompensationError, match=why):
        TakeUpCurve(reversal, fraction, "axes.X.compensation.takeup")


def test_the_chain_blends_a_nut_part_way_and_inverts_it():
    x = np.linspace(0.0, 100.0, 11)
    fwd = 1e-3 * np.sin(x / 17.0)
    table = PitchTable(x, fwd, fwd + 0.03 + 1e-4 * x)  # 30-40 µm of lost motion
    curve = TakeUpCurve([0.01, 0.3], [0.2, 1.0])
    chain = AxisChain("X", 0.001, pitch=PitchStage(table), takeup=curve)
    for e in (-1.0, -0.4, 0.0, 0.7, 1.0):
        for t in (3.3, 47.9, 91.05):
            c = chain.command_mm_scalar(t, e, 0.0)
            assert chain.actual_mm_scalar(c, e, 0.0) == pytest.approx(t, abs=1e-9)
            assert float(chain.command_mm(t, e)) == pytest.approx(c, abs=1e-12)
    # half way: the command sits half way between the two flanks' commands (to a few nm:
    # the blend is of the deviations at one command, not of two commands)
    t = 47.9
    ends = [chain.command_mm_scalar(t, d, 0.0) for d in (1.0, -1.0)]
    assert chain.command_mm_scalar(t, 0.0, 0.0) == pytest.approx(np.mean(ends), abs=1e-5)
    # a constant backlash blends the same way
    lash = AxisChain("X", 0.001, backlash=BacklashStage(0.02, "forward"), takeup=curve)
    assert lash.command_mm_scalar(10.0, -0.5, 0.0) == pytest.approx(10.0 - 0.015)
    with pytest.raises(CompensationError, match="no lost motion"):
        AxisChain("X", 0.001, takeup=curve)


def test_fit_keeps_the_switch_for_a_dead_band_and_a_curve_for_a_soft_nut():
    rng = np.random.default_rng(5)
    m = np.array(RUNGS_MM)
    dead = np.minimum(m, 0.010)[None, :] + rng.normal(0, 3e-4, (3, m.size))
    assert fit_takeup(m, dead, np.full(3, 0.010), 3e-4).curve is None
    q = np.clip(m / 0.2, 0.0, 1.0)  # 25 µm over 0.2 mm of motor, in the test's own terms
    soft = 0.025 * (3 * q**2 - 2 * q**3)[None, :] + rng.normal(0, 3e-4, (3, m.size))
    fit = fit_takeup(m, soft, np.full(3, 0.025), 3e-4)
    assert fit.curve is not None and fit.miss_um > 20.0
    section = fit.config()
    assert section is not None and section["fraction"][-1] == 1.0
    assert all(np.diff(section["fraction"]) >= 0) and all(np.diff(section["reversal_um"]) > 0)
    # a stop that fell short by 8 µm at one place and rung (stick-slip) moves nothing
    short = soft.copy()
    short[1, 4] -= 0.008
    again = fit_takeup(m, short, np.full(3, 0.025), 3e-4)
    assert again.curve is not None
    np.testing.assert_allclose(again.curve.fraction, fit.curve.fraction, atol=0.05)
    dead[2, 3] -= 0.008
    assert fit_takeup(m, dead, np.full(3, 0.010), 3e-4).curve is None


def test_a_bad_takeup_section_names_the_axis(tmp_path: Path):
    data = without(example_config(5021), "pitch", "thermal", "planar")
    data.pop("thermal_sources", None)
    data["axes"]["X"]["compensation"] = {
        "backlash_mm": 0.01, "takeup": {"reversal_um": [0, 20], "fraction": [0.5, 0.9]}}
    config = parse_config(data, "gw.yaml")
    with pytest.raises(ConfigError, match=r"axes\.X\.compensation\.takeup.*end at 1"):
        build_chain(config, tmp_path)


# ---------------------------------------------------------------------- through the sim


def soft_nut_sim() -> dict:
    data = example_dict()
    sim = data["sim"]
    for axis in sim["axes"].values():
        axis["pulse_mm"] = 0.0001  # the drive's unit under config/example.yaml's ×10
    sim["machine"]["X"] = {"repeatability_um": 0.2, "lost_motion": {
        "um": LOST_UM, "takeup": {"curve": "smooth", "distance_um": TAKEUP_UM}}}
    sim["machine"]["Y"] = {"repeatability_um": 0.0}
    # 30″: X's error grows 0.145 µm per mm of Y (the laser reads X at Y = 0, none of it)
    sim["plane"] = {"axes": ["X", "Y"], "squareness_arcsec": SQUARE_ARCSEC}
    for name in ("delta_a", "temperature"):
        sim["instruments"].pop(name)
    return data


def gateway_data(sim_port: int, compensation: dict, planar: str | None = None) -> dict:
    """The gateway on the soft-nut sim; ``planar``: commit mode of a plane model that has
    the sim's squareness (written in ``work`` by :func:`square_model`)."""
    data = without(example_config(sim_port), "pitch", "thermal", "planar")
    data.pop("thermal_sources", None)
    data["axes"]["X"]["compensation"] = {"max_correction_mm": 0.2, **compensation}
    data["axes"]["Y"]["compensation"] = {"max_correction_mm": 0.2}
    if planar is not None:
        data["planar"] = {"axes": ["X", "Y"], "model": "xy.yaml", "commit": planar}
    return data


def square_model(work: Path) -> None:
    """The plane's model, in its own terms: X off by y · tan(30″), a 3 × 3 grid."""
    per_mm_um = 1e3 * float(np.tan(np.radians(SQUARE_ARCSEC / 3600.0)))
    (work / "xy.csv").write_text("x_mm,y_mm,dx_um,dy_um\n" + "".join(
        f"{x},{y},{per_mm_um * y:.4f},0\n" for x in (0, 400, 800) for y in (0, 300, 600)))
    (work / "xy.yaml").write_text("points: xy.csv\nmodel: grid\n")


async def run(sim_port: int, work: Path, compensation: dict, plan: Plan, raw: Path,
              planar: str | None = None) -> None:
    config = parse_config(gateway_data(sim_port, compensation, planar), str(work / "gw.yaml"))
    async with GatewayApp(config, build_chain(config, work)) as app:
        session = Session(config, work, Endpoint("127.0.0.1", app.tcp_port, 1),
                          Instruments(laser=Endpoint("127.0.0.1", sim_port, 20),
                                      laser_axes=["X", "Y"],
                                      xy=Endpoint("127.0.0.1", sim_port, 21)))  # fmt: skip
        await session.run(snap_to_pulses(plan, {"X": 0.001, "Y": 0.001}), raw,
                          "on" if compensation else "off")  # fmt: skip


def column_plan(x_mm: float, ys_mm: list[float], again: bool) -> Plan:
    """X at ``x_mm`` approached in + once, then Y up the column with X's target sent again
    at each stop (a PLC drilling a column of holes); ``again``: X approached in + from
    1 mm below at every stop instead."""
    moves = [Move(1, 0, "takeup", (x_mm - 1.0, 0.0))]
    for y in ys_mm:
        if again:
            moves.append(Move(1, 0, "takeup", (x_mm - 1.0, y)))
        moves.append(Move(1, 0, "measure", (x_mm, y)))
    return Plan("xy-verification", ("X", "Y"), tuple(moves))


async def soft_nut(work: Path) -> dict[str, float]:
    async with SimServer(config_from(soft_nut_sim()), tcp_port=0) as sim:
        port = sim.tcp_port
        travel = (0.0, 800.0)
        await run(port, work, {}, backlash_plan("X", travel), work / "backlash.csv")
        b = backlash_from_raw(read_raw_csv(work / "backlash.csv"), "X")
        await run(port, work, {}, takeup_plan("X", travel), work / "takeup.csv")
        fit = fit_takeup_raw(read_raw_csv(work / "takeup.csv"), "X", b)
        section = fit.config()
        assert section is not None, fit.why
        switch = {"backlash_mm": round(b.backlash_mm, 4), "backlash_table_direction": "forward"}
        out = {"lost_um": b.backlash_mm * 1e3, "miss_um": fit.miss_um}
        for name, comp in (("switch", switch), ("curve", {**switch, "takeup": section})):
            raw = work / f"steps-{name}.csv"
            await run(port, work, comp, short_steps_plan("X", travel, 3, count=80), raw)
            dev_um = read_raw_csv(raw).deviation_mm * 1e3
            out[f"{name}_rms_um"] = float(np.sqrt(np.mean(dev_um**2)))
            out[f"{name}_max_um"] = float(np.abs(dev_um).max())
        # the plane moves X's command as Y goes up a column: X, sent again, goes on along
        # its flank and takes up more of the play (0.145 µm per mm of Y: 58 µm at 400 mm)
        square_model(work)
        ys = [float(y) for y in range(25, 401, 25)]
        for name, again in (("column", False), ("column_again", True)):
            raw = work / f"{name}.csv"
            await run(port, work, {**switch, "takeup": section}, column_plan(400.0, ys, again),
                      raw, planar="on_trigger")  # fmt: skip
            dx_um = planar_measurement(read_raw_csv(raw), ("X", "Y")).error_mm[:, 0] * 1e3
            out[f"{name}_dx_um"] = dx_um.round(2).tolist()
        # the same two runs through `compgw fit`, as a technician calibrating by hand would
        gw = work / "gw.yaml"
        gw.write_text(yaml.safe_dump(gateway_data(port, {})))
        rc, text, err = compgw("fit", work / "backlash.csv", work / "takeup.csv", "-c", gw)
        assert rc == 0, err
        assert f"set axes.X.compensation.takeup: {{reversal_um: {section['reversal_um']}" in text
        rc, _, err = compgw("fit", work / "takeup.csv", "-c", gw)
        assert rc != 0 and "together with the axis's --backlash run" in err
        args = build_parser().parse_args(["calibrate", "-c", str(gw), "--takeup", "X"])
        plan = make_plan(args, parse_config(gateway_data(port, {}), str(gw)))
        assert plan.kind == "takeup" and len(plan.moves) == 4 * 3 * len(RUNGS_MM)
        return out


def test_a_soft_nut_is_measured_fitted_and_corrected_on_short_steps(tmp_path: Path):
    """The ladder's curve on short steps either way, and with the plane's model on: X held
    at 400 mm while Y goes up a column."""
    out = asyncio.run(asyncio.wait_for(soft_nut(tmp_path), 120))
    print(out)
    assert abs(out["lost_um"] - LOST_UM) < 2.0, out
    assert out["miss_um"] > 0.5 * LOST_UM, out  # a full switch overshoots short reversals
    assert out["switch_rms_um"] > 8.0, out
    assert out["curve_rms_um"] < 0.25 * out["switch_rms_um"], out
    assert out["curve_max_um"] < 3.0, out  # 1.6 µm: straight lines between the rungs 3.1
    # X sent again up a column of Y targets, its command going on 58 µm: 0.8 µm at most
    # (before: 11.4 µm off at the top, the engagement left where the first step put it);
    # approached in + at every stop: 0.4
    assert max(map(abs, out["column_dx_um"])) < 1.5, out
    assert max(map(abs, out["column_again_dx_um"])) < 1.0, out


def test_commission_finds_a_soft_nut_and_writes_its_curve(tmp_path: Path):
    """`compgw commission` on the small random machine with X's lost motion (25 µm) taken
    up over 150 µm: one rung shows less than all of it, the ladder runs, the final config
    carries the curve; Y (a dead band under 2 µm) is left alone."""
    template = tmp_path / "template"
    small_machine(template, seed=7)
    sim_path = template / "sim.yaml"
    sim = yaml.safe_load(sim_path.read_text())
    x = sim["sim"]["machine"]["X"]
    x["deviation"].pop("reverse_column")  # the lost motion is the nut's, taken up softly
    x["lost_motion"] = {"um": 25.0, "takeup": {"curve": "smooth", "distance_um": 150.0}}
    sim_path.write_text(yaml.safe_dump(sim, sort_keys=False))
    with running(template, tmp_path / "m") as rig:
        lead = rig.machine["axes"]["X"]["lead_mm"]
        proc = Proc(["-m", "gateway.cli", "commission", "-c", str(rig.config),
                     "--gateway", f"127.0.0.1:{rig.gw_port}",
                     "--laser", f"127.0.0.1:{rig.sim_port}:20", "--axes", "X",
                     "--lead-mm", f"X={lead:g}", "--tolerance-um", "5", "--no-progress",
                     "--no-heat-warmup"])  # (the suite's time: the take-up is what is tested)
        rc = proc.popen.wait(timeout=300)
        assert rc in (0, 1) and (rig.dir / "commission" / "summary.json").exists(), proc.text()
        state = json.loads((rig.dir / "commission" / "commission.json").read_text())
        found = state["identify"]["takeup-X"]
        assert found["kept"] and abs(found["lost_um"] - 25.0) < 2.0, found
        assert {"takeup-probe-X", "takeup-X"} <= set(state["steps"])
        final = yaml.safe_load(rig.config.read_text())["axes"]["X"]["compensation"]
        curve = final["takeup"]
        assert curve["fraction"][-1] == 1.0 and curve["fraction"][0] < 0.3, curve
        assert "taken up over a reversal of about" in proc.text()
        # judged where nothing was fitted: random short steps in the after-run
        summary = json.loads((rig.dir / "commission" / "summary.json").read_text())
        steps = summary["axes"]["X"]["short_steps"]
        assert steps["rms_um"] < 2.0 and steps["switch_miss_um"] > 15.0, steps
        state = json.loads((rig.dir / "commission" / "commission.json").read_text())
        assert len(state["steps"]["after-steps-X"]["parts"]) == 1  # references around all
        report = (rig.dir / "commission" / "report" / "report.html").read_text()
        assert "id='short-steps-X'" in report


def test_the_take_up_is_said_where_the_curve_shows_all_of_it():
    """Trial (issue 54): "taken up over a reversal of about 1269 µm" where the ladder
    showed all of the lost motion by the 40 µm rung: the curve's last point, not its
    first full one."""
    section = {"reversal_um": [5.0, 10.0, 20.0, 40.0, 80.0, 640.0, 1269.0],
               "fraction": [0.2, 0.45, 0.8, 1.0, 1.0, 1.0, 1.0]}
    assert full_takeup_um(section) == 40.0
    assert full_takeup_um({"reversal_um": [5.0, 10.0], "fraction": [0.3, 0.9]}) == 10.0
