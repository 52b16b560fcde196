"""Values to Modbus registers in every Telegraf (inputs.modbus) value encoding.

The simulator's own encoder, written from Telegraf's documentation of ``byte_order`` and
not from the gateway's decoder (this package never imports ``gateway``), so that a round
trip sim-encode -> gateway-decode is checked by an independent witness. It uses the
``struct`` module byte by byte, deliberately unlike the gateway's numpy word arithmetic.

An order name lists the bytes of the value in the order they go on the wire, where A is
the most significant byte (the value packed big-endian is "ABCD..."):

* ``ABCD``: big-endian (Modbus default), ``DCBA``: little-endian,
* ``BADC``: bytes swapped inside each register, ``CDAB``: registers (words) swapped.

A 16-bit value only has two bytes: ABCD and CDAB send "AB", BADC and DCBA send "BA"; the
names "AB" and "BA" are accepted for 16-bit types. A float64 has eight: ABCD, CDAB, BADC
and DCBA mean ABCDEFGH, GHEFCDAB, BADCFEHG and HGFEDCBA, and those eight-letter names are
accepted for float64 too (Telegraf's register-style ``byte_order`` accepts exactly these
2/4/8-letter names). Each pair of wire bytes is one register, first byte high (Modbus
sends a register high byte first).

A value becomes ``raw = (value - offset) / scale`` (the inverse of Telegraf's
``value = raw * scale``, plus an offset added after scaling); integer types round ``raw`` to
the nearest integer (ties to even), float32 to the nearest single-precision value. A value
that does not fit the type raises ``ValueError``.
"""

from __future__ import annotations

import math
import struct
from collections.abc import Iterable
from typing import Final

# struct format (big-endian) of each type; its size in bytes fixes the register count
STRUCT_FORMATS: Final = {
    "uint16": ">H",
    "int16": ">h",
    "uint32": ">I",
    "int32": ">i",
    "float32": ">f",
    "float64": ">d",
}
ORDERS: Final = ("ABCD", "CDAB", "BADC", "DCBA")

# wire layout (letters of the big-endian value, in wire order) per order name and byte count
_LAYOUTS: Final[dict[int, dict[str, str]]] = {
    2: {"ABCD": "AB", "CDAB": "AB", "BADC": "BA", "DCBA": "BA", "AB": "AB", "BA": "BA"},
    4: {"ABCD": "ABCD", "CDAB": "CDAB", "BADC": "BADC", "DCBA": "DCBA"},
    8: {
        "ABCD": "ABCDEFGH",
        "CDAB": "GHEFCDAB",
        "BADC": "BADCFEHG",
        "DCBA": "HGFEDCBA",
        "ABCDEFGH": "ABCDEFGH",
        "GHEFCDAB": "GHEFCDAB",
        "BADCFEHG": "BADCFEHG",
        "HGFEDCBA": "HGFEDCBA",
    },
}


def layout(value_type: str, order: str) -> str:
    """The wire layout (e.g. "GHEFCDAB") of ``order`` for ``value_type``."""
    fmt = STRUCT_FORMATS.get(value_type)
    if fmt is None:
        raise ValueError(f"value type must be one of {', '.join(STRUCT_FORMATS)}, got {value_type!r}")
    layouts = _LAYOUTS[struct.calcsize(fmt)]
    if order not in layouts:
        raise ValueError(f"byte order for {value_type} must be one of {', '.join(layouts)}, got {order!r}")
    return layouts[order]


def _raw(value: float, value_type: str, scale: float, offset: float) -> float | int:
    raw = (float(value) - offset) / scale
    if value_type.startswith("float"):
        return raw
    if not math.isfinite(raw):
        raise ValueError(f"value {value!r} is {raw!r} after scaling: not an integer for {value_type}")
    return round(raw)


def encode(
    values: Iterable[float], value_type: str, order: str = "ABCD", scale: float = 1.0, offset: float = 0.0
) -> list[int]:
    """Registers (in wire order) holding ``values`` as ``value_type`` in layout ``order``."""
    wire_layout = layout(value_type, order)
    if not (math.isfinite(scale) and scale != 0.0) or not math.isfinite(offset):
        raise ValueError(f"scale must be finite and non-zero, offset finite; got {scale!r}, {offset!r}")
    fmt = STRUCT_FORMATS[value_type]
    registers: list[int] = []
    for value in values:
        raw = _raw(value, value_type, scale, offset)
        try:
            big_endian = struct.pack(fmt, raw)  # "ABCD...": A most significant
        except (struct.error, OverflowError) as exc:
            raise ValueError(
                f"value {value!r} ({raw!r} after scaling) does not fit {value_type}: {exc}"
            ) from None
        wire = bytes(big_endian[ord(letter) - ord("A")] for letter in wire_layout)
        registers.extend(struct.unpack(f">{len(wire) // 2}H", wire))
    return registers
