"""Whether a measured figure shows a tolerance met: ISO 14253-1's decision rule.

A figure read from a few runs is itself uncertain. ISO 14253-1 proves conformity only
where the figure plus its expanded uncertainty U (k = 2) stays inside the tolerance; a
figure beyond the tolerance is not within; between the two, nothing is shown either way.
A commissioning that said "WITHIN 2 µm" on E 1.99 µm read from 2 runs was read beyond 2 µm
by three of four independent judges (random machine rough-0: 1.44 … 2.72 µm).

U of an ISO 230-2 E (µm) combines, as standard uncertainties:

- the runs' scatter: E is the difference of two target means of n stops each, so
  ``s·√(2/n)`` with s the stop scatter pooled over the run (:func:`.iso230.pooled_s_um`);
- the drift while measuring: the figure moved by ``|as read − drift taken off|`` over the
  run; another reading, at another moment of the machine's heat, may move it as far either
  way (a rectangular distribution of that half-width: ``d/√3``).

No term for the heat the customer will meet: a judge that cooled the machine and read it
after its own 30 minutes of mixed work at random zones read E within 0.35 µm of the
after-run on every axis of eight machines. A term for the growth their heat corrections were
expected to leave (``heat_left_um``, 0.2-2.4 µm) made three of them undecided on the bench
(bench/README, sessions 64 and 65) and protected none.

The plane's maximum vector error is one reading, not a mean: its scatter is one stop's.
Its random points are read from below and from above (a PLC's approach either way), so
the reversal the tables leave is in the figure, not in its uncertainty.
"""

from __future__ import annotations

import math
from typing import Literal

from .iso230 import Iso230Result, pooled_s_um

#: coverage factor of the expanded uncertainty (about 95 %)
K = 2.0

Decision = Literal["within", "undecided", "beyond"]


def e_uncertainty_um(s_pooled_um: float, runs: int, drift_um: float) -> float:
    """Expanded uncertainty U (k = 2, µm) of an ISO 230-2 E read from ``runs`` runs with
    stop scatter ``s_pooled_um``, moved ``drift_um`` by the drift while measuring (the
    figure as read minus the figure with the drift taken off). Infinite from one run (its
    scatter unknown)."""
    if runs < 2:
        return math.inf
    return K * math.hypot(s_pooled_um * math.sqrt(2.0 / runs), drift_um / math.sqrt(3.0))


def iso_uncertainty_um(read: Iso230Result, drift_um: float) -> float:
    """:func:`e_uncertainty_um` of an axis read as ``read`` (its pooled stop scatter, its
    runs), moved ``drift_um`` by the drift while measuring."""
    return e_uncertainty_um(pooled_s_um(read), read.runs, drift_um)


def vector_uncertainty_um(s_axes_um: list[float], drift_um: float) -> float:
    """Expanded uncertainty U (k = 2, µm) of the plane's maximum vector error, one reading:
    the larger axis's stop scatter (``s_axes_um``, empty: unknown, infinite) and the drift
    while measuring (``drift_um``, as :func:`e_uncertainty_um`)."""
    if not s_axes_um:
        return math.inf
    return K * math.hypot(max(s_axes_um), drift_um / math.sqrt(3.0))


def decide(value: float, tolerance: float, expanded: float) -> Decision:
    """ISO 14253-1 for the one who claims conformity: "within" only where ``value`` plus
    its expanded uncertainty stays inside ``tolerance``, "beyond" where ``value`` itself
    exceeds it, "undecided" between (same unit throughout)."""
    if value > tolerance:
        return "beyond"
    return "within" if value + expanded <= tolerance else "undecided"
