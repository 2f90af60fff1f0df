"""The travel profile (compensation.thermal.profile): the Δa of a screw warm where its nut
has worked, put where the heat is. Checked against the sim's heat equation of the screw
(sim/heat.py, written independently) on the accuracy judge's warm-up, and by hand."""

from __future__ import annotations

import numpy as np
import pytest

from gateway.compensation.thermal import (
    EndFold,
    ThermalStage,
    fold_at_ends,
    travel_delta_a_mm,
    travel_integral,
    travel_weights,
)
from gateway.config import AxisThermal, TravelProfile
from gateway.thermal_travel import TravelHistory


def test_even_weights_or_none_give_back_the_linear_spread() -> None:
    stage = ThermalStage(1000.0, -40.0)
    x = np.linspace(-400.0, 1400.0, 361)
    even, none = travel_integral(x, np.ones_like(x)), travel_integral(x, np.zeros_like(x))
    for at in (0.0, 333.0, 960.0):
        assert travel_delta_a_mm(0.02, at, x, even, stage, 1) == pytest.approx(0.02)
        assert travel_delta_a_mm(0.02, at, x, none, stage, 1) == 0.02
    # fixed at the high end, the travel below it: the same
    high = ThermalStage(1000.0, 1040.0)
    assert travel_delta_a_mm(0.02, 100.0, x, even, high, -1) == pytest.approx(0.02)


def test_heat_in_one_zone_by_hand() -> None:
    """Weights 1 on 200..400 mm only, fixed end at 0, Δa point at 1000: the growth is 0 up
    to 200, Δa at 400 and beyond; at 300 half of it."""
    stage = ThermalStage(1000.0, 0.0)
    x = np.arange(-100.0, 1100.0 + 1e-9, 1.0)
    w = ((x >= 200) & (x <= 400)).astype(float)
    da = 0.03

    def growth(at: float) -> float:
        return travel_delta_a_mm(da, at, x, travel_integral(x, w), stage, 1) * (at - 0.0) / 1000.0

    assert growth(100.0) == pytest.approx(0.0, abs=1e-6)
    assert growth(300.0) == pytest.approx(da / 2, rel=0.01)
    assert growth(800.0) == pytest.approx(da, rel=0.01)


def _judge_warmup(rng: np.random.Generator, zone_at: float | None = None,
                  ends: bool = False) -> tuple[float, ...]:  # fmt: skip
    """One random screw cycled over 40 % of its travel for 30 min (as bench/evaluate.py;
    ``zone_at``: where the zone starts, a share of the travel, else random): largest error
    at 5 places of the linear spread and of the travel profile (µm); with ``ends``, also of
    the profile at the screw's own spread, without and with the screw's ends."""
    from sim.config_truth import ScrewHeat
    from sim.heat import ScrewHeatModel

    travel = float(rng.choice(np.arange(300, 1001, 50)))
    nut, speed = float(rng.uniform(30, 60)), float(rng.uniform(50, 200))
    screw = (-nut, travel + nut)
    fixed, free = screw if rng.random() < 0.75 else screw[::-1]
    h = float(rng.uniform(10, 25))
    model = ScrewHeatModel(ScrewHeat(lead_mm=10.0, drag_torque_Nm=0.02, diameter_mm=16.0,
                                     nut_length_mm=nut, h_W_m2K=h, screw_mm=screw,
                                     fixed_end_mm=fixed), (0.0, travel))  # fmt: skip
    # (with the ends: the spread a warm-up fits, about √(κτ) = √(k·d / 4h), in mm)
    spread = 1000.0 * float(np.sqrt(45.0 * 0.016 / (4 * h)))
    profiles = [TravelProfile()] + ([TravelProfile(spread_mm=spread),
                                     TravelProfile(spread_mm=spread, screw_mm=screw)]
                                    if ends else [])  # fmt: skip
    thermal = AxisThermal(source="x", length_mm=abs(free - fixed), origin_mm=fixed,
                          profile=profiles[0])  # fmt: skip
    histories = [TravelHistory(thermal, p, (0.0, travel)) for p in profiles]
    z0 = float(rng.uniform(0, 0.6 * travel)) if zone_at is None else zone_at * travel
    t_s, pos = 0.0, z0
    for history in histories:
        history.move_to(pos)
    while t_s < 1800.0:
        to = z0 + 0.4 * travel if pos == z0 else z0
        dt = abs(to - pos) / speed
        model.add_move(t_s, t_s + dt, pos, to, speed)
        for history in histories:
            history.move_to(to)
        t_s, pos = t_s + dt, to
    da = model.growth_mm(free, t_s) * 1e3 * (1 if free > fixed else -1)  # elongation, µm
    places = rng.uniform(2, travel - 2, 5)
    truth = np.array([model.growth_mm(p, t_s) for p in places]) * 1e3
    linear = np.array([(p - fixed) * da / thermal.length_mm for p in places])
    errors = [float(np.abs(truth - linear).max())]
    for history in histories:
        profiled = np.array([(p - fixed) * history.delta_a_mm(da, p) / thermal.length_mm
                             for p in places])  # fmt: skip
        errors.append(float(np.abs(truth - profiled).max()))
    return tuple(errors)


