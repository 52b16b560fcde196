"""The sensor model: forward resistance, creep state, and force inversion.

Total resistance (paper eq. 10, 13, 17, extended by the named effects)::

    R_core = T(temp) * R0 (1 - eps) exp(-gamma s0 eps) + k / sqrt(F) + R_series
    R      = R_core || R_leak
    eps    = F / (A E0(F)) + e_kv1 + e_kv2 - h * d

with ``k / sqrt(F) = 2 R_con`` (eq. 12), Kelvin strains e_kv (eq. 14 in state form),
and d in [-1, 1] the load direction of the hysteresis effect: +1 after loading, -1 after
unloading. d follows the force through a narrow play (backlash) operator, p <- clip(p, F - w,
F + w) with w = 0.1 F_h, so that noise does not wander it, and then approaches the sign of
each play move exponentially in the force travelled (a Duhem / Bouc-Wen form):
d <- sign(dp) + (d - sign(dp)) exp(-|dp| / F_h), F_h = ``hysteresis_force_n``. State is
passed in and returned (``ModelState``); nothing is hidden in the model object.

Time stepping convention (shared by the forward model and the inversion, so a round trip
is exact): at each sample the state is first *relaxed* over the elapsed time with the
previous force held, the resistance is computed (or inverted) with that state, then the
new force is *recorded* into the state (it becomes the held force and moves the play).
"""

from __future__ import annotations

import enum
from collections.abc import Iterable, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .effects import parse_effects
from .params import ChannelParams, SensorParams
from .physics import contact_coefficient_ohm_sqrt_n, interparticle_separation_m, tunneling_decay_per_m

FloatArray = NDArray[np.float64]
StatusArray = NDArray[np.int8]

_NEWTON_STOP_STEP = 1e-5  # in ln F; quadratic convergence leaves an error of ~1e-10
_NEWTON_MAX_ITER = 60
#: Dead band of the hysteresis play operator, as a fraction of ``hysteresis_force_n``.
HYSTERESIS_DEAD_BAND = 0.1
_RECURRENCE_WINDOW = 65536  # bounds the rounding of the running sums
_MIN_LOG_DECAY = -36.0  # exp(-36) ~ 2e-16: a smaller factor is zero in double precision


class ForceStatus(enum.IntEnum):
    """Per-sample outcome of an inversion."""

    OK = 0
    NO_CONTACT = 1  # resistance at or above R(force_min): reads 0 N
    SATURATED = 2  # resistance at or below R(force_max): reads force_max
    INVALID = 3  # NaN, zero, negative or infinite resistance: reads NaN, never exported


# plain ints for the hot path (numpy probes an enum member's attributes on every use)
_OK, _NO_CONTACT, _SATURATED, _INVALID = (
    int(ForceStatus.OK),
    int(ForceStatus.NO_CONTACT),
    int(ForceStatus.SATURATED),
    int(ForceStatus.INVALID),
)
#: Inversion status by 4 * invalid + 2 * (R >= R(force_min)) + (R <= R(force_max)).
_STATUS_BY_CODE = np.array(
    [_OK, _SATURATED, _NO_CONTACT, _NO_CONTACT, _INVALID, _INVALID, _INVALID, _INVALID], dtype=np.int8
)


@dataclass(frozen=True)
class ModelState:
    """Per-channel state carried between samples (arrays of shape (N,))."""

    kv1_strain: FloatArray
    kv2_strain: FloatArray
    play_n: FloatArray  # hysteresis dead-band play output, N
    direction: FloatArray  # hysteresis load direction in [-1, 1]
    last_force_n: FloatArray

    @classmethod
    def zeros(cls, n_channels: int) -> ModelState:
        z = np.zeros(n_channels)
        return cls(z, z.copy(), z.copy(), z.copy(), z.copy())

    def select(self, index: ArrayLike) -> ModelState:
        """The state of a subset of channels."""
        idx = np.asarray(index)
        return ModelState(
            self.kv1_strain[idx],
            self.kv2_strain[idx],
            self.play_n[idx],
            self.direction[idx],
            self.last_force_n[idx],
        )


@dataclass(frozen=True)
class ResistanceBreakdown:
    """Forward model output; every array has the shape of the force input."""

    total_ohm: FloatArray
    contact_ohm: FloatArray
    polymer_ohm: FloatArray
    strain: FloatArray


