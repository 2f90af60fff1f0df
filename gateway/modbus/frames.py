"""Modbus PDU helpers: pure functions, no I/O.

A PDU here is ``function code + data`` (no unit id, no MBAP header, no CRC), as bytes.
The transports (``upstream``, ``downstream``) move PDUs byte-exact; only code that rewrites
a request (the interception layer) parses it, with :func:`parse_request`. RTU framing needs
frame lengths before the CRC can be checked: :func:`rtu_request_length` and
:func:`rtu_response_length` compute them from the first bytes, and :func:`find_rtu_frame`
scans a receive buffer for the first CRC-valid frame (resynchronising after garbage).
CRC is pymodbus's (``FramerRTU.compute_CRC``); nothing here re-implements it.
"""

from __future__ import annotations

import struct
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Literal

from pymodbus.framer import FramerRTU

# Function codes handled explicitly (everything else passes through raw).
READ_COILS = 0x01
READ_DISCRETE_INPUTS = 0x02
READ_HOLDING_REGISTERS = 0x03
READ_INPUT_REGISTERS = 0x04
WRITE_SINGLE_COIL = 0x05
WRITE_SINGLE_REGISTER = 0x06
WRITE_MULTIPLE_COILS = 0x0F
WRITE_MULTIPLE_REGISTERS = 0x10
MASK_WRITE_REGISTER = 0x16
READ_WRITE_MULTIPLE_REGISTERS = 0x17

# Exception codes.
ILLEGAL_FUNCTION = 0x01
ILLEGAL_DATA_ADDRESS = 0x02
ILLEGAL_DATA_VALUE = 0x03
SERVER_DEVICE_FAILURE = 0x04
SERVER_DEVICE_BUSY = 0x06
GATEWAY_PATH_UNAVAILABLE = 0x0A
GATEWAY_TARGET_NO_RESPONSE = 0x0B
#: the exception codes in words (the application protocol spec's names)
EXCEPTION_NAMES = {
    ILLEGAL_FUNCTION: "illegal function", ILLEGAL_DATA_ADDRESS: "illegal data address",
    ILLEGAL_DATA_VALUE: "illegal data value", SERVER_DEVICE_FAILURE: "device failure",
    SERVER_DEVICE_BUSY: "busy", GATEWAY_PATH_UNAVAILABLE: "gateway path unavailable",
    GATEWAY_TARGET_NO_RESPONSE: "gateway target device failed to respond",
}  # fmt: skip


def exception_words(code: int, hint: str = "") -> str:
    """"exception 0x0a (gateway path unavailable)": a Modbus exception code in words, with
    ``hint`` (what to check) inside the brackets."""
    return (f"exception {code:#04x} ({EXCEPTION_NAMES.get(code, 'refused')}"
            + (f": {hint}" if hint else "") + ")")

EXCEPTION_BIT = 0x80
MAX_PDU_BYTES = 253  # Modbus application protocol spec 1.1b3, section 4.1

# Protocol limits on quantities (spec section 6).
MAX_READ_BITS = 2000
MAX_READ_REGISTERS = 125
MAX_WRITE_BITS = 1968
MAX_WRITE_REGISTERS = 123
MAX_RW_WRITE_REGISTERS = 121

WordOrder = Literal["hi_lo", "lo_hi"]


class FrameError(ValueError):
    """A PDU or frame that does not follow the protocol (message says what is wrong).

    ``code``: the exception a conforming server answers it with (spec 1.1b3 section 6): 0x03
    for a wrong length, byte count or quantity, 0x02 for a range running past 0xFFFF.
    """

    def __init__(self, message: str, code: int = ILLEGAL_DATA_VALUE) -> None:
        super().__init__(message)
        self.code = code


