"""Modbus/TCP Security end to end: pymodbus's TLS client → the gateway's TLS listener →
the simulated drives, with certificates made here (a CA, the server, clients with roles
``operator``, ``monitor``, a write-range ``setter``, none, an invalid one, one from another
CA, one expired). Handshake refusals also with ``openssl s_client`` and a plain client."""

from __future__ import annotations

import asyncio
import os
import re
import shutil
import signal
import ssl
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
import yaml
from cryptography.hazmat import asn1
from pymodbus.client import AsyncModbusTlsClient

from gateway.cli import main as cli_main
from gateway.compensation import AxisInput
from gateway.modbus.frames import pack_int32
from tests.gateway_rig import FEEDBACK, SIM_EXAMPLE, TARGET, TRIGGER, base_config, rig
from tests.helpers_modbus import wait_for_condition
from tests.test_gateway_e2e import PITCH_X, move, read32, with_pitch
from tests.test_metrics import scrape, value
from tests.tls_certs import (
    DAY,
    NOW,
    Issued,
    issue,
    issue_duplicate_role,
    make_ca,
    make_ed25519_ca,
)

ROOT = Path(__file__).resolve().parent.parent
ROLES = {
    "operator": {"units": "all", "read": True, "write": True},
    "monitor": {"read": True, "write": False},
    "setter": {"units": [1], "read": False, "write": [[TARGET, TARGET + 1]]},
}


def run(coro, timeout_s: float = 20.0):
    return asyncio.run(asyncio.wait_for(coro, timeout_s))


@pytest.fixture(scope="module")
def pki(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Issued]:
    d = tmp_path_factory.mktemp("pki")
    ca, other, ed_ca = make_ca(d), make_ca(d, "other-ca", "another CA"), make_ed25519_ca(d)
    server = issue(d, "server", ca, server=True)
    bundle = d / "bundle.pem"  # the gateway trusts both CAs
    bundle.write_bytes(ca.cert_path.read_bytes() + ed_ca.cert_path.read_bytes())
    return {
        "ca": ca, "other_ca": other, "server": server,
        "bundle": Issued(ca.cert, ca.key, bundle, ca.key_path),
        "duplicate": issue_duplicate_role(d, "duplicate", ed_ca),
        "operator": issue(d, "operator", ca, role="operator"),
        "monitor": issue(d, "monitor", ca, role="monitor"),
        "setter": issue(d, "setter", ca, role="setter"),
        "guest": issue(d, "guest", ca, role="guest"),  # a role the gateway does not know
        "none": issue(d, "none", ca),
        "printable": issue(d, "printable", ca, role_der=b"\x13\x08operator"),
        "foreign": issue(d, "foreign", other, role="operator"),
        "expired": issue(d, "expired", ca, role="operator", not_before=NOW - 10 * DAY,
                         not_after=NOW - DAY),
        "server_expired": issue(d, "server-expired", ca, server=True,
                                not_before=NOW - 10 * DAY, not_after=NOW - DAY),
        "server_soon": issue(d, "server-soon", ca, server=True, not_after=NOW + 10 * DAY),
        "server_foreign": issue(d, "server-foreign", other, server=True),
    }


def tls_section(pki: dict[str, Issued], no_role: str = "refuse", **extra: Any) -> dict:
    return {"host": "127.0.0.1", "port": 0, "cert": str(pki["server"].cert_path),
            "key": str(pki["server"].key_path), "ca": str(pki["bundle"].cert_path),
            "roles": ROLES, "no_role": no_role, **extra}


def with_tls(pki: dict[str, Issued], no_role: str = "refuse") -> Callable[[dict], None]:
    def edit(data: dict) -> None:
        with_pitch(data)
        data["upstream"]["tls"] = tls_section(pki, no_role)
        data["metrics"] = {"port": 0}

    return edit


