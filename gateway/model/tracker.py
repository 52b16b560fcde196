"""Tracking calibrated channels: force and status from resistance, sample by sample.

The one tracker of every ``calibrated.CurveChannel`` (a line, a lookup, any curve with or
without dynamics, a device's own calibrated output): the runtime, ``apply`` and the ranking of
``calibrate`` all read force through it. It inverts ``drift``'s forward model exactly, one
sample at a time: relax the Kelvin elements over dt with the previous force held (loading or
recovery time constant by direction), move the plays with the reading x_k, then
F_k = (x_k - z1 - z2) / (1 + beta s_k), recorded as the held force. The first valid sample
starts from the equilibrium at its load (``drift`` module docstring).

Statuses (``ForceStatus``): a NaN reading is INVALID (the held force stays, the state relaxes
with it); a force at or below the channel's ``no_contact_below_n`` reads 0 N NO_CONTACT; a
force outside [force_min_n, force_max_n] is read along the curve and flagged by the
``extrapolated`` mask. ``CurveSet`` does this for a device's channels at once (vectorised over
channels); ``track_series`` for one channel over a whole record (the same arithmetic on
floats, fast for long records).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .calibrated import CurveChannel
from .drift import PLAY_SHARES, equilibrium_force_n, play_direction_series
from .inversion import ForceStatus
from .static_curves import CURVE_KINDS, CountsLookupCurve, KnotTable, LineCurve, LookupCurve, PowerLawCurve

__all__ = ["CurveSet", "CurveState", "track_series"]

FloatArray = NDArray[np.float64]
StatusArray = NDArray[np.int8]
BoolArray = NDArray[np.bool_]

_OK, _NO_CONTACT, _INVALID = int(ForceStatus.OK), int(ForceStatus.NO_CONTACT), int(ForceStatus.INVALID)
_DUMMY: tuple[tuple[float, ...], tuple[float, ...]] = ((1.0, 2.0), (1.0, 0.0))


@dataclass(frozen=True)
class CurveState:
    """Per-channel state of curve channels (arrays over the device's curve channels): the
    Kelvin elements z1, z2 (N), the plays (N), the held force (N), whether the channel has
    had its first valid sample (before it, the next valid sample sets the equilibrium) and the
    sensitivity element's log gain u."""

    z1: FloatArray
    z2: FloatArray
    play_n: FloatArray  # (channels, len(PLAY_SHARES))
    last_force_n: FloatArray
    started: BoolArray
    #: the log of each channel's sensitivity (``drift``'s sensitivity element; 0 at rest)
    log_gain: FloatArray
    #: the last valid reading x (N): what the sensitivity element follows
    last_reading_n: FloatArray

    @classmethod
    def zeros(cls, n: int) -> CurveState:
        zero = np.zeros(n)
        return cls(zero, zero, np.zeros((n, len(PLAY_SHARES))), zero, np.zeros(n, dtype=np.bool_), zero, zero)

    @classmethod
    def rested(cls, n: int) -> CurveState:
        """The state of channels known to have been unloaded long enough to settle."""
        return replace(cls.zeros(n), started=np.ones(n, dtype=np.bool_))

    def select(self, idx: NDArray[np.intp]) -> CurveState:
        return CurveState(
            self.z1[idx], self.z2[idx], self.play_n[idx], self.last_force_n[idx], self.started[idx],
            self.log_gain[idx], self.last_reading_n[idx],
        )  # fmt: skip


class CurveSet:
    """The curve channels of a device at positions ``positions``, tracked together (vectorised
    over channels, each kind of curve with its own arrays)."""

    def __init__(self, channels: Sequence[CurveChannel], positions: Sequence[int] | None = None) -> None:
        self.channels = tuple(channels)
        n = len(self.channels)
        self.positions = np.asarray(range(n) if positions is None else positions, dtype=np.intp)
        chans = self.channels
        power = [c.curve if isinstance(c.curve, PowerLawCurve) else PowerLawCurve(1.0, 1.0) for c in chans]
        line = [c.curve if isinstance(c.curve, LineCurve) else LineCurve(1.0, 0.0) for c in chans]
        self.kind = np.array([CURVE_KINDS.index(c.curve.kind) for c in chans], dtype=np.intp)
        self.gain = np.array([c.gain for c in chans], dtype=np.float64)
        self.offset = np.array([c.offset_n for c in chans], dtype=np.float64)
        self.low = np.array([c.force_min_n for c in chans], dtype=np.float64)
        self.high = np.array([c.force_max_n for c in chans], dtype=np.float64)
        self.floor = np.array([c.no_contact_below_n for c in chans], dtype=np.float64)
        self.k = np.array([p.coefficient_s for p in power], dtype=np.float64)
        self.inv_n = np.array([1.0 / p.exponent for p in power], dtype=np.float64)
        self.m = np.array([x.slope_s_per_n for x in line], dtype=np.float64)
        self.c = np.array([x.intercept_s for x in line], dtype=np.float64)
        self.knots = KnotTable(
            [
                (c.curve.knot_abscissa(), c.curve.force_n)
                if isinstance(c.curve, LookupCurve)
                else (c.curve.knot_abscissa(), c.curve._knot_forces())
                if isinstance(c.curve, CountsLookupCurve)
                else _DUMMY
                for c in chans
            ]
        )
        #: tables given in counts, read at their readings' exact codes (not in ln R): the
        #: channels of each front end, and one of their curves (the code is the front end's)
        by_front_end: dict[object, tuple[list[int], CountsLookupCurve]] = {}
        for k, c in enumerate(chans):
            if isinstance(c.curve, CountsLookupCurve):
                group = by_front_end.setdefault(c.curve.front_end, ([], c.curve))
                group[0].append(k)
        self.in_counts = tuple((np.array(ks, dtype=np.intp), curve) for ks, curve in by_front_end.values())
        self.is_power = self.kind == 0
        self.is_line = self.kind == 1
        self.is_lookup = self.kind == 2
        d = [c.drift for c in self.channels]
        self.a1 = np.array([x.creep_fraction for x in d])
        self.tau1 = np.array([x.creep_tau_s for x in d])
        self.rec1 = np.array([x.recovery_tau1_s for x in d])
        self.a2 = np.array([x.creep2_fraction for x in d])
        self.tau2 = np.array([x.creep2_tau_s for x in d])
        self.rec2 = np.array([x.recovery_tau2_s for x in d])
        self.sign1, self.sign2 = np.sign(self.a1), np.sign(self.a2)
        self.cs = np.array([x.sensitivity_per_n for x in d])
        self.taus = np.array([x.sensitivity_tau_s for x in d])
        self.recs = np.array([x.recovery_sensitivity_tau_s for x in d])
        self.signs = np.sign(self.cs)
        self.sensitive = bool(np.any(self.cs != 0.0))
        self.beta = np.array([x.hysteresis_fraction for x in d])
        self.width = np.array([x.hysteresis_width_n for x in d])
        #: each channel's plays' widths (channels, len(PLAY_SHARES)), N
        self.play_widths = self.width[:, None] * np.asarray(PLAY_SHARES)[None, :]
        self.dynamic = bool(any(x.active for x in d))

    def __len__(self) -> int:
        return len(self.channels)

    def initial_state(self) -> CurveState:
        """A load history not known: the first valid sample sets the equilibrium at its load."""
        return CurveState.zeros(len(self.channels))

    def rested_state(self) -> CurveState:
        """Known to have been at rest: the first sample is tracked from a settled, unloaded state."""
        return CurveState.rested(len(self.channels))

    def static_force(self, resistance_ohm: FloatArray) -> FloatArray:
        """Each channel's apparent force x (N) at its resistance (one value per channel)."""
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            r = np.asarray(resistance_ohm, dtype=np.float64) / self.gain
            g = np.where(r > 0.0, 1.0 / np.where(r > 0.0, r, 1.0), np.nan)
            g = np.where(np.isposinf(r), 0.0, g)
            x = np.zeros_like(r)
            if self.is_power.any():
                x = np.where(self.is_power, (g / self.k) ** self.inv_n, x)
            if self.is_line.any():
                x = np.where(self.is_line, (g - self.c) / self.m, x)
            if self.is_lookup.any():
                lr = np.where(r > 0.0, np.log(np.where(r > 0.0, r, 1.0)), np.nan)
                for ks, curve in self.in_counts:
                    lr[ks] = curve.abscissa(r[ks])
                x = np.where(self.is_lookup, self.knots.force(lr), x)
            # an open sensor (no current) carries no load, whatever the curve reads at 0 S
            return np.asarray(np.where(np.isnan(g), np.nan, np.where(g == 0.0, 0.0, x + self.offset)))

    def track(
        self, resistance_ohm: FloatArray, state: CurveState, dt_s: float | FloatArray
    ) -> tuple[FloatArray, StatusArray, FloatArray, BoolArray, CurveState]:
        """One sample per channel: force (N), ``ForceStatus``, static force x (N), the
        extrapolated flag (outside the calibrated range) and the new state."""
        return self.track_apparent(self.static_force(resistance_ohm), state, dt_s)

    def track_apparent(
        self, x: FloatArray, state: CurveState, dt_s: float | FloatArray
    ) -> tuple[FloatArray, StatusArray, FloatArray, BoolArray, CurveState]:
        """``track`` from the apparent force x (N) itself: a device that calibrates its own
        static curve reports x, and only the dynamics are corrected here."""
        valid = ~np.isnan(x)
        started = state.started
        if self.dynamic:
            fresh = valid & ~started
            z1, z2, play, held = state.z1, state.z2, state.play_n, np.maximum(state.last_force_n, 0.0)
            u, x_held = state.log_gain, np.maximum(state.last_reading_n, 0.0)
            if fresh.any():  # the equilibrium at the first load (``drift``)
                f0 = np.array(
                    [equilibrium_force_n(v, c.drift) if m else 0.0
                     for v, c, m in zip(x.tolist(), self.channels, fresh.tolist(), strict=True)]
                )  # fmt: skip
                z1 = np.where(fresh, self.a1 * f0, z1)
                z2 = np.where(fresh, self.a2 * f0, z2)
                x_held = np.where(fresh, np.maximum(np.where(fresh, x, 0.0), 0.0), x_held)
                u = np.where(fresh, self.cs * x_held, u)
                play = np.where(fresh[:, None], np.where(fresh, x, 0.0)[:, None], play)
                held = np.where(fresh, f0, held)
            if isinstance(dt_s, np.ndarray):  # a step per channel (a replay: ``runtime.replay``)
                dt: float | FloatArray = np.where(np.isfinite(dt_s), np.maximum(dt_s, 0.0), 0.0)
            else:
                dt = max(float(dt_s), 0.0) if math.isfinite(dt_s) else 0.0
            t1, t2 = self.a1 * held, self.a2 * held
            # loading: the held force above the element's own unit response z / a
            e1 = np.exp(-dt / np.where((t1 - z1) * self.sign1 > 0.0, self.tau1, self.rec1))
            e2 = np.exp(-dt / np.where((t2 - z2) * self.sign2 > 0.0, self.tau2, self.rec2))
            z1 = t1 + (z1 - t1) * e1
            z2 = t2 + (z2 - t2) * e2
            if self.sensitive:
                tu = self.cs * x_held
                u = tu + (u - tu) * np.exp(-dt / np.where((tu - u) * self.signs > 0.0, self.taus, self.recs))
            widths = self.play_widths
            xs = x[:, None]
            play = np.where(valid[:, None], np.clip(play, xs - widths, xs + widths), play)
            s = np.mean((play - xs) / widths, axis=1)
            f = (x - z1 - z2) / ((1.0 + self.beta * s) * np.exp(u))
        else:
            z1, z2, play, f, u = state.z1, state.z2, state.play_n, x, state.log_gain
        invalid = np.isnan(f)
        no_contact = ~invalid & (f <= self.floor)
        status = np.where(invalid, _INVALID, np.where(no_contact, _NO_CONTACT, _OK)).astype(np.int8)
        force = np.where(invalid, np.nan, np.where(no_contact, 0.0, f))
        with np.errstate(invalid="ignore"):
            extrapolated = ~invalid & ~no_contact & ((force < self.low) | (force > self.high))
        new_held = np.where(invalid, state.last_force_n, force)
        reading = np.where(valid, x, state.last_reading_n)
        return force, status, x, extrapolated, CurveState(z1, z2, play, new_held, started | valid, u, reading)


def track_series(
    channel: CurveChannel, resistance_ohm: ArrayLike, time_s: ArrayLike, *, from_rest: bool = False
) -> tuple[FloatArray, FloatArray]:
    """One channel's tracked force and apparent (static) force over a series (N), sample by
    sample with ``CurveSet.track``'s arithmetic on floats (fast for long records): from the
    equilibrium at the first valid sample's load (``CurveSet.initial_state``) or, with
    ``from_rest``, from a settled, unloaded sensor (``CurveSet.rested_state``).

    Invalid samples read NaN and keep the held force; forces at or below the channel's
    no-contact floor read 0 N."""
    x = channel.static_force(resistance_ohm)
    floor = channel.no_contact_below_n
    d = channel.drift
    if not d.active:
        return np.where(np.isnan(x), np.nan, np.where(x <= floor, 0.0, x)), x
    t = np.asarray(time_s, dtype=np.float64)
    dt = np.maximum(np.diff(t, prepend=t[:1]), 0.0)
    a1, a2, beta = d.creep_fraction, d.creep2_fraction, d.hysteresis_fraction
    e1u, e1d = np.exp(-dt / d.creep_tau_s).tolist(), np.exp(-dt / d.recovery_tau1_s).tolist()
    e2u, e2d = np.exp(-dt / d.creep2_tau_s).tolist(), np.exp(-dt / d.recovery_tau2_s).tolist()
    c = d.sensitivity_per_n
    esu = np.exp(-dt / d.sensitivity_tau_s).tolist()
    esd = np.exp(-dt / d.recovery_sensitivity_tau_s).tolist()
    s = (
        play_direction_series(x, d.hysteresis_width_n, 0.0 if from_rest else None).tolist()
        if beta
        else [0.0] * x.size
    )
    out = [0.0] * x.size
    z1 = z2 = held = u = x_held = 0.0
    started = from_rest
    for k, xk in enumerate(x.tolist()):
        if not started and xk == xk:
            held = equilibrium_force_n(xk, d)
            x_held = max(xk, 0.0)
            z1, z2, u, started = a1 * held, a2 * held, c * x_held, True
        t1, t2, tu = a1 * held, a2 * held, c * x_held
        z1 = t1 + (z1 - t1) * (e1u[k] if (t1 - z1) * a1 > 0.0 else e1d[k])
        z2 = t2 + (z2 - t2) * (e2u[k] if (t2 - z2) * a2 > 0.0 else e2d[k])
        u = tu + (u - tu) * (esu[k] if (tu - u) * c > 0.0 else esd[k])
        if xk != xk:  # NaN: invalid, the held force stays
            out[k] = xk
            continue
        x_held = max(xk, 0.0)
        f = (xk - z1 - z2) / ((1.0 + beta * s[k]) * math.exp(u))
        if f <= floor:
            f = 0.0
        out[k] = f
        held = f
    return np.asarray(out, dtype=np.float64), x
