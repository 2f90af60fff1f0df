"""The laser recording continuously, as CARTO's Dynamic capture does (``laser.recording``).

Why: a technician's laser often cannot be asked for readings at all; it records the whole
run and the file is matched to the plan afterwards (by the sequence of stops, not by
timestamps). The sim writes such files from its truth, so that matching can be tested.

Timeline: the recording follows machine time. Every :meth:`MachineClock.advance` reaches
:meth:`Recorder._on_advance`, which first (at ``time_scale`` 0 only) adds the wall time
that passed since the last event as standstill at the current position, scaled by
``1 / idle_time_scale`` (at time_scale 0 a master's dwell is wall time the machine never
sees: this is how it shows in the recording), then samples the machine at ``rate_hz`` for
the machine times in (t_old, t_new] with :meth:`Machine.table_mm`, in increasing time.
At ``time_scale`` > 0 wall time already is machine time: :meth:`Recorder.catch_up` (before
every Modbus request, and at the stop) samples up to now and no idle is added.

A sample = table position + laser noise (``noise_um``) + while the axis moves a sine of
``vibration_um`` at ``vibration_hz`` with normal noise of half that, or after a stop a
decaying oscillation (``ringing_um``, ``ringing_s``, at ``vibration_hz``) ahead in the
move's direction; rounded to 1 nm. Samples are kept in µm and converted on writing.

Files (written atomically: a temporary file, then a rename):

* ``.rtx``: ``HEADER::`` CRLF, ``Key: value`` CRLF lines, ``Data:`` CRLF, the samples as
  little-endian float64 in the configured unit, ``EOF::`` CRLF (../shared/INSTRUMENTS.md);
* ``.csv``: a header row ``time_s,position_um`` (or ``position_mm``; in ``csv_columns``
  order), one row per sample, time from the start plus ``clock_offset_s``, 6 decimals.

``drop_s: [start_s, end_s]`` leaves the samples of that stretch of recording time out of
the file (a lost beam). Control over Modbus: :mod:`sim.instruments` (register 0x0100).
"""

from __future__ import annotations

import math
import os
import re
from collections.abc import Callable
from datetime import datetime
from pathlib import Path

import numpy as np

from sim.clock import MachineClock
from sim.config import LaserRecordingConfig
from sim.machine import AxisState, Machine

#: after the last move of any axis, every sample is taken from the machine while it may
#: still settle (SETTLED_TAUS of its settling time constant, at most EXACT_S; STILL_S
#: without settling); later ones from knots COARSE_S apart (slow drift, linear between)
EXACT_S = 2.0
SETTLED_TAUS = 8.0
STILL_S = 0.05
COARSE_S = 1.0
#: the middle of a move (the recorded axis's, up to MOVE_EDGE_S before it ends) is taken
#: from knots MOVE_KNOT_S apart, linear between: a laser's samples while the axis runs are
#: only ever seen as not standing still, and each exact one costs the whole truth (a
#: 33-minute warm-up at 500 Hz: 978 000 of them, most of a recorded commissioning's time)
MOVE_KNOT_S = 0.02
MOVE_EDGE_S = 0.05
_FILE_RE = re.compile(r"rec-(\d{3,})\.(rtx|csv)$")


class RecorderError(RuntimeError):
    """A control request the recorder cannot follow (not recording, a file not written)."""


