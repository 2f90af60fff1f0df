"""Shared, generic test fixtures (no project logic here)."""

from __future__ import annotations

import os
import sys

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


@pytest.hookimpl(wrapper=True)
def pytest_collection(session: pytest.Session) -> object:
    """Collected with bytecode written: each worker imports every test module, and pytest
    rewrites a module's asserts as it imports it (7 s of CPU a worker for the suite's), its
    rewritten copy kept in tests/__pycache__ only where bytecode is written. Where the
    environment says not to (PYTHONDONTWRITEBYTECODE: the Makefile compiles the project's
    modules for it), every worker rewrote them all on every run: 11 s a worker to collect,
    4 s from the copies. Only while collecting: the processes the tests start are the
    environment's."""
    was = sys.dont_write_bytecode
    sys.dont_write_bytecode = False
    try:
        return (yield)
    finally:
        sys.dont_write_bytecode = was


@pytest.fixture
def pty_pair() -> Iterator[PtyPair]:
    """A bridged pty pair: open ``.a`` on one side (e.g. a server) and ``.b`` on the other."""
    pair = PtyPair()
    try:
        yield pair
    finally:
        pair.close()


#: the suite's longest files (seconds of wall on 2 cores, 3 workers, as a whole suite's run
#: measured them in session 81): run first, so that pytest-xdist's first round hands them
#: out one a worker and the short files fill in around them (the Makefile keeps this order:
#: `--no-loadscope-reorder`; xdist's own order, files with the most tests first, ran
#: test_commission_recorded.py's 68 s, mostly waiting on the laser software's recordings,
#: last and alone: 328 s, the other workers done at 235 s)
LONG_FILES_S = {
    "test_commission.py": 155, "test_commission_budget.py": 130,
    "test_commission_recorded.py": 82, "test_commission_run_heat.py": 80,
    "test_commission_short.py": 56, "test_calibration_e2e.py": 55, "test_demo.py": 51,
    "test_sweep.py": 51, "test_commission_instruments.py": 42,
    "test_commission_rotary.py": 36, "test_commission_verdict.py": 35, "test_fuzz.py": 35,
    "test_commission_thermal_short.py": 29, "test_faults.py": 20, "test_thermal_shape.py": 19,
    "test_takeup.py": 18, "test_service.py": 17, "test_bench_smoke.py": 16,
    "test_cyclic_sim.py": 14, "test_cyclic_cal_e2e.py": 12,
}  # fmt: skip


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """The longest files first (:data:`LONG_FILES_S`), each file's tests kept together and
    in their order."""
    items.sort(key=lambda item: -LONG_FILES_S.get(item.path.name, 0))
