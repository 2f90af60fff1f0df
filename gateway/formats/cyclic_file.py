"""The cyclic-error file: lead, phase origin and harmonic amplitudes at stations (YAML).

::

    lead_mm: 10            # the screw lead: one period of the cyclic error
    origin_mm: 0           # where θ = 0
    stations:              # amplitudes (µm) of harmonics 1..K, measured at these positions
      - {position_mm: 100, sin_um: [0.75, 0.05], cos_um: [1.30, -0.02]}
      - {position_mm: 400, sin_um: [0.70, 0.04], cos_um: [1.25, -0.01]}

Between stations the amplitudes are interpolated linearly, beyond them held. Other top-level
keys (e.g. how the file was fitted) and per-station ``sin_sd_um``/``cos_sd_um`` (standard
uncertainties) are for the report and ignored by the correction.
"""

from __future__ import annotations

import os
from typing import Any

import numpy as np
import yaml

from ..compensation.cyclic import CyclicModel
from ..compensation.errors import TableError
from ..config_types import read_yaml
from .atomic import atomic_write_text
from .lines import POSITION_DECIMALS

_STATION_KEYS = {"position_mm", "sin_um", "cos_um", "sin_sd_um", "cos_sd_um"}


def read_cyclic(path: str | os.PathLike[str]) -> CyclicModel:
    spec = read_yaml(path, TableError)
    if not isinstance(spec, dict):
        raise TableError(f"{path}: expected a mapping with lead_mm and stations")
    for key in ("lead_mm", "stations"):
        if key not in spec:
            raise TableError(f"{path}: {key}: missing")
    stations = spec["stations"]
    if not isinstance(stations, list) or not stations:
        raise TableError(f"{path}: stations: a list of at least one station")
    positions, sines, cosines = [], [], []
    for i, st in enumerate(stations):
        where = f"{path}: stations.{i}"
        if not isinstance(st, dict) or not {"position_mm", "sin_um", "cos_um"} <= set(st):
            raise TableError(f"{where}: needs position_mm, sin_um and cos_um")
        unknown = set(st) - _STATION_KEYS
        if unknown:
            raise TableError(f"{where}.{sorted(unknown)[0]}: unknown key")
        try:
            positions.append(float(st["position_mm"]))
            sines.append([float(v) for v in st["sin_um"]])
            cosines.append([float(v) for v in st["cos_um"]])
        except (TypeError, ValueError):
            raise TableError(f"{where}: positions and amplitudes must be numbers") from None
        if len(sines[-1]) != len(sines[0]) or len(cosines[-1]) != len(sines[0]):
            raise TableError(f"{where}: every station needs the same number of harmonics")
    try:
        lead = float(spec["lead_mm"])
        origin = float(spec.get("origin_mm", 0.0))
    except (TypeError, ValueError):
        raise TableError(f"{path}: lead_mm and origin_mm must be numbers") from None
    return CyclicModel(
        lead,
        np.array(positions),
        np.array(sines) * 1e-3,
        np.array(cosines) * 1e-3,
        origin,
        source=str(path),
    )


def write_cyclic(
    path: str | os.PathLike[str],
    model: CyclicModel,
    extra: dict[str, Any] | None = None,
    sd_mm: tuple[np.ndarray, np.ndarray] | None = None,
) -> None:
    """Write ``model`` (µm), with optional per-station standard uncertainties (mm)."""
    stations = []
    for i, pos in enumerate(model.station_mm):
        st: dict[str, Any] = {
            "position_mm": round(float(pos), POSITION_DECIMALS),
            "sin_um": [round(float(v) * 1e3, 4) for v in model.sin_mm[i]],
            "cos_um": [round(float(v) * 1e3, 4) for v in model.cos_mm[i]],
        }
        if sd_mm is not None:
            st["sin_sd_um"] = [round(float(v) * 1e3, 4) for v in sd_mm[0][i]]
            st["cos_sd_um"] = [round(float(v) * 1e3, 4) for v in sd_mm[1][i]]
        stations.append(st)
    doc = {
        "lead_mm": float(model.lead_mm),
        "origin_mm": float(model.origin_mm),
        **(extra or {}),
        "stations": stations,
    }
    atomic_write_text(path, yaml.safe_dump(doc, sort_keys=False, default_flow_style=None))
