"""The commissioning report (HTML + PNG): before / after on the same verification targets
(ISO 230-2 per axis, the XY vector map), what each round bought, what remains and why, and
the machine time used. Built from the summary and the steps' raw data, so it can be made
again at any time."""

from __future__ import annotations

import html
import math
from collections.abc import Callable
from pathlib import Path
from typing import Any

from ..fitting import conformity
from ..fitting.iso230 import ARCSEC_PER_MDEG, iso230_raw
from ..plans.rawdata import RawData
from ..reporting.report import (
    ANGULAR,
    LINEAR,
    Figure,
    _f,
    _figures_table,
    _img,
    _page,
    change_text,
    plot_axis,
    plot_xy,
    write_report,
)
from .ident_text import identification_rows
from .spent import spent_rows

#: a step's raw data as commissioning judged it, or None
Load = Callable[[str], "RawData | None"]


def _angular(entry: dict[str, Any]) -> bool:
    """A rotary axis's summary entry: figures in arcseconds (``*_arcsec``)."""
    return entry.get("unit") == "deg"


def _fig(figures: dict[str, Any], key: str) -> float | None:
    """Figure ``key`` (E, A, R, B, M) in its axis's unit: µm, or arcseconds."""
    return figures.get(f"{key}_arcsec", figures.get(f"{key}_um"))


def _unit(entry: dict[str, Any]) -> str:
    return "″" if _angular(entry) else " µm"


def _cut(before: float | None, after: float | None) -> str:
    if not before or after is None:
        return "–"
    return f"{100 * (1 - after / before):.0f} %"


def _tolerance_text(summary: dict[str, Any]) -> str:
    """The tolerances asked, in words: "2 µm", "3″", "2 µm (rotary axes 3″)"."""
    linear = bool(summary.get("xy")) or any(not _angular(e) for e in summary["axes"].values())
    tols = ([f"{summary['tolerance_um']:g} µm"] if linear else []) + (
        [f"{summary['tolerance_arcsec']:g}″"] if "tolerance_arcsec" in summary else [])
    return " (rotary axes ".join(tols) + (")" if len(tols) > 1 else "")


#: what to do next, per outcome that missed the tolerance
NEXT = {
    "budget": "the budget ran out: the same command with a larger --budget-h carries on "
              "from here (every reading is kept)",
    "rounds": "the rounds ran out: the same command with more --max-rounds (or a larger "
              "--budget-h) carries on from here",
    "floor": "what misses is the machine's own scatter or finer than a table follows: more "
             "budget will not help; see the report's What remains (a looser tolerance, or "
             "the mechanics)",
    "after": "the rounds' random targets read within, the after-run's did not: the same "
             "command with a tighter --tolerance-um carries on refining from here (every "
             "reading is kept), or --recheck reads the after-run's targets again",
    "after_again": "the rounds' random targets read within, the after-run's did not, "
                   "again after carrying on: --recheck reads the after-run's targets once "
                   "more; a tighter --tolerance-um again would refine on this machine's "
                   "scatter and heat, not on its tables",
    "undecided": "--recheck reads the after-run's targets again and judges them by the "
                 "same rule; where the budget ran out before it read them again, the same "
                 "command with a larger --budget-h does (every reading is kept); a figure "
                 "that stays this close is the machine's scatter and heat, not its tables: "
                 "more refining will not help",
    "heat": "the tables hold, the machine's heat does not: it drifted while the after-run "
            "measured. Let it cool (an hour or more at rest), then --recheck reads the "
            "after-run's targets again; a temperature or Δa sensor corrects heat in use. "
            "More refining will not help",
}  # fmt: skip


def _uncertainty(figures: dict[str, Any], key: str) -> float:
    """A figure's expanded uncertainty (``<key>_U_um`` or ``_arcsec``): infinite where the
    summary says it is unknown (None: one run), 0 where a summary older than the rule
    gives none."""
    for unit in ("arcsec", "um"):
        if f"{key}_U_{unit}" in figures:
            value = figures[f"{key}_U_{unit}"]
            return math.inf if value is None else float(value)
    return 0.0


