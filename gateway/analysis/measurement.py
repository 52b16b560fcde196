"""The measurement model of a record: how uncertain each measured log-resistance is.

Two parts, added in quadrature, per row:

- **read-out quantization**: one ADC count moves the resistance by a factor that depends on
  where the reading sits in the converter's range. For a divider (``high_side``/``low_side``,
  eq. 18) ``d ln r / d code = (R_ref + r)^2 / (FS R_ref r)``; for the reciprocal read-out of
  the TAMS boards (``reciprocal``: r = R_ref / (1 - code/N)) it is ``r / (N R_ref)``. The
  quantization's standard deviation is ``sqrt(1/12 + noise_lsb_rms^2)`` counts.
- **relative sensor noise** ``sigma_rel``, estimated from the record: ln R minus a smooth
  function of ln F (the force dependence), second-differenced along the record (which removes
  slow effects: creep, hysteresis, drift), robust scale (MAD), less the quantization share.

The front end comes from the record's ``#`` metadata: ``front_end``, ``adc_bits``,
``reference_ohm``, ``noise_lsb_rms`` (the simulator writes the last three; its front end is
eq. 18, ``high_side``), or the real files' line ``# resistance: R = R_ref / (1 - adc/1024),
R_ref = 10000 ohm``. Without it the quantization is unknown, the noise is taken as uniform in
log-resistance at the estimated level, and ``estimated`` is True (reports say so).
"""

from __future__ import annotations

import math
import re
import warnings
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]

FRONT_ENDS = ("high_side", "low_side", "reciprocal")
#: The smallest relative sensor noise the estimate may return (0.1 %).
MIN_REL_NOISE = 1e-3
_RECIPROCAL = re.compile(r"R\s*=\s*R_ref\s*/\s*\(\s*1\s*-\s*adc\s*/\s*(\d+)\s*\)")
_R_REF = re.compile(r"R_ref\s*=\s*([0-9.eE+-]+)\s*ohm")


@dataclass(frozen=True)
class ReadOut:
    """A record's front end and converter, as far as its metadata states them."""

    kind: str  # one of FRONT_ENDS
    full_scale_counts: float
    reference_ohm: float
    noise_lsb_rms: float = 0.0

    def log_r_per_count(self, resistance_ohm: FloatArray) -> FloatArray:
        """|d ln r / d code| at each resistance (inf for an open circuit)."""
        r = np.asarray(resistance_ohm, dtype=np.float64)
        ref, fs = self.reference_ohm, self.full_scale_counts
        with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
            out = r / (fs * ref) if self.kind == "reciprocal" else (ref + r) ** 2 / (fs * ref * r)
        return np.asarray(np.where(np.isfinite(r), out, np.inf))

    def describe(self) -> str:
        eq = {
            "high_side": "r = R_ref (FS/code - 1) (eq. 18)",
            "low_side": "r = R_ref code / (FS - code)",
            "reciprocal": "r = R_ref / (1 - code/N)",
        }[self.kind]
        return (
            f"{self.kind} read-out {eq}, R_ref = {self.reference_ohm:g} ohm, "
            f"{self.full_scale_counts:g} counts full scale, {self.noise_lsb_rms:g} LSB rms noise"
        )


def read_out_from_metadata(metadata: Mapping[str, str]) -> ReadOut | None:
    """The read-out a record's metadata states, or None when it does not state one."""
    text = metadata.get("resistance", "")
    m = _RECIPROCAL.search(text)
    ref = _R_REF.search(text)
    if m and ref:
        return ReadOut("reciprocal", float(m.group(1)), float(ref.group(1)))
    try:
        bits = int(float(metadata["adc_bits"]))
        reference = float(metadata["reference_ohm"])
    except (KeyError, ValueError):
        return None
    kind = metadata.get("front_end", "high_side").strip()
    if kind not in FRONT_ENDS or not (1 <= bits <= 32) or not reference > 0:
        return None
    try:
        lsb = float(metadata.get("noise_lsb_rms", "0"))
    except ValueError:
        lsb = 0.0
    full = 2.0**bits if kind == "reciprocal" else 2.0**bits - 1.0
    return ReadOut(kind, full, reference, lsb if math.isfinite(lsb) and lsb >= 0 else 0.0)


