"""Prometheus metrics: off unless ``metrics.port`` is set; served on ``metrics.host``
(loopback by default) from the event loop (no thread reads the gateway's state).

Counted on the request path by wrapping the upstream handler (one dict lookup, two
counter increments and a histogram observation per request):

- ``compgw_requests_total{function}`` requests handled, by function code (decimal);
- ``compgw_exceptions_total{function,code}`` exception replies sent, by function and
  exception code (``0x0B`` …), whoever produced them (drive, gateway, bus);
- ``compgw_request_seconds{function}`` latency histogram, request received → reply ready.

Read from the live state at scrape time: per bus queue depth, connected flag and counters;
per axis last correction, Δa used and compensation switch; per thermal source state (0
starting, 1 ok, 2 holding, 3 alarm), Δa and failed reads; per listener connections and
refusals; gateway counters (targets committed, refused); with ``upstream.tls``, TLS clients
refused by reason (``compgw_tls_refused{reason}``) and requests refused by role
(``compgw_role_denied{role,reason}``).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import time
from collections.abc import Awaitable, Callable, Iterator
from typing import TYPE_CHECKING, Any, Protocol

from prometheus_client import CONTENT_TYPE_LATEST, CollectorRegistry, Counter, Histogram
from prometheus_client.core import CounterMetricFamily, GaugeMetricFamily, Metric
from prometheus_client.exposition import generate_latest
from prometheus_client.registry import Collector

from .modbus.frames import SERVER_DEVICE_FAILURE, ModbusError

if TYPE_CHECKING:
    from .modbus.downstream import Bus
    from .modbus.security import WriteGuard
    from .modbus.upstream import RtuServer, TcpServer
    from .router import Gateway
    from .sensors import SensorSet

log = logging.getLogger(__name__)

Handler = Callable[[int, bytes], Awaitable[bytes | None]]
Done = Callable[[bytes | None, BaseException | None], None]
FastHandler = Callable[[int, bytes, Done], bool]

LATENCY_BUCKETS_S = (0.0005, 0.001, 0.002, 0.005, 0.01, 0.02, 0.05, 0.1, 0.2, 0.5, 1.0, 2.5)


class RequestMetrics:
    """Counters and the latency histogram of the request path."""

    def __init__(self, registry: CollectorRegistry) -> None:
        self.requests = Counter("compgw_requests", "Upstream requests handled",
                                ["function"], registry=registry)
        self.exceptions = Counter("compgw_exceptions", "Exception replies sent upstream",
                                  ["function", "code"], registry=registry)
        self.latency = Histogram("compgw_request_seconds", "Request latency in the gateway",
                                 ["function"], buckets=LATENCY_BUCKETS_S, registry=registry)
        self._per_fc: dict[int, tuple[Any, Any]] = {}

    def _children(self, fc: int) -> tuple[Any, Any]:
        children = self._per_fc.get(fc)
        if children is None:
            label = str(fc)
            children = (self.requests.labels(label), self.latency.labels(label))
            self._per_fc[fc] = children
        return children

    def wrap(self, handler: Handler) -> Handler:
        """``handler`` counted: same results, same exceptions."""

        async def counted(unit_id: int, pdu: bytes) -> bytes | None:
            fc = pdu[0] & 0x7F if pdu else 0
            requests, latency = self._children(fc)
            requests.inc()
            start = time.perf_counter()
            code = 0
            try:
                reply = await handler(unit_id, pdu)
            except ModbusError as err:
                code = err.code
                raise
            except Exception:
                code = SERVER_DEVICE_FAILURE
                raise
            finally:
                latency.observe(time.perf_counter() - start)
                if code:
                    self.exceptions.labels(str(fc), f"0x{code:02X}").inc()
            if reply is not None and len(reply) >= 2 and reply[0] & 0x80:
                self.exceptions.labels(str(fc), f"0x{reply[1]:02X}").inc()
            return reply

        return counted

    def wrap_fast(self, fast: FastHandler) -> FastHandler:
        """A fast handler (see :mod:`gateway.modbus.upstream`) counted as :meth:`wrap` counts."""

        def counted(unit_id: int, pdu: bytes, done: Done) -> bool:
            fc = pdu[0] & 0x7F if pdu else 0
            requests, latency = self._children(fc)
            start = time.perf_counter()

            def finished(reply: bytes | None, exc: BaseException | None) -> None:
                latency.observe(time.perf_counter() - start)
                if exc is not None:
                    code = exc.code if isinstance(exc, ModbusError) else SERVER_DEVICE_FAILURE
                    if code:
                        self.exceptions.labels(str(fc), f"0x{code:02X}").inc()
                elif reply is not None and len(reply) >= 2 and reply[0] & 0x80:
                    self.exceptions.labels(str(fc), f"0x{reply[1]:02X}").inc()
                done(reply, exc)

            if not fast(unit_id, pdu, finished):
                return False
            requests.inc()
            return True

        return counted


def _line_families(prefix: str, label: str, what: str
                   ) -> tuple[CounterMetricFamily, CounterMetricFamily]:
    """The two counters of a serial line: noise bytes and empty wake-ups."""
    return (CounterMetricFamily(f"{prefix}_garbage_bytes", f"Bytes on {what} that formed no "
                                "frame for the gateway: noise, fragments, late replies",
                                labels=[label]),
            CounterMetricFamily(f"{prefix}_empty_wakeups", f"Times {what} reported bytes and "
                                "had none (the line is kept open)", labels=[label]))


class AppState(Protocol):
    """What the metrics read from the running gateway (``gateway.app.GatewayApp`` has it):
    named here, so that the app imports the metrics and not the other way round."""

    buses: dict[str, Bus]
    gateway: Gateway
    sensors: SensorSet
    write_guard: WriteGuard
    tcp: TcpServer | None
    tls: TcpServer | None
    rtu: RtuServer | None


class StateCollector(Collector):
    """Gauges and counters read from the running app at scrape time."""

    def __init__(self, app: AppState) -> None:
        self.app = app

    def collect(self) -> Iterator[Metric]:
        app = self.app
        depth = GaugeMetricFamily("compgw_bus_queue_depth", "Transactions waiting for the bus",
                                  labels=["bus"])
        up = GaugeMetricFamily("compgw_bus_connected", "1 while the bus port/connection is open",
                               labels=["bus"])
        bus_counters = {
            key: CounterMetricFamily(f"compgw_bus_{key}", f"Bus {key}", labels=["bus"])
            for key in ("transactions", "replies", "timeouts", "retries", "dropped",
                        "unavailable", "reconnects")
        }
        garbage, empty = _line_families("compgw_bus_line", "bus", "an RTU bus")
        for name, bus in app.buses.items():
            depth.add_metric([name], bus.queue_depth)
            up.add_metric([name], int(bus.connected))
            for key, family in bus_counters.items():
                family.add_metric([name], getattr(bus.counters, key))
            line = getattr(bus, "line", None)  # RTU buses only
            if line is not None:
                garbage.add_metric([name], line.garbage_bytes)
                empty.add_metric([name], line.spurious_wakeups)
        yield depth
        yield up
        yield from bus_counters.values()
        yield garbage
        yield empty

        gw = app.gateway
        correction = GaugeMetricFamily("compgw_axis_last_correction_mm",
                                       "Last correction sent (command - nominal), mm",
                                       labels=["axis"])
        delta_a = GaugeMetricFamily("compgw_axis_delta_a_mm", "Thermal Δa used for the axis, mm",
                                    labels=["axis"])
        enabled = GaugeMetricFamily("compgw_axis_compensation_enabled",
                                    "1 when compensation is switched on", labels=["axis"])
        for name, axis in gw.setup.config.axes.items():
            correction.add_metric([name], gw.last_correction_mm(name))
            value = (app.sensors.axis_delta_a_mm(name)
                     if axis.compensation.thermal is not None else None)
            delta_a.add_metric([name], value or 0.0)
            enabled.add_metric([name], int(gw.axis_state(name).enabled))
        yield correction
        yield delta_a
        yield enabled

        state = GaugeMetricFamily("compgw_thermal_source_state",
                                  "0 starting, 1 ok, 2 holding, 3 alarm", labels=["source"])
        source_da = GaugeMetricFamily("compgw_thermal_source_delta_a_mm",
                                      "Filtered Δa of the source, mm", labels=["source"])
        failures = CounterMetricFamily("compgw_thermal_source_failures",
                                       "Failed sensor reads", labels=["source"])
        for name in app.sensors:
            sensor = app.sensors[name]
            state.add_metric([name], int(sensor.state))
            source_da.add_metric([name], sensor.delta_a_mm or 0.0)
            failures.add_metric([name], sensor.counters.failures)
        yield state
        yield source_da
        yield failures
        alarm = GaugeMetricFamily("compgw_thermal_alarm", "1 when a thermal source is in alarm")
        alarm.add_metric([], int(app.sensors.alarm))
        yield alarm

        c = gw.counters
        for key, help_text in (("commits", "Corrected targets written to drives"),
                               ("refused_travel", "Targets refused: outside travel"),
                               ("refused_correction", "Targets refused: correction above cap"),
                               ("feedback_reads", "Feedback reads corrected"),
                               ("broadcasts", "Broadcast (unit 0) writes handled"),
                               ("broadcasts_expanded",
                                "Broadcasts touching a target, sent as corrected unicasts")):
            family = CounterMetricFamily(f"compgw_{key}", help_text)
            family.add_metric([], getattr(c, key))
            yield family

        listeners = [(kind, srv) for kind, srv in (("tcp", app.tcp), ("tls", app.tls),
                                                   ("rtu", app.rtu)) if srv is not None]
        current = GaugeMetricFamily("compgw_upstream_connections_open",
                                    "Open upstream TCP connections", labels=["listener"])
        up_counters = {
            key: CounterMetricFamily(f"compgw_upstream_{key}", f"Upstream {key}",
                                     labels=["listener"])
            for key in ("connections", "refused", "evicted", "slow_frames", "idle_closed",
                        "malformed", "handler_errors")
        }
        up_garbage, up_empty = _line_families("compgw_upstream_line", "listener",
                                              "the upstream RTU line")
        for kind, srv in listeners:
            if kind != "rtu":
                current.add_metric([kind], srv.connection_count)  # type: ignore[union-attr]
            else:
                up_garbage.add_metric([kind], srv.line.garbage_bytes)  # type: ignore[union-attr]
                up_empty.add_metric([kind], srv.line.spurious_wakeups)  # type: ignore[union-attr]
            for key, family in up_counters.items():
                family.add_metric([kind], getattr(srv.counters, key))
        yield current
        yield from up_counters.values()
        yield up_garbage
        yield up_empty
        protected = CounterMetricFamily("compgw_write_protect_refused",
                                        "Writes refused by write_protect")
        protected.add_metric([], app.write_guard.refused if app.write_guard else 0)
        yield protected
        gate = app.tls.tls if app.tls is not None else None
        if gate is not None:
            refused = CounterMetricFamily("compgw_tls_refused", "TLS clients refused: at the "
                                          "handshake (no certificate, another CA, expired, "
                                          "TLS < 1.2, ...), the allowlist, an invalid role "
                                          "extension", labels=["reason"])
            for reason, count in sorted(gate.refused.items()):
                refused.add_metric([reason], count)
            denied = CounterMetricFamily("compgw_role_denied", "Requests refused with 0x01 by "
                                         "the client's role", labels=["role", "reason"])
            for (role, reason), count in sorted(gate.denied.items()):
                denied.add_metric([role, reason], count)
            yield refused
            yield denied


class MetricsServer:
    """A minimal HTTP endpoint on the event loop: ``GET /metrics``."""

    def __init__(self, registry: CollectorRegistry, host: str, port: int) -> None:
        self.registry = registry
        self.host = host
        self._port = port
        self._server: asyncio.Server | None = None

    @property
    def port(self) -> int:
        return self._port

    async def start(self) -> None:
        self._server = await asyncio.start_server(self._serve, self.host, self._port)
        self._port = self._server.sockets[0].getsockname()[1]
        log.info("metrics on http://%s:%d/metrics", self.host, self._port)

    async def close(self) -> None:
        server, self._server = self._server, None
        if server is not None:
            server.close()
            with contextlib.suppress(Exception):
                await asyncio.wait_for(server.wait_closed(), 1.0)

    async def _serve(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        try:
            head = await asyncio.wait_for(reader.readuntil(b"\r\n\r\n"), 5.0)
            parts = head.split(b"\r\n", 1)[0].split()
            path = parts[1].split(b"?", 1)[0] if len(parts) >= 2 else b""
            if parts[:1] == [b"GET"] and path in (b"/metrics", b"/"):
                body = generate_latest(self.registry)
                status, ctype = b"200 OK", CONTENT_TYPE_LATEST.encode()
            else:
                body, status, ctype = b"not found\n", b"404 Not Found", b"text/plain"
            writer.write(b"HTTP/1.1 " + status + b"\r\nContent-Type: " + ctype
                         + b"\r\nContent-Length: " + str(len(body)).encode()
                         + b"\r\nConnection: close\r\n\r\n" + body)
            await writer.drain()
        except (asyncio.TimeoutError, asyncio.IncompleteReadError, asyncio.LimitOverrunError,
                ConnectionError, OSError):
            pass
        finally:
            writer.close()
            with contextlib.suppress(Exception):
                await asyncio.wait_for(writer.wait_closed(), 1.0)


def build(app: AppState) -> tuple[CollectorRegistry, RequestMetrics]:
    """A registry holding the request metrics and the app's state collector."""
    registry = CollectorRegistry(auto_describe=False)
    request_metrics = RequestMetrics(registry)
    registry.register(StateCollector(app))
    return registry, request_metrics
