"""A step whose readings come from a file after the moves: a laser's recording or capture.

compgw runs the plan with a dwell at every measured stop while the laser's own software
records continuously (``--laser recording:DIR``) or captures on stationary
(``--laser capture:MAPPING.yaml:DIR``); then it says which file it waits for, in which
folder, and waits. The file is read, its stops matched with the plan's
(:mod:`gateway.instruments.recording`, :mod:`gateway.instruments.capture`), and only a file
that matches gives raw rows: a file that does not is refused with one line, nothing is
fitted, and the same command carries on once the file is fixed (the moves are not made
again: a marker beside the raw file says they were).
"""

from __future__ import annotations

import asyncio
import json
import sys
import time
from collections.abc import Awaitable, Callable, Mapping, Sequence
from pathlib import Path

import numpy as np

from ...formats import atomic_write_text
from ...instruments.base import InstrumentError
from ...instruments.capture import PlanStop, load_layout, read_export
from ...instruments.recording import datum_of, matched, plan_stops, read_recording, zeroed
from ...instruments.spec import InstrumentSpec
from ..plans.plans import Move, Plan
from ..plans.runner import ExtraFn, RunSummary, join_values_async, raw_runs
from .machine import MachineError

Say = Callable[[str], None]
MoveFn = Callable[[Mapping[str, float]], Awaitable[None]]
Ready = Callable[[], Awaitable[None]]

#: how often the folder is looked at while compgw waits for the file (s)
POLL_S = 0.2


def expected_files(spec: InstrumentSpec, name: str) -> list[Path]:
    """The files a step's readings may come in (the first that exists is read)."""
    assert spec.directory is not None
    suffixes = (".rtx", ".csv") if spec.kind == "recording" else (".csv",)
    return [spec.directory / f"{name}{s}" for s in suffixes]


async def stand(seconds: float) -> None:
    """Stand still at a stop for ``seconds`` (the laser software sees the axis still)."""
    await asyncio.sleep(seconds)


#: the column of compgw's clock (s: time.time, or the machine's where the gateway shows
#: one) at each stop after its dwell: when the laser read it, as compgw keeps the time of
#: a live reading (the drift log's)
STOP_TIME = "stop_time_s"


