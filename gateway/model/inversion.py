"""Force from resistance: the inversion's statuses and its Newton solvers.

Inverting R(F) = R_meas is a root of g(u) = ln R(e^u) - ln R_meas in u = ln F, over the
force range [force_min_n, force_max_n]: R falls with F, so R >= R(force_min) reads as no
contact (0 N), R <= R(force_max) as saturated (force_max), and a NaN, zero, negative or
(with the sensor closed at rest) infinite resistance is invalid (NaN). Inside, a plain
clipped Newton from a close guess (tracking) or a safeguarded Newton with a bisection
bracket finds the force; both use the evaluator's g and dg/du.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .evaluator import ResistanceEvaluator
from .params import ChannelParams

FloatArray = NDArray[np.float64]
StatusArray = NDArray[np.int8]

_NEWTON_STOP_STEP = 1e-5  # in ln F; quadratic convergence leaves an error of ~1e-10
_NEWTON_MAX_ITER = 60


class ForceStatus(enum.IntEnum):
    """Per-sample outcome of an inversion."""

    OK = 0
    NO_CONTACT = 1  # resistance at or above R(force_min): reads 0 N
    SATURATED = 2  # resistance at or below R(force_max): reads force_max
    INVALID = 3  # NaN, zero, negative or infinite resistance: reads NaN, never exported
    #: a force outside the calibrated range, read along the calibration beyond it (never
    #: from the inversion itself: curves, lines and lookups set it, and the runtime for a
    #: force of the model outside a channel's calibrated range)
    EXTRAPOLATED = 4


# plain ints for the hot path (numpy probes an enum member's attributes on every use)
_OK, _NO_CONTACT, _SATURATED, _INVALID = (
    int(ForceStatus.OK),
    int(ForceStatus.NO_CONTACT),
    int(ForceStatus.SATURATED),
    int(ForceStatus.INVALID),
)
INVALID = _INVALID
#: Inversion status by 4 * invalid + 2 * (R >= R(force_min)) + (R <= R(force_max)).
_STATUS_BY_CODE = np.array(
    [_OK, _SATURATED, _NO_CONTACT, _NO_CONTACT, _INVALID, _INVALID, _INVALID, _INVALID], dtype=np.int8
)


@dataclass(frozen=True)
class Inversion:
    """Inverse model output: force estimates and their status codes (``ForceStatus``)."""

    force_n: FloatArray
    status: StatusArray


class Inverter:
    """Inverts the evaluator's R(F) over each channel's force range."""

    def __init__(self, evaluator: ResistanceEvaluator, params: ChannelParams) -> None:
        self.ev = evaluator
        self.params = params
        self._force_ends = np.stack([params.force_min_n, params.force_max_n])
        self._log_force_ends = np.log(self._force_ends)
        # the parts of R(force_min) and R(force_max) that no state changes
        self._ends_strain = evaluator.elastic_strain(self._force_ends)
        self._ends_fixed_ohm = evaluator.fixed_ohm(self._force_ends)
        self._static_ends: FloatArray | None = None

    def ends_ohm(self, state_strain: FloatArray, r0: FloatArray) -> FloatArray:
        """R(force_min) and R(force_max) per channel, shape (2, N)."""
        return self.ev.ohm_from_parts(self._ends_strain, self._ends_fixed_ohm, state_strain, r0)

    def invert(
        self,
        r_meas: FloatArray,
        state_strain: ArrayLike,
        temp_factor: ArrayLike,
        guess_n: ArrayLike | None,
    ) -> Inversion:
        """Forces (N) and ``ForceStatus`` for resistances ``r_meas`` (ohm) with the state's
        strain and the temperature factor; ``guess_n`` starts the plain Newton (tracking)."""
        p = self.params
        strain = np.asarray(state_strain, dtype=np.float64)
        shape = r_meas.shape
        r0t: FloatArray = (
            p.r0_ohm
            if isinstance(temp_factor, float) and temp_factor == 1.0
            else np.asarray(temp_factor, dtype=np.float64) * p.r0_ohm
        )
        lean = shape == p.r0_ohm.shape and strain.shape in ((), shape)
        if lean:  # one sample per channel (the polling path): no broadcasting copies
            fmin, fmax = p.force_min_n, p.force_max_n
            if r0t is p.r0_ohm and strain.ndim == 0 and float(strain) == 0.0:
                # no state, no temperature (a static inversion): the same ends every call
                if self._static_ends is None:
                    self._static_ends = self.ends_ohm(strain, r0t)
                    self._static_ends.flags.writeable = False
                ends = self._static_ends
            else:
                ends = self.ends_ohm(strain, r0t)
        else:
            shape = np.broadcast_shapes(r_meas.shape, p.r0_ohm.shape, strain.shape)
            r_meas = np.broadcast_to(r_meas, shape)
            fmin = np.broadcast_to(p.force_min_n, shape)
            fmax = np.broadcast_to(p.force_max_n, shape)
            ends = self.ev.total_ohm(np.stack([fmin, fmax]), strain, r0t)
        r_at_min, r_at_max = ends[0], ends[1]
        # NaN compares false (and quietly) everywhere: it is invalid and neither end
        invalid = ~(r_meas > 0.0) | ((r_meas == np.inf) & self.ev.closed_at_rest)
        code = invalid.view(np.int8) * np.int8(4)
        code += (r_meas >= r_at_min).view(np.int8) * np.int8(2)
        code += (r_meas <= r_at_max).view(np.int8)
        status = _STATUS_BY_CODE[code]
        solve = status == _OK
        all_solve = bool(solve.all())
        if all_solve:
            force = np.empty(shape)
        else:
            force = np.where(status == _SATURATED, fmax, 0.0)
            force[invalid] = np.nan
        if all_solve or solve.any():
            target = np.log(r_meas if all_solve else np.where(solve, r_meas, r_at_min))
            if lean:
                lo, hi = self._log_force_ends[0], self._log_force_ends[1]
            else:
                lo, hi = np.log(fmin), np.log(fmax)
            if guess_n is None:
                # straight line between the range ends in (ln F, ln R)
                lr_min, lr_max = np.log(r_at_min), np.log(np.where(r_at_max > 0, r_at_max, 1e-300))
                frac = np.clip((lr_min - target) / np.where(lr_min > lr_max, lr_min - lr_max, 1.0), 0.0, 1.0)
                u = lo + frac * (hi - lo)
            else:
                # fmax/fmin rather than clip: a NaN or infinite guess starts at the range end
                g = np.fmin(np.fmax(np.asarray(guess_n, dtype=np.float64), fmin), fmax)
                u = np.log(g) if g.shape == shape else np.log(g) + np.zeros(shape)
            # only the solved channels' convergence counts: the others stand in at a range
            # end, where with the state's strain their root may lie just outside the bracket
            care = None if all_solve else solve
            if guess_n is None or not self._newton_fast(u, lo, hi, target, strain, r0t, care):
                u = self._newton(u, lo + np.zeros(shape), hi + np.zeros(shape), target, strain, r0t, care)
            if all_solve:
                np.exp(u, out=force)
            else:
                force = np.where(solve, np.exp(u), force)
        return Inversion(force, status)

    def _newton_fast(
        self,
        u: FloatArray,
        lo: FloatArray,
        hi: FloatArray,
        target: FloatArray,
        state_strain: FloatArray,
        r0: FloatArray,
        care: NDArray[np.bool_] | None = None,
        max_iter: int = 4,
    ) -> bool:
        """Plain Newton (clipped to the range) from a close guess, in place; True if converged.

        Tracking starts from the previous sample's force, where a few plain steps suffice;
        the bracketing of ``_newton`` costs twice the array operations per step.
        """
        step_of = self.ev.log_gap_and_slope
        for _ in range(max_iter):
            g, slope = step_of(u, target, state_strain, r0)
            step = g / slope
            np.minimum(np.maximum(u - step, lo), hi, out=u)
            if care is not None:
                step = step[care]
            if float(np.abs(step).max(initial=0.0)) < _NEWTON_STOP_STEP:
                return True
        return False

    def _newton(
        self,
        u: FloatArray,
        lo: FloatArray,
        hi: FloatArray,
        target: FloatArray,
        state_strain: FloatArray,
        r0: FloatArray,
        care: NDArray[np.bool_] | None = None,
    ) -> FloatArray:
        """Safeguarded Newton on ln R(e^u) = target, with a bisection bracket [lo, hi]; done when
        the channels of ``care`` (default all) have converged."""
        for _ in range(_NEWTON_MAX_ITER):
            g, slope = self.ev.log_gap_and_slope(u, target, state_strain, r0)
            np.copyto(lo, u, where=g > 0.0)
            np.copyto(hi, u, where=g <= 0.0)
            step = g / slope
            new = u - step
            outside = ~((new >= lo) & (new <= hi))
            if care is None:
                largest = float(np.max(np.abs(step), initial=0.0))
                escaped = bool(outside.any())
            else:
                largest = float(np.max(np.abs(step[care]), initial=0.0))
                escaped = bool(outside[care].any())
            if largest < _NEWTON_STOP_STEP and not escaped:
                # quadratic convergence: the error after a step this small is far below 1e-12
                return new
            u = np.where(outside, 0.5 * (lo + hi), new)
        return u


def hold_invalid(inv: Inversion, last_force_n: FloatArray) -> FloatArray:
    """Forces used to advance the state: invalid samples hold the last valid force."""
    f = inv.force_n
    bad = inv.status == _INVALID
    if not bad.any():
        return f
    n_t = f.shape[0]
    idx = np.where(bad, -1, np.arange(n_t)[:, None])
    idx = np.maximum.accumulate(idx, axis=0)
    filled = np.take_along_axis(f, np.maximum(idx, 0), axis=0)
    return np.asarray(np.where(idx < 0, last_force_n, filled))