@dataclass(frozen=True)
class Inversion:
    """Inverse model output: force estimates and their status codes (``ForceStatus``)."""

    force_n: FloatArray
    status: StatusArray


class SensorModel:
    """A model of N sensor channels: the tunneling baseline plus named effects."""

    def __init__(
        self,
        effects: str | Iterable[str],
        params: SensorParams | Sequence[SensorParams] | ChannelParams,
    ) -> None:
        self.effects: tuple[str, ...] = parse_effects(effects)
        self.params = params if isinstance(params, ChannelParams) else ChannelParams.stack(params)
        p = self.params
        on = self.has
        self._gamma_s0 = tunneling_decay_per_m(p.barrier_height_ev) * interparticle_separation_m(
            p.particle_diameter_m, p.volume_fraction
        )
        k = contact_coefficient_ohm_sqrt_n(p.rho1_ohm_m, p.rho2_ohm_m, p.hardness_pa)
        self._contact_k = k if on("contact") else np.zeros_like(k)
        self._series = p.series_resistance_ohm if on("series_resistance") else np.zeros_like(k)
        self._leak = p.leakage_resistance_ohm if on("leakage") else np.full_like(k, np.inf)
        self._has_leak = bool(on("leakage") and np.isfinite(self._leak).any())
        # with an open contact at rest, +inf is the model's own reading of an unloaded sensor
        self._open_at_rest = np.asarray((self._contact_k > 0.0) & np.isinf(self._leak))
        self._closed_at_rest = ~self._open_at_rest
        self._has_contact = bool((self._contact_k > 0.0).any())
        self._has_series = bool((self._series != 0.0).any())
        self._a_e0 = p.area_m2 * p.e0_pa
        self._a_e0_slope = p.area_m2 * p.e0_slope_pa_per_n
        self._neg_gamma_s0 = -self._gamma_s0
        self._hyst = p.hysteresis_strain if on("hysteresis") else np.zeros_like(k)
        self._force_ends = np.stack([p.force_min_n, p.force_max_n])
        self._log_force_ends = np.log(self._force_ends)
        # the parts of R(force_min) and R(force_max) that no state changes
        self._ends_strain = self._force_ends / (self._a_e0 + self._a_e0_slope * self._force_ends)
        self._ends_fixed_ohm = self._contact_k / np.sqrt(self._force_ends) + self._series

    # ----------------------------------------------------------------- structure
    def has(self, effect: str) -> bool:
        return effect in self.effects

    @property
    def n_channels(self) -> int:
        return self.params.n_channels

    def initial_state(self) -> ModelState:
        """Unloaded, fully relaxed state."""
        return ModelState.zeros(self.n_channels)

    def gamma_s0(self) -> FloatArray:
        """The exponent scale gamma * s0 of eq. 9 per channel (dimensionless)."""
        return self._gamma_s0.copy()

    # ------------------------------------------------------------------- forward
    def instantaneous_strain(self, force_n: ArrayLike) -> FloatArray:
        """Elastic strain F / (A E0(F)) of the instantaneous spring (eq. 15, first term)."""
        f = np.maximum(np.asarray(force_n, dtype=np.float64), 0.0)
        return np.asarray(f / (self._a_e0 + self._a_e0_slope * f))

    def _state_strain(self, state: ModelState | None) -> FloatArray | float:
        if state is None:
            return 0.0
        terms: list[FloatArray] = []
        if self.has("creep"):
            terms.append(state.kv1_strain)
        if self.has("creep2"):
            terms.append(state.kv2_strain)
        if self.has("hysteresis"):
            terms.append(-self._hyst * state.direction)
        if not terms:
            return 0.0
        total = terms[0]
        for t in terms[1:]:
            total = total + t
        return total

    def _temperature_factor(self, temperature_c: ArrayLike | None) -> FloatArray | float:
        if temperature_c is None or not self.has("temperature"):
            return 1.0
        p = self.params
        dt = np.asarray(temperature_c, dtype=np.float64) - p.reference_temperature_c
        return np.asarray(np.exp(p.temperature_coeff_per_k * dt))

    def _breakdown(
        self, force_n: ArrayLike, state_strain: ArrayLike, temp_factor: ArrayLike
    ) -> ResistanceBreakdown:
        f = np.asarray(force_n, dtype=np.float64)
        strain = self.instantaneous_strain(f) + np.asarray(state_strain, dtype=np.float64)
        polymer = (
            np.asarray(temp_factor) * self.params.r0_ohm * (1.0 - strain) * np.exp(-self._gamma_s0 * strain)
        )
        with np.errstate(divide="ignore"):
            contact = np.where(f > 0.0, self._contact_k / np.sqrt(np.where(f > 0.0, f, 1.0)), np.inf)
        contact = np.where(self._contact_k > 0.0, contact, 0.0)
        core = polymer + contact + self._series
        total = _parallel(core, self._leak) if self._has_leak else core
        shape = np.broadcast_shapes(f.shape, np.shape(total))
        return ResistanceBreakdown(
            total_ohm=np.broadcast_to(total, shape).astype(np.float64),
            contact_ohm=np.broadcast_to(contact, shape).astype(np.float64),
            polymer_ohm=np.broadcast_to(polymer, shape).astype(np.float64),
            strain=np.broadcast_to(strain, shape).astype(np.float64),
        )

    def breakdown(
        self,
        force_n: ArrayLike,
        state: ModelState | None = None,
        temperature_c: ArrayLike | None = None,
    ) -> ResistanceBreakdown:
        """Resistance of each channel at ``force_n`` with the given creep state.

        ``state=None`` is the relaxed, never-loaded state (the instantaneous response).
        A force <= 0 with contact on gives an open contact: +inf (or R_leak with leakage).
        """
        return self._breakdown(force_n, self._state_strain(state), self._temperature_factor(temperature_c))

    def resistance(
        self,
        force_n: ArrayLike,
        state: ModelState | None = None,
        temperature_c: ArrayLike | None = None,
    ) -> FloatArray:
        """Total resistance in ohm (see ``breakdown``)."""
        return self.breakdown(force_n, state, temperature_c).total_ohm

    def held_step(
        self, force_n: ArrayLike, time_s: ArrayLike, temperature_c: ArrayLike | None = None
    ) -> ResistanceBreakdown:
        """Closed form (eq. 15-17): a force applied as a step at t = 0 and held to ``time_s``.

        E0, E1 and mu1 are evaluated at the applied force, as the paper does.
        """
        f = np.maximum(np.asarray(force_n, dtype=np.float64), 0.0)
        t = np.asarray(time_s, dtype=np.float64)
        p = self.params
        strain: FloatArray | float = 0.0
        if self.has("creep"):
            e1 = p.e1_pa + p.e1_slope_pa_per_n * f
            mu1 = p.mu1_pa_s + p.mu1_slope_pa_s_per_n * f
            strain = f / (p.area_m2 * e1) * (1.0 - np.exp(-e1 * t / mu1))
        if self.has("creep2"):
            strain = strain + f / (p.area_m2 * p.e2_pa) * (1.0 - np.exp(-p.e2_pa * t / p.mu2_pa_s))
        if self.has("hysteresis"):
            # recorded from rest: the play moves by max(0, F - w)
            travel = np.maximum(f - HYSTERESIS_DEAD_BAND * p.hysteresis_force_n, 0.0)
            direction = np.where(t > 0.0, -np.expm1(-travel / p.hysteresis_force_n), 0.0)
            strain = strain - self._hyst * direction
        return self._breakdown(f, strain, self._temperature_factor(temperature_c))

    # --------------------------------------------------------------------- state
    def _kelvin_log_decay(self, force_n: FloatArray, dt_s: ArrayLike) -> tuple[FloatArray, FloatArray]:
        """log of kv1's per-step decay factor, and its target strain, for held forces >= 0."""
        p = self.params
        e1 = p.e1_pa + p.e1_slope_pa_per_n * force_n
        mu1 = p.mu1_pa_s + p.mu1_slope_pa_s_per_n * force_n
        neg_dt = -dt_s if isinstance(dt_s, float) else -np.asarray(dt_s, dtype=np.float64)
        return np.asarray(e1 * neg_dt / mu1), np.asarray(force_n / (p.area_m2 * e1))

    def relax(self, state: ModelState, dt_s: ArrayLike) -> ModelState:
        """Advance the creep state over ``dt_s`` seconds with ``state.last_force_n`` held.

        Exact for a constant force (eq. 14 in state form); E1 and mu1 at the held force.
        """
        p = self.params
        f = np.maximum(state.last_force_n, 0.0)
        kv1 = state.kv1_strain
        if self.has("creep"):
            log_a, target = self._kelvin_log_decay(f, dt_s)
            kv1 = target + (kv1 - target) * np.exp(log_a)
        kv2 = state.kv2_strain
        if self.has("creep2"):
            target2 = f / (p.area_m2 * p.e2_pa)
            kv2 = target2 + (kv2 - target2) * np.exp(-p.e2_pa * np.asarray(dt_s) / p.mu2_pa_s)
        return ModelState(np.asarray(kv1), np.asarray(kv2), state.play_n, state.direction, state.last_force_n)

    def record(self, state: ModelState, force_n: ArrayLike) -> ModelState:
        """Make ``force_n`` the held force and move the hysteresis direction with it."""
        f = np.maximum(np.asarray(force_n, dtype=np.float64), 0.0)
        play, direction = state.play_n, state.direction
        if self.has("hysteresis"):
            f_h = self.params.hysteresis_force_n
            w = HYSTERESIS_DEAD_BAND * f_h
            new_play = np.clip(play, f - w, f + w)
            move = new_play - play
            a = np.exp(-np.abs(move) / f_h)
            direction = np.sign(move) * (1.0 - a) + direction * a
            play = new_play
        return ModelState(state.kv1_strain, state.kv2_strain, np.asarray(play), np.asarray(direction), f)

    def _state_series(
        self, force_n: FloatArray, dt_s: FloatArray, state0: ModelState
    ) -> tuple[FloatArray, ModelState]:
        """Summed state strain before each sample for a known force series (T, N).

        ``dt_s[k]`` is the time from sample k-1 to sample k (dt_s[0] from the state's time).
        Every state variable obeys a linear recurrence x[k+1] = a[k] x[k] + b[k], solved
        in vectorized chunks; the result equals stepping ``relax``/``record`` sample by sample.
        """
        n_t = force_n.shape[0]
        held = np.maximum(np.vstack([state0.last_force_n[None, :], force_n[:-1]]), 0.0)  # before k
        dt = np.broadcast_to(dt_s.reshape(-1, 1), force_n.shape)
        total = np.zeros_like(force_n)
        p = self.params
        kv1_end, kv2_end = state0.kv1_strain, state0.kv2_strain
        play_end, dir_end = state0.play_n, state0.direction
        if self.has("creep"):
            log_a, target = self._kelvin_log_decay(held, dt)
            kv1, kv1_end = _relax_series(log_a, target, state0.kv1_strain)
            total += kv1
        if self.has("creep2"):
            log_a2 = np.broadcast_to(-p.e2_pa * dt / p.mu2_pa_s, force_n.shape)
            kv2, kv2_end = _relax_series(log_a2, held / (p.area_m2 * p.e2_pa), state0.kv2_strain)
            total += kv2
        if self.has("hysteresis"):
            f_h = p.hysteresis_force_n
            play = _play_series(force_n, HYSTERESIS_DEAD_BAND * f_h, state0.play_n)  # after recording F[k]
            move = np.diff(np.vstack([state0.play_n[None, :], play]), axis=0)
            after, _ = _relax_series(-np.abs(move) / f_h, np.sign(move), state0.direction)
            before = np.vstack([state0.direction[None, :], after[:-1]])
            total -= self._hyst * before
            play_end, dir_end = play[-1], after[-1]
        last = force_n[-1] if n_t else state0.last_force_n
        # kv ends are "before the last sample's relax"; the final state is after recording it
        return total, ModelState(
            np.asarray(kv1_end),
            np.asarray(kv2_end),
            np.asarray(play_end),
            np.asarray(dir_end),
            np.asarray(last),
        )

    def simulate(
        self,
        force_n: ArrayLike,
        time_s: ArrayLike,
        state0: ModelState | None = None,
        temperature_c: ArrayLike | None = None,
        t0_s: float | None = None,
    ) -> tuple[ResistanceBreakdown, ModelState]:
        """Forward model over a load history ``force_n`` of shape (T, N) at times (T,).

        The state is relaxed from ``t0_s`` (default: the first sample time) to each sample.
        Returns the per-sample breakdown and the state after the last sample.
        """
        f = np.maximum(np.atleast_2d(np.asarray(force_n, dtype=np.float64)), 0.0)
        f = np.broadcast_to(f, (f.shape[0], self.n_channels)).copy()
        t = np.asarray(time_s, dtype=np.float64).reshape(-1)
        state0 = state0 or self.initial_state()
        dt = np.diff(t, prepend=t[0] if t0_s is None else t0_s)
        strain, final = self._state_series(f, dt, state0)
        out = self._breakdown(f, strain, self._temperature_factor(temperature_c))
        return out, final

    # ------------------------------------------------------------------- inverse
    def invert(
        self,
        resistance_ohm: ArrayLike,
        state: ModelState | None = None,
        temperature_c: ArrayLike | None = None,
        guess_n: ArrayLike | None = None,
    ) -> Inversion:
        """Force that gives ``resistance_ohm`` with the given state (no state update).

        Flags instead of raising: >= R(force_min) is NO_CONTACT (0 N), <= R(force_max) is
        SATURATED (force_max), NaN/zero/negative/infinite is INVALID (NaN force). The one
        exception is +inf on a model whose contact is open at rest (contact on, no leakage):
        that is the model's own reading of an unloaded sensor, so it is NO_CONTACT.
        """
        strain = self._state_strain(state)
        return self._invert(
            np.asarray(resistance_ohm, dtype=np.float64),
            strain,
            self._temperature_factor(temperature_c),
            guess_n,
        )

    def invert_static(self, resistance_ohm: ArrayLike, temperature_c: ArrayLike | None = None) -> Inversion:
        """Naive inversion with no creep state: what a static lookup table reads."""
        return self.invert(resistance_ohm, None, temperature_c)

    def track(
        self,
        resistance_ohm: ArrayLike,
        state: ModelState,
        dt_s: ArrayLike,
        temperature_c: ArrayLike | None = None,
    ) -> tuple[Inversion, ModelState]:
        """Drift-corrected inversion of one sample per channel.

        Relax the state over ``dt_s`` with the previous force held, invert with it, then
        record the new force (0 N for no contact; the previous force for invalid samples).
        """
        relaxed = self.relax(state, dt_s)
        inv = self.invert(resistance_ohm, relaxed, temperature_c, guess_n=np.maximum(state.last_force_n, 0.0))
        held = np.where(inv.status == _INVALID, relaxed.last_force_n, inv.force_n)
        return inv, self.record(relaxed, held)

    def track_series(
        self,
        resistance_ohm: ArrayLike,
        time_s: ArrayLike,
        state0: ModelState | None = None,
        temperature_c: ArrayLike | None = None,
        t0_s: float | None = None,
        max_sweeps: int = 60,
    ) -> tuple[Inversion, ModelState]:
        """Drift-corrected inversion of a whole series (T, N) at once.

        Equivalent to calling ``track`` sample by sample, but solved as a fixed point over
        the whole series: invert all samples with a state history, recompute the state
        history from the forces (vectorized linear recurrences), repeat until the forces
        stop changing. Falls back to the sample-by-sample loop if that does not converge.
        """
        r = np.atleast_2d(np.asarray(resistance_ohm, dtype=np.float64))
        r = np.broadcast_to(r, (r.shape[0], self.n_channels))
        t = np.asarray(time_s, dtype=np.float64).reshape(-1)
        state0 = state0 or self.initial_state()
        dt = np.diff(t, prepend=t[0] if t0_s is None else t0_s)
        temp = self._temperature_factor(temperature_c)
        has_state = any(self.has(e) for e in ("creep", "creep2", "hysteresis"))
        strain: FloatArray | float = self._state_strain(state0)
        guess: FloatArray | None = None
        inv = self._invert(r, strain, temp, None)
        for _ in range(max_sweeps):
            held = _hold_invalid(inv, state0.last_force_n)
            state_strain, final = self._state_series(held, dt, state0)
            if not has_state:
                return inv, final
            guess = inv.force_n
            inv = self._invert(r, state_strain, temp, guess)
            change = np.abs(np.nan_to_num(inv.force_n - guess))
            if float(change.max(initial=0.0)) <= 1e-11 * max(
                1.0, float(np.nanmax(np.abs(guess), initial=0.0))
            ):
                held = _hold_invalid(inv, state0.last_force_n)
                return inv, self._state_series(held, dt, state0)[1]
        return self._track_loop(r, dt, state0, temperature_c)

    def _track_loop(
        self, r: FloatArray, dt: FloatArray, state: ModelState, temperature_c: ArrayLike | None
    ) -> tuple[Inversion, ModelState]:
        forces = np.empty_like(r)
        status = np.empty(r.shape, dtype=np.int8)
        temps = None if temperature_c is None else np.broadcast_to(np.asarray(temperature_c), r.shape)
        for k in range(r.shape[0]):
            inv, state = self.track(r[k], state, dt[k], None if temps is None else temps[k])
            forces[k], status[k] = inv.force_n, inv.status
        return Inversion(forces, status), state

    def _invert(
        self,
        r_meas: FloatArray,
        state_strain: ArrayLike,
        temp_factor: ArrayLike,
        guess_n: ArrayLike | None,
    ) -> Inversion:
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
            ends = self._ends_ohm(strain, r0t)
        else:
            shape = np.broadcast_shapes(r_meas.shape, p.r0_ohm.shape, strain.shape)
            r_meas = np.broadcast_to(r_meas, shape)
            fmin = np.broadcast_to(p.force_min_n, shape)
            fmax = np.broadcast_to(p.force_max_n, shape)
            ends = self._total_ohm(np.stack([fmin, fmax]), strain, r0t)
        r_at_min, r_at_max = ends[0], ends[1]
        # NaN compares false (and quietly) everywhere: it is invalid and neither end
        invalid = ~(r_meas > 0.0) | ((r_meas == np.inf) & self._closed_at_rest)
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
            if guess_n is None or not self._newton_fast(u, lo, hi, target, strain, r0t):
                u = self._newton(u, lo + np.zeros(shape), hi + np.zeros(shape), target, strain, r0t)
            if all_solve:
                np.exp(u, out=force)
            else:
                force = np.where(solve, np.exp(u), force)
        return Inversion(force, status)

    def _ends_ohm(self, state_strain: FloatArray, r0: FloatArray) -> FloatArray:
        """R(force_min) and R(force_max) per channel, shape (2, N), from the precomputed
        parts that do not depend on the state."""
        return self._ohm_from_parts(self._ends_strain, self._ends_fixed_ohm, state_strain, r0)

    def _total_ohm(self, force_n: FloatArray, state_strain: FloatArray, r0: FloatArray) -> FloatArray:
        """Total resistance for forces > 0 (the lean path of ``_breakdown`` for the inversion)."""
        inst_strain = force_n / (self._a_e0 + self._a_e0_slope * force_n)
        fixed_ohm = self._contact_k / np.sqrt(force_n) + self._series
        return self._ohm_from_parts(inst_strain, fixed_ohm, state_strain, r0)

    def _ohm_from_parts(
        self, inst_strain: FloatArray, fixed_ohm: FloatArray, state_strain: FloatArray, r0: FloatArray
    ) -> FloatArray:
        """R = (R0 (1 - eps) e^(-gamma s0 eps) + contact + series) || R_leak, eps = the
        instantaneous strain plus the state's."""
        eps = inst_strain + state_strain
        core = r0 * (1.0 - eps) * np.exp(self._neg_gamma_s0 * eps) + fixed_ohm
        if self._has_leak:
            return np.asarray(core * self._leak / (core + self._leak))
        return np.asarray(core)

    def _log_gap_and_slope(
        self, u: FloatArray, target: FloatArray, state_strain: FloatArray, r0: FloatArray
    ) -> tuple[FloatArray, FloatArray]:
        """g = ln R(F) - target and dg/du at F = e^u (the Newton step of both solvers).

        With q = F / (A E0(F)) and eps = q + state strain: F dR_pol/dF =
        -R0 e^(-gamma s0 eps) (1 + gamma s0 (1 - eps)) q A E0(0) / (A E0(F)) (F deps/dF);
        F d(k / sqrt F)/dF = -k / (2 sqrt F); a parallel leakage path scales the derivative
        by (R_leak / (R_core + R_leak))^2. dg/du = F dR/dF / R.
        """
        f = np.exp(u)
        den = self._a_e0 + self._a_e0_slope * f
        q = f / den
        eps = q + state_strain
        one_m = 1.0 - eps
        ex = r0 * np.exp(self._neg_gamma_s0 * eps)
        core = ex * one_m
        f_dcore = (ex * (-1.0 - self._gamma_s0 * one_m)) * (q * self._a_e0 / den)
        if self._has_contact:
            rc = self._contact_k / np.sqrt(f)
            core += rc
            f_dcore -= 0.5 * rc
        if self._has_series:
            core += self._series
        if self._has_leak:
            share = self._leak / (core + self._leak)
            core *= share
            f_dcore *= share * share
        return np.log(core) - target, f_dcore / core

    def _newton_fast(
        self,
        u: FloatArray,
        lo: FloatArray,
        hi: FloatArray,
        target: FloatArray,
        state_strain: FloatArray,
        r0: FloatArray,
        max_iter: int = 4,
    ) -> bool:
        """Plain Newton (clipped to the range) from a close guess, in place; True if converged.

        Tracking starts from the previous sample's force, where a few plain steps suffice;
        the bracketing of ``_newton`` costs twice the array operations per step.
        """
        for _ in range(max_iter):
            g, slope = self._log_gap_and_slope(u, target, state_strain, r0)
            step = g / slope
            np.minimum(np.maximum(u - step, lo), hi, out=u)
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
    ) -> FloatArray:
        """Safeguarded Newton on ln R(e^u) = target, with a bisection bracket [lo, hi]."""
        for _ in range(_NEWTON_MAX_ITER):
            g, slope = self._log_gap_and_slope(u, target, state_strain, r0)
            np.copyto(lo, u, where=g > 0.0)
            np.copyto(hi, u, where=g <= 0.0)
            step = g / slope
            new = u - step
            outside = ~((new >= lo) & (new <= hi))
            largest = float(np.max(np.abs(step), initial=0.0))
            if largest < _NEWTON_STOP_STEP and not outside.any():
                # quadratic convergence: the error after a step this small is far below 1e-12
                return new
            u = np.where(outside, 0.5 * (lo + hi), new)
        return u


