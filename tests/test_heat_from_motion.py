"""thermal.motion: Δa without a sensor, from the heat an axis's own moves put into its
screw; and its fit from commissioning's drift references (gateway/calibration/heat_fit)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from gateway.calibration.commissioning.thermal import travel_before_warmup
from gateway.calibration.thermal.heat_fit import clock_kept_time, motion_heat_fit
from gateway.calibration.thermal.run_levels import (
    means_by,
    on_the_way,
    row_odometer_mm,
    run_levels_um,
)
from gateway.compensation.errors import TableError
from gateway.compensation.thermal import (
    motion_heat_after_m,
    motion_heat_m,
    motion_heat_one_m,
    motion_heat_series_m,
)
from gateway.config import AxisThermal, MotionHeat
from gateway.sensors import SensorSet
from gateway.thermal_travel import HeatFromMotion


def test_steady_travel_levels_off_at_speed_times_tau_and_a_pause_cools() -> None:
    """Travel at v for a long time: heat → v·τ (the continuous solution, not the recursion);
    a pause of τ leaves 1/e."""
    v_m_s, tau = 0.1, 300.0
    strokes = 2000
    heat = motion_heat_series_m(np.full(strokes, 0.05), np.full(strokes, 0.5), tau)
    t = np.arange(1, strokes + 1) * 0.5
    assert heat == pytest.approx(v_m_s * tau * (1 - np.exp(-t / tau)), rel=1e-9)
    assert motion_heat_m(heat[-1], 0.0, tau, tau) == pytest.approx(heat[-1] / math.e)
    with pytest.raises(Exception, match="tau > 0"):
        motion_heat_m(0.0, 0.1, 1.0, 0.0)


def test_one_screw_in_plain_floats_is_the_array_form() -> None:
    """The gateway's per-request form (plain floats) gives what the array form gives, over
    stretches from none to many time constants, and refuses what it refuses."""
    rng = np.random.default_rng(5)
    heat, travel = rng.uniform(0, 30, 400), rng.uniform(0, 2, 400)
    elapsed = np.concatenate([[0.0, 1e-15, 1e-9], 10 ** rng.uniform(-6, 5, 397)])
    tau = rng.uniform(60, 3000, 400)
    want = motion_heat_m(heat, travel, elapsed, tau)
    got = [motion_heat_one_m(*map(float, args)) for args in zip(heat, travel, elapsed, tau)]
    assert got == pytest.approx(want, rel=1e-14, abs=1e-15)
    for bad in ((0.0, -0.1, 1.0, 300.0), (0.0, 0.1, -1.0, 300.0), (0.0, 0.1, 1.0, 0.0)):
        with pytest.raises(Exception, match="tau > 0"):
            motion_heat_one_m(*bad)


def test_the_heat_after_a_sequence_at_once_is_the_series_last() -> None:
    """What a model loaded mid-run starts from (hundreds of thousands of moves counted at a
    reload): the series' last value, to rounding, pauses and stretches of many τ included."""
    rng = np.random.default_rng(9)
    travel = rng.uniform(0, 0.5, 3000) * (rng.uniform(size=3000) < 0.7)
    elapsed = np.where(rng.uniform(size=3000) < 0.05, 2000.0, rng.uniform(0, 5, 3000))
    for tau in (60.0, 900.0, 1e5):
        assert motion_heat_after_m(travel, elapsed, tau) == pytest.approx(
            motion_heat_series_m(travel, elapsed, tau)[-1], rel=1e-10)  # fmt: skip
    assert motion_heat_after_m([], [], 900.0) == 0.0


class Clock:
    def __init__(self) -> None:
        self.t = 0.0

    def __call__(self) -> float:
        return self.t


