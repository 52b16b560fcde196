"""Register decoding: Modbus 16-bit registers to counts, float32 values and status bitmaps.

Pure and vectorized (numpy); no I/O. A Modbus register is a 16-bit word that the protocol
sends high byte first. Devices differ in how they lay multi-register values out:

* ``byte_order`` is the order of the two bytes inside each register as the device meant
  them ("big": high byte first, the Modbus default; "little": swapped).
* ``word_order`` is the order of the registers inside a 32/64-bit value ("big": the high
  word at the lower address; "little": the low word first).

The register map of ``docs/register-map.md`` is big/big ("ABCD"). Every function raises
``DecodeError`` (never returns garbage) when the registers cannot be what was asked for.

``decode_values``/``encode_values`` speak Telegraf's (inputs.modbus) vocabulary instead: a
value type from ``VALUE_TYPES`` and a ``byte_order`` name from ``VALUE_ORDERS``, where A is
the most significant byte of the value and the letters are listed in wire order:

* ``ABCD``: big-endian, the Modbus default (word_order "big", byte_order "big");
* ``CDAB``: registers (words) swapped (word_order "little", byte_order "big");
* ``BADC``: bytes swapped inside each register (word_order "big", byte_order "little");
* ``DCBA``: little-endian (word_order "little", byte_order "little").

16-bit types only have a byte order: ABCD and CDAB read "AB", BADC and DCBA read "BA"; the
two-letter names "AB"/"BA" are accepted for them. For float64 the four names generalise to
ABCDEFGH, GHEFCDAB, BADCFEHG and HGFEDCBA, which are accepted as spellings too (Telegraf's
register-style configuration accepts exactly these 2/4/8-letter names and maps the 8-letter
ones to the 4-letter ones).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Final

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..errors import DecodeError

Order = str  # "big" or "little" (validated)
U16Array = NDArray[np.uint16]
FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]

_ORDERS = ("big", "little")
BITS_PER_REGISTER = 16

VALUE_TYPES: Final = {"uint16": 1, "int16": 1, "uint32": 2, "int32": 2, "float32": 2, "float64": 4}
"""Registers per value of every type ``decode_values`` understands."""

VALUE_ORDERS: Final = ("ABCD", "CDAB", "BADC", "DCBA")
"""Telegraf's ``byte_order`` names (A = most significant byte, letters in wire order)."""

# (word_order, byte_order) of each accepted name, per register count of the type.
_ORDER_PARTS_32: Final = {
    "ABCD": ("big", "big"),
    "CDAB": ("little", "big"),
    "BADC": ("big", "little"),
    "DCBA": ("little", "little"),
}
_ORDER_PARTS: Final[dict[int, dict[str, tuple[str, str]]]] = {
    # one register: no word order ("big" by convention); CDAB reads AB, DCBA reads BA
    1: {
        "ABCD": ("big", "big"),
        "CDAB": ("big", "big"),
        "BADC": ("big", "little"),
        "DCBA": ("big", "little"),
        "AB": ("big", "big"),
        "BA": ("big", "little"),
    },
    2: dict(_ORDER_PARTS_32),
    4: {
        **_ORDER_PARTS_32,
        "ABCDEFGH": ("big", "big"),
        "GHEFCDAB": ("little", "big"),
        "BADCFEHG": ("big", "little"),
        "HGFEDCBA": ("little", "little"),
    },
}
_INT_LIMITS: Final = {
    "uint16": (0, 0xFFFF),
    "int16": (-0x8000, 0x7FFF),
    "uint32": (0, 0xFFFF_FFFF),
    "int32": (-0x8000_0000, 0x7FFF_FFFF),
}
_FLOAT32_MAX: Final = float(np.finfo(np.float32).max)


