"""The technician at the laser's own software or at a gauge, for compgw's file and manual kinds.

Why: with ``--laser recording:DIR`` or ``capture:MAPPING:DIR`` compgw moves while the
laser software records, then waits for the file; with ``--laser manual`` it asks for each
reading at the terminal. On site a person does that; this does the same to the sim's laser
(:mod:`sim.instruments`: the recorder controlled over Modbus, register 0x0100 1 = start,
2 = stop and save, 0x0101 the last file's number; the readings at registers 2k), reading
compgw's output as a person would:

* ``NAME: start the laser's recording now: …; press Enter once it records`` → start, Enter
  (:class:`Technician`);
* ``NAME: moves done; waiting for NAME.rtx in DIR`` → stop, copy ``rec-NNN.rtx|csv`` there;
  for a capture (``fmt`` "capture"), the recording captured on stationary and exported
  against compgw's ``NAME.targets.csv`` (:mod:`sim.capture`);
* ``X at 125.0000 mm: the gauge's deviation in um?`` → the laser's reading less the target,
  typed to 0.1 µm, then Enter to take it (:class:`Gauge`).

Only pymodbus and the files: the sim never imports compgw's gateway.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import tempfile
import time
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import IO

from pymodbus.client import ModbusTcpClient

from sim.capture import STILL_S, Datum, export
from sim.instruments import REC_AXIS, REC_CONTROL, REC_LAST, REC_START, REC_STOP

START = re.compile(r"start the laser's (recording|capture)")
WAITING = re.compile(r"waiting for (\S+?)\.(rtx|csv) in (\S+)")
ASKED = re.compile(r"(\w+) at (-?[\d.]+) mm: the gauge's (deviation|reading) in (\w+)\? $")
CONFIRM = re.compile(r"Enter to take it, r to read again: $")
#: a prompt waits for input without a newline: these ends of a partial line are heard
PROMPT_END = re.compile(r"[?:] $")

Hear = Callable[[str, IO[str] | None], None]


class _SimLaser:
    """The sim's laser over Modbus (one client, closed on exit)."""

    def __init__(self, host: str, port: int, unit: int) -> None:
        self.client = ModbusTcpClient(host, port=port)
        self.unit = unit

    def __enter__(self):  # type: ignore[no-untyped-def]
        if not self.client.connect():
            raise ConnectionError("the sim's laser does not answer")
        return self

    def __exit__(self, *exc: object) -> None:
        self.client.close()

    def attend(self, argv: list[str], cwd: Path, timeout_s: float,
               env: Mapping[str, str] | None = None) -> subprocess.CompletedProcess[str]:
        """:func:`attend` with this one's :meth:`hear`."""
        return attend(argv, cwd, timeout_s, self.hear, env)

    def hear(self, line: str, stdin: IO[str] | None) -> None:
        raise NotImplementedError


class Technician(_SimLaser):
    """Starts and stops the sim's recording when compgw says so, and saves each file under
    the name compgw waits for. ``recordings``: where the sim writes ``rec-NNN`` files;
    ``fmt``: "rtx" or "csv" (the recording as it is), or "capture" (the recording, in
    ``source`` format, captured on stationary for ``still_s`` and exported, one zero for
    every export)."""

    def __init__(self, host: str, port: int, unit: int, recordings: Path, fmt: str,
                 source: str = "csv", still_s: float = STILL_S) -> None:  # fmt: skip
        super().__init__(host, port, unit)
        self.recordings = recordings
        self.fmt = fmt
        self.source = source
        self.still_s = still_s
        self.saved: list[Path] = []
        self.datum = Datum()

    def _write(self, value: int, address: int = REC_CONTROL) -> None:
        answer = self.client.write_register(address, value, device_id=self.unit)
        if answer.isError():
            raise RuntimeError(f"the sim's recorder refused {value} at {address:#x}: {answer}")

    def set_up_on(self, channel: int) -> None:
        """The laser moved to the axis of ``channel`` (the sim laser's order) and zeroed
        there anew, between two commissionings."""
        self._write(channel, REC_AXIS)
        self.datum = Datum()

    def hear(self, line: str, stdin: IO[str] | None) -> None:
        """Act on one line compgw printed (``stdin``: its input, where Enter goes)."""
        if START.search(line):
            try:
                self._write(REC_START)
            except RuntimeError:  # still recording for a run that aborted: anew, as one would
                self._write(REC_STOP)
                self._write(REC_START)
            if stdin is not None:
                stdin.write("\n")
                stdin.flush()
            return
        found = WAITING.search(line)
        if found is None:
            return
        self._write(REC_STOP)
        number = self.client.read_holding_registers(REC_LAST, count=1,
                                                    device_id=self.unit).registers[0]  # fmt: skip
        suffix = self.source if self.fmt == "capture" else self.fmt
        made = self.recordings / f"rec-{number:03d}.{suffix}"
        folder, name = Path(found.group(3)), found.group(1)
        target = folder / f"{name}.{'csv' if self.fmt == 'capture' else self.fmt}"
        if self.fmt == "capture":
            export(target, made, folder / f"{name}.targets.csv", self.datum, self.still_s)
        else:
            shutil.copyfile(made, target.with_suffix(".part"))
            target.with_suffix(".part").replace(target)  # whole, or not there
        self.saved.append(target)


