"""A laser's continuous recording: read it, find the stops, align them with the plan.

The laser's software records while compgw runs a plan with a dwell at every measured stop
(CARTO's Dynamic capture writes ``.rtx``; most software exports a CSV time series). The
laser's clock and compgw's are not synchronised, so the stops are found in the recording
itself (stretches that stay within a band for a good part of the dwell) and matched with
the plan's stops by order and by the steps between them; the laser reads relative to where
it was zeroed, so the plan's first stop is the reference. A recording that does not match
is refused with one line naming the file, how many stops were found against how many were
expected, and the first stop that disagrees, with what that looks like (a reversed sign, a
unit off by 1000, a pause mid-move, another axis's recording). Nothing is fitted from it.

Pure functions over numpy arrays and files; no Modbus.
"""

from __future__ import annotations

import csv
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy.ndimage import maximum_filter1d, minimum_filter1d

from .base import InstrumentError, to_mm, unit_of

#: a stop's samples stay within this band (µm) over the stillness window
DEFAULT_BAND_UM = 3.0
#: the stillness window (s): long enough to tell a slow move from a stop
STILL_WINDOW_S = 0.05
#: recordings faster than this are averaged down to it before the stops are sought (Hz)
WORK_RATE_HZ = 500.0
#: the first part of a stop left out of its value (ringing after the stop)
SETTLE_FRACTION = 0.25
#: steps must agree with the plan's within this (mm): no axis error is larger
STEP_TOLERANCE_MM = 0.25


class RecordingError(InstrumentError):
    """A recording that cannot be used; the message names the file."""


@dataclass(frozen=True)
class Recording:
    """Samples of one channel: times (s from the recording's start) and values (mm)."""

    path: str
    t_s: np.ndarray
    value_mm: np.ndarray
    rate_hz: float
    header: dict[str, str] = field(default_factory=dict)


@dataclass(frozen=True)
class Stop:
    """A stationary stretch of a recording: when, how long, what it read (mm)."""

    start_s: float
    end_s: float
    value_mm: float
    spread_um: float

    @property
    def duration_s(self) -> float:
        return self.end_s - self.start_s


# -- reading files ------------------------------------------------------------------------------
RTX_EOF = (b"EOF::\r\n", b"EOF::\n", b"EOF::")


def read_rtx(path: str | Path, unit: str) -> Recording:
    """A CARTO Dynamic ``.rtx`` file (header, ``Data:``, float64 samples, ``EOF::``), its
    samples in ``unit`` (the header does not say)."""
    unit = unit_of(unit, str(path))
    name = str(path)
    data = Path(path).read_bytes()
    if not data.startswith(b"HEADER::"):
        raise RecordingError(f"{name}: not a CARTO .rtx recording (no 'HEADER::' at its start)")
    marker = data.find(b"Data:\r\n")
    size = 7
    if marker < 0:
        marker, size = data.find(b"Data:\n"), 6
    if marker < 0:
        raise RecordingError(f"{name}: truncated: no 'Data:' line after the header")
    header: dict[str, str] = {}
    for line in data[len(b"HEADER::") : marker].decode("ascii", "replace").splitlines():
        key, sep, value = line.partition(":")
        if sep:
            header[key.strip()] = value.strip()
    body = data[marker + size :]
    eof = next((e for e in RTX_EOF if body.endswith(e)), None)
    if eof is None:
        raise RecordingError(f"{name}: truncated: it does not end with 'EOF::' ({len(body)} "
                             "bytes after 'Data:')")
    body = body[: len(body) - len(eof)]
    if len(body) % 8:
        raise RecordingError(f"{name}: truncated: {len(body)} bytes of samples is not a whole "
                             "number of 8-byte values")
    samples = np.frombuffer(body, "<f8").astype(float)
    rate = _header_float(header, "Sample rate", name)
    actual = header.get("Actual sample rate")
    if actual:
        rate = _header_float(header, "Actual sample rate", name)
    count = header.get("Sample no")
    if count is not None and count.strip().isdigit() and int(count) != samples.size:
        raise RecordingError(f"{name}: the header's 'Sample no' is {int(count)} but the data "
                             f"hold {samples.size} samples")
    bad = np.flatnonzero(~np.isfinite(samples))
    if bad.size:
        raise RecordingError(f"{name}: sample {int(bad[0])} is not a number")
    t_s = np.arange(samples.size) / rate
    return Recording(name, t_s, samples * to_mm(1.0, unit), rate, header)


