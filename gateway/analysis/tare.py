"""Zero: the unloaded baseline of every channel, from samples of an array at rest.

A channel that reads ``R_b`` unloaded where the model expects ``R(0 N)`` carries a parallel
conductance ``1/R_b - 1/R(0)`` (board leakage, a preloaded cell); the gateway takes it off every
reading (``runtime.processor``), so a channel at its baseline reads 0 N, no contact. ``tare``
measures ``R_b`` (as ADC counts for ADC devices, the raw reading) and refuses a sample set that
is not a still, unloaded array, saying which channels and why:

* too few polls (fewer than ``MIN_POLLS``);
* a channel that drifts: the mean of the last third of the polls differs from the first
  third's by more than ``max(DRIFT_FLOOR, 4 standard errors)``, in its own unit (creep after
  a load was lifted, a hand still on the array);
* a channel whose noise (standard deviation) exceeds ``max_noise`` (counts, or a relative
  ``max_noise_rel`` of the resistance for float devices);
* a channel that looks loaded: the model reads more than ``max_force_n`` at its baseline, or
  its baseline conductance is more than ``LOADED_FACTOR`` times the median channel's
  (arrays of at least 4 channels).
* a channel shorted or invalid at rest (a fault, not a baseline); a channel open at rest is
  recorded as such (no correction), and the result says so.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Final, Protocol

import numpy as np
from numpy.typing import NDArray

from ..config import DeviceConfig
from ..errors import GatewayError
from ..model import DividerStatus, SensorModel

__all__ = ["MIN_POLLS", "TareError", "TareResult", "compute_tare"]

MIN_POLLS: Final = 10
DRIFT_FLOOR_COUNTS: Final = 2.0
DRIFT_FLOOR_REL: Final = 0.005
LOADED_FACTOR: Final = 3.0

FloatArray = NDArray[np.float64]


class RawSample(Protocol):
    """One poll's values of every channel (``gateway.modbus.image.RawSample`` is one)."""

    @property
    def counts(self) -> NDArray[np.integer[Any]] | None: ...

    @property
    def resistance_ohm(self) -> FloatArray | None: ...


class TareError(GatewayError):
    """The samples are not those of a still, unloaded array (the message says why)."""


@dataclass(frozen=True)
class TareResult:
    """The baselines of a device: ``key`` is ``baseline_counts`` or ``baseline_ohm``,
    ``values`` one per channel (index order), ``resistance_ohm`` the same as resistances,
    ``force_before_n`` what the model read at each baseline without the tare."""

    key: str
    values: tuple[float, ...]
    resistance_ohm: tuple[float, ...]
    force_before_n: tuple[float, ...]
    noise: tuple[float, ...]
    n_polls: int
    notes: tuple[str, ...]


def _names(device: DeviceConfig, idx: Sequence[int] | NDArray[np.intp], detail: Sequence[str]) -> str:
    shown = [f"{device.channels[int(i)].name} ({d})" for i, d in zip(idx, detail, strict=True)]
    more = f" and {len(shown) - 6} more" if len(shown) > 6 else ""
    return ", ".join(shown[:6]) + more