def client_context(pki: dict[str, Issued], who: str | None) -> ssl.SSLContext:
    ctx = ssl.create_default_context(cafile=str(pki["ca"].cert_path))
    if who is not None:
        ctx.load_cert_chain(pki[who].cert_path, pki[who].key_path)
    return ctx


def tls_client(port: int, ctx: ssl.SSLContext) -> AsyncModbusTlsClient:
    return AsyncModbusTlsClient("127.0.0.1", port=port, sslctx=ctx, timeout=2, retries=0,
                                reconnect_delay=0)


async def as_client(r: dict, pki: dict[str, Issued], who: str | None) -> AsyncModbusTlsClient:
    client = tls_client(r["app"].tls.port, client_context(pki, who))
    assert await client.connect()
    return client


async def refused_at_handshake(port: int, ctx: ssl.SSLContext) -> bool:
    """A Python ssl client sends a target write: True when the connection ends unanswered
    (with TLS 1.3 the client's side of the handshake completes before the server's)."""
    try:
        reader, writer = await asyncio.open_connection("127.0.0.1", port, ssl=ctx)
    except (ssl.SSLError, ConnectionError):
        return True
    writer.write(bytes.fromhex("00010000000b01106201000204000100e240"))
    try:
        data = await asyncio.wait_for(reader.read(), 5)
    except (ssl.SSLError, ConnectionError):
        data = b""
    writer.close()
    return data == b""


def test_operator_moves_the_axis_and_the_drive_gets_the_corrected_target(
        tmp_path: Path, pki: dict[str, Issued]):
    async def body():
        async with rig(tmp_path, with_tls(pki), {"x.csv": PITCH_X}) as r:
            client = await as_client(r, pki, "operator")
            try:
                await move(client, 1, 300_000)
                expected = r["chain"].command_pulses("X", {"X": AxisInput(300_000, 1)})
                assert expected == pytest.approx(300_000 - 16, abs=1)  # the pitch table's
                assert await read32(r["direct"], 1, TARGET) == expected  # what the drive got
                assert await read32(client, 1, FEEDBACK) == 300_000  # nominal, over TLS
            finally:
                client.close()
            assert r["app"].tls.tls.denied == {}

    run(body())


def test_monitor_reads_but_its_write_gets_0x01_and_the_drive_is_unchanged(
        tmp_path: Path, pki: dict[str, Issued]):
    async def body():
        async with rig(tmp_path, with_tls(pki), {"x.csv": PITCH_X}) as r:
            await move(r["master"], 1, 200_000)  # plain TCP on loopback: allowed as ever
            before = await read32(r["direct"], 1, TARGET)
            client = await as_client(r, pki, "monitor")
            try:
                assert await read32(client, 1, TARGET) == 200_000  # reads: yes
                reply = await client.write_registers(TARGET, list(pack_int32(400_000)),
                                                     device_id=1)
                assert reply.isError() and reply.exception_code == 0x01
                reply = await client.write_register(TRIGGER, 0x10, device_id=1)
                assert reply.isError() and reply.exception_code == 0x01
                assert await read32(r["direct"], 1, TARGET) == before  # nothing forwarded
                assert await read32(client, 1, FEEDBACK) == 200_000  # still served
            finally:
                client.close()
            gate = r["app"].tls.tls
            assert gate.denied == {("monitor", "write"): 2}
            _, metrics = await scrape(r["app"].metrics.port)
            assert value(metrics, "compgw_role_denied_total", role="monitor",
                         reason="write") == 2

    run(body())


