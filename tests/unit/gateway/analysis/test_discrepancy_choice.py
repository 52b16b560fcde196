"""Model choice on both gaps: near ties add the better candidate; a candidate that reads the
tracked held-out force worse is never added, on any route."""

from __future__ import annotations

import math
from dataclasses import replace

from test_discrepancy import NOISE, world_channel  # same directory (rootdir-relative import mode)

from gateway.analysis.diagnostics import Finding
from gateway.analysis.discrepancy import CandidateScore, _decide, _penalized
from gateway.analysis.discrepancy_choice import (
    TRACKED_FORCE_SLACK,
    known_state_force_rms,
    refusal,
    tracked_force_not_worse,
)
from gateway.analysis.fitting import FitData, fit_channel


def test_a_near_tie_adds_the_better_candidate_names_the_runner_up_and_reaches_the_noise() -> None:
    data = FitData.from_channel(world_channel((), 2))
    base = fit_channel(data, ("tunneling", "creep"))
    contact = fit_channel(data, ("tunneling", "contact", "creep"))
    series = fit_channel(data, ("tunneling", "creep", "series_resistance"))
    now = _penalized(base, data)
    best_score = _penalized(contact, data)
    # the runner-up gains 95 % of the best's score gain: the two cannot be told apart by score
    tie_score = now - 0.95 * (now - best_score)
    scored = [
        CandidateScore("contact", 1, contact.gap_test, best_score, contact),
        CandidateScore("series_resistance", 1, series.gap_test, tie_score, series),
    ]
    # the runner-up's held-out RMS as close as the score says (a near tie on log-R too)
    near = replace(contact.gap_test, log_resistance_rms=contact.gap_test.log_resistance_rms * 1.02)
    scored[1] = replace(scored[1], gap_test=near)
    added, evidence, runner_up = _decide(base, data, scored, ())
    assert added == "contact" and runner_up == "series_resistance", evidence
    assert "series_resistance fits nearly as well" in evidence
    # the record spans 0.2-8 N already, so the separating measurement is not asked for
    assert "to separate them" not in evidence
    assert contact.gap_test.log_resistance_rms <= 1.5 * NOISE
    assert base.gap_test.log_resistance_rms > 1.3 * contact.gap_test.log_resistance_rms


def test_a_candidate_that_makes_the_force_worse_is_not_added() -> None:
    data = FitData.from_channel(world_channel((), 2))
    base = fit_channel(data, ("tunneling", "creep"))
    contact = fit_channel(data, ("tunneling", "contact", "creep"))
    worse = replace(contact.gap_test, force_rms_n=base.gap_test.force_rms_n * 1.5)
    # worse with the tracked state and with the state the reference force drives
    known_worse = known_state_force_rms(data, base) * 1.5
    scored = [CandidateScore("contact", 1, worse, _penalized(contact, data), contact, known_worse)]
    added, evidence, _ = _decide(base, data, scored, ())
    assert added is None
    before, after = base.gap_test.force_rms_n, worse.force_rms_n
    assert f"contact refused: tracked held-out force {before:.4g} -> {after:.4g} N" in evidence


def test_a_candidate_worse_only_with_the_tracked_state_is_refused_too() -> None:
    """Before: near an ADC rail the tracked state (hysteresis direction) moves on read-out noise,
    and a candidate worse only with the tracked state was added because, with the state the
    reference force drives, it improved. The runtime reads with the tracked state, so such a
    candidate now is refused on the log-R route as on the force route."""
    data = FitData.from_channel(world_channel((), 2))
    base = fit_channel(data, ("tunneling", "creep"))
    contact = fit_channel(data, ("tunneling", "contact", "creep"))
    worse = replace(contact.gap_test, force_rms_n=base.gap_test.force_rms_n * 1.5)
    known = known_state_force_rms(data, contact)
    assert known < known_state_force_rms(data, base)
    # it wins clearly on log-R (route 1) ...
    assert _penalized(contact, data) < _penalized(base, data) - 30.0
    scored = [CandidateScore("contact", 1, worse, _penalized(contact, data), contact, known)]
    added, evidence, _ = _decide(base, data, scored, ())
    assert added is None, evidence
    assert "contact refused: tracked held-out force" in evidence