def _header_float(header: dict[str, str], key: str, name: str) -> float:
    text = header.get(key)
    try:
        value = float(text) if text is not None else math.nan
    except ValueError:
        value = math.nan
    if not math.isfinite(value) or value <= 0:
        raise RecordingError(f"{name}: header '{key}' is {text!r}, not a positive number")
    return value


def read_csv_series(path: str | Path, unit: str, value_column: str | None = None
                    ) -> Recording:  # fmt: skip
    """A CSV time series: a header row; the time column is the one whose name holds
    "time" (seconds, or ms when its name says ms); the value is the other column (or
    ``value_column``), in ``unit``; the columns in any order."""
    unit = unit_of(unit, str(path))
    name = str(path)
    with open(path, newline="", encoding="utf-8-sig") as f:
        lines = f.read().splitlines()
    if len(lines) < 2:
        raise RecordingError(f"{name}: no samples (a header row and one row per sample)")
    head = [h.strip() for h in next(csv.reader(lines[:1]))]
    times = [i for i, h in enumerate(head) if "time" in h.lower()]
    if len(times) != 1:
        raise RecordingError(f"{name}: {len(times)} columns named like a time in {head}: "
                             "name exactly one 'time'")
    ti = times[0]
    if value_column is not None:
        if value_column not in head:
            raise RecordingError(f"{name}: no column {value_column!r} in {head}")
        vi = head.index(value_column)
    else:
        others = [i for i in range(len(head)) if i != ti]
        if len(others) != 1:
            raise RecordingError(f"{name}: columns {head}: say which holds the reading")
        vi = others[0]
    scale_s = 1e-3 if "ms" in head[ti].lower() else 1.0
    try:  # numpy's own parser: a recording of hours at 500 Hz is millions of rows
        both = np.loadtxt(lines[1:], delimiter=",", usecols=(ti, vi), ndmin=2, dtype=float)
        t, v = both[:, 0] * scale_s, both[:, 1]
    except (ValueError, IndexError):  # row by row, to name the line that is wrong
        t, v = _series_rows(list(csv.reader(lines)), ti, vi, scale_s, name)
    t_s, value = np.asarray(t), np.asarray(v) * to_mm(1.0, unit)
    dt = np.diff(t_s)
    if np.any(dt <= 0):
        i = int(np.flatnonzero(dt <= 0)[0])
        raise RecordingError(f"{name}: line {i + 3}: time {t_s[i + 1]:g} s does not follow "
                             f"{t_s[i]:g} s")
    rate = 1.0 / float(np.median(dt)) if dt.size else 1.0
    return Recording(name, t_s - t_s[0], value, rate, {})


def _series_rows(rows: list[list[str]], ti: int, vi: int, scale_s: float,
                 name: str) -> tuple[list[float], list[float]]:
    """A CSV series's time (s) and value columns row by row (blank rows skipped); raises
    RecordingError naming the first line that is not a time and a number."""
    t, v = [], []
    for n, row in enumerate(rows[1:], start=2):
        if not any(cell.strip() for cell in row):
            continue
        try:
            t.append(float(row[ti]) * scale_s)
            v.append(float(row[vi]))
        except (ValueError, IndexError):
            raise RecordingError(f"{name}: line {n}: {row!r} is not a time and a number") \
                from None  # fmt: skip
    return t, v


def read_recording(path: str | Path, unit: str) -> Recording:
    """``.rtx`` or CSV by the file's suffix."""
    if str(path).lower().endswith(".rtx"):
        return read_rtx(path, unit)
    return read_csv_series(path, unit)


