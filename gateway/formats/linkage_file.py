"""The linkage file of a swing axis (seed 003): rocking-block geometry and the control's
scale (YAML), read by the gateway's linkage stage and rewritten by ``compgw fit``.

::

    arm_mm: 150          # head pivot A to the nut's joint M
    base_mm: 450         # head pivot A to the rocking block's pivot N
    offset_mm: 10        # the screw axis beside N (0: through it)
    phi0_deg: 74.4       # angle MAN with the head at 0
    mm_per_deg: 2.5914   # screw travel per degree the control commands (its linear scale)
    zero_deg: 0          # the head's angle at command 0

Start from the drawing's values; ``compgw fit`` refines ``base_mm``, ``phi0_deg``,
``mm_per_deg`` and ``zero_deg`` by least squares from an identification run and keeps the
lengths it does not fit. Other top-level keys (how it was fitted) are ignored.
"""

from __future__ import annotations

import os
from typing import Any

import yaml

from ..compensation.errors import TableError
from ..compensation.linkage import PARAMETERS, LinkageModel
from ..config_types import read_yaml
from .atomic import atomic_write_text

_REQUIRED = ("arm_mm", "base_mm", "phi0_deg", "mm_per_deg")


def read_linkage(path: str | os.PathLike[str]) -> LinkageModel:
    spec = read_yaml(path, TableError)
    if not isinstance(spec, dict):
        raise TableError(f"{path}: expected a mapping with {', '.join(_REQUIRED)}")
    for key in _REQUIRED:
        if key not in spec:
            raise TableError(f"{path}: {key}: missing")
    values: dict[str, float] = {}
    for key in PARAMETERS:
        if key in spec:
            try:
                values[key] = float(spec[key])
            except (TypeError, ValueError):
                raise TableError(f"{path}: {key}: {spec[key]!r} is not a number") from None
    return LinkageModel(source=str(path), **values)


def write_linkage(
    path: str | os.PathLike[str], model: LinkageModel, comment: str = "",
    extra: dict[str, Any] | None = None,
) -> None:  # fmt: skip
    """Write ``model`` atomically (values to 1e-9), with comment lines and extra keys."""
    doc: dict[str, Any] = {k: round(v, 9) for k, v in model.values().items()}
    doc.update(extra or {})
    head = "".join(f"# {line}\n" for line in comment.splitlines())
    atomic_write_text(path, head + yaml.safe_dump(doc, sort_keys=False))