def test_other_axes_moves_pass_time_and_the_wall_clock_counts_pauses() -> None:
    clock = Clock()
    motion = MotionHeat(delta_a_um_per_m=10.0, tau_s=100.0, speeds_mm_s={"X": 100, "Y": 50})
    heat = HeatFromMotion("X", motion, clock)
    heat.moved("X", 0.0)
    heat.moved("X", 500.0)  # 0.5 m in 5 s
    h1 = 0.5 * (1 - math.exp(-0.05)) / 0.05
    assert heat.delta_a_mm() == pytest.approx(10.0 * h1 / 1000)
    heat.moved("Y", 0.0)
    heat.moved("Y", 500.0)  # Y takes 10 s: X's screw cools, nothing added
    assert heat.delta_a_mm() == pytest.approx(10.0 * h1 * math.exp(-0.1) / 1000)
    clock.t += 100.0  # a pause of tau
    assert heat.delta_a_mm() == pytest.approx(10.0 * h1 * math.exp(-1.1) / 1000)
    heat.moved("Z", 1.0)  # an axis with no speed passes only the wall clock's time
    assert heat.delta_a_mm() == pytest.approx(10.0 * h1 * math.exp(-1.1) / 1000)


def test_a_reload_keeps_the_screws_heat_and_gain_scales_it() -> None:
    motion = MotionHeat(delta_a_um_per_m=20.0, tau_s=1e5, speeds_mm_s={"X": 100})
    th = AxisThermal(length_mm=600, motion=motion)
    sensors = SensorSet({}, {"X": th})
    sensors.moved("X", 0.0)
    sensors.moved("X", 400.0)
    before = sensors.axis_delta_a_mm("X")
    assert before == pytest.approx(20.0 * 0.4 / 1000, rel=1e-4)
    sensors.set_axis_thermal({"X": th.model_copy(update={"gain": 0.5})})
    assert sensors.axis_delta_a_mm("X") == pytest.approx(before * 0.5, rel=1e-6)
    assert sensors.axis_delta_a_mm("Y") is None


def test_a_model_loaded_later_starts_from_the_heat_the_moves_before_it_put_in() -> None:
    """Commissioning loads heat from motion after hours of its own runs: the gateway counted
    every target since it started, so the model begins from that heat, as one loaded at
    the start that saw every move would have it (to the stretches' rounding), not from
    a cold screw; loaded again with another τ, the heat is counted again in that τ."""
    rng = np.random.default_rng(11)
    clock = Clock()
    motion = MotionHeat(delta_a_um_per_m=20.0, tau_s=900.0, speeds_mm_s={"X": 100, "Y": 50})
    th = AxisThermal(length_mm=600, motion=motion)
    sensors = SensorSet({}, {})
    sensors.moves.clock = clock
    witnesses = {tau: HeatFromMotion("X", motion.model_copy(update={"tau_s": tau}), clock)
                 for tau in (900.0, 300.0)}  # fmt: skip
    for _ in range(3000):  # an hour and more of runs of both axes, pauses between some
        axis = "X" if rng.uniform() < 0.6 else "Y"
        to = float(rng.uniform(0.0, 500.0))
        clock.t += float(rng.choice([0.0, 0.5, 20.0], p=[0.6, 0.3, 0.1]))
        sensors.moved(axis, to)
        for heat in witnesses.values():
            heat.moved(axis, to)
    clock.t += 60.0
    assert witnesses[900.0].delta_a_mm() > 5e-3  # µm of heat: a warm screw
    sensors.set_axis_thermal({"X": th})
    assert sensors.axis_delta_a_mm("X") == pytest.approx(witnesses[900.0].delta_a_mm(),
                                                          rel=0.02)  # fmt: skip
    faster = th.model_copy(update={"motion": motion.model_copy(update={"tau_s": 300.0})})
    sensors.set_axis_thermal({"X": faster})
    assert sensors.axis_delta_a_mm("X") == pytest.approx(witnesses[300.0].delta_a_mm(),
                                                          rel=0.02)  # fmt: skip
    cold = SensorSet({}, {"X": th})  # a gateway that saw none of it: a cold screw
    cold.moves.clock = clock
    assert cold.axis_delta_a_mm("X") == 0.0


