"""Two workflows (or budgets) compared over several judges: where the judge reads moves
a machine's E cut by more than most changes a workflow makes, so one judge's figure can
rank two calibrations either way.

Each run is ``bench/accuracy.py --judge-seeds K --json`` on the same machines; each judge
(``seed``) has its own random targets, park and XY points, the same for both runs (nearly:
each avoids the points its workflow measured). Per machine and axis (and the plane): the
E cut % (XY cut %) at each judge for both runs, their means, and the paired difference
B − A, its mean and standard deviation over the judges. The spread of one run's cut over
the judges is the judge's own scatter on that machine.

    python bench/judgings.py plain.json commission.json
    python bench/judgings.py --heat commission.json   # heat left at each judge's zone
    python bench/judgings.py --bars commission.json   # issue 54's 1.5 x bars, per machine
    python bench/judgings.py --verdict commission.json  # issue 52's bars, per machine
    python bench/judgings.py 0.5.json --ladder 1.json 1.5.json 3.json  # budgets in order

``--heat``: per machine and axis of one run, the judge's zone test at each judge (its own
zone along the travel): the change at its points after the zone's work, with the
calibration's thermal compensation (after) and without (before), in µm and as a share:
issue 52's heat left.

``--bars`` (a run with ``--oracle``): issue 54's bars at 1.5 × per machine. Each axis's E
cut ≥ 95 % (mean over the judges), or its E within 0.3 µm of a perfect table's at the
first judge's targets; A ≤ R + 2 µm (mean over the judges); XY cut ≥ 90 %. Then per group
whether every machine meets them, and the median one (by its worst margin).
"""

from __future__ import annotations

import argparse
import itertools
import json
import sys
from pathlib import Path
from typing import Any

import numpy as np
from accuracy import beyond_tolerance, sensed_axes
from scipy import stats


def judges(r: dict[str, Any]) -> list[dict[str, Any]]:
    """Every judge of one machine, the first (its ``before`` and ``after``) first, each
    with its ``seed`` (the first's: ``judge_seed``, 0 in runs that did not keep it)."""
    first = {"seed": r.get("judge_seed", 0), "before": r["before"], "after": r["after"]}
    return [first, *r.get("judgings", [])]


def cuts(r: dict[str, Any]) -> dict[int, dict[str, float]]:
    """Per judge seed, each axis's E cut % and the plane's (``XY``) max vector error cut %."""
    out: dict[int, dict[str, float]] = {}
    for j in judges(r):
        b, a = j["before"], j["after"]
        row = {n: 100 * (1 - a["axes"][n]["E_um"] / b["axes"][n]["E_um"]) for n in a["axes"]}
        if "xy" in a and "xy" in b:
            row["XY"] = 100 * (1 - a["xy"]["max_um"] / b["xy"]["max_um"])
        out[int(j["seed"])] = row
    return out


def heat_left(r: dict[str, Any]) -> dict[str, list[tuple[int, float, float, float]]]:
    """Per axis: (judge seed, zone test's change before, after, the after's standard error
    from its readings' scatter, NaN in older runs; µm) at every judge."""
    out: dict[str, list[tuple[int, float, float, float]]] = {}
    for j in judges(r):
        for n, fig in j["after"]["axes"].items():
            out.setdefault(n, []).append((int(j["seed"]), j["before"]["axes"][n]["thermal_um"],
                                          fig["thermal_um"],
                                          fig.get("thermal_se_um", float("nan"))))  # fmt: skip
    return out


def print_heat(data: dict[str, Any]) -> None:
    """Issue 52's heat left at each judge's zone, per machine and axis."""
    print(f"{'machine':<24}{'axis':>5}{'sensor':>13}{'worst %':>9}{'median %':>9}"
          "   per judge: before → after ± its standard error µm (left %)")
    for r in data["machines"]:
        if "error" in r:
            continue
        for n, rows in heat_left(r).items():
            left = [100 * a / b for _, b, a, _ in rows if b > 0]
            sensor = "yes" if n in r.get("sensor_axes", []) else (
                "motion" if n in r.get("model_axes", []) else "-")
            per = "  ".join(f"{b:.1f}→{a:.2f}" + ("" if np.isnan(se) else f"±{se:.2f}")
                            + f" ({100 * a / b:.0f})" for _, b, a, se in rows if b > 0)
            print(f"{r['machine']:<24}{n:>5}{sensor:>13}{max(left):9.1f}"
                  f"{float(np.median(left)):9.1f}   {per}")


