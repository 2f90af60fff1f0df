"""The `compgw` command line. Exit codes: 0 ok, 1 bad input, 2 usage, 3 runtime fault."""

from __future__ import annotations

import argparse
import logging
import os
import sys
from pathlib import Path
from typing import Any

from .cli_args import Parser, above

EXIT_OK = 0
EXIT_BAD_INPUT = 1
EXIT_USAGE = 2
EXIT_RUNTIME = 3


def _cmd_check(args: argparse.Namespace) -> int:
    from pathlib import Path

    from .config import ConfigError, file_warnings, load_config, warnings
    from .setup_report import describe
    from .tables import build_chain

    try:
        config = load_config(args.config)
        chain = build_chain(config, Path(args.config).resolve().parent)
        tls_lines, tls_warnings = [], []
        if config.upstream.tls is not None:
            from .modbus.tlsfiles import check_files

            tls_lines, tls_warnings = check_files(config.upstream.tls,
                                                  Path(args.config).resolve().parent)
    except ConfigError as exc:
        for line in exc.lines:
            print(f"compgw check: {line}", file=sys.stderr)
        return EXIT_BAD_INPUT
    print(describe(config, chain))
    for line in tls_lines:
        print(line)
    for line in [*file_warnings(args.config), *warnings(config), *tls_warnings]:
        print(f"compgw check: warning: {line}", file=sys.stderr)
    return EXIT_OK


def _cmd_run(args: argparse.Namespace) -> int:

    from .app import run
    from .service import configure_logging

    configure_logging(args.log_level)
    return run(args.config)


def _cmd_demo(args: argparse.Namespace) -> int:
    if args.commission:
        from .demos.commission import main as commission_demo

        return commission_demo(args.save)
    if args.seed003:
        from .demos.seed003 import main as seed003_demo

        return seed003_demo(as_json=args.json, work_dir=args.save)
    from .demos.tour import main as demo_main

    return demo_main(as_json=args.json, identify_dir=args.identify)


def _cmd_status(args: argparse.Namespace) -> int:
    import asyncio

    from pymodbus.client import AsyncModbusTcpClient, AsyncModbusTlsClient
    from pymodbus.exceptions import ModbusException

    from .config import ConfigError, config_crc, file_warnings, load_config
    from .status import INPUT_SIZE, MACHINE_CLOCK_REGISTER, format_status

    try:
        config = load_config(args.config)
    except ConfigError as exc:
        config = _reachable_part(args.config)
        if config is None:
            print(f"compgw status: {exc}", file=sys.stderr)
            return EXIT_BAD_INPUT
        print(f"compgw status: warning: {exc}; the gateway is asked all the same (its "
              "upstream and status sections are sound)", file=sys.stderr)  # fmt: skip
    up = config.upstream
    listen = up.tls if args.cert or args.key else up.tcp
    if listen is None:
        print("compgw status: " + (
            "--cert and --key need upstream.tls in the config" if args.cert or args.key else
            "the config serves only Modbus/TCP Security (upstream.tls): give --cert and --key "
            "of a master's certificate whose role reads (e.g. monitor), or add upstream.tcp "
            "on loopback" if up.tls is not None else
            "needs upstream.tcp (or upstream.tls) to reach the gateway"),
            file=sys.stderr)  # fmt: skip
        return EXIT_BAD_INPUT
    host = {"0.0.0.0": "127.0.0.1", "::": "::1", "": "127.0.0.1"}.get(listen.host, listen.host)
    port = args.port or listen.port
    section = "upstream.tls" if listen is up.tls else "upstream.tcp"
    if not port:
        print(f"compgw status: {args.config}: {section}.port is 0, so the gateway chose its "
              "port when it started (its log says '... server listening on HOST:PORT'): give "
              "that port with --port", file=sys.stderr)  # fmt: skip
        return EXIT_BAD_INPUT
    ctx = None
    if listen is up.tls:
        try:
            ctx = _tls_context(args, config)
        except (OSError, ValueError) as exc:  # ssl.SSLError is an OSError
            print(f"compgw status: --cert/--key/--ca: {exc}", file=sys.stderr)
            return EXIT_BAD_INPUT

    async def read() -> Any:  # (the clients are made on the running loop)
        client = AsyncModbusTcpClient(host, port=port, timeout=2, retries=0,
                                      reconnect_delay=0) if ctx is None else \
            AsyncModbusTlsClient(host, port=port, sslctx=ctx, timeout=2, retries=0,
                                 reconnect_delay=0)  # fmt: skip
        try:
            if not await client.connect():
                return None
            unit = config.status.upstream_unit
            head = await client.read_input_registers(0, count=1, device_id=unit)
            if head.isError():
                return head
            # a gateway before map v4 has no machine clock after its 120 registers
            count = INPUT_SIZE if head.registers[0] >= 4 else MACHINE_CLOCK_REGISTER
            return await client.read_input_registers(0, count=count, device_id=unit)
        finally:
            client.close()

    try:
        reply = asyncio.run(read())
    except ModbusException as exc:  # a timeout, the connection lost mid-request
        print(f"compgw status: no reply from {host}:{port} ({exc}); a host not in "
              f"{section}.allow is cut off at once, and the gateway's log says so",
              file=sys.stderr)  # fmt: skip
        return EXIT_RUNTIME
    if reply is None:
        print(f"compgw status: no gateway at {host}:{port}" + (
            " (or the TLS handshake failed: the gateway's log says why)"
            if listen is up.tls else ""), file=sys.stderr)  # fmt: skip
        return EXIT_RUNTIME
    if reply.isError():
        from .modbus.frames import exception_words

        code = getattr(reply, "exception_code", 0)
        print(f"compgw status: {host}:{port} answered {exception_words(code)} at unit "
              f"{config.status.upstream_unit}: is it a compgw gateway, running "
              f"{args.config}'s status.upstream_unit?", file=sys.stderr)  # fmt: skip
        return EXIT_RUNTIME
    print(format_status(list(config.axes), list(config.thermal_sources), reply.registers,
                        (args.config, config_crc(args.config)),
                        frozenset(a for a, c in config.axes.items() if c.rotary)))  # fmt: skip
    for line in file_warnings(args.config):
        print(f"compgw status: warning: {line}", file=sys.stderr)
    return EXIT_OK


