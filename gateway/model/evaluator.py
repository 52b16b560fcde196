"""The one evaluator of the sensor's resistance and its slope, and its breakdown into terms.

Total resistance (paper eq. 10, 13, 17, extended by the named effects)::

    R_core = T(temp) * R0 (1 - eps) exp(-gamma s0 eps) + k / sqrt(F) + R_series
    R      = R_core || R_leak
    eps    = F / (A E0(F)) + (the strains of the state-carrying effects)

with k / sqrt(F) = 2 R_con (eq. 12). The forward model (``breakdown``), the force range's ends
(``ohm_from_parts``) and the Newton solver (``log_gap_and_slope``) all evaluate it here, from
the submodels' terms; a switched-off effect contributes its neutral term and costs nothing
on the hot paths (the ``has_*`` flags skip it).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .physics import polymer_resistance_ohm
from .submodels import ParallelPath, SeriesTerm, Tunneling

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class ResistanceBreakdown:
    """Forward model output, every term of the resistance (as lmfit's ``eval_components``).

    Every array has the shape of the force input. Resistances in ohm, strains
    dimensionless. ``total_ohm = (temperature_factor * polymer' + contact + series) || leakage``
    where ``polymer_ohm`` already includes the temperature factor; ``strain`` is
    ``elastic_strain + kv1_strain + kv2_strain + hysteresis_strain``. A term of an effect
    that is off is its neutral value (0 ohm, 0 strain, +inf leakage, factor 1).
    """

    total_ohm: FloatArray
    contact_ohm: FloatArray
    polymer_ohm: FloatArray
    strain: FloatArray
    series_ohm: FloatArray
    leakage_ohm: FloatArray
    temperature_factor: FloatArray
    elastic_strain: FloatArray
    kv1_strain: FloatArray
    kv2_strain: FloatArray
    hysteresis_strain: FloatArray

    def components(self) -> dict[str, FloatArray]:
        """Every term by name, for reports and plots."""
        return {name: getattr(self, name) for name in self.__dataclass_fields__}


def parallel(a: ArrayLike, b: ArrayLike) -> FloatArray:
    """a || b for resistances where either may be +inf."""
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    with np.errstate(invalid="ignore", divide="ignore"):
        out = a * b / (a + b)
    out = np.where(np.isinf(a), b, out)
    return np.asarray(np.where(np.isinf(b), a, out))


class ResistanceEvaluator:
    """R(F) and d ln R / d ln F of N channels from the tunneling baseline and the
    resistance-shaping submodels (contact, series resistance, leakage; on or off)."""

    def __init__(
        self, tunneling: Tunneling, contact: SeriesTerm, series: SeriesTerm, leakage: ParallelPath
    ) -> None:
        self.r0_ohm = tunneling.params.r0_ohm
        self.gamma_s0 = tunneling.gamma_s0
        self.a_e0 = tunneling.a_e0
        self.a_e0_slope = tunneling.a_e0_slope
        self.contact_k = contact.coefficient
        self.series_ohm = series.coefficient
        self.leak_ohm = leakage.ohm
        self.has_leak = bool(leakage.active and np.isfinite(self.leak_ohm).any())

    # the rest is for the inversion: a fit builds an evaluator per residual and never inverts
    @cached_property
    def neg_gamma_s0(self) -> FloatArray:
        return np.asarray(-self.gamma_s0)

    @cached_property
    def has_contact(self) -> bool:
        return bool((self.contact_k > 0.0).any())

    @cached_property
    def has_series(self) -> bool:
        return bool((self.series_ohm != 0.0).any())

    @cached_property
    def open_at_rest(self) -> NDArray[np.bool_]:
        """With an open contact at rest, +inf is the model's own reading of an unloaded sensor."""
        return np.asarray((self.contact_k > 0.0) & np.isinf(self.leak_ohm))

    @cached_property
    def closed_at_rest(self) -> NDArray[np.bool_]:
        return np.asarray(~self.open_at_rest)

    def elastic_strain(self, force_n: FloatArray) -> FloatArray:
        """F / (A E0(F)) for forces >= 0."""
        return np.asarray(force_n / (self.a_e0 + self.a_e0_slope * force_n))

    def fixed_ohm(self, force_n: FloatArray) -> FloatArray:
        """The series terms that depend on the force alone: k / sqrt(F) + R_series (F > 0)."""
        return np.asarray(self.contact_k / np.sqrt(force_n) + self.series_ohm)

    def breakdown(
        self,
        force_n: FloatArray,
        state_strains: dict[str, FloatArray],
        temp_factor: ArrayLike,
        contact_root: tuple[NDArray[np.bool_], FloatArray] | None = None,
    ) -> ResistanceBreakdown:
        """Every term at forces ``force_n`` (>= 0), with the state-carrying effects' strains
        (by breakdown name) and the temperature factor. F = 0 with contact on is an open
        contact: +inf (or R_leak with leakage). ``contact_root``: (F > 0, sqrt F there) when
        the caller has them (``ForceSeries.contact_root``)."""
        f = force_n
        elastic, strain, polymer, contact, total = self._terms(
            f, state_strains, temp_factor, self.elastic_of(f), self.contact_of(f, contact_root)
        )
        shape = np.broadcast_shapes(f.shape, np.shape(total))

        def full(x: ArrayLike) -> FloatArray:
            out = np.empty(shape)
            out[...] = x
            return out

        zero = np.zeros(shape)
        return ResistanceBreakdown(
            total_ohm=full(total),
            contact_ohm=full(contact),
            polymer_ohm=full(polymer),
            strain=full(strain),
            series_ohm=full(self.series_ohm),
            leakage_ohm=full(self.leak_ohm),
            temperature_factor=full(temp_factor),
            elastic_strain=full(elastic),
            kv1_strain=full(state_strains.get("kv1_strain", zero)),
            kv2_strain=full(state_strains.get("kv2_strain", zero)),
            hysteresis_strain=full(state_strains.get("hysteresis_strain", zero)),
        )

    def forward_ohm(
        self,
        force_n: FloatArray,
        state_strains: dict[str, FloatArray],
        temp_factor: ArrayLike,
        elastic: FloatArray,
        contact: FloatArray,
    ) -> FloatArray:
        """``breakdown(...).total_ohm`` (the same numbers) without the other terms' arrays, from
        the terms that depend on the force alone: ``elastic_of(force_n)``, ``contact_of(force_n)``
        (a fit keeps them while their parameters are unchanged)."""
        total = self._terms(force_n, state_strains, temp_factor, elastic, contact)[4]
        shape = np.broadcast_shapes(force_n.shape, total.shape)
        if total.shape == shape and total.dtype == np.float64:
            return total
        out = np.empty(shape)
        out[...] = total
        return out

    def elastic_of(self, force_n: FloatArray) -> FloatArray:
        """The elastic strain F / (A E0(F)) at forces clamped at 0 N."""
        return self.elastic_strain(np.maximum(force_n, 0.0))

    def contact_of(
        self, force_n: FloatArray, contact_root: tuple[NDArray[np.bool_], FloatArray] | None = None
    ) -> FloatArray:
        """The contacts' k / sqrt(F) in ohm: +inf at F = 0 (open), 0 without contact.
        ``contact_root``: (F > 0, sqrt F there) when the caller has them."""
        positive, root = (force_n > 0.0, None) if contact_root is None else contact_root
        with np.errstate(divide="ignore"):
            if root is None:
                root = np.sqrt(np.where(positive, force_n, 1.0))
            contact = np.where(positive, self.contact_k / root, np.inf)
        return np.asarray(np.where(self.contact_k > 0.0, contact, 0.0))

    def _terms(
        self,
        f: FloatArray,
        state_strains: dict[str, FloatArray],
        temp_factor: ArrayLike,
        elastic: FloatArray,
        contact: FloatArray,
    ) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray, FloatArray]:
        """elastic strain, total strain, polymer, contact and total resistance at forces f >= 0."""
        strain = elastic
        if state_strains:
            terms = list(state_strains.values())
            state_strain = terms[0]
            for term in terms[1:]:
                state_strain = state_strain + term
            strain = elastic + state_strain
        polymer = polymer_resistance_ohm(np.asarray(temp_factor) * self.r0_ohm, strain, self.gamma_s0)
        core = polymer + contact + self.series_ohm
        total = parallel(core, self.leak_ohm) if self.has_leak else core
        return elastic, strain, polymer, contact, np.asarray(total)

    def ohm_from_parts(
        self, elastic_strain: FloatArray, fixed_ohm: FloatArray, state_strain: FloatArray, r0: FloatArray
    ) -> FloatArray:
        """R = (R0 (1 - eps) e^(-gamma s0 eps) + fixed) || R_leak, eps = the elastic strain
        plus the state's, for forces > 0 (the lean path of ``breakdown``)."""
        eps = elastic_strain + state_strain
        core = r0 * (1.0 - eps) * np.exp(self.neg_gamma_s0 * eps) + fixed_ohm
        if self.has_leak:
            return np.asarray(core * self.leak_ohm / (core + self.leak_ohm))
        return np.asarray(core)

    def total_ohm(self, force_n: FloatArray, state_strain: FloatArray, r0: FloatArray) -> FloatArray:
        """Total resistance for forces > 0."""
        return self.ohm_from_parts(self.elastic_strain(force_n), self.fixed_ohm(force_n), state_strain, r0)

    def log_gap_and_slope(
        self, u: FloatArray, target: FloatArray, state_strain: FloatArray, r0: FloatArray
    ) -> tuple[FloatArray, FloatArray]:
        """g = ln R(F) - target and dg/du at F = e^u (the Newton step of both solvers).

        With q = F / (A E0(F)) and eps = q + state strain: F dR_pol/dF =
        -R0 e^(-gamma s0 eps) (1 + gamma s0 (1 - eps)) q A E0(0) / (A E0(F)) (F deps/dF);
        F d(k / sqrt F)/dF = -k / (2 sqrt F); a parallel leakage path scales the derivative
        by (R_leak / (R_core + R_leak))^2. dg/du = F dR/dF / R.
        """
        f = np.exp(u)
        den = self.a_e0 + self.a_e0_slope * f
        q = f / den
        eps = q + state_strain
        one_m = 1.0 - eps
        ex = r0 * np.exp(self.neg_gamma_s0 * eps)
        core = ex * one_m
        f_dcore = (ex * (-1.0 - self.gamma_s0 * one_m)) * (q * self.a_e0 / den)
        if self.has_contact:
            rc = self.contact_k / np.sqrt(f)
            core += rc
            f_dcore -= 0.5 * rc
        if self.has_series:
            core += self.series_ohm
        if self.has_leak:
            share = self.leak_ohm / (core + self.leak_ohm)
            core *= share
            f_dcore *= share * share
        return np.log(core) - target, f_dcore / core
