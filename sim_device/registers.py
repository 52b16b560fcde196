"""The register map of ``docs/register-map.md`` as constants, encoders and write validation.

Pure python/numpy: the Modbus transport (``modbus_server``) only copies these images into
the server's register blocks and maps ``RegisterWriteError`` to exception responses.
Every multi-register value is big-endian ("ABCD": high word first, high byte first).
"""

from __future__ import annotations

import math
import struct
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .config import ELECTRONICS_LIMITS

# ------------------------------------------------------------------ holding registers
HR_CHANNEL_COUNT = 0
HR_ADC_BITS = 1
HR_SUPPLY_V = 2
HR_REFERENCE_OHM = 4
HR_SAMPLE_PERIOD_S = 6
HR_NOISE_LSB_RMS = 8
HR_GRID_COLUMNS = 10
HR_PITCH_UM = 11
HR_CHANNEL_MODE = 100

#: float32 settings: register address -> electronics field name.
HR_FLOATS: dict[int, str] = {
    HR_SUPPLY_V: "supply_v",
    HR_REFERENCE_OHM: "reference_ohm",
    HR_SAMPLE_PERIOD_S: "sample_period_s",
    HR_NOISE_LSB_RMS: "noise_lsb_rms",
}
HR_READ_ONLY = (HR_CHANNEL_COUNT, HR_GRID_COLUMNS, HR_PITCH_UM)

# -------------------------------------------------------------------- input registers
IR_SAMPLE_COUNTER = 0
IR_DEVICE_TIME_MS = 2
IR_STATUS_SUMMARY = 6
IR_OPEN_BITMAP = 16
IR_SHORT_BITMAP = 32
IR_SATURATED_BITMAP = 48
BITMAP_WORDS = 16
IR_ADC_COUNTS = 100
IR_RESISTANCE = 400
IR_TRUE_FORCE = 1000
IR_TEMPERATURE = 1600
IR_TRUE_RESISTANCE = 2200

STATUS_ANY_OPEN = 1
STATUS_ANY_SHORT = 2
STATUS_ANY_SATURATED = 4

ILLEGAL_ADDRESS = 2
ILLEGAL_VALUE = 3


class RegisterWriteError(ValueError):
    """A refused register write; ``code`` is the Modbus exception code (2 or 3)."""

    def __init__(self, code: int, message: str) -> None:
        super().__init__(message)
        self.code = code


def holding_size(n_channels: int) -> int:
    return HR_CHANNEL_MODE + n_channels


def input_size(n_channels: int) -> int:
    return IR_TRUE_RESISTANCE + 2 * n_channels


def float32_words(values: ArrayLike) -> list[int]:
    """float32 values as big-endian register pairs (high word first)."""
    return [int(w) for w in np.asarray(values, dtype=">f4").reshape(-1).view(">u2")]


def words_float32(words: Sequence[int]) -> float:
    """One float32 from two registers (high word first)."""
    return float(struct.unpack(">f", struct.pack(">HH", int(words[0]), int(words[1])))[0])


def bitmap_words(flags: NDArray[np.bool_]) -> NDArray[np.uint16]:
    """Channel i is bit (i % 16) of word i // 16; always 16 words (256 channels)."""
    bits = np.zeros(BITMAP_WORDS * 16, dtype=np.uint16)
    bits[: flags.shape[0]] = flags.astype(np.uint16)
    weights = (1 << np.arange(16, dtype=np.uint32)).astype(np.uint32)
    return np.asarray((bits.reshape(BITMAP_WORDS, 16) * weights).sum(axis=1), dtype=np.uint16)


@dataclass(frozen=True)
class Electronics:
    """Divider and converter settings of the array (the writable holding registers)."""

    adc_bits: int
    supply_v: float
    reference_ohm: float
    sample_period_s: float
    noise_lsb_rms: float


def holding_image(
    n_channels: int, columns: int, pitch_um: int, electronics: Electronics, modes: NDArray[np.int8]
) -> list[int]:
    """Holding registers 0 .. 100+N-1 (unmapped addresses read 0 here; the server marks them invalid)."""
    img = [0] * holding_size(n_channels)
    img[HR_CHANNEL_COUNT] = n_channels
    img[HR_ADC_BITS] = electronics.adc_bits
    for addr, name in HR_FLOATS.items():
        img[addr : addr + 2] = float32_words([getattr(electronics, name)])
    img[HR_GRID_COLUMNS] = columns
    img[HR_PITCH_UM] = pitch_um
    img[HR_CHANNEL_MODE : HR_CHANNEL_MODE + n_channels] = [int(m) for m in modes]
    return img


@dataclass(frozen=True)
class HoldingWrite:
    """The decoded effect of an accepted holding-register write."""

    electronics: dict[str, float]  # changed settings by field name
    modes: dict[int, int]  # channel -> mode code