class Gauge(_SimLaser):
    """Reads the sim's laser as a gauge read by eye when compgw asks (``manual:deviation``
    in µm, or ``manual:mm`` positions), to ``digits`` decimals; ``channels``: the sim
    laser's axes in register order. ``asked`` counts the readings typed."""

    def __init__(self, host: str, port: int, unit: int, channels: list[str],
                 digits: int = 1) -> None:  # fmt: skip
        super().__init__(host, port, unit)
        self.channels = channels
        self.digits = digits
        self.asked = 0

    def _position_mm(self, axis: str) -> float:
        """The laser's reading of ``axis`` once it says stable (as one waits to read)."""
        k, n = self.channels.index(axis), len(self.channels)
        for _ in range(200):
            regs = self.client.read_holding_registers(0, count=2 * n + n,
                                                      device_id=self.unit).registers  # fmt: skip
            if regs[2 * n + k]:
                break
        raw = (regs[2 * k] << 16) | regs[2 * k + 1]
        return (raw - (1 << 32) if raw & 0x80000000 else raw) / 1e6

    def hear(self, line: str, stdin: IO[str] | None) -> None:
        assert stdin is not None
        asked = ASKED.search(line)
        if asked is not None:
            axis, target_mm, what, unit = asked.groups()
            value_mm = self._position_mm(axis) - (float(target_mm) if what == "deviation"
                                                  else 0.0)  # fmt: skip
            scale = {"mm": 1.0, "um": 1000.0}[unit]
            digits = self.digits + (3 if unit == "mm" else 0)
            stdin.write(f"{value_mm * scale:.{digits}f}\n")
            stdin.flush()
            self.asked += 1
        elif CONFIRM.search(line):
            stdin.write("\n")
            stdin.flush()


def attend(argv: list[str], cwd: Path, timeout_s: float, hear: Hear,
           env: Mapping[str, str] | None = None) -> subprocess.CompletedProcess[str]:
    """Run ``argv`` (in ``env``, default this process's, unbuffered) and ``hear`` its
    stdout line by line, and each prompt left waiting without a newline, answering on its
    stdin (stderr kept apart); killed past ``timeout_s`` (TimeoutExpired)."""
    deadline = time.monotonic() + timeout_s
    with tempfile.TemporaryFile("w+") as err:
        proc = subprocess.Popen(argv, cwd=cwd, text=True, stdin=subprocess.PIPE,
                                stdout=subprocess.PIPE, stderr=err,
                                env={**(env or os.environ), "PYTHONUNBUFFERED": "1"})
        assert proc.stdout is not None
        out: list[str] = []
        pending = ""
        try:
            while True:
                chunk = os.read(proc.stdout.fileno(), 65536)
                if not chunk:
                    break
                pending += chunk.decode("utf-8", "replace")
                *lines, pending = pending.split("\n")
                for line in lines:
                    out.append(line + "\n")
                    hear(line, proc.stdin)
                if PROMPT_END.search(pending):
                    out.append(pending)
                    hear(pending, proc.stdin)
                    pending = ""
                if time.monotonic() > deadline:
                    raise subprocess.TimeoutExpired(argv, timeout_s)
            code = proc.wait(timeout=max(1.0, deadline - time.monotonic()))
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait()
        err.seek(0)
        return subprocess.CompletedProcess(argv, code, "".join(out) + pending, err.read())
