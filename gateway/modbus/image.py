"""The register image of one poll and its decoding into a ``RawSample``.

A ``RegisterImage`` holds the blocks of registers a poll's reads returned, by register space
(``input``, ``holding``, a vendor function's ``fc0x42``, a row's ``input@row3``);
``decode_sample`` takes from it what the register map (``register_map``) says a device
reports: ADC counts or float32 resistances (ohm), or a ``ValueFrame``'s values (counts,
resistance in ohm, or the device's own force in N or pressure in kPa), the
open/short/saturated bitmaps, the reference force (N), the temperature (degrees C) and the
device clock (s). A block that was not read is a ``DecodeError`` when required and absent
(None) when optional.
"""

from __future__ import annotations

import functools
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..errors import DecodeError
from .decode import decode_bitmap, decode_float32, decode_uint16, decode_values, register_value
from .register_map import (
    STATUS_BITMAP_STRIDE,
    DeviceLayout,
    Encoding,
    FrameQuantity,
    RegisterKind,
    RegisterSpace,
    ValueFrame,
    frame_space,
    status_registers,
)
from .special_codes import SpecialCodes

#: Each quantity's base unit (a frame decoded in it is not scaled).
_BASE_UNITS = {
    FrameQuantity.COUNTS: "counts",
    FrameQuantity.RESISTANCE: "ohm",
    FrameQuantity.FORCE: "N",
    FrameQuantity.PRESSURE: "kPa",
}

__all__ = ["ImageBlock", "RawSample", "RegisterImage", "RegisterKind", "RegisterSpace", "decode_sample"]

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]


@dataclass(frozen=True)
class ImageBlock:
    """Registers read by one request: ``values[k]`` is the register at ``address + k``."""

    kind: RegisterSpace
    address: int
    values: NDArray[np.uint16]

    def covers(self, kind: RegisterSpace, address: int, count: int) -> bool:
        return (
            kind == self.kind
            and self.address <= address
            and address + count <= self.address + len(self.values)
        )


@dataclass(frozen=True)
class RegisterImage:
    """The registers one poll read, as blocks (the coalesced reads of the read plan)."""

    blocks: tuple[ImageBlock, ...] = ()

    @classmethod
    def from_reads(
        cls, reads: Iterable[tuple[RegisterSpace, int, Sequence[int] | NDArray[np.uint16]]]
    ) -> RegisterImage:
        blocks = []
        for kind, address, values in reads:
            arr = np.array(values, dtype=np.uint16)  # always a copy: the image owns it
            arr.setflags(write=False)
            blocks.append(ImageBlock(kind, int(address), arr))
        return cls(tuple(blocks))

    def get(self, kind: RegisterSpace, address: int, count: int) -> NDArray[np.uint16] | None:
        """The registers ``address .. address + count - 1`` or None when not read; a range
        longer than one read (a long block split into legal reads) is joined from the reads
        that cover it end to end."""
        for b in self.blocks:
            if b.covers(kind, address, count):
                start = address - b.address
                return b.values[start : start + count]
        return self._joined(kind, address, count)

    def gather(self, kind: RegisterSpace, addresses: NDArray[np.intp], block: int) -> NDArray[np.uint16]:
        """The registers at ``addresses`` (ascending) from whichever reads hold them
        (``DecodeError`` naming frame block ``block`` if one was not read)."""
        lo, hi = int(addresses[0]), int(addresses[-1])
        out = np.zeros(len(addresses), dtype=np.uint16)
        filled = np.zeros(len(addresses), dtype=np.bool_)
        for b in self.blocks:
            end = b.address + len(b.values)
            if b.kind != kind or b.address > hi or end <= lo:
                continue
            inside = (addresses >= b.address) & (addresses < end)
            out[inside] = b.values[addresses[inside] - b.address]
            filled |= inside
        if not filled.all():
            missing = int(addresses[~filled][0])
            raise DecodeError(f"frame block {block}: {kind} register {missing} was not read")
        return out

    def _joined(self, kind: RegisterSpace, address: int, count: int) -> NDArray[np.uint16] | None:
        parts: list[NDArray[np.uint16]] = []
        at, end = address, address + count
        while at < end:
            b = next(
                (b for b in self.blocks if b.kind == kind and b.address <= at < b.address + len(b.values)),
                None,
            )
            if b is None:
                return None
            stop = min(end, b.address + len(b.values))
            parts.append(b.values[at - b.address : stop - b.address])
            at = stop
        joined = np.concatenate(parts)
        joined.setflags(write=False)
        return joined

    def require(self, kind: RegisterSpace, address: int, count: int, what: str) -> NDArray[np.uint16]:
        regs = self.get(kind, address, count)
        if regs is None:
            raise DecodeError(f"{what}: {kind} registers {address}..{address + count - 1} were not read")
        return regs


@dataclass(frozen=True)
class RawSample:
    """One poll's measurements of all N device channels, decoded but not yet converted."""

    #: ADC counts (encoding "adc"): uint16 straight from registers, float64 from a frame
    counts: NDArray[np.integer[Any]] | FloatArray | None = None
    resistance_ohm: FloatArray | None = None  # ohm (encoding "float32")
    open_bits: BoolArray | None = None
    short_bits: BoolArray | None = None
    saturated_bits: BoolArray | None = None
    temperature_c: FloatArray | None = None
    reference_force_n: FloatArray | None = None
    device_time_s: float | None = None
    #: the clock's raw counter value (ticks), for the wrap-around of narrow counters
    device_ticks: int | None = None
    #: the device's own calibrated output per channel: force (N) ...
    output_force_n: FloatArray | None = None
    #: ... or pressure (kPa), which the processor turns into force over the cell's area
    output_pressure_kpa: FloatArray | None = None
    #: per channel, whether its raw value is a declared code (``register_map.SpecialCodes``:
    #: 0 none, 1 saturated, 2 error); None when the frame declares none
    special: NDArray[np.int8] | None = None


