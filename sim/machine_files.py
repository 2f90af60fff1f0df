"""A generated machine as files: the sim config, its truth tables, a matching gateway config
and a summary (``machine.json``). Shared by random machines (:mod:`sim.random_machine`) and
real-data machines (:mod:`sim.real_machines`).

``DIR/sim.yaml``: ``compgw sim -c DIR/sim.yaml`` (127.0.0.1:5021, time_scale 0);
``DIR/gateway.yaml``: ``compgw run -c DIR/gateway.yaml`` (127.0.0.1:5020), uncalibrated: the
drives, registers, travel, resolution and the thermal sensor, no tables; ``DIR/truth/*.csv``
the true errors; ``DIR/machine.json`` what was drawn and where every instrument answers.
Files are written with fixed number formats, so a machine written twice is the same bytes.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from dataclasses import field as dc_field
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from sim.faults import ADDR_CLOCK_MS

SIM_PORT, GATEWAY_PORT = 5021, 5020
LASER_UNIT, XY_UNIT, DELTA_A_UNIT, TEMPERATURE_UNIT, FAULTS_UNIT = 20, 21, 10, 23, 250
#: the example sim's drive registers (Leadshine-like PR mode), as the gateway sees them
REGISTERS = {
    "target": {"address": 0x6201, "words": 2, "order": "hi_lo"},
    "feedback": {"address": 0x602A, "table": "holding", "order": "hi_lo",
                 "counts_per_pulse": 1, "upstream_counts_per_pulse": 1},
    "status": {"address": 0x1003, "homed_bit": 6},
    "trigger": {"address": 0x6002, "value": 0x10, "home_value": 0x20},
}  # fmt: skip


@dataclass
class AxisSpec:
    """One axis of a generated machine; deviations in µm on ``positions_mm``."""

    name: str
    unit: int
    travel_mm: tuple[float, float]
    speed_mm_s: float
    pulse_mm: float  # the upper computer's pulse
    command_scale: int  # drive units per pulse
    positions_mm: np.ndarray
    forward_um: np.ndarray
    reverse_um: np.ndarray
    lead_mm: float | None = None
    #: (stations_mm, amplitudes_um[k, station], phases_deg[k, station]) of the cyclic term
    cyclic: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
    takeup: dict[str, Any] | None = None
    repeatability_um: float = 0.3
    stick_slip: dict[str, float] | None = None
    settling: dict[str, float] | None = None
    thermal: dict[str, Any] | None = None  # sim config: {"thermal": {...}} or {"heat": {...}}
    fixed_end_mm: float | None = None  # where the screw is held axially (thermal origin)
    info: dict[str, Any] = dc_field(default_factory=dict)

    @property
    def drive_unit_mm(self) -> float:
        return self.pulse_mm / self.command_scale


@dataclass
class MachineSpec:
    """A whole XY table: two axes, the XY field, instruments and what to say about it."""

    name: str
    sim_seed: int
    axes: tuple[AxisSpec, AxisSpec]
    #: (xs_mm, ys_mm, ex_um[nx, ny], ey_um[nx, ny]) on grid nodes, or None
    field: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None = None
    #: None, {"kind": "delta_a", "axis", "a_mm"} or {"kind": "temperature", "positions_mm"}
    sensor: dict[str, Any] | None = None
    sample_s: float = 0.0
    header: str = ""
    info: dict[str, Any] = dc_field(default_factory=dict)


def fmt(value: float, decimals: int = 4) -> str:
    """A number with fixed decimals, no negative zero."""
    text = f"{value:.{decimals}f}"
    return "0." + "0" * decimals if text.lstrip("-") == "0." + "0" * decimals else text


def _csv(path: Path, header: list[str], columns: list[np.ndarray], comment: str,
         decimals: int = 4) -> None:
    lines = [f"# {line}" for line in comment.splitlines()] + [",".join(header)]
    for row in zip(*columns):
        lines.append(",".join(fmt(float(v), decimals) for v in row))
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")


def _clean(value: Any) -> Any:
    """Plain YAML/JSON types with floats rounded (stable text)."""
    if isinstance(value, dict):
        return {k: _clean(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_clean(v) for v in value]
    if isinstance(value, (np.floating, float)):
        return float(round(float(value), 6)) + 0.0
    if isinstance(value, np.integer):
        return int(value)
    return value


def sim_config(spec: MachineSpec) -> dict[str, Any]:
    """The ``sim:`` document."""
    axes, machine = {}, {}
    for ax in spec.axes:
        axes[ax.name] = {"unit": ax.unit, "pulse_mm": ax.drive_unit_mm,
                         "travel_mm": list(ax.travel_mm), "speed_mm_s": ax.speed_mm_s}  # fmt: skip
        m: dict[str, Any] = {
            "deviation": {"path": f"truth/{ax.name}_deviation.csv", "reverse_column": "reverse_um"},
            "repeatability_um": ax.repeatability_um,
        }
        if ax.cyclic is not None:
            m["cyclic"] = {"lead_mm": ax.lead_mm, "origin_mm": ax.travel_mm[0],
                           "path": f"truth/{ax.name}_cyclic.csv"}  # fmt: skip
        if ax.takeup is not None:
            m["lost_motion"] = {"takeup": ax.takeup}
        if ax.stick_slip is not None:
            m["stick_slip"] = ax.stick_slip
        if ax.settling is not None:
            m["settling"] = ax.settling
        if ax.thermal is not None:
            m.update(ax.thermal)
        machine[ax.name] = m
    names = [ax.name for ax in spec.axes]
    instruments: dict[str, Any] = {
        "laser": {"unit": LASER_UNIT, "axes": names, "resolution_um": 0.01, "noise_um": 0.05,
                  "sample_s": spec.sample_s},
        "xy": {"unit": XY_UNIT, "resolution_um": 0.01, "noise_um": 0.1, "sample_s": spec.sample_s},
    }  # fmt: skip
    sensor = spec.sensor or {}
    if sensor.get("kind") == "delta_a":
        instruments["delta_a"] = {"unit": DELTA_A_UNIT, "axis": sensor["axis"],
                                  "a_mm": sensor["a_mm"], "resolution_um": 0.1,
                                  "noise_um": 0.1, "direction": sensor["direction"]}  # fmt: skip
    elif sensor.get("kind") == "temperature":
        instruments["temperature"] = {"unit": TEMPERATURE_UNIT, "channels": [*names, "ambient"],
                                      "noise_C": 0.01,
                                      "positions_mm": sensor["positions_mm"]}  # fmt: skip
    doc: dict[str, Any] = {
        "seed": spec.sim_seed, "time_scale": 0,
        "tcp": {"host": "127.0.0.1", "port": SIM_PORT},
        "axes": axes, "machine": machine,
    }  # fmt: skip
    doc["plane"] = {"axes": names}
    if spec.field is not None:
        doc["plane"]["field"] = {"path": "truth/xy_field.csv"}
    doc["instruments"] = instruments
    doc["faults"] = {"unit": FAULTS_UNIT}
    return {"sim": _clean(doc)}


def largest_error_um(spec: MachineSpec) -> float:
    """The largest true deviation any correction must reach (µm), for max_correction_mm."""
    worst = 0.0
    for ax in spec.axes:
        worst = max(worst, float(np.abs(ax.forward_um).max()), float(np.abs(ax.reverse_um).max()))
        if ax.cyclic is not None:
            worst += float(ax.cyclic[1].sum(axis=0).max())
    if spec.field is not None:
        worst += float(np.hypot(spec.field[2], spec.field[3]).max())
    return worst


def _sensed(axis: dict[str, Any], source: str, ax: AxisSpec, a_mm: float | None) -> None:
    """Point an axis at the sensor mounted on its screw, as the technician who mounted it
    writes it: from the screw's fixed end to the Δa sensor (``a_mm``), or to the travel's
    far end for a temperature; commissioning fits the length or gain
    (`compgw commission --delta-a/--temperature`, which the printed command gives)."""
    if ax.fixed_end_mm is None:
        return
    origin = float(ax.fixed_end_mm)
    if a_mm is None:
        lo, hi = ax.travel_mm
        a_mm = hi if abs(hi - origin) >= abs(lo - origin) else lo
    axis["compensation"]["thermal"] = {"source": source, "origin_mm": origin,
                                       "length_mm": abs(float(a_mm) - origin)}


def gateway_config(spec: MachineSpec) -> dict[str, Any]:
    """The uncalibrated gateway config: drives, registers, travel, resolution, and the
    thermal sensors with each axis pointed at its own (no table, nothing fitted)."""
    cap_mm = max(0.2, math.ceil(1.5 * largest_error_um(spec) / 50.0) * 0.05)
    axes = {}
    for ax in spec.axes:
        axes[ax.name] = {
            "bus": "line1", "unit": ax.unit, "pulse_mm": ax.pulse_mm,
            "command_scale": ax.command_scale, "travel_mm": list(ax.travel_mm),
            "home_direction": 1, "registers": REGISTERS,
            "compensation": {"max_correction_mm": round(min(cap_mm, 5.0), 2)},
        }  # fmt: skip
    doc: dict[str, Any] = {
        "upstream": {"tcp": {"host": "127.0.0.1", "port": GATEWAY_PORT,
                             "allow": ["127.0.0.0/8", "::1/128"]}},
        "buses": {"line1": {"tcp": {"host": "127.0.0.1", "port": SIM_PORT}, "timeout_s": 0.2,
                            "retries": 1}},
        "axes": axes,
    }  # fmt: skip
    sources = {}
    # the sim runs at time_scale 0: its clock jumps by whole moves between two wall-clock
    # polls, so poll often, take each reading as it is and allow fast changes
    fast = {"poll_s": 0.01, "smoothing": 1.0, "max_rate_mm_s": 1.0}
    sensor = spec.sensor or {}
    by_name = {ax.name: ax for ax in spec.axes}
    if sensor.get("kind") == "delta_a":
        name = f"{sensor['axis'].lower()}_ref"
        sources[name] = {
            "bus": "line1", "unit": DELTA_A_UNIT,
            "register": {"address": 1, "table": "input", "words": 2, "order": "hi_lo"},
            "scale_mm": 1.0e-6, "noise_mm": 0.0005, **fast,
        }  # fmt: skip
        _sensed(axes[sensor["axis"]], name, by_name[sensor["axis"]], sensor["a_mm"])
    elif sensor.get("kind") == "temperature":
        for k, ax in enumerate(spec.axes):
            name = f"{ax.name.lower()}_screw"
            sources[name] = {
                "bus": "line1", "unit": TEMPERATURE_UNIT,
                "register": {"address": k, "table": "input", "words": 1},
                "kind": "temperature", "scale_c": 0.01, "reference_c": 20.0,
                "alpha_per_k": 11.5e-6, "noise_mm": 0.0005, **fast,
            }  # fmt: skip
            _sensed(axes[ax.name], name, ax, None)
    if sources:
        doc["thermal_sources"] = sources
    doc["passthrough"] = {LASER_UNIT: {"bus": "line1", "unit": LASER_UNIT},
                          XY_UNIT: {"bus": "line1", "unit": XY_UNIT}}  # fmt: skip
    doc["status"] = {"upstream_unit": 247, "remote_control": False}
    # the sim's clock runs hours of machine time in minutes: the gateway counts the heat
    # of motion (and commissioning its drift log) by it, read from the control unit
    doc["machine_clock"] = {"bus": "line1", "unit": FAULTS_UNIT,
                            "register": {"address": ADDR_CLOCK_MS, "table": "holding",
                                         "words": 2, "signed": False},
                            "scale_s": 0.001}  # fmt: skip
    return _clean(doc)


def instruments_summary(spec: MachineSpec) -> dict[str, Any]:
    """Where each instrument answers and how to read it (machine.json)."""
    names = [ax.name for ax in spec.axes]
    out: dict[str, Any] = {
        "laser": {"unit": LASER_UNIT, "registers": "axis k at input 2k, 2k+1: int32 nm, high "
                  "word first; 2N+k: stable flag", "channels": names,
                  "calibrate": f"--laser 127.0.0.1:{SIM_PORT}:{LASER_UNIT}"},
        "xy": {"unit": XY_UNIT, "registers": "0-1 X, 2-3 Y: int32 nm; 4, 5: stable flags",
               "calibrate": f"--xy-device 127.0.0.1:{SIM_PORT}:{XY_UNIT}"},
        "faults": {"unit": FAULTS_UNIT, "advance_clock_s": 0x0800, "advance_clock_ms": 0x0801},
    }  # fmt: skip
    sensor = spec.sensor or {}
    if sensor.get("kind") == "delta_a":
        out["delta_a"] = {"unit": DELTA_A_UNIT, "axis": sensor["axis"], "a_mm": sensor["a_mm"],
                          "reads": "elongation of the screw at a_mm (+ when warm)",
                          "registers": "1-2: int32 nm", "calibrate":
                          f"--delta-a 127.0.0.1:{SIM_PORT}:{DELTA_A_UNIT}:1"}  # fmt: skip
    elif sensor.get("kind") == "temperature":
        out["temperature"] = {"unit": TEMPERATURE_UNIT, "channels": [*names, "ambient"],
                              "positions_mm": sensor["positions_mm"],
                              "registers": "channel k at input k: int16, 0.01 degC",
                              "calibrate": f"--temperature 127.0.0.1:{SIM_PORT}:"
                                           f"{TEMPERATURE_UNIT}"}  # fmt: skip
    return out


def write_machine(spec: MachineSpec, out_dir: str | Path) -> Path:
    """Write DIR/sim.yaml, DIR/gateway.yaml, DIR/truth/*.csv, DIR/machine.json; return DIR."""
    out = Path(out_dir)
    truth = out / "truth"
    truth.mkdir(parents=True, exist_ok=True)
    for ax in spec.axes:
        _csv(truth / f"{ax.name}_deviation.csv", ["position_mm", "forward_um", "reverse_um"],
             [ax.positions_mm, ax.forward_um, ax.reverse_um],
             f"{spec.name}: true deviation of {ax.name} (true - commanded, um), approached\n"
             "moving + (forward) and moving - (reverse: the lost motion included);\n"
             "the turn-by-turn term is in the cyclic file, not here")  # fmt: skip
        if ax.cyclic is not None:
            stations, amps, phases = ax.cyclic
            header, cols = ["position_mm"], [stations]
            for k in range(amps.shape[0]):
                header += [f"a{k + 1}_um", f"phi{k + 1}_deg"]
                cols += [amps[k], phases[k]]
            _csv(truth / f"{ax.name}_cyclic.csv", header, cols,
                 f"{spec.name}: lead variation of {ax.name} within each turn (lead "
                 f"{ax.lead_mm:g} mm): sum of a_k sin(2 pi k (x - {ax.travel_mm[0]:g})/lead "
                 "+ phi_k)")  # fmt: skip
    if spec.field is not None:
        xs, ys, ex, ey = spec.field
        gx, gy = np.meshgrid(xs, ys, indexing="ij")
        _csv(truth / "xy_field.csv", ["x_mm", "y_mm", "ex_um", "ey_um"],
             [gx.ravel(), gy.ravel(), ex.ravel(), ey.ravel()],
             f"{spec.name}: XY error field (true - commanded, um) at grid nodes")  # fmt: skip
    head = spec.header or f"{spec.name}: a generated machine"
    sim_text = "".join(f"# {line}\n" for line in head.splitlines())
    sim_text += "# Every key: sim/README.md. Run: compgw sim -c sim.yaml\n"
    (out / "sim.yaml").write_text(
        sim_text + yaml.safe_dump(sim_config(spec), sort_keys=False), encoding="utf-8")
    gw_text = (f"# The gateway in front of {spec.name}, uncalibrated (no tables): compgw run -c "
               "gateway.yaml\n# Thermal sources poll fast: the sim runs at time_scale 0.\n")
    (out / "gateway.yaml").write_text(
        gw_text + yaml.safe_dump(gateway_config(spec), sort_keys=False), encoding="utf-8")
    summary = {
        "name": spec.name, **spec.info,
        "ports": {"sim": SIM_PORT, "gateway": GATEWAY_PORT},
        "files": {"sim": "sim.yaml", "gateway": "gateway.yaml", "truth": "truth/"},
        "axes": {ax.name: {"travel_mm": list(ax.travel_mm), "lead_mm": ax.lead_mm,
                           "pulse_mm": ax.pulse_mm, "command_scale": ax.command_scale,
                           "speed_mm_s": ax.speed_mm_s,
                           "screw_fixed_end_mm": ax.fixed_end_mm, **ax.info}
                 for ax in spec.axes},
        "instruments": instruments_summary(spec),
    }  # fmt: skip
    (out / "machine.json").write_text(json.dumps(_clean(summary), indent=2) + "\n",
                                      encoding="utf-8")
    return out
