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
  way (a rectangular distribution of that half-width: ``d/√3``);
- the heat the customer will meet: the after-run is read on a machine warmed by hours of
  commissioning; the customer's laser reads it cold, or warming through other work. Its
  heat correction is expected to leave ``h`` of the growth (``heat_left_um``: all of it
  on an axis with none), which may be in the figure either way (``h/√3``). Random machine
  rough-0: the plane read 0.59 µm at the after-run, 2.3-2.8 µm by four judges that cooled
  it and read it after 30 minutes of their own work.

The plane's maximum vector error is one reading, not a mean: its scatter is one stop's;
its heat the two axes' together.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Literal

from .iso230 import Iso230Result, pooled_s_um

#: coverage factor of the expanded uncertainty (about 95 %)
K = 2.0

Decision = Literal["within", "undecided", "beyond"]


def e_uncertainty_um(s_pooled_um: float, runs: int, drift_um: float,
                     heat_um: float = 0.0) -> float:  # fmt: skip
    """Expanded uncertainty U (k = 2, µm) of an ISO 230-2 E read from ``runs`` runs with
    stop scatter ``s_pooled_um``, moved ``drift_um`` by the drift while measuring (the
    figure as read minus the figure with the drift taken off), on a machine whose heat
    correction is expected to leave ``heat_um`` of its growth. Infinite from one run (its
    scatter unknown)."""
    if runs < 2:
        return math.inf
    return K * math.hypot(s_pooled_um * math.sqrt(2.0 / runs), drift_um / math.sqrt(3.0),
                          heat_um / math.sqrt(3.0))  # fmt: skip


def iso_uncertainty_um(read: Iso230Result, drift_um: float, heat_um: float = 0.0) -> float:
    """:func:`e_uncertainty_um` of an axis read as ``read`` (its pooled stop scatter, its
    runs), moved ``drift_um`` by the drift while measuring, ``heat_um`` of heat left."""
    return e_uncertainty_um(pooled_s_um(read), read.runs, drift_um, heat_um)


def vector_uncertainty_um(s_axes_um: Sequence[float], drift_um: float,
                          heat_axes_um: Sequence[float] = ()) -> float:
    """Expanded uncertainty U (k = 2, µm) of the plane's maximum vector error, one reading:
    the larger axis's stop scatter (``s_axes_um``, empty: unknown, infinite), the drift
    while measuring (``drift_um``, as :func:`e_uncertainty_um`) and the heat left on each
    axis (``heat_axes_um``: together, a vector)."""
    if not s_axes_um:
        return math.inf
    return K * math.hypot(max(s_axes_um), drift_um / math.sqrt(3.0),
                          math.hypot(*heat_axes_um) / math.sqrt(3.0))  # fmt: skip


def decide(value: float, tolerance: float, expanded: float) -> Decision:
    """ISO 14253-1 for the one who claims conformity: "within" only where ``value`` plus
    its expanded uncertainty stays inside ``tolerance``, "beyond" where ``value`` itself
    exceeds it, "undecided" between (same unit throughout)."""
    if value > tolerance:
        return "beyond"
    return "within" if value + expanded <= tolerance else "undecided"
