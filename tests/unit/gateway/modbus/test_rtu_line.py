"""The direct RTU backend's framing (``rtu_line``): CRC-16/MODBUS against its catalogue check
value and a bitwise CRC written here, whole frames against the well-known examples of the
Modbus serial-line literature, and an answer's length from its first bytes, counted by hand.
The backend on a serial line: tests/integration/test_rtu_line_pty.py."""

from __future__ import annotations

from typing import NoReturn

import pytest
from hypothesis import given
from hypothesis import strategies as st

from gateway.modbus.rtu_line import (
    SizeRule,
    _byte_count_rule,
    _device_id_rule,
    _echo_rule,
    adu,
    answer_size,
    crc16_modbus,
)
from gateway.modbus.vendor_fc import VendorRead


def bitwise_crc(data: bytes) -> int:
    """CRC-16/MODBUS bit by bit, as the serial-line specification (V1.02, 6.2.2) describes it:
    start from 0xFFFF, XOR each byte in, shift right 8 times, XOR 0xA001 after a 1 fell out."""
    crc = 0xFFFF
    for byte in data:
        crc ^= byte
        for _ in range(8):
            crc = (crc >> 1) ^ 0xA001 if crc & 1 else crc >> 1
    return crc


# ---------------------------------------------------------------------------- CRC


def test_crc_check_value_of_the_catalogue() -> None:
    # the CRC catalogue's "check" of CRC-16/MODBUS: the CRC of the ASCII digits 1..9
    assert crc16_modbus(b"123456789") == 0x4B37
    assert bitwise_crc(b"123456789") == 0x4B37


def test_crc_of_nothing_is_the_initial_value() -> None:
    assert crc16_modbus(b"") == 0xFFFF


@pytest.mark.parametrize(
    ("body", "crc_on_the_wire"),
    [
        ("01030000000A", "C5CD"),  # read 10 holding registers from 0 of device 1
        ("010600010003", "980B"),  # write holding register 1 = 3 on device 1
        ("1103006B0003", "7687"),  # the specification's example: read 3 holding from 0x6B of 0x11
        ("01040000000A", "700D"),  # read 10 input registers from 0 of device 1
    ],
)
def test_crc_of_well_known_frames(body: str, crc_on_the_wire: str) -> None:
    data = bytes.fromhex(body)
    low_first = bytes.fromhex(crc_on_the_wire)
    assert bitwise_crc(data).to_bytes(2, "little") == low_first  # the vector itself
    assert crc16_modbus(data) == int.from_bytes(low_first, "little")


@given(st.binary(max_size=300))
def test_crc_agrees_with_the_bitwise_crc(data: bytes) -> None:
    assert crc16_modbus(data) == bitwise_crc(data)


@given(st.binary(max_size=300))
def test_a_frame_followed_by_its_crc_checks_to_zero(data: bytes) -> None:
    assert crc16_modbus(data + crc16_modbus(data).to_bytes(2, "little")) == 0


# ---------------------------------------------------------------------------- frames


def test_adu_of_a_read_of_ten_holding_registers() -> None:
    assert adu(1, bytes.fromhex("030000000A")) == bytes.fromhex("01 03 00 00 00 0A C5 CD")


def test_adu_of_a_write_of_register_1() -> None:
    assert adu(1, bytes.fromhex("0600010003")) == bytes.fromhex("01 06 00 01 00 03 98 0B")


def test_adu_of_the_specifications_example() -> None:
    assert adu(0x11, bytes.fromhex("03006B0003")) == bytes.fromhex("11 03 00 6B 00 03 76 87")


def test_adu_puts_the_address_first_and_the_crc_low_byte_first() -> None:
    frame = adu(247, b"\x42\x00\x00\x00\x04")
    assert len(frame) == 1 + 5 + 2
    assert frame[:6] == b"\xf7\x42\x00\x00\x00\x04"
    crc = bitwise_crc(frame[:6])
    assert frame[6] == crc & 0xFF and frame[7] == crc >> 8


# ---------------------------------------------------------------------------- answer sizes


def never_called(data: bytes) -> NoReturn:
    raise AssertionError(f"the size rule was asked about {data.hex()}")


