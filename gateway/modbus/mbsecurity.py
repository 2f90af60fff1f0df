"""Modbus/TCP Security (MB-TCP-Security v36) on an upstream listener: the unchanged MBAP
frames over TLS >= 1.2, the client authenticated by its X.509v3 certificate (required,
verified against ``upstream.tls.ca``), each request authorised by the certificate's role.

**Handshake.** :class:`TlsServer` accepts TCP itself, checks the allowlist, then runs the
handshake (``loop.connect_accepted_socket``, on asyncio's loop and on uvloop alike) before
the connection's protocol exists: a refused handshake (no certificate, another CA, expired,
TLS older than 1.2, not TLS at all, no handshake within ``frame_timeout_s``) is seen with
the client's address, counted by reason (:attr:`TlsGate.refused`) and logged under one
template per reason (the log filter holds repeats back per template).

**Role.** The certificate's extension 1.3.6.1.4.1.50316.802.1, a DER UTF8String decoded by
``cryptography.hazmat.asn1`` (documented, marked unstable upstream: pinned version). No
extension: no role, the ``no_role`` rule. Two such extensions, or one that is not a
UTF8String: the certificate is refused (every request 0x01, logged at connect). A role not
in ``roles`` may do nothing.

**Requests** (:class:`Rules`; function codes in decimal): reads are FC01/02/03/04,
FC07/11/12/17/20/24 and FC43/14 (device identification), allowed by ``read``;
FC05/06/15/16/22 are writes, allowed by ``write: true`` or when every address they write
lies in the ``write`` ranges; FC23 needs both; any other function (diagnostics FC08, file
records, unknown codes) only with ``write: true``. Units outside ``units``, and
broadcasts (unit 0) unless ``units: all``, are refused. A refusal is exception 0x01
(ILLEGAL FUNCTION, as the spec chose), sent by the listener: nothing reaches the handler
or a drive. Counted by (role, reason) in :attr:`TlsGate.denied`.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import socket
import ssl
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass

from cryptography import x509
from cryptography.hazmat import asn1

from ..config import TlsListen, TlsRole
from .frames import ILLEGAL_FUNCTION, READ_WRITE_MULTIPLE_REGISTERS, ModbusError
from .security import written_range

log = logging.getLogger(__name__)

ROLE_OID = x509.ObjectIdentifier("1.3.6.1.4.1.50316.802.1")

#: the per-request check of one connection: None (allowed) or the error to answer with
Check = Callable[[int, bytes], ModbusError | None]

READ_FUNCTIONS = frozenset({0x01, 0x02, 0x03, 0x04, 0x07, 0x0B, 0x0C, 0x11, 0x14, 0x18})
RANGED_WRITES = frozenset({0x05, 0x06, 0x0F, 0x10, 0x16, READ_WRITE_MULTIPLE_REGISTERS})
MEI, READ_DEVICE_ID = 0x2B, 0x0E

# one template per cause (the log filter limits repeats per template); args: peer, detail
_REFUSED = {
    "allowlist": "refused TLS client %s: not in the allowlist%s",
    "busy": "refused TLS client %s: too many TLS handshakes in progress%s",
    "no_certificate": "refused TLS client %s: no client certificate%s",
    "unknown_ca": "refused TLS client %s: certificate not issued by upstream.tls.ca%s",
    "expired": "refused TLS client %s: certificate expired%s",
    "not_yet_valid": "refused TLS client %s: certificate not valid yet%s",
    "bad_certificate": "refused TLS client %s: certificate not accepted%s",
    "old_protocol": "refused TLS client %s: TLS older than 1.2%s",
    "not_tls": "refused TLS client %s: not TLS (plain Modbus TCP on the TLS port?)%s",
    "client_alert": "TLS client %s refused the handshake: does it trust our certificate?%s",
    "timeout": "refused TLS client %s: no TLS handshake within frame_timeout_s%s",
    "aborted": "TLS client %s left during the TLS handshake%s",
    "bad_role": "TLS client %s: its certificate's role extension is invalid%s: every request "
                "will be refused",
    "other": "refused TLS client %s: TLS handshake failed%s",
}
# args: peer, role, function code, unit, detail
_DENIED = {
    "unit": "TLS client %s (role %s): FC%02d to unit %d refused: not one of the role's "
            "units%s",
    "read": "TLS client %s (role %s): FC%02d to unit %d refused: the role may not read%s",
    "write": "TLS client %s (role %s): FC%02d to unit %d refused: the role may not write%s",
    "range": "TLS client %s (role %s): FC%02d to unit %d refused: outside the role's write "
             "ranges%s",
    "function": "TLS client %s (role %s): FC%02d to unit %d refused: a function only "
                "write: true allows%s",
    "no_role": "TLS client %s %s: FC%02d to unit %d refused: the certificate has no role "
               "(no_role: refuse)%s",
    "unknown_role": "TLS client %s (role %s): FC%02d to unit %d refused: the role is not in "
                    "upstream.tls.roles%s",
    "bad_role": "TLS client %s %s: FC%02d to unit %d refused: invalid role extension%s",
}
NO_ROLE, BAD_ROLE = "(none)", "(invalid)"


class RoleError(ValueError):
    """A certificate whose role extension cannot be used."""


def certificate_role(der: bytes) -> str | None:
    """The MB-TCP-Security role of a DER certificate; None without the extension.

    Raises RoleError when the extension is there twice or is not a DER UTF8String.
    """
    cert = x509.load_der_x509_certificate(der)
    try:
        value = cert.extensions.get_extension_for_oid(ROLE_OID).value
    except x509.ExtensionNotFound:
        return None
    except x509.DuplicateExtension:
        raise RoleError("the role extension appears more than once") from None
    except ValueError as err:  # an extension the library cannot parse
        raise RoleError(f"unreadable extensions: {err}") from None
    der_value = value.value if isinstance(value, x509.UnrecognizedExtension) else b""
    try:
        return str(asn1.decode_der(str, der_value))
    except ValueError:
        raise RoleError(f"the role is not a DER UTF8String ({der_value[:16].hex()})") from None


@dataclass(frozen=True)
class Rules:
    """What one role may do; :meth:`refusal` says why a request is not allowed."""

    units: frozenset[int] | None = None  # None: every unit, broadcasts included
    read: bool = True
    write: bool | tuple[tuple[int, int], ...] = True  # ranges: inclusive, sorted, merged
    refuse: str | None = None  # every request refused, for this reason

    @classmethod
    def of(cls, role: TlsRole) -> Rules:
        units = None if role.units == "all" else frozenset(role.units)
        write = role.write if isinstance(role.write, bool) else _merge(role.write)
        return cls(units, role.read, write)

    @property
    def allows_all(self) -> bool:
        return self.refuse is None and self.units is None and self.read and self.write is True

    def refusal(self, unit: int, pdu: bytes) -> str | None:
        """None when the request is allowed, else the reason (a key of ``_DENIED``)."""
        if self.refuse is not None:
            return self.refuse
        if self.units is not None and unit not in self.units:
            return "unit"
        fc = pdu[0] if pdu else -1
        if fc in READ_FUNCTIONS or (fc == MEI and pdu[1:2] == bytes((READ_DEVICE_ID,))):
            return None if self.read else "read"
        write = self.write
        if fc in RANGED_WRITES:
            if fc == READ_WRITE_MULTIPLE_REGISTERS and not self.read:
                return "read"
            if write is True:
                return None
            if write is False:
                return "write"
            try:
                span = written_range(pdu)
            except ValueError:  # too short to tell what it writes
                return "range"
            return None if span is not None and _covered(write, span[1], span[2]) else "range"
        if write is True:
            return None
        return "function" if write else "write"


READ_ONLY = Rules(read=True, write=False)


def _merge(ranges: list[tuple[int, int]]) -> tuple[tuple[int, int], ...]:
    out: list[tuple[int, int]] = []
    for first, last in sorted(ranges):
        if out and first <= out[-1][1] + 1:
            out[-1] = (out[-1][0], max(out[-1][1], last))
        else:
            out.append((first, last))
    return tuple(out)


def _covered(ranges: tuple[tuple[int, int], ...], start: int, count: int) -> bool:
    last = start + count - 1
    return any(first <= start and last <= end for first, end in ranges)


def _span(pdu: bytes) -> str:
    """`` (holding 100..101)`` for a write request, for a log line; else empty."""
    with contextlib.suppress(ValueError):
        span = written_range(pdu)
        if span is not None:
            return f" ({span[0]} {span[1]}..{span[1] + span[2] - 1})"
    return ""


_VERIFY_REASONS = {9: "not_yet_valid", 10: "expired", 2: "unknown_ca", 18: "unknown_ca",
                   19: "unknown_ca", 20: "unknown_ca", 21: "unknown_ca"}
_SSL_REASONS = {"PEER_DID_NOT_RETURN_A_CERTIFICATE": "no_certificate",
                "UNSUPPORTED_PROTOCOL": "old_protocol", "WRONG_SSL_VERSION": "old_protocol",
                "VERSION_TOO_LOW": "old_protocol", "WRONG_VERSION_NUMBER": "not_tls",
                "HTTP_REQUEST": "not_tls", "HTTPS_PROXY_REQUEST": "not_tls",
                "UNKNOWN_PROTOCOL": "not_tls", "PACKET_LENGTH_TOO_LONG": "not_tls"}


def handshake_reason(exc: BaseException) -> str:
    """Why a handshake failed, as a key of ``_REFUSED``."""
    if isinstance(exc, ssl.SSLCertVerificationError):
        return _VERIFY_REASONS.get(exc.verify_code, "bad_certificate")
    if isinstance(exc, ssl.SSLError):
        reason = exc.reason or ""
        if reason.startswith(("TLSV1_ALERT_", "SSLV3_ALERT_", "TLSV13_ALERT_")):
            return "client_alert"
        return _SSL_REASONS.get(reason, "other")
    if isinstance(exc, asyncio.TimeoutError | TimeoutError):
        return "timeout"
    if isinstance(exc, ConnectionError):
        return "aborted"
    return "other"


class TlsGate:
    """One TLS listener's context, role rules and refusal counters."""

    def __init__(self, config: TlsListen, context: ssl.SSLContext) -> None:
        self.config = config
        self.context = context
        self.rules = {name: Rules.of(role) for name, role in config.roles.items()}
        self.no_role = READ_ONLY if config.no_role == "read_only" else Rules(refuse="no_role")
        self.refused: Counter[str] = Counter()  # connections, by reason (_REFUSED)
        self.denied: Counter[tuple[str, str]] = Counter()  # requests, by (role, reason)

    def refuse(self, reason: str, peer: str, detail: str = "") -> None:
        self.refused[reason] += 1
        log.warning(_REFUSED[reason], peer, detail)

    async def serve(self, factory: Callable[[], asyncio.Protocol], host: str, port: int,
                    admit: Callable[[str], bool]) -> TlsServer:
        """Listen on ``host:port``: each allowed connection gets the TLS handshake, then a
        protocol from ``factory``; raises OSError if the address cannot be bound."""
        loop = asyncio.get_running_loop()
        infos = await loop.getaddrinfo(host, port, type=socket.SOCK_STREAM,
                                       flags=socket.AI_PASSIVE)
        if not infos:
            raise OSError(f"cannot resolve {host}")
        family, kind, proto, _, address = infos[0]
        sock = socket.socket(family, kind, proto)
        try:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            if family == socket.AF_INET6:
                sock.setsockopt(socket.IPPROTO_IPV6, socket.IPV6_V6ONLY, 1)
            sock.bind(address)
            sock.listen(100)
            sock.setblocking(False)
        except OSError:
            sock.close()
            raise
        return TlsServer(self, sock, factory, admit)

    def authoriser(self, transport: asyncio.BaseTransport, peer: str) -> Check | None:
        """The per-request check of a connection whose handshake succeeded (None: its role
        may do everything), from its certificate's role."""
        ssl_object = transport.get_extra_info("ssl_object")
        der = ssl_object.getpeercert(binary_form=True) if ssl_object is not None else None
        try:
            role = certificate_role(der) if der else None
        except (RoleError, ValueError) as err:
            self.refuse("bad_role", peer, f" ({err})")
            label, rules = BAD_ROLE, Rules(refuse="bad_role")
        else:
            if role is None:
                label, rules = NO_ROLE, self.no_role
            else:
                label, rules = role, self.rules.get(role, Rules(refuse="unknown_role"))
        log.debug("TLS client %s: role %s", peer, label)
        if rules.allows_all:
            return None
        denied = self.denied

        def check(unit: int, pdu: bytes) -> ModbusError | None:
            reason = rules.refusal(unit, pdu)
            if reason is None:
                return None
            denied[label, reason] += 1
            fc = pdu[0] if pdu else 0
            log.warning(_DENIED[reason], peer, label, fc, unit,
                        _span(pdu) if reason == "range" else "")
            return ModbusError(f"unit {unit}: FC{fc:02d} refused for role {label}",
                               ILLEGAL_FUNCTION)

        return check


