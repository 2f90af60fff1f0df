"""What ``compgw commission`` identified, in sentences a technician reads (the report's
Identification section), from the ``identify`` record of its state: one list of
(what, found) per axis. A record this module does not know is shown as it is stored."""

from __future__ import annotations

import contextlib
from collections.abc import Callable
from typing import Any

from ..fitting.iso230 import ARCSEC_PER_MDEG

Record = dict[str, Any]
#: a small error in its axis's unit: µm, or (rotary axes, stored in millidegrees) ″
Fmt = Callable[[float | None], str]


def _um(value: float | None) -> str:
    return "–" if value is None else f"{value:.2f} µm"


def _arcsec(value_mdeg: float | None) -> str:
    return "–" if value_mdeg is None else f"{value_mdeg * ARCSEC_PER_MDEG:.2f}″"


def _lead(r: Record, u: Fmt = _um) -> str:
    if r.get("lead_mm"):
        return (f"a periodic error of {r['amplitude_um']:.2f} µm every {r['lead_mm']:g} mm "
                "stands out of the noise: the cyclic stage follows it")  # fmt: skip
    return "no periodic error stands out of the noise: no cyclic stage"


def _backlash(r: Record, u: Fmt = _um) -> str:
    if "B_arcsec" in r:
        places = ", ".join(f"{v:.1f}″" for v in r.get("places_arcsec", []))
        return f"{r['B_arcsec']:.1f}″ at most (at three places: {places})"
    places = ", ".join(f"{v:.2f}" for v in r.get("places_um", []))
    return f"{r['B_um']:.2f} µm at most (at three places: {places} µm)"


def _takeup(r: Record, u: Fmt = _um) -> str:
    how = ("a take-up curve is kept" if r.get("kept") else
           "switched whole at a reversal")  # fmt: skip
    return f"lost motion {r['lost_um']:.1f} µm; {how}: {r.get('why', '')}"


def _motion_text(r: Record) -> str:
    return (f"Δa {r.get('delta_a_um_per_m', 0.0):.3g} µm per metre of heat, time constant "
            f"{r.get('tau_s', 0.0):.0f} s")  # fmt: skip


def _thermal(r: Record, u: Fmt = _um) -> str:
    if r.get("fitted") is False:
        return f"the configured setting kept: {r.get('why', '')}"
    if "gain" in r:
        text = (f"temperature gain {r['gain']:.3g}: {r['growth_max_um']:.1f} µm of growth "
                f"over {r.get('rise_K', 0.0):.1f} K, the model misses by "
                f"{r['residual_rms_um']:.2f} µm RMS")  # fmt: skip
    elif "delta_a_um_per_m" in r:  # no sensor: the zone warm-up's heat from motion
        shape = (f"spread where the nut worked ({r['spread_mm']:.0f} mm)" if r.get("spread_mm")
                 else "linear from the fixed end")  # fmt: skip
        rms = r.get("profile_rms_um") if r.get("spread_mm") else r.get("linear_rms_um")
        text = (f"heat from motion, read by the laser: {_motion_text(r)}, fixed end at "
                f"{r['origin_mm']:.0f} mm, {shape}: {r['growth_max_um']:.1f} µm of growth, "
                f"the model misses by {float(rms or 0.0):.2f} µm RMS")  # fmt: skip
    elif "length_mm" in r:
        text = (f"thermal length {r['length_mm']:.0f} mm: {r['growth_max_um']:.1f} µm of "
                f"growth, the model misses by {r['residual_rms_um']:.2f} µm RMS")  # fmt: skip
    else:
        return short(r)
    motion = r.get("motion")
    if isinstance(motion, dict) and motion.get("replaces_sensor"):
        text += (f"; heat from the axes' motion replaces the sensor in the final config "
                 f"({_motion_text(motion)}; it misses by {motion.get('motion_rms_um', 0.0):.2f} "
                 f"µm RMS where the sensor's model misses by "
                 f"{motion.get('sensor_rms_um', 0.0):.2f} µm)")  # fmt: skip
    weighed = (motion or {}).get("weighed") if isinstance(motion, dict) else None
    if weighed and "sensor_left_um" in weighed:
        text += (f"; on the drift references read since the start, the sensor's model leaves "
                 f"{weighed['sensor_left_um']:.2f} µm RMS, heat from motion "
                 f"{weighed['motion_left_um']:.2f} µm")  # fmt: skip
    return text


def _motion(r: Record, u: Fmt = _um) -> str:
    if not r.get("fitted"):
        return f"none: {r.get('why', '')}"
    return (f"no sensor; the axes' motion explains the drift ({r['growth_max_um']:.1f} µm "
            f"at most) to {r['residual_rms_um']:.2f} µm RMS: "
            f"{_motion_text(r.get('motion') or r)}; the growth spread evenly from the fixed "
            "end, as the commissioning's moves over the whole travel warmed it: a screw warm "
            "only around its nut, worked in one zone, grows otherwise (a bench machine "
            "cycled over 40 % of its travel kept 34 of its 59 µm); a Δa sensor "
            "(--delta-a) measures where it grows")  # fmt: skip


def _cyclic(r: Record, u: Fmt = _um) -> str:
    peak = f"{r['peak_arcsec']:.1f}″" if "peak_arcsec" in r else u(r["peak_um"])
    return f"{r['harmonics']} harmonic(s) per period, peak {peak}"