def figure_text(name: str, read: float, expanded: float, u: str) -> str:
    """``X E 1.99 µm ±0.90 µm``: a figure as read with its expanded uncertainty (``u``: its
    unit as printed after a number, " µm" or "″")."""
    what = "max" if name == "XY" else "E"
    return (f"{name} {what} {read:.2f}{u}"
            + (" (one run: its scatter unknown)" if math.isinf(expanded)
               else f" ±{expanded:.2f}{u}"))  # fmt: skip


def verdict(summary: dict[str, Any]) -> str:
    """One line a technician acts on: within the tolerance or not as the laser reads the
    after-run (ISO 230-2 E per axis, the plane's maximum vector error: nothing subtracted,
    what the customer's acceptance test reads), where it misses and what to do next.
    WITHIN only where each figure plus its expanded uncertainty is; UNDECIDED where none
    is beyond and some within by less (ISO 14253-1, :mod:`..fitting.conformity`). The
    figures with the machine's drift while measuring taken off are named beside a miss
    only (a diagnosis: heat, not the tables)."""
    tol_text = _tolerance_text(summary)
    missing, close, heat = [], [], True
    unjudged = []  # a table or the plane's model with no after-run (a short budget held none)
    for axis, entry in summary["axes"].items():
        after = entry.get("after") or {}
        e, e_read = _fig(after, "E"), _fig(after, "E_read")
        read = e_read if e_read is not None else e
        if read is None and entry.get("table_points"):
            unjudged.append(axis)
        tol = summary.get("tolerance_arcsec") if _angular(entry) else summary["tolerance_um"]
        if read is None or tol is None:
            continue
        u = _unit(entry)
        decided = conformity.decide(read, tol, _uncertainty(after, "E_read"))
        if decided == "beyond":
            missing.append(f"{axis} E {read:.2f}{u}" + (
                f" as read, {e:.2f} with the drift while measuring taken off"
                if e_read is not None and e is not None and abs(e - e_read) >= 0.05 else ""))
            heat = heat and e is not None and e_read is not None and e <= tol
        elif decided == "undecided":
            close.append(figure_text(axis, read, _uncertainty(after, "E_read"), u))
    after_xy = (summary.get("xy") or {}).get("after") or {}
    if "xy" in summary and not after_xy:
        unjudged.append("the plane")
    xy_read = after_xy.get("max_read_um", after_xy.get("max_um", 0.0))
    decided = conformity.decide(xy_read, summary["tolerance_um"],
                                _uncertainty(after_xy, "max_read"))  # fmt: skip
    if decided == "beyond":
        xy = after_xy.get("max_um", xy_read)
        missing.append(f"XY {xy_read:.2f} µm" + (
            f" as read, {xy:.2f} with the drift taken off" if abs(xy - xy_read) >= 0.05
            else ""))  # fmt: skip
        heat = heat and xy <= summary["tolerance_um"]
    elif decided == "undecided" and after_xy:
        close.append(figure_text("XY", xy_read, _uncertainty(after_xy, "max_read"), " µm"))
    outcome = summary["outcome"]
    if outcome == "within" and not missing and not unjudged and not close:
        return f"WITHIN {tol_text} as the laser reads it on every commissioned axis" + (
            " and the plane" if summary.get("xy") else "") + ", by more than each figure's " \
            "uncertainty; the tables are loaded"
    if unjudged and not missing:  # nothing read beyond it, and not all read: no word
        judged = [a for a in summary["axes"] if a not in unjudged]
        return (f"NO VERDICT on {_listed(unjudged)}: no after-run read there"
                + (f" ({_listed(judged)} within {tol_text} as the laser reads it)"
                   if judged else "")
                + f"; what was fitted is loaded. Next: {NEXT.get(outcome, NEXT['rounds'])}"
                + _same_tables_worse(summary) + _put_back(summary))  # fmt: skip
    if close and not missing and outcome in ("within", "undecided"):
        return (f"UNDECIDED against {tol_text}: {'; '.join(close)} as the laser reads it, "
                "within by less than its uncertainty (ISO 14253-1: neither within nor beyond "
                f"is shown); what was fitted is loaded. Next: {NEXT['undecided']}"
                + _same_tables_worse(summary) + _put_back(summary))  # fmt: skip
    if outcome in ("within", "undecided"):  # the rounds' word against the after-run's
        outcome = "after"
    missing += [f"no after-run on {_listed(unjudged)}"] if unjudged else []
    where = f" ({'; '.join(missing)})" if missing else ""
    if outcome == "after" and summary.get("run_before"):  # carried on, and missed again
        outcome = "after_again"
    advice = NEXT["heat"] if missing and heat else NEXT.get(outcome, NEXT["rounds"])
    if missing and heat and summary.get("cool_min"):
        advice = advice.replace("an hour or more at rest", f"about {summary['cool_min']} "
                                "minutes at rest: three of its fitted heat time constants")
    elif not (missing and heat) and outcome in ("after", "after_again", "rounds", "budget"):
        advice = _before_more(summary) or advice
    return (f"NOT within {tol_text}{where}; what was fitted is loaded. Next: {advice}"
            + _same_tables_worse(summary) + _put_back(summary))


