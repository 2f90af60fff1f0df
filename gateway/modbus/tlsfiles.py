"""The files of ``upstream.tls``: the server's SSL context, and what ``compgw check`` says
about them (readable, key matches certificate, certificate chains to ``ca``, dates).

Every problem is a ConfigError of one line naming the key and the file, e.g.
``upstream.tls.cert: /etc/compgw/server.pem: expired on 2026-11-01 00:00 UTC``.
"""

from __future__ import annotations

import datetime as dt
import ssl
from pathlib import Path

from cryptography import x509
from cryptography.exceptions import InvalidSignature
from cryptography.hazmat.primitives import serialization
from cryptography.hazmat.primitives.asymmetric.types import PrivateKeyTypes
from cryptography.x509.oid import NameOID

from ..config import ConfigError, TlsListen

#: a certificate that expires sooner than this gets a warning from `compgw check`
EXPIRY_WARNING = dt.timedelta(days=30)


def tls_path(path: str, base: Path | None) -> Path:
    """A path of the config, relative to the config file's directory."""
    p = Path(path)
    return p if p.is_absolute() or base is None else base / p


def server_context(tls: TlsListen, base: Path | None) -> ssl.SSLContext:
    """The listener's context: TLS >= 1.2, the server's certificate and key, client
    certificates required and verified against ``ca``."""
    cert, key, ca = (tls_path(p, base) for p in (tls.cert, tls.key, tls.ca))
    for name, path in (("cert", cert), ("key", key), ("ca", ca)):
        _read(name, path)  # a missing or unreadable file, named
    ctx = ssl.SSLContext(ssl.PROTOCOL_TLS_SERVER)
    ctx.minimum_version = ssl.TLSVersion.TLSv1_2
    ctx.verify_mode = ssl.CERT_REQUIRED
    try:
        ctx.load_cert_chain(cert, key)
    except ssl.SSLError as err:
        if err.reason == "KEY_VALUES_MISMATCH":
            raise ConfigError(f"upstream.tls.key: {key}: does not match the certificate "
                              f"{cert}") from None
        raise ConfigError(f"upstream.tls.cert, key: {cert}, {key}: {err}") from None
    try:
        ctx.load_verify_locations(cafile=ca)
    except ssl.SSLError as err:
        raise ConfigError(f"upstream.tls.ca: {ca}: {err}") from None
    return ctx


def _read(key: str, path: Path) -> bytes:
    try:
        return path.read_bytes()
    except OSError as err:
        raise ConfigError(f"upstream.tls.{key}: {path}: cannot read: {err.strerror}") from None


def _certificates(key: str, path: Path) -> list[x509.Certificate]:
    data = _read(key, path)  # (a ConfigError is a ValueError: read outside the try)
    try:
        return x509.load_pem_x509_certificates(data)
    except ValueError:
        raise ConfigError(f"upstream.tls.{key}: {path}: no PEM certificate in it") from None


def _private_key(path: Path) -> PrivateKeyTypes:
    data = _read("key", path)
    try:
        return serialization.load_pem_private_key(data, password=None)
    except TypeError:
        raise ConfigError(f"upstream.tls.key: {path}: the key is encrypted: the gateway "
                          "needs it unencrypted (readable by its user only)") from None
    except ValueError:
        raise ConfigError(f"upstream.tls.key: {path}: no PEM private key in it") from None


def _spki(public_key: object) -> bytes:
    return public_key.public_bytes(  # type: ignore[attr-defined]
        serialization.Encoding.DER, serialization.PublicFormat.SubjectPublicKeyInfo)


def _issued_by(cert: x509.Certificate, issuer: x509.Certificate) -> bool:
    try:
        cert.verify_directly_issued_by(issuer)
    except (ValueError, TypeError, InvalidSignature):
        return False
    return True


def chains_to(leaf: x509.Certificate, intermediates: list[x509.Certificate],
              cas: list[x509.Certificate]) -> x509.Certificate | None:
    """The CA of ``cas`` that ``leaf`` chains to (through ``intermediates``), or None."""
    current = leaf
    for _ in range(len(intermediates) + 1):
        for ca in cas:
            if _issued_by(current, ca):
                return ca
        step = next((c for c in intermediates if _issued_by(current, c)), None)
        if step is None:
            return None
        current = step
    return None


