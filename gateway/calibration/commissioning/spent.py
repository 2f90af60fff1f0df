"""What each of ``compgw commission``'s steps cost in machine time and what it bought, in
sentences a technician (and whoever pays for the machine's hours) reads: the report's
"Machine time" section, from the summary alone (``spent_s``: each step's machine time in
seconds, in the order run; ``refs_s``: the drift references read around them)."""

from __future__ import annotations

import re
from typing import Any

from .ident_text import sentence

#: a round's steps: its verification, and what it refined (sweeps, new points, a denser grid)
_ROUND = re.compile(r"^(verify|sweep|refine)(\d+)-")


def step_group(name: str) -> tuple[str, str]:
    """The group a step's machine time is counted in, and its axis ('' for none): an
    axis's own identification (``iso-X`` → ('iso', 'X')), a round (``sweep2-X`` →
    ('round 2', '')), the before- and after-runs that judge the tables, the plane's grid."""
    m = _ROUND.match(name)
    if m:
        return f"round {int(m.group(2))}", ""
    kind, _, rest = name.partition("-")
    if kind in ("before", "after"):
        return "judging", ""
    if name == "xy-grid":
        return "plane", ""
    axis = rest.rpartition("-")[2]  # takeup-probe-X → X
    return ("backlash" if kind == "takeup" else kind), axis


def _figure(entry: dict[str, Any], phase: str) -> float | None:
    value = (entry.get(phase) or {}).get("E_um")
    return None if value is None else float(value)


def _arrow(before: float | None, after: float | None) -> str:
    if before is None or after is None:
        return "–"
    return f"{before:.2f} → {after:.2f} µm"


def _round_bought(summary: dict[str, Any], number: int) -> str:
    """A round bought what the next round (or the after-run) reads against what it read."""
    rounds = {int(r["round"]): r for r in summary.get("rounds") or []}
    this = rounds.get(number)
    if this is None:
        return "not judged (the budget ran out in it)"
    done = []
    swept = this.get("swept") or []
    if swept:
        done.append("swept " + ", ".join(swept))
    added = {a: n for a, n in (this.get("added") or {}).items() if a not in swept}
    done += [f"{a} +{n} points" for a, n in added.items()]
    if this.get("grid"):
        done.append(f"XY grid {this['grid'][0]}×{this['grid'][1]}")
    nxt = rounds.get(number + 1)
    if not done:
        return "verified (nothing refined)"
    if nxt is None:
        return "; ".join(done) + ": judged by the after-run"
    figures = [f"{a} E {_arrow(v.get('E_um'), (nxt['axes'].get(a) or {}).get('E_um'))}"
               for a, v in this["axes"].items()]  # fmt: skip
    if this.get("xy") and nxt.get("xy"):
        figures.append(f"XY max {_arrow(this['xy']['max_um'], nxt['xy']['max_um'])}")
    return "; ".join(done) + f": round {number + 1} read " + ", ".join(figures)


def _judging_bought(summary: dict[str, Any]) -> str:
    """The before- and after-runs: the verdict, at the same random targets."""
    parts = [f"{a} E {_arrow(_figure(e, 'before'), _figure(e, 'after'))}"
             for a, e in summary.get("axes", {}).items()]  # fmt: skip
    xy = summary.get("xy") or {}
    if xy.get("before") and xy.get("after"):
        parts.append(f"XY max {_arrow(xy['before']['max_um'], xy['after']['max_um'])}")
    return "the verdict, before → after at the same random targets: " + ", ".join(parts)


def _axis_bought(summary: dict[str, Any], kind: str, axis: str) -> str:
    """What an axis's identification step found, as the report's Identification says it;
    the ISO runs: the table they began."""
    ident = summary.get("identify") or {}

    def found(what: str) -> str | None:
        record = ident.get(f"{what}-{axis}")
        return None if record is None else sentence(what, record)

    if kind == "iso":
        points = summary.get("axes", {}).get(axis, {}).get("table_points")
        return f"the pitch table ({points} points in the end)" if points else "the pitch table"
    if kind == "backlash":
        return "; ".join(t for t in (found("backlash"), found("takeup")) if t) or "–"
    if kind == "warmup":
        text = found("thermal") or "–"
        check = (ident.get(f"thermal-{axis}") or {}).get("drift_check")
        if check:
            text += (f"; on the commissioning's own drift it leaves {check['left_rms_um']:.2f} "
                     f"of {check['drift_rms_um']:.2f} µm RMS"
                     + ("" if check.get("holds") else ": not kept"))  # fmt: skip
        return text
    if kind == "cyclic":
        return found("cyclic") or "no periodic error read"
    return found(kind) or "–"


def spent_rows(summary: dict[str, Any]) -> list[tuple[str, float, str]]:
    """(step, machine minutes, what it bought) per group of steps, in the order first run,
    the drift references last; the minutes add up to the machine time used."""
    minutes: dict[tuple[str, str], float] = {}
    for name, seconds in (summary.get("spent_s") or {}).items():
        key = step_group(name)
        minutes[key] = minutes.get(key, 0.0) + float(seconds) / 60.0
    rows = []
    labels = {"backlash": "backlash and take-up", "iso": "ISO 230-2 runs",
              "cyclic": "cyclic scans", "lead": "lead search", "warmup": "zone warm-up",
              "judging": "before- and after-runs", "plane": "XY grid"}  # fmt: skip
    for (group, axis), mins in minutes.items():
        label = (f"{axis} " if axis else "") + labels.get(group, group)
        if group.startswith("round "):
            bought = _round_bought(summary, int(group.split()[1]))
        elif group == "judging":
            bought = _judging_bought(summary)
        elif group == "plane":
            bought = "the plane's model (see XY plane)"
        else:
            bought = _axis_bought(summary, group, axis)
        rows.append((label, mins, bought))
    refs_s = float(summary.get("refs_s") or 0.0)
    if refs_s > 0.0:
        warmed = summary.get("warmed_um") or {}
        grew = ", ".join(f"{a} {v:.1f} µm" for a, v in warmed.items())
        rows.append(("drift references", refs_s / 60.0,
                     "the screws' drift taken off every run" +
                     (f" (they grew up to {grew})" if grew else "")))  # fmt: skip
    return rows