def _listed(names: list[str]) -> str:
    """``X, Y and the plane``."""
    return names[0] if len(names) == 1 else f"{', '.join(names[:-1])} and {names[-1]}"


def _put_back(summary: dict[str, Any]) -> str:
    """Where a carried-on run put tables back because they read worse than the run
    before's (:mod:`.carried`): said, so its figures are known for the run before's."""
    back = summary.get("put_back") or []
    if not back:
        return ""
    return ("; " + ", ".join(back) + ": this run's refinement read worse as read and was put "
            "back: the run before's tables are loaded there")


def _same_tables_worse(summary: dict[str, Any]) -> str:
    """Where a carried-on run reads an axis or the plane worse than the run before on the
    tables that run left unchanged: said, so the difference is not taken for them (random
    machine 3, a tighter rerun after its warm-up: X's table kept, read 0.73 → 2.01 µm)."""
    worse = [(n, r) for n, r in (summary.get("run_before") or {}).items()
             if r["same_tables"] and r["now_um"] > r["before_um"] + 0.05]
    if not worse:
        return ""
    return ("; " + ", ".join(f"{n} {r['before_um']:.2f} → {r['now_um']:.2f} µm" + (
        f" (a target's mean over its runs scatters ±{r['scatter_um']:.2f} µm there)"
        if r.get("scatter_um") else "") for n, r in worse)
            + " as read on the tables the run before left as they were: the machine (its heat, "
            "its scatter) reads otherwise now, not the tables")  # fmt: skip


#: the references moved this much since the cold start (µm, or half the tolerance if more):
#: the machine is warm, and a refinement run now fits its heat, not its tables
WARM_UM = 2.0


def _linear_after(summary: dict[str, Any], key: str) -> dict[str, float | None]:
    """Each linear axis's after-run figure ``key`` in a summary (a rotary axis's figures are
    angles); None where it has none."""
    return {a: (e.get("after") or {}).get(key)
            for a, e in summary.get("axes", {}).items() if e.get("unit") != "deg"}


def as_read_figures(summary: dict[str, Any]) -> dict[str, float]:
    """A summary's after-run as read (µm): E per linear axis, the plane's maximum as
    ``"XY"``; what a carried-on run's after-run is set against."""
    figures = _linear_after(summary, "E_read_um")
    figures["XY"] = ((summary.get("xy") or {}).get("after") or {}).get("max_read_um")
    return {n: float(v) for n, v in figures.items() if v is not None}


def as_read_accuracy(summary: dict[str, Any]) -> dict[str, float]:
    """A summary's after-run as read: ISO 230-2 A per linear axis (µm), the customer's
    acceptance figure beside E."""
    return {n: float(v) for n, v in _linear_after(summary, "A_read_um").items()
            if v is not None}


def _warm_axes(summary: dict[str, Any]) -> dict[str, float]:
    """The axes whose growth since the cold start, as their heat correction is expected
    to leave it (``heat_left_um``; older summaries: the growth itself), is more than
    WARM_UM (or half the tolerance) (µm: the growth)."""
    limit = max(WARM_UM, 0.5 * summary.get("tolerance_um", 0.0))
    grown = summary.get("warmed_um") or {}
    left = summary.get("heat_left_um") or grown
    return {a: grown.get(a, w) for a, w in left.items() if w > limit}


