"""Calibration workflows run on a generated machine with the `compgw` command line only.

A workflow gets a :class:`MachineRun`: the machine's directory (``compgw sim --random-machine``
or ``--real-machine``: sim.yaml, gateway.yaml, machine.json), a running ``compgw sim`` and
``compgw run`` (separate processes, free ports), and helpers that do what a user does:
``compgw(...)`` runs a command, ``use(config)`` writes the gateway's config file and sends
SIGHUP (as ``systemctl reload``), ``cool_down()`` lets the machine cool (the sim's clock). It
returns the calibrated gateway config and the targets it measured, which the evaluator keeps
clear of. ``WORKFLOWS`` maps a name to a workflow (``--workflow`` of bench/accuracy.py):

- ``commission``: `compgw commission`, one command (README, "Commissioning a machine").
- ``manual``: exactly gateway/calibration/README.md's workflow: warm-up and thermal fit
  (with a Δa sensor), ISO 230-2 identification of each axis with a table every quarter of
  the screw lead (5 runs), the XY grid (9 x 7, 3 runs) with the pitch tables on, fits.

``python bench/workflows.py DIR [--workflow manual]`` runs one workflow on a machine
directory and prints the final config's path.
"""

from __future__ import annotations

import argparse
import contextlib
import copy
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml
from pymodbus.client import ModbusTcpClient

from sim.technician import Gauge, Technician

ROOT = Path(__file__).resolve().parent.parent
FAULTS_UNIT, ADVANCE_CLOCK_S = 250, 0x0800
STATUS_UNIT, SOURCE_BASE, SOURCE_STRIDE = 247, 80, 4
COOL_DOWN_S = 30_000
START_TIMEOUT_S, COMMAND_TIMEOUT_S = 60.0, 3600.0
#: the gateway's bus timeout here (s): a late answer is waited for, never asked again (a
#: trigger sent twice is a second stop: another draw of the stop's scatter)
BUS_TIMEOUT_S = 10.0
#: how often the gateway polls its thermal sources here (s): a write through the wire waits
#: for two polls (bench/lockstep.py), the figures do not depend on it
SOURCE_POLL_S = 0.002


