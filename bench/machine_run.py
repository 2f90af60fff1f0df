"""The machine a workflow works on: its sim, the wire and its gateway, in lock-step.

:class:`MachineRun` starts ``compgw sim`` (free port), the wire (bench/lockstep.py) when the
gateway polls thermal sources, and ``compgw run``; it runs `compgw` commands as a user
would, writes the gateway's config and reloads it, and lets the machine cool on the sim's
clock. How the sim's laser is reached (``laser_kind``: its Modbus registers, the bridge
protocol too, or a recording of one axis) is given when it starts. Used by
bench/workflows.py (the workflows) and bench/accuracy.py (the judge).
"""

from __future__ import annotations

import contextlib
import copy
import json
import os
import re
import signal
import subprocess
import sys
import threading
import time
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
#: how long compgw's requests wait for their answer here (s): a write waits in the wire
#: until the gateway has polled its sensors (bench/lockstep.py SYNC_TIMEOUT_S), seconds on
#: two loaded cores, where compgw's default 2 s aborted runs
REQUEST_TIMEOUT_S = 30.0
#: how often the gateway polls its thermal sources here (s): a write through the wire waits
#: for two polls (bench/lockstep.py), the figures do not depend on it
SOURCE_POLL_S = 0.002


#: the checkout this bench is in
ROOT = Path(__file__).resolve().parents[1]


def child_env() -> dict[str, str]:
    """The children's environment: str hashing (set order) the same in every run, one BLAS
    thread (the sums in the same order whatever ``--jobs``; set it to change it), and this
    checkout's code first on the path. A second checkout (a git worktree) sharing the
    first's virtualenv otherwise ran the first's code through its editable install: a
    bench of one commit measured whatever the other checkout held as it spawned."""
    threads = {k: "1" for k in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")}
    path = os.pathsep.join(p for p in (str(ROOT), os.environ.get("PYTHONPATH", "")) if p)
    return {**threads, **os.environ, "PYTHONHASHSEED": "0", "PYTHONPATH": path}


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
    #: the sim's laser on the bridge protocol (``laser_kind`` "bridge"), as --laser gives it
    laser_bridge: str | None = None
    #: how the sim's laser is reached besides its registers: "modbus" (only them), "bridge"
    #: (the bridge protocol too), "recording-rtx|csv" or "capture" (a recording of
    #: ``recorded_axis``, the sim's first axis by default)
    laser_kind: str = "modbus"
    recorded_axis: str | None = None

    # -- processes ----------------------------------------------------------------------------
    @classmethod
    def start(cls, machine_dir: Path, work: Path, laser_kind: str = "modbus",
              recorded_axis: str | None = None) -> MachineRun:  # fmt: skip
        """Start ``compgw sim`` (free port), the wire when the gateway has thermal sources,
        and ``compgw run`` with the uncalibrated config (``laser_kind``, ``recorded_axis``:
        the fields of those names)."""
        machine_dir, work = machine_dir.resolve(), work.resolve()
        machine = json.loads((machine_dir / "machine.json").read_text())
        work.mkdir(parents=True, exist_ok=True)
        run = cls(machine_dir, work, machine, laser_kind=laser_kind,
                  recorded_axis=recorded_axis)  # fmt: skip
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
        kind = self.laser_kind
        if kind == "bridge":  # the same laser on the bridge line protocol too
            data["sim"]["instruments"]["laser"]["bridge"] = {"host": "127.0.0.1", "port": 0}
        if kind.startswith("recording") or kind == "capture":  # ... recording one axis
            axis = self.recorded_axis or next(iter(data["sim"]["axes"]))
            data["sim"]["instruments"]["laser"]["recording"] = {
                "dir": str(self.work / "recordings"),
                "format": "csv" if kind == "capture" else kind.split("-")[1],
                "axis": axis, "rate_hz": 500, "unit": "um", "idle_time_scale": 1000.0}
        path = self.dir / "sim.run.yaml"  # beside sim.yaml: truth/ paths stay valid
        path.write_text(yaml.safe_dump(data, sort_keys=False))
        self._sim = subprocess.Popen([*compgw_argv(), "sim", "-c", str(path)], text=True,
                                     stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                                     env=child_env())  # fmt: skip
        lines = _Lines(self._sim.stdout)
        if kind == "bridge":
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
    def base_config(self, sensors: bool = False) -> dict[str, Any]:
        """The machine's gateway.yaml on this run's ports (uncalibrated): no compensation
        at all, or with ``sensors`` the axes' thermal settings on the sensors mounted on
        their screws, as the machine's gateway.yaml points them."""
        data = yaml.safe_load((self.dir / "gateway.yaml").read_text())
        # the lock-step (bench/lockstep.py) gives the gateway the machine's clock its own way
        data.pop("machine_clock", None)
        if not sensors:
            for axis in data["axes"].values():
                (axis.get("compensation") or {}).pop("thermal", None)
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


def main() -> int:
    """Start a generated machine's sim and gateway in lock-step, print where they answer,
    and stop them after Enter or ``--seconds``: the machine a workflow sees, by hand."""
    import argparse
    import select

    parser = argparse.ArgumentParser(description=main.__doc__)
    parser.add_argument("machine", type=Path, help="a `compgw sim --random-machine` directory")
    parser.add_argument("--work", type=Path, help="working directory (default: DIR/work)")
    parser.add_argument("--seconds", type=float, default=600.0, help="stop after (600)")
    args = parser.parse_args()
    run = MachineRun.start(args.machine, args.work or args.machine / "work")
    try:
        print(f"sim (instruments, clock) on 127.0.0.1:{run.sim_port}; gateway on "
              f"127.0.0.1:{run.gateway_port}; Enter stops", flush=True)  # fmt: skip
        select.select([sys.stdin], [], [], args.seconds)
    finally:
        run.stop()
    return 0


if __name__ == "__main__":
    sys.exit(main())