def _parallel(a: ArrayLike, b: ArrayLike) -> FloatArray:
    """a || b for resistances where either may be +inf."""
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    with np.errstate(invalid="ignore", divide="ignore"):
        out = a * b / (a + b)
    out = np.where(np.isinf(a), b, out)
    return np.asarray(np.where(np.isinf(b), a, out))


def _hold_invalid(inv: Inversion, last_force_n: FloatArray) -> FloatArray:
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


def _play_series(force_n: FloatArray, radius_n: FloatArray, p0_n: FloatArray) -> FloatArray:
    """Play operator over a series, p[k] = clip(p[k-1], F[k] - r, F[k] + r), shape (T, N).

    Each step is a clamp, and clamps compose into clamps:
    clip(clip(x, a1, b1), a2, b2) = clip(x, clip(a1, a2, b2), clip(b1, a2, b2)); an inclusive
    prefix scan over the clamp bounds (log2 T vectorized passes) gives every p[k] exactly.
    """
    lo = force_n - radius_n
    hi = force_n + radius_n
    shift = 1
    while shift < force_n.shape[0]:
        lo_new = np.clip(lo[:-shift], lo[shift:], hi[shift:])
        hi_new = np.clip(hi[:-shift], lo[shift:], hi[shift:])
        lo[shift:], hi[shift:] = lo_new, hi_new
        shift *= 2
    return np.asarray(np.clip(p0_n, lo, hi))