def test_the_travel_profile_follows_a_screw_warm_where_its_nut_worked() -> None:
    rng = np.random.default_rng(23)
    errors = np.array([_judge_warmup(rng) for _ in range(8)])
    linear, profiled = errors[:, 0], errors[:, 1]
    assert np.median(profiled) < 0.25 * np.median(linear), errors
    assert profiled.max() < 3.5, errors  # µm; the linear spread leaves up to tens
    assert linear.max() > 5.0, errors  # the case is one the linear spread gets wrong


def test_heat_stays_in_the_screw_at_its_ends() -> None:
    """A zone worked at either end of the travel (eight random screws, the profile at each
    one's own spread): the heat conducted past the travel stays in the steel up to the
    screw's ends (``screw_mm``) and warms that end. A profile whose heat runs on past them
    misses it there."""
    rng = np.random.default_rng(31)
    errors = np.array([_judge_warmup(rng, zone_at=(0.0, 0.6)[k % 2], ends=True)
                       for k in range(8)])  # fmt: skip
    running_on, ended = errors[:, 2], errors[:, 3]
    assert np.median(ended) < 0.8 * np.median(running_on), errors  # 0.49 against 0.66 µm
    assert ended.max() < 0.9 * running_on.max(), errors  # 0.78 against 1.03 µm


def test_folding_at_the_ends_keeps_the_heat() -> None:
    """By hand: weights past an end come back mirrored, the total on the screw kept."""
    x = np.arange(-50.0, 151.0, 10.0)
    w = np.zeros_like(x)
    w[x == -30.0] = 2.0  # 30 mm past the low end (0): back at 30 mm
    w[x == 110.0] = 1.0  # 10 mm past the high end (100): back at 90 mm
    folded = fold_at_ends(x, w, (0.0, 100.0))
    assert folded.sum() == pytest.approx(w.sum())
    assert folded[x == 30.0] == pytest.approx(2.0) and folded[x == 90.0] == pytest.approx(1.0)
    assert not folded[(x < 0.0) | (x > 100.0)].any()


def test_a_profile_needs_a_displacement_source() -> None:
    from gateway.config import GatewayConfig

    data = {"upstream": {"tcp": {"port": 0}},
            "buses": {"b": {"tcp": {"host": "127.0.0.1", "port": 1}}},
            "thermal_sources": {"t": {"bus": "b", "unit": 3, "register": {"address": 0},
                                      "kind": "temperature"}},
            "axes": {"X": {"bus": "b", "unit": 1, "pulse_mm": 0.001, "travel_mm": [0, 500],
                           "registers": {"target": {"address": 0}, "feedback": {"address": 2}},
                           "compensation": {"thermal": {"source": "t", "length_mm": 600,
                                                        "profile": {}}}}}}  # fmt: skip
    with pytest.raises(ValueError, match=r"thermal\.profile: needs a displacement"):
        GatewayConfig.model_validate(data)