def _warm_text(summary: dict[str, Any], warm: dict[str, float], moved: str) -> str:
    """How far the warm axes' references moved, and what their heat correction is expected
    to leave of it where that is less."""
    left = summary.get("heat_left_um") or {}
    less = {a: left[a] for a in warm if a in left and left[a] < warm[a] - 0.05}
    return (f"its drift references {moved} "
            + ", ".join(f"{a} {w:.1f} µm" for a, w in warm.items())
            + (" (its heat correction is expected to leave about "
               + ", ".join(f"{a} {v:.1f} µm" for a, v in less.items()) + " of it)"
               if less else ""))  # fmt: skip


def warm_rerun(summary: dict[str, Any], now_s: float | None = None,
               clock: str | None = None) -> str | None:
    """Said before a carried-on run moves anything, where the run before left the machine
    warm (its drift references moved more than WARM_UM, or half the tolerance) and it has
    not stood the time to cool since (``now_s`` on the ``clock`` the run before ended on,
    :meth:`.measuring.machine.GatewayClock.kind`): what this run reads carries heat its
    models may not follow, and how long to let it cool (random machine 7, a tighter rerun
    right after its warm-up: Y 0.56 → 3.53 µm as read on the table the run before left).
    None where it is not warm, or has cooled."""
    warm = _warm_axes(summary)
    if not warm:
        return None
    cool = summary.get("cool_min") or 60
    ended = summary.get("ended_clock_s")
    rested_min = None
    if ended is not None and now_s is not None and clock == summary.get("clock"):
        rested_min = max(0.0, (now_s - float(ended)) / 60.0)
        if rested_min >= cool:
            return None
    left = cool if rested_min is None else max(1, round(cool - rested_min))
    rested = "" if not rested_min else f" (it has stood {rested_min:.0f} minutes since)"
    return ("the run before left the machine warm: " + _warm_text(summary, warm, "had moved")
            + f" since it started cold{rested}. What this run reads carries that heat, and "
            "the figures may read worse on tables it leaves as they are. Best: stop now "
            f"(Ctrl-C) and let it cool about {left} more minutes at rest, then run the same "
            "command again; it carries on either way")  # fmt: skip


def _before_more(summary: dict[str, Any]) -> str | None:
    """Advice that never makes it worse: before another run is advised, has the machine
    warmed (its drift references moved), and did the last round read worse than the one
    before? Then that, and what to do instead; None when neither."""
    said = []
    warm = _warm_axes(summary)
    if warm:
        cool = summary.get("cool_min")
        said.append("the machine has warmed: " + _warm_text(summary, warm, "moved")
                    + " since it started cold, and a run now fits that heat, not the tables. "
                    f"Let it cool about {cool if cool else 60} minutes at rest"
                    + (" (three of its fitted heat time constants)" if cool else "")
                    + ", then run the same command again; a temperature or Δa sensor "
                    "corrects heat in use")  # fmt: skip
    worse = _worse_round(summary.get("rounds") or [])
    if worse:
        said.append(worse)
    return "; ".join(said) if said else None


def _worse_round(rounds: list[dict[str, Any]]) -> str | None:
    """The last round against the one before: the axes whose E read worse (more than the
    larger of 0.2 µm and 10 %), said with what was loaded."""
    if len(rounds) < 2:
        return None
    last, before = rounds[-1], rounds[-2]
    worse = []
    for axis, now in (last.get("axes") or {}).items():
        was = (before.get("axes") or {}).get(axis) or {}
        e_now, e_was = now.get("E_um"), was.get("E_um")
        if e_now is not None and e_was is not None and e_now > e_was + max(0.2, 0.1 * e_was):
            worse.append(f"{axis} E {e_was:.2f} → {e_now:.2f} µm")
    if not worse:
        return None
    kept = last.get("restored") or []
    return (f"round {last.get('round', len(rounds))} read worse than the one before "
            f"({', '.join(worse)})"
            + (f": the earlier, better table is loaded for {', '.join(kept)}" if kept else "")
            + ". More refining on this machine as it is now will not help")