def _relax_series(log_a: FloatArray, target: FloatArray, x0: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Solve x[k] = target[k] + (x[k-1] - target[k]) a[k] for k = 0..T-1 from x[-1] = x0.

    Returns (x, x[T-1]). Vectorized in chunks in which the cumulative log decay stays
    within the exponent range of a double; the sum is carried in scaled form.
    """
    n_t = log_a.shape[0]
    out = np.empty(np.broadcast_shapes(log_a.shape, target.shape))
    log_a = np.broadcast_to(np.maximum(log_a, _MIN_LOG_DECAY), out.shape)
    target = np.broadcast_to(target, out.shape)
    b = target * (-np.expm1(log_a))  # x[k] = a x[k-1] + (1 - a) target
    x = np.asarray(x0, dtype=np.float64)
    start = 0
    while start < n_t:
        window = min(n_t - start, _RECURRENCE_WINDOW)
        cum = np.cumsum(log_a[start : start + window], axis=0)
        over = np.nonzero(np.max(-cum, axis=tuple(range(1, cum.ndim))) > 600.0)[0]
        chunk = max(1, int(over[0])) if over.size else window
        seg = slice(start, start + chunk)
        lc = cum[:chunk]
        scaled = np.cumsum(b[seg] * np.exp(-lc), axis=0)
        out[seg] = np.exp(lc) * (x + scaled)
        x = out[start + chunk - 1]
        start += chunk
    return out, np.asarray(x)
