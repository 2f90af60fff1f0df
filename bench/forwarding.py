"""Gateway benchmark: latency (p50/p99) and transactions/s through `compgw run` vs direct
to `compgw sim`, in the same run, every party its own process.

Processes (all on 127.0.0.1, every TCP port bound as 0 and read back from the logs):

- sim A: ``compgw sim``: 8 drives (units 1..8) on Modbus TCP, and on RTU on a pty it makes
  itself (``rtu.port: pty``: a kernel terminal, no bridge thread or process);
- sim B: ``compgw sim``: the same 8 drives, RTU only on its own pty (the direct RTU line);
  the drives of both keep t3.5 of silence before they reply (``--drive-reply t35``), as a
  Modbus slave that finds the end of a request by silence;
- gateway: ``compgw run``: upstream TCP, and upstream RTU on a pty made by this process
  (its master end is inherited by each RTU load generator); axes T1..T8 (upstream units
  1..8) each on its own TCP bus (8 connections to sim A: 8 buses in parallel), axes R1..R8
  (upstream 11..18) on one RTU bus on sim A's pty (a single RS-485 line: transactions are
  serialised);
- load generators: one short-lived process per measurement (``fwd_load.py``),
  1 or 8 masters as asyncio tasks, each master on its own TCP connection and its own
  unit (drive); on an RTU line the masters share the one line (an asyncio lock = ideal
  arbitration on a single-master line).

The load is raw Modbus (MBAP over asyncio streams; RTU frames on the pty fd with
``loop.add_reader``), not pymodbus clients: a pymodbus client spends ~100-200 µs of its
own per request, which would be counted on both sides and hide the gateway's cost. Every
reply is checked (transaction id, function code, not an exception); errors are counted.

Cases (registers of the example drive profile; the gateway config intercepts them):

- ``FC03x10@6200``: read 10 holding registers 0x6200..0x6209; covers the target pair
  0x6201/02, so the gateway rewrites those words with the shadow of what was written;
- ``FC16x2@6204``: write 2 plain parameter registers 0x6204/05 (pass-through, byte-exact);
- ``FC03x2@602A`` (extra): the feedback pair, answered through the inverse chain (pitch
  table of config/tables/x_pitch.csv, after a compensated move: ``applied`` is set);
- ``FC16x2@6201`` (extra): a target write, corrected through the chain; the gateway reads
  the drive's status (homed bit) first, so this is 2 drive transactions for 1 request.

Timing: each master measures request-sent → reply-complete with ``perf_counter``; direct
and gateway runs alternate (direct, gateway, gateway, direct; half the requests each) so
slow drift of the shared machine hits both. tx/s = requests / wall time of the slowest
master. CPU per transaction of the gateway and sim processes comes from
/proc/PID/schedstat. RTU: a compliant master keeps t3.5 (1.75 ms above 19200 baud) of
silence after a reply before it sends, as think time (not in its latency). Rows ``rtu``:
the same RTU master program on the direct line and on the gateway's RTU server. Rows
``tcp>rtu``: a TCP master, which sends at once, so the gateway keeps the line's t3.5 inside
the transaction, as a gateway must. A pty has no baud rate, so no wire time is included
anywhere (FC03x10 at 115200 is ~2.9 ms of wire).

Run:  .venv/bin/python bench/forwarding.py            (full: 2000 requests per master, ~6 min)
      .venv/bin/python bench/forwarding.py --quick    (300 per master, ~1 min)
      options: --only tcp|rtu, --requests N, --time-cap S, --profile DIR (py-spy on the
      gateway, separate runs after the table), --what-if (a second gateway process whose RTU
      line's t3.5 is patched at start-up to the exact 0.30 ms at 115200, then to 0: how
      much of "RTU added" is the silence rule; diagnostic, not the product),
      --reference/--no-reference (a minimal asyncio.Protocol forwarder and a minimal RTU
      relay, no interception, and socat byte pumps when socat is installed, measured the
      same way: the floors for CPython and for C on this machine; on by default in the
      full run), --tls (also rows through the gateway's Modbus/TCP Security listener: TLS
      1.3, a client certificate whose role is checked at every request; direct stays plain
      TCP, and the plain TCP rows of the same run show the gateway without TLS).
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import os
import re
import shutil
import signal
import struct
import subprocess
import sys
import tempfile
import threading
import time
import tty
from collections.abc import Iterator
from pathlib import Path

from fwd_load import (
    CASES,
    PIN_GATEWAY,
    PIN_WORLD,
    RTU_UPSTREAM_OFFSET,
    UNITS,
    Case,
)
from fwd_report import HEADER, Row, Side, format_row, summarize_folded, verdicts

ROOT = Path(__file__).resolve().parent.parent
BENCH = ROOT / "bench"
TABLES = ROOT / "config" / "tables"
#: rows with the drives on the RTU line: an RTU master on the gateway's RTU server (the same
#: master program as direct, t3.5 think time included), and a TCP master (no think time)
RTU_TRANSPORTS = ["rtu", "tcp>rtu"]
BAUD = 115200
T35_S = 0.00175  # Modbus: fixed 1.75 ms above 19200 baud

# -- the orchestrator ------------------------------------------------------------------------


class Proc:
    """A child process whose combined output is drained by a thread (and kept)."""

    def __init__(self, name: str, argv: list[str], cwd: Path = ROOT,
                 cpus: set[int] | None = None) -> None:
        self.name = name
        env = {**os.environ, "PYTHONUNBUFFERED": "1"}
        self.p = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                                  text=True, cwd=cwd, env=env, start_new_session=True)
        if cpus is not None:
            os.sched_setaffinity(self.p.pid, cpus)
        self.lines: list[str] = []
        self._cond = threading.Condition()
        threading.Thread(target=self._drain, daemon=True).start()

    def _drain(self) -> None:
        assert self.p.stdout is not None
        for line in self.p.stdout:
            with self._cond:
                self.lines.append(line.rstrip("\n"))
                self._cond.notify_all()
        with self._cond:
            self._cond.notify_all()

    def wait_for(self, pattern: str, timeout_s: float = 30.0) -> re.Match[str]:
        deadline = time.monotonic() + timeout_s
        seen = 0
        with self._cond:
            while True:
                for line in self.lines[seen:]:
                    if m := re.search(pattern, line):
                        return m
                seen = len(self.lines)
                if self.p.poll() is not None and seen == len(self.lines):
                    raise RuntimeError(f"{self.name} exited {self.p.returncode}:\n"
                                       + "\n".join(self.lines[-20:]))
                left = deadline - time.monotonic()
                if left <= 0:
                    raise RuntimeError(f"{self.name}: no line matching {pattern!r}:\n"
                                       + "\n".join(self.lines[-20:]))
                self._cond.wait(min(left, 0.2))

    def cpu_s(self) -> float:
        """CPU time of the process and of its live children (all threads; a forking
        forwarder such as socat serves each connection in a child), from schedstat."""
        total = 0.0
        for proc in Path("/proc").iterdir():
            if not proc.name.isdigit():
                continue
            try:  # field 5 of stat is the process group: ours (start_new_session)
                fields = (proc / "stat").read_text().rsplit(")", 1)[1].split()
                if int(fields[2]) != self.p.pid:
                    continue
                total += int((proc / "schedstat").read_text().split()[0]) / 1e9
                if int(proc.name) == self.p.pid:  # children that ended (cutime + cstime)
                    total += (int(fields[13]) + int(fields[14])) / os.sysconf("SC_CLK_TCK")
            except (OSError, ValueError, IndexError):
                continue
        return total if total else float("nan")

    def stop(self) -> None:
        if self.p.poll() is None:
            self.p.send_signal(signal.SIGTERM)
            try:
                self.p.wait(timeout=20)
            except subprocess.TimeoutExpired:
                self.p.kill()
                self.p.wait()


# `compgw sim -c F` and `compgw run -c F` are thin wrappers over these calls (`app.run`
# picks uvloop when installed; older trees given with --baseline have only `serve`); calling
# them directly keeps the bench independent of the other subcommands' imports.
_SIM = "import sys; from sim.server import main; sys.exit(main(sys.argv[1]))"
_RUN = ("import asyncio, logging, sys; {patch}"
        "logging.basicConfig(level=logging.INFO, format='%(levelname)s %(name)s: %(message)s'); "
        "from gateway import app; "
        "sys.exit(app.run(sys.argv[1]) if hasattr(app, 'run') else "
        "asyncio.run(app.serve(sys.argv[1])))")


def compgw(command: str, config: Path, patch: str = "") -> list[str]:
    code = _SIM if command == "sim" else _RUN.format(patch=patch)
    return [sys.executable, "-c", code, str(config)]


def sim_config(tcp: bool, reply_silence_s: float = T35_S) -> dict:
    regs = {"memory": [{"address": 0x6200, "count": 16}]}
    sim: dict = {
        "seed": 1,
        "time_scale": 0,
        "axes": {f"A{u}": {"unit": u, "travel_mm": [0, 800], "registers": regs}
                 for u in UNITS},
    }
    if tcp:
        sim["tcp"] = {"host": "127.0.0.1", "port": 0}
    sim["rtu"] = {"port": "pty", "baudrate": BAUD, "parity": "N", "stopbits": 1,
                  "reply_silence_s": reply_silence_s}
    return {"sim": sim}


def gateway_config(sim_port: int, rtu_port: str, upstream_rtu: str,
                   tls: dict | None = None) -> dict:
    def axis(bus: str, unit: int, upstream: int) -> dict:
        return {
            "bus": bus, "unit": unit, "upstream_unit": upstream, "pulse_mm": 0.001,
            "travel_mm": [0, 800], "home_direction": 1,
            "registers": {
                "target": {"address": 0x6201, "words": 2, "order": "hi_lo"},
                "feedback": {"address": 0x602A, "table": "holding", "order": "hi_lo"},
                "status": {"address": 0x1003, "homed_bit": 6},
                "trigger": {"address": 0x6002, "value": 0x10},
            },
            "compensation": {
                "pitch": {"file": str(TABLES / "x_pitch.csv"), "interpolation": "smooth"},
                "max_correction_mm": 0.2,
            },
        }

    buses: dict = {f"t{u}": {"tcp": {"host": "127.0.0.1", "port": sim_port},
                             "timeout_s": 0.2, "retries": 1} for u in UNITS}
    buses["line"] = {"rtu": {"port": rtu_port, "baudrate": BAUD, "parity": "N", "stopbits": 1},
                     "timeout_s": 0.2, "retries": 1}
    axes = {f"T{u}": axis(f"t{u}", u, u) for u in UNITS}
    axes |= {f"R{u}": axis("line", u, RTU_UPSTREAM_OFFSET + u) for u in UNITS}
    config = {
        "upstream": {"tcp": {"host": "127.0.0.1", "port": 0, "max_connections": 64},
                     "rtu": {"port": upstream_rtu, "baudrate": BAUD, "parity": "N",
                             "stopbits": 1}},
        "buses": buses,
        "axes": axes,
        "status": {"upstream_unit": 247},
    }
    if tls is not None:  # a role that may do all on the TCP axes: checked at every request
        config["upstream"]["tls"] = {
            "host": "127.0.0.1", "port": 0, "max_connections": 64, "cert": tls["server"],
            "key": tls["server_key"], "ca": tls["ca"],
            "roles": {"operator": {"units": list(UNITS), "read": True, "write": True}}}
    return config


def make_certificates(directory: Path) -> dict:
    """A CA, the gateway's certificate and an `operator` client's (tests/tls_certs.py)."""
    sys.path.insert(0, str(ROOT))
    from tests.tls_certs import issue, make_ca

    ca = make_ca(directory)
    server = issue(directory, "server", ca, server=True)
    client = issue(directory, "operator", ca, role="operator")
    return {"ca": str(ca.cert_path), "server": str(server.cert_path),
            "server_key": str(server.key_path), "cert": str(client.cert_path),
            "key": str(client.key_path)}


def _write_yaml(path: Path, data: dict) -> Path:
    import yaml

    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


def run_load(spec: dict) -> dict:
    out = subprocess.run([sys.executable, str(BENCH / "fwd_load.py"), json.dumps(spec)],
                         capture_output=True, text=True, cwd=ROOT, timeout=spec["time_cap"] + 60,
                         pass_fds=(spec["fd"],) if "fd" in spec else ())
    if out.returncode != 0:
        raise RuntimeError(f"load generator failed:\n{out.stderr[-2000:]}")
    return json.loads(out.stdout)


class Bench:
    def __init__(self, args: argparse.Namespace) -> None:
        self.args = args
        self.tmp = Path(tempfile.mkdtemp(prefix="compgw-bench-"))
        self.procs: dict[str, Proc] = {}
        self.keep_fds: list[int] = []
        self.reply_s = T35_S if args.drive_reply == "t35" else 0.0

    # ---------------------------------------------------------------- set-up
    def start(self) -> None:
        # Every RTU line is one pseudo-terminal, no bridge: the sims open theirs (`port:
        # pty`) and print the path; the gateway's upstream line is made here and its
        # master end handed to each load generator.
        self.master_fd, upstream_fd = os.openpty()
        tty.setraw(upstream_fd)
        self.keep_fds = [self.master_fd, upstream_fd]
        self.upstream_line = os.ttyname(upstream_fd)  # the gateway's RTU server
        world = PIN_WORLD if self.args.pin else None
        sim_a = Proc("sim A", compgw("sim", _write_yaml(
            self.tmp / "sim-a.yaml", sim_config(True, self.reply_s))), cpus=world)
        self.procs["sim"] = sim_a
        sim_b = Proc("sim B", compgw("sim", _write_yaml(
            self.tmp / "sim-b.yaml", sim_config(False, self.reply_s))), cpus=world)
        self.procs["simB"] = sim_b
        self.sim_port = int(sim_a.wait_for(r"modbus tcp on 127\.0\.0\.1:(\d+)").group(1))
        self.gw_line = sim_a.wait_for(r"modbus rtu on (\S+)").group(1)  # the gateway's bus
        self.direct_line = sim_b.wait_for(r"modbus rtu on (\S+)").group(1)  # direct master
        self.tls = make_certificates(self.tmp) if self.args.tls else None
        self.gw_cfg = _write_yaml(self.tmp / "gw.yaml", gateway_config(
            self.sim_port, self.gw_line, self.upstream_line, self.tls))
        self.gw_port = self.start_gateway("gw", self.gw_cfg)
        if self.tls is not None:
            self.tls_port = int(self.procs["gw"].wait_for(
                r"\(TLS\) server listening on 127\.0\.0\.1:(\d+)").group(1))

    def start_gateway(self, name: str, cfg: Path, t35_s: float | None = None,
                      root: Path = ROOT) -> int:
        patch = "" if t35_s is None else (  # diagnostic: the RTU line's t3.5 replaced
            f"import gateway.modbus.serialline as s; s.t35_s = lambda *a, **k: {t35_s!r}; ")
        argv = compgw("run", cfg, patch)
        cpus = PIN_GATEWAY if self.args.pin else None
        proc = Proc(name, argv, cwd=root, cpus=cpus)  # `import gateway` resolves in root first
        self.procs[name] = proc
        port = int(proc.wait_for(r"listening on 127\.0\.0\.1:(\d+)").group(1))
        self.warm_up(port)
        return port

    def warm_up(self, port: int) -> None:
        """A compensated move on every axis (target + trigger), so feedback reads go
        through the inverse chain; check that the gateway answers every route."""

        async def go() -> None:
            r, w = await asyncio.open_connection("127.0.0.1", port)
            tid = 0
            upstream = [*UNITS, *(RTU_UPSTREAM_OFFSET + u for u in UNITS)]
            for unit in upstream:
                for pdu in (CASES[3].pdu, struct.pack(">BHH", 6, 0x6002, 0x10),
                            CASES[0].pdu, CASES[2].pdu):
                    tid += 1
                    w.write(struct.pack(">HHHB", tid, 0, len(pdu) + 1, unit) + pdu)
                    head = await r.readexactly(7)
                    body = await r.readexactly(struct.unpack(">H", head[4:6])[0] - 1)
                    if body[0] & 0x80:
                        raise RuntimeError(f"warm-up: unit {unit} PDU {pdu.hex()} answered "
                                           f"exception {body.hex()}")
            w.close()

        asyncio.run(asyncio.wait_for(go(), 30))

    def stop(self) -> None:
        for name in reversed(list(self.procs)):
            self.procs[name].stop()
        for fd in self.keep_fds:
            os.close(fd)
        shutil.rmtree(self.tmp, ignore_errors=True)

    # ---------------------------------------------------------------- measuring
    def measure(self, spec: dict, watch: tuple[str, ...]) -> tuple[dict, dict[str, float]]:
        before = {k: self.procs[k].cpu_s() for k in watch}
        result = run_load(spec)
        return result, {k: self.procs[k].cpu_s() - before[k] for k in watch}

    def pair(self, transport: str, case: Case, masters: int, requests: int,
             gw_port: int | None = None, gw_name: str = "gw",
             upstream_offset: int = RTU_UPSTREAM_OFFSET) -> Row:
        a = self.args
        units = list(UNITS[:masters])
        common = {"pdu": case.pdu.hex(), "warmup": a.warmup, "time_cap": a.time_cap / 2,
                  "pin": a.pin}
        if transport in ("tcp", "tls"):
            direct = {**common, "kind": "tcp", "host": "127.0.0.1", "port": self.sim_port,
                      "units": units}
            through = {**common, "kind": "tcp", "host": "127.0.0.1", "units": units,
                       "port": gw_port or self.gw_port}
            if transport == "tls":  # the gateway's TLS listener; direct: plain TCP, as ever
                through |= {"port": self.tls_port, "tls": self.tls}
            d_watch, g_watch = ("sim",), ("sim", gw_name)
        else:  # the drives on the RTU line; direct: a master on that line (sim B's)
            direct = {**common, "kind": "rtu", "device": self.direct_line, "units": units,
                      "gap_s": T35_S}
            upstream_units = [upstream_offset + u for u in units]
            if transport == "rtu":  # the same RTU master program, on the gateway's RTU server
                through = {**common, "kind": "rtu", "fd": self.master_fd,
                           "units": upstream_units, "gap_s": T35_S}
            else:  # "tcp>rtu": a TCP master, which sends at once: no t3.5 think time
                through = {**common, "kind": "tcp", "host": "127.0.0.1",
                           "port": gw_port or self.gw_port, "units": upstream_units}
            d_watch, g_watch = ("simB",), ("sim", gw_name)
        d, g = Side(), Side()
        half = max(requests // 2, 1)
        for side, spec, watch in ((d, direct, d_watch), (g, through, g_watch),
                                  (g, through, g_watch), (d, direct, d_watch)):
            side.add(*self.measure({**spec, "requests": half}, watch))
        return Row(transport, case, masters, d, g)


    def run_rows(self, out: list[Row], transport: str, cases: tuple[Case, ...] | list[Case],
                 masters: tuple[int, ...], requests: int, *, rtu8: int | None = None,
                 note: str = "", **pair_kw: object) -> None:
        """Measure every case with each number of masters, print and keep each row (``rtu8``:
        requests per master with 8 masters on an RTU line)."""
        for case in cases:
            for m in masters:
                n = rtu8 if rtu8 and m == 8 and transport in RTU_TRANSPORTS else requests
                row = self.pair(transport, case, m, n, **pair_kw)  # type: ignore[arg-type]
                row.note = note
                out.append(row)
                print(format_row(row), flush=True)

    @contextlib.contextmanager
    def main_gateway_stopped(self) -> Iterator[None]:
        """The main gateway SIGSTOPped meanwhile: another process uses its RTU lines."""
        self.procs["gw"].p.send_signal(signal.SIGSTOP)
        try:
            yield
        finally:
            self.procs["gw"].p.send_signal(signal.SIGCONT)

    def profile(self, out: Path, transport: str, case: Case, masters: int,
                requests: int) -> Path | None:
        """Gateway side of one case again, with py-spy attached to the gateway process
        (non-blocking sampling, idle samples dropped: where its CPU goes). Not in the table:
        the sampler competes for the same cores."""
        spy = shutil.which("py-spy", path=_venv_bin())
        if spy is None:
            print("profile: py-spy not found (.venv/bin/pip install py-spy)")
            return None
        out.mkdir(parents=True, exist_ok=True)
        dest = out / f"gateway-{transport}-{case.name.replace('@', '-')}-x{masters}.folded"
        units = list(UNITS[:masters]) if transport == "tcp" \
            else [RTU_UPSTREAM_OFFSET + u for u in UNITS[:masters]]
        spec = {"pdu": case.pdu.hex(), "warmup": self.args.warmup, "requests": requests,
                "time_cap": self.args.time_cap, "kind": "tcp", "host": "127.0.0.1",
                "port": self.gw_port, "units": units}
        rec = subprocess.Popen([spy, "record", "--pid", str(self.procs["gw"].p.pid),
                                "--nonblocking", "--rate", "1000", "--format", "raw",
                                "-o", str(dest)], stdout=subprocess.DEVNULL,
                               stderr=subprocess.PIPE, text=True)
        time.sleep(1.0)  # attached
        try:
            run_load(spec)
        finally:
            rec.send_signal(signal.SIGINT)
            _, err = rec.communicate(timeout=30)
        if not dest.exists():
            print(f"profile: py-spy wrote nothing: {err[-500:]}")
            return None
        return dest


def _venv_bin() -> str:
    return os.pathsep.join([str(ROOT / ".venv" / "bin"), os.environ.get("PATH", "")])


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="300 requests per master, issue cases")
    ap.add_argument("--requests", type=int, help="requests per master (default 2000)")
    ap.add_argument("--rtu8-requests", type=int,
                    help="requests per master on the shared RTU line with 8 masters "
                         "(default requests/4: the line serialises them)")
    ap.add_argument("--time-cap", type=float, default=60.0, help="seconds per measurement")
    ap.add_argument("--warmup", type=int, default=20, help="untimed requests per master")
    ap.add_argument("--only", choices=("tcp", "rtu"),
                    help="tcp: TCP master and drives; rtu: the drives on the RTU line, with an "
                         "RTU master (rtu) and a TCP master (tcp>rtu) on the gateway")
    ap.add_argument("--extra", action=argparse.BooleanOptionalAction, default=None,
                    help="also the feedback-read and target-write cases (default: full run)")
    ap.add_argument("--what-if", action="store_true",
                    help="also: a second gateway whose RTU line has `t35: exact` (3.5 "
                         f"characters at {BAUD} baud), and one with no silence (diagnostic)")
    ap.add_argument("--profile", metavar="DIR",
                    help="run the gateway under py-spy (raw folded stacks to DIR)")
    ap.add_argument("--reference", action=argparse.BooleanOptionalAction, default=None,
                    help="also a minimal asyncio.Protocol forwarder (no interception) as a "
                         "floor for CPython on this machine (default: full run)")
    ap.add_argument("--baseline", metavar="DIR",
                    help="also measure the gateway of another source tree (e.g. a `git "
                         "archive` of an older commit), in the same run, for before/after")
    ap.add_argument("--pin", action="store_true",
                    help="diagnostic: the load generator and the sims on CPU 0, the gateway "
                         "on CPU 1 (a gateway on its own box), in both the direct and the "
                         "gateway runs; not the issue's measurement")
    ap.add_argument("--drive-reply", choices=("t35", "at-once"), default="t35",
                    help="when the RTU drives reply: after t3.5 (1.75 ms) of silence, as a "
                         "Modbus slave that finds the request's end by silence (default), or "
                         "at once (faster than a real drive; the gateway's own t3.5 before "
                         "its RTU reply is then all added latency)")
    ap.add_argument("--tls", action="store_true",
                    help="also rows through the gateway's Modbus/TCP Security listener (TLS, "
                         "a client certificate with a role), direct still plain TCP")
    a = ap.parse_args(argv)
    requests = a.requests or (300 if a.quick else 2000)
    rtu8 = a.rtu8_requests or max(requests // 4, 50)
    extra = (not a.quick) if a.extra is None else a.extra
    cases = [c for c in CASES if extra or not c.extra]
    transports = {"tcp": ["tcp"], "rtu": RTU_TRANSPORTS}.get(a.only, ["tcp", *RTU_TRANSPORTS])
    bench = Bench(a)
    rows: list[Row] = []
    t_start = time.monotonic()
    try:
        bench.start()
        print(f"sim tcp :{bench.sim_port}, gateway tcp :{bench.gw_port}, gateway RTU line "
              f"{bench.gw_line}, direct RTU line {bench.direct_line}; {os.cpu_count()} CPUs; "
              f"{requests} requests/master ({rtu8} on RTU x8)", flush=True)
        print(HEADER, flush=True)
        both = (1, 8)
        for transport in transports:
            bench.run_rows(rows, transport, cases, both, requests, rtu8=rtu8)
        if a.tls and "tcp" in transports:  # compare with the tcp rows just above
            bench.run_rows(rows, "tls", cases, both, requests,
                           note="Modbus/TCP Security: TLS 1.3, client certificate, role check")
        if a.baseline:  # another gateway tree (e.g. `git archive` of an older commit)
            with bench.main_gateway_stopped():  # it shares the RTU lines
                port = bench.start_gateway("gw-base", bench.gw_cfg, root=Path(a.baseline))
                for transport in transports:
                    bench.run_rows(rows, transport, cases[:2], both, requests, rtu8=rtu8,
                                   note=f"baseline gateway from {a.baseline}",
                                   gw_port=port, gw_name="gw-base")
                bench.procs.pop("gw-base").stop()
        reference = (not a.quick) if a.reference is None else a.reference
        pin = PIN_GATEWAY if a.pin else None
        socat = shutil.which("socat")
        if reference and "tcp" in transports:
            ref = bench.procs["ref"] = Proc("ref", [
                sys.executable, str(BENCH / "fwd_reference.py"), "--proxy", str(bench.sim_port)],
                cpus=pin)  # fmt: skip
            port = int(ref.wait_for(r"reference proxy listening on 127\.0\.0\.1:(\d+)")
                       .group(1))
            bench.run_rows(rows, "tcp", cases[:2], both, requests, gw_port=port, gw_name="ref",
                           note="reference forwarder, not the gateway")
            bench.procs.pop("ref").stop()
            if socat:  # a C forwarder, a process per connection: what the machine allows
                proc = bench.procs["socat-tcp"] = Proc("socat-tcp", [
                    socat, "-d", "-d", "TCP-LISTEN:0,bind=127.0.0.1,reuseaddr,fork",
                    f"TCP:127.0.0.1:{bench.sim_port}"], cpus=pin)
                port = int(proc.wait_for(r"listening on .*127\.0\.0\.1:(\d+)").group(1))
                bench.run_rows(rows, "tcp", cases[:2], both, requests, gw_port=port,
                               gw_name="socat-tcp",
                               note="socat byte pump (C, a process per connection)")
                bench.procs.pop("socat-tcp").stop()
        if reference and "rtu" in transports:
            with bench.main_gateway_stopped():  # the forwarders use its RTU lines
                relay = bench.procs["relay"] = Proc("relay", [
                    sys.executable, str(BENCH / "fwd_reference.py"), "--relay",
                    bench.upstream_line, bench.gw_line], cpus=pin)
                relay.wait_for(r"reference relay on")
                bench.run_rows(rows, "rtu", cases[:2], (1,), requests, gw_name="relay",
                               note="reference RTU relay, not the gateway")
                bench.procs.pop("relay").stop()
                if socat:  # a byte pump in C: what two pty hops and a process cost here
                    bench.procs["socat"] = Proc("socat", [
                        socat, "-b", "4096", f"FILE:{bench.upstream_line},raw,echo=0",
                        f"FILE:{bench.gw_line},raw,echo=0"], cpus=pin)
                    time.sleep(0.5)  # socat prints nothing when it is up
                    bench.run_rows(rows, "rtu", cases[:2], (1,), requests, gw_name="socat",
                                   upstream_offset=0,  # no unit mapping: the drives' units
                                   note="socat byte pump (C), not the gateway")
                    bench.procs.pop("socat").stop()
        if a.what_if and "tcp>rtu" in transports:
            exact = gateway_config(bench.sim_port, bench.gw_line, bench.upstream_line)
            exact["buses"]["line"]["rtu"]["t35"] = "exact"  # the product's option
            exact_cfg = _write_yaml(bench.tmp / "gw-exact.yaml", exact)
            for t35, label in ((3.5 * 10 / BAUD, "config rtu.t35: exact at 115200 8N1"),
                               (0.0, "none, patched in: diagnostic")):
                with bench.main_gateway_stopped():  # or both would read the drives' replies
                    if t35:
                        port = bench.start_gateway("gw-t35", exact_cfg)
                    else:
                        port = bench.start_gateway("gw-t35", bench.gw_cfg, t35_s=t35)
                    bench.run_rows(rows, "tcp>rtu", cases[:2], (1,), requests, gw_port=port,
                                   gw_name="gw-t35",
                                   note=f"what-if: gateway t3.5 = {t35 * 1e3:.2f} ms ({label})")
                    bench.procs.pop("gw-t35").stop()
        if a.profile:
            targets = [("tcp", CASES[0], 8), ("tcp", CASES[0], 1), ("tcp>rtu", CASES[0], 1)]
            for transport, case, masters in targets:
                if transport in transports:
                    n = requests if masters == 1 else max(requests // 2, 100)
                    folded = bench.profile(Path(a.profile), transport, case, masters, n)
                    if folded is not None:
                        summary = summarize_folded(folded)
                        folded.with_suffix(".txt").write_text(summary + "\n")
                        print("\n" + summary, flush=True)
    finally:
        bench.stop()
    print("\ntargets (issue 4)" + (", PINNED (diagnostic: world on CPU 0, gateway on "
                                   "CPU 1; not the issue's measurement):" if a.pin else ":"))
    print("\n".join(verdicts(rows)))
    print(f"\ncolumns: m = concurrent masters; latencies in ms; 'x' = gateway/direct; "
          f"'+p50' = gateway p50 - direct p50 in ms ('RTU added p50' on rtu rows); cpu/tx = "
          f"CPU µs per transaction (schedstat) of all processes of the direct run (d: load "
          f"generator + sim), of the gateway run (g: load + sim + gateway), and of the "
          f"gateway alone (gw). {os.cpu_count()} CPUs. Took {time.monotonic() - t_start:.0f} s.")
    if a.profile:
        print(f"profile: folded stacks and summaries in {a.profile}/")
    return 1 if any(r.direct.errors or r.gateway.errors for r in rows) else 0


if __name__ == "__main__":
    sys.exit(main())