def _reachable_part(path: str) -> Any:
    """What ``compgw status`` needs of a config that does not validate as a whole (a typo
    in an axis must not hide the live gateway): its upstream and status sections, the axis
    and thermal source names; None when those are not sound either."""
    from types import SimpleNamespace

    from pydantic import ValidationError

    from .config import ConfigError, Status, Upstream
    from .config_types import read_yaml

    try:
        data = read_yaml(path, ConfigError)
        upstream = Upstream.model_validate(data.get("upstream"))
        status = Status.model_validate(data.get("status") or {})
    except (ConfigError, ValidationError, AttributeError):
        return None
    axes = data.get("axes") if isinstance(data.get("axes"), dict) else {}
    sources = data.get("thermal_sources") if isinstance(data.get("thermal_sources"),
                                                         dict) else {}  # fmt: skip
    return SimpleNamespace(upstream=upstream, status=status, thermal_sources=dict(sources),
                           axes={name: SimpleNamespace(rotary=bool(isinstance(a, dict)
                                                                   and a.get("rotary")))
                                 for name, a in axes.items()})  # fmt: skip


def _tls_context(args: argparse.Namespace, config: Any) -> Any:
    """The SSL context of a master with the certificate of ``--cert``/``--key``, checking
    the gateway's certificate against ``--ca`` (default: the config's upstream.tls.ca,
    relative to the config file)."""
    import ssl

    if not (args.cert and args.key):
        raise ValueError("give both --cert and --key")
    ca = args.ca or str(Path(args.config).resolve().parent / config.upstream.tls.ca)
    ctx = ssl.create_default_context(cafile=ca)
    ctx.load_cert_chain(args.cert, args.key)
    return ctx


def _cmd_sim(args: argparse.Namespace) -> int:
    if args.random_machine is not None or args.real_machine is not None:
        from sim.machine_cli import write_machine_dir

        return write_machine_dir(args.random_machine, args.roughness, args.real_machine, args.out)
    if args.config is None:
        print("compgw sim: give -c FILE, --random-machine SEED or --real-machine NAME",
              file=sys.stderr)
        return EXIT_USAGE
    from sim.server import main as sim_main

    return sim_main(args.config)


#: the commands the gateway's own modules serve: their processes (the daemon, the sim) need
#: not import the calibration's parsers and what those pull in (0.4-0.5 s of start-up each)
_LIGHT = frozenset({"run", "check", "sim", "demo", "status"})


