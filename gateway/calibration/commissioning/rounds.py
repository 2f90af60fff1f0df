"""Commissioning's step 3: the verification rounds and what they refine."""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import numpy as np

from ...formats import read_pitch_csv
from ..fitting import adaptive
from ..plans.plans import (
    Plan,
    targets_plan,
)
from ..plans.rawdata import axis_deviations
from .steps import (
    BudgetSpent,
)

if TYPE_CHECKING:
    from .after import AfterSteps
    from .axes import Axes
    from .best import BestTables
    from .budget import Budget
    from .fit import FitSteps
    from .planner import Planner
    from .record import Record
    from .refine import RefineSteps
    from .rotary import RotarySteps
    from .stager import Stager
    from .steps import StepRunner

Say = Callable[[str], None]

#: a verification's runs per target are doubled, up to this, before an axis is settled
MAX_VERIFY_RUNS = 8


class Rounds:
    """Step 3: rounds of verification at targets never used for fitting; the best tables kept;
    what misses refined."""

    def __init__(self, axes: Axes, record: Record, stager: Stager, budget: Budget,
                 runner: StepRunner, rotary: RotarySteps, plans: Planner, refine: RefineSteps,
                 after: AfterSteps, best: BestTables, fit: FitSteps, say: Say) -> None:
        self.s = axes.s
        self.axes = axes
        self.record = record
        self.stager = stager
        self.budget = budget
        self.runner = runner
        self.rotary = rotary
        self.plans = plans
        self.refine = refine
        self.after = after
        self.best = best
        self.fit = fit
        self.say = say

    async def run(self) -> str:
        """Verify; keep the best tables; refine what misses; a refinement that does not pay
        is taken back and its axis (or the plane) settled at its best."""
        await self.stager.use(self.record.tables_phase)
        rounds = self.record.state["rounds"]
        best = self.record.state.setdefault("best", {})
        settled = self.record.state.setdefault("settled", [])
        while len(rounds) < self.s.max_rounds:
            r = len(rounds) + 1
            verdicts, xy = await self._verify(r)
            entry: dict[str, Any] = {"round": r, "axes": {a: v.to_json()
                                                          for a, v in verdicts.items()},
                                     "xy": xy, "machine_s": self.record.used_s}  # fmt: skip
            self.say(f"round {r}: " + "; ".join(
                self.rotary.verdict_text(a, v) for a, v in verdicts.items())
                + (f"; XY max {xy['max_um']:.2f} µm" if xy else ""))  # fmt: skip
            scores = {a: v.E_um for a, v in verdicts.items()}
            if xy is not None:
                scores["XY"] = xy["max_um"]
            last = rounds[-1] if rounds else {}
            swept = set(last.get("swept") or [])
            for name in [a for a in verdicts if a not in settled and a in best
                         and best[a]["round"] < r and not _refined(last, a)]:  # fmt: skip
                was = best[name]["score"]
                now = self.best.read_again(name, scores.pop(name), r)
                self.say(f"round {r}: {name}: round {best[name]['round']}'s table read again: "
                         f"{self.rotary.score_text(name, now)} over its "
                         f"{len(best[name]['reads'])} verifications (was "
                         f"{self.rotary.score_text(name, was)})")  # fmt: skip
                if now <= self.rotary.tolerance_of(name):  # within, twice over: settled
                    settled.append(name)
            restored = [name for name, score in scores.items() if name not in settled
                        and not self.best.keep_best(name, score, r,
                                                xy["rms_um"] if name == "XY" and xy else None,
                                                swept=name in swept,
                                                noise=verdicts[name].noise_um
                                                if name in verdicts else 0.0)]  # fmt: skip
            more_runs: dict[str, int] = {}
            for name in restored:
                what = "model" if name == "XY" else "table"
                self.say(f"round {r}: {name}: " + (
                    "the last refinement did not pay; back to round " if _refined(last, name) else
                    f"read {self.rotary.score_text(name, scores[name])}, not refined since round ")
                    + f"{best[name]['round']}'s {what} "
                    f"({self.rotary.score_text(name, best[name]['score'])})")  # fmt: skip
                self._settle(r, name, more_runs)
            names = [*self.s.axes, *(["XY"] if self.s.planar else [])]
            good = {n: n in best and best[n]["score"] <= self.rotary.tolerance_of(n) for n in names}
            entry["restored"] = restored
            if all(good.values()):
                entry["outcome"] = "within"
                rounds.append(entry)
                self.record.save()
                if restored:
                    await self.stager.use(self.record.tables_phase)
                self.say(f"round {r}: within {self.rotary.tolerance_text()} between the points")
                return "within"
            added: dict[str, int] = {}
            refining = [a for a in verdicts
                        if not good[a] and a not in settled and a not in more_runs]
            plane = "XY" in scores and not good["XY"] and "XY" not in settled
            # what the round may spend, shared in turn (the worst axis first, the plane
            # last): each takes an equal share of what is left, a sweep as much as leaves
            # half an equal share for each one after it
            claimants = len(refining) + plane
            keep_s = 0.5 * self.refine.allowance_s(r, claimants)
            trimmed = []
            for i, a in enumerate(sorted(refining, key=lambda n: -verdicts[n].E_um)):
                pool_s = self.refine.allowance_s(r, 1)
                coarser = self.refine.sweeps(r, a, pool_s - (claimants - i - 1) * keep_s)
                if coarser is not None:
                    added[a] = await self.refine.sweep_axis(r, a, coarser)
                    entry.setdefault("swept", []).append(a)
                    continue
                v = self.refine.affordable(r, a, verdicts[a], pool_s / (claimants - i))
                if len(v.failing_spans) < len(verdicts[a].failing_spans):
                    trimmed.append(f"{a} {len(v.failing_spans)} of "
                                   f"{len(verdicts[a].failing_spans)} spans")
                added[a] = await self.refine.refine_axis(r, a, v) if v.failing_spans else 0
                if not added[a] and v.failing_spans == verdicts[a].failing_spans:
                    self._settle(r, a, more_runs)
            if trimmed:
                entry["budget"] = trimmed
                self.say(f"round {r}: the budget allows the worst spans only: "
                         + ", ".join(trimmed))  # fmt: skip
            denser = adaptive.denser_grid(*tuple(self.record.state.get("grid", self.s.grid)))
            if plane and self.axes.estimate_s(self.plans.grid_plan(denser, runs=1)) \
                    > self.refine.allowance_s(r, 1):
                settled.append("XY")  # a denser grid does not fit in what is left
                entry.setdefault("budget", []).append("XY: no denser grid")
            elif plane:
                if self.record.state.get("densified", 0) < 2:
                    entry["grid"] = list(await self._refine_plane(r))
                    self.record.state["densified"] = self.record.state.get("densified", 0) + 1
                else:
                    settled.append("XY")
            entry["added"] = added
            if more_runs:
                entry["verify_runs"] = more_runs
            rounds.append(entry)
            self.record.save()
            if not any(added.values()) and "grid" not in entry and not more_runs \
                    and "swept" not in entry:
                if restored:
                    await self.stager.use(self.record.tables_phase)
                if "budget" in entry:
                    self.say(f"round {r}: no refinement and the round after it fit in the "
                             "budget left")  # fmt: skip
                    return "budget"
                self.say(f"round {r}: nothing left to refine where it misses (repeatability "
                         "or structure below the table's resolution)")  # fmt: skip
                return "floor"
            await self.stager.use(self.record.tables_phase)
        return "rounds"

    # -- 3. verification rounds ----------------------------------------------------------

    def _settle(self, r: int, name: str, more_runs: dict[str, int]) -> None:
        """An axis with nothing left to refine at its verification's noise (no span stands
        out of 3 standard errors of a target mean, or the last refinement did not pay) is
        settled, unless it misses its tolerance and the budget affords a verification with
        twice the runs (up to ``MAX_VERIFY_RUNS``): the standard error of a mean falls as
        1/√runs, so residuals the scatter of single stops hid then stand out. The best
        table is judged again at the new runs (its score at fewer runs read more noise)."""
        settled = self.record.state.setdefault("settled", [])
        best = self.record.state.get("best", {}).get(name)
        runs = self.budget.verify_runs(name)
        # the next verification costs twice this round's; a refinement about as much again
        if (name == "XY" or best is None or best["score"] <= self.rotary.tolerance_of(name)
                or 2 * runs > MAX_VERIFY_RUNS
                or 2 * self.refine.verify_s(r, name) > self.refine.allowance_s(r, 1)):
            settled.append(name)
            return
        self.record.state.setdefault("verify_runs", {})[name] = 2 * runs
        self.record.state.setdefault("spans", {})[name] = []  # no new span: random targets only
        del self.record.state["best"][name]  # its next score, at 2 × runs, is the new baseline
        more_runs[name] = 2 * runs
        self.say(f"round {r}: {name}: what misses is within the noise of {runs} runs; "
                 f"verified again with {2 * runs}")  # fmt: skip

    def _verify_targets(self, r: int, axis: str) -> np.ndarray:
        table = read_pitch_csv(self.record.config_dir / self.record.tables.pitch[axis]).position_mm
        if self.axes.rotary(axis):
            return self.rotary.rotary_verify_targets(r, axis, table)
        spans = self.record.state.get("spans", {}).get(axis)  # None: all spans new
        mids = adaptive.midpoints_mm(table, spans)
        rand = adaptive.random_targets_mm(self.axes.travel(axis), adaptive.RANDOM_TARGETS,
                                          100 * r + self.s.seed, table)  # fmt: skip
        targets = np.unique(np.concatenate([mids, rand]))
        return targets

    async def _verify(self, r: int) -> tuple[dict[str, adaptive.AxisVerdict], dict | None]:
        """Round ``r``'s verification of every axis not settled and of the plane; begun only
        where the budget holds all of it (one axis verified alone judges nothing: at 1.5 x a
        manual calibration's time the sdss plates verified X, 5.9 min, and not Y)."""
        settled = self.record.state.get("settled", [])
        makes: dict[str, Callable[[], Plan]] = {
            a: (lambda a=a: targets_plan(a, self.axes.travel(a), self._verify_targets(r, a),
                                         self.budget.verify_runs(a), kind="iso230-verification",
                                         round=r))
            for a in self.s.axes if a not in settled}  # (settled: nothing new to judge)
        if self.s.planar is not None and "XY" not in settled:
            grid = tuple(self.record.state.get("grid", self.s.grid))
            makes["xy"] = lambda: self.plans.xy_check_plan(r, grid)
        if not any((self.record.dir / "plans" / f"verify{r}-{n}.plan").exists() for n in makes):
            need_s = sum(self.budget.step_cost_s(make()) for make in makes.values())
            left_s = self.budget.left_s()
            if need_s > left_s:
                raise BudgetSpent(f"round {r}'s verification needs {need_s / 60:.1f} min of "
                                  f"machine time, {max(0.0, left_s) / 60:.1f} min left")
        verdicts = {}
        for a in [a for a in makes if a != "xy"]:
            await self.runner.step(f"verify{r}-{a}", makes[a], "on", self.axes.park(a))
            table = read_pitch_csv(self.record.config_dir / self.record.tables.pitch[a]).position_mm
            dev = axis_deviations(self.runner.raw(f"verify{r}-{a}"), a)
            verdicts[a] = self.rotary.judge(a, dev, table)
        xy = None
        if "xy" in makes:
            await self.runner.step(f"verify{r}-xy", makes["xy"], "on")
            xy = self.after.xy_figures(f"verify{r}-xy")
        return verdicts, xy

    async def _refine_plane(self, r: int) -> tuple[int, int]:
        grid = adaptive.denser_grid(*tuple(self.record.state.get("grid", self.s.grid)))
        if not self.record.done(f"refine{r}-xy"):  # the round's new tables loaded: the frame read
            await self.stager.use(self.record.tables_phase)
        await self.runner.step(f"refine{r}-xy", lambda: self.plans.grid_plan(grid, runs=1), "on")
        config, _ = self.stager.staged("full")
        self.fit.fit_plane(config, f"refine{r}-xy", residual=True)
        self.record.state["grid"] = list(grid)
        return grid


def _refined(last: dict[str, Any], name: str) -> bool:
    """Whether round ``last`` changed this axis's table (or, "XY", the plane's model)."""
    return bool(name in (last.get("swept") or []) or (last.get("added") or {}).get(name)
                or (name == "XY" and "grid" in last))
