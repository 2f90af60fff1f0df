"""Shared, generic test fixtures (no project logic here)."""

from __future__ import annotations

from collections.abc import Iterator

import pytest

from sim.nullmodem import PtyPair

__all__ = ["PtyPair", "pty_pair"]


@pytest.fixture
def pty_pair() -> Iterator[PtyPair]:
    """A bridged pty pair: open ``.a`` on one side (e.g. a server) and ``.b`` on the other."""
    pair = PtyPair()
    try:
        yield pair
    finally:
        pair.close()
