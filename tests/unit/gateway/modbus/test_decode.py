"""Register decoding: uint16 counts, float32 in all word/byte orders, status bitmaps."""

from __future__ import annotations

import struct

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from gateway.errors import DecodeError
from gateway.modbus.decode import (
    as_registers,
    decode_bitmap,
    decode_float32,
    decode_uint16,
    decode_uint32,
    decode_uint64,
    encode_bitmap,
    encode_float32,
)


def test_uint16_counts_big_and_little_byte_order() -> None:
    assert decode_uint16([0, 1, 0x1234, 0xFFFF]).tolist() == [0, 1, 0x1234, 0xFFFF]
    assert decode_uint16([0x3412, 0x0100], byte_order="little").tolist() == [0x1234, 1]


def test_float32_abcd_matches_struct() -> None:
    raw = struct.pack(">ff", 1.5, -1234.25)
    regs = list(struct.unpack(">4H", raw))
    assert decode_float32(regs).tolist() == [1.5, -1234.25]


@pytest.mark.parametrize(
    ("word_order", "byte_order", "layout"),
    [
        ("big", "big", "ABCD"),
        ("little", "big", "CDAB"),
        ("big", "little", "BADC"),
        ("little", "little", "DCBA"),
    ],
)
def test_float32_orders(word_order: str, byte_order: str, layout: str) -> None:
    value = 10000.0
    abcd = struct.pack(">f", value)
    wire = bytes(abcd["ABCD".index(c)] for c in layout)
    regs = list(struct.unpack(">2H", wire))
    assert decode_float32(regs, word_order, byte_order).tolist() == [value]
    assert encode_float32([value], word_order, byte_order) == regs


def test_float32_special_values_pass_through() -> None:
    regs = encode_float32([np.inf, 0.0, np.nan, -1.0])
    out = decode_float32(regs)
    assert np.isposinf(out[0]) and out[1] == 0.0 and np.isnan(out[2]) and out[3] == -1.0


@given(st.lists(st.floats(width=32, allow_nan=False), min_size=1, max_size=40))
def test_float32_roundtrip(values: list[float]) -> None:
    for wo in ("big", "little"):
        for bo in ("big", "little"):
            assert decode_float32(encode_float32(values, wo, bo), wo, bo).tolist() == values


def test_uint32_and_uint64() -> None:
    assert decode_uint32([0x0001, 0x0002]).tolist() == [0x00010002]
    assert decode_uint32([0x0002, 0x0001], word_order="little").tolist() == [0x00010002]
    assert decode_uint64([0, 0, 0x0001, 0x86A0]).tolist() == [100000]
    assert decode_uint64([0xFFFF] * 4).tolist() == [2**64 - 1]


def test_odd_register_count_for_float32_is_a_decode_error() -> None:
    with pytest.raises(DecodeError, match="whole number"):
        decode_float32([1, 2, 3])


def test_register_validation() -> None:
    with pytest.raises(DecodeError, match="expected 3 registers, got 2"):
        as_registers([1, 2], expected=3)
    with pytest.raises(DecodeError, match="outside"):
        as_registers([70000])
    with pytest.raises(DecodeError, match="outside"):
        as_registers([-1])
    with pytest.raises(DecodeError, match="integers"):
        as_registers([1.5])
    with pytest.raises(DecodeError, match="big' or 'little"):
        decode_float32([0, 0], word_order="middle")


def test_bitmap_layout_bit_i_mod_16_of_register_i_div_16() -> None:
    # channels 0, 3, 15 in register 0 and channel 17 in register 1
    regs = [(1 << 0) | (1 << 3) | (1 << 15), 1 << 1]
    bits = decode_bitmap(regs, 20)
    assert np.nonzero(bits)[0].tolist() == [0, 3, 15, 17]
    assert encode_bitmap(bits) == regs


def test_bitmap_needs_enough_registers() -> None:
    with pytest.raises(DecodeError, match="need 2 registers"):
        decode_bitmap([0], 17)


@given(st.lists(st.booleans(), min_size=0, max_size=256))
def test_bitmap_roundtrip(bits: list[bool]) -> None:
    regs = encode_bitmap(bits)
    assert decode_bitmap(regs, len(bits)).tolist() == bits