def _name(cert: x509.Certificate) -> str:
    cn = cert.subject.get_attributes_for_oid(NameOID.COMMON_NAME)
    return str(cn[0].value) if cn else cert.subject.rfc4514_string()


def _when(t: dt.datetime) -> str:
    return t.strftime("%Y-%m-%d %H:%M UTC")


def _dates(key: str, path: Path, cert: x509.Certificate, now: dt.datetime) -> list[str]:
    """Raise when ``cert`` is not valid at ``now``; a warning when it expires soon."""
    if now < cert.not_valid_before_utc:
        raise ConfigError(f"upstream.tls.{key}: {path}: not valid before "
                          f"{_when(cert.not_valid_before_utc)}")
    if now > cert.not_valid_after_utc:
        raise ConfigError(f"upstream.tls.{key}: {path}: expired on "
                          f"{_when(cert.not_valid_after_utc)}")
    left = cert.not_valid_after_utc - now
    if left < EXPIRY_WARNING:
        return [f"upstream.tls.{key}: {path} ({_name(cert)}) expires in {left.days} days, "
                f"on {_when(cert.not_valid_after_utc)}"]
    return []


def certificate_dates(tls: TlsListen, base: Path | None, now: dt.datetime | None = None
                      ) -> list[str]:  # fmt: skip
    """What the gateway checks of its certificate chain at start: ConfigError (one line)
    when one is expired or not yet valid (every handshake would fail, and the service
    would look ready while serving no one); warnings for one that expires within
    ``EXPIRY_WARNING``. (Whether it chains to ``ca`` is `compgw check`'s: a server
    certificate from another CA than the clients' is a setup some plants use.)"""
    now = now or dt.datetime.now(dt.timezone.utc)
    path = tls_path(tls.cert, base)
    warnings: list[str] = []
    for cert in _certificates("cert", path):
        warnings += _dates("cert", path, cert, now)
    return warnings


def check_files(tls: TlsListen, base: Path | None, now: dt.datetime | None = None
                ) -> tuple[list[str], list[str]]:
    """What `compgw check` prints about the TLS files, and its warnings; raises
    ConfigError (one line) when the listener could not run with them or a client could
    not trust them: unreadable, key not the certificate's, certificate not from ``ca``,
    any of them expired or not yet valid."""
    now = now or dt.datetime.now(dt.timezone.utc)
    cert_path, key_path, ca_path = (tls_path(p, base) for p in (tls.cert, tls.key, tls.ca))
    chain = _certificates("cert", cert_path)
    key = _private_key(key_path)
    cas = _certificates("ca", ca_path)
    leaf = chain[0]
    if _spki(key.public_key()) != _spki(leaf.public_key()):
        raise ConfigError(f"upstream.tls.key: {key_path}: does not match the certificate "
                          f"{cert_path}")
    ca = chains_to(leaf, chain[1:], cas)
    if ca is None:
        raise ConfigError(f"upstream.tls.cert: {cert_path}: not issued by a CA of "
                          f"upstream.tls.ca {ca_path} (issuer {leaf.issuer.rfc4514_string()})")
    warnings = certificate_dates(tls, base, now) + _dates("ca", ca_path, ca, now)
    mode = key_path.stat().st_mode & 0o777
    if mode & 0o027:  # group read is how a service user gets it (systemd/README.md)
        warnings.append(f"upstream.tls.key: {key_path} is open to others (mode {mode:o}): "
                        "chmod 600, or 640 with a group only the gateway is in")
    server_context(tls, base)  # what the listener will do with them
    try:
        names = leaf.extensions.get_extension_for_class(x509.SubjectAlternativeName).value
        sans = ", ".join(str(n.value) for n in names)
    except x509.ExtensionNotFound:
        sans = "none"
    lines = [f"tls cert {cert_path}: {_name(leaf)}, names {sans}, valid until "
             f"{_when(leaf.not_valid_after_utc)} ({(leaf.not_valid_after_utc - now).days} "
             f"days), issued by {_name(ca)} ({ca_path})"]
    return lines, warnings
