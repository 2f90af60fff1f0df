"""The benchmarks stay runnable from a fresh clone: each script starts as `make bench` and
the README run it (``python bench/NAME.py``, so ``bench/`` is first on ``sys.path`` and a
file there named like a package would shadow it) and prints its help."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

BENCH = Path(__file__).resolve().parent.parent / "bench"
SCRIPTS = sorted(p.name for p in BENCH.glob("*.py"))
PACKAGES = {"gateway", "sim", "tests"}


def test_no_bench_script_shadows_a_package() -> None:
    assert SCRIPTS, "no benchmark scripts found"
    shadowing = [name for name in SCRIPTS if name.removesuffix(".py") in PACKAGES]
    assert shadowing == [], f"bench/{shadowing[0]} would shadow the package of that name"


@pytest.mark.parametrize("script", SCRIPTS)
def test_bench_script_help(script: str) -> None:
    out = subprocess.run([sys.executable, str(BENCH / script), "--help"], cwd=BENCH.parent,
                         capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, f"bench/{script} --help: {out.stderr.strip()[-400:]}"
    assert "usage:" in out.stdout