# -- stops ---------------------------------------------------------------------------------------
def find_stops(rec: Recording, band_um: float = DEFAULT_BAND_UM,
               min_s: float = 0.0) -> list[Stop]:  # fmt: skip
    """Every stationary stretch: the samples within ``band_um`` over a window of
    :data:`STILL_WINDOW_S`, lasting at least ``min_s`` (and a few samples). A gap in the
    times (samples missing) ends a stretch, and so does a step between two samples beyond
    the band (two stops a short move apart are two). A fast recording is averaged down to about
    :data:`WORK_RATE_HZ` first (a stop lasts seconds; 50 kHz samples add nothing)."""
    t_s, v = _decimated(rec.t_s, rec.value_mm, rec.rate_hz)
    rate = rec.rate_hz * t_s.size / max(rec.t_s.size, 1)
    n = v.size
    w = max(3, round(STILL_WINDOW_S * rate))
    if n < w:
        return []
    # a window starting at i is still when its range is within the band; a sample is
    # still when a still window holds it
    hi = maximum_filter1d(v, w, origin=-(w // 2))[: n - w + 1]
    lo = minimum_filter1d(v, w, origin=-(w // 2))[: n - w + 1]
    still_start = (hi - lo) <= band_um / 1000.0
    covered = np.concatenate(([0], np.cumsum(still_start)))
    idx = np.arange(n)
    first = np.clip(idx - w + 1, 0, still_start.size)
    last = np.clip(idx + 1, 0, still_start.size)
    still = covered[last] - covered[first] > 0
    # a gap in the times, or a step between two samples larger than the band (a move
    # shorter than the window: 0.1 mm at 100 mm/s takes 1 ms), ends a stretch
    gap = (np.diff(t_s) > 3.0 / rate) | (np.abs(np.diff(v)) > band_um / 1000.0)
    out: list[Stop] = []
    i = 0
    while i < n:
        if not still[i]:
            i += 1
            continue
        j = i
        while j + 1 < n and still[j + 1] and not gap[j]:
            j += 1
        if j - i + 1 >= w and t_s[j] - t_s[i] >= min_s:
            part = v[i + int((j - i + 1) * SETTLE_FRACTION) : j + 1]
            out.append(Stop(float(t_s[i]), float(t_s[j]), float(np.median(part)),
                            float(np.ptp(part)) * 1000.0))  # fmt: skip
        i = j + 1
    return out


def _decimated(t_s: np.ndarray, v: np.ndarray, rate_hz: float) -> tuple[np.ndarray, np.ndarray]:
    """Block means down to about :data:`WORK_RATE_HZ` (unchanged when slower)."""
    factor = int(rate_hz // WORK_RATE_HZ)
    if factor <= 1:
        return t_s, v
    n = v.size // factor * factor
    return t_s[:n:factor], v[:n].reshape(-1, factor).mean(axis=1)


def plan_stops(rec: Recording, expected: int, dwell_s: float,
               band_um: float = DEFAULT_BAND_UM) -> list[Stop]:  # fmt: skip
    """The stops compgw dwelt at: the stationary stretches about as long as the dwell (a
    reversal's pause is shorter). Checks the recording's time base against the dwell (a
    sample rate that disagrees with the data makes every stop too short or too long) and
    its unit (values 1000 times off show no stop at all within the band)."""
    found = find_stops(rec, band_um)
    if len(found) < expected / 2:
        for factor, words in ((1e-3, "µm declared as mm"), (1e3, "mm declared as µm")):
            scaled = Recording(rec.path, rec.t_s, rec.value_mm * factor, rec.rate_hz)
            if len(find_stops(scaled, band_um)) >= expected / 2:
                raise RecordingError(f"{rec.path}: found {len(found)} stops, expected "
                                     f"{expected}: the values look like {words} (they show "
                                     "the stops when read so)")
    longest = sorted((s.duration_s for s in found), reverse=True)[: max(expected, 1)]
    if len(longest) >= 3:
        typical = float(np.median(longest))
        if not 0.4 * dwell_s <= typical <= 3.0 * dwell_s:
            raise RecordingError(
                f"{rec.path}: its stops last {typical:.3g} s by its sample rate "
                f"({rec.rate_hz:g} Hz) where compgw stood still {dwell_s:g} s at each: the "
                f"rate disagrees with the data (about {rec.rate_hz * typical / dwell_s:.4g} "
                "Hz would fit)")
    return [s for s in found if s.duration_s >= 0.5 * dwell_s]


def align(rec: Recording, stops: Sequence[Stop], targets_mm: Sequence[float],
          sign: float = 1.0, tolerance_mm: float = STEP_TOLERANCE_MM,
          datum_mm: float | None = None) -> np.ndarray:  # fmt: skip
    """Each plan stop's reading (mm), the stops matched with the plan (:func:`matched`):
    the first stop taken as its target, or with ``datum_mm`` (what the laser read at the
    machine's zero in an earlier recording of the same setup, :func:`datum_of`) each
    reading less the datum: the same zero in every recording."""
    targets = np.asarray(targets_mm, dtype=float)
    found = matched(rec, stops, targets, sign, tolerance_mm)
    return zeroed(found, targets, datum_mm, rec.path)


def matched(rec: Recording, stops: Sequence[Stop], targets_mm: Sequence[float],
            sign: float = 1.0, tolerance_mm: float = STEP_TOLERANCE_MM,
            say: Callable[[str], None] | None = None) -> np.ndarray:  # fmt: skip
    """The readings (mm, as the laser read them, at its own zero) of the stops found,
    matched with the plan's ``targets_mm`` by order and by the steps between them; a
    pause mid-move left out is told to ``say``. Refuses (RecordingError, one line) a
    recording whose stops do not follow the plan."""
    targets = np.asarray(targets_mm, dtype=float)
    found = np.array([s.value_mm for s in stops]) * sign
    name, k, m = rec.path, targets.size, found.size
    if m == 0:
        raise RecordingError(f"{name}: found no stops, expected {k} (is this the recording "
                             "of this step? was the axis still for the dwell?)")
    steps_plan = targets - targets[0]
    for lead in range(1, m - k + 1):  # the machine standing before the first stop or after
        window = found[lead : lead + k]  # the last one (the laser started early, stopped
        if np.all(np.abs(window - window[0] - steps_plan) <= tolerance_mm):  # late)
            return window
    kept = _past_pauses(found, steps_plan, tolerance_mm)
    if kept is not None:
        for i in sorted(set(range(kept[0], kept[-1] + 1)) - set(kept.tolist())):
            if say is not None:
                say(f"{name}: the stop at {stops[i].start_s:.2f} s "
                    f"({found[i] - found[kept[0]]:+.4f} mm from the first) is at none of the "
                    "plan's steps: a pause mid-move, left out")  # fmt: skip
        return found[kept]
    steps_read = found - found[0]
    n = min(k, m)
    off = np.flatnonzero(np.abs(steps_read[:n] - steps_plan[:n]) > tolerance_mm)
    first = int(off[0]) if off.size else n
    if first < 3:  # the very first steps disagree: the whole recording reads otherwise
        head = [i for i in range(1, min(n, 6)) if abs(steps_plan[i]) > 1.0]
        if head:
            ratio = float(np.median([steps_read[i] / steps_plan[i] for i in head]))
            why = _ratio_words(ratio)
            if why is not None:
                raise RecordingError(f"{name}: found {m} stops, expected {k}: the steps "
                                     f"read {ratio:.4g} x the plan's: {why}")
    if first < n:
        at = stops[first]
        raise RecordingError(
            f"{name}: found {m} stops, expected {k}: stop {first + 1} (at {at.start_s:.2f} s "
            f"in the recording) reads {steps_read[first]:+.4f} mm from the first, the plan's "
            f"stop {first + 1} is {steps_plan[first]:+.4f} mm from it{_count_words(m, k)}")
    if m != k:
        at = stops[n].start_s if m > k else stops[-1].end_s
        which = (f"stop {n + 1} at {at:.2f} s is one the plan does not have (a pause "
                 "mid-move?)" if m > k else f"after stop {m} (at {at:.2f} s) the plan's stop "
                 f"{m + 1} at {targets[m]:.4f} mm is missing (a stop cut short, or the "
                 "recording ended early?)")  # fmt: skip
        raise RecordingError(f"{name}: found {m} stops, expected {k}: {which}")
    return found


#: a recording may hold this many stops more than the plan, at none of its steps (pauses)
MAX_PAUSES, PAUSES_PER_STOP = 2, 0.02


def _past_pauses(found: np.ndarray, steps_plan: np.ndarray, tolerance_mm: float
                 ) -> np.ndarray | None:  # fmt: skip
    """The found stops that are the plan's, in order, where the recording holds a few more
    that lie at none of its steps: pauses mid-move (a computer that stalled between an
    approach and its target shows in the recording as the axis standing there), left out
    as a laser's own capture leaves out standstill outside its targets' windows. None
    where the stops do not all match so, where more than a few would be left out
    (:data:`MAX_PAUSES`, or :data:`PAUSES_PER_STOP` of the plan's), or where two stops in
    a row lie at one step the plan reads once (which is the reading is not known)."""
    k, m = steps_plan.size, found.size
    most = max(MAX_PAUSES, int(PAUSES_PER_STOP * k))
    if m <= k or m - k > most:
        return None
    for lead in range(m - k + 1):  # (the machine standing before the first stop)
        kept, i = [lead], lead + 1
        for j in range(1, k):
            while i < m and abs(found[i] - found[lead] - steps_plan[j]) > tolerance_mm:
                i += 1
            if i == m:
                break
            repeated = j + 1 < k and abs(steps_plan[j + 1] - steps_plan[j]) <= tolerance_mm
            if not repeated and i + 1 < m and \
                    abs(found[i + 1] - found[lead] - steps_plan[j]) <= tolerance_mm:  # fmt: skip
                return None  # two stops at one step: which is the reading?
            kept.append(i)
            i += 1
        else:
            if kept[-1] - kept[0] + 1 - k <= most:
                return np.asarray(kept)
    return None


#: a recording's first stop this far (mm) from where the datum puts it: the laser was zeroed
#: again, or its beam broken, since the datum was taken
DATUM_TOLERANCE_MM = 0.5


def datum_of(readings_mm: Sequence[float], targets_mm: Sequence[float]) -> float:
    """The laser's reading at the machine's zero, from a recording's first stop (its
    deviation taken as 0): what :func:`align` takes off later recordings of the setup."""
    return float(readings_mm[0] - targets_mm[0])


def zeroed(found: np.ndarray, targets: np.ndarray, datum_mm: float | None,
           name: Path) -> np.ndarray:  # fmt: skip
    """The readings of the matched stops (``found``, plan order) as positions (mm), less
    ``datum_mm`` (None: the first stop's, :func:`datum_of`)."""
    if datum_mm is None:
        datum_mm = datum_of(found, targets)
    off = float(found[0] - datum_mm - targets[0])
    if abs(off) > DATUM_TOLERANCE_MM:
        raise RecordingError(f"{name}: its first stop reads {off:+.3f} mm from where the "
                             "earlier recordings' zero puts it: the laser was zeroed again "
                             "or its beam broken since; keep one zero for the whole "
                             "commissioning (or start it over)")  # fmt: skip
    return found - datum_mm


def _ratio_words(ratio: float) -> str | None:
    """What a ratio of the steps read to the plan's says, None when it is 1."""
    if abs(ratio - 1.0) < 0.02:
        return None
    if abs(ratio + 1.0) < 0.02:
        return "the sign is reversed (the laser counts the other way: give the sign -1)"
    for factor, words in ((1000.0, "the values look like µm declared as mm"),
                          (0.001, "the values look like mm declared as µm")):
        if abs(ratio / factor - 1.0) < 0.02:
            return words
    return "the stops do not follow this plan (another axis's recording? another step's?)"


def _count_words(found: int, expected: int) -> str:
    if found > expected:
        return " (an extra stop before it: a pause mid-move?)"
    if found < expected:
        return " (a stop missing before it?)"
    return ""
