"""Status lookup tables of the conversion: the channel status from the read-out's verdict,
the device's fault bitmaps and the model's verdict, and the per-code lookup tables of an ADC
front end (every 16-bit register value to its resistance and status, computed once per front
end). Tables, not chains of ``where``: the poll path indexes them."""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from ..model import DividerStatus, ForceStatus, FrontEnd
from .snapshot import ChannelStatus, frozen_copy

FloatArray = NDArray[np.float64]

# plain ints: numpy compares these without probing an enum member's attributes (hot path)
_CHANNEL_ERROR = int(ChannelStatus.ERROR)
_CHANNEL_EXTRAPOLATED = int(ChannelStatus.EXTRAPOLATED)
_CHANNEL_NO_CONTACT = int(ChannelStatus.NO_CONTACT)
_CHANNEL_NO_ZERO = int(ChannelStatus.NO_ZERO)
_CHANNEL_OK = int(ChannelStatus.OK)
_CHANNEL_OPEN = int(ChannelStatus.OPEN)
_CHANNEL_SATURATED = int(ChannelStatus.SATURATED)
_CHANNEL_SHORT = int(ChannelStatus.SHORT)
_CHANNEL_STALE = int(ChannelStatus.STALE)
_CHANNEL_UNCALIBRATED = int(ChannelStatus.UNCALIBRATED)
_DIVIDER_INVALID = int(DividerStatus.INVALID)
_DIVIDER_OPEN = int(DividerStatus.OPEN)
_DIVIDER_SHORT = int(DividerStatus.SHORT)
_DIVIDER_SATURATED = int(DividerStatus.SATURATED)
_FORCE_EXTRAPOLATED = int(ForceStatus.EXTRAPOLATED)
_FORCE_INVALID = int(ForceStatus.INVALID)
_FORCE_NO_CONTACT = int(ForceStatus.NO_CONTACT)
_FORCE_OK = int(ForceStatus.OK)
_FORCE_SATURATED = int(ForceStatus.SATURATED)


#: The final status is looked up at ``FINAL_BASE_STRIDE`` * base status + 2 * model status +
#: the device's saturated bit: 2 * 4 + 1 = 9 codes per base status need a stride of 16, and
#: 16 * 6 + 9 = 105 (the largest base status is ``ERROR`` = 6: the read-out's verdicts and
#: the bitmaps give no other) still fits the int8 the processor computes it in.
FINAL_BASE_STRIDE = 16


def _final_status_table() -> NDArray[np.int8]:
    """Channel status by 16 * base status + 2 * model status + device saturated bit.

    A base status other than OK (open, short, error from the registers) stands; on a usable
    channel the model's verdict decides, and the device's saturated bit turns a force (inside
    the calibrated range or extrapolated beyond it) into saturated: the converter is at a
    rail, so the reading is at its limit (at the bottom rail the model already reads no
    contact).
    """
    assert 2 * max(ForceStatus) + 1 < FINAL_BASE_STRIDE
    assert FINAL_BASE_STRIDE * _CHANNEL_ERROR + 2 * max(ForceStatus) + 1 <= np.iinfo(np.int8).max
    table = np.empty(FINAL_BASE_STRIDE * len(ChannelStatus), dtype=np.int8)
    table.fill(_CHANNEL_ERROR)  # codes no model status gives
    by_model = {
        _FORCE_OK: _CHANNEL_OK,
        _FORCE_NO_CONTACT: _CHANNEL_NO_CONTACT,
        _FORCE_SATURATED: _CHANNEL_SATURATED,
        _FORCE_INVALID: _CHANNEL_ERROR,
        _FORCE_EXTRAPOLATED: _CHANNEL_EXTRAPOLATED,
    }
    for base in ChannelStatus:
        for model_status, channel_status in by_model.items():
            for device_saturated in (0, 1):
                value = int(base)
                if base == ChannelStatus.OK:
                    value = channel_status
                    if device_saturated and model_status in (_FORCE_OK, _FORCE_EXTRAPOLATED):
                        value = _CHANNEL_SATURATED
                table[FINAL_BASE_STRIDE * int(base) + 2 * model_status + device_saturated] = value
    table.setflags(write=False)
    return table


_FINAL_STATUS = _final_status_table()


def _base_status(divider_status: int, open_bit: int, short_bit: int) -> int:
    if open_bit:
        return _CHANNEL_OPEN
    if short_bit:
        return _CHANNEL_SHORT
    if divider_status == _DIVIDER_SATURATED:
        return _CHANNEL_SATURATED
    return _CHANNEL_ERROR if divider_status == _DIVIDER_INVALID else _CHANNEL_OK


#: Base status of an ADC channel by 4 * divider status + 2 * open bit + short bit (with bitmaps).
_BASE_FROM_BITMAPS = frozen_copy(
    np.array(
        [_base_status(d, o, sh) for d in range(len(DividerStatus)) for o in (0, 1) for sh in (0, 1)],
        dtype=np.int8,
    )
)
#: What a rail reads as when the device's bitmaps say the channel is not faulty (ohm).
_BIG_OHM = float(np.finfo(np.float64).max)
_TINY_OHM = float(np.finfo(np.float64).tiny)


@dataclass(frozen=True, eq=False)
class AdcTables:
    """Per 16-bit register value: the resistance to report (NaN for none: open or
    invalid), the resistance the model gets with and without fault bitmaps, and the
    ``DividerStatus`` (arrays of 65536, read-only); ``idle_floor`` marks the codes at the
    converter's idle floor (``FrontEnd.idle_floor_codes``)."""

    report_ohm: FloatArray
    model_ohm: FloatArray
    model_with_bitmaps_ohm: FloatArray
    status: NDArray[np.int8]
    idle_floor: NDArray[np.bool_]


@functools.lru_cache(maxsize=16)
def _adc_tables(divider: FrontEnd) -> AdcTables:
    """Lookup tables of a divider, shared by every device that has it (about 2 MB)."""
    codes = np.arange(0x10000, dtype=np.int64)
    r, status = divider.resistance(codes)
    low, high = divider.idle_floor_codes()
    return AdcTables(
        idle_floor=frozen_copy((codes >= low) & (codes <= high)),
        report_ohm=frozen_copy(np.where(r == np.inf, np.nan, r)),
        model_ohm=frozen_copy(r),
        model_with_bitmaps_ohm=frozen_copy(np.minimum(np.maximum(r, _TINY_OHM), _BIG_OHM)),
        status=frozen_copy(status),
    )


#: Base status of an ADC channel by divider status (no bitmaps: the rails are faults; an
#: ADC rail that is not the circuit's open or short level is a reading beyond the range).
_BASE_FROM_DIVIDER = frozen_copy(
    np.array([_CHANNEL_OK, _CHANNEL_OPEN, _CHANNEL_SHORT, _CHANNEL_ERROR, _CHANNEL_SATURATED], dtype=np.int8)
)