def test_write_ranges_and_units_of_a_role(tmp_path: Path, pki: dict[str, Issued]):
    async def body():
        async with rig(tmp_path, with_tls(pki), {"x.csv": PITCH_X}) as r:
            client = await as_client(r, pki, "setter")
            try:  # setter: unit 1, writes of the target pair only, no reads
                reply = await client.write_registers(TARGET, list(pack_int32(250_000)),
                                                     device_id=1)
                assert not reply.isError(), reply
                for call in (client.write_register(TRIGGER, 0x10, device_id=1),  # range
                             client.write_registers(TARGET, [0, 1, 2], device_id=1),  # range
                             client.write_registers(TARGET, [0, 1], device_id=2),  # unit
                             client.read_holding_registers(TARGET, count=2, device_id=1),
                             client.diag_read_bus_message_count(device_id=1)):  # FC08
                    reply = await call
                    assert reply.isError() and reply.exception_code == 0x01, reply
            finally:
                client.close()
            assert await read32(r["master"], 1, TARGET) == 250_000  # written, not moved
            assert r["app"].tls.tls.denied == {("setter", "range"): 2, ("setter", "unit"): 1,
                                               ("setter", "read"): 1,
                                               ("setter", "function"): 1}

    run(body())


@pytest.mark.parametrize("no_role", ["refuse", "read_only"])
def test_a_certificate_without_role_gets_the_no_role_rule(tmp_path: Path,
                                                          pki: dict[str, Issued], no_role: str):
    async def body():
        async with rig(tmp_path, with_tls(pki, no_role), {"x.csv": PITCH_X}) as r:
            before = await read32(r["direct"], 1, TARGET)
            client = await as_client(r, pki, "none")
            try:
                read = await client.read_holding_registers(FEEDBACK, count=2, device_id=1)
                write = await client.write_registers(TARGET, list(pack_int32(99_000)),
                                                     device_id=1)
            finally:
                client.close()
            assert write.isError() and write.exception_code == 0x01
            if no_role == "refuse":
                assert read.isError() and read.exception_code == 0x01
                assert r["app"].tls.tls.denied == {("(none)", "no_role"): 2}
            else:
                assert not read.isError(), read
                assert r["app"].tls.tls.denied == {("(none)", "write"): 1}
            assert await read32(r["direct"], 1, TARGET) == before

    run(body())


def test_unknown_and_invalid_roles_may_do_nothing(tmp_path: Path, pki: dict[str, Issued]):
    async def body():
        async with rig(tmp_path, with_tls(pki, "read_only"), {"x.csv": PITCH_X}) as r:
            for who in ("guest", "printable", "duplicate"):
                client = await as_client(r, pki, who)
                try:
                    read = await client.read_holding_registers(FEEDBACK, count=2, device_id=1)
                    assert read.isError() and read.exception_code == 0x01, (who, read)
                finally:
                    client.close()
            gate = r["app"].tls.tls
            assert gate.denied == {("guest", "unknown_role"): 1, ("(invalid)", "bad_role"): 2}
            assert gate.refused == {"bad_role": 2}

    run(body())


async def s_client(port: int, pki: dict[str, Issued], *args: str) -> int:
    proc = await asyncio.create_subprocess_exec(
        "openssl", "s_client", "-connect", f"127.0.0.1:{port}", "-CAfile",
        str(pki["ca"].cert_path), *args, stdin=subprocess.PIPE, stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL)
    await asyncio.wait_for(proc.communicate(b""), 10)
    assert proc.returncode is not None
    return proc.returncode