def remains(summary: dict[str, Any]) -> list[str]:
    """Sentences on what remains after commissioning, and why."""
    out = []
    outcome = summary["outcome"]
    tol_text = _tolerance_text(summary)
    if outcome == "within":
        out.append(f"Every axis is within {tol_text} (E) between the calibration points.")
    elif outcome == "budget":
        out.append(f"The machine-time budget ({summary['budget_h']:.2f} h) was spent before "
                   f"the verification met {tol_text}; what was fitted so far is "
                   "loaded.")  # fmt: skip
    elif outcome == "floor":
        out.append("The residual that misses the tolerance does not stand out of the "
                   "machine's repeatability (judged with more runs per target where the budget "
                   "allowed), or it is finer than the table can follow: more points "
                   "would not help.")  # fmt: skip
    elif outcome == "undecided":
        out.append(f"The after-run reads within {tol_text}, but on some axis or the plane by "
                   "less than what its few runs can show (its expanded uncertainty: the "
                   "runs' scatter and the drift while measuring): neither within nor beyond "
                   "is shown (ISO 14253-1).")  # fmt: skip
    elif outcome == "after":
        out.append(f"The verification rounds met {tol_text} at their random targets; the "
                   "after-run, at the before-run's, did not (below): the tables hold that "
                   "well at some places and not at others.")  # fmt: skip
    else:
        out.append(f"The rounds ran out before the verification met {tol_text}.")
    for axis, entry in summary["axes"].items():
        after = entry.get("after")
        if not after:
            continue
        a, r, e = _fig(after, "A"), _fig(after, "R"), _fig(after, "E")
        u = _unit(entry)
        if a is not None and r is not None and e is not None:
            b = _fig(after, "B")
            out.append(f"Axis {axis}: A {a:.2f}{u}, of which E {e:.2f}{u} is systematic (what "
                       f"a table corrects) and R {r:.2f}{u} the scatter from one approach to "
                       "the next at a target (ISO 230-2's repeatability, ±2s, with the "
                       "reversal between directions"
                       + (f", B {abs(b):.2f}{u}" if b is not None else "")
                       + "): no table removes scatter, so a large R against the drive's own "
                       "repeatability points at the mechanics or at heat while measuring."
                       + _pooled(after, u))  # fmt: skip
    out += [str(n) for n in summary.get("notes", [])]
    return out


def _pooled(after: dict[str, Any], unit: str) -> str:
    """What R rests on where it has few runs per target, and the pooled scatter of a stop
    (linear axes; older summaries have neither: nothing said)."""
    runs, s = after.get("runs"), after.get("s_pooled_um")
    if runs is None or s is None or runs >= 5 or unit != " µm":
        return ""
    return (f" Here R rests on {runs} runs per target (ISO 230-2 asks 5): the largest of "
            f"many scatters each from {runs} stops reads high; pooled over the targets a stop "
            f"scatters {s:.2f} µm (±2s: {4 * s:.2f} µm), the figure to hold against the "
            "drive's repeatability.")


def _drift_off(before: float, after: float, read: float, unit: str, what: str = "E") -> str:
    """The figures with the machine's drift while measuring taken off, where they differ
    from what the laser read: a diagnosis (what the tables leave on a machine at rest)."""
    if abs(after - read) <= max(0.3, 0.2 * read):
        return ""
    return (f"; with the drift while measuring taken off (diagnosis: heat): {what} "
            f"{before:.2f} → {after:.2f}{unit}")


def _carried(after: dict[str, Any]) -> str:
    """Where a carried-on run kept the run before's after-run (its tables as it left them)."""
    return ("; after: the run before's reading (its tables as it left them, not read again)"
            if after.get("carried") else "")


#: an after-run read alone (``--finish`` stopped the run before its before-run)
NO_BEFORE = ("no before-run (the run stopped before it): read once, with the tables on, at "
             "random targets none of them was fitted on")