def time_is_real(metadata: Mapping[str, str]) -> bool:
    """False when the metadata says the record has no real time (``# time: none`` or a
    ``# time: sample index ...`` line): time-dependent effects cannot be identified."""
    t = metadata.get("time", "").strip().lower()
    return not (t.startswith("none") or "sample index" in t)


@dataclass(frozen=True)
class NoiseModel:
    """Per-row standard deviation of ln R, and how it was obtained."""

    sigma_log: FloatArray  # per row; inf where the reading carries no information
    quantization_log: FloatArray  # per row, the read-out's share
    rel_noise: float  # estimated relative sensor noise
    read_out: ReadOut | None

    @property
    def estimated(self) -> bool:
        """True when the read-out is unknown and the whole noise model is estimated."""
        return self.read_out is None

    def floor_log(self, rows: NDArray[np.bool_]) -> float:
        """The log-resistance RMS an exact model would leave on ``rows``."""
        s = self.sigma_log[rows]
        s = s[np.isfinite(s)]
        return float(np.sqrt(np.mean(s * s))) if s.size else math.nan

    def describe(self) -> str:
        if self.read_out is None:
            return (
                f"noise model estimated from the record (no front-end metadata): uniform "
                f"{100 * self.rel_noise:.2g} % in resistance"
            )
        q = self.quantization_log[np.isfinite(self.quantization_log)]
        worst = float(np.max(q)) if q.size else 0.0
        return (
            f"{self.read_out.describe()}; quantization up to {100 * worst:.2g} % per row, "
            f"relative sensor noise {100 * self.rel_noise:.2g} % (estimated from the record)"
        )


def noise_model(
    metadata: Mapping[str, str],
    force_n: FloatArray,
    resistance_ohm: FloatArray,
) -> NoiseModel:
    """The measurement model of one channel (see the module docstring)."""
    read_out = read_out_from_metadata(metadata)
    r = np.asarray(resistance_ohm, dtype=np.float64)
    if read_out is None:
        q = np.zeros(r.size)
    else:
        q = read_out.log_r_per_count(r) * math.sqrt(1.0 / 12.0 + read_out.noise_lsb_rms**2)
    rel = estimate_rel_noise(force_n, r, q)
    sigma = np.sqrt(q * q + rel * rel)
    sigma = np.where(np.isfinite(r) & (r > 0), sigma, np.inf)
    return NoiseModel(np.asarray(sigma), np.asarray(q), rel, read_out)


def _trend(x: FloatArray, y: FloatArray) -> FloatArray:
    """The coefficients of a cubic in x through (x, y), of a lower degree where the rows do not
    determine a cubic (fewer than four distinct x, or x values too close: numpy's RankWarning)."""
    deg = min(3, int(np.unique(x).size) - 1)
    while True:
        with warnings.catch_warnings():
            warnings.simplefilter("error", np.exceptions.RankWarning)
            try:
                return np.asarray(np.polyfit(x, y, deg))
            except np.exceptions.RankWarning:
                if deg == 0:
                    raise
                deg -= 1


def estimate_rel_noise(
    force_n: FloatArray, resistance_ohm: FloatArray, quantization_log: FloatArray
) -> float:
    """Relative sensor noise: second differences of ln R about a cubic in ln F (loaded rows)."""
    ok = (force_n > 0) & np.isfinite(resistance_ohm) & (resistance_ohm > 0)
    if np.count_nonzero(ok) < 12:
        return 0.01
    lf, lr, q = np.log(force_n[ok]), np.log(resistance_ohm[ok]), quantization_log[ok]
    u = lr - np.polyval(_trend(lf, lr), lf)
    z = u[:-2] - 2.0 * u[1:-1] + u[2:]
    qz = q[1:-1]
    calm = qz <= np.percentile(qz, 50)
    total = 1.4826 * float(np.median(np.abs(z[calm] - np.median(z[calm])))) / math.sqrt(6.0)
    quant2 = float(np.mean(qz[calm] ** 2))
    return max(math.sqrt(max(total * total - quant2, 0.0)), MIN_REL_NOISE)
