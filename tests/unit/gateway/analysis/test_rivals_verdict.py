"""``rivals.verdict`` names the best static rival, never the line alone."""

from __future__ import annotations

import math

from gateway.analysis.rivals import verdict


def test_the_lookup_beats_the_model_which_beats_the_line_and_the_verdict_names_the_lookup() -> None:
    text = verdict(1.2, {"conductance line": 1.5, "monotone lookup": 0.9})
    assert text == (
        "THE MONOTONE LOOKUP WINS: the physical model reads force worse (1.2 N) than the monotone "
        "lookup (0.9 N), the best static rival on the same held-out rows"
    )
    assert "wins: 1.2 N" not in text and "line" not in text


def test_the_model_beating_every_rival_wins_against_the_best_of_them() -> None:
    rivals = {"conductance line": 1.5, "monotone lookup": 0.9, "power_law + static": 1.1}
    assert verdict(0.5, rivals) == (
        "the physical model wins: 0.5 N against the best static rival's (monotone lookup) 0.9 N"
    )


def test_the_tie_is_two_percent_of_the_best_rival_either_way() -> None:
    rivals = {"line": 2.0, "lookup": 1.0}
    # 1.0 x (1 - 0.02) = 0.98 wins, 0.99 and 1.02 tie, 1.03 loses
    assert verdict(0.98, rivals).startswith("the physical model wins")
    assert (
        verdict(0.99, rivals)
        == "the physical model ties with the best static rival (lookup): 0.99 N against 1 N"
    )
    assert verdict(1.02, rivals).startswith("the physical model ties")
    assert verdict(1.03, rivals).startswith("THE LOOKUP WINS")


def test_the_judged_model_is_named_and_rivals_without_a_figure_are_left_out() -> None:
    text = verdict(
        0.21, {"power_law + static": 8.6, "lookup + static": math.nan}, model_name="power_law + creep"
    )
    assert text == "power_law + creep wins: 0.21 N against the best static rival's (power_law + static) 8.6 N"
    nothing = verdict(0.21, {"lookup + static": math.nan})
    assert nothing == "the physical model and its static rivals cannot be compared on these rows"
    assert "cannot be compared" in verdict(math.nan, {"line": 1.0})


def test_a_bare_number_is_the_line_in_the_words_it_always_had() -> None:
    """The former signature ``verdict(model_rms, line_rms)`` (``Calibration.verdict``)."""
    assert verdict(1.0, 2.0) == "the physical model wins: 1 N against the line's 2 N"
    assert verdict(2.0, 2.0) == "the physical model ties with the line: 2 N against 2 N"
    assert verdict(3.0, 2.0) == (
        "THE LINE WINS: the physical model reads force worse (3 N) than the conductance line (2 N) "
        "on the same held-out rows"
    )
    assert verdict(math.nan, 2.0) == "the model and the line cannot be compared on these rows"
