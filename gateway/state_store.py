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
    """``load()`` the saved axes, ``changed()`` after a commit, ``flush()`` at stop."""

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
            self._pending = asyncio.get_running_loop().call_later(self.delay_s, self.flush)

    def flush(self) -> None:
        """Write now (a failure is logged; the gateway keeps serving)."""
        if self._pending is not None:
            self._pending.cancel()
            self._pending = None
        try:
            data: dict[str, Any] = {"format": FORMAT, "axes": self.snapshot()}
            if self.heat is not None:
                data["heat"] = self.heat()
            atomic_write_text(self.path, json.dumps(data, indent=1) + "\n")
            self.writes += 1
        except OSError as exc:
            log.warning("state file %s not written: %s", self.path, exc)
