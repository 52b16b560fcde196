"""One channel's samples prepared for a fit (``FitData``): the data ``fitting`` fits and
``objectives`` measures, below both of them.

The rows a fit may use (``usable``) are cut into training and held-out rows: the timeline is
cut in ``HELD_OUT_BLOCKS`` blocks and every fourth one is held out, so that the gaps measured
on it are on segments the fit never saw.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from .records import ChannelRecord

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]

HELD_OUT_BLOCKS = 20  # the timeline is cut in this many blocks; every fourth is held out


@dataclass(frozen=True)
class FitData:
    """One channel's samples prepared for fitting."""

    time_s: FloatArray
    resistance_ohm: FloatArray
    force_n: FloatArray
    temperature_c: FloatArray | None
    usable: BoolArray
    held_out: BoolArray
    #: per-row standard deviation of ln R (``measurement.NoiseModel``); None: uniform noise
    sigma_log: FloatArray | None = None

    @classmethod
    def from_channel(
        cls,
        channel: ChannelRecord,
        held_out_blocks: int = HELD_OUT_BLOCKS,
        sigma_log: FloatArray | None = None,
    ) -> FitData:
        if channel.force_n is None:
            raise ValueError(
                f"channel {channel.name!r} has no force_n column: a fit needs the reference force"
            )
        t = channel.time_s
        span = float(t[-1] - t[0]) if t.size else 0.0
        block = np.zeros(t.size, dtype=np.int64)
        if span > 0:
            block = np.minimum(((t - t[0]) / span * held_out_blocks).astype(np.int64), held_out_blocks - 1)
        return cls(
            time_s=t,
            resistance_ohm=channel.resistance_ohm,
            force_n=channel.force_n,
            temperature_c=channel.temperature_c,
            usable=channel.usable_for_fit(),
            held_out=np.asarray(block % 4 == 2),
            sigma_log=sigma_log,
        )

    def weights(self) -> FloatArray:
        """Residual weights 1/sigma, scaled to a median of 1 over the usable rows (uniform: 1)."""
        if self.sigma_log is None:
            return np.ones(self.time_s.size)
        s = self.sigma_log
        ok = self.usable & np.isfinite(s) & (s > 0)
        ref = float(np.median(s[ok])) if ok.any() else 1.0
        with np.errstate(divide="ignore"):
            return np.asarray(np.where(np.isfinite(s) & (s > 0), ref / s, 0.0))

    @property
    def train(self) -> BoolArray:
        return np.asarray(self.usable & ~self.held_out)

    @property
    def test(self) -> BoolArray:
        return np.asarray(self.usable & self.held_out)
