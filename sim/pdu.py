"""Modbus PDU handling for the simulated units: parse a request PDU, call the unit, encode.

Works on raw PDU bytes (function code + data) so that the transports (TCP, RTU) only frame
and unframe, and every unit sees exactly one call per request (no double calls, no lost
transaction ids). Supported: FC03, FC04, FC06, FC16, FC23, and FC01, FC02, FC05, FC15 for
units with coils (:meth:`BitUnit.read_bits`, :meth:`BitUnit.write_coils`); anything else ->
exception 0x01.
"""

from __future__ import annotations

import struct
from typing import Protocol

ILLEGAL_FUNCTION = 0x01
ILLEGAL_ADDRESS = 0x02
ILLEGAL_VALUE = 0x03
DEVICE_FAILURE = 0x04
GATEWAY_NO_RESPONSE = 0x0B


class ModbusError(Exception):
    """Raised by a unit to answer with a Modbus exception code."""

    def __init__(self, code: int, why: str = "") -> None:
        super().__init__(f"exception {code:#04x}{': ' + why if why else ''}")
        self.code = code


class RegisterUnit(Protocol):
    """What a simulated unit implements; register addresses are 0-based PDU addresses."""

    def read(self, table: str, address: int, count: int) -> list[int]:
        """Read ``count`` registers from ``table`` ("holding" or "input")."""
        ...

    def write(self, address: int, values: list[int], function_code: int) -> None:
        """Write holding registers (all or nothing); raise ModbusError to refuse."""
        ...


class BitUnit(Protocol):
    """What a unit with coils adds (optional: a unit without them, or whose ``has_coils``
    is false, answers FC01/02/05/15 with exception 0x01, whatever the request's length)."""

    has_coils: bool

    def read_bits(self, table: str, address: int, count: int) -> list[int]:
        """Read ``count`` bits of ``table`` ("coils" or "discrete")."""
        ...

    def write_coils(self, address: int, bits: list[int], function_code: int) -> None:
        """Write coils (values 0/1; all or nothing); raise ModbusError to refuse."""
        ...


def exception_pdu(function_code: int, code: int) -> bytes:
    """The exception response for a request with this function code."""
    return bytes([(function_code | 0x80) & 0xFF, code & 0xFF])


def _registers(values: list[int]) -> bytes:
    return struct.pack(f">B{len(values)}H", 2 * len(values), *values)


def handle_pdu(unit: RegisterUnit, pdu: bytes) -> bytes:
    """Execute one request PDU against ``unit`` and return the response PDU."""
    if not pdu:
        raise ValueError("empty PDU")
    fc = pdu[0]
    try:
        return _dispatch(unit, fc, pdu[1:])
    except ModbusError as err:
        return exception_pdu(fc, err.code)
    except struct.error:
        return exception_pdu(fc, ILLEGAL_VALUE)