def build_parser(argv: list[str] | None = None) -> argparse.ArgumentParser:
    """Every command's parser; given the arguments to parse, only the calibration's when the
    command is one of them (or none is named: ``compgw --help`` lists them all)."""
    parser = Parser(
        prog="compgw",
        description="Modbus compensation gateway: pitch, backlash, XY and thermal correction.",
    )
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    p = sub.add_parser(
        "run", help="run the gateway daemon (foreground; systemd Type=notify)",
        description="Run the gateway in the foreground. SIGTERM/SIGINT: finish the "
        "transactions in flight and stop; SIGHUP: reload config and tables (validated "
        "first, the old ones stay if invalid). Under systemd: READY=1, STATUS=, watchdog "
        "pings (WatchdogSec=), journald priorities on the log lines.")
    p.add_argument("-c", "--config", required=True, help="gateway YAML config")
    p.add_argument(
        "--log-level", default="info", choices=["debug", "info", "warning", "error"],
        help="info: one line per event (start, stop, reload, bus up/down, refusals); "
        "debug adds per-connection and per-exception lines",
    )
    p.set_defaults(func=_cmd_run)

    p = sub.add_parser("check", help="validate config and tables, print the resolved setup",
                       description="Validate a gateway config as `compgw run` would load it "
                       "(every table, model and TLS file read), print the resolved setup per "
                       "axis, and warn of what loads but should be acted on. Exit 0: it "
                       "loads; 1: it does not (one line naming the key or file).")  # fmt: skip
    p.add_argument("-c", "--config", required=True, help="gateway YAML config")
    p.set_defaults(func=_cmd_check)

    p = sub.add_parser("sim", help="run the simulated drives and instruments")
    p.add_argument("-c", "--config", help="simulator YAML config")
    p.add_argument("--random-machine", type=int, metavar="SEED",
                   help="write a random machine (sim + gateway config, truth) and exit")
    p.add_argument("--roughness", choices=["smooth", "rough"], default="smooth")
    p.add_argument("--real-machine", metavar="NAME",
                   help="write a machine from real measured data (sim/README.md) and exit")
    p.add_argument("--out", metavar="DIR", help="where to write the machine")
    p.set_defaults(func=_cmd_sim)

    p = sub.add_parser("demo", help="sim + gateway + scripted upper computer, before/after")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.add_argument(
        "--identify", metavar="DIR", help="measure the example machine, write its tables to DIR"
    )
    p.add_argument("--commission", action="store_true",
                   help="run `compgw commission` live on a random machine (about 20 s)")
    p.add_argument("--seed003", action="store_true",
                   help="seed 003's swing head through a linkage: uncompensated, the seed's "
                        "table and compgw's choice from the same readings (about 6 s)")
    p.add_argument("--save", metavar="FILE", help="with --commission: keep its output there "
                   "(with --seed003: a directory for the raw files, tables and linkage)")
    p.set_defaults(func=_cmd_demo)

    command = next((a for a in argv if not a.startswith("-")), None) if argv else None
    if command not in _LIGHT:
        from .calibration.commands import add_parsers as add_calibration_parsers

        add_calibration_parsers(sub)

    p = sub.add_parser("status", help="read the live gateway's status registers",
                       description="Read the status unit of the running gateway (config "
                       "generation, last reload, the loaded file's CRC, per-axis state) over "
                       "plain Modbus/TCP (upstream.tcp), or over Modbus/TCP Security with "
                       "--cert and --key (a master's certificate whose role reads).")  # fmt: skip
    p.add_argument("-c", "--config", required=True, help="gateway YAML config")
    p.add_argument("--port", type=above(0, "TCP port", int, most=65535),
                   help="gateway TCP port (default: from the config)")
    p.add_argument("--cert", help="over upstream.tls: a master's certificate (PEM) whose role "
                   "reads, e.g. monitor")  # fmt: skip
    p.add_argument("--key", help="over upstream.tls: that certificate's key (PEM)")
    p.add_argument("--ca", help="over upstream.tls: the CA the gateway's certificate is "
                   "checked against (default: upstream.tls.ca)")  # fmt: skip
    p.set_defaults(func=_cmd_status)
    return parser


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    args = build_parser(argv).parse_args(argv)
    if args.func not in (_cmd_run, _cmd_sim):  # (the services log; see service.py)
        # a command's own one-line message says what failed, in the user's terms: not also
        # the library's ("Connection to (…) failed", a late reply after Ctrl-C)
        logging.getLogger("pymodbus").setLevel(logging.CRITICAL)
    try:
        return int(args.func(args))
    except KeyboardInterrupt:  # before a command's own handler (at its start): one line
        print(f"compgw {argv[0] if argv else ''}: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:  # `compgw check | head`: the reader has what it wanted
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())  # (no second error
        return EXIT_OK  # at exit's flush)


if __name__ == "__main__":
    sys.exit(main())
