"""Certificates made in the test, with `cryptography`: a CA, a server certificate for
127.0.0.1, client certificates carrying an MB-TCP-Security role (or none), one from
another CA, an expired one. P-256 keys: fast to make and to handshake."""

from __future__ import annotations

import datetime as dt
import ipaddress
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from cryptography import x509
from cryptography.hazmat import asn1
from cryptography.hazmat.primitives import hashes, serialization
from cryptography.hazmat.primitives.asymmetric import ec, ed25519
from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

ROLE_OID = x509.ObjectIdentifier("1.3.6.1.4.1.50316.802.1")
_SAME_LENGTH_OID = x509.ObjectIdentifier("1.3.6.1.4.1.50316.802.2")
NOW = dt.datetime.now(dt.timezone.utc)
DAY = dt.timedelta(days=1)


@dataclass(frozen=True)
class Issued:
    """A certificate and its key, also written as PEM files."""

    cert: x509.Certificate
    key: Any  # a private key
    cert_path: Path
    key_path: Path


def _name(common_name: str) -> x509.Name:
    return x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, common_name)])


def _write(directory: Path, stem: str, cert: x509.Certificate, key: Any) -> Issued:
    cert_path, key_path = directory / f"{stem}.pem", directory / f"{stem}.key"
    cert_path.write_bytes(cert.public_bytes(serialization.Encoding.PEM))
    key_path.write_bytes(key.private_bytes(serialization.Encoding.PEM,
                                           serialization.PrivateFormat.PKCS8,
                                           serialization.NoEncryption()))
    key_path.chmod(0o600)
    return Issued(cert, key, cert_path, key_path)


def make_ca(directory: Path, stem: str = "ca", common_name: str = "compgw test CA") -> Issued:
    key = ec.generate_private_key(ec.SECP256R1())
    cert = (x509.CertificateBuilder()
            .subject_name(_name(common_name)).issuer_name(_name(common_name))
            .public_key(key.public_key()).serial_number(x509.random_serial_number())
            .not_valid_before(NOW - DAY).not_valid_after(NOW + 3650 * DAY)
            .add_extension(x509.BasicConstraints(ca=True, path_length=None), critical=True)
            .add_extension(x509.KeyUsage(False, False, False, False, False, True, True, False,
                                         False), critical=True)
            .sign(key, hashes.SHA256()))
    return _write(directory, stem, cert, key)


def issue(directory: Path, stem: str, ca: Issued, *, server: bool = False,
          role: str | None = None, role_der: bytes | None = None,
          not_before: dt.datetime | None = None, not_after: dt.datetime | None = None,
          key: ec.EllipticCurvePrivateKey | None = None) -> Issued:
    """A leaf certificate signed by ``ca``: a server one for 127.0.0.1, or a client one
    with ``role`` (a UTF8String) or ``role_der`` (any DER, to test bad encodings)."""
    key = key or ec.generate_private_key(ec.SECP256R1())
    builder = (x509.CertificateBuilder()
               .subject_name(_name(stem)).issuer_name(ca.cert.subject)
               .public_key(key.public_key()).serial_number(x509.random_serial_number())
               .not_valid_before(not_before or NOW - DAY)
               .not_valid_after(not_after or NOW + 365 * DAY)
               .add_extension(x509.BasicConstraints(ca=False, path_length=None),
                              critical=True))
    if server:
        builder = (builder
                   .add_extension(x509.SubjectAlternativeName(
                       [x509.IPAddress(ipaddress.ip_address("127.0.0.1"))]), critical=False)
                   .add_extension(x509.ExtendedKeyUsage([ExtendedKeyUsageOID.SERVER_AUTH]),
                                  critical=False))
    else:
        builder = builder.add_extension(
            x509.ExtendedKeyUsage([ExtendedKeyUsageOID.CLIENT_AUTH]), critical=False)
    if role is not None:
        role_der = asn1.encode_der(role)
    if role_der is not None:
        builder = builder.add_extension(x509.UnrecognizedExtension(ROLE_OID, role_der),
                                        critical=False)
    return _write(directory, stem, builder.sign(ca.key, hashes.SHA256()), key)


def make_ed25519_ca(directory: Path, stem: str = "ed-ca") -> Issued:
    """A CA whose signatures are always 64 bytes (see :func:`issue_duplicate_role`)."""
    key = ed25519.Ed25519PrivateKey.generate()
    cert = (x509.CertificateBuilder()
            .subject_name(_name("compgw Ed25519 CA")).issuer_name(_name("compgw Ed25519 CA"))
            .public_key(key.public_key()).serial_number(x509.random_serial_number())
            .not_valid_before(NOW - DAY).not_valid_after(NOW + 3650 * DAY)
            .add_extension(x509.BasicConstraints(ca=True, path_length=None), critical=True)
            .add_extension(x509.KeyUsage(False, False, False, False, False, True, True, False,
                                         False), critical=True)
            .sign(key, None))
    return _write(directory, stem, cert, key)


def issue_duplicate_role(directory: Path, stem: str, ed_ca: Issued) -> Issued:
    """A client certificate with the role extension twice ("operator", "monitor"), which
    no certificate builder makes: one is made with a second extension whose OID has the
    same length, that OID is swapped in the signed bytes, and they are signed again (an
    Ed25519 signature keeps its length, so every length in the DER stays right)."""
    key = ec.generate_private_key(ec.SECP256R1())
    cert = (x509.CertificateBuilder()
            .subject_name(_name(stem)).issuer_name(ed_ca.cert.subject)
            .public_key(key.public_key()).serial_number(x509.random_serial_number())
            .not_valid_before(NOW - DAY).not_valid_after(NOW + 365 * DAY)
            .add_extension(x509.ExtendedKeyUsage([ExtendedKeyUsageOID.CLIENT_AUTH]),
                           critical=False)
            .add_extension(x509.UnrecognizedExtension(ROLE_OID, asn1.encode_der("operator")),
                           critical=False)
            .add_extension(x509.UnrecognizedExtension(_SAME_LENGTH_OID,
                                                      asn1.encode_der("monitor")),
                           critical=False)
            .sign(ed_ca.key, None))
    tbs = cert.tbs_certificate_bytes
    swapped = tbs.replace(asn1.encode_der(_SAME_LENGTH_OID), asn1.encode_der(ROLE_OID))
    der = cert.public_bytes(serialization.Encoding.DER)
    der = der.replace(tbs, swapped).replace(cert.signature, ed_ca.key.sign(swapped))
    return _write(directory, stem, x509.load_der_x509_certificate(der), key)