def as_registers(registers: ArrayLike, expected: int | None = None) -> U16Array:
    """Validate raw registers (integers in [0, 65535]) and return them as uint16.

    ``expected`` is the register count the request asked for; a different count is a
    ``DecodeError`` (a short or long response must not shift channels).
    """
    try:
        raw = np.asarray(registers)
    except (TypeError, ValueError) as exc:
        raise DecodeError(f"registers are not a sequence of integers: {exc}") from None
    if raw.ndim != 1:
        raise DecodeError(f"registers must be a flat sequence, got shape {raw.shape}")
    if expected is not None and raw.shape[0] != expected:
        raise DecodeError(f"expected {expected} registers, got {raw.shape[0]}")
    if raw.dtype == np.uint16:  # already registers: nothing to check
        return raw
    if raw.size == 0:
        return np.zeros(0, dtype=np.uint16)
    if raw.dtype.kind not in "iu":
        raise DecodeError(f"registers must be integers, got dtype {raw.dtype}")
    if int(raw.min()) < 0 or int(raw.max()) > 0xFFFF:
        raise DecodeError("register value outside [0, 65535]")
    return raw.astype(np.uint16)


def _check_order(name: str, value: str) -> None:
    if value not in _ORDERS:
        raise DecodeError(f"{name} must be 'big' or 'little', got {value!r}")


def _words(registers: ArrayLike, byte_order: Order) -> U16Array:
    _check_order("byte_order", byte_order)
    regs = as_registers(registers)
    if byte_order == "little":
        regs = regs.byteswap()
    return regs


def decode_uint16(registers: ArrayLike, byte_order: Order = "big") -> NDArray[np.uint16]:
    """One unsigned 16-bit value per register (ADC counts), as uint16 (0..65535 by type;
    widen before arithmetic)."""
    return _words(registers, byte_order)


def _combine(registers: ArrayLike, n_words: int, word_order: Order, byte_order: Order) -> NDArray[np.uint64]:
    _check_order("word_order", word_order)
    words = _words(registers, byte_order)
    if words.size % n_words:
        raise DecodeError(f"{words.size} registers is not a whole number of {n_words}-register values")
    grouped = words.reshape(-1, n_words).astype(np.uint64)
    if word_order == "little":
        grouped = grouped[:, ::-1]
    out = np.zeros(grouped.shape[0], dtype=np.uint64)
    for k in range(n_words):
        out = (out << np.uint64(16)) | grouped[:, k]
    return out


def decode_uint32(
    registers: ArrayLike, word_order: Order = "big", byte_order: Order = "big"
) -> NDArray[np.int64]:
    """Unsigned 32-bit values from register pairs."""
    return _combine(registers, 2, word_order, byte_order).astype(np.int64)


def decode_uint64(
    registers: ArrayLike, word_order: Order = "big", byte_order: Order = "big"
) -> NDArray[np.uint64]:
    """Unsigned 64-bit values from groups of four registers."""
    return _combine(registers, 4, word_order, byte_order)


def decode_float32(registers: ArrayLike, word_order: Order = "big", byte_order: Order = "big") -> FloatArray:
    """IEEE 754 single-precision values from register pairs, widened to float64.

    NaN and infinities pass through unchanged; judging them is the caller's job (the
    register map uses +inf for an open sensor and 0 for a short).
    """
    bits = _combine(registers, 2, word_order, byte_order).astype(np.uint32)
    with np.errstate(invalid="ignore"):  # a signalling NaN is a value here, not a warning
        return bits.view(np.float32).astype(np.float64)


def encode_float32(values: ArrayLike, word_order: Order = "big", byte_order: Order = "big") -> list[int]:
    """Inverse of ``decode_float32`` (used for writes and tests)."""
    _check_order("word_order", word_order)
    _check_order("byte_order", byte_order)
    bits = np.asarray(values, dtype=np.float32).reshape(-1).view(np.uint32)
    hi = (bits >> np.uint32(16)).astype(np.uint16)
    lo = (bits & np.uint32(0xFFFF)).astype(np.uint16)
    pairs = np.stack([hi, lo], axis=1) if word_order == "big" else np.stack([lo, hi], axis=1)
    words = pairs.reshape(-1)
    if byte_order == "little":
        words = words.byteswap()
    return [int(w) for w in words]


