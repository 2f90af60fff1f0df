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
from collections.abc import Callable, Mapping

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
        self._describe: Callable[[], str] | None = None
        self._described: str | None = None

    def send(self, *fields: str) -> None:
        if self._notifier is not None:
            self._notifier.notify("\n".join(fields))

    def ready(self, status: str) -> None:
        self.send("READY=1", f"STATUS={status}")
        log.debug("sd_notify READY=1 (%s)", status)

    def status(self, status: str) -> None:
        self.send(f"STATUS={status}")

    def follow(self, describe: Callable[[], str]) -> None:
        """Send ``describe()`` (the listeners' and buses' state) as STATUS= with a watchdog
        ping whenever it changed since the last, so `systemctl status` follows a bus going
        down and up; a STATUS= said otherwise (a refused reload) stays until it changes."""
        self._describe, self._described = describe, describe()

    def reloading(self) -> None:
        usec = time.clock_gettime_ns(time.CLOCK_MONOTONIC) // 1000
        self.send("RELOADING=1", f"MONOTONIC_USEC={usec}", "STATUS=reloading")

    def stopping(self) -> None:
        self.send("STOPPING=1", "STATUS=stopping: finishing transactions in flight")

    def watchdog(self) -> None:
        self.pings += 1
        fields = ["WATCHDOG=1"]
        now = self._describe() if self._describe is not None else None
        if now is not None and now != self._described:
            self._described = now
            fields.append(f"STATUS={now}")
        self.send(*fields)

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


#: ``log.error(..., extra=EVERY)``: a record :class:`RepeatFilter` never holds back
EVERY = {"every": True}


class RepeatFilter(logging.Filter):
    """At most ``burst`` records of one kind (logger, level, message template) per
    ``window_s``; the next one let through says how many were held back.

    A master that reconnects or retries a refused write 100 times a second must not fill
    the journal: the first few lines say what happened, then one line a window. A record
    logged with ``extra=EVERY`` is never held back: an operator's own action (a refused
    reload) gets its line each time, with its reason.
    """

    def __init__(self, burst: int = 5, window_s: float = 60.0,
                 clock: Callable[[], float] = time.monotonic) -> None:
        super().__init__()
        self.burst, self.window_s, self.clock = burst, window_s, clock
        self._kinds: dict[tuple[str, int, str], list[float | int]] = {}  # start, seen, held

    def filter(self, record: logging.LogRecord) -> bool:
        if record.levelno < logging.WARNING or getattr(record, "every", False):
            return True
        now = self.clock()
        key = (record.name, record.levelno, str(record.msg))
        kind = self._kinds.get(key)
        if kind is None or now - kind[0] >= self.window_s:
            held = 0 if kind is None else int(kind[2])
            self._kinds[key] = [now, 1, 0]
            if held:
                record.msg = f"{record.msg} ({held} more like this held back)"
            return True
        kind[1] = int(kind[1]) + 1
        if kind[1] <= self.burst:
            return True
        kind[2] = int(kind[2]) + 1
        return False


def configure_logging(level: str, environ: Mapping[str, str] | None = None) -> None:
    """Log to stderr, one line per event; journald format when started by systemd
    (``JOURNAL_STREAM`` set)."""
    env = os.environ if environ is None else environ
    handler = logging.StreamHandler()
    handler.setFormatter(OneLineFormatter(journal=bool(env.get("JOURNAL_STREAM"))))
    handler.addFilter(RepeatFilter())
    root = logging.getLogger()
    root.handlers[:] = [handler]
    root.setLevel(getattr(logging, level.upper()))
    # pymodbus logs per frame at INFO/DEBUG in places: keep it to warnings
    logging.getLogger("pymodbus").setLevel(max(root.level, logging.WARNING))
