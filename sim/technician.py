"""The technician at the laser's own software, for compgw's recording kind (tests, bench).

Why: with ``--laser recording:DIR`` compgw moves while the laser software records, then
waits for the file; on site a person starts the recording, presses Enter, stops it after
the moves and saves it under the name compgw asks for. This does the same to the sim's
laser (:mod:`sim.recorder`, controlled over Modbus: register 0x0100 1 = start, 2 = stop
and save; 0x0101 the last file's number), reading compgw's lines as a person would:

* ``NAME: start the laser's recording now: …; press Enter once it records`` → start, Enter;
* ``NAME: moves done; waiting for NAME.rtx in DIR`` → stop, copy ``rec-NNN.rtx|csv`` there.

Only pymodbus and the files: the sim never imports compgw's gateway.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import tempfile
import time
from collections.abc import Mapping
from pathlib import Path
from typing import IO

from pymodbus.client import ModbusTcpClient

from sim.instruments import REC_CONTROL, REC_LAST, REC_START, REC_STOP

START = re.compile(r"start the laser's recording now")
WAITING = re.compile(r"waiting for (\S+?)\.(rtx|csv) in (\S+)")


class Technician:
    """Starts and stops the sim's recording when compgw says so, and saves each file under
    the name compgw waits for. ``recordings``: where the sim writes ``rec-NNN`` files."""

    def __init__(self, host: str, port: int, unit: int, recordings: Path, fmt: str) -> None:
        self.client = ModbusTcpClient(host, port=port)
        self.unit = unit
        self.recordings = recordings
        self.fmt = fmt
        self.saved: list[Path] = []

    def __enter__(self) -> Technician:
        if not self.client.connect():
            raise ConnectionError("the sim's laser does not answer")
        return self

    def __exit__(self, *exc: object) -> None:
        self.client.close()

    def _write(self, value: int) -> None:
        answer = self.client.write_register(REC_CONTROL, value, device_id=self.unit)
        if answer.isError():
            raise RuntimeError(f"the sim's recorder refused {value}: {answer}")

    def hear(self, line: str, stdin: IO[str] | None) -> None:
        """Act on one line compgw printed (``stdin``: its input, where Enter goes)."""
        if START.search(line):
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
        made = self.recordings / f"rec-{number:03d}.{self.fmt}"
        target = Path(found.group(3)) / f"{found.group(1)}.{self.fmt}"
        shutil.copyfile(made, target.with_suffix(".part"))
        target.with_suffix(".part").replace(target)  # whole, or not there
        self.saved.append(target)

    def attend(self, argv: list[str], cwd: Path, timeout_s: float,
               env: Mapping[str, str] | None = None) -> subprocess.CompletedProcess[str]:
        """Run ``argv`` (in ``env``, default this process's, unbuffered) and hear its
        stdout line by line, answering on its stdin (stderr kept apart); killed past
        ``timeout_s`` (TimeoutExpired)."""
        deadline = time.monotonic() + timeout_s
        with tempfile.TemporaryFile("w+") as err:
            proc = subprocess.Popen(argv, cwd=cwd, text=True, stdin=subprocess.PIPE,
                                    stdout=subprocess.PIPE, stderr=err,
                                    env={**(env or os.environ), "PYTHONUNBUFFERED": "1"})
            lines = []
            try:
                assert proc.stdout is not None
                for line in proc.stdout:
                    lines.append(line)
                    self.hear(line, proc.stdin)
                    if time.monotonic() > deadline:
                        raise subprocess.TimeoutExpired(argv, timeout_s)
                code = proc.wait(timeout=max(1.0, deadline - time.monotonic()))
            finally:
                if proc.poll() is None:
                    proc.kill()
                    proc.wait()
            err.seek(0)
            return subprocess.CompletedProcess(argv, code, "".join(lines), err.read())