#: issue 54's bars at 1.5 ×: E cut %, or E this near a perfect table's (µm); A - R (µm);
#: the plane's cut %
E_CUT_BAR, ORACLE_NEAR_UM, A_OVER_R_UM, XY_CUT_BAR = 95.0, 0.3, 2.0, 90.0


def bars(r: dict[str, Any]) -> dict[str, Any]:
    """One machine against issue 54's 1.5 × bars: per axis its mean E cut, E against a
    perfect table's (first judge), mean A - R; the plane's mean cut; each bar's margin
    (≥ 0 met; points of cut, µm of A - R), the worst of which ranks the machine."""
    every = judges(r)
    c = cuts(r)
    out: dict[str, Any] = {"machine": r["machine"], "axes": {}, "margins": []}
    for n in r["after"]["axes"]:
        cut = float(np.mean([c[s][n] for s in c]))
        a_r = float(np.mean([j["after"]["axes"][n]["A_um"] - j["after"]["axes"][n]["R_um"]
                             for j in every]))  # fmt: skip
        e_um = r["after"]["axes"][n]["E_um"]
        perfect = (r.get("oracle") or {}).get("axes", {}).get(n, {}).get("E_um")
        near_perfect = perfect is not None and e_um - perfect <= ORACLE_NEAR_UM
        # E's margin in points of cut; 0 where only the perfect table's clause meets it
        e_margin = 0.0 if near_perfect and cut < E_CUT_BAR else cut - E_CUT_BAR
        out["axes"][n] = {"cut": cut, "e_um": e_um, "perfect_um": perfect, "a_r_um": a_r,
                          "e_met": e_margin >= 0, "a_met": a_r <= A_OVER_R_UM}  # fmt: skip
        out["margins"] += [e_margin, A_OVER_R_UM - a_r]
    if "XY" in c[next(iter(c))]:
        out["xy_cut"] = float(np.mean([c[s]["XY"] for s in c]))
        out["margins"].append(out["xy_cut"] - XY_CUT_BAR)
    out["met"] = all(m >= 0 for m in out["margins"])
    return out