VENDOR = VendorRead(0x42)


@pytest.mark.parametrize("function_code", [0x03, 0x04, 0x06, 0x10, 0x2B, 0x42])
def test_an_exception_answer_is_five_bytes_whatever_the_function(function_code: int) -> None:
    # address, function | 0x80, exception code, CRC (2): the function's own rule is not asked
    head = bytes((1, function_code | 0x80))
    assert answer_size(function_code, never_called, head) == 5
    assert answer_size(function_code, never_called, head + b"\x02") == 5
    assert answer_size(function_code, never_called, bytearray(head + b"\x02\x00\x00")) == 5


def test_read_registers_answer_length_follows_its_byte_count() -> None:
    # address, function, byte count 4, 4 data bytes, CRC: 1 + 1 + 1 + 4 + 2
    assert answer_size(3, _byte_count_rule, b"\x01\x03\x04") == 9
    assert answer_size(4, _byte_count_rule, b"\x01\x04\x04\x00\x01") == 9
    assert answer_size(4, _byte_count_rule, b"\x01\x04\x14") == 2 + 1 + 20 + 2  # 10 registers
    assert answer_size(3, _byte_count_rule, b"\x01\x03\x00") == 5  # a byte count of 0


def test_write_answers_are_an_eight_byte_echo() -> None:
    # address, function, register address (2), value or count (2), CRC (2)
    assert answer_size(6, _echo_rule, b"\x01\x06") == 8
    assert answer_size(0x10, _echo_rule, b"\x01\x10") == 8


def test_a_vendor_read_answer_length_follows_its_byte_count_field() -> None:
    assert answer_size(0x42, VENDOR.response_size, b"\x01\x42\x08") == 2 + 1 + 8 + 2
    wide = VendorRead(0x43, byte_count_bytes=2)
    assert answer_size(0x43, wide.response_size, b"\x01\x43\x00") is None
    assert answer_size(0x43, wide.response_size, b"\x01\x43\x01\x00") == 2 + 2 + 256 + 2


@pytest.mark.parametrize(
    ("function_code", "rule", "head"),
    [
        (3, _byte_count_rule, b""),
        (3, _byte_count_rule, b"\x01"),
        (3, _byte_count_rule, b"\x01\x03"),  # no byte count yet
        (4, _byte_count_rule, b"\x01\x04"),
        (6, _echo_rule, b"\x01"),
        (0x42, VENDOR.response_size, b"\x01\x42"),
        (0x2B, _device_id_rule, b"\x01"),
    ],
)
def test_too_few_bytes_give_no_length_yet(function_code: int, rule: SizeRule, head: bytes) -> None:
    assert answer_size(function_code, rule, head) is None


#: Read Device Identification (43/14, read code 2) of device 1: conformity 1, no more, next
#: object 0, two objects: VendorName (0) "ABC" and ProductCode (1) "XY", then a CRC.
DEVICE_ID_ANSWER = bytes.fromhex("01 2B 0E 02 01 00 00 02") + b"\x00\x03ABC" + b"\x01\x02XY" + b"\xaa\xbb"


def test_device_identification_answer_length_counts_each_object() -> None:
    # address, function, MEI type, read code, conformity, more, next id, object count (8),
    # object 0: id, length, 3 bytes (5), object 1: id, length, 2 bytes (4), CRC (2) = 19
    assert len(DEVICE_ID_ANSWER) == 19
    assert answer_size(0x2B, _device_id_rule, DEVICE_ID_ANSWER) == 19


def test_device_identification_answer_length_needs_every_objects_length_byte() -> None:
    # the head must reach the object count (8 bytes), then the first object's length byte
    # (byte 9), then the second's (byte 14); the second object's data are not needed
    for n in range(len(DEVICE_ID_ANSWER) + 1):
        expected = None if n < 15 else 19
        assert answer_size(0x2B, _device_id_rule, DEVICE_ID_ANSWER[:n]) == expected, n


def test_device_identification_answer_without_objects() -> None:
    assert answer_size(0x2B, _device_id_rule, bytes.fromhex("01 2B 0E 02 01 00 00 00")) == 2 + 6 + 2
