"""One way to run a coroutine to completion: on uvloop where it is installed (a pinned
dependency on Linux), else on asyncio's own loop. The daemon forwards every request and a
commissioning sends tens of thousands; uvloop spends about half the standard loop's CPU on
each. (sim/server.py has its own three lines: sim/ never imports gateway/.)"""

from __future__ import annotations

import asyncio
from collections.abc import Coroutine
from typing import Any, TypeVar

T = TypeVar("T")


def run_loop(main: Coroutine[Any, Any, T]) -> T:
    """``asyncio.run(main)``, on uvloop where it is installed."""
    try:
        import uvloop
    except ImportError:  # pragma: no cover - a pinned dependency on Linux
        return asyncio.run(main)
    return uvloop.run(main)


def new_loop() -> asyncio.AbstractEventLoop:
    """A new event loop for a thread of its own to run: uvloop's where it is installed."""
    try:
        import uvloop
    except ImportError:  # pragma: no cover - a pinned dependency on Linux
        return asyncio.new_event_loop()
    return uvloop.new_event_loop()