def test_a_pause_forgets_the_old_zone_with_memory_s() -> None:
    """Zone A cycled 30 min, two hours' pause (the sim's screw cools), zone B cycled
    10 min: with ``memory_s`` (the screw's cooling time constant, ρ·c·d / 4h) the profile
    puts the Δa in zone B (0.96 µm off at most of 44 µm); without it zone A's old travel
    still shares it (21 µm off)."""
    from sim.config_truth import ScrewHeat
    from sim.heat import ScrewHeatModel

    travel, nut, speed, h = 800.0, 40.0, 100.0, 15.0
    screw = (-nut, travel + nut)
    tau_s = 7850 * 460 * 0.016 / (4 * h)  # 963 s
    model = ScrewHeatModel(ScrewHeat(lead_mm=5.0, drag_torque_Nm=0.05, diameter_mm=16.0,
                                     nut_length_mm=nut, h_W_m2K=h, screw_mm=screw,
                                     fixed_end_mm=screw[0]), (0.0, travel))  # fmt: skip
    clock = [0.0]
    histories = {}
    for memory_s in (None, tau_s):
        th = AxisThermal(source="x", length_mm=screw[1] - screw[0], origin_mm=screw[0],
                         profile=TravelProfile(memory_s=memory_s))  # fmt: skip
        histories[memory_s] = TravelHistory(th, th.profile, (0.0, travel),  # type: ignore[arg-type]
                                            clock=lambda: clock[0])  # fmt: skip

    def cycle(z0: float, z1: float, until_s: float) -> None:
        pos = z0
        for hist in histories.values():
            hist.move_to(pos)
        while clock[0] < until_s:
            to = z1 if pos == z0 else z0
            dt = abs(to - pos) / speed
            model.add_move(clock[0], clock[0] + dt, pos, to, speed)
            clock[0] += dt
            for hist in histories.values():
                hist.move_to(to)
            pos = to

    cycle(50.0, 300.0, 1800.0)  # zone A
    clock[0] += 7200.0  # the pause: nothing moves
    cycle(500.0, 750.0, clock[0] + 600.0)  # zone B
    da = model.growth_mm(screw[1], clock[0])
    places = np.array([100.0, 250.0, 400.0, 600.0, 700.0])
    truth = np.array([model.growth_mm(p, clock[0]) for p in places])
    err = {k: float(np.abs(truth - [(p - screw[0]) * hist.delta_a_mm(da, p)
                                   / (screw[1] - screw[0]) for p in places]).max()) * 1e3
           for k, hist in histories.items()}  # fmt: skip
    assert da * 1e3 > 5.0
    assert err[tau_s] < 0.4 * err[None], err


def _screw() -> AxisThermal:
    """A 700 mm screw fixed at −40 mm, its heat fading per 900 mm travelled or 600 s."""
    return AxisThermal(source="x", length_mm=700.0, origin_mm=-40.0,
                       profile=TravelProfile(spread_mm=60.0, memory_mm=900.0, memory_s=600.0,
                                             screw_mm=(-40.0, 640.0)))  # fmt: skip


def _histories_at_300(th: AxisThermal, clock: list[float]) -> tuple[TravelHistory, TravelHistory]:
    """Two histories of ``th`` on one clock (``clock[0]``, s), each moved to 300 mm."""
    pair = tuple(TravelHistory(th, th.profile, (0.0, 600.0), clock=lambda: clock[0])  # type: ignore[arg-type]
                 for _ in range(2))  # fmt: skip
    for h in pair:
        h.move_to(300.0)
    return pair  # type: ignore[return-value]


