#!/usr/bin/env python3
"""A bridge between compgw and an instrument compgw cannot talk to itself.

compgw starts this script (``--laser "bridge:cmd:python3 bridge_template.py ..."``), writes
one request per line to its standard input and reads one answer per line from its standard
output (protocol version 1, docs/instruments-bridge.md):

    HELLO 1           ->  OK NAME channels=X,Y unit=um
    READ X [Y ...]    ->  OK 1234.567 [...] um STABLE   (or MOVING: compgw asks again)
    BYE               ->  OK
    anything wrong    ->  ERR what went wrong, in words

To adapt it to your instrument, change only :func:`read` (and :func:`setup` for the
arguments it needs): return the channel's value, its unit (mm, um, nm, deg, mdeg, udeg,
arcsec) and whether the reading may be taken now (your instrument's "capture when stable").
Raise an exception when it cannot read: the bridge answers ``ERR`` with its message.
Standard output carries answers only; anything you print for yourself goes to standard
error (compgw puts it in its log).

As shipped it reads the simulator's Modbus laser (``compgw sim -c config/example-sim.yaml``)
with pymodbus: channel k of ``--channels`` (the laser's axis order) at input registers 2k,
2k+1 (int32 nm, high word first), its stable flag at 2N + k (N channels). Try it by hand:

    python3 examples/bridge_template.py --modbus 127.0.0.1:5021:20 --channels X,Y
    HELLO 1
    READ X
"""

from __future__ import annotations

import argparse
import sys

NAME = "template-modbus-laser"  # the bridge's name in HELLO's answer (no spaces)
UNITS = ("mm", "um", "nm", "deg", "mdeg", "udeg", "arcsec")

CHANNELS: list[str] = []  # the channels this bridge can read (HELLO lists them)
_modbus: dict = {}  # the demonstration's connection: client, unit id


# --------------------------------------------------------------------- fill in here
def setup(args: argparse.Namespace) -> None:
    """Open the instrument once, before the first request (demonstration: Modbus TCP)."""
    from pymodbus.client import ModbusTcpClient  # pymodbus 3.16

    host, port, unit = args.modbus.rsplit(":", 2)
    CHANNELS[:] = args.channels.split(",")
    # short timeout, no retries: compgw has its own timeout (5 s) and asks again
    _modbus["client"] = ModbusTcpClient(host, port=int(port), timeout=1.0, retries=0)
    _modbus["unit"] = int(unit)


def read(channel: str) -> tuple[float, str, bool]:
    """One reading of ``channel``: (value, unit, stable). Replace the body for your
    instrument; raise an exception with a short message when it cannot read."""
    client = _modbus["client"]
    if not client.connected and not client.connect():
        raise ConnectionError("the laser's Modbus server does not answer")
    k, n = CHANNELS.index(channel), len(CHANNELS)
    # one request for every register: the value and its stable flag from the same sample
    rr = client.read_input_registers(0, count=3 * n, device_id=_modbus["unit"])
    if rr.isError():
        raise OSError(f"Modbus exception {getattr(rr, 'exception_code', '?')}")
    hi, lo = rr.registers[2 * k], rr.registers[2 * k + 1]
    raw = (hi << 16) | lo
    nm = raw - (1 << 32) if raw & 0x80000000 else raw  # int32, two's complement
    return nm / 1000.0, "um", rr.registers[2 * n + k] == 1


# --------------------------------------------------------------------- the protocol
def _number(value: float) -> str:
    """A decimal number (no exponent), to 1e-9."""
    text = f"{value:.9f}".rstrip("0").rstrip(".")
    return "0" if text in ("-0", "") else text


def _one_line(text: str) -> str:
    """An answer must stay one line: control characters become spaces."""
    return "".join(ch if ch.isprintable() else " " for ch in text)


def answer(line: str) -> tuple[str, bool]:
    """The answer to one request line, and whether the bridge should exit after it."""
    fields = line.rstrip("\r\n").split(" ")
    command, args = fields[0], fields[1:]
    if command == "HELLO":
        if args != ["1"]:
            return "ERR only protocol version 1 is spoken here", False
        return f"OK {NAME} channels={','.join(CHANNELS)} unit=um", False
    if command == "BYE":
        return "OK", True
    if command == "READ":
        if not args:
            return "ERR READ needs a channel", False
        unknown = [ch for ch in args if ch not in CHANNELS]
        if unknown:
            return f"ERR unknown channel {unknown[0]} (channels {','.join(CHANNELS)})", False
        readings = [read(ch) for ch in args]
        units = {unit for _value, unit, _stable in readings}
        if len(units) != 1 or not units <= set(UNITS):
            return f"ERR the channels answered in units {sorted(units)}", False
        values = " ".join(_number(value) for value, _unit, _stable in readings)
        state = "STABLE" if all(stable for _v, _u, stable in readings) else "MOVING"
        return f"OK {values} {units.pop()} {state}", False
    return _one_line(f"ERR unknown request {command[:40]}"), False


def main(argv: list[str] | None = None) -> int:
    """Answer requests from standard input until BYE or end of input."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--modbus", default="127.0.0.1:5021:20", help="HOST:PORT:UNIT")
    parser.add_argument("--channels", default="X,Y", help="the laser's axes, in order")
    args = parser.parse_args(argv)
    sys.stdin.reconfigure(encoding="utf-8", errors="replace")
    sys.stdout.reconfigure(encoding="utf-8", newline="\n")
    try:
        setup(args)
    except Exception as err:  # answered on every request rather than dying unseen
        print(f"bridge: setup failed: {err}", file=sys.stderr)
        failed = _one_line(f"ERR setup failed: {type(err).__name__}: {err}")
    else:
        failed = ""
    while True:
        line = sys.stdin.readline()
        if not line:  # compgw closed our input: done
            return 0
        if not line.strip():
            text, done = "ERR empty request", False
        elif failed and not line.startswith(("HELLO", "BYE")):
            text, done = failed, False
        else:
            try:
                text, done = answer(line)
            except Exception as err:  # never a traceback on stdout: one ERR line instead
                text, done = _one_line(f"ERR {type(err).__name__}: {err}"), False
        sys.stdout.write(text + "\n")
        sys.stdout.flush()  # compgw waits for this line: never leave it in a buffer
        if done:
            return 0


if __name__ == "__main__":
    sys.exit(main())
