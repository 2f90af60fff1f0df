"""The zone warm-up's choice of growth shape (gateway.calibration.thermal.thermal_shape): the
truth is the sim's 1-D heat equation of the screw (warm where its nut runs) or a screw at
one temperature along its length, never the gateway's travel counts it is judged against."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import yaml

from gateway.calibration.commissioning.configs import (
    HEADER,
    Tables,
    identification,
    own_config_path,
    with_tables,
)
from gateway.calibration.fitting.plans_scans import warmup_plan
from gateway.calibration.plans.rawdata import RawData
from gateway.calibration.thermal.thermal_shape import thermal_shape_fit
from gateway.calibration.thermal.warmup_heat import warmup_heat_fit
from gateway.compensation.errors import TableError
from gateway.config import AxisThermal, load_config
from sim.config_truth import ScrewHeat
from sim.heat import ScrewHeatModel

TRAVEL, SPEED, NUT = (0.0, 600.0), 100.0, 40.0
SCREW = (-NUT, 600.0 + NUT)  # fixed at the low end, the Δa sensor at the free (high) end
PLACES = [600 * f for f in (0.12, 0.22, 0.4, 0.5, 0.6, 0.78, 0.88)]


def _plan():
    return warmup_plan("X", (180.0, 420.0), SPEED, 1800.0, 570.0, places_mm=PLACES)


def _stops(plan, heat):
    """The plan run in machine time (``SPEED``, each reading's dwell), every move told to
    ``heat`` (``heat.move(t0, t1, x0, x1)``; None: time only): (move, x_mm, t_s) per
    measured stop."""
    t, pos = 0.0, None
    for m in plan.moves:
        x = m.target_mm[0]
        if pos is not None and x != pos:
            dt = abs(x - pos) / SPEED
            if heat is not None:
                heat.move(t, t + dt, pos, x)
            t += dt
        pos = x
        if m.measured:
            t += m.dwell_s or 0.0
            yield m, x, t


def _raw(plan, growth_at, noise_um: float, seed: int) -> RawData:
    """The plan run in machine time; ``growth_at(x, t)`` (mm) the truth; Δa read at the
    free end. Readings carry ``noise_um`` of Gaussian noise."""
    rng = np.random.default_rng(seed)
    rows: list[tuple[int, int, float, float, float]] = []
    for m, x, t in _stops(plan, growth_at):
        noise = rng.normal(0.0, noise_um / 1000.0, 2)
        rows.append((m.run, m.direction, x, x + growth_at(x, t) + noise[0],
                     growth_at(SCREW[1], t) + noise[1] / 5))  # fmt: skip
    run, direction, target, actual, d_a = map(np.array, zip(*rows, strict=True))
    return RawData(("X",) * len(rows), run.astype(np.int64), direction.astype(np.int8),
                   target, actual, {"delta_a_mm": tuple(f"{v:.7f}" for v in d_a)},
                   tuple(range(2, 2 + len(rows))), "warmup-X.csv")  # fmt: skip


class _NutHeat:
    """The sim's screw: heat where the nut runs, conducted and lost to the air."""

    def __init__(self) -> None:
        self.model = ScrewHeatModel(ScrewHeat(lead_mm=5.0, drag_torque_Nm=0.06,
                                              diameter_mm=16.0, nut_length_mm=NUT,
                                              h_W_m2K=15.0, screw_mm=SCREW,
                                              fixed_end_mm=SCREW[0]), TRAVEL)  # fmt: skip

    def move(self, t0: float, t1: float, x0: float, x1: float) -> None:
        self.model.add_move(t0, t1, x0, x1, SPEED)

    def __call__(self, x: float, t: float) -> float:
        return self.model.growth_mm(x, t)


class _EvenHeat:
    """A screw at one temperature along its length, rising to 3 K with a 600 s lag."""

    def move(self, t0: float, t1: float, x0: float, x1: float) -> None:
        pass

    def __call__(self, x: float, t: float) -> float:
        return 11.5e-6 * 3.0 * (1.0 - np.exp(-t / 600.0)) * (x - SCREW[0])


THERMAL = AxisThermal(source="da", length_mm=600.0, origin_mm=SCREW[0])


def test_a_screw_warm_where_its_nut_runs_gets_the_travel_profile() -> None:
    plan = _plan()
    fit = thermal_shape_fit(_raw(plan, _NutHeat(), 0.3, 1), plan, "X", THERMAL, TRAVEL)
    assert fit.growth_max_um > 10.0
    assert fit.shape == "profile" and fit.profile() is not None
    assert fit.profile_rms_um < 0.35 * fit.linear_rms_um, fit
    # the profile forgets as the screw cools: ρ·c·d / 4h = 963 s for this screw in air
    assert fit.tau_s == pytest.approx(7850 * 460 * 0.016 / (4 * 15.0), rel=0.15)
    # the screw's ends: its fixed end, and as far past the travel's other end (the sim's)
    assert fit.profile() == {"spread_mm": fit.spread_mm, "memory_s": fit.tau_s,
                             "memory_mm": pytest.approx(SPEED * fit.tau_s, rel=0.01),
                             "screw_mm": list(SCREW)}


def test_an_evenly_warm_screw_stays_linear_with_its_length() -> None:
    plan = _plan()
    fit = thermal_shape_fit(_raw(plan, _EvenHeat(), 0.3, 2), plan, "X", THERMAL, TRAVEL)
    assert fit.shape == "linear" and fit.profile() is None, fit
    assert fit.length_mm == pytest.approx(SCREW[1] - SCREW[0], rel=0.03)
    assert fit.linear_rms_um < 0.6
    assert fit.tau_s == pytest.approx(600.0, rel=0.05)  # its rise


def test_a_warm_up_read_at_one_place_cannot_tell_the_shape() -> None:
    plan = warmup_plan("X", (30.0, 570.0), SPEED, 600.0, 570.0)
    with pytest.raises(TableError, match="3 places or more"):
        thermal_shape_fit(_raw(plan, _EvenHeat(), 0.3, 3), plan, "X", THERMAL, TRAVEL)


def test_the_chosen_shape_reaches_the_configs_commissioning_writes(tmp_path: Path) -> None:
    """Tables keep the choice across a resume (JSON); the tables' configs have it and the
    gateway loads it (a Δa source: example.yaml's X); the identification config right
    after the zone warm-up spreads linearly; a linear choice clears the user's profile."""
    root = Path(__file__).resolve().parents[1]
    original = yaml.safe_load((root / "config" / "example.yaml").read_text())
    original["axes"]["X"]["compensation"]["thermal"]["profile"] = {"spread_mm": 60.0}
    tables = Tables(thermal_length_mm={"X": 812.5, "Y": 600.0},
                    thermal_profile={"X": {"spread_mm": 150.0}})  # fmt: skip
    tables = Tables.from_json(json.loads(json.dumps(tables.to_json())))

    def loaded(data: dict) -> AxisThermal:
        path = tmp_path / "gw.yaml"
        path.write_text(yaml.safe_dump(data))
        for name in ("x_pitch.csv", "y_pitch.csv"):  # the example's tables beside it
            src = root / "config" / name
            if src.exists():
                (tmp_path / name).write_text(src.read_text())
        th = load_config(path).axes["X"].compensation.thermal
        assert th is not None and th.length_mm == 812.5
        return th

    th = loaded(with_tables(original, ("X", "Y"), tables, planar=False))
    assert th.profile is not None and th.profile.spread_mm == 150.0
    assert loaded(identification(original, ("X", "Y"), tables)).profile is None
    tables.thermal_profile["X"] = None  # the warm-up said linear: the user's profile goes
    assert loaded(with_tables(original, ("X", "Y"), tables, planar=False)).profile is None


def _raw_temperature(plan, heat: _NutHeat, spot_mm: float, seed: int) -> RawData:
    """The plan on the nut-heated screw, with a temperature sensor at ``spot_mm`` (°C)."""
    rng = np.random.default_rng(seed)
    rows = [(m.run, m.direction, x, x + heat(x, t) + rng.normal(0.0, 0.3e-3),
             20.0 + heat.model.temperature_rise_K(spot_mm, t))
            for m, x, t in _stops(plan, heat)]  # fmt: skip
    run, direction, target, actual, temp = map(np.array, zip(*rows, strict=True))
    return RawData(("X",) * len(rows), run.astype(np.int64), direction.astype(np.int8),
                   target, actual, {"temperature_c": tuple(f"{v:.3f}" for v in temp)},
                   tuple(range(2, 2 + len(rows))), "warmup-X.csv")  # fmt: skip


def test_heat_from_motion_replaces_a_sensor_beyond_the_zone() -> None:
    """A temperature sensor at 90 mm, beyond the zone the warm-up cycles (180-420 mm): the
    heat of the axis's own motion, where it travelled, explains the growth the sensor
    cannot; the section it writes loads as the gateway's thermal.motion."""
    plan = _plan()
    th = AxisThermal(source="t", length_mm=600.0, origin_mm=SCREW[0])
    fit = warmup_heat_fit(_raw_temperature(plan, _NutHeat(), 90.0, 4), plan, "X", th,
                          11.5e-6, TRAVEL)  # fmt: skip
    assert fit.replaces_sensor, fit
    assert fit.motion_rms_um < 0.3 * fit.sensor_rms_um
    assert fit.spread_mm is not None  # where it travelled, not linear
    section = fit.config({"X": SPEED})
    assert AxisThermal.model_validate(section).motion is not None


def test_a_sensor_that_reads_the_whole_screw_is_kept() -> None:
    """An evenly warm screw: its temperature anywhere is the whole screw's, the sensor's
    model leaves the noise, and heat from motion does not replace it."""
    plan = _plan()
    even = _EvenHeat()
    th = AxisThermal(source="t", length_mm=600.0, origin_mm=SCREW[0])
    raw = _raw(plan, even, 0.3, 6)  # Δa column unused here; a temperature column instead
    temp = tuple(f"{20.0 + 3.0 * (1.0 - np.exp(-t_s / 600.0)):.3f}"
                 for t_s in _times(plan))  # fmt: skip
    raw = RawData(raw.axis, raw.run, raw.direction, raw.target_mm, raw.actual_mm,
                  {"temperature_c": temp}, raw.lines, raw.source)  # fmt: skip
    fit = warmup_heat_fit(raw, plan, "X", th, 11.5e-6, TRAVEL)
    assert fit.sensor_rms_um < 0.6 and not fit.replaces_sensor, fit


def _times(plan) -> list[float]:
    """Machine time at each measured stop, as _raw counts it."""
    return [t for _, _, t in _stops(plan, None)]


def _predicted_after_zone(section: dict, zone_mm: tuple[float, float], places: list[float],
                          truth: _NutHeat | None = None, travel: tuple[float, float] = TRAVEL,
                          ) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """The bench judge's warm-up on a fresh screw: cycle ``zone_mm`` for 30 min, then the
    growth at ``places`` (µm), as the sim's heat equation makes it and as the gateway's
    heat from motion (its own HeatFromMotion and TravelHistory on machine time) predicts."""
    from gateway.compensation.thermal import ThermalStage
    from gateway.thermal_travel import HeatFromMotion, TravelHistory

    th = AxisThermal.model_validate(section)
    t = [0.0]
    clock = lambda: t[0]  # noqa: E731
    heat = HeatFromMotion("X", th.motion, clock=clock)
    history = TravelHistory(th, th.profile, travel, clock=clock) if th.profile else None
    truth = truth or _NutHeat()
    pos = zone_mm[0]
    for x in [pos] + [zone_mm[k % 2 == 0] for k in range(int(1800 * SPEED / np.ptp(zone_mm)))]:
        dt = abs(x - pos) / SPEED
        if dt:
            truth.move(t[0], t[0] + dt, pos, x)
        t[0] += dt
        heat.moved("X", x)
        if history is not None:
            history.move_to(x)
        pos = x
    stage = ThermalStage(th.length_mm, th.origin_mm)
    real = np.array([truth(x, t[0]) for x in places]) * 1e3
    da = heat.delta_a_mm()
    pred = np.array([stage.inverse_scalar(x, history.delta_a_mm(da, x) if history else da) - x
                     for x in places]) * 1e3  # fmt: skip
    return real, pred


@pytest.mark.parametrize("zone", [(0.0, 240.0), (360.0, 600.0), (120.0, 360.0)])
def test_heat_from_motion_holds_on_a_zone_it_was_not_fitted_on(zone) -> None:
    """Fitted on the commissioning's zone (180-420 mm), the model must follow the judge's
    warm-up on another zone: the total elongation follows the heat put in, wherever, and
    the heat stays in the screw at its ends (0.8-1.6 % left; 5.0 and 8.3 % at the ends
    when the profile let it run on past them)."""
    plan = _plan()
    th = AxisThermal(source="t", length_mm=600.0, origin_mm=SCREW[0])
    fit = warmup_heat_fit(_raw_temperature(plan, _NutHeat(), 90.0, 4), plan, "X", th,
                          11.5e-6, TRAVEL)  # fmt: skip
    real, pred = _predicted_after_zone(fit.config({"X": SPEED}), zone,
                                       [30.0, 150.0, 300.0, 450.0, 580.0])  # fmt: skip
    assert np.abs(real).max() > 10.0
    assert np.abs(pred - real).max() < 0.04 * np.abs(real).max(), (real, pred)


def test_heat_left_by_the_runs_before_the_warm_up_is_counted() -> None:
    """The commissioning's own runs before an axis's warm-up (here 40 m of strokes over the
    whole travel in 1800 s, then 900 s of other axes' work) leave heat in its screw that
    fades while the warm-up adds more: the growth read is less than the warm-up's own heat
    makes. Told that travel, the fit follows the judge's warm-up on a fresh screw to 4 %
    of its growth; without it, 7.5 % short."""
    plan = _plan()
    truth = _NutHeat()
    t, pos, prior_m, prior_s = 0.0, 0.0, [], []
    for _ in range(66):  # 66 strokes of 600 mm: 39.6 m in 396 s of motion
        x = 600.0 - pos
        truth.move(t, t + 6.0, pos, x)
        t, pos = t + 6.0 + 21.0, x  # each stroke, then 21 s of runs elsewhere (reads, dwell)
        prior_m.append(0.6)
        prior_s.append(27.0)
    prior_m.append(0.0)
    prior_s.append(900.0)
    t += 900.0

    class _After(_NutHeat):  # the warm-up on that screw, its clock from the warm-up's start
        def __init__(self) -> None:
            self.model = truth.model

        def move(self, t0: float, t1: float, x0: float, x1: float) -> None:
            super().move(t + t0, t + t1, x0, x1)

        def __call__(self, x: float, t_s: float) -> float:
            return super().__call__(x, t + t_s)

    raw = _raw_temperature(plan, _After(), 90.0, 4)
    th = AxisThermal(source="t", length_mm=600.0, origin_mm=SCREW[0])
    err = {}
    for told in (False, True):
        prior = (prior_m, prior_s) if told else ()
        fit = warmup_heat_fit(raw, plan, "X", th, 11.5e-6, TRAVEL, *prior)
        real, pred = _predicted_after_zone(fit.config({"X": SPEED}), (120.0, 360.0),
                                           [30.0, 150.0, 300.0, 450.0, 580.0])  # fmt: skip
        err[told] = float(np.abs(pred - real).max() / np.abs(real).max())
    assert err[True] < 0.12 and err[False] > 1.5 * err[True], err


def test_the_travel_before_a_warm_up_comes_from_the_drift_log() -> None:
    """What the commission hands the fit (:func:`travel_before_warmup` of the drift log up
    to the warm-up's start): the axis's travel between drift readings and the time they
    took. Not timed by the machine's clock: every axis's travel at the commissioning
    speed, or the clock where that is longer. Timed by it: the clock alone, as the
    gateway counts a model fitted on it."""
    from gateway.calibration.commissioning.thermal import travel_before_warmup

    log = [{"odometer_mm": {"X": x, "Y": y}, "wall_s": w} for x, y, w in
           ((0.0, 0.0, 0.0), (200_000.0, 500.0, 1.0), (200_000.0, 30_500.0, 2.0),
            (200_000.0, 30_500.0, 3602.0))]  # fmt: skip
    travel_m, elapsed_s = travel_before_warmup(log, "Y", ("X", "Y"), 100.0, timed=False)
    np.testing.assert_allclose(travel_m, [0.5, 30.0, 0.0])
    # X's 200 m warm-up took 2000 s of Y's cooling; an hour's pause counts by the clock
    np.testing.assert_allclose(elapsed_s, [2005.0, 300.0, 3600.0])
    travel_m, elapsed_s = travel_before_warmup(log, "Y", ("X", "Y"), 100.0, timed=True)
    np.testing.assert_allclose(elapsed_s, [1.0, 1.0, 3600.0])
    assert travel_before_warmup(log[:1], "Y", ("X", "Y"), 100.0, timed=True)[0].size == 0


def test_the_travel_before_the_first_drift_reading_and_after_the_last_counts_too() -> None:
    """The heat still fading in a warm-up is all the travel since the commissioning began:
    the moves before the first drift reading (at the estimated speed: no clock logged
    them) and those from the last reading to the warm-up's start. Rough-1's X moved 3.4 m
    so; left out, its Δa per metre came out 2.4 % short."""
    from gateway.calibration.commissioning.thermal import travel_before_warmup

    log = [{"odometer_mm": {"X": 1673.0, "Y": 527.0}, "wall_s": 100.0}] * 2
    start = {"odometer_mm": {"X": 3391.0, "Y": 527.0}, "wall_s": 150.0}
    travel_m, elapsed_s = travel_before_warmup(log, "X", ("X", "Y"), 100.0, True, start)
    np.testing.assert_allclose(travel_m, [1.673, 0.0, 1.718])
    np.testing.assert_allclose(elapsed_s, [22.0, 0.0, 50.0])
    # a log that begins at the start, with no warm-up start given: as before
    travel_m, _ = travel_before_warmup(log, "X", ("X", "Y"), 100.0, True)
    np.testing.assert_allclose(travel_m, [1.673, 0.0])


def test_a_warm_up_not_timed_by_a_clock_counts_the_other_axes_at_the_speeds_found() -> None:
    """No clock (a sim at time_scale 0): the warm-up's model counts its own axis at the
    estimated speed and each other axis at the ratio a drift references' fit found
    between them (random machine 7: X at 50 mm/s, Y at 120; X's fit found Y 1.9 times
    faster), not at the same estimate."""
    from types import SimpleNamespace

    from gateway.calibration.commissioning.record import Record
    from gateway.calibration.commissioning.thermal import ThermalSteps

    record = Record(Path("/nonexistent"), Path("/nonexistent"))
    record.state["identify"] = {
        "motion-X": {"fitted": True, "motion": {"speeds_mm_s": {"X": 100.0, "Y": 190.0}}},
        "motion-Y": {"fitted": True, "motion": {"speeds_mm_s": {"X": 100.0, "Y": 100.0}}}}
    axes = SimpleNamespace(s=SimpleNamespace(axes=("X", "Y"), speed_mm_s=100.0), config=None)
    steps = ThermalSteps(axes, record, None, print)  # type: ignore[arg-type]
    assert steps._estimated_speeds("Y") == pytest.approx({"X": 100.0 / 1.9, "Y": 100.0})
    assert steps._estimated_speeds("X") == pytest.approx({"X": 100.0, "Y": 190.0})
    record.state["identify"] = {}  # no fit found a ratio: the estimate for every axis
    assert steps._estimated_speeds("Y") == {"X": 100.0, "Y": 100.0}


def _no_sensor_plan():
    """The zone warm-up of an axis with no sensor: both references, beyond the zone."""
    return warmup_plan("X", (180.0, 420.0), SPEED, 1800.0, 570.0, places_mm=PLACES,
                       also_mm=60.0, sensor=False)  # fmt: skip


def test_an_axis_with_no_sensor_gets_its_heat_from_a_zone_warm_up_read_by_the_laser() -> None:
    """No sensor column: the laser's readings alone give the time constant (the two
    references' rise), the screw's fixed end (the linear growth's zero) and its Δa per
    metre; the section loads as the gateway's heat from motion."""
    from gateway.calibration.thermal.warmup_motion import warmup_motion_fit

    plan = _no_sensor_plan()
    assert sum(m.measured for m in plan.moves) > 2 * len(PLACES) + 10
    fit = warmup_motion_fit(_raw(plan, _EvenHeat(), 0.3, 7), plan, "X", TRAVEL)
    assert fit.spread_mm is None, fit  # one temperature along the screw: linear
    assert fit.tau_s == pytest.approx(600.0, rel=0.1)
    assert fit.origin_mm == pytest.approx(SCREW[0], abs=25.0)  # 0.3 µm of noise: ±20 mm
    assert fit.linear_rms_um < 0.6
    section = fit.config({"X": SPEED})
    assert AxisThermal.model_validate(section).motion is not None


@pytest.mark.parametrize("zone", [(0.0, 240.0), (360.0, 600.0)])
def test_heat_from_motion_with_no_sensor_holds_on_a_zone_it_was_not_fitted_on(zone) -> None:
    """The sim's screw warm where its nut runs, no sensor: fitted on the commissioning's
    zone, the model follows the judge's warm-up on another zone to 15 % of its growth."""
    from gateway.calibration.thermal.warmup_motion import warmup_motion_fit

    plan = _no_sensor_plan()
    fit = warmup_motion_fit(_raw(plan, _NutHeat(), 0.3, 8), plan, "X", TRAVEL)
    assert fit.spread_mm is not None, fit  # where it travelled
    real, pred = _predicted_after_zone(fit.config({"X": SPEED}), zone,
                                       [30.0, 150.0, 300.0, 450.0, 580.0])  # fmt: skip
    assert np.abs(real).max() > 10.0
    assert np.abs(pred - real).max() < 0.15 * np.abs(real).max(), (real, pred)


class _FarEndNut(_NutHeat):
    """Random rough machine 0's X screw: fixed at the far end, just beyond a 700 mm travel,
    its heat from the sim's own parameters."""

    def __init__(self) -> None:
        self.model = ScrewHeatModel(ScrewHeat(lead_mm=5.0, drag_torque_Nm=0.0205,
                                              diameter_mm=20.0, nut_length_mm=41.0,
                                              h_W_m2K=24.95, screw_mm=(-41.0, 741.0),
                                              fixed_end_mm=741.0), (0.0, 700.0))  # fmt: skip


def test_a_linear_growth_that_changes_sign_in_the_travel_is_taken_as_the_zone_s_shape() -> None:
    """Read with a rough machine's scatter, the zone's growth looked nearly linear, its
    zero 30-40 mm inside the travel: taken linear, the judge's warm-ups on other zones
    kept 29-61 % of their growth. No screw's heat makes a growth that changes sign along
    the travel: the profile, or linear from the nearer end, whichever leaves less."""
    from gateway.calibration.thermal.warmup_motion import warmup_motion_fit

    travel = (0.0, 700.0)
    places = [700 * f for f in (0.05, 0.12, 0.22, 0.5, 0.78, 0.88, 0.95)]
    plan = warmup_plan("X", (210.0, 490.0), SPEED, 1800.0, places[-1], 10, places_mm=places,
                       also_mm=places[0], sensor=False)  # fmt: skip
    for seed in (1, 2):  # the draws whose linear zero fell inside the travel
        fit = warmup_motion_fit(_raw(plan, _FarEndNut(), 0.8, seed), plan, "X", travel)
        assert fit.spread_mm is not None and fit.origin_mm == 700.0, fit
        for zone in ((0.0, 240.0), (460.0, 700.0), (120.0, 360.0)):
            real, pred = _predicted_after_zone(fit.config({"X": SPEED}), zone,
                                               [30.0, 150.0, 300.0, 450.0, 600.0, 680.0],
                                               _FarEndNut(), travel)  # fmt: skip
            assert np.abs(pred - real).max() < 0.3 * np.abs(real).max(), (seed, zone)


def test_a_warm_up_with_no_growth_gives_no_model_and_says_why() -> None:
    from gateway.calibration.thermal.warmup_motion import warmup_motion_fit

    plan = _no_sensor_plan()
    with pytest.raises(TableError, match=r"warmup-X.csv: axis X: .*under 3 µm: too little heat"):
        warmup_motion_fit(_raw(plan, _Cold(), 0.3, 9), plan, "X", TRAVEL)


def test_a_warm_up_whose_growth_is_its_noise_gives_no_model() -> None:
    """Issue 52: at 3 x a plain calibration's time sdss-1396's Y (a plate with 1 µm of
    repeatability and almost no heat) got a zone warm-up whose readings spread 2.8 µm;
    heat from motion fitted them with τ 90 s and left 1.9 µm RMS, and the model it put
    in the final config read E 13.8 µm at the judge's targets (6.9 without). A model that
    leaves more than half of what the places grew is refused, by name."""
    from gateway.calibration.thermal.warmup_motion import warmup_motion_fit

    plan = _no_sensor_plan()

    class _Faint(_EvenHeat):
        def __call__(self, x: float, t: float) -> float:
            return 0.15 * super().__call__(x, t)  # about 3.4 µm at the free end

    with pytest.raises(TableError, match=r"warmup-X.csv: axis X: heat from motion leaves .* "
                       r"not the screw's heat"):  # fmt: skip
        warmup_motion_fit(_raw(plan, _Faint(), 1.5, 4), plan, "X", TRAVEL)
    fit = warmup_motion_fit(_raw(plan, _Faint(), 0.1, 4), plan, "X", TRAVEL)  # read clean
    assert fit.linear_rms_um < 0.3


class _Cold(_EvenHeat):
    """A screw that does not warm."""

    def __call__(self, x: float, t: float) -> float:
        return 0.0


def test_a_warm_up_model_is_checked_on_the_drift_of_other_runs() -> None:
    """The drift references of the runs after the warm-up judge its model, nothing
    refitted: the model they were made by leaves the noise, one that cools 4 x too slowly
    leaves most of the drift."""
    from gateway.calibration.thermal.heat_fit import drift_left_um
    from gateway.compensation.thermal import motion_heat_series_m

    rng = np.random.default_rng(3)
    section = {"origin_mm": -40.0, "length_mm": 640.0,
               "motion": {"delta_a_um_per_m": 0.9, "tau_s": 900.0, "speeds_mm_s": {"X": 100.0}}}
    strokes = rng.uniform(0.0, 30.0, 60)  # m of travel between readings, 120 s apart
    odo_m = np.cumsum(strokes)
    wall = np.arange(60) * 120.0 + 120.0
    heat = motion_heat_series_m(strokes, np.maximum(strokes * 10.0, 120.0), 900.0)
    refs = (60.0, 570.0)
    growth = 0.9 * heat[:, None] * (np.array(refs) + 40.0)[None, :] / 640.0
    growth += rng.normal(0.0, 0.2, growth.shape)
    good = drift_left_um("X", section, {"X": odo_m}, wall, growth, refs)
    slow = {**section, "motion": {**section["motion"], "tau_s": 3600.0}}
    bad = drift_left_um("X", slow, {"X": odo_m}, wall, growth, refs)
    spread = float(np.sqrt(np.mean((growth - growth[0]) ** 2)))
    assert spread > 5.0
    assert good < 0.4 and bad > 0.5 * spread, (good, bad, spread)


def test_a_warm_up_is_timed_by_the_readings_clock_only_where_it_is_the_machine_s() -> None:
    """The raw file's time_s times the fit where it spans the plan's time (a real machine);
    a simulator's clock that runs with its moves, not with the computer's, spans seconds:
    the plan's estimated times then (the config's speeds count them)."""
    from gateway.calibration.thermal.thermal_shape import stop_times_s
    from gateway.calibration.thermal.warmup_heat import readings_clock_s

    plan = _no_sensor_plan()
    raw = _raw(plan, _EvenHeat(), 0.3, 10)
    assert readings_clock_s(raw, plan, "X") is None  # no time_s column
    planned = stop_times_s(plan, "X")
    for scale, used in ((1.3, True), (0.01, False)):
        timed = RawData(raw.axis, raw.run, raw.direction, raw.target_mm, raw.actual_mm,
                        {"time_s": tuple(f"{1e9 + scale * t:.3f}" for t in planned)},
                        raw.lines, raw.source)  # fmt: skip
        assert (readings_clock_s(timed, plan, "X") is not None) == used, scale


def test_a_carried_on_run_decides_from_the_users_own_config(tmp_path: Path) -> None:
    """A run carried on (or resumed) finds the gateway running a config commissioning
    wrote, with the heat-from-motion model the run before fitted: what the user set is in
    the copy kept before it began, and that is what decides (an axis with no thermal
    setting of its own keeps its drift taken off)."""
    config, original = tmp_path / "gw.yaml", tmp_path / "commission" / "original.yaml"
    config.write_text("axes: {}\n")
    assert own_config_path(config, original) == config  # nothing kept yet: the file itself
    original.parent.mkdir()
    original.write_text("axes: {}\n")
    assert own_config_path(config, original) == config  # the user's own, edited or not
    config.write_text(HEADER.format(phase="full", original=original) + "axes: {}\n")
    assert own_config_path(config, original) == original


class _ShortScrew:
    """Random smooth machine 2's Y: 150 mm of travel, fixed 59 mm below it, growing about
    3 µm at the far end in a warm-up (the sim's heat per metre, its τ of 860 s)."""

    def move(self, t0: float, t1: float, x0: float, x1: float) -> None:
        pass

    def __call__(self, x: float, t: float) -> float:
        return 1.45e-5 * (1.0 - np.exp(-t / 860.0)) * (x + 59.0)


def test_a_light_growth_s_fixed_end_rests_on_all_the_references_readings() -> None:
    """Issue 52: smooth-2's Y grew 3.4 µm in its warm-up; each reference's growth was
    counted from its one cold reading (±0.45 µm), which put the fixed end at −28 mm (the
    sim's −59) and left 27 % of the judge's zone test. Each reference's cold value fitted
    as an offset rests on all its readings: over twelve draws of the noise every warm-up
    fits, its fixed end within 30 mm of the truth (before: two draws fitted nothing, the
    others' ends 6-1442 mm off, median 72)."""
    from gateway.calibration.thermal.warmup_motion import warmup_motion_fit

    plan = warmup_plan("X", (45.0, 105.0), 50.0, 1800.0, 132.0,
                       places_mm=[33.0, 60.0, 75.0, 90.0, 117.0], also_mm=18.0,
                       sensor=False)  # fmt: skip
    off = [abs(warmup_motion_fit(_raw(plan, _ShortScrew(), 0.45, seed), plan, "X",
                                 (0.0, 150.0)).origin_mm + 59.0)
           for seed in range(1, 13)]  # fmt: skip
    assert max(off) < 30.0 and float(np.median(off)) < 15.0, off


FIVE, SEVEN = [33.0, 60.0, 75.0, 90.0, 117.0], [18.0, 33.0, 60.0, 75.0, 90.0, 117.0, 132.0]


def test_a_light_growth_read_at_the_noise_is_not_refused_for_leaving_the_noise() -> None:
    """A warm-up that grew 3 µm, read with 0.45 µm of scatter a stop, leaves that scatter at
    its places read once cold and once warm, whatever the model. A fit is refused only
    where it leaves more than half the growth and more than the references' own scatter
    explains, its growth standing out of that. The draws here: the five the former rule
    refused (before 86c3f5c: five of eighty, each leaving the axis's heat in), of which
    one's growth does not stand out (five places, seed 33), and the first four of each
    place set. The rate over eighty draws, one refused: bench/light_growth.py."""
    from gateway.calibration.thermal.warmup_motion import warmup_motion_fit

    refused = []
    for places, seeds in ((FIVE, (1, 2, 3, 4, 18, 25, 33)), (SEVEN, (1, 2, 3, 4, 11, 14))):
        plan = warmup_plan("X", (45.0, 105.0), 50.0, 1800.0, 132.0, places_mm=places,
                           also_mm=18.0, sensor=False)  # fmt: skip
        for seed in seeds:
            try:
                warmup_motion_fit(_raw(plan, _ShortScrew(), 0.45, seed), plan, "X", (0.0, 150.0))
            except TableError as exc:
                assert "scatter explains" in str(exc)
                refused.append((len(places), seed))
    assert set(refused) <= {(5, 33)}, refused


@pytest.mark.parametrize("origin_mm, screw_mm, memory_mm", [
    (-59.0, (-59.0, 160.0), 100_000.0), (200.0, (-10.0, 200.0), 3000.0),
    (-20.0, None, 100_000.0)])  # fmt: skip
def test_a_fit_s_fractions_are_what_the_gateway_would_count_stop_by_stop(
        origin_mm: float, screw_mm: tuple[float, float] | None,
        memory_mm: float) -> None:  # fmt: skip
    """``profile_fractions`` reads every stop of a warm-up at once (the gateway's hot path
    keeps its scalar :meth:`TravelHistory.delta_a_mm`, four times faster on one target):
    at each measured stop it equals that path, the plan's moves sent one stop at a time,
    on either side of the travel's fixed end, with the screw's ends folded or not."""
    from gateway.calibration.thermal.thermal_shape import profile_fractions
    from gateway.config import TravelProfile
    from gateway.thermal_travel import TravelHistory

    plan = warmup_plan("X", (45.0, 105.0), 50.0, 1800.0, 132.0,
                       places_mm=[33.0, 60.0, 75.0, 90.0, 117.0], also_mm=18.0,
                       sensor=False)  # fmt: skip
    thermal = AxisThermal(source="x", length_mm=300.0, origin_mm=origin_mm)
    for spread_mm in (50.0, 300.0):
        profile = TravelProfile(spread_mm=spread_mm, memory_mm=memory_mm, screw_mm=screw_mm)
        for length_mm in (150.0, 480.0):
            th = thermal.model_copy(update={"length_mm": length_mm, "profile": profile})
            gateway = TravelHistory(th, profile, (0.0, 150.0), clock=lambda: 0.0)
            by_stop, going = [], []
            for move in plan.moves:
                going.append(float(move.target_mm[0]))
                if move.measured:
                    gateway.moves_to(going)
                    lever = going[-1] - origin_mm
                    by_stop.append(gateway.delta_a_mm(1.0, going[-1]) * lever / length_mm
                                   if abs(lever) >= 1.0 else 0.0)  # fmt: skip
                    going = []
            got = profile_fractions(plan, "X", thermal, profile, (0.0, 150.0), length_mm)
            assert got.shape == (len(by_stop),)
            assert np.allclose(got, by_stop, rtol=1e-12, atol=1e-12), (spread_mm, length_mm)
