"""The force ranges a calibration writes: the model's own range and the calibrated one.

The calibrated range (``calibrated_min_n``/``calibrated_max_n``: outside it a force reads
``extrapolated``) reaches as far beyond the record's ends as the calibrated model reads the
record's own end loads (``end_noise_margin_n``); the physical model's own range
(``force_min_n``/``force_max_n``, where it reads no contact and saturated) reaches well beyond
it (``model_force_range``).
"""

from __future__ import annotations

import math

import numpy as np

from .fit_data import FloatArray

__all__ = [
    "LIGHT_TOUCH_N",
    "MODEL_RANGE_ABOVE",
    "MODEL_RANGE_BELOW",
    "RANGE_END_BAND",
    "RANGE_MARGIN_SIGMA",
    "end_noise_margin_n",
    "model_force_range",
    "widened_range_n",
]

#: The physical model's written range reaches light touch: force_min_n = min(calibrated
#: minimum / ``MODEL_RANGE_BELOW``, ``LIGHT_TOUCH_N``) ...
MODEL_RANGE_BELOW = 10.0
LIGHT_TOUCH_N = 0.01
#: ... and beyond the top: force_max_n = ``MODEL_RANGE_ABOVE`` x the calibrated maximum.
MODEL_RANGE_ABOVE = 3.0


def model_force_range(calibrated_n: tuple[float, float]) -> tuple[float, float]:
    """The physical model's ``force_min_n``/``force_max_n`` written for a channel calibrated
    over ``calibrated_n`` (N): from light touch (min(low / 10, 0.01 N)) to 3 x the top. Between
    them and the calibrated range the model reads forces flagged ``extrapolated``."""
    low, high = calibrated_n
    return min(low / MODEL_RANGE_BELOW, LIGHT_TOUCH_N), MODEL_RANGE_ABOVE * high


#: The calibrated range reaches this many standard deviations of the reading noise beyond
#: the record's ends (a reading of the end force lies beyond it with probability 0.13 %) ...
RANGE_MARGIN_SIGMA = 3.0
#: ... the noise measured on the rows whose reference lies within this share of the record's
#: span of each end.
RANGE_END_BAND = 0.1


def end_noise_margin_n(
    reference_n: FloatArray, force_read_n: FloatArray, range_n: tuple[float, float]
) -> tuple[float, float]:
    """How far beyond each end of the record's loaded range ``range_n`` (N) the calibrated
    model reads the record's own end loads: the reading's bias there (the median of read -
    reference, where it points outward) + ``RANGE_MARGIN_SIGMA`` x the reading's scatter.
    ``reference_n`` and ``range_n`` are as the model reads them (F_ref + the fitted zero
    offset); ``force_read_n``: the record read back with the calibrated model, row by row
    (drift-corrected, not capped at the range). Both over the consecutive rows whose reference
    lies within ``RANGE_END_BAND`` of the span of that end; the scatter is the robust
    second-difference estimate 1.4826 median|x[k-1] - 2 x[k] + x[k+1]| / sqrt(6) (a hold's
    creep and a ramp's slope cancel in a second difference, a step between two loads is an
    outlier the median ignores). 0 where fewer than 5 such triples exist."""
    lo, hi = range_n
    band = RANGE_END_BAND * max(hi - lo, 0.0)
    out: list[float] = []
    for end, outward in ((lo, -1.0), (hi, 1.0)):
        near = (reference_n > 0) & (np.abs(reference_n - end) <= band) & np.isfinite(force_read_n)
        triple = near[:-2] & near[1:-1] & near[2:]
        d2 = (force_read_n[:-2] - 2.0 * force_read_n[1:-1] + force_read_n[2:])[triple]
        if d2.size < 5:
            out.append(0.0)
            continue
        sigma = 1.4826 * float(np.median(np.abs(d2))) / math.sqrt(6.0)
        bias = outward * float(np.median((force_read_n - reference_n)[near]))
        out.append(max(bias, 0.0) + RANGE_MARGIN_SIGMA * sigma)
    return out[0], out[1]


def widened_range_n(range_n: tuple[float, float], margin_n: tuple[float, float]) -> tuple[float, float]:
    """``range_n`` (N) widened by ``margin_n`` below and above, the low end never below half of
    itself: the calibrated range written for a record's range (``end_noise_margin_n``)."""
    (low, high), (below, above) = range_n, margin_n
    return max(low - below, 0.5 * low), high + above