def summary_lines(summary: dict[str, Any]) -> list[str]:
    """What a commissioning bought, a line per axis, the plane and the outcome: the figures
    as the laser read them (nothing subtracted), the drift-corrected ones beside them where
    they differ (a diagnosis: the machine's heat while measuring, not the tables)."""
    lines = []
    for axis, entry in summary["axes"].items():
        b, a = entry.get("before", {}), entry.get("after", {})
        if b and a:
            u = _unit(entry)
            eb, ea = _fig(b, "E") or 0.0, _fig(a, "E") or 0.0
            rb, ra = _fig(b, "E_read"), _fig(a, "E_read")
            if rb is None or ra is None:  # (a summary from before the as-read figures)
                rb, ra = eb, ea
            a_read = _fig(a, "A_read")
            lines.append(f"{axis}: E {rb:.2f} → {ra:.2f}{u} as read "
                         f"({change_text(rb, ra) if rb else '–'}), A "
                         f"{_fig(b, 'A_read') or _fig(b, 'A') or 0:.2f} → "
                         f"{a_read if a_read is not None else _fig(a, 'A') or 0:.2f}{u} (R "
                         f"{_fig(a, 'R') or 0:.2f}), {entry.get('table_points')} table points"
                         + (f", {entry['interpolation']} interpolation"
                            if "interpolation" in entry else "")
                         + _drift_off(eb, ea, ra, u) + _carried(a))  # fmt: skip
        elif a:  # (--finish stopped the run before its before-run)
            u, ra = _unit(entry), _fig(a, "E_read") or _fig(a, "E") or 0.0
            lines.append(f"{axis}: E {ra:.2f}{u} as read, A "
                         f"{_fig(a, 'A_read') or _fig(a, 'A') or 0:.2f}{u} (R "
                         f"{_fig(a, 'R') or 0:.2f}), {entry.get('table_points')} table points; "
                         + NO_BEFORE)  # fmt: skip
    xy = summary.get("xy") or {}
    if xy.get("before") and xy.get("after"):
        b, a = xy["before"]["max_um"], xy["after"]["max_um"]
        rb = xy["before"].get("max_read_um", b)
        ra = xy["after"].get("max_read_um", a)
        lines.append(f"XY max vector error {rb:.2f} → {ra:.2f} µm as read "
                     f"({change_text(rb, ra)})" + _drift_off(b, a, ra, " µm", "max")
                     + _carried(xy["after"]))  # fmt: skip
    elif xy.get("after"):
        a = xy["after"]["max_um"]
        lines.append(f"XY max vector error {xy['after'].get('max_read_um', a):.2f} µm as read; "
                     + NO_BEFORE)  # fmt: skip
    if summary.get("retried"):
        lines.append(f"{summary['retried']} Modbus requests answered only when tried again "
                     "(exception 6 or 11: a drive or instrument slow to answer; if many, "
                     "raise the bus's timeout_s)")
    lines.append(f"outcome: {summary['outcome']}; machine time {summary['machine_h']:.2f} h "
                 "(plan estimate); before and after at the same random targets, none a "
                 f"table point{_before_iso(summary)}")  # fmt: skip
    lines.append(verdict(summary))
    return lines


def _before_iso(summary: dict[str, Any]) -> str:
    """Said where an axis's figures before are its ISO runs' (no before-run read)."""
    iso = [a for a, e in summary["axes"].items() if (e.get("before") or {}).get("read_at") == "iso"]
    return (f" ({', '.join(iso)}: no before-run; the figures before are the ISO runs', the "
            "tables off, at the table's own points)" if iso else "")