def _dispatch(unit: RegisterUnit, fc: int, data: bytes) -> bytes:
    if fc in (0x03, 0x04):
        _check_length(data, 4)
        address, count = struct.unpack(">HH", data)
        if not 1 <= count <= 125:
            raise ModbusError(ILLEGAL_VALUE, "read count")
        _check_span(address, count)
        values = unit.read("holding" if fc == 0x03 else "input", address, count)
        return bytes([fc]) + _registers(values)
    if fc == 0x06:
        _check_length(data, 4)
        address, value = struct.unpack(">HH", data)
        unit.write(address, [value], fc)
        return bytes([fc]) + data[:4]
    if fc == 0x10:
        address, count, nbytes = struct.unpack(">HHB", data[:5])
        if not 1 <= count <= 123 or nbytes != 2 * count or len(data) != 5 + nbytes:
            raise ModbusError(ILLEGAL_VALUE, "write count")
        _check_span(address, count)
        values = list(struct.unpack(f">{count}H", data[5 : 5 + nbytes]))
        unit.write(address, values, fc)
        return bytes([fc]) + data[:4]
    if fc == 0x16:  # mask write: (current AND and) OR (or AND NOT and)
        _check_length(data, 6)
        address, and_mask, or_mask = struct.unpack(">HHH", data)
        current = unit.read("holding", address, 1)[0]
        unit.write(address, [(current & and_mask) | (or_mask & ~and_mask & 0xFFFF)], fc)
        return bytes([fc]) + data
    if fc == 0x17:
        r_addr, r_count, w_addr, w_count, nbytes = struct.unpack(">HHHHB", data[:9])
        if not (1 <= r_count <= 125 and 1 <= w_count <= 121 and nbytes == 2 * w_count
                and len(data) == 9 + nbytes):
            raise ModbusError(ILLEGAL_VALUE, "read/write count")
        _check_span(r_addr, r_count)
        _check_span(w_addr, w_count)
        values = list(struct.unpack(f">{w_count}H", data[9 : 9 + nbytes]))
        unit.write(w_addr, values, fc)
        return bytes([fc]) + _registers(unit.read("holding", r_addr, r_count))
    if fc in (0x01, 0x02, 0x05, 0x0F):
        return _dispatch_bits(unit, fc, data)
    raise ModbusError(ILLEGAL_FUNCTION, f"function {fc:#04x}")


def _dispatch_bits(unit: RegisterUnit, fc: int, data: bytes) -> bytes:
    if not getattr(unit, "has_coils", False):
        raise ModbusError(ILLEGAL_FUNCTION, f"function {fc:#04x}: no coils")
    bits_unit: BitUnit = unit  # type: ignore[assignment]
    if fc in (0x01, 0x02):
        _check_length(data, 4)
        address, count = struct.unpack(">HH", data)
        if not 1 <= count <= 2000:
            raise ModbusError(ILLEGAL_VALUE, "read count")
        _check_span(address, count)
        bits = bits_unit.read_bits("coils" if fc == 0x01 else "discrete", address, count)
        packed = bytearray((count + 7) // 8)
        for i, bit in enumerate(bits):
            if bit:
                packed[i // 8] |= 1 << (i % 8)
        return bytes([fc, len(packed)]) + bytes(packed)
    if fc == 0x05:
        _check_length(data, 4)
        address, value = struct.unpack(">HH", data)
        if value not in (0x0000, 0xFF00):
            raise ModbusError(ILLEGAL_VALUE, "coil value")
        bits_unit.write_coils(address, [1 if value else 0], fc)
        return bytes([fc]) + data[:4]
    address, count, nbytes = struct.unpack(">HHB", data[:5])
    if not 1 <= count <= 1968 or nbytes != (count + 7) // 8 or len(data) != 5 + nbytes:
        raise ModbusError(ILLEGAL_VALUE, "write count")
    _check_span(address, count)
    bits = [data[5 + i // 8] >> (i % 8) & 1 for i in range(count)]
    bits_unit.write_coils(address, bits, fc)
    return bytes([fc]) + data[:4]


def _check_length(data: bytes, length: int) -> None:
    """A request whose length its function code does not allow: 0x03, as the spec says."""
    if len(data) != length:
        raise ModbusError(ILLEGAL_VALUE, f"{len(data) + 1}-byte PDU")


def _check_span(address: int, count: int) -> None:
    if address + count > 0x10000:
        raise ModbusError(ILLEGAL_ADDRESS, "past 0xFFFF")


def int32_to_words(value: int, order: str) -> list[int]:
    """Signed 32-bit value (wrapped) as two registers in ``order`` ("hi_lo" or "lo_hi")."""
    raw = value & 0xFFFFFFFF
    hi, lo = raw >> 16, raw & 0xFFFF
    return [hi, lo] if order == "hi_lo" else [lo, hi]


def words_to_int32(words: list[int], order: str) -> int:
    """Two registers in ``order`` as a signed 32-bit value."""
    hi, lo = (words[0], words[1]) if order == "hi_lo" else (words[1], words[0])
    raw = (hi << 16) | lo
    return raw - (1 << 32) if raw & 0x80000000 else raw
