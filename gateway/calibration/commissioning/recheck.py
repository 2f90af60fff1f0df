"""``compgw commission --recheck``: whether a finished commissioning's tables still hold.

Months on, after a crash or a repair, the question is not "calibrate again?" but "is it
still within?". The recheck measures the commissioning's own before/after targets again
(random, none a table point; the plane's random points too) with the gateway on the
config it runs now, judges them as the after-run was judged (ISO 230-2 E per axis, the
plane's maximum vector error) against the commissioning's tolerance, and says, per axis,
then and now. It fits nothing and writes no config: its readings and figures go to
``recheck/<date-time>/`` beside the commissioning's own. No drift references: the machine
is judged as it stands.
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from ...formats import atomic_write_text
from ..fitting import conformity
from ..fitting.iso230 import ARCSEC_PER_MDEG, iso230_axis, pooled_s_um
from ..measuring.session import Session, planar_figures
from ..plans.plans import Plan, read_plan
from ..plans.rawdata import axis_deviations, read_raw_csv


def finished_summary(directory: Path, state: dict[str, Any]) -> dict[str, Any] | None:
    """The summary of the commissioning that finished in ``directory`` (None: none did)."""
    path = directory / "summary.json"
    if state.get("finished") is None or not path.exists():
        return None
    return dict(json.loads(path.read_text()))


def recheck_plans(job: Any, summary: dict[str, Any]) -> list[tuple[str, Plan]]:
    """The commissioning's after-run plans still on disk (the before-run's targets, or
    those of one read alone), else its before-run's: per axis, then the plane."""
    out = []
    plane = summary.get("xy") and job.s.planar is not None  # (with --xy-device only)
    names = [*summary["axes"], *(["xy"] if plane else [])]
    for name in names:
        paths = [job.record.dir / "plans" / f"{phase}-{name}.plan" for phase in ("after", "before")]
        path = next((p for p in paths if p.exists()), None)
        if path is not None:
            out.append((name, read_plan(path)))
    return out


async def recheck(job: Any, summary: dict[str, Any], say: Callable[[str], None] = print
                  ) -> dict[str, Any]:  # fmt: skip
    """Measure the commissioning's random targets again with the loaded config; the
    figures then and now per axis and for the plane, and whether each is within the
    commissioning's tolerance (also written to ``recheck/<date-time>/recheck.json``)."""
    plans = recheck_plans(job, summary)
    if not plans:
        raise ValueError(f"{job.record.dir}: no before/after plan to measure again "
                         "(plans/before-*)")
    stamp = time.strftime("%Y%m%d-%H%M%S")
    out_dir = job.record.dir / "recheck" / stamp
    for k in range(2, 100):  # two in one second: each its own
        if not out_dir.exists():
            break
        out_dir = job.record.dir / "recheck" / f"{stamp}-{k}"
    out_dir.mkdir(parents=True)
    total_s = sum(job.axes.estimate_s(p) for _, p in plans)
    say(f"recheck of the commissioning finished {summary.get('finished_at', '(undated)')}: "
        f"{sum(sum(m.measured for m in p.moves) for _, p in plans)} readings at its random "
        f"targets, about {total_s / 3600:.2f} h of machine time, the tables as loaded now")
    result: dict[str, Any] = {"commissioned": summary.get("finished_at"),
                              "at": time.strftime("%Y-%m-%d %H:%M"), "items": {}}
    for name, plan in plans:
        raw = out_dir / f"{name}.csv"
        park = {} if name == "xy" else job.axes.park(name)
        session = Session(job.axes.config, job.record.config_dir, job.s.gateway, job.s.instruments,
                          job.s.motion, park)  # fmt: skip
        await session.run(plan, raw, "on")
        scatter = [it["s_pooled_um"] for it in result["items"].values() if "s_pooled_um" in it]
        result["items"][name] = _judged(name, raw, summary, job, scatter)
        say(item_line(name, result["items"][name]))
    result["within"] = all(item["within"] for item in result["items"].values())
    atomic_write_text(out_dir / "recheck.json", json.dumps(result, indent=1))
    result["dir"] = str(out_dir)
    return result


