"""Pure PDU helpers: parse/build round trips, lengths, reply matching, RTU scanning, int32."""

from __future__ import annotations

import struct

import pytest
from pymodbus.client import AsyncModbusTcpClient

from gateway.modbus import frames as f


def test_exception_pdu() -> None:
    assert f.exception_pdu(0x03, f.GATEWAY_TARGET_NO_RESPONSE) == b"\x83\x0b"
    assert f.exception_pdu(0x90, f.GATEWAY_PATH_UNAVAILABLE) == b"\x90\x0a"
    assert f.is_exception(b"\x83\x0b") and not f.is_exception(b"\x03\x02\x00\x01")
    assert f.exception_code(b"\x86\x02") == 2
    assert f.exception_code(b"\x06\x00\x01\x00\x02") is None
    assert (f.ILLEGAL_FUNCTION, f.ILLEGAL_DATA_ADDRESS, f.ILLEGAL_DATA_VALUE,
            f.SERVER_DEVICE_FAILURE) == (1, 2, 3, 4)


REQUESTS = [
    f.build_read_request(1, 7, 19),
    f.build_read_request(2, 0, 2000),
    f.build_read_request(3, 0x6201, 2),
    f.build_read_request(4, 65534, 2),
    f.build_write_single_coil(9, True),
    f.build_write_single_register(0x6002, 0x10),
    f.build_write_multiple_coils(20, [1, 0, 1, 1, 0, 0, 0, 0, 1]),
    f.build_write_multiple_registers(0x6200, [1, 0, 0xFFFF, 0x2710, 100, 100, 0, 0x10]),
    f.build_read_write_request(10, 3, 30, [5, 6]),
]


@pytest.mark.parametrize("pdu", REQUESTS, ids=lambda p: f"FC{p[0]:02d}")
def test_parse_build_round_trip(pdu: bytes) -> None:
    req = f.parse_request(pdu)
    assert f.build_request(req) == pdu
    assert f.rtu_request_length(pdu) == len(pdu)


def test_parse_fields() -> None:
    req = f.parse_request(f.build_read_write_request(10, 3, 30, [5, 6]))
    assert (req.read_address, req.read_count, req.write_address, req.values) == (10, 3, 30,
                                                                                 (5, 6))
    req = f.parse_request(f.build_write_multiple_registers(0x6201, [0x0001, 0x86A0]))
    assert (req.write_address, req.write_count, req.read_address) == (0x6201, 2, None)
    req = f.parse_request(f.build_write_multiple_coils(4, [1, 0, 1]))
    assert req.values == (1, 0, 1)
    assert f.parse_request(f.build_write_single_coil(3, False)).values == (0,)


@pytest.mark.parametrize("pdu,why", [
    (b"", "empty"),
    (b"\x03\x00\x00\x00", "expected 5"),
    (b"\x03\x00\x00\x00\x00", "quantity 0"),
    (b"\x03\x00\x00\x00\x7e", "quantity 126"),
    (b"\x03\xff\xff\x00\x02", "exceeds 65536"),
    (b"\x05\x00\x01\x12\x34", "coil value"),
    (b"\x10\x00\x00\x00\x02\x03\x00\x01\x00", "byte count 3"),
    (b"\x10\x00\x00\x00\x02\x04\x00\x01", "expected 10"),
    (b"\x17\x00\x00\x00\x01\x00\x00\x00\x01\x02\x00", "expected 12"),
    (b"\x2b\x0e\x01\x00", "not parsed"),
])
def test_parse_rejects(pdu: bytes, why: str) -> None:
    with pytest.raises(f.FrameError, match=why):
        f.parse_request(pdu)