def test_moves_at_once_are_the_moves_one_by_one() -> None:
    """``moves_to`` (a fit's replay) sweeps as ``move_to`` called for each move at the
    same clock reading, and as the sweep written out by hand: fade what was swept by the
    move's length over ``memory_mm``, then add the stretch it crossed (a pause before the
    first move fades by ``memory_s``; standing still sweeps nothing)."""
    th = _screw()
    rng = np.random.default_rng(5)
    targets = np.round(rng.uniform(0.0, 600.0, 40), 1)
    targets[7] = targets[6]  # a move to where it stands
    clock = [0.0]
    one, many = _histories_at_300(th, clock)
    clock[0] = 120.0  # a pause: the first move fades by 120 / 600 at least
    for x in targets:
        one.move_to(float(x))
    many.moves_to(targets)
    by_hand, last = np.zeros_like(one.swept), 300.0
    c, half = one.centres_mm, th.profile.bin_mm / 2.0  # type: ignore[union-attr]
    for k, x in enumerate(targets):
        if x == last:
            continue
        fade = abs(x - last) / 900.0
        by_hand *= np.exp(-(max(fade, 120.0 / 600.0) if k == 0 else fade))
        lo, hi = sorted((last, x))
        by_hand += np.clip(np.minimum(c + half, hi) - np.maximum(c - half, lo), 0.0, None) \
            / th.profile.bin_mm  # type: ignore[union-attr]  # fmt: skip
        last = x
    assert np.allclose(one.swept, by_hand, rtol=1e-12, atol=1e-12)
    assert np.allclose(many.swept, by_hand, rtol=1e-12, atol=1e-12)
    assert by_hand.max() > 1.0  # (swept more than once somewhere: the fading counts)
    for at in (50.0, 333.0, 590.0):
        assert many.delta_a_mm(0.02, at) == pytest.approx(one.delta_a_mm(0.02, at), rel=1e-12)


def test_a_replay_reads_every_stop_as_the_moves_one_by_one_would() -> None:
    """``replay`` (a warm-up fit's: every stop of a replay at once) gives the swept travel
    ``moves_to`` leaves stop by stop, and its read-out rows give W where ``delta_a_mm``
    reads it: through the spread, the fold at the screw's ends and the integral."""
    th = _screw()
    rng = np.random.default_rng(8)
    targets = np.round(rng.uniform(0.0, 600.0, 60), 1)
    targets[9] = targets[8]  # a move to where it stands
    stops = np.array([0, 3, 8, 9, 10, 31, 59])
    clock = [0.0]
    whole, steps = _histories_at_300(th, clock)
    clock[0] = 120.0  # a pause before the first move
    rows = whole.replay(targets, stops)
    assert rows.shape == (stops.size, whole.swept.size)
    places = np.array([-60.0, -40.0, 12.3, 300.0, 655.0, 700.0])
    read = rows @ whole.integral_rows(places).T
    came = 0
    for k, stop in enumerate(stops):
        steps.moves_to(targets[came:stop + 1])
        came = stop + 1
        assert np.allclose(rows[k], steps.swept, rtol=1e-12, atol=1e-12), k
        weights = EndFold.of(steps.centres_mm, (-40.0, 640.0))(
            travel_weights(steps.swept, 5.0, 60.0))
        integral = travel_integral(steps.centres_mm, weights)
        assert np.allclose(read[k], np.interp(places, steps.centres_mm, integral),
                           rtol=1e-12, atol=1e-12), k  # fmt: skip
        # and the Δa the gateway corrects with, from those numbers
        at = float(targets[stop])
        o, a_end = (np.interp(p, steps.centres_mm, integral) for p in (-40.0, 660.0))
        share = (np.interp(at, steps.centres_mm, integral) - o) / (a_end - o)
        assert np.isclose(steps.delta_a_mm(0.1, at), 0.1 * share * 700.0 / (at + 40.0),
                          rtol=1e-12), k  # fmt: skip
    steps.moves_to(targets[came:])
    assert np.allclose(whole.swept, steps.swept, rtol=1e-12, atol=1e-12)
    assert whole.last_mm == steps.last_mm == targets[-1]
