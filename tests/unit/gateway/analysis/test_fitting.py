"""Fits recover known parameters within their reported intervals; limits are named."""

from __future__ import annotations

import numpy as np

from gateway.analysis.fitting import FitData, FitResult, fit_channel, record_limitations
from gateway.analysis.objectives import OFFSET
from gateway.analysis.records import ChannelRecord
from gateway.model import SensorModel, SensorParams

PAPER = ("tunneling", "contact", "creep")
TRUE = SensorParams(r0_ohm=180e3, e0_pa=16e6, rho2_ohm_m=1.2, e1_pa=170e6, mu1_pa_s=1.9e10)


def _record(
    levels: list[float],
    hold_s: float,
    seed: int,
    noise: float = 0.01,
    params: SensorParams = TRUE,
    reference_error_n: float = 0.0,
) -> FitData:
    """A simulated record; its reference force reads the true force + ``reference_error_n``
    (a load cell whose zero is off: it reads ``reference_error_n`` with nothing on it)."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, hold_s * len(levels), 0.5)
    f = np.array(levels)[np.minimum((t // hold_s).astype(int), len(levels) - 1)]
    out, _ = SensorModel(PAPER, params).simulate(f[:, None], t)
    r = out.total_ohm[:, 0] * np.exp(noise * rng.standard_normal(t.size))
    return FitData.from_channel(ChannelRecord("0", t, r, f + reference_error_n, None, np.arange(t.size)))


RICH = [0.0, 0.3, 1.0, 0.0, 2.0, 4.0, 0.5, 6.0, 0.0, 3.0, 8.0, 1.5, 0.0]


def test_full_model_recovers_parameters_within_95_percent_intervals() -> None:
    inside, total = 0, 0
    for seed in range(1, 7):
        result = fit_channel(_record(RICH, 200.0, seed), PAPER)
        assert result.fixed_reasons == {}
        for est in result.estimates:
            truth = getattr(TRUE, est.name)
            half = (est.high - est.low) / 2
            inside += est.low <= truth <= est.high
            total += 1
            # no estimate is far outside its interval
            assert abs(est.value - truth) <= 2.5 * half, (seed, est, truth)
            # and the intervals are informative, not absurdly wide
            assert est.high / est.low < 2.0, (seed, est)
        # with only 1 % noise left the held-out gap is the noise
        assert 0.008 < result.gap_test.log_resistance_rms < 0.013
        assert result.gap_test.force_rms_n < 0.1
    coverage = inside / total
    print(f"\n95 % interval coverage over 6 seeds x 8 parameters: {coverage:.2f}")
    assert coverage >= 0.85


def test_leaving_out_an_effect_leaves_a_gap() -> None:
    data = _record(RICH, 200.0, 5)
    without_creep = fit_channel(data, ("tunneling", "contact"))
    with_creep = fit_channel(data, PAPER)
    assert without_creep.gap_test.log_resistance_rms > 4 * with_creep.gap_test.log_resistance_rms
    assert without_creep.gap_test.force_rms_n > with_creep.gap_test.force_rms_n


def test_no_holds_means_creep_is_fixed_at_its_prior_with_the_reason() -> None:
    t = np.arange(0.0, 120.0, 0.1)
    f = 2.5 + 2.0 * np.sin(2 * np.pi * t / 4.0)  # fast cycling: no hold anywhere
    out, _ = SensorModel(PAPER, TRUE).simulate(f[:, None], t)
    data = FitData.from_channel(ChannelRecord("0", t, out.total_ohm[:, 0], f, None, np.arange(t.size)))
    reasons = record_limitations(data, PAPER, SensorParams())
    assert "creep cannot be fitted" in reasons["e1_pa"]
    result = fit_channel(data, PAPER)
    e1 = result.estimate("e1_pa")
    assert not e1.fitted and e1.value == SensorParams().e1_pa
    assert "creep cannot be fitted" in e1.note


def test_narrow_force_range_fixes_the_contact_coefficient() -> None:
    data = _record([2.0, 2.5, 3.0, 2.2, 2.8], 200.0, 6)
    result = fit_channel(data, PAPER)
    contact = result.estimate("rho2_ohm_m")
    assert not contact.fitted
    assert "too narrow to separate contact from tunneling" in contact.note


def _covers_truth(result: FitResult, offset_n: float) -> None:
    for est in result.estimates:
        truth = offset_n if est.name == OFFSET else getattr(TRUE, est.name)
        assert est.fitted, est
        assert est.low <= truth <= est.high, (est, truth)


def test_a_reference_zero_offset_is_fitted_with_the_right_sign_and_the_rest_still_recovered() -> None:
    # the load cell reads 0.1 N low (-0.1 N with nothing on it): the model is driven by F_ref + offset,
    # so the fitted offset is +0.1 N
    for seed in (1, 3):
        data = _record(RICH, 200.0, seed, reference_error_n=-0.1)
        result = fit_channel(data, PAPER, fit_force_offset=True)
        assert result.fixed_reasons == {}
        assert OFFSET in result.correlation_names
        offset = result.estimate(OFFSET)
        assert offset.low < 0.1 < offset.high and offset.low > 0.0, offset  # and it excludes 0
        assert abs(result.force_offset_n - 0.1) < 0.03
        _covers_truth(result, 0.1)
        # the force gap is against F_ref + offset, i.e. the true force: as small as without the error
        assert result.gap_test.force_rms_n < 0.03
        # the range the inversion uses is the prior's in corrected terms
        assert result.params.force_max_n == SensorParams().force_max_n + result.force_offset_n


def test_without_a_reference_error_the_fitted_offset_covers_zero() -> None:
    for seed in (1, 3):
        result = fit_channel(_record(RICH, 200.0, seed), PAPER, fit_force_offset=True)
        offset = result.estimate(OFFSET)
        assert offset.fitted and offset.low < 0.0 < offset.high, offset
        assert offset.high - offset.low < 0.3  # informative: +-0.15 N at most
        _covers_truth(result, 0.0)


def test_the_force_objective_recovers_the_parameters_of_a_noiseless_record() -> None:
    data = _record(RICH, 200.0, 1, noise=0.0)
    result = fit_channel(data, PAPER, objective="force")
    assert result.objective == "force" and result.fixed_reasons == {}
    for est in result.estimates:
        assert abs(est.value / getattr(TRUE, est.name) - 1) < 1e-4, est
    assert result.gap_test.force_rms_n < 1e-4


def test_the_force_objective_reads_force_no_worse_than_the_log_r_one_on_a_noisy_record() -> None:
    data = _record(RICH, 200.0, 2)
    log_r, force = fit_channel(data, PAPER), fit_channel(data, PAPER, objective="force")
    assert force.gap_train.force_rms_n <= log_r.gap_train.force_rms_n * 1.02
    assert force.gap_test.force_rms_n < 0.03
    try:
        fit_channel(data, PAPER, objective="newtons")
    except ValueError as exc:
        assert "objective must be one of log_r, force" in str(exc)
    else:
        raise AssertionError("an unknown objective was accepted")