def child_env() -> dict[str, str]:
    """The children's environment: str hashing (set order) the same in every run, and one
    BLAS thread (the sums in the same order whatever ``--jobs``; set it to change it)."""
    threads = {k: "1" for k in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")}
    return {**threads, **os.environ, "PYTHONHASHSEED": "0"}


def compgw_argv() -> list[str]:
    """The `compgw` command of this Python environment."""
    script = Path(sys.executable).with_name("compgw")
    return [str(script)] if script.exists() else [sys.executable, "-m", "gateway.cli"]


def lockstep_argv(sim_port: int) -> list[str]:
    """`compgw` on the machine's clock (bench/lockstep.py clock): ARGS to follow."""
    return [sys.executable, str(Path(__file__).with_name("lockstep.py")), "clock",
            f"127.0.0.1:{sim_port}", "--"]  # fmt: skip


class CommandFailed(RuntimeError):
    """A `compgw` command exited non-zero; the message holds its last stderr lines."""


class _Lines:
    """Lines of a child's stream, collected by a thread; wait for a pattern."""

    def __init__(self, stream: Any) -> None:
        self.lines: list[str] = []
        self._cond = threading.Condition()
        self._thread = threading.Thread(target=self._read, args=(stream,), daemon=True)
        self._thread.start()

    def _read(self, stream: Any) -> None:
        for line in stream:
            with self._cond:
                self.lines.append(line.rstrip("\n"))
                self._cond.notify_all()

    def wait_for(self, pattern: str, start: int = 0, timeout_s: float = START_TIMEOUT_S
                 ) -> re.Match[str]:  # fmt: skip
        rx = re.compile(pattern)
        deadline = time.monotonic() + timeout_s
        with self._cond:
            while True:
                for line in self.lines[start:]:
                    found = rx.search(line)
                    if found:
                        return found
                left = deadline - time.monotonic()
                if left <= 0:
                    tail = "\n".join(self.lines[-5:])
                    raise TimeoutError(f"no line matching {pattern!r} in {timeout_s:g} s: {tail}")
                self._cond.wait(min(left, 0.5))


@dataclass
class MachineRun:
    """A generated machine with its sim and gateway running; what a workflow works with.

    In lock-step with the machine (bench/lockstep.py): every `compgw` command and the
    gateway run on the sim's machine clock; with thermal sources the wire stands between
    the sim and everyone (``sim_port``, the gateway's bus, ``gateway_port``)."""

    dir: Path
    work: Path
    machine: dict[str, Any]
    #: where the instruments and the control block answer (the wire, or the sim itself)
    sim_port: int = 0
    #: where the masters reach the gateway (through the wire, or the gateway itself)
    gateway_port: int = 0
    #: the sim itself (its clock) and where the gateway's bus goes
    machine_port: int = 0
    bus_port: int = 0
    commands: list[str] = field(default_factory=list)
    command_wall_s: float = 0.0
    #: machine time of the plans run, as each command estimated it before moving (s)
    machine_s: float = 0.0
    #: the manual workflow's machine time on this machine (s), when a workflow asked for it
    manual_s: float | None = None
    #: the wire's count of writes that went on with the sources not read (see lockstep.py)
    unsynced: int = 0
    _sim: subprocess.Popen[str] | None = None
    _wire: subprocess.Popen[str] | None = None
    _wire_out: _Lines | None = None
    _gateway: subprocess.Popen[str] | None = None
    _gw_log: _Lines | None = None
    _gw_path: Path | None = None
    #: the sim's laser on the bridge protocol (``LASER_KIND`` "bridge"), as --laser gives it
    laser_bridge: str | None = None

    # -- processes ----------------------------------------------------------------------------
    @classmethod
    def start(cls, machine_dir: Path, work: Path) -> MachineRun:
        """Start ``compgw sim`` (free port), the wire when the gateway has thermal sources,
        and ``compgw run`` with the uncalibrated config."""
        machine_dir, work = machine_dir.resolve(), work.resolve()
        machine = json.loads((machine_dir / "machine.json").read_text())
        work.mkdir(parents=True, exist_ok=True)
        run = cls(machine_dir, work, machine)
        try:
            sim = run._start_sim()
            run._start_wire(sim)
            run._start_gateway(run.base_config())
        except BaseException:
            run.stop()
            raise
        return run

    def _start_sim(self) -> dict[str, Any]:
        data = yaml.safe_load((self.dir / "sim.yaml").read_text())
        data["sim"]["tcp"]["port"] = 0
        data["sim"]["time_scale"] = 0  # the machine's clock moves with requests alone
        if LASER_KIND == "bridge":  # the same laser on the bridge line protocol too
            data["sim"]["instruments"]["laser"]["bridge"] = {"host": "127.0.0.1", "port": 0}
        if reads_later():  # ... recording the first commissioned axis (a capture: CSV)
            axis = (COMMISSION_AXES or list(data["sim"]["axes"]))[0]
            data["sim"]["instruments"]["laser"]["recording"] = {
                "dir": str(self.work / "recordings"),
                "format": "csv" if LASER_KIND == "capture" else LASER_KIND.split("-")[1],
                "axis": axis, "rate_hz": 500, "unit": "um", "idle_time_scale": 1000.0}
        path = self.dir / "sim.run.yaml"  # beside sim.yaml: truth/ paths stay valid
        path.write_text(yaml.safe_dump(data, sort_keys=False))
        self._sim = subprocess.Popen([*compgw_argv(), "sim", "-c", str(path)], text=True,
                                     stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                                     env=child_env())  # fmt: skip
        lines = _Lines(self._sim.stdout)
        if LASER_KIND == "bridge":
            found = lines.wait_for(r"laser bridge on ([\d.]+:\d+)")
            self.laser_bridge = f"bridge:tcp:{found.group(1)}"
        self.machine_port = int(lines.wait_for(r"modbus tcp on [\d.]+:(\d+)").group(1))
        self.sim_port = self.bus_port = self.machine_port
        return data["sim"]

    def _start_wire(self, sim: dict[str, Any]) -> None:
        """The wire (bench/lockstep.py) when the gateway polls thermal sources."""
        base = yaml.safe_load((self.dir / "gateway.yaml").read_text())
        sources = base.get("thermal_sources") or {}
        if not sources:
            return
        ins = sim.get("instruments") or {}
        sensors = []
        if ins.get("delta_a"):
            sensors.append(f"{ins['delta_a']['unit']}:3")
        if ins.get("temperature"):
            t = ins["temperature"]
            channels = t.get("channels") or [*sim["axes"], "ambient"]
            sensors.append(f"{t['unit']}:{len(channels)}")
        argv = [sys.executable, str(Path(__file__).with_name("lockstep.py")), "wire",
                "--sim", f"127.0.0.1:{self.machine_port}",
                "--status-unit", str(base["status"]["upstream_unit"])]  # fmt: skip
        for s in sensors:
            argv += ["--sensor", s]
        for axis in sim["axes"].values():
            argv += ["--drive", str(axis["unit"])]
        for src in sources.values():
            reg = src["register"]
            argv += ["--source", f"{src['unit']}:{reg['address']}:{reg.get('words', 1)}"]
        with (self.work / "wire.log").open("w") as log:
            self._wire = subprocess.Popen(argv, text=True, stdin=subprocess.PIPE,
                                          stdout=subprocess.PIPE, stderr=log,
                                          env=child_env())  # fmt: skip
        self._wire_out = _Lines(self._wire.stdout)
        found = self._wire_out.wait_for(r"lockstep wire: sim (\d+) bus (\d+)")
        self.sim_port, self.bus_port = int(found.group(1)), int(found.group(2))

    def _start_gateway(self, config: dict[str, Any]) -> None:
        self._gw_path = self.work / "gw.yaml"
        self._write(self._gw_path, config)
        self._gateway = subprocess.Popen(
            [*lockstep_argv(self.machine_port), "run", "-c", str(self._gw_path),
             "--log-level", "info"],
            text=True, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
            env=child_env())  # fmt: skip
        self._gw_log = _Lines(self._gateway.stderr)
        found = self._gw_log.wait_for(r"compgw running: Modbus TCP [\d.]+:(\d+)")
        self.gateway_port = int(found.group(1))
        if self._wire is not None and self._wire_out is not None:
            assert self._wire.stdin is not None
            self._wire.stdin.write(f"gateway {self.gateway_port}\n")
            self._wire.stdin.flush()
            found = self._wire_out.wait_for(r"lockstep wire: gateway (\d+)")
            self.gateway_port = int(found.group(1))

    def stop(self) -> None:
        """SIGTERM the gateway, the wire and the sim, wait for them."""
        procs = (self._gateway, self._wire, self._sim)
        for proc in procs:
            if proc is not None and proc.poll() is None:
                proc.send_signal(signal.SIGTERM)
        for proc in procs:
            if proc is not None:
                try:
                    proc.wait(10)
                except subprocess.TimeoutExpired:
                    proc.kill()
                    proc.wait(10)
        if self._wire_out is not None:
            with contextlib.suppress(TimeoutError):
                found = self._wire_out.wait_for(r"unsynced (\d+)", timeout_s=1.0)
                self.unsynced = int(found.group(1))

    # -- configs ------------------------------------------------------------------------------
    def base_config(self) -> dict[str, Any]:
        """The machine's gateway.yaml on this run's ports (uncalibrated)."""
        data = yaml.safe_load((self.dir / "gateway.yaml").read_text())
        data["upstream"]["tcp"]["port"] = 0
        for bus in data["buses"].values():
            bus["tcp"]["port"] = self.bus_port
            bus["timeout_s"] = max(bus.get("timeout_s", 0.0), BUS_TIMEOUT_S)
        for src in (data.get("thermal_sources") or {}).values():
            src["poll_s"] = SOURCE_POLL_S
        return data

    @staticmethod
    def _write(path: Path, data: dict[str, Any]) -> None:
        tmp = path.with_suffix(".tmp")
        tmp.write_text(yaml.safe_dump(data, sort_keys=False))
        os.replace(tmp, path)

    def write_config(self, name: str, data: dict[str, Any]) -> Path:
        """A config file in the work directory (tables relative to it)."""
        path = self.work / name
        self._write(path, data)
        return path

    def use(self, data: dict[str, Any] | Path) -> None:
        """Make the running gateway load ``data`` (its config file rewritten, then SIGHUP)."""
        assert self._gateway is not None and self._gw_log is not None and self._gw_path
        if isinstance(data, Path):
            data = yaml.safe_load(data.read_text())
        self._write(self._gw_path, data)
        start = len(self._gw_log.lines)
        self._gateway.send_signal(signal.SIGHUP)
        found = self._gw_log.wait_for(r"(reloaded|reload refused.*)", start)
        if found.group(1) != "reloaded":
            raise CommandFailed(f"gateway: {found.group(1)}")

    # -- the machine --------------------------------------------------------------------------
    def instrument(self, unit: int, address: int | None = None) -> str:
        tail = "" if address is None else f":{address}"
        return f"127.0.0.1:{self.sim_port}:{unit}{tail}"

    @property
    def gateway(self) -> str:
        return f"127.0.0.1:{self.gateway_port}"

    def cool_down(self, seconds: int = COOL_DOWN_S) -> None:
        """Let the machine cool (the sim's clock), then wait until the gateway's thermal
        sources read cold again (its status unit).

        Hours pass in the sim at once: the gateway's wall clock does not see them, as it
        would in a real night, so axes with heat from motion would still be warm to it. A
        reload without their ``thermal.motion`` and one with it again give them what the
        hours would: a cold screw. A travel profile that forgets in time (``memory_s``,
        set by commission's zone warm-up) is reloaded the same way: the hours would have
        faded its old zones."""
        client = ModbusTcpClient("127.0.0.1", port=self.sim_port, timeout=2, retries=0)
        assert client.connect()
        try:
            client.write_register(ADVANCE_CLOCK_S, seconds, device_id=FAULTS_UNIT)
        finally:
            client.close()
        config = yaml.safe_load(self._gw_path.read_text())  # type: ignore[union-attr]
        bare = copy.deepcopy(config)
        for ax in bare["axes"].values():
            thermal = (ax.get("compensation") or {}).get("thermal") or {}
            if thermal.get("motion") or (thermal.get("profile") or {}).get("memory_s"):
                del ax["compensation"]["thermal"]
        if bare != config:
            self.use(bare)
            self.use(config)
        sources = len(config.get("thermal_sources") or {})
        if not sources:
            return
        gw = ModbusTcpClient("127.0.0.1", port=self.gateway_port, timeout=2, retries=0)
        assert gw.connect()
        try:
            deadline = time.monotonic() + 20
            while True:
                regs = gw.read_input_registers(SOURCE_BASE, count=SOURCE_STRIDE * sources,
                                               device_id=STATUS_UNIT).registers  # fmt: skip
                cold = True
                for s in range(sources):
                    state, hi, lo = regs[4 * s: 4 * s + 3]
                    da = ((hi << 16) | lo) - ((1 << 32) if hi & 0x8000 else 0)
                    cold &= state == 1 and abs(da) <= 5  # 0.5 µm
                if cold:
                    return
                if time.monotonic() > deadline:
                    raise TimeoutError("thermal sources did not read cold after the cool-down")
                time.sleep(0.02)
        finally:
            gw.close()

    def compgw(self, *args: object, technician: Technician | Gauge | None = None) -> str:
        """Run ``compgw ARGS`` in the work directory; its stdout; CommandFailed if non-zero.
        ``technician``: hears every line as it comes and answers on stdin (a recording)."""
        argv = [*lockstep_argv(self.machine_port), *(str(a) for a in args)]
        self.commands.append(" ".join(["compgw", *(str(a) for a in args)]))
        t0 = time.monotonic()
        if technician is None:
            out = subprocess.run(argv, cwd=self.work, text=True, capture_output=True,
                                 timeout=COMMAND_TIMEOUT_S, env=child_env())  # fmt: skip
        else:
            out = technician.attend(argv, self.work, COMMAND_TIMEOUT_S, child_env())
        self.command_wall_s += time.monotonic() - t0
        self.machine_s += 60 * sum(float(m) for m in re.findall(
            r"about ([\d.]+) min of machine time", out.stdout))  # fmt: skip
        if out.returncode != 0:
            tail = (out.stderr.strip() or out.stdout.strip()).splitlines()[-3:]
            raise CommandFailed(f"compgw {' '.join(map(str, args[:3]))}: exit "
                                f"{out.returncode}: {' | '.join(tail)}")  # fmt: skip
        return out.stdout


@dataclass
class WorkflowResult:
    """What a workflow leaves: the calibrated config, the targets it measured, remarks."""

    config: dict[str, Any]
    calibration_targets_mm: dict[str, list[float]]
    notes: list[str] = field(default_factory=list)
    machine_time_s: float = 0.0


# -- helpers shared by workflows -----------------------------------------------------------------
def without(data: dict[str, Any], *stages: str) -> dict[str, Any]:
    """A copy with the given compensation stages (pitch, thermal, cyclic, planar) removed."""
    data = copy.deepcopy(data)
    for axis in data["axes"].values():
        for stage in stages:
            axis.get("compensation", {}).pop(stage, None)
    if "planar" in stages:
        data.pop("planar", None)
    return data


#: Δa axes get ``thermal.profile`` (the travel-shaped spread); accuracy.py --thermal-profile
THERMAL_PROFILE = False


def thermal_setup(run: MachineRun, data: dict[str, Any]) -> str | None:
    """Point each axis with a sensor at its thermal source (origin at the screw's fixed end);
    the sensor kind (``delta_a``, ``temperature``) or None."""
    sources = data.get("thermal_sources") or {}
    kind = None
    for name, axis in data["axes"].items():
        info = run.machine["axes"][name]
        origin = info.get("screw_fixed_end_mm")
        lo, hi = axis["travel_mm"]
        for src_name, src in sources.items():
            displacement = src.get("kind", "displacement") == "displacement"
            if displacement and src_name == f"{name.lower()}_ref":
                a_mm = run.machine["instruments"]["delta_a"]["a_mm"]
                axis["compensation"]["thermal"] = {"source": src_name, "origin_mm": origin,
                                                   "length_mm": abs(a_mm - origin)}  # fmt: skip
                if THERMAL_PROFILE:
                    axis["compensation"]["thermal"]["profile"] = {}
                kind = "delta_a"
            elif src.get("kind") == "temperature" and src_name == f"{name.lower()}_screw":
                far = hi if abs(hi - origin) >= abs(lo - origin) else lo
                axis["compensation"]["thermal"] = {"source": src_name, "origin_mm": origin,
                                                   "length_mm": abs(far - origin)}  # fmt: skip
                kind = "temperature"
    return kind


def measured_targets(raw_path: Path) -> dict[str, list[float]]:
    """Targets of the measured rows of a raw CSV, by axis (XY files: both coordinates)."""
    out: dict[str, set[float]] = {}
    lines = [ln for ln in raw_path.read_text().splitlines() if ln and not ln.startswith("#")]
    header = lines[0].split(",")
    col = {name: k for k, name in enumerate(header)}
    for line in lines[1:]:
        cells = line.split(",")
        out.setdefault(cells[col["axis"]], set()).add(float(cells[col["target_mm"]]))
        for axis in ("X", "Y"):
            key = f"{axis.lower()}_mm"
            if key in col and cells[col[key]]:
                out.setdefault(axis, set()).add(float(cells[col[key]]))
    return {a: sorted(v) for a, v in out.items()}


def merge_targets(*parts: dict[str, list[float]]) -> dict[str, list[float]]:
    out: dict[str, set[float]] = {}
    for part in parts:
        for axis, values in part.items():
            out.setdefault(axis, set()).update(values)
    return {a: sorted(v) for a, v in out.items()}


def table_step_mm(info: dict[str, Any]) -> tuple[float, float | None]:
    """The README's table spacing: a quarter of the screw lead (else half the data spacing of
    a real-data axis, whose lead is not known); and the lead for ``--lead-mm``."""
    lead = info.get("lead_mm")
    if lead:
        return lead / 4.0, float(lead)
    return float(info.get("data_spacing_mm") or 10.0) / 2.0, None


#: the manual workflow's XY grid (with the pitch tables on)
MANUAL_XY = ("--xy", "--grid", "9", "7", "--grid-runs", "3", "--overrun-mm", "1")


def manual_iso(run: MachineRun, axis: str, low: dict[str, float]) -> list[str]:
    """The manual workflow's ISO 230-2 identification of ``axis``: a table every quarter
    lead, 5 runs, the other axis parked at its low end."""
    other = next(a for a in low if a != axis)
    step, lead = table_step_mm(run.machine["axes"][axis])
    return ["--iso", axis, "--step-mm", f"{step:g}", "--runs", "5", "--overrun-mm", "1",
            "--park", f"{other}={low[other]:g}", *(["--lead-mm", f"{lead:g}"] if lead else [])]


def manual_config(run: MachineRun) -> tuple[dict[str, Any], str | None]:
    """The manual workflow's calibrated config before any fit (its table paths, the plane,
    the thermal source) and the thermal sensor kind."""
    full = run.base_config()
    names = list(full["axes"])
    for a in names:
        full["axes"][a]["compensation"]["pitch"] = {"file": f"tables/{a.lower()}_pitch.csv",
                                                    "interpolation": "smooth"}  # fmt: skip
    full["planar"] = {"axes": names, "model": "tables/xy_model.yaml", "commit": "on_trigger"}
    return full, thermal_setup(run, full)


# -- the workflows -------------------------------------------------------------------------------
def manual(run: MachineRun) -> WorkflowResult:
    """gateway/calibration/README.md, step by step, as a user types it."""
    notes: list[str] = []
    full, kind = manual_config(run)
    (run.work / "tables").mkdir(exist_ok=True)
    names = list(full["axes"])
    low = {a: full["axes"][a]["travel_mm"][0] for a in names}
    gw = run.write_config("gw.calibrated.yaml", full)
    laser = run.instrument(20)
    common = ["-c", gw, "--gateway", run.gateway, "--no-progress"]
    targets: list[dict[str, list[float]]] = []

    # 1. warm-up with nothing on: the thermal length (a Δa sensor only)
    if kind == "delta_a":
        axis = next(a for a in names if "thermal" in full["axes"][a]["compensation"])
        other = next(a for a in names if a != axis)
        run.use(without(full, "pitch", "thermal", "planar"))
        run.cool_down()
        delta_a = run.instrument(10, 1)
        run.compgw("calibrate", *common, "--warmup", axis, "--laser", laser, "--delta-a",
                   delta_a, "--park", f"{other}={low[other]:g}", "--measure-every", "2",
                   "--raw", run.work / "warm.csv")  # fmt: skip
        fit = json.loads(run.compgw("fit", run.work / "warm.csv", "-c", gw, "--json"))
        length = fit[axis]["thermal"]["length_mm"]
        full["axes"][axis]["compensation"]["thermal"]["length_mm"] = round(length, 1)
        notes.append(f"thermal length of {axis}: {length:.1f} mm")
        gw = run.write_config("gw.calibrated.yaml", full)
    ident = run.work / "ident.yaml"
    run.compgw("calibrate", "-c", gw, "--identify-config", ident)

    # 2. ISO 230-2 identification of each axis, a table every quarter lead, thermal on
    run.use(ident)
    run.cool_down()
    raws = []
    for axis in names:
        raw = run.work / f"{axis}_id.csv"
        run.compgw("calibrate", *common, *manual_iso(run, axis, low), "--laser", laser,
                   "--raw", raw)  # fmt: skip
        raws.append(raw)
        targets.append(measured_targets(raw))
    run.compgw("fit", *raws, "-c", gw)

    # 3. the XY grid with the pitch tables on
    run.use(without(full, "planar"))
    run.cool_down()
    xy_raw = run.work / "xy_id.csv"
    run.compgw("calibrate", *common, *MANUAL_XY, "--xy-device", run.instrument(21),
               "--raw", xy_raw)  # fmt: skip
    targets.append(measured_targets(xy_raw))
    pins = [f"{a}@{b}={low[b]:g}" for a, b in ((names[0], names[1]), (names[1], names[0]))]
    fit = json.loads(run.compgw("fit", xy_raw, "-c", gw, "--json", "--pitch-line", pins[0],
                                "--pitch-line", pins[1]))  # fmt: skip
    planar = fit.get("planar", {})
    notes.append(f"planar: {planar.get('kind')} degree {planar.get('degree')}, residual RMS "
                 f"{planar.get('residual_rms_um', float('nan')):.2f} µm")  # fmt: skip
    return WorkflowResult(yaml.safe_load(gw.read_text()), merge_targets(*targets), notes)


#: the tolerance `compgw commission` is given (µm, ISO 230-2 E and XY max vector error);
#: accuracy.py --tolerance-um sets it
TOLERANCE_UM = 2.0
#: commission's machine-time budget as this many times the manual workflow's on the same
#: machine (its plans' estimate, nothing run); None: commission's own default (8 h)
BUDGET_VS_MANUAL: float | None = None
#: ... or as this many times the plain workflow's (``accuracy.py --budget-vs-plain``)
BUDGET_VS_PLAIN: float | None = None
#: how commission reads the sim's laser (``accuracy.py --laser-kind``)
LASER_KINDS = ("modbus", "bridge", "recording-rtx", "recording-csv", "capture", "manual")
LASER_KIND = "modbus"
#: the axes commission is given (``accuracy.py --commission-axes``; None: all, the plane
#: too): a recording reads one axis, so it is compared on that axis alone
COMMISSION_AXES: list[str] | None = None
#: a recording's stand at each stop (s of the machine's clock: bench/lockstep.py advances
#: it, no wall time passes): the Modbus path's estimate of a stop, so both cost the same
RECORDING_DWELL_S = 2.0


def reads_later() -> bool:
    """Whether commission reads the laser from its software's file after the moves."""
    return LASER_KIND.startswith("recording") or LASER_KIND == "capture"


def manual_machine_s(run: MachineRun) -> float:
    """The machine time the manual workflow's plans take on this machine (s)."""
    full, kind = manual_config(run)
    names = list(full["axes"])
    low = {a: full["axes"][a]["travel_mm"][0] for a in names}
    asks: list[list[str]] = []
    if kind == "delta_a":
        axis = next(a for a in names if "thermal" in full["axes"][a]["compensation"])
        asks.append(["--warmup", axis, "--measure-every", "2"])
    asks += [manual_iso(run, axis, low) for axis in names]
    asks.append(list(MANUAL_XY))
    return estimate_s(run, full, asks)


def plain_machine_s(run: MachineRun) -> float:
    """The machine time the plain workflow's plans take on this machine (s)."""
    full, _ = plain_config(run)
    return estimate_s(run, full, plain_asks(run, full))


def estimate_s(run: MachineRun, config: dict[str, Any], asks: list[list[str]]) -> float:
    """The machine time of ``asks`` (each a `compgw calibrate` plan) on ``config`` (s): what
    `compgw calibrate` prints before it moves, asked without a --raw file (nothing runs)."""
    gw = run.write_config("gw.estimate.yaml", config)
    total_min = 0.0
    for ask in asks:
        out = subprocess.run([*compgw_argv(), "calibrate", "-c", str(gw), *ask], cwd=run.work,
                             text=True, capture_output=True, timeout=COMMAND_TIMEOUT_S)  # fmt: skip
        found = re.findall(r"about ([\d.]+) min of machine time", out.stdout)
        if not found:
            raise CommandFailed(f"no machine-time estimate from calibrate {' '.join(ask)}: "
                                f"{out.stderr.strip()[-200:]}")  # fmt: skip
        total_min += float(found[0])
    return 60.0 * total_min


# -- the plain ISO 230-2 calibration (issue 54) ----------------------------------------------------
#: a table every this many mm, 5 bidirectional runs (calibrate's own defaults)
PLAIN_STEP_MM = 25.0
#: the plain workflow's XY grid (with the pitch tables on)
PLAIN_XY = ("--xy", "--grid", "9", "7", "--grid-runs", "2", "--overrun-mm", "1")


def plain_config(run: MachineRun) -> tuple[dict[str, Any], str | None]:
    """The plain workflow's calibrated config before any fit: the manual one's, and a
    cyclic file on every axis whose lead the machine's data sheet gives."""
    full, kind = manual_config(run)
    for a, info in run.machine["axes"].items():
        if info.get("lead_mm") and a in full["axes"]:
            full["axes"][a]["compensation"]["cyclic"] = f"tables/{a.lower()}_cyclic.yaml"
    return full, kind


def plain_asks(run: MachineRun, full: dict[str, Any]) -> list[list[str]]:
    """The plain workflow's plans: per axis the ISO 230-2 runs (a table every 25 mm, 5
    runs, the other axis parked low) and, where the lead is known, the dense scans for the
    once-per-lead error; then the XY grid."""
    names = list(full["axes"])
    low = {a: full["axes"][a]["travel_mm"][0] for a in names}
    asks = []
    for axis in names:
        other = next(a for a in names if a != axis)
        park = ["--park", f"{other}={low[other]:g}"]
        lead = run.machine["axes"][axis].get("lead_mm")
        by_lead = ["--lead-mm", f"{lead:g}"] if lead else []
        asks.append(["--iso", axis, "--step-mm", f"{PLAIN_STEP_MM:g}", "--runs", "5",
                     "--overrun-mm", "1", *park, *by_lead])  # fmt: skip
        if lead:
            asks.append(["--cyclic", axis, *by_lead, *park])
    asks.append(list(PLAIN_XY))
    return asks


def plain(run: MachineRun) -> WorkflowResult:
    """The plain ISO 230-2 calibration a technician bills (issue 54), one `compgw
    calibrate` per step as the manual path in docs/calibration.md has it: each axis's ISO
    runs and cyclic scans with the identification config, one joint fit, the XY grid with
    the pitch tables on and its fit. The sensors' thermal settings are kept as configured
    (no warm-up)."""
    full, _ = plain_config(run)
    (run.work / "tables").mkdir(exist_ok=True)
    names = list(full["axes"])
    low = {a: full["axes"][a]["travel_mm"][0] for a in names}
    gw = run.write_config("gw.calibrated.yaml", full)
    common = ["-c", gw, "--gateway", run.gateway, "--no-progress"]
    ident = run.work / "ident.yaml"
    run.compgw("calibrate", "-c", gw, "--identify-config", ident)
    run.use(ident)
    run.cool_down()
    raws, targets = [], []
    for ask in plain_asks(run, full)[:-1]:
        raw = run.work / f"{ask[1]}_{ask[0].lstrip('-')}.csv"
        run.compgw("calibrate", *common, *ask, "--laser", run.instrument(20), "--raw", raw)
        raws.append(raw)
        targets.append(measured_targets(raw))
    run.compgw("fit", *raws, "-c", gw)
    run.use(without(full, "planar"))
    xy_raw = run.work / "xy_id.csv"
    run.compgw("calibrate", *common, *PLAIN_XY, "--xy-device", run.instrument(21),
               "--raw", xy_raw)  # fmt: skip
    targets.append(measured_targets(xy_raw))
    pins = [f"{a}@{b}={low[b]:g}" for a, b in ((names[0], names[1]), (names[1], names[0]))]
    run.compgw("fit", xy_raw, "-c", gw, "--pitch-line", pins[0], "--pitch-line", pins[1])
    return WorkflowResult(yaml.safe_load(gw.read_text()), merge_targets(*targets),
                          [f"plain: {len(raws)} runs fitted jointly, XY 9 x 7"])


def commission(run: MachineRun) -> WorkflowResult:
    """`compgw commission`: one command, the leads from the machine's data sheet
    (machine.json), the Δa or temperature sensors when there are, ``TOLERANCE_UM``;
    started cold."""
    data = run.base_config()
    data["status"]["remote_control"] = True  # it reloads the gateway through the status unit
    kind = thermal_setup(run, data)
    run.use(data)
    run.cool_down()
    leads = [f"{a}={info['lead_mm']:g}" for a, info in run.machine["axes"].items()
             if info.get("lead_mm") and (COMMISSION_AXES is None or a in COMMISSION_AXES)]
    args = ["commission", "-c", run.work / "gw.yaml", "--gateway", run.gateway,
            "--tolerance-um", f"{TOLERANCE_UM:g}", "--no-progress"]  # fmt: skip
    technician: Technician | Gauge | None = None
    if reads_later():
        laser_dir = run.work / "laser"
        laser_dir.mkdir(exist_ok=True)
        laser = (f"capture:{ROOT / 'config' / 'capture-generic.yaml'}:{laser_dir}"
                 if LASER_KIND == "capture" else f"recording:{laser_dir}:um")  # fmt: skip
        args += ["--laser", laser, "--dwell-s", f"{RECORDING_DWELL_S:g}", "--wait-start"]
        technician = Technician("127.0.0.1", run.sim_port, 20, run.work / "recordings",
                                LASER_KIND.removeprefix("recording-"))  # fmt: skip
    elif LASER_KIND == "manual":  # a gauge read by eye, to 0.1 µm, typed at the prompt
        args += ["--laser", "manual:deviation"]
        sim = yaml.safe_load((run.dir / "sim.yaml").read_text())["sim"]
        channels = sim["instruments"]["laser"].get("axes") or list(sim["axes"])
        technician = Gauge("127.0.0.1", run.sim_port, 20, channels)
    else:
        args += ["--laser", run.laser_bridge or run.instrument(20)]
    if COMMISSION_AXES is not None:
        args += ["--axes", ",".join(COMMISSION_AXES)]
    else:
        args += ["--xy-device", run.instrument(21)]
    if leads:
        args += ["--lead-mm", ",".join(leads)]
    if BUDGET_VS_MANUAL is not None or BUDGET_VS_PLAIN is not None:
        factor = BUDGET_VS_PLAIN if BUDGET_VS_PLAIN is not None else BUDGET_VS_MANUAL
        run.manual_s = (plain_machine_s if BUDGET_VS_PLAIN is not None
                        else manual_machine_s)(run)  # fmt: skip
        budget_h = factor * run.manual_s / 3600  # type: ignore[operator]
        args += ["--budget-h", f"{budget_h:.3f}"]
    if kind == "delta_a":
        args += ["--delta-a", run.instrument(10, 1)]
    elif kind == "temperature":  # the sensors' unit; registers from the thermal sources
        unit = next(s["unit"] for s in data["thermal_sources"].values()
                    if s.get("kind") == "temperature")  # fmt: skip
        args += ["--temperature", run.instrument(unit)]
    notes = []
    try:
        if technician is None:
            run.compgw(*args)
        else:
            with technician:
                run.compgw(*args, technician=technician)
    except CommandFailed as exc:  # exit 1: tolerance not met (the evaluator judges anyway)
        notes.append(str(exc))
    out = run.work / "commission"
    if not (out / "summary.json").exists():
        raise CommandFailed(f"commission ended without a summary: {' | '.join(notes)}")
    summary = json.loads((out / "summary.json").read_text())
    run.machine_s = summary["machine_h"] * 3600
    notes.append(f"commission: {summary['outcome']}, {summary['machine_h']:.2f} h, "
                 f"{len(summary['rounds'])} round(s)")  # fmt: skip
    targets = merge_targets(*(measured_targets(raw) for raw in sorted((out / "raw").glob(
        "*.csv"))))  # fmt: skip
    return WorkflowResult(yaml.safe_load((run.work / "gw.yaml").read_text()), targets, notes,
                          summary["machine_h"] * 3600)  # fmt: skip


Workflow = Callable[[MachineRun], WorkflowResult]
WORKFLOWS: dict[str, Workflow] = {"manual": manual, "plain": plain, "commission": commission}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("machine", type=Path, help="a machine directory (machine.json, ...)")
    parser.add_argument("--workflow", choices=sorted(WORKFLOWS), default="manual")
    parser.add_argument("--work", type=Path, help="work directory (default: DIR/work)")
    args = parser.parse_args()
    work = args.work or args.machine / "work"
    with contextlib.suppress(FileNotFoundError):
        shutil.rmtree(work)
    run = MachineRun.start(args.machine, work)
    try:
        result = WORKFLOWS[args.workflow](run)
    finally:
        run.stop()
    print("\n".join(run.commands))
    print("\n".join(result.notes))
    print(run.write_config("gw.final.yaml", result.config))
    return 0


if __name__ == "__main__":
    sys.exit(main())