def test_expected_response_length_and_matching() -> None:
    read = f.build_read_request(3, 100, 10)
    assert f.expected_response_length(read) == 22
    assert f.expected_response_length(f.build_read_request(1, 0, 9)) == 4
    assert f.expected_response_length(f.build_read_write_request(0, 4, 0, [1])) == 10
    assert f.expected_response_length(b"\x2b\x0e\x01\x00") is None
    good = f.build_read_registers_response(3, range(10))
    assert f.response_matches(read, good)
    assert f.response_matches(read, b"\x83\x02")
    assert not f.response_matches(read, f.build_read_registers_response(3, range(2)))
    assert not f.response_matches(read, b"\x84\x02")
    write = f.build_write_multiple_registers(0x6201, [1, 2])
    assert f.response_matches(write, f.build_write_response(16, 0x6201, 2))
    assert not f.response_matches(write, f.build_write_response(16, 0x6200, 2))
    assert not f.response_matches(write, f.build_write_response(16, 0x6201, 3))
    single = f.build_write_single_register(7, 42)
    assert f.response_matches(single, single)
    assert not f.response_matches(single, f.build_write_single_register(7, 43))
    assert f.parse_read_registers_response(good) == list(range(10))
    bits = f.build_read_bits_response(1, [1, 0, 1, 1, 0, 0, 0, 0, 1])
    assert f.parse_read_bits_response(bits, 9) == [1, 0, 1, 1, 0, 0, 0, 0, 1]
    assert f.response_for_write(f.parse_request(write)) == f.build_write_response(16, 0x6201, 2)


def test_rtu_lengths() -> None:
    assert f.rtu_request_length(b"\x10\x00\x00\x00") == f.NEED_MORE
    assert f.rtu_request_length(b"\x41") is None
    assert f.rtu_response_length(b"\x03") == f.NEED_MORE
    assert f.rtu_response_length(b"\x03\x04") == 6
    assert f.rtu_response_length(b"\x90") == 2
    assert f.rtu_response_length(b"\x10") == 5


def test_rtu_encode_uses_modbus_crc() -> None:
    assert f.rtu_encode(1, b"\x03\x00\x00\x00\x02").hex() == "010300000002c40b"
    assert f.rtu_crc_ok(bytes.fromhex("010300000002c40b"))
    assert not f.rtu_crc_ok(bytes.fromhex("010300000002c40c"))


def test_find_rtu_frame_resynchronises() -> None:
    frame = f.rtu_encode(1, f.build_read_request(3, 0, 2))
    scan = f.find_rtu_frame(b"\x01\x03\x00" + b"\xff\x00" + frame, f.rtu_request_length)
    assert scan.frame == frame and scan.consumed == 5 + len(frame)
    scan = f.find_rtu_frame(frame[:5], f.rtu_request_length)
    assert scan.frame is None and scan.waiting and scan.consumed == 0
    # A frame of unknown function code is only taken at line silence.
    odd = f.rtu_encode(7, b"\x41\x01\x02")
    assert f.find_rtu_frame(odd, f.rtu_request_length).frame is None
    assert f.find_rtu_frame(odd, f.rtu_request_length, at_silence=True).frame == odd
    # Pure noise at silence is all consumed.
    scan = f.find_rtu_frame(b"\x99\x98\x97", f.rtu_request_length, at_silence=True)
    assert scan.frame is None and scan.consumed == 3
    # Two frames back to back: the first one, and exactly its bytes.
    two = frame + f.rtu_encode(2, f.build_write_single_register(1, 2))
    scan = f.find_rtu_frame(two, f.rtu_request_length)
    assert scan.frame == frame and scan.consumed == len(frame)


@pytest.mark.parametrize("value", [0, 1, -1, 100_000, -100_000, 2**31 - 1, -(2**31)])
@pytest.mark.parametrize("order,pymodbus_order", [("hi_lo", "big"), ("lo_hi", "little")])
def test_int32_matches_pymodbus(value: int, order: f.WordOrder, pymodbus_order: str) -> None:
    words = f.pack_int32(value, order)
    expected = AsyncModbusTcpClient.convert_to_registers(
        value, AsyncModbusTcpClient.DATATYPE.INT32, word_order=pymodbus_order)
    assert list(words) == expected
    assert f.unpack_int32(words, order) == value


def test_int32_limits() -> None:
    with pytest.raises(ValueError, match="signed 32-bit"):
        f.pack_int32(2**31)
    assert f.pack_int32(0xFFFFFFFF, signed=False) == (0xFFFF, 0xFFFF)
    assert f.unpack_int32((0xFFFF, 0xFFFF), signed=False) == 0xFFFFFFFF
    assert f.pack_int32(0x12345678, "lo_hi") == (0x5678, 0x1234)
    assert struct.pack(">HH", *f.pack_int32(-2)) == struct.pack(">i", -2)