def test_handshakes_refused_without_a_good_certificate_or_with_old_tls(
        tmp_path: Path, pki: dict[str, Issued], caplog: pytest.LogCaptureFixture):
    async def body():
        async with rig(tmp_path, with_tls(pki), {"x.csv": PITCH_X}) as r:
            port = r["app"].tls.port
            gate = r["app"].tls.tls
            before = await read32(r["direct"], 1, TARGET)
            cases = {"no_certificate": client_context(pki, None),
                     "unknown_ca": client_context(pki, "foreign"),
                     "expired": client_context(pki, "expired")}
            for reason, ctx in cases.items():
                assert await refused_at_handshake(port, ctx), reason
                await wait_for_condition(lambda reason=reason: gate.refused[reason] == 1)
            reader, writer = await asyncio.open_connection("127.0.0.1", port)  # plain Modbus
            writer.write(bytes.fromhex("000100000006010300000001"))
            assert await reader.read() == b""  # closed, never answered
            writer.close()
            await wait_for_condition(lambda: gate.refused["not_tls"] == 1)
            if shutil.which("openssl"):
                assert await s_client(port, pki, "-tls1_1", "-cert",
                                      str(pki["operator"].cert_path), "-key",
                                      str(pki["operator"].key_path)) != 0
                await wait_for_condition(lambda: gate.refused["old_protocol"] == 1)
                assert await s_client(port, pki, "-tls1_2") != 0  # no certificate, TLS 1.2
                await wait_for_condition(lambda: gate.refused["no_certificate"] == 2)
            assert await read32(r["direct"], 1, TARGET) == before
            assert gate.denied == {}
            assert r["app"].tls.counters.connections == 0  # none got past the handshake
            templates = {rec.msg for rec in caplog.records
                         if rec.name == "gateway.modbus.mbsecurity"}
            assert len(templates) == len(gate.refused)  # one log kind per reason
            _, metrics = await scrape(r["app"].metrics.port)
            assert value(metrics, "compgw_tls_refused_total", reason="expired") == 1
        if not shutil.which("openssl"):
            pytest.skip("openssl not installed: the TLS 1.1 and s_client cases were not run")

    run(body())


def check_config(tmp_path: Path, pki: dict[str, Issued], cert: str = "server",
                 key: str | None = None) -> Path:
    """A gateway config whose upstream.tls names the files relative to it."""
    for name, issued in (("server.pem", pki[cert].cert_path), ("server.key",
                         pki[key or cert].key_path), ("ca.pem", pki["ca"].cert_path)):
        shutil.copy(issued, tmp_path / name)
    (tmp_path / "server.key").chmod(0o600)
    data = base_config(5021)
    data["upstream"]["tls"] = {"cert": "server.pem", "key": "server.key", "ca": "ca.pem",
                               "roles": ROLES}
    path = tmp_path / "gw.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


@pytest.mark.parametrize(("cert", "key", "error"), [
    ("server_expired", None, r"upstream\.tls\.cert: .*server\.pem: expired on "),
    ("server", "operator", r"upstream\.tls\.key: .*server\.key: does not match the cert"),
    ("server_foreign", None, r"upstream\.tls\.cert: .*server\.pem: not issued by a CA of "),
])
def test_check_refuses_bad_tls_files(tmp_path: Path, pki: dict[str, Issued], capsys,
                                     cert: str, key: str | None, error: str):
    assert cli_main(["check", "-c", str(check_config(tmp_path, pki, cert, key))]) == 1
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1
    assert __import__("re").search(error, err), err


def test_check_prints_the_tls_files_and_warns_before_expiry(tmp_path: Path,
                                                            pki: dict[str, Issued], capsys):
    assert cli_main(["check", "-c", str(check_config(tmp_path, pki))]) == 0
    out = capsys.readouterr()
    assert "tls cert" in out.out and "names 127.0.0.1" in out.out and "valid until" in out.out
    assert "operator (units all, read, write)" in out.out
    assert "setter (units 1, no read, write 0x6201-0x6202)" in out.out
    assert "expires in" not in out.err
    assert cli_main(["check", "-c", str(check_config(tmp_path, pki, "server_soon"))]) == 0
    assert "server.pem (server-soon) expires in 9 days" in capsys.readouterr().err
    (tmp_path / "server.key").chmod(0o644)
    assert cli_main(["check", "-c", str(tmp_path / "gw.yaml")]) == 0
    assert "server.key is open to others (mode 644)" in capsys.readouterr().err