def _judged(name: str, raw: Path, summary: dict[str, Any], job: Any,
            scatter_um: list[float]) -> dict[str, Any]:  # fmt: skip
    """One axis's (or the plane's) figure now, then, the tolerance, in its unit, and the
    decision by the commissioning's rule (:mod:`..fitting.conformity`: no drift references
    here, so the runs' scatter alone; the plane's from the linear axes read before it,
    ``scatter_um``)."""
    data = read_raw_csv(raw)
    extra: dict[str, Any] = {}
    if name == "xy":
        now = planar_figures(data, job.s.planar)["max_um"]
        after = summary["xy"].get("after", {})
        then = after.get("max_read_um", after.get("max_um"))
        tol, unit, what = summary["tolerance_um"], "µm", "XY max vector error"
        expanded = conformity.vector_uncertainty_um(scatter_um, 0.0)
    else:
        entry = summary["axes"][name]
        iso = iso230_axis(axis_deviations(data, name))
        expanded = conformity.iso_uncertainty_um(iso, 0.0)
        after = entry.get("after", {})
        if entry.get("unit") == "deg":  # figures in millidegrees; the summary's in ″
            now = iso.E_um * ARCSEC_PER_MDEG
            then = after.get("E_read_arcsec", after.get("E_arcsec"))
            expanded *= ARCSEC_PER_MDEG
            tol, unit = summary.get("tolerance_arcsec", 3.0), "″"
        else:
            now, then = iso.E_um, after.get("E_read_um", after.get("E_um"))
            tol, unit = summary["tolerance_um"], "µm"
            extra["s_pooled_um"] = pooled_s_um(iso)
        what = f"{name}: E"
    decided = conformity.decide(now, tol, expanded)
    return {"what": what, "now": now, "then": then, "tolerance": tol, "unit": unit,
            "U": None if math.isinf(expanded) else expanded, "decided": decided,
            "within": decided == "within", **extra}  # fmt: skip


def item_line(name: str, item: dict[str, Any]) -> str:
    """One axis's (or the plane's) recheck line: then, now, its uncertainty, its decision."""
    u = item["unit"] if item["unit"] == "″" else f" {item['unit']}"
    then = "–" if item["then"] is None else f"{item['then']:.2f}{u}"
    tol = f"{item['tolerance']:g}{u}"
    spread = "one run: its scatter unknown" if item.get("U") is None else f"±{item['U']:.2f}{u}"
    verdict = {"within": f"within {tol}, by more than its uncertainty ({spread})",
               "beyond": f"NOT within {tol}"}.get(
        item["decided"], f"UNDECIDED against {tol}: within by less than its "
                                 f"uncertainty ({spread})")  # fmt: skip
    return f"{item['what']} {then} at the after-run, {item['now']:.2f}{u} now (both as read): " \
           + verdict


def verdict_line(result: dict[str, Any]) -> str:
    """The recheck in one line a technician acts on."""
    def named(name: str) -> str:
        return name.upper() if name == "xy" else name

    missing = [n for n, item in result["items"].items()
               if item["decided"] == "beyond"]
    close = [n for n, item in result["items"].items() if item["decided"] == "undecided"]
    if not missing and not close:
        return "the tables still hold: every axis and the plane within the commissioning's " \
               "tolerance"
    if not missing:
        return (f"UNDECIDED on {', '.join(map(named, close))}: within the commissioning's "
                "tolerance by less than the reading's uncertainty (its runs' scatter; ISO "
                "14253-1): neither within nor beyond is shown; the machine's scatter, not its "
                "tables")
    # read as far out at the after-run: the machine's own drift while measuring, not a change
    same = [n for n in missing if (then := result["items"][n]["then"]) is not None
            and then > result["items"][n]["tolerance"]]  # fmt: skip
    changed = [n for n in missing if n not in same]
    out = []
    if changed:
        out.append(f"NOT within on {', '.join(map(named, changed))}: the machine has changed "
                   "since (or the gateway does not run the commissioned config: compgw status "
                   "says which it loaded); commission it again into a new directory (--out)")
    if same:
        out.append(f"NOT within on {', '.join(map(named, same))}, as it read at the after-run "
                   "too: the machine's drift while measuring (heat), which the commissioning's "
                   "own figures take off; a thermal setting for the axis (a sensor, or heat "
                   "from motion) corrects it, not a new table")
    return "; ".join(out)
