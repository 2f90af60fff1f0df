"""The laser software's capture on stationary and its CSV export (for compgw's capture kind).

Why: many technicians do not record continuously. Their software takes one reading each
time the axis has stood still long enough, numbers the readings against the target list
typed into it, and exports a table. This makes that table from a sim recording, with the
laser software's own arithmetic (the sim never imports compgw's gateway).

Capture: a stretch of samples that stays within ``band_um`` of its first sample for
``still_s`` is a stop; its reading is the mean of that stretch. The next capture waits for
the reading to leave the band (the axis moved). Nothing is captured before the first move.

Export: one row per capture, ``Target (mm)``, ``Error (um)``, ``Run``, ``Dir``, the target
list's rows in order. The error is against the laser's datum: the technician zeroes the
laser once, at the first target of the first capture, and keeps that zero (:class:`Datum`).
"""

from __future__ import annotations

import csv
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

#: the software's stability band (µm, the reading's whole spread) and time (s)
BAND_UM = 2.0
STILL_S = 0.5
#: the export's header (what config/capture-generic.yaml names)
EXPORT_HEADER = ("Target (mm)", "Error (um)", "Run", "Dir")


def read_series(path: Path, rtx_unit: str = "um") -> tuple[np.ndarray, np.ndarray]:
    """(time s, value µm) of a sim recording: ``.rtx`` (its header's sample rate, samples
    in ``rtx_unit``) or CSV (``time_s``, ``position_um`` or ``position_mm``, either order)."""
    if path.suffix == ".rtx":
        data = path.read_bytes()
        head, _, rest = data.partition(b"Data:\r\n")
        fields = dict(line.split(": ", 1) for line in head.decode("ascii").split("\r\n")
                      if ": " in line)  # fmt: skip
        values = np.frombuffer(rest[: len(rest) - len(b"EOF::\r\n")], dtype="<f8")
        times_s = np.arange(values.size) / float(fields["Sample rate"])
        return times_s, values * (1000.0 if rtx_unit == "mm" else 1.0)
    with path.open(newline="") as f:
        rows = list(csv.reader(f))
    head_row = [h.strip() for h in rows[0]]
    table = np.array(rows[1:], dtype=np.float64).reshape(-1, len(head_row))
    t_col = next(i for i, h in enumerate(head_row) if h.startswith("time"))
    v_col = 1 - t_col
    scale = 1000.0 if head_row[v_col].endswith("_mm") else 1.0
    return table[:, t_col], table[:, v_col] * scale


def captures(times_s: np.ndarray, values_um: np.ndarray, band_um: float = BAND_UM,
             still_s: float = STILL_S) -> list[float]:  # fmt: skip
    """The reading of each stationary stretch (µm), in order (see the module docstring)."""
    out: list[float] = []
    start, armed = 0, False
    for i in range(1, values_um.size):
        if abs(values_um[i] - values_um[start]) > band_um / 2:
            start, armed = i, True
        elif armed and times_s[i] - times_s[start] >= still_s:
            out.append(float(np.mean(values_um[start:i + 1])))
            armed = False
    return out


@dataclass
class Datum:
    """The laser's zero, set once: the first capture, at the first target (µm, mm)."""

    reading_um: float | None = None
    target_mm: float = 0.0
    exports: list[Path] = field(default_factory=list)

    def error_um(self, reading_um: float, target_mm: float) -> float:
        if self.reading_um is None:
            self.reading_um, self.target_mm = reading_um, target_mm
        return (reading_um - self.reading_um) - (target_mm - self.target_mm) * 1000.0


def read_targets(path: Path) -> list[tuple[float, str, str]]:
    """The target list the technician typed in: (target mm, run, direction) per stop, from
    the ``NAME.targets.csv`` compgw writes (columns ``target_mm``, ``run``, ``direction``)."""
    with path.open(newline="") as f:
        return [(float(r["target_mm"]), r["run"], r["direction"]) for r in csv.DictReader(f)]


def export(path: Path, recording: Path, targets: Path, datum: Datum,
           still_s: float = STILL_S) -> int:  # fmt: skip
    """Capture ``recording`` on stationary (``still_s``) and export it to ``path`` against
    the target list ``targets``; the number of captures (rows past the list get no
    target)."""
    taken = captures(*read_series(recording), still_s=still_s)
    listed = read_targets(targets)
    rows = []
    for k, reading in enumerate(taken):
        if k < len(listed):
            target, run, direction = listed[k]
            rows.append((f"{target:.4f}", f"{datum.error_um(reading, target):.3f}", run,
                         direction))  # fmt: skip
        else:
            rows.append(("", f"{reading:.3f}", "", ""))
    part = path.with_suffix(".part")
    with part.open("w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(EXPORT_HEADER)
        writer.writerows(rows)
    part.replace(path)  # whole, or not there
    datum.exports.append(path)
    return len(taken)