def print_bars(data: dict[str, Any]) -> None:
    """Issue 54's 1.5 × bars per machine, then per group (every machine, the median)."""
    rows = [bars(r) for r in data["machines"] if "error" not in r]
    print(f"{'machine':<24}{'axis':>5}{'cut %':>7}{'E µm':>7}{'perfect':>8}{'A-R µm':>8}"
          f"{'E':>4}{'A':>3}{'XY %':>7}")
    for b in rows:
        for k, (n, f) in enumerate(b["axes"].items()):
            xy = f"{b['xy_cut']:7.1f}" if k == 0 and "xy_cut" in b else ""
            perfect = "-" if f["perfect_um"] is None else f"{f['perfect_um']:.2f}"
            print(f"{b['machine'] if k == 0 else '':<24}{n:>5}{f['cut']:7.1f}{f['e_um']:7.2f}"
                  f"{perfect:>8}{f['a_r_um']:8.2f}{'ok' if f['e_met'] else 'NO':>4}"
                  f"{'ok' if f['a_met'] else 'NO':>3}{xy}")  # fmt: skip
    for group in sorted({b["machine"].split("-")[0] for b in rows}):
        inside = sorted((b for b in rows if b["machine"].split("-")[0] == group),
                        key=lambda b: min(b["margins"]))  # fmt: skip
        median = inside[(len(inside) - 1) // 2]  # (of an even count: the lower one)
        missed = [b["machine"] for b in inside if not b["met"]]
        print(f"{group}: {len(inside) - len(missed)} of {len(inside)} meet every bar; the "
              f"median one ({median['machine']}) {'meets' if median['met'] else 'misses'}"
              + (f"; missed: {', '.join(missed)}" if missed else ""))


#: issue 52's bars: A - R as read after commissioning (µm); the heat a judge's zone test
#: leaves on an axis without a sensor (% of its uncorrected drift), and on one with (µm)
A_OVER_R_52_UM, HEAT_LEFT_PCT, SENSOR_LEFT_UM = 3.0, 20.0, 2.0


def verdict_bars(r: dict[str, Any], tolerance_um: float) -> dict[str, Any]:
    """One machine against issue 52's bars. Heat is counted by the sensor the machine was
    GIVEN, whatever the final config made of it (heat from motion may replace a
    temperature sensor): the worst judge's zone test per axis. The verdict agrees unless
    it said WITHIN where the judge's as-read E (cold, or warm with --warm-judge) is beyond
    the tolerance."""
    axes = r.get("judged_axes") or list(r["after"]["axes"])
    a_r = max(r["after"]["axes"][n]["A_um"] - r["after"]["axes"][n]["R_um"] for n in axes)
    given = sensed_axes(r, axes)
    heat: dict[str, dict[str, Any]] = {}
    for n, rows in heat_left(r).items():
        if n not in axes:
            continue
        worst = max(rows, key=lambda t: t[2])
        pct = max((100 * a / b for _, b, a, _ in rows if b > 0), default=float("nan"))
        heat[n] = {"given": n in given, "before_um": worst[1], "left_um": worst[2],
                   "left_pct": pct,
                   "motion": n in r.get("model_axes", []), "met": (
                       worst[2] <= SENSOR_LEFT_UM if n in given else
                       not pct > HEAT_LEFT_PCT)}  # fmt: skip
    beyond = beyond_tolerance(r, tolerance_um)
    said = r.get("said")
    return {"machine": r["machine"], "a_r_um": a_r, "a_met": a_r <= A_OVER_R_52_UM,
            "heat": heat, "said": said, "beyond": beyond,
            "agrees": not (said == "WITHIN" and beyond)}


def print_verdict_bars(data: dict[str, Any]) -> None:
    """Issue 52's bars per machine, then per group: A - R and the sensorless heat on every
    smooth machine and the median rough one; a given sensor's heat and the verdict's
    agreement on every machine."""
    tol = float(data.get("tolerance_um", 2.0))
    rows = [verdict_bars(r, tol) for r in data["machines"] if "error" not in r]
    print(f"tolerance {tol:g} µm; heat at the worst judge, by the sensor given "
          "(S: sensor given, M: heat from motion in the final config)")
    print(f"{'machine':<24}{'A-R':>6}  heat left per axis{'':<34}said / judge beyond")
    for b in rows:
        heat = "  ".join(
            f"{n}{'S' if h['given'] else ''}{'M' if h['motion'] else ''} "
            + (f"{h['left_um']:.2f} µm" if h["given"] else f"{h['left_pct']:.1f} %")
            + f" of {h['before_um']:.1f}" + ("" if h["met"] else " NO")
            for n, h in b["heat"].items())  # fmt: skip
        print(f"{b['machine']:<24}{b['a_r_um']:6.2f}{'' if b['a_met'] else ' NO':<3}"
              f"{heat:<52}{b['said'] or '-'} / {','.join(b['beyond']) or '-'}"
              + ("" if b["agrees"] else "  DISAGREES"))
    for group in sorted({b["machine"].split("-")[0] for b in rows}):
        inside = [b for b in rows if b["machine"].split("-")[0] == group]
        a_r = sorted(b["a_r_um"] for b in inside)
        # the worst sensorless axis of each machine that has one (NaN sorts anywhere)
        worst = [max((h["left_pct"] for h in b["heat"].values()
                      if not h["given"] and np.isfinite(h["left_pct"])), default=None)
                 for b in inside]  # fmt: skip
        free = sorted(w for w in worst if w is not None)
        sensed = [(b["machine"], n, h["left_um"]) for b in inside
                  for n, h in b["heat"].items() if h["given"]]  # fmt: skip
        worst_sensed = max(sensed, key=lambda t: t[2], default=None)
        print(f"{group}: A - R max {a_r[-1]:.2f}, median {a_r[(len(a_r) - 1) // 2]:.2f} µm; "
              + (f"heat left without a sensor worst {free[-1]:.1f} %, median "
                 f"{free[(len(free) - 1) // 2]:.1f} %; " if free else "")
              + (f"with a sensor worst {worst_sensed[2]:.2f} µm ({worst_sensed[0]} "
                 f"{worst_sensed[1]}); " if worst_sensed else "")
              + f"{sum(not b['agrees'] for b in inside)} WITHIN where the judge reads beyond")


def compare(a: dict[str, Any], b: dict[str, Any]) -> list[dict[str, Any]]:
    """Per machine in both runs and each figure: the cuts at every judge both read."""
    rows = []
    by_name = {r["machine"]: r for r in b["machines"] if "error" not in r}
    for ra in a["machines"]:
        rb = by_name.get(ra["machine"])
        if rb is None or "error" in ra:
            continue
        ca, cb = cuts(ra), cuts(rb)
        seeds = sorted(set(ca) & set(cb))
        for fig in ca[seeds[0]]:
            xa = np.array([ca[s][fig] for s in seeds])
            xb = np.array([cb[s][fig] for s in seeds])
            d = xb - xa
            rows.append({"machine": ra["machine"], "figure": fig, "seeds": seeds,
                         "a": xa.tolist(), "b": xb.tolist(),
                         "mean_a": float(xa.mean()), "mean_b": float(xb.mean()),
                         "diff": float(d.mean()),
                         "diff_sd": float(d.std(ddof=1)) if d.size > 1 else float("nan"),
                         "sd_a": float(xa.std(ddof=1)) if xa.size > 1 else float("nan"),
                         "sd_b": float(xb.std(ddof=1)) if xb.size > 1 else float("nan")})
    return rows


#: the share of equal pairs a one-sided flag lets through (half of the test's 5 %)
CHANCE = 0.025
#: the share of figures flagged (both ways) between two runs of the same code and budget on
#: another draw of the sims' noise (session 62: 1.5 x, the 20 random, --sim-seed 1: 7 of 54):
#: the commissioning's own noise, which one run per budget does not show
AA_SHARE = 7 / 54


def _beyond(row: dict[str, Any]) -> int:
    """+1 where B's mean cut is above A's beyond the judges' scatter (a paired Student t
    test, two-sided at 1 − 2 · CHANCE), −1 below, 0 within or with one judge."""
    n = len(row["seeds"])
    if n < 2 or not np.isfinite(row["diff_sd"]):
        return 0
    half = stats.t.ppf(1.0 - CHANCE, n - 1) * row["diff_sd"] / np.sqrt(n)
    return int(np.sign(row["diff"])) if abs(row["diff"]) > half else 0


def print_ladder(paths: list[Path]) -> None:
    """Issue 54's ladder: runs of the same machines at growing budgets, in the order given
    (the plain workflow is no rung: compare it with a budget as two runs). Per machine and
    figure, each run's mean cut over the judges (± their standard deviation) and machine
    hours; a step down marked ``v``
    where it falls beyond the judges' scatter (the paired t test of :func:`_beyond`)."""
    runs = [json.loads(q.read_text()) for q in paths]
    names = [q.stem for q in paths]
    print("mean cut % over the judges (sd); v: below the run before beyond the judges' scatter")
    print(f"{'machine':<24}{'fig':>4}" + "".join(f"{n:>14}" for n in names))
    falls = 0
    first = {r["machine"]: r for r in runs[0]["machines"] if "error" not in r}
    for m in first:
        rows = [next((r for r in run["machines"] if r["machine"] == m and "error" not in r),
                     None) for run in runs]  # fmt: skip
        if any(r is None for r in rows):
            continue
        steps = [{c["figure"]: c for c in compare({"machines": [a]}, {"machines": [b]})}
                 for a, b in itertools.pairwise(rows)]  # fmt: skip
        for fig in cuts(rows[0])[next(iter(cuts(rows[0])))]:
            cells = []
            for k, r in enumerate(rows):
                xs = [c[fig] for c in cuts(r).values()]
                down = k > 0 and _beyond(steps[k - 1][fig]) < 0
                falls += down
                sd = float(np.std(xs, ddof=1)) if len(xs) > 1 else float("nan")
                cells.append(f"{np.mean(xs):7.1f} ({sd:3.1f}){'v' if down else ' '}")
            print(f"{m:<24}{fig:>4}" + "".join(f"{c:>14}" for c in cells))
        print(f"{'':<24}{'h':>4}" + "".join(f"{r.get('machine_h', float('nan')):>14.2f}"
                                            for r in rows))  # fmt: skip
    print(f"steps down beyond the judges' scatter: {falls}")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter,
                                     epilog=__doc__.split("\n\n", 1)[1])  # fmt: skip
    parser.add_argument("a", type=Path, help="the first run's --json output")
    parser.add_argument("b", type=Path, nargs="?", help="the second run's --json output")
    parser.add_argument("--heat", action="store_true",
                        help="the heat left at each judge's zone, of the first run alone")
    parser.add_argument("--bars", action="store_true",
                        help="issue 54's 1.5 x bars per machine, of the first run alone")
    parser.add_argument("--verdict", action="store_true",
                        help="issue 52's bars per machine, of the first run alone")
    parser.add_argument("--ladder", type=Path, nargs="*", metavar="RUN",
                        help="more runs: the first run and these, at growing budgets")
    args = parser.parse_args()
    if args.ladder is not None:
        print_ladder([args.a, *([args.b] if args.b else []), *args.ladder])
        return 0
    if args.verdict:
        print_verdict_bars(json.loads(args.a.read_text()))
        return 0
    if args.bars:
        print_bars(json.loads(args.a.read_text()))
        return 0
    if args.heat or args.b is None:
        print_heat(json.loads(args.a.read_text()))
        return 0
    rows = compare(json.loads(args.a.read_text()), json.loads(args.b.read_text()))
    if not rows:
        print("no machine in both runs", file=sys.stderr)
        return 1
    print(f"A: {args.a}\nB: {args.b}")
    print(f"{'machine':<24}{'fig':>4}{'judges':>7}{'A cut %':>9}{'sd':>6}{'B cut %':>9}"
          f"{'sd':>6}{'B − A':>8}{'sd':>6}   per judge A / B")
    for r in rows:
        per = "  ".join(f"{x:.1f}/{y:.1f}" for x, y in zip(r["a"], r["b"]))
        print(f"{r['machine']:<24}{r['figure']:>4}{len(r['seeds']):>7}{r['mean_a']:9.1f}"
              f"{r['sd_a']:6.1f}{r['mean_b']:9.1f}{r['sd_b']:6.1f}{r['diff']:8.1f}"
              f"{r['diff_sd']:6.1f}   {per}")
    # beyond the judges' scatter: a paired Student t test at 95 % two-sided; with 4 judges
    # t = 3.18 (twice the standard error, as before, let 14 % of equal pairs through)
    below = [r for r in rows if _beyond(r) < 0]
    above = [r for r in rows if _beyond(r) > 0]
    tested = [r for r in rows if len(r["seeds"]) > 1]
    print(f"\nB above A beyond the judges' scatter (paired t test, 95 %): {len(above)} of "
          f"{len(rows)}; below: {len(below)}; the judges' scatter alone would give about "
          f"{CHANCE * len(tested):.1f} each way by chance, two commissionings of one machine "
          f"about {AA_SHARE / 2 * len(tested):.1f} (their own noise too)"
          + "".join(f"\n  {r['machine']} {r['figure']}: {r['mean_a']:.1f} → {r['mean_b']:.1f} %"
                    for r in below))  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