def test_the_daemon_refuses_to_start_without_its_tls_files(tmp_path: Path,
                                                           pki: dict[str, Issued], caplog):
    from gateway.app import serve

    path = check_config(tmp_path, pki)
    (tmp_path / "server.key").unlink()
    assert asyncio.run(serve(path)) == 1  # bad input: systemd does not restart it in a loop
    errors = [r.getMessage() for r in caplog.records if r.levelname == "ERROR"]
    assert len(errors) == 1 and "upstream.tls.key: " in errors[0], errors
    assert "server.key: cannot read: No such file or directory" in errors[0]
    # nor on an expired certificate: every handshake would fail while it looked ready
    caplog.clear()
    path = check_config(tmp_path, pki, "server_expired")
    assert asyncio.run(serve(path)) == 1
    errors = [r.getMessage() for r in caplog.records if r.levelname == "ERROR"]
    assert len(errors) == 1 and re.search(r"upstream\.tls\.cert: .*server\.pem: expired on ",
                                          errors[0]), errors  # fmt: skip


def test_the_daemon_warns_of_a_certificate_that_expires_soon(tmp_path: Path,
                                                             pki: dict[str, Issued]):
    """What the daemon checks at start of its certificates: their dates (``compgw check``
    checks the rest); 30 days ahead it warns."""
    from gateway.config import load_config
    from gateway.modbus.tlsfiles import certificate_dates

    tls = load_config(check_config(tmp_path, pki)).upstream.tls
    assert tls is not None and certificate_dates(tls, tmp_path) == []
    tls = load_config(check_config(tmp_path, pki, "server_soon")).upstream.tls
    assert tls is not None
    warned = certificate_dates(tls, tmp_path)
    assert len(warned) == 1 and "server.pem (server-soon) expires in 9 days" in warned[0]


def test_check_says_a_missing_tls_file_is_missing(tmp_path: Path, pki: dict[str, Issued],
                                                  capsys):
    """Not "no PEM certificate in it": the file is not there."""
    path = check_config(tmp_path, pki)
    for name, key in (("ca.pem", "ca"), ("server.pem", "cert"), ("server.key", "key")):
        (tmp_path / name).rename(tmp_path / f"{name}.away")
        assert cli_main(["check", "-c", str(path)]) == 1
        err = capsys.readouterr().err
        assert f"upstream.tls.{key}: " in err and f"{name}: cannot read: No such file" in err
        (tmp_path / f"{name}.away").rename(tmp_path / name)


def test_compgw_run_on_uvloop_serves_tls(tmp_path: Path, pki: dict[str, Issued]):
    """The daemon as systemd starts it (`compgw run`, uvloop): TLS served, SIGTERM ends it."""
    from sim.config import parse_config as parse_sim_config
    from sim.server import SimServer
    from tests.test_sim_support import example_dict

    async def body():
        sim_cfg = parse_sim_config(example_dict(), SIM_EXAMPLE.parent)
        async with SimServer(sim_cfg, tcp_port=0, time_scale=0) as sim:
            data = base_config(sim.tcp_port)
            data["upstream"] = {"tls": tls_section(pki)}
            path = tmp_path / "gw.yaml"
            path.write_text(yaml.safe_dump(data))
            proc = await asyncio.create_subprocess_exec(
                sys.executable, "-c", "import sys; from gateway.cli import main; "
                "sys.exit(main(sys.argv[1:]))", "run", "-c", str(path), "--log-level", "debug",
                cwd=ROOT, stderr=subprocess.PIPE, env={**os.environ, "PYTHONASYNCIODEBUG": ""})
            stderr = proc.stderr
            assert stderr is not None

            async def line_with(text: str) -> str:
                while True:
                    line = (await asyncio.wait_for(stderr.readline(), 10)).decode()
                    assert line, f"compgw run ended before logging {text!r}"
                    assert "Using selector" not in line, "not on uvloop: " + line
                    if text in line:
                        return line

            try:
                line = await line_with("TCP Security (TLS) server listening on")
                port = int(line.rsplit(":", 1)[1])
                client = tls_client(port, client_context(pki, "operator"))
                assert await client.connect()
                await move(client, 2, 100_000)
                assert await read32(client, 2, FEEDBACK) == 100_000
                client.close()
                # compgw status over TLS with a monitor's certificate; without one it says so
                status = ["-m", "gateway.cli", "status", "-c", str(path), "--port", str(port)]
                monitor = ["--cert", str(pki["monitor"].cert_path),
                           "--key", str(pki["monitor"].key_path),
                           "--ca", str(pki["ca"].cert_path)]  # fmt: skip
                out = subprocess.run([sys.executable, *status, *monitor], cwd=ROOT,
                                     capture_output=True, text=True, timeout=30)  # fmt: skip
                assert out.returncode == 0 and "config generation" in out.stdout, out
                out = subprocess.run([sys.executable, *status], cwd=ROOT,
                                     capture_output=True, text=True, timeout=30)  # fmt: skip
                assert out.returncode == 1 and out.stderr.strip() == (
                    "compgw status: the config serves only Modbus/TCP Security (upstream.tls): "
                    "give --cert and --key of a master's certificate whose role reads (e.g. "
                    "monitor), or add upstream.tcp on loopback"), out.stderr
                assert await refused_at_handshake(port, client_context(pki, "expired"))
                await line_with("certificate expired")
                proc.send_signal(signal.SIGTERM)
                assert await asyncio.wait_for(proc.wait(), 10) == 0
            finally:
                if proc.returncode is None:
                    proc.kill()
                    await proc.wait()

    run(body(), 30.0)