def test_the_rule_allows_floating_point_slack_only() -> None:
    """``candidate <= now * (1 + 1e-9)``: equal (or worse by rounding) passes, one part in a
    million worse does not; a candidate whose tracked force cannot be computed is refused."""
    assert TRACKED_FORCE_SLACK <= 1e-9
    assert tracked_force_not_worse(1.0, 1.0)
    assert tracked_force_not_worse(1.0 + 1e-12, 1.0)
    assert tracked_force_not_worse(0.5, 1.0)
    assert not tracked_force_not_worse(1.0 + 1e-6, 1.0)
    assert not tracked_force_not_worse(math.nan, 1.0)
    assert tracked_force_not_worse(1.0, math.nan)
    assert not tracked_force_not_worse(0.0 + 1e-15, 0.0)


def test_a_clear_log_r_win_one_part_in_a_million_worse_on_tracked_force_is_refused() -> None:
    data = FitData.from_channel(world_channel((), 2))
    base = fit_channel(data, ("tunneling", "creep"))
    contact = fit_channel(data, ("tunneling", "contact", "creep"))
    now = base.gap_test.force_rms_n
    hair = replace(contact.gap_test, force_rms_n=now * (1.0 + 1e-6))
    candidate = CandidateScore("contact", 1, hair, _penalized(contact, data), contact)
    added, evidence, _ = _decide(base, data, [candidate], ())
    assert added is None
    why = refusal(candidate, now)
    # the numbers are printed with as many digits as it takes to tell them apart
    assert why is not None and why in evidence
    before, after = why.removeprefix("refused: tracked held-out force ").removesuffix(" N").split(" -> ")
    assert before != after
    equal = replace(candidate, gap_test=replace(contact.gap_test, force_rms_n=now))
    added, evidence, _ = _decide(base, data, [equal], ())
    assert added == "contact", evidence


def test_the_force_route_needs_a_finding_on_the_effects_axis() -> None:
    """A candidate that does not win clearly on log-R is added on a clear force gain only when
    the diagnostics found a disagreement on its own axis (hysteresis: the load direction)."""
    data = FitData.from_channel(world_channel(("hysteresis",), 1))
    base = fit_channel(data, ("tunneling", "contact", "creep"))
    with_h = fit_channel(data, ("tunneling", "contact", "creep", "hysteresis"))
    now = _penalized(base, data)
    # a log-R gain too small for route 1, a clear force gain
    weak = CandidateScore("hysteresis", 2, with_h.gap_test, now - 5.0, with_h)
    assert with_h.gap_test.force_rms_n < 0.97 * base.gap_test.force_rms_n
    direction = Finding(
        "direction", "unloading", -0.03, 500, "while unloading the measured resistance is 3 % below"
    )
    temperature = Finding(
        "temperature", "above 27 °C", -0.02, 500, "above 27 °C the measured resistance is 2 % below"
    )
    added, evidence, _ = _decide(base, data, [weak], (direction,))
    assert added == "hysteresis" and "added on the force" in evidence, evidence
    added, evidence, _ = _decide(base, data, [weak], (temperature,))
    assert added is None, evidence
    # the force route obeys the tracked-force rule too: a candidate that reads force better
    # with the state the reference force drives but worse with the tracked state is refused
    tracked_worse = replace(
        weak, gap_test=replace(with_h.gap_test, force_rms_n=base.gap_test.force_rms_n * 1.1)
    )
    tracked_worse = replace(tracked_worse, known_force_n=0.5 * known_state_force_rms(data, base))
    added, evidence, _ = _decide(base, data, [tracked_worse], (direction,))
    assert added is None and "hysteresis refused: tracked held-out force" in evidence, evidence