class ModbusError(Exception):
    """Raised by a request handler to answer with a Modbus exception ``code``.

    The upstream servers turn it into an exception PDU; the downstream errors
    (``DriveTimeout`` → 0x0B, ``BusUnavailable`` → 0x0A) derive from it.
    """

    code: int = SERVER_DEVICE_FAILURE

    def __init__(self, message: str = "", code: int | None = None) -> None:
        super().__init__(message)
        if code is not None:
            self.code = code


# --------------------------------------------------------------------------- exceptions


def exception_pdu(function: int, code: int) -> bytes:
    """Exception response PDU for a request with ``function`` (bit 7 set, then the code)."""
    return bytes(((function & 0x7F) | EXCEPTION_BIT, code & 0xFF))


def is_exception(pdu: bytes) -> bool:
    """True if ``pdu`` is an exception response."""
    return len(pdu) >= 1 and bool(pdu[0] & EXCEPTION_BIT)


def exception_code(pdu: bytes) -> int | None:
    """The exception code of an exception response, else None."""
    if len(pdu) == 2 and pdu[0] & EXCEPTION_BIT:
        return pdu[1]
    return None


# --------------------------------------------------------------------------- requests


@dataclass(frozen=True)
class Request:
    """A parsed request: what it reads and what it writes.

    ``read_address``/``read_count`` are set for FC 1-4 and 23; ``write_address``/``values``
    for FC 5, 6, 15, 16 and 23. ``values`` are register words (FC 6, 16, 23) or bits as
    0/1 (FC 5, 15).
    """

    function: int
    read_address: int | None = None
    read_count: int = 0
    write_address: int | None = None
    values: tuple[int, ...] = ()

    @property
    def write_count(self) -> int:
        return len(self.values)


def _need(pdu: bytes, length: int, what: str) -> None:
    if len(pdu) != length:
        raise FrameError(f"{what}: PDU is {len(pdu)} bytes, expected {length}")


def _check_count(count: int, limit: int, what: str) -> None:
    if not 1 <= count <= limit:
        raise FrameError(f"{what}: quantity {count} is not in 1..{limit}")


def _check_range(address: int, count: int, what: str) -> None:
    if address + count > 0x10000:
        raise FrameError(f"{what}: address {address} + quantity {count} exceeds 65536",
                         ILLEGAL_DATA_ADDRESS)