class TlsServer(asyncio.AbstractServer):
    """A listening socket whose connections are handshaken before their protocol is made
    (what ``loop.create_server(ssl=...)`` does, but with failures seen here)."""

    def __init__(self, gate: TlsGate, sock: socket.socket,
                 factory: Callable[[], asyncio.Protocol], admit: Callable[[str], bool]) -> None:
        self.gate = gate
        self.sockets = [sock]
        self._factory = factory
        self._admit = admit
        self._loop = asyncio.get_running_loop()
        self._handshakes: set[asyncio.Task[None]] = set()
        self._closed = False
        self._task = self._loop.create_task(self._accept(), name="compgw-tls-accept")
        self._task.add_done_callback(lambda _: sock.close())

    async def _accept(self) -> None:
        loop, sock, config = self._loop, self.sockets[0], self.gate.config
        while True:
            try:
                conn, address = await loop.sock_accept(sock)
            except OSError as err:  # out of file descriptors, say: try again shortly
                log.warning("TLS listener: accept failed: %s", err)
                await asyncio.sleep(0.1)
                continue
            peer = f"{address[0]}:{address[1]}"
            if not self._admit(str(address[0])):
                self.gate.refuse("allowlist", peer)
                conn.close()
            elif len(self._handshakes) >= config.max_connections:
                self.gate.refuse("busy", peer, f" ({len(self._handshakes)})")
                conn.close()
            else:
                task = loop.create_task(self._handshake(conn, peer), name="compgw-tls-handshake")
                self._handshakes.add(task)
                task.add_done_callback(self._handshakes.discard)

    async def _handshake(self, conn: socket.socket, peer: str) -> None:
        timeout_s = self.gate.config.frame_timeout_s
        try:
            await asyncio.wait_for(self._loop.connect_accepted_socket(
                self._factory, conn, ssl=self.gate.context,
                ssl_handshake_timeout=timeout_s + 5.0), timeout_s)
        except asyncio.CancelledError:
            conn.close()
            raise
        except Exception as exc:
            conn.close()  # the transport, if one was made, has closed it already
            self.gate.refuse(handshake_reason(exc), peer, f" ({exc})" if str(exc) else "")

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        self._task.cancel()  # its done callback closes the listening socket
        for task in list(self._handshakes):
            task.cancel()

    def get_loop(self) -> asyncio.AbstractEventLoop:
        return self._loop

    def is_serving(self) -> bool:
        return not self._closed

    async def start_serving(self) -> None:
        return None

    async def serve_forever(self) -> None:
        with contextlib.suppress(asyncio.CancelledError):
            await self._task

    async def wait_closed(self) -> None:
        tasks = [self._task, *self._handshakes]
        await asyncio.wait(tasks)
