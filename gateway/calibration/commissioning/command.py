"""``compgw commission``'s command before anything moves (:class:`.commission.Commission`
asks it first): the plan it prints; what it asks (budget, rounds, the
tolerances that judge its axes) and commissions (axes and plane); whether the
commissioning in its directory is this one, and whether it finished with nothing more
asked.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import numpy as np

from ...compensation.errors import TableError
from ..fitting import adaptive
from ..fitting.takeup_fit import MIN_LOST_UM
from ..plans.plans import Plan
from .settings import SHORT_WARMUP_S

if TYPE_CHECKING:
    from .axes import Axes
    from .budget import Budget
    from .planner import Planner
    from .record import Record
    from .rotary import RotarySteps
    from .short import ShortBudget
    from .thermal import ThermalSteps

Say = Callable[[str], None]



class CommandChecks:
    """The command's plan, and what it asks of the commissioning in its directory."""

    def __init__(self, axes: Axes, record: Record, rotary: RotarySteps, thermal: ThermalSteps,
                 plans: Planner, short: ShortBudget, say: Say) -> None:
        self.s = axes.s
        self.config = axes.config
        self.axes = axes
        self.record = record
        self.rotary = rotary
        self.thermal = thermal
        self.plans = plans
        self.short = short
        self.say = say

    def print_plan(self) -> float:
        """Say what will be measured first and its machine time; returns that time (s)."""
        total = 0.0
        done = list(self.record.state.get("steps", {}))
        ended = self.record.state.get("finished")
        if ended is not None:  # asked for more (:meth:`finished` is None)
            self.say(f"carrying on the commissioning in {self.record.dir}, which ended "
                     f"'{ended.get('outcome')}': {_count(len(done), 'step')} done, the after-run "
                     "measured again at the end")  # fmt: skip
        elif done:
            self.say(f"resuming in {self.record.dir}: {_count(len(done), 'step')} done (the last "
                     f"{done[-1]}), "
                     f"{self.record.used_s / 3600:.2f} h of machine time used; every reading kept, "
                     "a step begun carries on from its last reading")  # fmt: skip
        self.say(f"commissioning {', '.join(self.s.axes)}"
                 f"{' and the plane ' + '/'.join(self.s.planar) if self.s.planar else ''}: "
                 f"tolerance {self.rotary.tolerance_text()} between the points, budget "
                 f"{self.s.budget_s / 3600:.2f} h of machine time")  # fmt: skip
        first = self.plans.initial_plans()
        for name, plan in first:
            self.axes.check_limits(plan)
            t = self.axes.estimate_s(plan)
            total += t
            self.say(f"  {name:<14} {sum(m.measured for m in plan.moves):>5} readings "
                     f"{len(plan.moves):>5} moves {t / 60:>7.1f} min  "
                     f"{self._purpose(name)}")  # fmt: skip
        if any(not self.axes.rotary(a) for a in self.s.axes):
            self.say(f"  (takeup-*: the reversal ladder, only where the backlash test shows "
                     f"{MIN_LOST_UM:g} µm or more of lost motion and one rung of it, 12 moves, "
                     "shows less than all of it)")  # fmt: skip
        if self.thermal.heat_zoned():
            self.say("  (warmup-* with no sensor: heat from motion, after the rounds, before "
                     "the after-run: only where the drift references show the screw warming "
                     "and the budget left holds it; --no-heat-warmup leaves it out)")  # fmt: skip
        self.say(f"  then verification rounds (before, each round, after) within the budget; "
                 f"first steps: {total / 3600:.2f} h at {self.s.speed_mm_s:g} "
                 f"{'deg/s' if all(self.axes.rotary(a) for a in self.s.axes) else 'mm/s'} and "
                 f"{self.s.stop_s:g} s per reading")  # fmt: skip
        if total > self.s.budget_s:
            self.say(f"  the budget ({self.s.budget_s / 3600:.2f} h) does not hold these first "
                     "steps: only the axes identified within it get tables, from those runs "
                     f"alone and unverified; give at least {total / 3600:.2f} h, and more for "
                     "the verification rounds")  # fmt: skip
            self.say("  " + self._bought(first))
        # decided once, when it began (:meth:`.short.ShortBudget.short`): a
        # resume says what it was (the config then is a phase's own, its estimate another)
        short = self.record.state["short"] if "short" in self.record.state else (
            not self.thermal.zoned() and self.short.first_need_s() > self.s.budget_s)  # fmt: skip
        if short:
            plane = self.s.planar is not None
            self.say("  a short budget: a plain calibration's steps first: every axis's ISO runs "
                     f"at {self.s.runs} runs per target, the cyclic scans where the lead is "
                     "known, the midpoints of a table that misses between its points, time "
                     f"held for a {SHORT_WARMUP_S / 60:.0f}-minute zone warm-up (down to "
                     f"{SHORT_WARMUP_S / 120:.0f} where that is what fits) per axis whose heat "
                     "one identifies (a sensor's first; run last), up to 5 runs per "
                     "target (or the quarter points of a table that still misses)"
                     + (", then the plane's grid (9 nodes along the longer travel)" if plane
                        else "") + "; then, as the budget allows, "
                     + ("the plane's verdict (its random points), " if plane else "")
                     + "the quarter points of a table that still misses (its eighth "
                     "points where it misses even so), each axis's verdict "
                     "(its after-run alone), the backlash tests, the warm-ups, the lead searches"
                     + ("; no round will refine the plane, so its grid is made denser with "
                        "what the budget then leaves (more readings than the xy-grid line "
                        "above: the budget is spent, not exceeded)" if plane else ""))  # fmt: skip
            if ended is None and not done:
                self.say("  where it holds them, it reads instead of the lines above:")
                for name, plan in self._plain_steps():
                    self.say(f"  {name:<14} {sum(m.measured for m in plan.moves):>5} readings "
                             f"{len(plan.moves):>5} moves "
                             f"{self.axes.estimate_s(plan) / 60:>7.1f} min  "
                             f"{self._purpose(name)}")  # fmt: skip
        if any(self.axes.rotary(a) for a in self.s.axes) and self.s.tolerance_arcsec < 0.1:
            self.say(f"  --tolerance-arcsec {self.s.tolerance_arcsec:g}: below what an angle "
                     "instrument resolves; it is in arcseconds (0.001° is 3.6″)")  # fmt: skip
        ins = self.s.instruments
        kinds = {self.thermal.source_kind(a) for a in self.s.axes}
        for option, given, used in (("--delta-a", ins.given("delta_a"),
                                     kinds - {None, "temperature"}),
                                    ("--temperature", ins.given("temperature"),
                                     kinds & {"temperature"})):  # fmt: skip
            if given and not used:
                self.say(f"  {option} is given, but no commissioned axis's thermal setting "
                         f"reads a source of that kind (axes.<name>.compensation.thermal."
                         "source): no warm-up uses it")  # fmt: skip
        had = [a for a in self.s.axes if self._compensated(a)]
        if had and ended is None and not done:
            self.say(f"  your config compensates {', '.join(had)} already (tables from an "
                     "earlier calibration): the identification measures without them and "
                     "the final config has the new ones; yours is kept in "
                     f"{self.record.original_path}")  # fmt: skip
        self.rotary.rotary_plan_lines()
        return total

    def _purpose(self, name: str) -> str:
        """What a first step is for, in a few words (the printed plan's last column)."""
        kind, _, axis = name.partition("-")
        if kind == "warmup":
            source = self.thermal.source_kind(axis)
            if source is None:
                return "thermal: heat from motion (no sensor)"
            return f"thermal: the {'sensor gain' if source == 'temperature' else 'Δa length'}"
        return {"backlash": "backlash at three places", "iso": "the pitch table (ISO 230-2)",
                "cyclic": "the once-per-lead error", "lead": "lead search (periodic error)",
                "takeup": "reversal ladder (if lost motion)",
                "xy": "the plane (XY grid)"}.get(kind, "")  # fmt: skip

    def _bought(self, first: list[tuple[str, Plan]]) -> str:
        """What a budget short of the first steps buys, in the order a short budget takes
        them (a plain ISO 230-2 calibration's steps first: :mod:`.short`), and what the
        rest needs: "with 0.90 h: pitch tables, plane; thermal identification needs 0.75 h
        more". Estimates without the drift references, the tables and the grid a plain
        calibration's (:meth:`.short.ShortBudget.plain_steps`); the verdict is each
        linear axis's after-run and the plane's random points before and after."""
        groups = (("pitch tables", ("iso",)), ("once-per-lead error", ("cyclic",)),
                  ("plane", ("xy",)), ("verdict", ("before",)), ("backlash", ("backlash",)),
                  ("thermal identification", ("warmup",)),
                  ("lead search", ("lead",)))  # fmt: skip
        # the verdict: each linear axis's after-run alone (its ISO runs read it before),
        # the plane's random points before and after
        linear = [a for a in self.s.axes if not self.axes.rotary(a)]
        steps = [(n, p) for n, p in first if n.partition("-")[0] not in ("iso", "cyclic", "xy")]
        steps += self._plain_steps()
        steps += [("before-" + a, self.plans.before_plan(a, avoid_mm=np.zeros(0)))
                  for a in linear]  # fmt: skip
        if self.axes.plane_with(linear):
            steps += 2 * [("before-xy", self.plans.before_xy_plan())]

        def need_s(kinds: tuple[str, ...]) -> float:
            return sum(self.axes.estimate_s(p) for n, p in steps
                       if n.partition("-")[0] in kinds)  # fmt: skip

        used_s, got, short = 0.0, [], []
        if need_s(("iso",)) > self.s.budget_s:  # then the tables at fewer runs
            steps = [(n, p) for n, p in steps if not n.startswith("iso-")] + [
                (n, p) for n, p in self._plain_steps(runs=2) if n.startswith("iso-")]
            groups = (("pitch tables (at fewer runs)", ("iso",)), *groups[1:])
        for label, kinds in groups:  # each taken where it fits in what is left
            need = need_s(kinds)
            if need <= 0.0:
                continue
            # the once-per-lead error only where the plane's grid still fits beside it
            later_s = need_s(("xy",)) if kinds == ("cyclic",) else 0.0
            if used_s + need + later_s <= self.s.budget_s:
                got.append(label)
                used_s += need
            else:
                more_s = used_s + need + later_s - self.s.budget_s
                short.append(f"{label} needs {more_s / 3600:.2f} h more")
        head = f"with {self.s.budget_s / 3600:.2f} h: " + (", ".join(got) or "no table")
        return head + ("; " + ", ".join(short) if short else "")

    def _plain_steps(self, runs: int | None = None) -> list[tuple[str, Plan]]:
        """A plain calibration's steps as a short budget reads them
        (:meth:`.short.ShortBudget.plain_steps`), snapped as the printed plan's are."""
        linear = [a for a in self.s.axes if not self.axes.rotary(a)]
        return [(n, self.axes.snap(p)) for n, p in self.short.plain_steps(linear, runs)]

    def finish_now(self, budget: Budget) -> str:
        """``--finish``: no step begins but the after-run (the budget becomes the machine time
        spent and the after-run's, for what decides by the time left); the tables are fitted
        from what was read, as when a budget is spent, and the after-run judges them. What
        to say; TableError where nothing has been read yet."""
        if not self.record.state.get("steps"):
            raise TableError(f"--finish: nothing has been read in {self.s.out_dir} yet: no "
                             "table to fit (run without --finish)")  # fmt: skip
        def begun(name: str) -> bool:  # a before-run begun: in the reserve already
            step = "before-xy" if name == "XY" else f"before-{name}"
            return (self.record.dir / "plans" / f"{step}.plan").exists()

        after_s = budget.reserve_s() + sum(self.axes.estimate_s(self.axes.snap(plan))
                                           for n, plan in self.plans.judged_alone().items()
                                           if not begun(n))  # fmt: skip
        used_s = self.record.used_s
        self.s.budget_s = used_s + after_s
        return (f"--finish: nothing more is measured: the tables are fitted from the "
                f"{used_s / 3600:.2f} h read so far, loaded, and judged by the after-run "
                f"(about {after_s / 60:.1f} min; at new random targets where no before-run "
                "was read)")  # fmt: skip

    def too_short(self) -> str | None:
        """Why a fresh commissioning would end with no table: its budget does not hold even
        the cheapest linear axis's ISO runs at 2 runs per target on 5 targets (the least a
        short budget takes); None when it does, on a resume, or with rotary axes only."""
        linear = [a for a in self.s.axes if not self.axes.rotary(a)]
        if self.record.state.get("steps") or not linear:
            return None
        costs = {a: self.axes.estimate_s(self.axes.snap(self.plans.iso_plan(
            a, runs=2, points=adaptive.ISO_LEAST_POINTS))) for a in linear}  # fmt: skip
        axis, least_s = min(costs.items(), key=lambda item: item[1])
        if least_s <= self.s.budget_s:
            return None
        def hours(seconds: float) -> str:  # rounded up: the budget that holds it
            return f"{math.ceil(seconds / 36.0) / 100:.2f} h"

        return (f"--budget-h {self.s.budget_s / 3600:g}: not even one axis's ISO runs fit "
                f"({axis}'s, 2 runs on 5 targets, take {least_s / 60:.1f} min of machine "
                "time before the drift references): the commissioning would end with no "
                f"table; give at least {hours(least_s)} (every axis's: "
                f"{hours(sum(costs.values()))})")  # fmt: skip

    def _compensated(self, axis: str) -> bool:
        """Whether the user's config has a table stage on ``axis`` (pitch, cyclic, linkage,
        backlash, take-up) or a planar model over it."""
        comp = self.config.axes[axis].compensation
        planar = self.config.planar is not None and axis in self.config.planar.axes
        return planar or any((comp.pitch, comp.cyclic, comp.linkage, comp.backlash_mm,
                              comp.takeup))  # fmt: skip

    def asked(self) -> dict[str, float]:
        """What this command asks of the commissioning: more of any of it carries on a
        finished one (a tolerance only where an axis or the plane is judged by it)."""
        out = {"budget_s": self.s.budget_s, "max_rounds": float(self.s.max_rounds)}
        if self.s.planar is not None or any(not self.axes.rotary(a) for a in self.s.axes):
            out["tolerance_um"] = -self.s.tolerance_um
        if any(self.axes.rotary(a) for a in self.s.axes):
            out["tolerance_arcsec"] = -self.s.tolerance_arcsec
        return out

    def other(self) -> str | None:
        """Why this command cannot carry on the commissioning in its directory: it holds
        one of other axes or another plane, whose readings, drift references and tables
        are that one's (carried on, it crashed on a reference of an axis it never read);
        None when it holds none or this one."""
        # (a state finished by 5dcf6cc's code kept it in "finished")
        state = self.record.state
        what = state.get("what") or (state.get("finished") or {}).get("what")
        if what is None or what == self.what():
            return None
        axes, plane = what

        def name(axes: list[str], plane: list[str] | None) -> str:
            return ", ".join(axes) + (f" and the plane {'/'.join(plane)}" if plane else "")

        return (f"{self.record.dir} holds the commissioning of {name(axes, plane)}; this command "
                f"asks for {name(*self.what())}: give --out DIR for another commissioning "
                "(it starts from your config as it is now, the tables of that one in it), or "
                "the same --axes and plane to carry that one on")  # fmt: skip

    def what(self) -> list[Any]:
        """What is commissioned: other axes or another plane are another commissioning."""
        return [list(self.s.axes), list(self.s.planar) if self.s.planar else None]

    def finished(self) -> dict[str, Any] | None:
        """The summary of a commissioning that finished in this directory and that this
        command asks nothing more of (no larger budget, tighter tolerance or more rounds;
        other axes or another plane are refused first, :meth:`other`): run again, it would
        only take the references anew and judge old readings against them, so it is not
        run again."""
        done = self.record.state.get("finished")
        path = self.record.dir / "summary.json"
        if done is None or not path.exists() or self.other() is not None:
            return None
        if any(v > done["asked"].get(k, v) + 1e-9 for k, v in self.asked().items()):
            return None
        return dict(json.loads(path.read_text()))



def _count(n: int, what: str) -> str:
    """``n`` of ``what``, plural past one: "1 step", "4 steps"."""
    return f"{n} {what}{'' if n == 1 else 's'}"