def compute_tare(
    device: DeviceConfig,
    samples: Sequence[RawSample],
    *,
    max_force_n: float = 0.5,
    max_noise_counts: float = 8.0,
    max_noise_rel: float = 0.02,
) -> TareResult:
    """The baselines of ``device`` from ``samples`` of it at rest; ``TareError`` if they are
    not those of a still, unloaded array (see the module docstring)."""
    if len(samples) < MIN_POLLS:
        raise TareError(
            f"only {len(samples)} polls; a tare needs at least {MIN_POLLS} (sample longer); "
            "nothing was written"
        )
    adc = device.encoding == "adc"
    if adc:
        data = np.array([np.asarray(s.counts, dtype=np.float64) for s in samples if s.counts is not None])
    else:
        data = np.array(
            [np.asarray(s.resistance_ohm, dtype=np.float64) for s in samples if s.resistance_ohm is not None]
        )
    if data.shape[0] < MIN_POLLS:
        raise TareError("the samples carry no values of this device's encoding; nothing was written")
    n_polls = data.shape[0]
    third = max(1, n_polls // 3)
    with np.errstate(invalid="ignore"):
        mean = data.mean(axis=0)
        std = data.std(axis=0, ddof=1)
        drift = data[-third:].mean(axis=0) - data[:third].mean(axis=0)
    std_err = std * math.sqrt(2.0 / third)
    if adc:
        floor = np.full_like(mean, DRIFT_FLOOR_COUNTS)
        noisy = std > max_noise_counts
        noise_limit = f"{max_noise_counts:g} counts"
    else:
        floor = DRIFT_FLOOR_REL * np.abs(mean)
        noisy = std > max_noise_rel * np.abs(mean)
        noise_limit = f"{100 * max_noise_rel:g} % of the reading"
    finite = np.isfinite(mean)
    drifting = finite & (np.abs(drift) > np.maximum(floor, 4.0 * std_err))
    if drifting.any():
        idx = np.flatnonzero(drifting)
        unit = "counts" if adc else "ohm"
        detail = [f"{drift[i]:+.3g} {unit} over the window" for i in idx]
        raise TareError(
            f"not still: {_names(device, idx, detail)} drift; wait until the array has settled "
            "(creep after a load is lifted takes tens of seconds) and tare again; nothing was written"
        )
    noisy &= finite
    if noisy.any():
        idx = np.flatnonzero(noisy)
        detail = [f"std {std[i]:.3g}" for i in idx]
        raise TareError(
            f"too noisy: {_names(device, idx, detail)} above {noise_limit}; check the wiring or "
            "shielding, or raise the limit; nothing was written"
        )

    if adc:
        r, status = device.front_end.resistance(mean)
        value = np.rint(mean)
        _, rounded_status = device.front_end.resistance(value)
        status = np.where(rounded_status == int(DividerStatus.OK), status, rounded_status)
    else:
        r = mean.copy()
        status = np.where(np.isfinite(r) & (r > 0), int(DividerStatus.OK), int(DividerStatus.INVALID))
        value = r
    ok = status == int(DividerStatus.OK)
    labels = {int(s): s.name.lower() for s in DividerStatus}
    faulty = np.flatnonzero(np.isin(status, [int(DividerStatus.SHORT), int(DividerStatus.INVALID)]))
    if faulty.size:
        detail = [labels[int(status[i])] for i in faulty]
        raise TareError(
            f"faulty at rest: {_names(device, faulty, detail)}; a short or an invalid reading is a fault, "
            "not a baseline (disable the channel or fix it); nothing was written"
        )
    notes: list[str] = []
    not_ok = np.flatnonzero(~ok)
    if not_ok.size:
        detail = [labels[int(status[i])] for i in not_ok]
        notes.append(
            f"{_names(device, not_ok, detail)} read at a rail at rest: the baseline records it, and readings "
            "there stay flagged"
        )

    force = np.full(device.n_channels, np.nan)
    for i, ch in enumerate(device.channels):
        if ok[i]:
            model = SensorModel(ch.effects, [ch.params])
            with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
                force[i] = float(model.invert_static(np.array([r[i]])).force_n[0])
    loaded = ok & (force > max_force_n)
    conductance = np.where(ok, 1.0 / np.where(ok, r, 1.0), np.nan)
    if np.count_nonzero(ok) >= 4:
        median = float(np.nanmedian(conductance))
        loaded |= ok & (conductance > LOADED_FACTOR * median) & (median > 0)
    if loaded.any():
        idx = np.flatnonzero(loaded)
        detail = [f"{force[i]:.3g} N by the model, {r[i]:.4g} ohm" for i in idx]
        raise TareError(
            f"looks loaded: {_names(device, idx, detail)} (more than {max_force_n:g} N, or "
            f"{LOADED_FACTOR:g}x the median channel's conductance); lift everything off the array and "
            "tare again; nothing was written"
        )
    key = "baseline_counts" if adc else "baseline_ohm"
    stored = [float(v) for v in value]
    return TareResult(
        key=key,
        values=tuple(stored),
        resistance_ohm=tuple(float(x) for x in r),
        force_before_n=tuple(float(x) for x in force),
        noise=tuple(float(x) for x in std),
        n_polls=n_polls,
        notes=tuple(notes),
    )