async def run_for_file(plan: Plan, raw_path: Path, spec: InstrumentSpec, move: MoveFn,
                       dwell_s: float, meta: Mapping[str, str], say: Say = print,
                       ready: Ready | None = None, datum_mm: float | None = None,
                       extra: ExtraFn | None = None, extra_names: tuple[str, ...] = (),
                       clock: Callable[[], float] = time.time) -> RunSummary:  # fmt: skip
    """Move through ``plan`` dwelling ``dwell_s`` at each measured stop, then wait for the
    step's file and join its readings into ``raw_path`` (see the module docstring).
    ``ready``: awaited before the first move (the technician says the laser records).
    ``datum_mm``: a recording's readings less it (one zero across recordings, see
    :func:`..instruments.recording.align`), a capture's too (the zero moved since the
    technician's, default none); the datum used is kept in the raw file's meta
    (``datum_mm``: a recording's first stop's, where none was given). ``extra``: read at each stop
    after the dwell (a Δa or temperature sensor, ``extra_names`` its columns), kept beside
    the marker until the file comes, then beside the laser's readings. ``clock`` (s) times
    each stop (the machine's, where it is not the computer's)."""
    if len(plan.axes) != 1:
        raise MachineError(f"--laser {spec.text}: a {spec.kind} reads one axis; this step "
                           f"moves {', '.join(plan.axes)} (give --xy-device for the plane)")
    plan, _ = raw_runs(plan)
    name = raw_path.stem
    files = expected_files(spec, name)
    moved = raw_path.with_suffix(".moved")
    sensors = raw_path.with_suffix(".sensors.json")  # the extra columns, read while moving
    measured = [m for m in plan.moves if m.measured]
    if raw_path.exists() and raw_path.stat().st_size > 0 and _complete(raw_path, measured):
        return RunSummary(raw_path, len(plan.moves), len(plan.moves), 0, True)
    if not moved.exists():
        stale = next((f for f in files if f.exists()), None)
        if stale is not None:  # (a folder shared with another commissioning: its refs-001)
            raise MachineError(f"{stale}: there before the moves it is to record (a file of "
                               "another run): move it away or give the laser another folder, "
                               "then run the same command again; nothing moved for it")
        what = "recording"
        if spec.kind == "capture":
            listed = write_targets(spec.directory / f"{name}.targets.csv", measured)
            what = (f"capture (on stationary, dwell under {dwell_s:g} s; its targets: "
                    f"{listed})")  # fmt: skip
        say(f"{name}: start the laser's {what} now: {len(measured)} stops of {dwell_s:g} s; "
            f"save it as {files[0]}" + (f" (or {files[1].name})" if len(files) > 1 else "")
            + ("; press Enter once it records" if ready is not None else ""))
        if ready is not None:
            await ready()
        sensed: list[dict[str, float]] = []
        for m in plan.moves:
            await move(dict(zip(plan.axes, m.target_mm)))
            if m.measured:
                await stand(dwell_s)
                read = dict(await extra(m)) if extra is not None else {}
                sensed.append({**read, STOP_TIME: clock()})
        atomic_write_text(sensors, json.dumps(sensed))
        atomic_write_text(moved, f"{name}: moves done; readings from {files[0]}\n")
    found = next((f for f in files if f.exists()), None)
    if found is None:
        say(f"{name}: moves done; waiting for {files[0].name} in {spec.directory} (Ctrl-C "
            "stops; the same command carries on from here)")
        while found is None:
            await asyncio.sleep(POLL_S)
            found = next((f for f in files if f.exists()), None)
        await asyncio.sleep(POLL_S)  # a file being written: its writer finishes first
    axis = plan.axes[0]
    try:
        if spec.kind == "recording":
            rec = read_recording(found, spec.unit)
            stops = plan_stops(rec, len(measured), dwell_s)
            targets = np.array([m.target_mm[0] for m in measured])
            readings = matched(rec, stops, targets, spec.sign, say=say)
            if datum_mm is None:
                datum_mm = datum_of(readings, targets)
            values = zeroed(readings, targets, datum_mm, found)
        else:
            assert spec.mapping is not None
            stops_plan = [PlanStop(m.target_mm[0], m.run, m.direction) for m in measured]
            values = read_export(found, load_layout(spec.mapping), stops_plan)
            values = values - (datum_mm or 0.0)  # the zero moved since (one across exports)
    except InstrumentError as exc:
        raise MachineError(f"{exc}; nothing fitted from it: fix or replace the file and run "
                           "the same command again") from None  # fmt: skip
    except OSError as exc:
        raise MachineError(f"{found}: {exc}") from None
    kept = {"datum_mm": f"{datum_mm:.6f}"} if datum_mm is not None else {}
    sensed = json.loads(sensors.read_text()) if sensors.exists() else []
    names = (*extra_names, STOP_TIME) if sensed and STOP_TIME in sensed[0] else extra_names
    return await join_values_async(plan, [{axis: float(v)} for v in values], found, raw_path,
                                   {**meta, "instrument": spec.kind, **kept}, sensed,
                                   names if sensed else ())  # fmt: skip


def write_targets(path: Path, measured: Sequence[Move]) -> Path:
    """The step's target list for the laser software (``stop, target_mm, run,
    direction``, one row per measured stop, in order): what the technician enters, or
    imports, so that the export's targets, runs and directions are the plan's."""
    rows = ["stop,target_mm,run,direction"]
    rows += [f"{k},{m.target_mm[0]:.4f},{m.run},{'+' if m.direction > 0 else '-'}"
             for k, m in enumerate(measured, start=1)]
    atomic_write_text(path, "\n".join(rows) + "\n")
    return path


def _complete(raw_path: Path, measured: list) -> bool:  # type: ignore[type-arg]
    from ..plans.rawdata import read_raw_csv

    try:
        return len(read_raw_csv(raw_path)) >= len(measured)
    except Exception:
        return False


async def enter_pressed() -> None:
    """Wait for a line on standard input (Enter at the terminal); at its end, go on."""
    await asyncio.to_thread(sys.stdin.readline)
