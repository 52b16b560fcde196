"""The simulator's struct-based encoder against hand-computed registers (no gateway code).

Order names as Telegraf inputs.modbus documents ``byte_order``: A is the most significant
byte, letters in wire order; ABCD big-endian, DCBA little-endian, BADC bytes swapped in each
register, CDAB registers swapped; AB/BA for 16 bits; ABCDEFGH, GHEFCDAB, BADCFEHG, HGFEDCBA
for 64 bits (plugins/inputs/modbus/README.md and configuration_register.go).
"""

from __future__ import annotations

import math
import struct

import pytest

from sim_device.encodings import ORDERS, STRUCT_FORMATS, encode, layout

F32_PI = struct.unpack(">f", struct.pack(">f", math.pi))[0]

HAND: list[tuple[str, str, list[int], float]] = [
    ("float32", "ABCD", [0x3F80, 0x0000], 1.0),
    ("float32", "CDAB", [0x0000, 0x3F80], 1.0),
    ("float32", "BADC", [0x803F, 0x0000], 1.0),
    ("float32", "DCBA", [0x0000, 0x803F], 1.0),
    ("float32", "ABCD", [0x4049, 0x0FDB], F32_PI),
    ("float32", "CDAB", [0x0FDB, 0x4049], F32_PI),
    ("float32", "BADC", [0x4940, 0xDB0F], F32_PI),
    ("float32", "DCBA", [0xDB0F, 0x4940], F32_PI),
    ("uint32", "ABCD", [0x1234, 0x5678], 0x12345678),
    ("uint32", "CDAB", [0x5678, 0x1234], 0x12345678),
    ("uint32", "BADC", [0x3412, 0x7856], 0x12345678),
    ("uint32", "DCBA", [0x7856, 0x3412], 0x12345678),
    ("int32", "ABCD", [0xFFFF, 0xFFFF], -1),
    ("int32", "DCBA", [0xFFFF, 0xFFFF], -1),
    ("int32", "ABCD", [0xFFFF, 0xFFFE], -2),
    ("int32", "CDAB", [0xFFFE, 0xFFFF], -2),
    ("int32", "BADC", [0xFFFF, 0xFEFF], -2),
    ("int32", "DCBA", [0xFEFF, 0xFFFF], -2),
    ("int16", "ABCD", [0xFFFE], -2),
    ("int16", "AB", [0xFFFE], -2),
    ("int16", "CDAB", [0xFFFE], -2),
    ("int16", "BADC", [0xFEFF], -2),
    ("int16", "BA", [0xFEFF], -2),
    ("int16", "DCBA", [0xFEFF], -2),
    ("uint16", "AB", [0x1234], 0x1234),
    ("uint16", "BA", [0x3412], 0x1234),
    ("float64", "ABCD", [0x4009, 0x21FB, 0x5444, 0x2D18], math.pi),
    ("float64", "ABCDEFGH", [0x4009, 0x21FB, 0x5444, 0x2D18], math.pi),
    ("float64", "CDAB", [0x2D18, 0x5444, 0x21FB, 0x4009], math.pi),
    ("float64", "GHEFCDAB", [0x2D18, 0x5444, 0x21FB, 0x4009], math.pi),
    ("float64", "BADC", [0x0940, 0xFB21, 0x4454, 0x182D], math.pi),
    ("float64", "BADCFEHG", [0x0940, 0xFB21, 0x4454, 0x182D], math.pi),
    ("float64", "DCBA", [0x182D, 0x4454, 0xFB21, 0x0940], math.pi),
    ("float64", "HGFEDCBA", [0x182D, 0x4454, 0xFB21, 0x0940], math.pi),
]


@pytest.mark.parametrize(("value_type", "order", "registers", "value"), HAND)
def test_hand_computed(value_type: str, order: str, registers: list[int], value: float) -> None:
    assert encode([value], value_type, order) == registers


def test_several_values_are_concatenated() -> None:
    assert encode([1, 2, 3], "uint32", "CDAB") == [1, 0, 2, 0, 3, 0]
    assert encode([], "float64", "ABCD") == []


def test_scale_and_offset() -> None:
    # raw = (value - offset) / scale, the inverse of Telegraf's value = raw * scale (+ offset)
    assert encode([230.1], "int16", "AB", scale=0.1) == [2301]
    assert encode([2931 * 0.1 - 273.15], "uint16", "AB", scale=0.1, offset=-273.15) == [2931]
    assert encode([3.0], "float32", "CDAB", scale=2.0, offset=1.0) == [0x0000, 0x3F80]
    assert encode([2.5, 3.5], "uint16", "AB") == [2, 4]  # nearest, ties to even


def test_special_floats() -> None:
    assert encode([math.inf], "float32", "ABCD") == [0x7F80, 0x0000]
    assert encode([-math.inf], "float32", "DCBA") == [0x0000, 0x80FF]
    assert encode([math.nan], "float64", "ABCD")[0] & 0x7FF0 == 0x7FF0


def test_layouts() -> None:
    assert [layout("float64", o) for o in ORDERS] == ["ABCDEFGH", "GHEFCDAB", "BADCFEHG", "HGFEDCBA"]
    assert [layout("uint16", o) for o in ORDERS] == ["AB", "AB", "BA", "BA"]
    assert [layout("int32", o) for o in ORDERS] == list(ORDERS)
    assert set(STRUCT_FORMATS) == {"uint16", "int16", "uint32", "int32", "float32", "float64"}


@pytest.mark.parametrize(
    ("value_type", "order"),
    [("uint32", "AB"), ("float32", "ABCDEFGH"), ("int16", "HGFEDCBA"), ("float64", "BA"), ("int16", "XYZ")],
)
def test_order_that_does_not_fit(value_type: str, order: str) -> None:
    with pytest.raises(ValueError, match=f"byte order for {value_type} must be one of ABCD, CDAB"):
        encode([0], value_type, order)


@pytest.mark.parametrize(
    ("values", "value_type", "scale"),
    [
        ([40000], "int16", 1.0),
        ([-1], "uint16", 1.0),
        ([700.0], "uint16", 0.01),
        ([2.0**32], "uint32", 1.0),
        ([math.nan], "int32", 1.0),
        ([1e39], "float32", 1.0),
    ],
)
def test_value_that_does_not_fit(values: list[float], value_type: str, scale: float) -> None:
    with pytest.raises(ValueError, match=value_type):
        encode(values, value_type, "ABCD", scale=scale)


def test_unknown_type_and_bad_scale() -> None:
    with pytest.raises(ValueError, match="value type must be one of uint16, int16"):
        encode([0], "int64", "ABCD")
    with pytest.raises(ValueError, match="scale"):
        encode([0], "uint16", "ABCD", scale=0.0)
