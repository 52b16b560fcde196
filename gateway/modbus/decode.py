"""Register decoding: Modbus 16-bit registers to counts, float32 values and status bitmaps.

Pure and vectorized (numpy); no I/O. A Modbus register is a 16-bit word that the protocol
sends high byte first. Devices differ in how they lay multi-register values out:

* ``byte_order`` is the order of the two bytes inside each register as the device meant
  them ("big": high byte first, the Modbus default; "little": swapped).
* ``word_order`` is the order of the registers inside a 32/64-bit value ("big": the high
  word at the lower address; "little": the low word first).

The register map of ``docs/register-map.md`` is big/big ("ABCD"). Every function raises
``DecodeError`` (never returns garbage) when the registers cannot be what was asked for.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..errors import DecodeError

Order = str  # "big" or "little" (validated)
U16Array = NDArray[np.uint16]
FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]

_ORDERS = ("big", "little")
BITS_PER_REGISTER = 16


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
