"""The daemon: buses, listeners and the request handler assembled from a config.

`compgw run -c FILE` runs :func:`serve` in the foreground: SIGTERM/SIGINT stop it (the
transaction in flight finishes, queued and new requests are refused, connections close),
SIGHUP reloads the config and tables — validated completely first; an invalid one is
logged and the old one stays. Under systemd it speaks the notify protocol
(:mod:`gateway.service`): READY=1 once listening, watchdog pings from the event loop.

The upstream handler is the router's, wrapped: write protection (:mod:`gateway.modbus.security`)
inside, metrics (:mod:`gateway.metrics`, only when ``metrics.port`` is set) outside. The
TCP listener also gets the router's fast handler (:meth:`Gateway.handle_fast`), wrapped
the same way. With ``upstream.tls`` a second TCP listener speaks Modbus/TCP Security
(:mod:`gateway.modbus.mbsecurity`): same handlers, each request first authorised by the client
certificate's role.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import signal
import socket
import time
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

from .compensation import Chain
from .config import Bus as BusConfig
from .config import (
    ConfigError,
    GatewayConfig,
    TcpListen,
    bus_silence_s,
    config_crc,
    file_warnings,
    load_config,
)
from .config import warnings as config_warnings
from .event_loop import run_loop
from .machine_clock import MachineTime
from .modbus.downstream import Bus, RtuBus, TcpBus
from .modbus.rtu_over_tcp import RtuOverTcpBus
from .modbus.security import WriteGuard
from .modbus.serialline import SerialLineLost
from .modbus.upstream import RtuServer, TcpServer
from .router import Gateway
from .sensors import SensorSet
from .service import EVERY, Notifier
from .state_store import StateStore
from .status import StatusUnit
from .tables import build_chain

if TYPE_CHECKING:
    from .metrics import MetricsServer
    from .modbus.mbsecurity import TlsGate

log = logging.getLogger(__name__)


def _port_free(host: str, port: int) -> None:
    """OSError (as the listener would raise it) when ``host:port`` is taken."""
    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    with socket.socket(family, socket.SOCK_STREAM) as probe:
        probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)  # as asyncio's server
        try:
            probe.bind((host, port))
        except OSError as exc:
            raise OSError(exc.errno, f"error while attempting to bind on address "
                                     f"{(host, port)!r}: {exc.strerror}") from None


def make_bus(name: str, cfg: BusConfig, min_silence_s: float | None = None) -> Bus:
    """The downstream bus a config section describes (``min_silence_s``: what its drives
    need, when longer than the bus's own setting)."""
    common = {
        "name": name,
        "timeout_s": cfg.timeout_s,
        "retries": cfg.retries,
        "min_silence_s": cfg.min_silence_s if min_silence_s is None else min_silence_s,
        "turnaround_s": cfg.turnaround_s,
    }
    if cfg.tcp is not None:
        return TcpBus(cfg.tcp.host, cfg.tcp.port, **common)
    if cfg.rtu_over_tcp is not None:
        rot = cfg.rtu_over_tcp
        return RtuOverTcpBus(rot.host, rot.port, baudrate=rot.baudrate, bytesize=rot.bytesize,
                             parity=rot.parity, stopbits=rot.stopbits, t35=rot.t35, **common)
    assert cfg.rtu is not None
    return RtuBus(
        cfg.rtu.port,
        baudrate=cfg.rtu.baudrate,
        bytesize=cfg.rtu.bytesize,
        parity=cfg.rtu.parity,
        stopbits=cfg.rtu.stopbits,
        t35=cfg.rtu.t35,
        **common,
    )


def load(path: str | Path) -> tuple[GatewayConfig, Chain]:
    """Config and chain from a file, fully validated (raises ConfigError)."""
    config = load_config(path)
    return config, build_chain(config, Path(path).resolve().parent)


def _load_with_crc(path: str | Path) -> tuple[GatewayConfig, Chain, int]:
    crc = config_crc(path)  # before the load: a file replaced meanwhile reads as another
    return (*load(path), crc)


class GatewayApp:
    """A running gateway: ``async with GatewayApp(config, chain) as app: app.tcp_port``."""

    def __init__(self, config: GatewayConfig, chain: Chain, *, source: str | None = None) -> None:
        self.config = config
        self.source = source
        self.buses = {
            name: make_bus(name, cfg, bus_silence_s(config, name))
            for name, cfg in config.buses.items()
        }
        clock = config.machine_clock
        self.machine_time = (None if clock is None
                             else MachineTime(clock, self.buses[clock.bus]))  # fmt: skip
        # None: the heat classes' own default clock, the computer's (bench/lockstep.py puts
        # the simulated machine's in its place)
        heat_clock = None if self.machine_time is None else self.machine_time.now_s
        self.sensors = SensorSet.from_config(config.thermal_sources, self.buses, axes=config.axes,
                                             motion_clock=heat_clock)  # fmt: skip
        self.gateway = Gateway(
            config, chain, self.buses, delta_a_mm=self.sensors.axis_delta_a_mm,
            moved=self.sensors.moved, clock=heat_clock,
            before_correct=None if self.machine_time is None else self.machine_time.refresh,
        )
        self.status = StatusUnit(
            self.gateway,
            self.sensors,
            lambda: any(not bus.connected for bus in self.buses.values()),
            machine_time=self.machine_time,
        )
        self.gateway.status_handler = self.status.handle
        if source is not None:
            self.status.reloader = self.reload_file
            self.status.config_crc = config_crc(source)
        self._reload_lock = asyncio.Lock()
        self.write_guard = WriteGuard(lambda: self.config.write_protect)
        self.handler = self.write_guard.wrap(self.gateway.handle)
        self.fast_handler = self.write_guard.wrap_fast(self.gateway.handle_fast)
        self.metrics: MetricsServer | None = None
        if config.metrics.port is not None:  # (imported here: a gateway without them starts
            from .metrics import MetricsServer  # without prometheus_client or cryptography)
            from .metrics import build as build_metrics

            registry, request_metrics = build_metrics(self)
            self.handler = request_metrics.wrap(self.handler)
            self.fast_handler = request_metrics.wrap_fast(self.fast_handler)
            self.metrics = MetricsServer(registry, config.metrics.host, config.metrics.port)
        self.state_store: StateStore | None = None
        self._state_live = False  # read and carried on: written at stop
        if config.state_file is not None:
            path = Path(config.state_file)
            if source is not None and not path.is_absolute():
                path = Path(source).resolve().parent / path
            self.state_store = StateStore(path, self.gateway.saved_axes,
                                          heat=self.sensors.saved_heat)
        self.tcp: TcpServer | None = None
        self.tls: TcpServer | None = None  # Modbus/TCP Security
        self.rtu: RtuServer | None = None
        self._stop_sensors = asyncio.Event()
        self._sensor_task: asyncio.Task[None] | None = None

    @property
    def tcp_port(self) -> int:
        assert self.tcp is not None, "no TCP listener configured"
        return self.tcp.port

    def upstream_units(self) -> set[int]:
        units = {axis.upstream for axis in self.config.axes.values()}
        units |= set(self.config.passthrough)
        units.add(self.config.status.upstream_unit)
        return units

    async def start(self) -> None:
        """Connect the buses (a bus that is down is retried on use) and listen. A fixed
        upstream port already taken fails first, before a bus or the state file is
        touched: a second `compgw run` beside the service must not take a drive's one
        connection, nor write its state file."""
        up = self.config.upstream
        for listen in (up.tcp, up.tls):
            if listen is not None and listen.port:
                _port_free(listen.host, listen.port)
        for name, bus in self.buses.items():
            if not await bus.connect():
                log.warning("bus %s is down at start; requests get 0x0A until it is back", name)
        if self.state_store is not None:
            await self.gateway.carry_on(self.state_store.load())
            self.sensors.carry_on_heat(self.state_store.saved_heat)
            self.gateway.on_state_change = self.state_store.changed
            self._state_live = True
        if len(self.sensors):
            self._sensor_task = asyncio.create_task(self.sensors.run(self._stop_sensors))
        try:
            if up.tcp is not None:
                self.tcp = self._tcp_server(up.tcp)
                await self.tcp.start()
            if up.tls is not None:  # raises ConfigError when its files cannot be used
                from .modbus.mbsecurity import TlsGate
                from .modbus.tlsfiles import certificate_dates, server_context

                base = Path(self.source).resolve().parent if self.source is not None else None
                context = server_context(up.tls, base)
                for warning in certificate_dates(up.tls, base):
                    log.warning("%s", warning)
                self.tls = self._tcp_server(up.tls, TlsGate(up.tls, context))
                await self.tls.start()
            if up.rtu is not None:
                self.rtu = RtuServer(
                    self.handler,
                    up.rtu.port,
                    unit_ids=self.upstream_units(),
                    baudrate=up.rtu.baudrate,
                    bytesize=up.rtu.bytesize,
                    parity=up.rtu.parity,
                    stopbits=up.rtu.stopbits,
                    t35=up.rtu.t35,
                )
                try:
                    await self.rtu.start()
                except SerialLineLost as err:  # (an OSError: "cannot listen", exit 3)
                    raise SerialLineLost(f"upstream.rtu {err}") from err
            if self.metrics is not None:
                await self.metrics.start()
        except BaseException:
            await self.stop()
            raise

    def _tcp_server(self, listen: TcpListen, tls: TlsGate | None = None) -> TcpServer:
        return TcpServer(
            self.handler,
            listen.host,
            listen.port,
            allow=listen.allow,
            max_connections=listen.max_connections,
            idle_timeout_s=listen.idle_timeout_s or None,
            frame_timeout_s=listen.frame_timeout_s,
            fast=self.fast_handler,
            tls=tls,
        )

    async def stop(self) -> None:
        """Stop listening (in-flight transactions finish), then close the buses."""
        for listener in (self.tcp, self.tls, self.rtu, self.metrics):
            if listener is not None:
                await listener.close()
        self._stop_sensors.set()
        if self._sensor_task is not None:
            await self._sensor_task
            self._sensor_task = None
        for bus in self.buses.values():
            await bus.close()
        if self.state_store is not None and self._state_live:  # (else it was never read)
            await self.state_store.close()

    def reload(self, config: GatewayConfig, chain: Chain) -> None:
        """Swap tables and per-axis settings between transactions.

        Listeners, buses, thermal sources, the metrics endpoint and the state file stay:
        changing those sections needs a restart, and is refused here with a log line.
        """
        fixed = ("upstream", "buses", "thermal_sources", "metrics", "state_file", "machine_clock")
        changed = [key for key in fixed if getattr(config, key) != getattr(self.config, key)]
        if changed:
            raise ConfigError(f"{', '.join(changed)} cannot change on reload; restart instead")
        rescaled = [name for name, axis in config.axes.items()
                    if name in self.config.axes
                    and axis.command_scale != self.config.axes[name].command_scale]
        if rescaled:  # the positions the gateway remembers are in the old drive units
            raise ConfigError(f"axes.{rescaled[0]}.command_scale cannot change on reload; "
                              "restart instead")  # fmt: skip
        self.sensors.set_axes(config.axes)
        self.gateway.reload(config, chain)
        self.config = config

    async def reload_file(self) -> str | None:
        """Load the config file again (``source``) and swap to it; None when taken, else
        the one-line reason it was refused (the old config stays). SIGHUP and the status
        unit's reload register both come here. The file is read and its tables built in a
        worker thread (a fine plane grid takes up to a second), so the masters' requests
        are answered meanwhile; the swap itself happens on the loop, between two of them.
        Reloads queue behind each other."""
        assert self.source is not None
        async with self._reload_lock:
            began_s = time.monotonic()
            try:
                new_config, new_chain, crc = await asyncio.to_thread(_load_with_crc,
                                                                     self.source)  # fmt: skip
                self.reload(new_config, new_chain)
                self.status.config_crc = crc
            except ConfigError as exc:
                log.error("reload refused, old config kept: %s", exc, extra=EVERY)
                self.status.reloaded(str(exc))
                return str(exc)
            log.info("reloaded %s (read and built in %.2f s)", self.source,
                     time.monotonic() - began_s)
            self.status.reloaded(None)
            return None

    async def __aenter__(self) -> GatewayApp:
        await self.start()
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.stop()


    def describe(self) -> str:
        """One line for logs and ``systemctl status``."""
        parts = []
        if self.tcp is not None:
            parts.append(f"Modbus TCP {self.tcp.host}:{self.tcp.port}")
        if self.tls is not None:
            parts.append(f"Modbus/TCP Security {self.tls.host}:{self.tls.port}")
        if self.rtu is not None:
            parts.append(f"Modbus RTU {self.rtu.line.port}")
        buses = ", ".join(f"{name} {'up' if bus.connected else 'DOWN'}"
                          for name, bus in self.buses.items())
        parts.append(f"buses: {buses}")
        if self.metrics is not None:
            parts.append(f"metrics {self.metrics.host}:{self.metrics.port}")
        return "; ".join(parts)


async def serve(path: str | Path, *, stop: asyncio.Event | None = None,
                notifier: Notifier | None = None,
                on_ready: Callable[[GatewayApp], None] | None = None) -> int:
    """Run until SIGTERM/SIGINT (or ``stop`` is set); SIGHUP reloads. Returns an exit code.

    READY=1 goes to systemd once every listener is bound and every bus has been connected
    or found down (:meth:`GatewayApp.start`); ``on_ready(app)`` is called then too.
    """
    notifier = notifier if notifier is not None else Notifier()
    try:
        config, chain = load(path)
    except ConfigError as exc:
        log.error("%s", exc)
        notifier.status(f"config error: {exc}")
        return 1
    # what `compgw check` warns of, in the journal
    for warning in [*file_warnings(path), *config_warnings(config)]:
        log.warning("%s", warning)
    app = GatewayApp(config, chain, source=str(path))
    try:
        await app.start()
    except ConfigError as exc:  # upstream.tls files the listener cannot use
        log.error("%s", exc)
        notifier.status(f"config error: {exc}")
        return 1
    except OSError as exc:
        log.error("cannot listen: %s", exc)
        notifier.status(f"cannot listen: {exc}")
        return 3
    stop = stop if stop is not None else asyncio.Event()
    loop = asyncio.get_running_loop()

    async def reload_and_notify() -> None:
        notifier.reloading()
        if await app.reload_file() is not None:
            notifier.ready(f"reload refused, old config kept; {app.describe()}")
            return
        notifier.ready(app.describe())

    reloads: set[asyncio.Task[None]] = set()  # held until done (the loop keeps weak refs)

    def do_reload() -> None:
        task = asyncio.ensure_future(reload_and_notify())
        reloads.add(task)
        task.add_done_callback(reloads.discard)

    loop.add_signal_handler(signal.SIGTERM, stop.set)
    loop.add_signal_handler(signal.SIGINT, stop.set)
    loop.add_signal_handler(signal.SIGHUP, do_reload)
    log.info("compgw running: %s", app.describe())
    notifier.ready(app.describe())
    notifier.follow(app.describe)  # a bus going down or up: STATUS= with the next ping
    watchdog = notifier.start_watchdog()
    if on_ready is not None:
        on_ready(app)
    try:
        await stop.wait()
        log.info("stopping: finishing transactions in flight")
        notifier.stopping()
    finally:
        for sig in (signal.SIGTERM, signal.SIGINT, signal.SIGHUP):
            with contextlib.suppress(Exception):
                loop.remove_signal_handler(sig)
        await app.stop()
        if watchdog is not None:
            watchdog.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await watchdog
    log.info("compgw stopped")
    return 0


def run(path: str | Path) -> int:
    """`compgw run`: the daemon on uvloop when it is installed (about half the event-loop
    CPU per transaction of the standard loop), else on asyncio's own loop."""
    return run_loop(serve(path))
