"""Fits the rows cannot determine are handled, not left to numpy's RankWarning on stderr (it
printed once per channel of a calibrate)."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from gateway.analysis.candidates import fit_curve
from gateway.analysis.measurement import estimate_rel_noise


def test_the_noise_of_a_record_held_at_two_forces_is_estimated_without_a_warning() -> None:
    # a cubic in ln F through two distinct forces is rank-deficient
    f = np.repeat([1.0, 2.0], 20)
    r = 1e4 / f * (1.0 + 0.01 * np.random.default_rng(1).standard_normal(f.size))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        rel = estimate_rel_noise(f, r, np.zeros(f.size))
    assert 0.001 < rel < 0.05


def test_a_line_through_a_conductance_that_never_changes_is_refused_without_a_warning() -> None:
    f = np.linspace(0.5, 3.0, 20)
    r = np.full(f.size, 1e4)  # stuck at one value whatever the force
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(ValueError, match="does not change with force"):
            fit_curve("line", f, r)
