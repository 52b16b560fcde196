"""The sensor model: forward resistance, creep state, and force inversion.

``SensorModel(effects, params)`` builds one submodel per effect of the contract, the effect
itself when named and its null variant otherwise (``effects.EFFECTS``), puts the resistance
terms behind one ``ResistanceEvaluator`` and the state-carrying effects (creep, creep2,
hysteresis) in a list it loops over. State is passed in and returned (``ModelState``);
nothing is hidden in the model object.

Time stepping convention (shared by the forward model and the inversion, so a round trip
is exact): at each sample the state is first *relaxed* over the elapsed time with the
previous force held, the resistance is computed (or inverted) with that state, then the
new force is *recorded* into the state (it becomes the held force and moves the play).
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from functools import cached_property, lru_cache

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .effects import EFFECTS, parse_effects
from .evaluator import ResistanceBreakdown, ResistanceEvaluator
from .inversion import INVALID, Inversion, Inverter, hold_invalid
from .params import ChannelParams, SensorParams
from .series import ForceSeries
from .state import ModelState
from .submodels import Factor, ParallelPath, SeriesTerm, StrainState, Submodel, Tunneling

FloatArray = NDArray[np.float64]


class SensorModel:
    """A model of N sensor channels: the tunneling baseline plus named effects."""

    def __init__(
        self,
        effects: str | Iterable[str],
        params: SensorParams | Sequence[SensorParams] | ChannelParams,
    ) -> None:
        self.effects: tuple[str, ...] = (
            _parsed(effects) if isinstance(effects, str | tuple) else parse_effects(effects)
        )
        self.params = params if isinstance(params, ChannelParams) else ChannelParams.stack(params)
        self.submodels: dict[str, Submodel] = {}
        for name, (on, off) in EFFECTS.items():
            form = on if name in self.effects or off is None else off
            self.submodels[name] = form(self.params)
        sub = self.submodels
        assert isinstance(sub["tunneling"], Tunneling)
        assert isinstance(sub["contact"], SeriesTerm) and isinstance(sub["leakage"], ParallelPath)
        assert isinstance(sub["series_resistance"], SeriesTerm)
        assert isinstance(sub["temperature"], Factor)
        self.tunneling = sub["tunneling"]
        self.temperature: Factor = sub["temperature"]
        self.evaluator = ResistanceEvaluator(
            self.tunneling, sub["contact"], sub["series_resistance"], sub["leakage"]
        )
        #: the active state-carrying effects, in canonical order
        self.state_effects: tuple[StrainState, ...] = tuple(
            s for s in sub.values() if isinstance(s, StrainState) and s.active
        )

    @cached_property
    def inverter(self) -> Inverter:
        """The force inversion (built on first use: a fit's forward runs never need it)."""
        return Inverter(self.evaluator, self.params)

    # ----------------------------------------------------------------- structure
    def has(self, effect: str) -> bool:
        return effect in self.effects

    @property
    def n_channels(self) -> int:
        return self.params.n_channels

    def initial_state(self) -> ModelState:
        """Unloaded, fully relaxed state: a sensor known to have been at rest."""
        return ModelState.zeros(self.n_channels)

    def unknown_state(self) -> ModelState:
        """A load history not known (a starting gateway, a record's first row): ``track``
        starts each channel at its first valid sample from the equilibrium at the load it reads
        (``equilibrium_state``), never from rest. Marked by a NaN held force."""
        state = ModelState.zeros(self.n_channels)
        return state.updated({"last_force_n": np.full(self.n_channels, np.nan)})

    def settled_state(self, force_n: ArrayLike) -> ModelState:
        """The state of a sensor loaded from rest to ``force_n`` (N) and held there until every
        element has settled: creep strains at F / (A E(F)), the hysteresis direction after
        loading, ``force_n`` held."""
        f = np.maximum(np.asarray(force_n, dtype=np.float64), 0.0) * np.ones(self.n_channels)
        return self.relax(self.record(ModelState.zeros(self.n_channels), f), SETTLED_S)

    def equilibrium_state(
        self, resistance_ohm: ArrayLike, temperature_c: ArrayLike | None = None
    ) -> tuple[Inversion, ModelState]:
        """The force a sensor settled at its load reads from ``resistance_ohm`` (ohm), and its
        settled state (``settled_state``): the fixed point F = invert(R, settled strain at F),
        from the instantaneous reading. Where the reading is no contact the sensor is at rest;
        where it is invalid the state stays unknown (NaN held force)."""
        r = np.asarray(resistance_ohm, dtype=np.float64) * np.ones(self.n_channels)
        inv = self.invert(r, None, temperature_c)
        for _ in range(EQUILIBRIUM_SWEEPS):
            state = self.settled_state(np.nan_to_num(inv.force_n))
            nxt = self.invert(r, state, temperature_c, guess_n=np.nan_to_num(inv.force_n))
            change = np.abs(np.nan_to_num(nxt.force_n - inv.force_n))
            inv = nxt
            if float(change.max(initial=0.0)) <= 1e-10 * max(
                1.0, float(np.nanmax(np.abs(inv.force_n), initial=0.0))
            ):
                break
        state = self.settled_state(np.nan_to_num(inv.force_n))
        unknown = inv.status == INVALID
        if unknown.any():
            state = state.updated({"last_force_n": np.where(unknown, np.nan, state.last_force_n)})
        return inv, state

    def _start_unknown(
        self, resistance_ohm: ArrayLike, state: ModelState, temperature_c: ArrayLike | None
    ) -> ModelState:
        """``state`` with every channel of unknown history set to its equilibrium at
        ``resistance_ohm`` (``equilibrium_state``); the others as they are. A channel whose
        reading is itself invalid (NaN or negative: a special code, a fault) stays unknown, so
        it costs no equilibrium sweep over the device on every sample."""
        with np.errstate(invalid="ignore"):
            readable = np.asarray(resistance_ohm, dtype=np.float64) >= 0.0
        fresh = np.isnan(state.last_force_n) & readable
        if not fresh.any():
            return state
        _, eq = self.equilibrium_state(resistance_ohm, temperature_c)
        return ModelState(
            *(np.where(fresh, getattr(eq, f), getattr(state, f)) for f in ModelState.__dataclass_fields__)
        )

    def gamma_s0(self) -> FloatArray:
        """The exponent scale gamma * s0 of eq. 9 per channel (dimensionless)."""
        return self.tunneling.gamma_s0.copy()

    # ------------------------------------------------------------------- forward
    def instantaneous_strain(self, force_n: ArrayLike) -> FloatArray:
        """Elastic strain F / (A E0(F)) of the instantaneous spring (eq. 15, first term)."""
        return self.tunneling.elastic_strain(force_n)

    def _state_strains(self, state: ModelState | None) -> dict[str, FloatArray]:
        if state is None:
            return {}
        out: dict[str, FloatArray] = {}
        for effect in self.state_effects:
            strain = effect.strain(state)
            if strain is not None:
                out[effect.term] = strain
        return out

    def _state_strain(self, state: ModelState | None) -> FloatArray | float:
        """The summed strain of the state-carrying effects (0.0 without any)."""
        if state is None:
            return 0.0
        total: FloatArray | None = None
        for effect in self.state_effects:
            strain = effect.strain(state)
            if strain is not None:
                total = strain if total is None else total + strain
        return 0.0 if total is None else total

    def _temperature_factor(self, temperature_c: ArrayLike | None) -> FloatArray | float:
        return self.temperature.factor(temperature_c)

    def breakdown(
        self,
        force_n: ArrayLike,
        state: ModelState | None = None,
        temperature_c: ArrayLike | None = None,
    ) -> ResistanceBreakdown:
        """Every term of the resistance of each channel at ``force_n`` with the given state.

        ``state=None`` is the relaxed, never-loaded state (the instantaneous response).
        A force <= 0 with contact on gives an open contact: +inf (or R_leak with leakage).
        """
        f = np.asarray(force_n, dtype=np.float64)
        return self.evaluator.breakdown(
            f, self._state_strains(state), self._temperature_factor(temperature_c)
        )

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
        strains: dict[str, FloatArray] = {}
        for effect in self.state_effects:
            strain = effect.held_step(f, t)
            if strain is not None:
                strains[effect.term] = strain
        return self.evaluator.breakdown(f, strains, self._temperature_factor(temperature_c))

    # --------------------------------------------------------------------- state
    def relax(self, state: ModelState, dt_s: ArrayLike) -> ModelState:
        """Advance the state over ``dt_s`` seconds with ``state.last_force_n`` held.

        Exact for a constant force (eq. 14 in state form); E1 and mu1 at the held force.
        """
        held = np.maximum(state.last_force_n, 0.0)
        changes: dict[str, FloatArray] = {}
        for effect in self.state_effects:
            changes.update(effect.relax(state, held, dt_s))
        return state.updated(changes)

    def record(self, state: ModelState, force_n: ArrayLike) -> ModelState:
        """Make ``force_n`` the held force and move the hysteresis direction with it."""
        f = np.maximum(np.asarray(force_n, dtype=np.float64), 0.0)
        changes: dict[str, FloatArray] = {"last_force_n": f}
        for effect in self.state_effects:
            changes.update(effect.record(state, f))
        return state.updated(changes)

    def _state_series(self, history: ForceSeries) -> tuple[dict[str, FloatArray], ModelState]:
        """Each state effect's strain before each sample of ``history``, and the state after it.

        Every state variable obeys a linear recurrence x[k+1] = a[k] x[k] + b[k], solved
        in vectorized chunks; the result equals stepping ``relax``/``record`` sample by sample.
        """
        strains: dict[str, FloatArray] = {}
        changes: dict[str, FloatArray] = {}
        for effect in self.state_effects:
            strain, end = history.solve(effect)
            if strain is not None:
                strains[effect.term] = strain
            changes.update(end)
        # kv ends are "before the last sample's relax"; the final state is after recording it
        force_n, state0 = history.force_n, history.state0
        changes["last_force_n"] = force_n[-1] if force_n.shape[0] else state0.last_force_n
        return strains, state0.updated({k: np.asarray(v) for k, v in changes.items()})

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
        history = ForceSeries.of(force_n, time_s, self.n_channels, state0 or self.initial_state(), t0_s)
        strains, final = self._state_series(history)
        temp = self._temperature_factor(temperature_c)
        return self.evaluator.breakdown(history.force_n, strains, temp, history.contact_root()), final

    def total_ohm(self, history: ForceSeries, temperature_c: ArrayLike | None = None) -> FloatArray:
        """The total resistance (T, N) in ohm over ``history``: ``simulate``'s ``total_ohm``, the
        same numbers, for a fit that drives one history with many parameter sets (the state
        effects' series are reused from ``history`` while their parameters are unchanged)."""
        strains: dict[str, FloatArray] = {}
        for effect in self.state_effects:
            strain = history.solve(effect)[0]
            if strain is not None:
                strains[effect.term] = strain
        ev, f = self.evaluator, history.force_n
        elastic = history.term(("elastic", ev.a_e0, ev.a_e0_slope), lambda: ev.elastic_of(f))
        contact = history.term(("contact", ev.contact_k), lambda: ev.contact_of(f, history.contact_root()))
        return ev.forward_ohm(f, strains, self._temperature_factor(temperature_c), elastic, contact)

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
        return self.inverter.invert(
            np.asarray(resistance_ohm, dtype=np.float64),
            self._state_strain(state),
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
        state = self._start_unknown(resistance_ohm, state, temperature_c)
        relaxed = self.relax(state, dt_s)
        inv = self.invert(resistance_ohm, relaxed, temperature_c, guess_n=np.maximum(state.last_force_n, 0.0))
        held = np.where(inv.status == INVALID, relaxed.last_force_n, inv.force_n)
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
        if t.size and np.isnan(state0.last_force_n).any():
            return self._start_then_series(r, t, dt, state0, temperature_c, max_sweeps)
        temp = self._temperature_factor(temperature_c)
        inv = self.inverter.invert(r, self._state_strain(state0), temp, None)
        for _ in range(max_sweeps):
            held = hold_invalid(inv, state0.last_force_n)
            strains, final = self._state_series(ForceSeries(held, dt, state0))
            if not self.state_effects:
                return inv, final
            guess = inv.force_n
            inv = self.inverter.invert(r, _summed(strains), temp, guess)
            change = np.abs(np.nan_to_num(inv.force_n - guess))
            if float(change.max(initial=0.0)) <= 1e-11 * max(
                1.0, float(np.nanmax(np.abs(guess), initial=0.0))
            ):
                held = hold_invalid(inv, state0.last_force_n)
                return inv, self._state_series(ForceSeries(held, dt, state0))[1]
        return self._track_loop(r, dt, state0, temperature_c)

    def _start_then_series(
        self,
        r: FloatArray,
        t: FloatArray,
        dt: FloatArray,
        state: ModelState,
        temperature_c: ArrayLike | None,
        max_sweeps: int,
    ) -> tuple[Inversion, ModelState]:
        """A history not known: sample by sample until every channel has started from its
        equilibrium, then the rest as one series."""
        temps = None if temperature_c is None else np.broadcast_to(np.asarray(temperature_c), r.shape)
        forces, status = np.empty_like(r), np.empty(r.shape, dtype=np.int8)
        k = 0
        while k < r.shape[0] and np.isnan(state.last_force_n).any():
            inv, state = self.track(r[k], state, dt[k], None if temps is None else temps[k])
            forces[k], status[k] = inv.force_n, inv.status
            k += 1
        if k < r.shape[0]:
            rest, state = self.track_series(
                r[k:], t[k:], state, None if temps is None else temps[k:], float(t[k - 1]), max_sweeps
            )
            forces[k:], status[k:] = rest.force_n, rest.status
        return Inversion(forces, status), state

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


#: How long ``settled_state`` holds the load (s): every element has settled long before.
SETTLED_S = 1e12
#: The most fixed-point sweeps ``equilibrium_state`` takes.
EQUILIBRIUM_SWEEPS = 60


@lru_cache(maxsize=64)
def _parsed(effects: str | tuple[str, ...]) -> tuple[str, ...]:
    """``parse_effects`` of a hashable effect list, kept (a fit builds a model per residual)."""
    return parse_effects(effects)


def _summed(strains: dict[str, FloatArray]) -> FloatArray | float:
    """The state effects' strains added in canonical order (0.0 without any)."""
    terms = list(strains.values())
    if not terms:
        return 0.0
    total = terms[0]
    for term in terms[1:]:
        total = total + term
    return total