def test_role_is_read_from_the_extension_and_an_invalid_one_is_refused(
        pki: dict[str, Issued]):
    from gateway.modbus.mbsecurity import RoleError, certificate_role

    def der(who: str) -> bytes:
        from cryptography.hazmat.primitives.serialization import Encoding
        return pki[who].cert.public_bytes(Encoding.DER)

    assert certificate_role(der("operator")) == "operator"
    assert certificate_role(der("none")) is None
    assert asn1.decode_der(str, asn1.encode_der("monitor")) == "monitor"
    with pytest.raises(RoleError, match="not a DER UTF8String"):
        certificate_role(der("printable"))
    with pytest.raises(RoleError, match="more than once"):
        certificate_role(der("duplicate"))


def test_rules_sort_every_function_into_read_write_or_neither():
    from gateway.config import TlsRole
    from gateway.modbus.mbsecurity import READ_ONLY, Rules

    monitor = Rules.of(TlsRole(read=True, write=False))
    setter = Rules.of(TlsRole(units=[1], read=False, write=[(0x6201, 0x6201), (0x6202, 0x6203)]))
    fc16 = "10{:04x}0002040000000a"
    cases = [  # (rules, unit, PDU hex, refusal)
        (monitor, 1, "0300000002", None), (monitor, 9, "0400000001", None),
        (monitor, 0, "2b0e0100", None),  # read device identification
        (monitor, 1, "2b0d00", "write"), (monitor, 1, "0800000000", "write"),
        (monitor, 1, "17000000010000000102ffff", "write"), (monitor, 1, "0600000001", "write"),
        (setter, 1, fc16.format(0x6201), None), (setter, 1, "0562020000", None),  # coil
        (setter, 1, fc16.format(0x6200), "range"), (setter, 1, fc16.format(0x6203), "range"),
        (setter, 1, "066201", "range"),  # too short to tell what it writes
        (setter, 1, "1700000001620100010200ff", "read"), (setter, 1, "0300000001", "read"),
        (setter, 1, "0800000000", "function"), (setter, 1, "63", "function"),
        (setter, 0, fc16.format(0x6201), "unit"), (setter, 2, fc16.format(0x6201), "unit"),
        (READ_ONLY, 1, fc16.format(0x6201), "write"),
    ]
    for rules, unit, pdu, refusal in cases:
        assert rules.refusal(unit, bytes.fromhex(pdu)) == refusal, (rules, unit, pdu)
    assert Rules.of(TlsRole(write=True)).allows_all and not monitor.allows_all
    assert setter.write == ((0x6201, 0x6203),)  # adjacent ranges merged