def _strided_index(values: int, stride: int, width: int) -> NDArray[np.intp]:
    """The positions of ``values`` values of ``width`` registers, ``stride`` registers apart."""
    starts = np.arange(values, dtype=np.intp) * stride
    return (starts[:, None] + np.arange(width, dtype=np.intp)[None, :]).reshape(-1)


def decode_frame(frame: ValueFrame, image: RegisterImage) -> NDArray[np.uint16] | FloatArray:
    """A frame's values in its quantity's base unit (counts, ohm, N or kPa), channel by
    channel over its blocks. Plain 16-bit counts (uint16, big bytes, no scaling) stay uint16
    registers, so the divider's lookup tables read them; anything else is float64."""
    plain = (frame.value_type, frame.scale, frame.offset, frame.factor) == ("uint16", 1.0, 0.0, 1.0) and (
        frame.order in ("ABCD", "CDAB", "AB")
    )
    parts: list[Any] = []
    for k, b in enumerate(frame.blocks):
        space = frame_space(frame.table, frame.vendor, b.row)
        if frame.value_stride == frame.width:
            words = image.require(space, b.address, frame.span(b), f"frame block {k}")
        else:  # each value's registers, the rest skipped (and perhaps not read)
            index = _strided_index(b.values, frame.value_stride, frame.width)
            whole = image.get(space, b.address, frame.span(b))
            words = whole[index] if whole is not None else image.gather(space, b.address + index, k)
        parts.append(
            words if plain else decode_values(words, frame.value_type, frame.order, frame.scale, frame.offset)
        )
    values = parts[0] if len(parts) == 1 else np.concatenate(parts)
    if plain:
        return np.asarray(values, dtype=np.uint16)
    return (
        np.asarray(values, dtype=np.float64) * frame.factor
        if frame.factor != 1.0
        else np.asarray(values, dtype=np.float64)
    )


def _special_codes(frame: ValueFrame, image: RegisterImage) -> NDArray[np.int8]:
    """Each channel's special code (``SpecialCodes.classify``) from its raw integer; a code of
    a 16-bit value is looked up in a table made once per frame."""
    special = frame.special
    assert special is not None
    raw = decode_frame(replace(frame, scale=1.0, offset=0.0, unit=_BASE_UNITS[frame.quantity]), image)
    if frame.value_type == "uint16" and raw.dtype == np.uint16:
        return _special_table(special)[raw]
    return special.classify(np.asarray(raw).astype(np.int64))


@functools.lru_cache(maxsize=32)
def _special_table(special: SpecialCodes) -> NDArray[np.int8]:
    table = special.classify(np.arange(0x10000, dtype=np.int64))
    table.setflags(write=False)
    return table


def decode_sample(device: DeviceLayout, image: RegisterImage) -> RawSample:
    """Decode the registers of one poll of ``device`` (``DecodeError`` if any are missing)."""
    regs = device.registers
    n = device.n_channels
    wo, bo = regs.word_order, regs.byte_order
    table: RegisterKind = regs.table
    counts: Any = None
    resistance = output_force = output_pressure = None
    if regs.frame is not None:
        values = decode_frame(regs.frame, image)
        quantity = regs.frame.quantity
        if quantity is FrameQuantity.COUNTS:
            counts = values
        elif quantity is FrameQuantity.RESISTANCE:
            resistance = np.asarray(values, dtype=np.float64)
        elif quantity is FrameQuantity.FORCE:
            output_force = np.asarray(values, dtype=np.float64)
        elif quantity is FrameQuantity.PRESSURE:
            output_pressure = np.asarray(values, dtype=np.float64)
        else:
            raise DecodeError(f"unknown frame quantity {quantity!r}")
    elif device.encoding is Encoding.ADC:
        counts = decode_uint16(image.require(table, regs.adc_address, n, "ADC counts"), bo)
    elif device.encoding is Encoding.FLOAT32:
        raw = image.require(table, regs.float_address, 2 * n, "float32 resistances")
        resistance = decode_float32(raw, wo, bo)
    else:
        raise DecodeError(f"unknown encoding {device.encoding!r}")
    bitmaps: list[BoolArray | None] = [None, None, None]
    if regs.status_address is not None:
        n_regs = status_registers(n)
        for k in range(3):
            words = image.get(table, regs.status_address + k * STATUS_BITMAP_STRIDE, n_regs)
            if words is not None:
                bitmaps[k] = decode_bitmap(words, n, bo)
    temperature = reference = None
    if regs.temperature_address is not None:
        words = image.get(table, regs.temperature_address, 2 * n)
        if words is not None:
            temperature = decode_float32(words, wo, bo)
    if regs.force_reference_address is not None:
        words = image.get(table, regs.force_reference_address, 2 * n)
        if words is not None:
            reference = decode_float32(words, wo, bo)
    device_time = ticks = None
    clock = regs.clock
    if clock is not None:
        words = image.get(clock.table, clock.address, clock.registers)
        if words is not None:
            ticks = register_value(words.tolist(), wo, bo)
            device_time = ticks * clock.tick_s
    special = None
    if regs.frame is not None and regs.frame.special is not None:
        if isinstance(counts, np.ndarray) and counts.dtype == np.uint16:  # the raw registers
            special = _special_table(regs.frame.special)[counts]
        else:
            special = _special_codes(regs.frame, image)
    return RawSample(
        counts,
        resistance,
        bitmaps[0],
        bitmaps[1],
        bitmaps[2],
        temperature,
        reference,
        device_time,
        ticks,
        output_force,
        output_pressure,
        special,
    )
