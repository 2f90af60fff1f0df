"""systemd integration: the notify protocol and the watchdog pinger.

Under systemd (``Type=notify``) ``NOTIFY_SOCKET`` names a datagram socket; the daemon
sends ``READY=1`` once the upstream listeners are bound and every bus has been connected
or found down, ``STATUS=…`` lines for ``systemctl status``, ``RELOADING=1`` … ``READY=1``
around a SIGHUP reload, ``STOPPING=1`` on SIGTERM, and ``WATCHDOG=1`` from a task on the
event loop every half ``WATCHDOG_USEC``: a loop that is blocked (a hung handler, a busy
loop) stops the pings and systemd restarts the service (``WatchdogSec=``,
``Restart=on-failure``). Without ``NOTIFY_SOCKET`` everything here is a no-op.
"""

from __future__ import annotations

import asyncio
import logging
import os
import time
from collections.abc import Mapping

import sdnotify

log = logging.getLogger(__name__)


def watchdog_interval_s(environ: Mapping[str, str] | None = None, pid: int | None = None
                        ) -> float | None:
    """Seconds between watchdog pings (half of ``WATCHDOG_USEC``), or None when systemd
    asked for no watchdog (unset, 0, or ``WATCHDOG_PID`` names another process)."""
    env = os.environ if environ is None else environ
    usec = env.get("WATCHDOG_USEC", "")
    if not usec.isdigit() or int(usec) == 0:
        return None
    owner = env.get("WATCHDOG_PID", "")
    if owner.isdigit() and int(owner) != (os.getpid() if pid is None else pid):
        return None
    return int(usec) / 2e6


class Notifier:
    """sd_notify messages over ``NOTIFY_SOCKET`` (a no-op when it is not set)."""

    def __init__(self, environ: Mapping[str, str] | None = None) -> None:
        env = os.environ if environ is None else environ
        self.enabled = bool(env.get("NOTIFY_SOCKET"))
        self._notifier = sdnotify.SystemdNotifier() if self.enabled else None
        self.watchdog_s = watchdog_interval_s(env)
        self.pings = 0

    def send(self, *fields: str) -> None:
        if self._notifier is not None:
            self._notifier.notify("\n".join(fields))

    def ready(self, status: str) -> None:
        self.send("READY=1", f"STATUS={status}")
        log.debug("sd_notify READY=1 (%s)", status)

    def status(self, status: str) -> None:
        self.send(f"STATUS={status}")

    def reloading(self) -> None:
        usec = time.clock_gettime_ns(time.CLOCK_MONOTONIC) // 1000
        self.send("RELOADING=1", f"MONOTONIC_USEC={usec}", "STATUS=reloading")

    def stopping(self) -> None:
        self.send("STOPPING=1", "STATUS=stopping: finishing transactions in flight")

    def watchdog(self) -> None:
        self.pings += 1
        self.send("WATCHDOG=1")

    async def watchdog_loop(self) -> None:
        """Ping every ``watchdog_s`` from the event loop, until cancelled."""
        if self.watchdog_s is None or not self.enabled:
            return
        log.info("systemd watchdog: pinging every %.2f s", self.watchdog_s)
        while True:
            self.watchdog()
            await asyncio.sleep(self.watchdog_s)

    def start_watchdog(self) -> asyncio.Task[None] | None:
        if self.watchdog_s is None or not self.enabled:
            return None
        return asyncio.create_task(self.watchdog_loop(), name="compgw-watchdog")


_SYSLOG_PRIORITY = {logging.CRITICAL: 2, logging.ERROR: 3, logging.WARNING: 4,
                    logging.INFO: 6, logging.DEBUG: 7}


class OneLineFormatter(logging.Formatter):
    """One line per event: a traceback is folded into the same line (`` | `` between
    lines), so journald and grep see one record. ``journal=True`` prefixes the syslog
    priority (``<4>``) that journald reads from stdout/stderr, and drops the level name
    and time (journald shows both)."""

    def __init__(self, journal: bool) -> None:
        fmt = "%(name)s: %(message)s" if journal else \
            "%(asctime)s %(levelname)s %(name)s: %(message)s"
        super().__init__(fmt)
        self.journal = journal

    def format(self, record: logging.LogRecord) -> str:
        text = super().format(record).replace("\n", " | ")
        if self.journal:
            prio = _SYSLOG_PRIORITY.get(record.levelno, 6 if record.levelno < 30 else 3)
            return f"<{prio}>{text}"
        return text


def configure_logging(level: str, environ: Mapping[str, str] | None = None) -> None:
    """Log to stderr, one line per event; journald format when started by systemd
    (``JOURNAL_STREAM`` set)."""
    env = os.environ if environ is None else environ
    handler = logging.StreamHandler()
    handler.setFormatter(OneLineFormatter(journal=bool(env.get("JOURNAL_STREAM"))))
    root = logging.getLogger()
    root.handlers[:] = [handler]
    root.setLevel(getattr(logging, level.upper()))
    # pymodbus logs per frame at INFO/DEBUG in places: keep it to warnings
    logging.getLogger("pymodbus").setLevel(max(root.level, logging.WARNING))