class Recorder:
    """One laser channel recorded at a fixed rate along machine time (+ idle wall time)."""

    def __init__(
        self,
        cfg: LaserRecordingConfig,
        axis: str,
        machine: Machine,
        clock: MachineClock,
        rng: np.random.Generator,
        base_dir: str | Path,
        wall_s: Callable[[], float],
    ) -> None:
        self.cfg = cfg
        self.axis = axis
        self.machine = machine
        self.clock = clock
        self.rng = rng
        self.wall_s = wall_s
        self.dir = Path(base_dir) / cfg.dir
        self.recording = False
        self.full = False  # max_samples reached: later samples were not kept
        self.last_number = 0  # NNN of the last rec-NNN file saved (0: none yet)
        self.started_at: datetime | None = None
        self._chunks: list[np.ndarray] = []  # samples in µm, grid index 0, 1, 2, ...
        self._count = 0
        self._k = 0  # next grid index (sample k at recording time k / rate_hz)
        self._t0_s = 0.0  # machine time at the start
        self._idle_s = 0.0  # recording seconds added for idle wall time
        self._last_t_s = 0.0  # machine time sampled up to
        self._last_wall_s = 0.0
        self._stops_seen = 0
        self._stop_r_s = -math.inf  # recording time of the latest stop (ringing)
        self._stop_dir = 0
        clock.listeners.append(self._on_advance)

    # ------------------------------------------------------------ control
    def set_axis(self, axis: str) -> None:
        """Record ``axis`` from the next start on (the laser set up on another axis)."""
        if self.recording:
            raise RecorderError("recording: stop it before moving the laser")
        self.axis = axis

    def start(self) -> None:
        """Start a new recording at the current machine time (the old samples go)."""
        if self.recording:
            raise RecorderError("already recording")
        now_s = self.clock.now_s()
        self.machine.update(now_s)
        ax = self.machine.axes[self.axis]
        self._chunks, self._count, self._k, self.full = [], 0, 0, False
        self._t0_s, self._idle_s, self._last_t_s = now_s, 0.0, now_s
        self._stops_seen = ax.stops
        if ax.stops and ax.move_dir and not ax.moving:  # still ringing from before the start
            self._stop_r_s, self._stop_dir = ax.end_s - now_s, ax.move_dir
        else:
            self._stop_r_s, self._stop_dir = -math.inf, 0
        self.started_at = datetime.now()
        self.recording = True
        self._sample_machine(now_s)  # sample 0: where the axis is at the start
        self._last_wall_s = self.wall_s()

    def finish(self) -> None:
        """End the capture (idle time up to now included); the samples stay for :meth:`write`."""
        if not self.recording:
            raise RecorderError("not recording")
        if self.clock.time_scale == 0:
            self._add_idle()
        else:
            self._sample_machine(self.clock.now_s())
        self.recording = False

    def stop(self, path: str | Path | None = None) -> Path:
        """End the capture and write it to ``path`` (default: the next ``DIR/rec-NNN``; a
        ``.rtx`` or ``.csv`` path chooses its format, any other the config's)."""
        self.finish()
        return self.write(path)

    def catch_up(self) -> None:
        """At time_scale > 0: sample up to now (before anything changes the machine)."""
        if self.recording and self.clock.time_scale > 0:
            self._sample_machine(self.clock.now_s())

    def values_um(self) -> np.ndarray:
        """Every sample kept so far (µm, the drop stretch included)."""
        return np.concatenate(self._chunks) if self._chunks else np.zeros(0)

    def kept(self) -> tuple[np.ndarray, np.ndarray]:
        """(recording time s, value µm) of the samples a file holds (drop stretch out)."""
        values = self.values_um()
        times_s = np.arange(values.size) / self.cfg.rate_hz
        if self.cfg.drop_s is not None:
            lo_s, hi_s = self.cfg.drop_s
            keep = (times_s < lo_s) | (times_s >= hi_s)
            return times_s[keep], values[keep]
        return times_s, values

    def next_path(self) -> Path:
        """``DIR/rec-NNN.rtx|csv``: one past the highest number saved or found in DIR."""
        highest = self.last_number
        if self.dir.is_dir():
            for entry in self.dir.iterdir():
                match = _FILE_RE.fullmatch(entry.name)
                if match:
                    highest = max(highest, int(match.group(1)))
        return self.dir / f"rec-{highest + 1:03d}.{self.cfg.format}"

    def write(self, path: str | Path | None = None) -> Path:
        """Write the captured samples (format: the path's suffix .rtx or .csv, else the
        config's); returns the path."""
        target = Path(path) if path is not None else self.next_path()
        fmt = target.suffix.lower().lstrip(".")
        fmt = fmt if fmt in ("rtx", "csv") else self.cfg.format
        times_s, values_um = self.kept()
        data = self._rtx(values_um) if fmt == "rtx" else self._csv(times_s, values_um)
        try:
            target.parent.mkdir(parents=True, exist_ok=True)
            tmp = target.with_name(f".{target.name}.{os.getpid()}.tmp")
            tmp.write_bytes(data)
            os.replace(tmp, target)
        except OSError as err:
            raise RecorderError(f"cannot write {target}: {err.strerror or err}") from None
        match = _FILE_RE.fullmatch(target.name)
        if match and target.parent.resolve() == self.dir.resolve():
            self.last_number = int(match.group(1))
        return target

    # ------------------------------------------------------------ formats
    def _scaled(self, values_um: np.ndarray) -> np.ndarray:
        return values_um / 1000.0 if self.cfg.unit == "mm" else values_um

    def _rtx(self, values_um: np.ndarray) -> bytes:
        """HEADER:: + Key: value lines + Data: + float64 LE samples + EOF:: (CRLF each)."""
        rate = self.cfg.rate_hz
        when = (self.started_at or datetime.now()).strftime("%d/%m/%Y %H:%M:%S")
        fields = [
            ("Owner", "CARTO-Dynamic"),
            ("Version no", "1.0 (compgw sim)"),
            ("File Type", "Dynamic"),
            ("Velocity", "0"),
            ("Sample rate", str(int(rate)) if float(rate).is_integer() else repr(rate)),
            ("Sample no", str(values_um.size)),
            ("Actual sample rate", repr(float(rate))),
            ("Trigger point", "0"),
            ("Trigger interval", "1"),
            ("Flags", "0 0 0"),
            ("Machine", "compgw sim"),
            ("Serial No", "SIM0001"),
            ("Date", when),
            ("By", "compgw sim"),
            ("Axis", self.axis),
            ("Location", "sim"),
        ]
        head = "HEADER::\r\n" + "".join(f"{k}: {v}\r\n" for k, v in fields) + "Data:\r\n"
        body = np.asarray(self._scaled(values_um), dtype="<f8").tobytes()
        return head.encode("ascii") + body + b"EOF::\r\n"

    def _csv(self, times_s: np.ndarray, values_um: np.ndarray) -> bytes:
        """Header row and one row per sample, in ``csv_columns`` order."""
        unit = self.cfg.unit
        names = {"time": "time_s", "value": f"position_{unit}"}
        places = 6 if unit == "mm" else 3
        cols = {
            "time": [f"{t:.6f}" for t in times_s + self.cfg.clock_offset_s],
            "value": [f"{v:.{places}f}" for v in self._scaled(values_um)],
        }
        first, second = self.cfg.csv_columns
        lines = [f"{names[first]},{names[second]}"]
        lines += [f"{a},{b}" for a, b in zip(cols[first], cols[second], strict=True)]
        return ("\n".join(lines) + "\n").encode("ascii")

    # ------------------------------------------------------------ timeline
    def _on_advance(self, t_old_s: float, t_new_s: float) -> None:
        """Clock listener: idle wall time first (time_scale 0), then the machine to t_new."""
        if not self.recording:
            return
        if self.clock.time_scale == 0:
            self._add_idle()
        self._sample_machine(t_new_s)
        self._last_wall_s = self.wall_s()

    def _rec_s(self, t_s: float) -> float:
        """Recording time of machine time ``t_s``."""
        return t_s - self._t0_s + self._idle_s

    def _grid(self, r_new_s: float) -> np.ndarray:
        """Grid indices from the next one up to recording time ``r_new_s``, of which those
        still within ``max_samples`` are returned (the grid moves on past the others)."""
        k_hi = math.floor(r_new_s * self.cfg.rate_hz + 1e-6)  # float dust in wall sums
        ks = np.arange(self._k, k_hi + 1, dtype=np.int64)
        self._k = max(self._k, k_hi + 1)
        room = max(0, self.cfg.max_samples - self._count)
        if ks.size > room:
            self.full = True
        return ks[:room]

    def _add_idle(self) -> None:
        """Wall time since the last event, as standstill at the current position."""
        wall_now_s = self.wall_s()
        idle_wall_s, self._last_wall_s = wall_now_s - self._last_wall_s, wall_now_s
        if idle_wall_s <= 0:
            return
        add_s = idle_wall_s / self.cfg.idle_time_scale
        ks = self._grid(self._rec_s(self._last_t_s) + add_s)
        self._idle_s += add_s
        if ks.size == 0:
            return
        pos_um = self.machine.table_mm(self.axis, self._last_t_s) * 1000.0
        r_s = ks / self.cfg.rate_hz
        moving = np.zeros(ks.size, dtype=bool)
        stops = (np.full(ks.size, self._stop_r_s), np.full(ks.size, self._stop_dir))
        self._keep(ks, np.full(ks.size, pos_um), moving, *stops, r_s)

    def _sample_machine(self, t_new_s: float) -> None:
        """Samples of the machine for machine times up to ``t_new_s`` (increasing)."""
        ks = self._grid(self._rec_s(t_new_s))
        self._last_t_s = max(self._last_t_s, t_new_s)
        if ks.size == 0:
            return
        r_s = ks / self.cfg.rate_hz
        ts_s = np.minimum(self._t0_s + r_s - self._idle_s, t_new_s)
        exact_until_s = max(ax.end_s + _settling_s(ax) for ax in self.machine.axes.values())
        n_exact = int(np.searchsorted(ts_s, exact_until_s, side="right"))
        pos_um = np.empty(ks.size)
        moving = np.zeros(ks.size, dtype=bool)
        stop_r = np.empty(ks.size)
        stop_dir = np.empty(ks.size)
        ax = self.machine.axes[self.axis]
        # the recorded axis's move under way: its middle from knots (smooth; no stop in it)
        lo = hi = 0
        if ax.moving:
            lo = int(np.searchsorted(ts_s[:n_exact], ax.start_s, side="right"))
            hi = int(np.searchsorted(ts_s[:n_exact], ax.end_s - MOVE_EDGE_S))
        i = 0
        while i < n_exact:
            if i == lo and hi - lo > 2:
                mid_s = ts_s[lo:hi]
                knots_s = np.append(np.arange(mid_s[0], mid_s[-1], MOVE_KNOT_S), mid_s[-1])
                knots_um = [self.machine.table_mm(self.axis, float(t)) * 1000.0
                            for t in knots_s]  # fmt: skip
                pos_um[lo:hi] = np.interp(mid_s, knots_s, knots_um)
                moving[lo:hi] = True
                stop_r[lo:hi], stop_dir[lo:hi] = self._stop_r_s, self._stop_dir
                i = hi
                continue
            pos_um[i] = self.machine.table_mm(self.axis, float(ts_s[i])) * 1000.0
            moving[i] = ax.moving
            if ax.stops != self._stops_seen:
                self._stops_seen = ax.stops
                if ax.move_dir != 0:
                    self._stop_r_s, self._stop_dir = self._rec_s(ax.end_s), ax.move_dir
            stop_r[i], stop_dir[i] = self._stop_r_s, self._stop_dir
            i += 1
        if n_exact < ks.size:  # long standstill: the slow drift from knots, linear between
            rest_s = ts_s[n_exact:]
            knots_s = np.append(np.arange(rest_s[0], rest_s[-1], COARSE_S), rest_s[-1])
            knots_um = [self.machine.table_mm(self.axis, float(t)) * 1000.0 for t in knots_s]
            pos_um[n_exact:] = np.interp(rest_s, knots_s, knots_um)
            stop_r[n_exact:], stop_dir[n_exact:] = self._stop_r_s, self._stop_dir
        self._keep(ks, pos_um, moving, stop_r, stop_dir, r_s)

    def _keep(
        self,
        ks: np.ndarray,
        pos_um: np.ndarray,
        moving: np.ndarray,
        stop_r_s: np.ndarray,
        stop_dir: np.ndarray,
        r_s: np.ndarray,
    ) -> None:
        """Add noise, vibration and ringing to the positions and keep them."""
        cfg = self.cfg
        n = ks.size
        values = pos_um.copy()
        if cfg.noise_um > 0:
            values += self.rng.normal(0.0, cfg.noise_um, n)
        omega = 2.0 * math.pi * cfg.vibration_hz
        if cfg.vibration_um > 0 and moving.any():
            m = int(moving.sum())
            vib = cfg.vibration_um * np.sin(omega * r_s[moving])
            values[moving] += vib + self.rng.normal(0.0, cfg.vibration_um / 2.0, m)
        if cfg.ringing_um > 0:
            dt_s = r_s - stop_r_s
            ring = (~moving) & (stop_dir != 0) & (dt_s >= 0)
            if ring.any():
                d = dt_s[ring]
                values[ring] += (stop_dir[ring] * cfg.ringing_um * np.exp(-d / cfg.ringing_s)
                                 * np.sin(omega * d))  # fmt: skip
        self._chunks.append(np.round(values, 3))
        self._count += n


def _settling_s(ax: AxisState) -> float:
    """How long after its last stop an axis may still move by its own settling (s)."""
    st = ax.errors.settling
    return STILL_S if st is None else min(EXACT_S, SETTLED_TAUS * st.time_constant_s)