def decode_holding_write(
    current: Sequence[int], n_channels: int, address: int, values: Sequence[int]
) -> HoldingWrite:
    """Validate a write of ``values`` at ``address`` against the map; nothing is applied.

    Raises ``RegisterWriteError`` with code 2 (illegal address: read-only or unmapped) or
    3 (illegal value: out of range, or half of a float32).
    """
    count = len(values)
    end = address + count
    if count < 1:
        raise RegisterWriteError(ILLEGAL_VALUE, "empty write")
    for addr in range(address, end):
        mapped = addr <= HR_PITCH_UM or HR_CHANNEL_MODE <= addr < HR_CHANNEL_MODE + n_channels
        if not mapped:
            raise RegisterWriteError(ILLEGAL_ADDRESS, f"holding register {addr} is not mapped")
        if addr in HR_READ_ONLY:
            raise RegisterWriteError(ILLEGAL_ADDRESS, f"holding register {addr} is read-only")
    for v in values:
        if not 0 <= int(v) <= 0xFFFF:
            raise RegisterWriteError(ILLEGAL_VALUE, f"register value {v!r} is not a uint16")
    proposed = list(current)
    proposed[address:end] = [int(v) for v in values]
    electronics: dict[str, float] = {}
    if address <= HR_ADC_BITS < end:
        bits = proposed[HR_ADC_BITS]
        low, high = ELECTRONICS_LIMITS["adc_bits"]
        if not low <= bits <= high:
            raise RegisterWriteError(ILLEGAL_VALUE, f"adc_bits {bits} outside {low:g}..{high:g}")
        electronics["adc_bits"] = bits
    for addr, name in HR_FLOATS.items():
        first, second = address <= addr < end, address <= addr + 1 < end
        if first != second:
            raise RegisterWriteError(
                ILLEGAL_VALUE, f"write covers half of the float32 {name} at {addr}-{addr + 1}"
            )
        if first:
            value = words_float32(proposed[addr : addr + 2])
            low, high = ELECTRONICS_LIMITS[name]
            if not (math.isfinite(value) and low <= value <= high):
                raise RegisterWriteError(ILLEGAL_VALUE, f"{name} {value!r} outside {low:g}..{high:g}")
            electronics[name] = value
    modes: dict[int, int] = {}
    for addr in range(max(address, HR_CHANNEL_MODE), min(end, HR_CHANNEL_MODE + n_channels)):
        mode = proposed[addr]
        if mode not in (0, 1, 2):
            raise RegisterWriteError(
                ILLEGAL_VALUE, f"channel_mode[{addr - HR_CHANNEL_MODE}] = {mode} is not 0, 1 or 2"
            )
        modes[addr - HR_CHANNEL_MODE] = mode
    return HoldingWrite(electronics, modes)


class InputImage:
    """Builds the input-register image 0 .. 2200+2N-1 from the latest sample (numpy, no loops)."""

    def __init__(self, n_channels: int) -> None:
        self.n = n_channels
        self.words = np.zeros(input_size(n_channels), dtype=np.uint16)

    def update(
        self,
        *,
        sample_counter: int,
        device_time_ms: int,
        open_: NDArray[np.bool_],
        short: NDArray[np.bool_],
        saturated: NDArray[np.bool_],
        adc_counts: NDArray[np.int64],
        resistance_ohm: NDArray[np.float64],
        true_force_n: NDArray[np.float64],
        temperature_c: NDArray[np.float64],
        true_resistance_ohm: NDArray[np.float64],
    ) -> list[int]:
        n, w = self.n, self.words
        counter = sample_counter & 0xFFFFFFFF
        w[IR_SAMPLE_COUNTER] = counter >> 16
        w[IR_SAMPLE_COUNTER + 1] = counter & 0xFFFF
        t_ms = max(0, int(device_time_ms)) & 0xFFFFFFFFFFFFFFFF
        for k in range(4):
            w[IR_DEVICE_TIME_MS + k] = (t_ms >> (16 * (3 - k))) & 0xFFFF
        w[IR_STATUS_SUMMARY] = (
            (STATUS_ANY_OPEN if open_.any() else 0)
            | (STATUS_ANY_SHORT if short.any() else 0)
            | (STATUS_ANY_SATURATED if saturated.any() else 0)
        )
        w[IR_OPEN_BITMAP : IR_OPEN_BITMAP + BITMAP_WORDS] = bitmap_words(open_)
        w[IR_SHORT_BITMAP : IR_SHORT_BITMAP + BITMAP_WORDS] = bitmap_words(short)
        w[IR_SATURATED_BITMAP : IR_SATURATED_BITMAP + BITMAP_WORDS] = bitmap_words(saturated)
        w[IR_ADC_COUNTS : IR_ADC_COUNTS + n] = adc_counts
        for addr, values in (
            (IR_RESISTANCE, resistance_ohm),
            (IR_TRUE_FORCE, true_force_n),
            (IR_TEMPERATURE, temperature_c),
            (IR_TRUE_RESISTANCE, true_resistance_ohm),
        ):
            w[addr : addr + 2 * n] = np.asarray(values, dtype=">f4").view(">u2")
        image: list[int] = w.tolist()
        return image