def _reversal(r: Record, u: Fmt = _um) -> str:
    how = ("per table point: the play varies along the travel beyond the runs' scatter"
           if r.get("per_point") else "a smooth function of the position")  # fmt: skip
    return f"{how} (scatter of a point's readings {u(r['scatter_um'])})"


def _smoothed(r: Record, u: Fmt = _um) -> str:
    return (f"the table smoothed as its own leave-one-out says: its points moved "
            f"{u(r['change_rms_um'])} RMS")  # fmt: skip


def _interpolation(r: Record, u: Fmt = _um) -> str:
    loo = r.get("loo_rms_um") or {}
    text = f"{r.get('method', 'linear')} ({r.get('why', '')})"
    if loo:
        text += "; leave-one-out RMS " + ", ".join(f"{k} {u(v)}" for k, v in loo.items())
    return text


def _sweep(r: Record, u: Fmt = _um) -> str:
    step = f"{r['step_mm']:g}°" if u is _arcsec else f"{r['step_mm']:g} mm"
    cyclic = (f" and {r['harmonics']} harmonic(s) per turn at {r['stations']} stations"
              if r.get("harmonics") else "")  # fmt: skip
    text = (f"round {r['round']}: {r['readings']} readings every {step} over the travel, "
            f"fitted as a level of {r['knots']} points{cyclic}; they miss it by "
            f"{u(r['residual_rms_um'])} RMS")  # fmt: skip
    if r.get("weighted_out"):
        text += f"; {r['weighted_out']} readings left out (stops that fell short)"
    return text


def _between(r: Record, u: Fmt, table: str, what: str) -> str:
    """What a short budget read between a table's points (``what``), and why."""
    ratio = r.get("misses_x_scatter")
    miss = "–" if ratio is None else f"{ratio:.1f} ×"
    rms = f"{u(r['miss_rms_um'])} RMS, " if r.get("miss_rms_um") is not None else ""
    runs = f", {r['runs']} run{'s' if r['runs'] > 1 else ''} each" if r.get("runs") else ""
    instead = " in place of its more runs" if r.get("instead_of_more_runs") else ""
    read = (f"read{instead or ' too'}{runs}" if r.get("measured") else
            "not read (they did not fit beside the plane's grid, or it does not miss)")  # fmt: skip
    return f"{table} misses between its points {rms}{miss} what its scatter " \
           f"explains; its {what} {read}"


def _midpoints(r: Record, u: Fmt = _um) -> str:
    return _between(r, u, "the first table", "midpoints")


def _quarters(r: Record, u: Fmt = _um) -> str:
    return _between(r, u, "the table with its midpoints", "quarter points")


def _eighths(r: Record, u: Fmt = _um) -> str:
    return _between(r, u, "the table with its quarter points", "eighth points")


def _fit(r: Record, u: Fmt = _um) -> str:
    """A rotary axis's fit: its interpolation and linkage (arcseconds)."""
    text = f"{r['interpolation']} interpolation"
    if "loo_rms_arcsec" in r:
        text += f" (leave-one-out RMS {r['loo_rms_arcsec']:.2f}″)"
    if "linkage_rms_arcsec" in r:
        text += f"; the linkage fitted, residual {r['linkage_rms_arcsec']:.2f}″ RMS"
    return text


#: record kind → (what it is, its sentence)
KINDS: dict[str, tuple[str, Callable[[Record, Fmt], str]]] = {
    "lead": ("lead search", _lead),
    "thermal": ("warm-up (thermal)", _thermal),
    "motion": ("heat from motion", _motion),
    "backlash": ("backlash", _backlash),
    "takeup": ("take-up of the lost motion", _takeup),
    "cyclic": ("periodic error (per screw turn or worm tooth)", _cyclic),
    "reversal": ("reversal (backlash along the travel)", _reversal),
    "smoothed": ("table smoothing", _smoothed),
    "interpolation": ("between the table's points", _interpolation),
    "sweep": ("sweep", _sweep),
    "midpoints": ("midpoints (short budget)", _midpoints),
    "quarters": ("quarter points (short budget)", _quarters),
    "eighths": ("eighth points (short budget)", _eighths),
    "fit": ("table fit (rotary)", _fit),
}


def short(value: Any) -> str:
    """A record as it is stored, inline (lists left out)."""
    if isinstance(value, dict):
        return ", ".join(f"{k} {v:.4g}" if isinstance(v, float) else
                         f"{k} ({short(v)})" if isinstance(v, dict) else f"{k} {v}"
                         for k, v in value.items() if not isinstance(v, list))  # fmt: skip
    return str(value)


def identification_rows(identify: dict[str, Any], rotary: frozenset[str] = frozenset()
                        ) -> dict[str, list[tuple[str, str]]]:  # fmt: skip
    """Per axis (records named ``kind-AXIS``), (what, found) in the order identified, the
    ``rotary`` axes' small errors in ″; a record of no known kind, or one whose fields are
    not the expected, as stored."""
    out: dict[str, list[tuple[str, str]]] = {}
    for key, record in identify.items():
        kind, _, axis = key.partition("-")
        what = KINDS[kind][0] if kind in KINDS else kind
        out.setdefault(axis or "–", []).append((what, sentence(kind, record, axis in rotary)))
    return out


def sentence(kind: str, record: Any, rotary: bool = False) -> str:
    """One identification record (``kind`` as in ``kind-AXIS``) in a sentence; as stored
    where its kind or fields are not the expected."""
    if kind in KINDS and isinstance(record, dict):
        with contextlib.suppress(KeyError, TypeError, ValueError):
            return KINDS[kind][1](record, _arcsec if rotary else _um)
    return short(record)