def build(summary: dict[str, Any], load: Load) -> tuple[str, list[Figure]]:
    """HTML text and figures of a commissioning: its summary, and ``load(step)``, a step's
    raw data as commissioning judged it (drift taken off), None when not measured."""
    parts = ["<h1>compgw commissioning report</h1>",
             f"<p id='verdict'><b>{html.escape(verdict(summary))}</b>.</p>",
             f"<p>Configuration: {html.escape(summary['config'])}. Tolerance "
             f"{html.escape(_tolerance_text(summary))} (ISO 230-2 E between the calibration "
             f"points). Outcome: <b>{html.escape(summary['outcome'])}</b>. Machine time used "
             f"{summary['machine_h']:.2f} h of a {summary['budget_h']:.2f} h budget. "
             "Before and after are measured at the same random targets, none of them a "
             f"calibration point{_before_iso(summary)}; figures per ISO 230-2, in µm (rotary "
             "axes: in arcseconds ″, targets in degrees).</p>"]  # fmt: skip
    figures: list[Figure] = []
    rows = []
    for axis, entry in summary["axes"].items():
        b, a = entry.get("before", {}), entry.get("after", {})
        name = f"{axis} ({_unit(entry).strip()})"
        rows.append(f"<tr><th>{html.escape(name)}</th><td>{_f(_fig(b, 'E'))}</td>"
                    f"<td>{_f(_fig(a, 'E'))}</td><td>{_cut(_fig(b, 'E'), _fig(a, 'E'))}</td>"
                    f"<td>{_f(_fig(b, 'A'))}</td><td>{_f(_fig(a, 'A'))}</td>"
                    f"<td>{_f(_fig(a, 'R'))}</td><td>{entry.get('table_points', '–')}</td>"
                    f"<td>{_f(_fig(b, 'E_read'))} → {_f(_fig(a, 'E_read'))}</td></tr>")
    parts.append("<h2>Summary</h2><table id='summary'><tr><th>axis</th><th>E before</th>"
                 "<th>E after</th><th>E cut</th><th>A before</th><th>A after</th>"
                 "<th>R after</th><th>table points</th><th>E as read</th></tr>"
                 + "".join(rows) + "</table>"
                 "<p>E, A and R judge the tables: the machine's drift while it was measured "
                 "(read at the drift references) is taken off. <i>E as read</i> leaves it in: "
                 "what the same targets read as they were read, and what <code>compgw "
                 "commission --recheck</code> compares later. Far apart, the machine moved "
                 "while measuring (heat): a thermal setting corrects that, not a table.</p>")
    xy = summary.get("xy") or {}
    if xy:
        b, a = xy.get("before", {}), xy.get("after", {})
        read = (f" As read (the drift left in): {_f(b.get('max_read_um'))} → "
                f"{_f(a.get('max_read_um'))} µm." if a.get("max_read_um") is not None else "")
        parts.append(f"<p id='summary-xy'>XY maximum vector error: {_f(b.get('max_um'))} µm "
                     f"before, {_f(a.get('max_um'))} µm after "
                     f"({change_text(b['max_um'], a['max_um']) if b and a else '–'}).{read}</p>")
    parts.append("<h2>What remains</h2><ul>" + "".join(
        f"<li>{html.escape(s)}</li>" for s in remains(summary)) + "</ul>")  # fmt: skip
    rrows = []
    angular = any(_angular(e) for e in summary["axes"].values())
    round_units = "µm, rotary axes ″" if angular else "µm"
    for entry in summary["rounds"]:
        axes = "; ".join(_round_cell(k, v, summary["axes"].get(k, {}))
                         for k, v in entry["axes"].items())  # fmt: skip
        if entry.get("xy"):
            axes += f"; XY max {entry['xy']['max_um']:.2f}"
        swept = entry.get("swept") or []
        added = ", ".join(f"{k} swept over its travel (+{n} points)" if k in swept else
                          f"{k} +{n} points" for k, n in (entry.get("added") or {}).items())
        if entry.get("grid"):
            added += f"{', ' if added else ''}XY grid {entry['grid'][0]}×{entry['grid'][1]}"
        for name in entry.get("restored") or []:
            added += f"{', ' if added else ''}{name} back to its best (the refinement did not pay)"
        for name, runs in (entry.get("verify_runs") or {}).items():
            added += (f"{', ' if added else ''}{name} verified again with {runs} runs (what "
                      "misses is within the noise of fewer)")  # fmt: skip
        rrows.append(f"<tr><td>{entry['round']}</td><td>{html.escape(axes)}</td>"
                     f"<td>{html.escape(added or entry.get('outcome', '–'))}</td>"
                     f"<td>{entry['machine_s'] / 3600:.2f}</td></tr>")  # fmt: skip
    parts.append("<h2>Rounds: what each refinement bought</h2><p>Each round is judged at "
                 "targets never used to fit (the new spans' midpoints and fresh random "
                 "targets); where the residual stands out, the span gets a new point (the first "
                 "time an axis misses, if the budget allows, a sweep of its whole travel "
                 "gives it a point at every target read and the cyclic term a station every "
                 "few leads).</p>"
                 + (f"<table id='rounds'><tr><th>round</th><th>verification ({round_units})"
                    "</th><th>then</th><th>machine h so far</th></tr>" + "".join(rrows)
                    + "</table>" if rrows else
                    "<p id='rounds'>No round ran: the budget was spent before the first "
                    "verification (see what remains, above).</p>"))  # fmt: skip
    spent = spent_rows(summary)
    if spent:
        used_min = sum(m for _, m, _ in spent)
        cells = "".join(f"<tr><th>{html.escape(step)}</th><td>{m:.1f}</td>"
                        f"<td>{100.0 * m / used_min:.0f} %</td><td>{html.escape(bought)}</td></tr>"
                        for step, m, bought in spent)  # fmt: skip
        parts.append("<h2>Machine time: what each step cost and bought</h2><table id='spent'>"
                     "<tr><th>step</th><th>machine min</th><th>share</th><th>bought</th></tr>"
                     + cells + "</table>")  # fmt: skip
    ident = identification_rows(summary.get("identify", {}), frozenset(
        a for a, e in summary["axes"].items() if _angular(e)))  # fmt: skip
    if ident:
        parts.append("<h2>Identification</h2><p>What the first steps (and each sweep) "
                     "found, per axis, in the order found.</p>")  # fmt: skip
        for axis, rows in ident.items():
            cells = "".join(f"<tr><th>{html.escape(what)}</th><td>{html.escape(text)}</td></tr>"
                            for what, text in rows)  # fmt: skip
            parts.append(f"<table id='identify-{html.escape(axis)}'><caption>axis "
                         f"{html.escape(axis)}</caption>{cells}</table>")  # fmt: skip
    for axis in summary["axes"]:
        raws = {p: r for p in ("before", "after") if (r := load(f"{p}-{axis}")) is not None}
        if not raws:
            continue
        iso = {p: iso230_raw(r)[axis] for p, r in raws.items()}
        units = ANGULAR if _angular(summary["axes"][axis]) else LINEAR
        parts.append(f"<h2>Axis {html.escape(axis)}</h2>")
        parts.append(_figures_table(axis, iso, units))
        steps = summary["axes"][axis].get("short_steps")
        if steps:
            switch = steps.get("switch_miss_um")
            parts.append(f"<p id='short-steps-{html.escape(axis)}'>Short steps ({steps['stops']} "
                         "random steps of 5 µm to 2 mm either way, where a reversal takes up "
                         "only part of the play; none a calibration point), everything on: "
                         f"RMS {steps['rms_um']:.2f} µm, largest {steps['max_um']:.2f} µm"
                         + (f" (switching the whole lost motion at a reversal would miss by up "
                            f"to {switch:.1f} µm after such reversals)" if switch else "")
                         + ".</p>")  # fmt: skip
        png = plot_axis(axis, {p: (raws[p], iso[p]) for p in raws}, units)
        figures.append(Figure(f"axis-{axis}", png, f"axis {axis}: before and after, at the "
                              "same verification targets"))  # fmt: skip
        parts.append(_img(figures[-1]))
    xy_raws = {p: r for p in ("before", "after") if (r := load(f"{p}-xy")) is not None}
    if xy and xy_raws:
        raws = xy_raws
        axes = tuple(next(iter(raws.values())).axes)[:2]
        png, _ = plot_xy(raws, axes)  # type: ignore[arg-type]
        figures.append(Figure("xy-field", png, "XY error field before and after"))
        parts.append("<h2>XY plane</h2>" + _img(figures[-1]))
    return _page("compgw commissioning report", "\n".join(parts)), figures


def _round_cell(axis: str, verdict: dict[str, Any], entry: dict[str, Any]) -> str:
    """A round's verdict of an axis (µm; a rotary axis's millidegrees shown in ″)."""
    if _angular(entry):
        k = ARCSEC_PER_MDEG
        return f"{axis}: E {verdict['E_um'] * k:.2f}″, A {verdict['A_um'] * k:.2f}″"
    return f"{axis}: E {verdict['E_um']:.2f}, A {verdict['A_um']:.2f}"


def write(directory: Path, summary: dict[str, Any], load: Load) -> Path:
    """The report in ``directory``/report (see :func:`build`)."""
    text, figures = build(summary, load)
    return write_report(directory / "report", text, figures)