def parse_request(pdu: bytes) -> Request:
    """Parse a request PDU for FC 1-6, 15, 16, 23; raise :class:`FrameError` otherwise."""
    if not pdu:
        raise FrameError("empty PDU")
    fc = pdu[0]
    name = f"FC{fc:02d}"
    if fc in (READ_COILS, READ_DISCRETE_INPUTS, READ_HOLDING_REGISTERS, READ_INPUT_REGISTERS):
        _need(pdu, 5, name)
        address, count = struct.unpack(">HH", pdu[1:5])
        limit = MAX_READ_BITS if fc <= READ_DISCRETE_INPUTS else MAX_READ_REGISTERS
        _check_count(count, limit, name)
        _check_range(address, count, name)
        return Request(fc, read_address=address, read_count=count)
    if fc == WRITE_SINGLE_COIL:
        _need(pdu, 5, name)
        address, value = struct.unpack(">HH", pdu[1:5])
        if value not in (0x0000, 0xFF00):
            raise FrameError(f"{name}: coil value 0x{value:04X} is not 0x0000 or 0xFF00")
        return Request(fc, write_address=address, values=(1 if value else 0,))
    if fc == WRITE_SINGLE_REGISTER:
        _need(pdu, 5, name)
        address, value = struct.unpack(">HH", pdu[1:5])
        return Request(fc, write_address=address, values=(value,))
    if fc in (WRITE_MULTIPLE_COILS, WRITE_MULTIPLE_REGISTERS):
        if len(pdu) < 6:
            raise FrameError(f"{name}: PDU is {len(pdu)} bytes, expected at least 6")
        address, count, byte_count = struct.unpack(">HHB", pdu[1:6])
        if fc == WRITE_MULTIPLE_COILS:
            _check_count(count, MAX_WRITE_BITS, name)
            expected_bytes = (count + 7) // 8
        else:
            _check_count(count, MAX_WRITE_REGISTERS, name)
            expected_bytes = 2 * count
        if byte_count != expected_bytes:
            raise FrameError(f"{name}: byte count {byte_count}, expected {expected_bytes}")
        _need(pdu, 6 + byte_count, name)
        _check_range(address, count, name)
        data = pdu[6:]
        if fc == WRITE_MULTIPLE_COILS:
            bits = tuple((data[i // 8] >> (i % 8)) & 1 for i in range(count))
            return Request(fc, write_address=address, values=bits)
        return Request(fc, write_address=address, values=struct.unpack(f">{count}H", data))
    if fc == READ_WRITE_MULTIPLE_REGISTERS:
        if len(pdu) < 10:
            raise FrameError(f"{name}: PDU is {len(pdu)} bytes, expected at least 10")
        r_addr, r_count, w_addr, w_count, byte_count = struct.unpack(">HHHHB", pdu[1:10])
        _check_count(r_count, MAX_READ_REGISTERS, name)
        _check_count(w_count, MAX_RW_WRITE_REGISTERS, name)
        if byte_count != 2 * w_count:
            raise FrameError(f"{name}: byte count {byte_count}, expected {2 * w_count}")
        _need(pdu, 10 + byte_count, name)
        _check_range(r_addr, r_count, name)
        _check_range(w_addr, w_count, name)
        values = struct.unpack(f">{w_count}H", pdu[10:])
        return Request(fc, read_address=r_addr, read_count=r_count, write_address=w_addr,
                       values=values)
    raise FrameError(f"{name}: function code not parsed here")


def build_read_request(function: int, address: int, count: int) -> bytes:
    """FC 1-4 request PDU."""
    return struct.pack(">BHH", function, address, count)


def build_write_single_coil(address: int, on: bool) -> bytes:
    """FC 5 request PDU (also its normal response: the echo)."""
    return struct.pack(">BHH", WRITE_SINGLE_COIL, address, 0xFF00 if on else 0)


def build_write_single_register(address: int, value: int) -> bytes:
    """FC 6 request PDU (also its normal response: the echo)."""
    return struct.pack(">BHH", WRITE_SINGLE_REGISTER, address, value & 0xFFFF)


def _pack_bits(bits: Sequence[int | bool]) -> bytes:
    out = bytearray((len(bits) + 7) // 8)
    for i, bit in enumerate(bits):
        if bit:
            out[i // 8] |= 1 << (i % 8)
    return bytes(out)


def build_write_multiple_coils(address: int, bits: Sequence[int | bool]) -> bytes:
    """FC 15 request PDU."""
    data = _pack_bits(bits)
    return struct.pack(">BHHB", WRITE_MULTIPLE_COILS, address, len(bits), len(data)) + data


def build_write_multiple_registers(address: int, values: Sequence[int]) -> bytes:
    """FC 16 request PDU."""
    words = [v & 0xFFFF for v in values]
    return struct.pack(f">BHHB{len(words)}H", WRITE_MULTIPLE_REGISTERS, address, len(words),
                       2 * len(words), *words)


def build_read_write_request(read_address: int, read_count: int, write_address: int,
                             values: Sequence[int]) -> bytes:
    """FC 23 request PDU."""
    words = [v & 0xFFFF for v in values]
    return struct.pack(f">BHHHHB{len(words)}H", READ_WRITE_MULTIPLE_REGISTERS, read_address,
                       read_count, write_address, len(words), 2 * len(words), *words)


def build_request(req: Request) -> bytes:
    """Re-encode a parsed :class:`Request` (inverse of :func:`parse_request`)."""
    fc = req.function
    if fc in (READ_COILS, READ_DISCRETE_INPUTS, READ_HOLDING_REGISTERS, READ_INPUT_REGISTERS):
        assert req.read_address is not None
        return build_read_request(fc, req.read_address, req.read_count)
    assert req.write_address is not None
    if fc == WRITE_SINGLE_COIL:
        return build_write_single_coil(req.write_address, bool(req.values[0]))
    if fc == WRITE_SINGLE_REGISTER:
        return build_write_single_register(req.write_address, req.values[0])
    if fc == WRITE_MULTIPLE_COILS:
        return build_write_multiple_coils(req.write_address, req.values)
    if fc == WRITE_MULTIPLE_REGISTERS:
        return build_write_multiple_registers(req.write_address, req.values)
    if fc == READ_WRITE_MULTIPLE_REGISTERS:
        assert req.read_address is not None
        return build_read_write_request(req.read_address, req.read_count, req.write_address,
                                        req.values)
    raise FrameError(f"FC{fc:02d}: function code not built here")


# --------------------------------------------------------------------------- responses


# Compiled struct formats of register responses by word count (on the request hot path).
_WORDS = [struct.Struct(f">{n}H") for n in range(128)]
_RESPONSES = [struct.Struct(f">BB{n}H") for n in range(128)]


def build_read_registers_response(function: int, values: Sequence[int]) -> bytes:
    """FC 3, 4 or 23 normal response PDU."""
    words = [v & 0xFFFF for v in values]
    n = len(words)
    fmt = _RESPONSES[n] if n < 128 else struct.Struct(f">BB{n}H")
    return fmt.pack(function, 2 * n, *words)


def build_read_bits_response(function: int, bits: Sequence[int | bool]) -> bytes:
    """FC 1 or 2 normal response PDU."""
    data = _pack_bits(bits)
    return bytes((function, len(data))) + data


def build_write_response(function: int, address: int, value_or_count: int) -> bytes:
    """FC 5, 6 (address, value echo) or FC 15, 16 (address, quantity) response PDU."""
    return struct.pack(">BHH", function, address, value_or_count & 0xFFFF)


def response_for_write(req: Request) -> bytes:
    """The normal response a drive gives to the write request ``req`` (FC 5, 6, 15, 16)."""
    assert req.write_address is not None
    if req.function == WRITE_SINGLE_COIL:
        return build_write_single_coil(req.write_address, bool(req.values[0]))
    if req.function == WRITE_SINGLE_REGISTER:
        return build_write_single_register(req.write_address, req.values[0])
    return build_write_response(req.function, req.write_address, req.write_count)


def parse_read_registers_response(pdu: bytes) -> list[int]:
    """Register words of an FC 3, 4 or 23 normal response."""
    if len(pdu) < 2 or pdu[1] % 2 or len(pdu) != 2 + pdu[1]:
        raise FrameError(f"register response malformed: {pdu.hex()}")
    return list(_WORDS[pdu[1] // 2].unpack_from(pdu, 2))


def parse_read_bits_response(pdu: bytes, count: int) -> list[int]:
    """First ``count`` bits (0/1) of an FC 1 or 2 normal response."""
    if len(pdu) < 2 or len(pdu) != 2 + pdu[1] or pdu[1] * 8 < count:
        raise FrameError(f"bit response malformed: {pdu.hex()}")
    return [(pdu[2 + i // 8] >> (i % 8)) & 1 for i in range(count)]


def expected_response_length(request_pdu: bytes) -> int | None:
    """Length of the normal response PDU to ``request_pdu``; None if not computable.

    An exception response is always 2 bytes. Used by the RTU bus to check replies and by
    tests; unknown function codes return None (framed by line silence instead).
    """
    if len(request_pdu) < 5:
        return None
    fc = request_pdu[0]
    count = (request_pdu[3] << 8) | request_pdu[4]
    if fc in (READ_COILS, READ_DISCRETE_INPUTS):
        return 2 + (count + 7) // 8
    if fc in (READ_HOLDING_REGISTERS, READ_INPUT_REGISTERS, READ_WRITE_MULTIPLE_REGISTERS):
        return 2 + 2 * count
    if fc in (WRITE_SINGLE_COIL, WRITE_SINGLE_REGISTER, WRITE_MULTIPLE_COILS,
              WRITE_MULTIPLE_REGISTERS):
        return 5
    return None


def response_matches(request_pdu: bytes, response_pdu: bytes) -> bool:
    """True if ``response_pdu`` can be the drive's answer to ``request_pdu``.

    Checks the function (or function | 0x80 with a 2-byte exception), and for the known
    function codes the byte count of reads and the echoed address and quantity/value of
    writes; so a late reply to an earlier request is not given to this one. Unknown
    function codes are matched on the function code alone.
    """
    if not request_pdu or not response_pdu:
        return False
    fc = request_pdu[0]
    if response_pdu[0] == fc | EXCEPTION_BIT:
        return len(response_pdu) == 2
    if response_pdu[0] != fc:
        return False
    expected = expected_response_length(request_pdu)
    if expected is None:
        return True
    if len(response_pdu) != expected:
        return False
    if fc in (WRITE_SINGLE_COIL, WRITE_SINGLE_REGISTER):
        return response_pdu == request_pdu[:5]
    if fc in (WRITE_MULTIPLE_COILS, WRITE_MULTIPLE_REGISTERS):
        return response_pdu[1:5] == request_pdu[1:5]
    return response_pdu[1] == expected - 2  # reads: byte count


# --------------------------------------------------------------------------- RTU framing

NEED_MORE = -1  # returned by the RTU length functions when the prefix is too short

# Fixed RTU request PDU lengths by function code (fc + data, no unit id, no CRC).
_FIXED_REQUEST = {1: 5, 2: 5, 3: 5, 4: 5, 5: 5, 6: 5, 7: 1, 8: 5, 11: 1, 12: 1, 17: 1,
                  22: 7, 24: 3}
# Fixed RTU normal-response PDU lengths.
_FIXED_RESPONSE = {5: 5, 6: 5, 7: 2, 8: 5, 11: 5, 15: 5, 16: 5, 22: 7}
# Responses with a one-byte byte count right after the function code.
_COUNTED_RESPONSE = {1, 2, 3, 4, 12, 17, 23}


def rtu_request_length(pdu_prefix: bytes) -> int | None:
    """PDU length of the request starting with ``pdu_prefix``.

    NEED_MORE if more bytes are needed to tell, None for a function code whose length
    cannot be computed (framed by line silence instead).
    """
    if not pdu_prefix:
        return NEED_MORE
    fc = pdu_prefix[0]
    if fc in _FIXED_REQUEST:
        return _FIXED_REQUEST[fc]
    if fc in (WRITE_MULTIPLE_COILS, WRITE_MULTIPLE_REGISTERS):
        return 6 + pdu_prefix[5] if len(pdu_prefix) >= 6 else NEED_MORE
    if fc == READ_WRITE_MULTIPLE_REGISTERS:
        return 10 + pdu_prefix[9] if len(pdu_prefix) >= 10 else NEED_MORE
    return None


def rtu_response_length(pdu_prefix: bytes) -> int | None:
    """PDU length of the response starting with ``pdu_prefix`` (see rtu_request_length)."""
    if not pdu_prefix:
        return NEED_MORE
    fc = pdu_prefix[0]
    if fc & EXCEPTION_BIT:
        return 2
    if fc in _FIXED_RESPONSE:
        return _FIXED_RESPONSE[fc]
    if fc in _COUNTED_RESPONSE:
        return 2 + pdu_prefix[1] if len(pdu_prefix) >= 2 else NEED_MORE
    if fc == 24:  # read FIFO queue: two-byte byte count
        return 3 + int.from_bytes(pdu_prefix[1:3], "big") if len(pdu_prefix) >= 3 else NEED_MORE
    return None


def rtu_crc_ok(frame: bytes) -> bool:
    """True if the last two bytes of ``frame`` are the Modbus CRC of the rest."""
    if len(frame) < 4:
        return False
    return FramerRTU.check_CRC(frame[:-2], int.from_bytes(frame[-2:], "big"))


def rtu_encode(unit_id: int, pdu: bytes) -> bytes:
    """RTU frame: unit id, PDU, CRC (pymodbus's framer)."""
    return _RTU.encode(pdu, unit_id, 0)


_RTU = FramerRTU(None)  # type: ignore[arg-type]  # encode() needs no decoder


@dataclass(frozen=True)
class RtuScan:
    """Result of :func:`find_rtu_frame`.

    ``frame`` (unit id + PDU + CRC) was found at ``start``; ``consumed`` bytes of the
    buffer can be discarded (garbage before it, and the frame). ``frame`` is None if no
    complete valid frame is there yet: then ``consumed`` bytes are certainly garbage.
    ``waiting`` is True if a plausible frame start still lacks bytes.
    """

    frame: bytes | None
    consumed: int
    waiting: bool


def find_rtu_frame(buf: bytes, length_fn: Callable[[bytes], int | None], *,
                   at_silence: bool = False) -> RtuScan:
    """Find the first CRC-valid RTU frame in ``buf``, resynchronising past garbage.

    Each offset is tried as a frame start: its length comes from ``length_fn`` (request or
    response rules); a known-length candidate with a good CRC wins. With ``at_silence``
    (the line went quiet, so the buffer ends a frame), a frame of unknown function code is
    also accepted when ``buf[offset:]`` as a whole has a good CRC.
    """
    first_maybe: int | None = None  # first offset that may still start a frame
    waiting = False
    for start in range(len(buf) - 1):
        length = length_fn(buf[start + 1:])
        if length is None:
            if at_silence:
                if rtu_crc_ok(buf[start:]):
                    return RtuScan(bytes(buf[start:]), len(buf), False)
            elif first_maybe is None:
                first_maybe = start
            continue
        if length == NEED_MORE or start + 1 + length + 2 > len(buf):
            waiting = True
            first_maybe = start if first_maybe is None else first_maybe
            continue
        end = start + 1 + length + 2
        if rtu_crc_ok(buf[start:end]):
            return RtuScan(bytes(buf[start:end]), end, False)
    if first_maybe is not None:
        return RtuScan(None, first_maybe, waiting)
    # Nothing can start before the last byte; at silence even that one is garbage.
    return RtuScan(None, len(buf) if at_silence else max(len(buf) - 1, 0), False)


# --------------------------------------------------------------------------- 32-bit values


def pack_int32(value: int, order: WordOrder = "hi_lo", *, signed: bool = True) -> tuple[int, int]:
    """Two register words holding ``value`` in word ``order`` (bytes in a word: big-endian)."""
    fmt = ">i" if signed else ">I"
    try:
        hi, lo = struct.unpack(">HH", struct.pack(fmt, value))
    except struct.error as err:
        kind = "signed" if signed else "unsigned"
        raise ValueError(f"{value} does not fit a {kind} 32-bit register pair") from err
    return (hi, lo) if order == "hi_lo" else (lo, hi)


def unpack_int32(words: Sequence[int], order: WordOrder = "hi_lo", *, signed: bool = True) -> int:
    """Value of two register words in word ``order`` (inverse of :func:`pack_int32`)."""
    if len(words) != 2:
        raise ValueError(f"a 32-bit value needs 2 words, got {len(words)}")
    hi, lo = (words[0], words[1]) if order == "hi_lo" else (words[1], words[0])
    raw = ((hi & 0xFFFF) << 16) | (lo & 0xFFFF)
    if signed and raw & 0x80000000:
        raw -= 1 << 32
    return raw
