"""Per-axis gateway state kept in a small JSON file across restarts (``state_file``).

The gateway remembers, per axis, the nominal target the master wrote, the corrected
command the drive got, the direction of approach and whether compensation was applied.
Lost in a restart, the next feedback reads would report the drive's raw position (off by
the correction) and the first move's backlash side would be a guess. The file is written
atomically, at most every ``delay_s`` after a change (commits come in bursts), and at
stop. A restarted gateway takes an axis's entry back only when the drive still holds that
command in its target register (:meth:`GatewayApp.restore_state`). The heat of screws
with ``thermal.motion`` is kept beside the axes (``heat``), with the time it was saved.
"""

from __future__ import annotations

import asyncio
import json
import logging
from collections.abc import Callable
from pathlib import Path
from typing import Any

from .formats import atomic_write_text

log = logging.getLogger(__name__)

FORMAT = 1


class StateStore:
    """``load()`` the saved axes, ``changed()`` after a commit, ``close()`` at stop."""

    def __init__(self, path: str | Path, snapshot: Callable[[], dict[str, Any]],
                 delay_s: float = 0.05, heat: Callable[[], dict[str, Any]] | None = None
                 ) -> None:  # fmt: skip
        self.path = Path(path)
        self.snapshot = snapshot
        #: heat from motion per axis (the screws' warmth is not the drives' to keep)
        self.heat = heat
        self.saved_heat: dict[str, Any] = {}
        self.delay_s = delay_s
        self._pending: asyncio.TimerHandle | None = None
        self._writing: asyncio.Future[None] | None = None
        self.writes = 0

    def load(self) -> dict[str, dict[str, Any]]:
        """Saved axes by name; {} when there is no file or it cannot be used (logged)."""
        try:
            data = json.loads(self.path.read_text())
        except FileNotFoundError:
            return {}
        except (OSError, ValueError) as exc:
            log.warning("state file %s unreadable, starting afresh: %s", self.path, exc)
            return {}
        axes = data.get("axes") if isinstance(data, dict) else None
        if not isinstance(axes, dict) or data.get("format") != FORMAT:
            log.warning("state file %s is not a compgw state file, starting afresh", self.path)
            return {}
        heat = data.get("heat")
        self.saved_heat = heat if isinstance(heat, dict) else {}
        return axes

    def changed(self) -> None:
        """Write soon (coalesced): called on the event loop after a state change."""
        if self._pending is None:
            self._pending = asyncio.get_running_loop().call_later(self.delay_s, self._write_soon)

    def _write_soon(self) -> None:
        """The state as it is now, written in a worker thread: a write ends with an fsync,
        which the loop would otherwise wait for between two requests (0.65 ms on this VM's
        disk, tens of ms on an SD card). One write at a time: a change while one is under
        way is written once it is done."""
        self._pending = None
        loop = asyncio.get_running_loop()
        if self._writing is not None:
            self._pending = loop.call_later(self.delay_s, self._write_soon)
            return
        self._writing = loop.run_in_executor(None, self._write, self._text())
        self._writing.add_done_callback(self._written)

    def _written(self, _: asyncio.Future[None]) -> None:
        self._writing = None

    async def close(self) -> None:
        """Write the final state now (at stop), after any write under way."""
        if self._pending is not None:
            self._pending.cancel()
            self._pending = None
        if self._writing is not None:
            await self._writing
        self._write(self._text())

    def _text(self) -> str:
        data: dict[str, Any] = {"format": FORMAT, "axes": self.snapshot()}
        if self.heat is not None:
            data["heat"] = self.heat()
        return json.dumps(data, indent=1) + "\n"

    def _write(self, text: str) -> None:
        """Write ``text`` atomically (a failure is logged; the gateway keeps serving)."""
        try:
            atomic_write_text(self.path, text)
            self.writes += 1
        except OSError as exc:
            log.warning("state file %s not written: %s", self.path, exc)
