"""Shared, generic test fixtures (no project logic here)."""

from __future__ import annotations

import os

# One BLAS thread per process: the suite runs a worker per core and one more, and OpenBLAS's second
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

__all__ = ["PtyPair", "pty_pair"]


@pytest.fixture
def pty_pair() -> Iterator[PtyPair]:
    """A bridged pty pair: open ``.a`` on one side (e.g. a server) and ``.b`` on the other."""
    pair = PtyPair()
    try:
        yield pair
    finally:
        pair.close()
