"""``compgw commission``: one command from an uncalibrated machine to verified tables.

The steps, each a plan run through the running gateway (readings appended and flushed by
:mod:`..plans.runner`), each recorded in ``DIR/commission.json`` once done, so running the same
command again after Ctrl-C, a crash or a power loss carries on where it stopped:

1. identification config (no pitch, backlash, cyclic or planar stage) loaded; per axis
   with a thermal source and its sensor given, a warm-up for the thermal length (Δa) or
   gain (temperature), over a zone read inside and beyond it (:mod:`.thermal`);
   per axis seed 000's backlash at three places (and, where a reversal does not take the
   lost motion up at once, the reversal ladder: :mod:`.takeup`), a coarse ISO
   230-2 run, the cyclic scans
   (when the lead is known), and the *before* verification run (random targets off the
   table), ordered so that no axis is measured right after its own zone warm-up; the
   *before* XY run when the plane is commissioned;
2. tables fitted (the joint pitch + cyclic fit), the *pitch* config loaded, the XY grid
   measured and the planar model fitted (poly or grid by cross-validation), the *full*
   config loaded;
3. rounds of verification at targets never used for fitting (the new spans' midpoints and
   fresh random targets): judged by ISO 230-2 E (XY: maximum vector error) against the
   tolerance; an axis that misses is swept once over its whole travel (:mod:`..fitting.sweep`,
   :mod:`.refine`) when the budget allows; after that, where the residual
   stands out of the repeatability the span gets new table points (their values: the
   table's own plus the residual), a failing plane a denser grid; until within tolerance,
   out of rounds, or out of budget;
4. per axis with no sensor whose screw warmed, its zone warm-up for heat from motion
   (:meth:`.identify.IdentifySteps.heat_warm_ups`); then the *before* targets measured
   again with everything on, on the screw it left warm (before / after on the same
   points), then random short steps on an axis with a take-up curve in what the budget
   has left (:mod:`.after`), the full config left loaded (the user's own where
   the plane reads worse with the tables than without), the report written.

A budget short of the first steps, the before- and after-runs and one round (the drift
references around each counted) takes every axis's ISO runs first, the cyclic scans where
the lead is known and the plane's grid still fits beside them, the plane's grid (with
those tables on, as dense as the budget left allows: :mod:`.short`), then the before-runs
and the backlash tests, and the lead searches last (a plain ISO 230-2 calibration's steps
first, then what judges them, then the extras); spent
before the fit, it still fits the axes whose ISO runs were made (no round verified them,
said so). Where no round judged the tables, the after-run judges them as a round would
(:meth:`.after.AfterSteps.after_verdict`).

The gateway is made to load each config by writing it over the config file it runs and
asking it to reload (the status unit's reload register, or SIGHUP / a command). An abort
puts the user's own config back, reloads it, and says so. Machine time is the plans'
estimate (:func:`..plans.plans.plan_time_s`): the same yardstick for any workflow.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from typing import Any

from ...config import load_config
from ...formats import atomic_write_text
from ..measuring.machine import MachineError
from .after import AfterSteps
from .axes import Axes
from .best import BestTables
from .budget import Budget
from .carried import RunBefore
from .command import CommandChecks
from .configs import own_config_path
from .drift import DriftRefs
from .fit import FitSteps
from .identify import IdentifySteps
from .planner import Planner
from .record import Record, plain_json
from .refine import RefineSteps
from .report import as_read_accuracy, as_read_figures, warm_rerun
from .rotary import RotarySteps
from .rounds import Rounds
from .run_heat import RunHeat
from .short import ShortBudget
from .stager import Reload, Stager
from .steps import BudgetSpent, CommissionAborted, Settings, StepRunner
from .takeup import TakeUpSteps
from .thermal import ThermalSteps

Say = Callable[[str], None]


class Commission:
    """One commissioning: its collaborators wired once, and the four steps in order."""

    def __init__(self, settings: Settings, reload: Reload, say: Say = print,
                 progress: Callable[[str, int, int], None] | None = None) -> None:
        self.s = settings
        self.say = say
        record = Record(settings.out_dir, settings.config_path.resolve().parent)
        for axis, lead in record.state.get("leads", {}).items():  # found by a lead search
            if lead and axis not in settings.lead_mm:
                settings.lead_mm[axis] = float(lead)
        axes = Axes(settings, load_config(own_config_path(settings.config_path,
                                                          record.original_path)))
        # the shared collaborators: what is done, the drift references, the configs, time
        self.record, self.axes = record, axes
        self.drift = drift = DriftRefs(axes, record, say)
        self.stager = stager = Stager(axes, record, drift, reload, say)
        self.budget = budget = Budget(axes, record, drift)
        self.runner = runner = StepRunner(axes, record, drift, budget, say, progress)
        self.run_heat = RunHeat(axes, record, drift, runner, say)
        # the steps, each given what it works with
        self.rotary = rotary = RotarySteps(axes, record, runner=runner, say=say)
        self.thermal = thermal = ThermalSteps(axes, record, drift=drift, say=say)
        self.plans = plans = Planner(axes, record, budget=budget, rotary=rotary,
                                     thermal=thermal)  # fmt: skip
        self.refine = refine = RefineSteps(axes, record, drift=drift, stager=stager,
                                           budget=budget, runner=runner, rotary=rotary,
                                           say=say)  # fmt: skip
        self.takeup = takeup = TakeUpSteps(axes, record, runner=runner, say=say)
        self.run_before = run_before = RunBefore(record)
        self.after = after = AfterSteps(axes, record, stager=stager, runner=runner,
                                        rotary=rotary, takeup=takeup, run_before=run_before,
                                        plans=plans, say=say, clock=drift.clock)  # fmt: skip
        self.best = best = BestTables(axes, record)
        self.short = short = ShortBudget(axes, record, budget=budget, runner=runner,
                                         plans=plans, refine=refine, say=say)  # fmt: skip
        self.command = CommandChecks(axes, record, rotary=rotary, thermal=thermal, plans=plans,
                                     short=short, say=say)  # fmt: skip
        self.fit = fit = FitSteps(axes, record, stager=stager, runner=runner, rotary=rotary,
                                  plans=plans, refine=refine, short=short, say=say)  # fmt: skip
        self.identify = IdentifySteps(axes, record, stager=stager, budget=budget,
                                      runner=runner, rotary=rotary, thermal=thermal,
                                      plans=plans, takeup=takeup, short=short, fit=fit,
                                      say=say)  # fmt: skip
        self.rounds = Rounds(axes, record, stager=stager, budget=budget, runner=runner,
                             rotary=rotary, plans=plans, refine=refine, after=after,
                             best=best, fit=fit, say=say)  # fmt: skip

    async def run(self) -> dict[str, Any]:
        """Commission; returns the summary (also in DIR/summary.json). Raises
        CommissionAborted (after restoring the user's config) on a machine fault."""
        done = self.record.state.pop("finished", None)
        if done is not None:  # asked for more: carries on
            await self.drift.read_clock()  # how long the machine has cooled since
            self._carry_on(done)
        if "what" not in self.record.state:
            self.record.state["what"] = self.command.what()
            self.record.save()
        self.stager.adopt_edits()
        self.stager.original()
        try:
            await self.identify.run()
            await self.fit.fit_axes(curves=bool(self.record.state.get("short")))
            await self.fit.plane()
            outcome = await self.rounds.run()
            ending = len(self.record.state["notes"])
        except BudgetSpent as exc:
            ending = len(self.record.state["notes"])
            self.record.state["notes"].append(f"budget spent: {exc}")
            self.say(f"budget spent: {exc}")
            outcome = "budget"
            self.best.restore_best()  # a refinement not yet judged is not kept
            await self.fit.fit_identified()
        except (MachineError, OSError) as exc:
            where = await self.stager.restore(exc)
            raise CommissionAborted(f"{exc}; {where}") from exc
        self.run_heat.fit()  # no references read: heat from the ISO runs' own levels
        self.drift.fit_motion_heat()
        try:  # heat from motion after the tables: no table is measured on the screw it warms
            await self.identify.heat_warm_ups()
        except BudgetSpent as exc:
            self.record.state["notes"].append(f"no warm-up: {exc}")
        except (MachineError, OSError) as exc:
            where = await self.stager.restore(exc)
            raise CommissionAborted(f"{exc}; {where}") from exc
        self.drift.adopt_warmed_motion()
        self.thermal.motion_for_sensors()  # the after-run judges the final config's heat
        self.run_heat.put_back_sensor(self.thermal.sensor_took_mm)  # tables read under it
        self.run_heat.put_back_refs()  # the identification's tables, by the final model
        try:  # on the screw the warm-up left warm: as the customer's laser will meet it
            await self.after.run()
        except BudgetSpent as exc:
            self.record.state["notes"].append(f"no after-run: {exc}")
        worse = self.after.plane_worse()
        if worse is not None:
            self.record.state["notes"].append(worse)
            self.say(worse)
        else:
            outcome = self.after.after_verdict(outcome)
        if self.record.tables.pitch and worse is None:
            await self.stager.use("full")
        else:
            self.say(await self.stager.restore())
        summary = self.after.summary(outcome)
        atomic_write_text(self.record.dir / "summary.json",
                          json.dumps(summary, indent=1, default=plain_json))
        self.record.state["finished"] = {"outcome": outcome, "asked": self.command.asked(),
                                         "machine_h": self.record.used_s / 3600,
                                         "notes_from": ending}  # fmt: skip
        self.record.save()
        return summary

    def _carry_on(self, done: dict[str, Any]) -> None:
        """A finished commissioning asked for more (budget, rounds, a tighter tolerance):
        what its ending said is dropped (a budget spent, an after-run's verdict) and its
        after-run measured again at the end, with the tables then loaded (its readings
        moved to ``raw/superseded/``); a note says where it carried on from."""
        try:
            summary = json.loads((self.record.dir / "summary.json").read_text())
        except (OSError, ValueError):
            summary = {}
        # what this run's after-run is set against: the run before's, with its tables
        accuracy = as_read_accuracy(summary)
        self.record.state["run_before"] = {
            n: {"read": v, "tables": self.record.tables.digest(n, self.record.config_dir),
                **({"read_A": accuracy[n]} if n in accuracy else {})}
            for n, v in as_read_figures(summary).items()}  # fmt: skip
        # a machine the run before left warm, and not cooled since: said before moving
        warm = warm_rerun(summary, self.drift.clock.now_s(), self.drift.clock.kind())
        if warm is not None:
            self.say(warm)
        notes = self.record.state["notes"]
        del notes[int(done.get("notes_from", len(notes))):]
        # its tables and after-run kept aside, the after-run's raw files in raw/superseded/
        self.run_before.keep([n for n in self.record.state["steps"] if n.startswith("after-")])
        used = done.get("machine_h")
        notes.append(f"carried on after '{done.get('outcome')}'"
                     + (f" at {used:.2f} h of machine time" if used is not None else ""))
        self.record.save()