def test_thermal_takes_a_source_or_motion_not_both() -> None:
    motion = {"delta_a_um_per_m": 1.0, "tau_s": 10.0}
    with pytest.raises(ValueError, match="either source"):
        AxisThermal.model_validate({"length_mm": 100, "source": "s", "motion": motion})
    with pytest.raises(ValueError, match="either source"):
        AxisThermal.model_validate({"length_mm": 100})


def _commissioning(rng: np.random.Generator, tau_s: float, fixed_mm: float, rise_um_per_m: float,
                   refs: tuple[float, float], hours: float = 3.0):
    """A lumped screw heated by X's travel, cooled by time, stepped in 0.1 s of machine time
    (the ODE integrated by Euler, not the fit's closed form); X at 100 mm/s, Y at 40; the
    drift read every 60 moves at both references, with 0.1 µm of noise."""
    dt, speeds = 0.1, {"X": 100.0, "Y": 40.0}
    x = {"X": 0.0, "Y": 0.0}
    odo = {"X": 0.0, "Y": 0.0}
    theta = 0.0  # growth per mm of lever, µm/mm
    log_odo: dict[str, list[float]] = {"X": [], "Y": []}
    growth: list[list[float]] = []
    t = 0.0
    move = 0
    while t < hours * 3600:
        axis = "X" if (move // 300) % 3 < 2 else "Y"  # runs of one axis, as in commissioning
        to = float(rng.uniform(0, 500))
        d = abs(to - x[axis])
        steps = max(1, round(d / speeds[axis] / dt))
        for _ in range(steps):
            q = rise_um_per_m * (d / 1000 / steps) / dt if axis == "X" else 0.0
            theta += (q - theta / tau_s) * dt
        t += steps * dt
        odo[axis] += d
        x[axis] = to
        move += 1
        if move % 60 == 0:
            for a in odo:
                log_odo[a].append(odo[a] / 1000)
            growth.append([theta * (r - fixed_mm) * 1e-3 + rng.normal(0, 0.1) for r in refs])
    return log_odo, growth


def test_the_fit_finds_tau_the_fixed_end_and_the_heat_per_metre() -> None:
    rng = np.random.default_rng(7)
    refs = (26.0, 475.0)
    for tau, fixed, rise in ((600.0, -40.0, 0.3), (1500.0, 540.0, 0.3)):
        odo, growth = _commissioning(rng, tau, fixed, rise, refs)
        wall = np.zeros(len(growth))  # a simulator's clock: the wall saw none of it
        # both speeds estimated at 100 mm/s: Y's moves take 2.5 times longer than that
        fit = motion_heat_fit("X", odo, wall, growth, refs, {"X": 100.0, "Y": 100.0}, (0, 500))
        assert fit.tau_s == pytest.approx(tau, rel=0.12)
        assert fit.origin_mm == pytest.approx(fixed, abs=10)
        # Δa per metre of heat at the fit's length = rise · length (µm/mm·m → µm/m)
        assert fit.delta_a_um_per_m / fit.length_mm * 1e3 == pytest.approx(rise, rel=0.1)
        assert fit.residual_rms_um < 0.2
        speeds = fit.config()["motion"]["speeds_mm_s"]
        assert speeds["X"] == 100.0 and speeds["Y"] == pytest.approx(40.0, rel=0.25)


def test_too_little_drift_or_heat_that_never_levels_off_is_refused_by_name() -> None:
    rng = np.random.default_rng(8)
    refs = (26.0, 475.0)
    odo, growth = _commissioning(rng, 600.0, -40.0, 0.002, refs)
    with pytest.raises(TableError, match=r"axis X: the screw grew .* no heat to model"):
        motion_heat_fit("X", odo, np.zeros(len(growth)), growth, refs, {"X": 100, "Y": 100},
                        (0, 500))
    odo, growth = _commissioning(rng, 1e6, -40.0, 0.2, refs, hours=1.0)
    with pytest.raises(TableError, match=r"axis X: .* never levelled off"):
        motion_heat_fit("X", odo, np.zeros(len(growth)), growth, refs, {"X": 100, "Y": 100},
                        (0, 500))


def test_the_heat_before_a_warm_up_is_counted_on_the_machine_s_own_clock() -> None:
    """A screw worked at 160 mm/s between drift readings on the machine's clock, then warmed
    up: the heat left from before is what that clock says (the gateway counts a timed model
    by it alone), not the commissioning's 100 mm/s estimate, which stretched every stretch,
    cooled the heat 16 % short and fitted Δa per metre 8 % short (random machine 3's X)."""
    rng = np.random.default_rng(3)
    moved_mm = rng.uniform(500.0, 3000.0, 30)  # X's travel per stretch, Y's the same
    took_s = 2 * moved_mm / 160.0 + rng.uniform(0.0, 5.0, 30)  # both axes, and stops
    log = [{"odometer_mm": {"X": float(x), "Y": float(x)}, "wall_s": float(t)}
           for x, t in zip(np.concatenate([[0.0], np.cumsum(moved_mm)]),
                           np.concatenate([[0.0], np.cumsum(took_s)]))]  # fmt: skip
    tau = 1033.0
    truth = motion_heat_series_m(moved_mm / 1000.0, took_s, tau)[-1]
    travel, elapsed = travel_before_warmup(log, "X", ("X", "Y"), 100.0, timed=True)
    assert motion_heat_series_m(travel, elapsed, tau)[-1] == pytest.approx(truth, rel=1e-9)
    # without the machine's clock (a simulator's computer time), the estimate stands
    travel, elapsed = travel_before_warmup(log, "X", ("X", "Y"), 100.0, timed=False)
    assert np.all(elapsed >= 2 * moved_mm / 100.0 - 1e-9)
    assert motion_heat_series_m(travel, elapsed, tau)[-1] < 0.95 * truth


def test_a_light_growth_that_stands_out_of_the_references_scatter_is_modelled() -> None:
    """Issue 52: at 1.5 x a plain calibration's time four Y screws grew 1.3-1.6 µm while
    commissioning (their references' scatter 0.1-0.3 µm) and no model was fitted: under
    the 2 µm tolerance. 30 minutes of work on a zone then moved them 13-24 µm. A growth
    that stands out of the references' own scatter (SEEN_X_SCATTER times it, at least
    MIN_SEEN_UM) is modelled; within it, or where no scatter is known yet, the tolerance
    still bounds it."""
    from types import SimpleNamespace

    from gateway.calibration.commissioning.drift import MIN_SEEN_UM, DriftRefs

    rng = np.random.default_rng(11)
    refs = (26.0, 475.0)
    odo, growth = _commissioning(rng, 900.0, -40.0, 0.045, refs, hours=1.5)
    peak = float(np.abs(growth).max())
    assert 1.2 < peak < 2.0  # a light growth, under the 2 µm tolerance
    drift = DriftRefs.__new__(DriftRefs)
    drift.s = SimpleNamespace(tolerance_um=2.0)
    drift.record = SimpleNamespace(state={"ref_scatter": {"X": (24 * (0.1e-3) ** 2, 24)}})
    least = drift.least_growth_um("X")
    assert least == MIN_SEEN_UM < peak
    fit = motion_heat_fit("X", odo, np.zeros(len(growth)), growth, refs, {"X": 100, "Y": 100},
                          (0, 500), least)  # fmt: skip
    assert fit.tau_s == pytest.approx(900.0, rel=0.35)
    assert fit.origin_mm == pytest.approx(-40.0, abs=60)
    with pytest.raises(TableError, match=r"axis X: the screw grew 1.5 µm .* \(under 2\)"):
        motion_heat_fit("X", odo, np.zeros(len(growth)), growth, refs, {"X": 100, "Y": 100},
                        (0, 500), 2.0)  # fmt: skip
    drift.record.state["ref_scatter"]["X"] = (24 * (0.5e-3) ** 2, 24)  # within the scatter
    assert drift.least_growth_um("X") == 2.0
    drift.record.state["ref_scatter"] = {}  # no scatter known: the tolerance
    assert drift.least_growth_um("X") == 2.0


def test_a_time_constant_the_growth_cannot_tell_is_taken_near_a_screw_s() -> None:
    """Issue 52: an 8-minute zone warm-up's growth hardly bends, and τ from 700 to 5000 s fit
    it alike; the least residual took 2686 s for rough-4's X (724 s in the simulator's
    heat equation), and the model grown on for the judge's 30 minutes left 15 of its 25
    µm. Of the τ within LIKE_SHARE of the best residual, the one nearest TAU_LIKELY_S is
    taken; a clear minimum stands, and so does heat that never levelled off."""
    from gateway.calibration.thermal.heat_fit import (
        LIKE_SHARE,
        TAU_GRID_S,
        TAU_LIKELY_S,
        likely_tau,
    )

    log_tau = np.log(TAU_GRID_S)
    flat = 1.0 + 0.5 * LIKE_SHARE * (log_tau - np.log(2686.0)) ** 2 / 4  # 700-5000 s alike
    j = likely_tau(flat)
    assert int(np.argmin(flat)) != j
    assert TAU_GRID_S[j] == pytest.approx(TAU_LIKELY_S, rel=0.1)
    sharp = 1.0 + 10.0 * (log_tau - np.log(400.0)) ** 2  # the drift says 400 s
    assert TAU_GRID_S[likely_tau(sharp)] == pytest.approx(400.0, rel=0.1)
    rising = np.linspace(2.0, 1.0, TAU_GRID_S.size)  # best at the grid's end: never levelled
    assert likely_tau(rising) == TAU_GRID_S.size - 1


def test_iso_runs_levels_give_the_growth_up_to_each_targets_static_error() -> None:
    """Issue 54 point 3 (the ISO runs warm the screw: use them): runs over the same
    targets, each read a static error the same in every run plus the growth then (linear
    from the fixed end), give per run the growth at the references up to one constant
    each; the reversal (↑ against ↓) drops out."""
    rng = np.random.default_rng(11)
    xs = np.linspace(5.0, 495.0, 21)
    static = rng.normal(0.0, 8e-3, xs.size)  # mm
    grow = np.array([0.0, 1.5, 2.6, 3.4])  # µm at 500 mm from a fixed end at 0
    run, target, dev = [], [], []
    for k, g in enumerate(grow):
        for sign in (1, -1):
            run += [k + 1] * xs.size
            target += list(xs)
            dev += list(static + sign * 2e-3 + g * xs / 500.0 * 1e-3
                        + rng.normal(0, 1e-5, xs.size))  # fmt: skip
    # two more runs over the midpoints (other targets, their own static error) later on
    mids = (xs[1:] + xs[:-1]) / 2
    more = np.array([4.0, 4.5])
    static_mids = rng.normal(0.0, 8e-3, mids.size)
    for k, g in enumerate(more):
        for sign in (1, -1):
            run += [k + 11] * mids.size
            target += list(mids)
            dev += list(static_mids + sign * 2e-3
                        + g * mids / 500.0 * 1e-3 + rng.normal(0, 1e-5, mids.size))  # fmt: skip
    lv = run_levels_um(run, target, np.array(dev), (25.0, 475.0))
    assert list(lv.runs) == [1, 2, 3, 4, 11, 12] and len(set(lv.group)) == 2
    assert list(lv.group[:4]) == [lv.group[0]] * 4 and lv.group[4] == lv.group[5] != lv.group[0]
    lever = np.array([25.0, 475.0])[None, :] / 500.0
    want = grow[:, None] * lever
    assert np.allclose(lv.levels_um[:4], want - want.mean(axis=0), atol=0.02), lv.levels_um
    want = more[:, None] * lever
    assert np.allclose(lv.levels_um[4:], want - want.mean(axis=0), atol=0.02), lv.levels_um
    assert 0.0 < lv.noise_um < 0.05  # the readings' 0.01 µm, at the line's ends
    row_s = np.arange(len(run), dtype=float)
    odo = row_odometer_mm(row_s, (0.0, len(run) - 1.0), ({"X": 100.0}, {"X": 900.0}))
    at, per_run = means_by(run, row_s), means_by(run, odo["X"])
    assert np.all(np.diff(at) > 0) and 100.0 < per_run[0] < per_run[-1] < 900.0


def test_heat_known_up_to_a_constant_is_fitted_from_its_changes() -> None:
    """The growth of a few ISO runs is known only up to the static error at each reference
    (``offset``): the fit takes its changes, and finds the same fixed end and heat per
    metre as from the cold start; taken as growth from the cold start, the static error
    is read as heat and the fit is wrong or refused. Split into two groups (the last
    readings over other targets, another constant), it still finds them."""
    rng = np.random.default_rng(12)
    refs = (26.0, 475.0)
    odo, growth = _commissioning(rng, 900.0, -40.0, 0.3, refs, hours=1.0)
    pick = np.arange(3, len(growth), max(1, len(growth) // 6))[:6]
    odo_few = {a: np.asarray(v)[pick] for a, v in odo.items()}
    levels = np.asarray(growth)[pick] + np.array([4.0, -3.0])  # the static error: unknown
    wall = np.zeros(pick.size)
    fit = motion_heat_fit("X", odo_few, wall, levels, refs, {"X": 100.0, "Y": 100.0},
                          (0, 500), offset=True)  # fmt: skip
    assert fit.origin_mm == pytest.approx(-40.0, abs=40)
    assert fit.delta_a_um_per_m / fit.length_mm * 1e3 == pytest.approx(0.3, rel=0.3)
    apart = levels + np.array([[0.0, 0.0]] * 4 + [[-6.0, 2.0]] * 2)  # the last two's own
    split = motion_heat_fit("X", odo_few, wall, apart, refs, {"X": 100.0, "Y": 100.0},
                            (0, 500), offset=[0, 0, 0, 0, 1, 1])  # fmt: skip
    assert split.origin_mm == pytest.approx(-40.0, abs=60)
    assert split.delta_a_um_per_m / split.length_mm * 1e3 == pytest.approx(0.3, rel=0.4)
    with pytest.raises(TableError, match=r"6 drift readings in 4 groups, too few"):
        motion_heat_fit("X", odo_few, wall, apart, refs, {"X": 100.0, "Y": 100.0}, (0, 500),
                        offset=[0, 0, 0, 1, 2, 3])  # fmt: skip
    try:
        wrong = motion_heat_fit("X", odo_few, wall, levels, refs, {"X": 100.0, "Y": 100.0},
                                (0, 500))  # fmt: skip
    except TableError:
        return
    assert abs(wrong.origin_mm + 40.0) > 100.0, wrong


def test_the_travel_between_runs_is_placed_in_time_by_the_steps_on_the_way() -> None:
    """The runs' levels alone spread the travel of another step (a scan, the other axis's
    runs) evenly from one run to the next. A burst of travel early in a long pause warms
    the screw and cools off again before the next run: spread evenly, the fit takes a far
    shorter time constant and more heat per metre (553 s for 800 here). With the step's
    ends as points on the way (NaN levels), the heat runs through them as it happened."""
    tau_s, per_um_m_mm, origin_mm, refs = 800.0, 0.002, -50.0, (26.0, 475.0)
    speed = np.zeros(4000)  # mm/s in each second
    runs = [(0, 300), (300, 600), (600, 900), (2400, 2700), (2700, 3000)]
    for a, b in runs:
        speed[a:b] = 20.0
    speed[900:1000] = 100.0  # another step: 10 m in 100 s, then nothing until 2400 s
    t = np.arange(1.0, 4001.0)
    odo = np.cumsum(speed)
    heat = motion_heat_series_m(speed / 1000.0, np.ones(t.size), tau_s)
    grow = heat[:, None] * per_um_m_mm * (np.array(refs)[None, :] - origin_mm)
    label = np.full(t.size, -1)
    for k, (a, b) in enumerate(runs):
        label[a:b] = k
    on = label >= 0
    levels = np.stack([means_by(label[on], grow[on][:, r]) for r in (0, 1)], axis=1)
    levels += np.array([3.0, -2.0])  # each reference's static error: unknown
    at, run_odo = means_by(label[on], t[on]), means_by(label[on], odo[on])
    spread = motion_heat_fit("X", {"X": run_odo / 1000}, at, levels, refs, {"X": 100.0},
                             (0, 500), 0.3, offset=True)  # fmt: skip
    way_s = np.array([900.0, 1000.0, 2400.0])
    where, at_s, odo_mm = on_the_way(at, {"X": run_odo}, way_s,
                                     {"X": np.interp(way_s, t, odo)})  # fmt: skip
    assert list(where) == [0, 1, 2, 6, 7] and np.all(np.diff(at_s) > 0)
    assert np.all(np.diff(odo_mm["X"]) >= 0)
    full = np.full((at_s.size, 2), np.nan)
    full[where] = levels
    group = np.full(at_s.size, -1)
    group[where] = 0
    placed = motion_heat_fit("X", {"X": odo_mm["X"] / 1000}, at_s, full, refs, {"X": 100.0},
                             (0, 500), 0.3, offset=group)  # fmt: skip
    assert placed.points == 5
    assert placed.tau_s == pytest.approx(tau_s, rel=0.06)
    assert placed.delta_a_um_per_m / placed.length_mm * 1e3 == pytest.approx(2.0, rel=0.03)
    assert placed.origin_mm == pytest.approx(origin_mm, abs=1.0)
    assert abs(spread.tau_s / tau_s - 1.0) > 0.2, spread  # what the points on the way mend


def _strokes(clock: Clock, heat: HeatFromMotion, lo_mm: float, hi_mm: float,
             speed_mm_s: float, seconds: float) -> None:  # fmt: skip
    """Strokes between ``lo_mm`` and ``hi_mm`` at ``speed_mm_s`` for ``seconds`` of the
    clock, each target told to ``heat`` as the gateway tells it."""
    x, end = lo_mm, clock.t + seconds
    while clock.t < end:
        x = hi_mm if x == lo_mm else lo_mm
        heat.moved("X", x)
        clock.t += (hi_mm - lo_mm) / speed_mm_s


def test_a_clocked_fit_counts_time_by_the_clock_not_by_an_estimated_speed() -> None:
    """The moves' time at the estimated speed (100 mm/s) stands in for the clock only where
    the clock did not keep the machine's time. Counted by it on a clocked machine whose X
    runs at 130, the gateway's model ran 1.3 times too fast through continuous strokes
    and left a quarter of a 30-minute warm-up. Fitted on the clock alone (no speeds in
    its config), it follows the warm-up."""
    tau_s, per_um = 700.0, 2.0  # Δa (µm) per metre of heat
    clock = Clock()
    truth = HeatFromMotion("X", MotionHeat(delta_a_um_per_m=per_um, tau_s=tau_s), clock)
    odo, wall, growth, at_mm = [0.0], [0.0], [[0.0, 0.0]], 0.0
    truth.moved("X", 0.0)
    for k in range(12):  # the commissioning: a minute of moves, two still, read
        before = clock.t
        _strokes(clock, truth, 0.0, 100.0 + 20.0 * k, 130.0, 60.0)
        at_mm += 130.0 * (clock.t - before)
        clock.t += 120.0
        odo.append(at_mm / 1000.0)
        wall.append(clock.t)
        g = truth.delta_a_mm() * 1000.0
        growth.append([g * 0.1, g * 0.9])  # references at 10 and 90 % from the fixed end
    odometer_m = {"X": np.array(odo)}
    assert clock_kept_time(odometer_m, wall, {"X": 100.0})
    assert not clock_kept_time(odometer_m, np.array(wall) / 100.0, {"X": 100.0})  # compressed
    fit = motion_heat_fit("X", odometer_m, wall, growth, (50.0, 450.0), None, (0, 500), 0.5)
    assert "speeds_mm_s" not in fit.config()["motion"]
    assert fit.tau_s == pytest.approx(tau_s, rel=0.1)
    clocked = MotionHeat(**fit.config()["motion"])
    estimated = clocked.model_copy(update={"speeds_mm_s": {"X": 100.0}})
    warm = {}
    for name, motion in (("truth", truth.motion), ("clocked", clocked),
                         ("estimated", estimated)):  # fmt: skip
        clock.t = 0.0
        heat = HeatFromMotion("X", motion, clock)
        heat.moved("X", 0.0)
        _strokes(clock, heat, 100.0, 300.0, 130.0, 1800.0)  # the customer's warm-up
        warm[name] = heat.delta_a_mm() / motion.delta_a_um_per_m
    at_length = per_um * fit.length_mm / 500.0  # the truth's Δa where the fit's is given
    assert warm["clocked"] * clocked.delta_a_um_per_m == pytest.approx(
        warm["truth"] * at_length, rel=0.1)  # fmt: skip
    assert warm["estimated"] < 0.85 * warm["truth"]  # what counting at the estimate left


def test_references_counted_from_one_cold_reading_are_fitted_by_their_changes() -> None:
    """The drift references' growth is counted from one reading at the cold start, and
    that reading's own scatter is in every later one (here +0.4 µm at the near reference,
    -0.3 at the far). Taken as zero, the fit moves the screw's fixed end by some 30 mm and
    Δa per metre up 14 %; fitted by its changes (``offset=True``), near the screw's own."""
    rng = np.random.default_rng(13)
    refs = (26.0, 475.0)
    odo, growth = _commissioning(rng, 900.0, -40.0, 0.3, refs, hours=1.5)
    odo = {a: np.concatenate([[0.0], v]) for a, v in odo.items()}
    drift = np.concatenate([[[0.0, 0.0]], np.asarray(growth) - np.array([0.4, -0.3])])
    wall = np.zeros(drift.shape[0])
    fits = {off: motion_heat_fit("X", odo, wall, drift, refs, {"X": 100.0, "Y": 40.0},
                                 (0, 500), offset=off) for off in (False, True)}  # fmt: skip
    per = {off: f.delta_a_um_per_m / f.length_mm * 1e3 for off, f in fits.items()}
    assert fits[True].origin_mm == pytest.approx(-40.0, abs=12.0), fits[True]
    assert per[True] == pytest.approx(0.3, rel=0.05), fits[True]
    assert abs(fits[False].origin_mm + 40.0) > 25.0, fits[False]  # the zero's own scatter


def test_a_drift_faster_than_any_screw_cools_is_not_taken_for_heat() -> None:
    """A drift that follows the moves within a minute (here a τ of 40 s; on a machine: the
    readings' scatter lining up with the travel before each run) is no screw's heat: a
    6 mm screw in a draught takes 108 s. Fitted, it swung the judge's E on rough-6 Y
    from 2.5 to 6.9 µm; refused, naming why."""
    rng = np.random.default_rng(14)
    refs = (26.0, 475.0)
    odo, growth = _commissioning(rng, 40.0, -40.0, 20.0, refs, hours=1.0)
    with pytest.raises(TableError, match=r"axis X: .*faster than any screw cools \(tau \d+ s\)"):
        motion_heat_fit("X", odo, np.zeros(len(growth)), growth, refs,
                        {"X": 100.0, "Y": 40.0}, (0, 500), offset=True)  # fmt: skip
