"""Shared, generic test fixtures (no project logic here)."""

from __future__ import annotations

import os

# One BLAS thread per process: the suite runs a worker per core, and OpenBLAS's second
# thread spins on a core another worker is using (a sweep fit: 19 s of CPU for 11 s of
# wall with two threads, 13 s with one). Set before numpy loads here and in every process
# a test starts (they inherit the environment).
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

from collections.abc import Iterator

import pytest
from hypothesis import settings

from sim.nullmodem import PtyPair

# Property tests are deterministic like the rest: the same examples on every run and
# machine (no random seed, no example database carried between runs).
settings.register_profile("compgw", derandomize=True, database=None)
settings.load_profile("compgw")


def _pin_worker_to_a_core() -> None:
    """Each pytest-xdist worker, and every process its tests start (they inherit it), on a
    core of its own. A test's sim, gateway and client answer each other over loopback
    thousands of times; on this VM each wake-up across cores costs an exit to the host
    (a commissioning test: 88 s of wall and 44 s of kernel time spread over the cores,
    36 s and 3.4 s on one core)."""
    worker = os.environ.get("PYTEST_XDIST_WORKER", "")
    if not worker.startswith("gw") or not hasattr(os, "sched_setaffinity"):
        return
    cores = sorted(os.sched_getaffinity(0))
    if len(cores) > 1:
        os.sched_setaffinity(0, {cores[int(worker[2:]) % len(cores)]})


_pin_worker_to_a_core()

__all__ = ["PtyPair", "pty_pair"]


@pytest.fixture
def pty_pair() -> Iterator[PtyPair]:
    """A bridged pty pair: open ``.a`` on one side (e.g. a server) and ``.b`` on the other."""
    pair = PtyPair()
    try:
        yield pair
    finally:
        pair.close()
