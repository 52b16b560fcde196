"""``VendorRead``: request bytes, answer parsing and framing against hand-written bytes."""

from __future__ import annotations

import pytest

from gateway.errors import ConfigError, DecodeError, GatewayError
from gateway.modbus.vendor_fc import VendorRead

SKIN = VendorRead(0x42)


def test_skin_request_for_all_60_points() -> None:
    assert SKIN.request_data(0, 60) == b"\x00\x00\x00\x3c"
    assert SKIN.request_data(0x0102, 3) == b"\x01\x02\x00\x03"


def test_skin_answer_of_60_points() -> None:
    words = [(k * 257) & 0xFFFF for k in range(60)]
    data = b"\x78" + b"".join(w.to_bytes(2, "big") for w in words)
    assert len(data) == 121
    assert SKIN.registers(data, 60) == words
    assert SKIN.response_size(data[:1]) == 121
    assert SKIN.response_size(b"") is None


def test_big_endian_words() -> None:
    assert SKIN.registers(b"\x04\x12\x34\xff\x01", 2) == [0x1234, 0xFF01]


@pytest.mark.parametrize(
    ("data", "count", "needle"),
    [
        (b"\x04\x00\x01\x00", 2, "byte count 4 but 3"),  # a byte short
        (b"\x02\x00\x01\x00\x02", 2, "byte count 2 but 4"),  # a byte count that lies
        (b"\x02\x00\x01", 2, "expected 4 for 2 words"),  # consistent, but not what was asked
        (b"", 1, "no 1-byte byte count"),
    ],
)
def test_bad_byte_count_is_a_decode_error(data: bytes, count: int, needle: str) -> None:
    with pytest.raises(DecodeError, match=needle):
        SKIN.registers(data, count)


def test_field_widths_and_units() -> None:
    narrow = VendorRead(0x64, address_bytes=1, count_bytes=1, count_unit="bytes", byte_count_bytes=2)
    assert narrow.request_data(7, 5) == b"\x07\x0a"  # 5 words = 10 bytes
    assert narrow.registers(b"\x00\x02\xab\xcd", 1) == [0xABCD]
    assert narrow.response_size(b"\x00") is None
    assert narrow.response_size(b"\x01\x00") == 2 + 256
    bare = VendorRead(0x41, address_bytes=0, count_bytes=0)
    assert bare.request_data(0, 60) == b""
    assert bare.parse_request(b"") == (0, None)
    assert SKIN.parse_request(b"\x00\x05\x00\x0a") == (5, 10)
    assert narrow.parse_request(b"\x07\x0a") == (7, 5)
    assert SKIN.response_data([1, 0x0203]) == b"\x04\x00\x01\x02\x03"


def test_values_that_do_not_fit_the_fields() -> None:
    narrow = VendorRead(0x64, address_bytes=1, count_bytes=1)
    with pytest.raises(GatewayError, match=r"does not fit the 1-byte start field \(0..255\)"):
        narrow.request_data(256, 1)
    with pytest.raises(GatewayError, match="no start field"):
        VendorRead(0x41, address_bytes=0).request_data(1, 1)
    with pytest.raises(GatewayError, match=r"count 0 outside 1..125"):
        SKIN.request_data(0, 0)
    with pytest.raises(GatewayError, match=r"count 126 outside 1..125"):
        SKIN.request_data(0, 126)
    assert VendorRead(0x64, count_bytes=1, count_unit="bytes").max_count == 125
    assert VendorRead(0x64, byte_count_bytes=2).max_count == 125


@pytest.mark.parametrize(
    ("kwargs", "needle"),
    [
        ({"function_code": 3}, r"function_code = 3 \(0x03\) is a public Modbus function"),
        ({"function_code": 43}, "user-defined code \\(65-72 = 0x41-0x48 or 100-110 = 0x64-0x6E\\)"),
        ({"function_code": 0}, r"must be an integer in 1..127"),
        ({"function_code": 128}, r"must be an integer in 1..127"),
        ({"function_code": True}, r"must be an integer in 1..127"),
        ({"function_code": 0x42, "address_bytes": 3}, r"address_bytes = 3 must be one of 0, 1, 2"),
        ({"function_code": 0x42, "count_bytes": -1}, r"count_bytes = -1 must be one of 0, 1, 2"),
        ({"function_code": 0x42, "byte_count_bytes": 0}, r"byte_count_bytes = 0 must be one of 1, 2"),
        (
            {"function_code": 0x42, "count_unit": "words"},
            r"count_unit = 'words' must be one of registers, bytes",
        ),
    ],
)
def test_validation_messages_name_the_allowed_values(kwargs: dict[str, object], needle: str) -> None:
    with pytest.raises(ConfigError, match=needle):
        VendorRead(**kwargs)  # type: ignore[arg-type]


def test_non_public_codes_outside_the_user_ranges_are_allowed() -> None:
    for code in (0x41, 0x48, 0x64, 0x6E, 0x09, 0x7F):
        assert VendorRead(code).function_code == code