def decode_bitmap(registers: ArrayLike, n_bits: int, byte_order: Order = "big") -> BoolArray:
    """Status bitmap: bit i is bit (i % 16) of register i // 16 (bit 0 = least significant).

    Needs at least ceil(n_bits / 16) registers; returns a bool array of length ``n_bits``.
    """
    if n_bits < 0:
        raise DecodeError(f"bit count must be >= 0, got {n_bits}")
    words = _words(registers, byte_order)
    needed = -(-n_bits // BITS_PER_REGISTER)
    if words.size < needed:
        raise DecodeError(f"{n_bits} status bits need {needed} registers, got {words.size}")
    # little-endian bytes, least significant bit first: bit i lands at position i
    octets = words[:needed].astype("<u2", copy=False).view(np.uint8)
    bits: BoolArray = np.unpackbits(octets, count=n_bits, bitorder="little").view(np.bool_)
    return bits


def register_value(registers: Sequence[int], word_order: Order = "big", byte_order: Order = "big") -> int:
    """One unsigned value from a few registers (a 32/64-bit counter), as a Python int."""
    _check_order("word_order", word_order)
    _check_order("byte_order", byte_order)
    value = 0
    for w in registers if word_order == "big" else reversed(registers):
        w = int(w)
        if not 0 <= w <= 0xFFFF:
            raise DecodeError("register value outside [0, 65535]")
        if byte_order == "little":
            w = ((w & 0xFF) << 8) | (w >> 8)
        value = (value << 16) | w
    return value


def encode_bitmap(bits: Sequence[bool] | BoolArray, n_registers: int | None = None) -> list[int]:
    """Inverse of ``decode_bitmap`` (big byte order)."""
    flags = np.asarray(bits, dtype=bool)
    count = n_registers if n_registers is not None else -(-flags.size // BITS_PER_REGISTER)
    out = np.zeros(count, dtype=np.uint32)
    for i in np.nonzero(flags)[0]:
        out[i // BITS_PER_REGISTER] |= np.uint32(1 << (int(i) % BITS_PER_REGISTER))
    return [int(w) for w in out]


def _registers_per_value(value_type: str) -> int:
    n = VALUE_TYPES.get(value_type) if isinstance(value_type, str) else None
    if n is None:
        raise DecodeError(f"value type must be one of {', '.join(VALUE_TYPES)}, got {value_type!r}")
    return n


def _check_scale(scale: float, offset: float) -> None:
    if not (np.isfinite(scale) and scale != 0.0):
        raise DecodeError(f"scale must be a finite, non-zero number, got {scale!r}")
    if not np.isfinite(offset):
        raise DecodeError(f"offset must be a finite number, got {offset!r}")


def order_parts(order: str, value_type: str) -> tuple[str, str]:
    """(word_order, byte_order), each "big" or "little", of a Telegraf ``byte_order`` name.

    ``order`` is one of ``VALUE_ORDERS``; "AB"/"BA" are also accepted for 16-bit types and
    "ABCDEFGH"/"GHEFCDAB"/"BADCFEHG"/"HGFEDCBA" for float64 (names are case-sensitive, as
    in Telegraf). A 16-bit type has no word order: its word_order is always "big" (CDAB
    reads like ABCD, DCBA like BADC). ``DecodeError`` (naming the names allowed for the
    type) for an unknown value type, an unknown name or one that does not fit the type
    (e.g. "AB" for a 32-bit type, "ABCDEFGH" for anything but float64).
    """
    allowed = _ORDER_PARTS[_registers_per_value(value_type)]
    parts = allowed.get(order) if isinstance(order, str) else None
    if parts is None:
        raise DecodeError(f"byte order for {value_type} must be one of {', '.join(allowed)}, got {order!r}")
    return parts


def decode_values(
    registers: ArrayLike, value_type: str, order: str = "ABCD", scale: float = 1.0, offset: float = 0.0
) -> FloatArray:
    """Telegraf-style decoding: one float64 per value, ``raw * scale + offset``.

    ``raw`` is the register value read as ``value_type`` (``VALUE_TYPES``; signed types are
    two's complement, float types IEEE 754) in the layout ``order`` names (see
    ``order_parts``). ``scale`` multiplies as Telegraf's ``scale`` does; ``offset`` (not a
    Telegraf setting) is added after scaling, so it is in the final unit. With the defaults
    (scale 1, offset 0) no arithmetic is done and the raw value comes back bit-exact.
    uint32/int32 are exact in float64. Float NaN and infinities are not rejected: they pass
    through (scaled: an infinity keeps or flips its sign with the sign of ``scale``) and
    judging them is the caller's job.

    ``DecodeError`` for an unknown type or order, a register count that is not a whole
    number of values, a register outside [0, 65535], a zero or non-finite ``scale`` or a
    non-finite ``offset``.
    """
    n = _registers_per_value(value_type)
    word_order, byte_order = order_parts(order, value_type)
    _check_scale(scale, offset)
    regs = as_registers(registers)
    if regs.size % n:
        raise DecodeError(
            f"{regs.size} registers is not a whole number of {value_type} values ({n} registers each)"
        )
    out: FloatArray
    if n == 1:
        words = _words(regs, byte_order)
        out = (words.view(np.int16) if value_type == "int16" else words).astype(np.float64)
    else:
        bits = _combine(regs, n, word_order, byte_order)
        if value_type == "uint32":
            out = bits.astype(np.float64)
        elif value_type == "int32":
            out = bits.astype(np.uint32).view(np.int32).astype(np.float64)
        elif value_type == "float32":
            with np.errstate(invalid="ignore"):  # a signalling NaN is a value here, not a warning
                out = bits.astype(np.uint32).view(np.float32).astype(np.float64)
        else:  # float64
            out = bits.view(np.float64)
    if scale != 1.0:
        out = out * scale
    if offset != 0.0:
        out = out + offset
    return out


def encode_values(
    values: ArrayLike, value_type: str, order: str = "ABCD", scale: float = 1.0, offset: float = 0.0
) -> list[int]:
    """Inverse of ``decode_values`` (for writes and tests): registers, in wire order.

    Each value becomes ``raw = (value - offset) / scale``. Integer types round ``raw`` to
    the nearest integer (ties to even, like Python's ``round``); float32 rounds it to the
    nearest single-precision value. NaN and infinities are encoded as such for float types.

    Errors are ``DecodeError`` (the module's one error type, so callers catch one thing),
    never a silent wrap or clamp: an unknown type or order, a bad ``scale``/``offset``, an
    integer type given a NaN/infinity or a value whose rounded ``raw`` is outside the
    type's range, a finite value too large for float32 after scaling.
    """
    n = _registers_per_value(value_type)
    word_order, byte_order = order_parts(order, value_type)
    _check_scale(scale, offset)
    try:
        given = np.asarray(values, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError) as exc:
        raise DecodeError(f"values are not numbers: {exc}") from None
    raw = given
    if offset != 0.0:
        raw = raw - offset
    if scale != 1.0:
        raw = raw / scale
    bits: NDArray[np.uint64]
    limits = _INT_LIMITS.get(value_type)
    if limits is not None:
        lo, hi = limits
        rounded = np.rint(raw)
        bad = ~np.isfinite(rounded) | (rounded < lo) | (rounded > hi)
        if bad.any():
            i = int(np.argmax(bad))
            raise DecodeError(
                f"value {float(given[i])!r} is {float(raw[i])!r} after (value - offset) / scale, "
                f"outside {value_type} [{lo}, {hi}]"
            )
        bits = (rounded.astype(np.int64) & np.int64((1 << (16 * n)) - 1)).astype(np.uint64)
    elif value_type == "float32":
        too_big = np.isfinite(raw) & (np.abs(raw) > _FLOAT32_MAX)
        if too_big.any():
            # a value that rounds down to FLOAT32_MAX is fine; one that rounds to inf is not
            with np.errstate(over="ignore"):
                overflow = too_big & ~np.isfinite(raw.astype(np.float32))
            if overflow.any():
                i = int(np.argmax(overflow))
                raise DecodeError(
                    f"value {float(given[i])!r} is {float(raw[i])!r} after (value - offset) / scale, "
                    f"too large for float32"
                )
        bits = raw.astype(np.float32).view(np.uint32).astype(np.uint64)
    else:  # float64
        bits = raw.view(np.uint64)
    shifts = np.arange(16 * (n - 1), -1, -16, dtype=np.uint64)  # most significant word first
    words = ((bits[:, None] >> shifts) & np.uint64(0xFFFF)).astype(np.uint16)
    if word_order == "little":
        words = words[:, ::-1]
    flat = words.reshape(-1)
    if byte_order == "little":
        flat = flat.byteswap()
    return [int(w) for w in flat]
