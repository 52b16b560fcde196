"""Whether a record starts with its sensor loaded (``gateway.analysis.load_history``)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from gateway.analysis.load_history import START_ROWS, channel_start_load, start_load, start_threshold_n
from gateway.analysis.records import parse_record


def test_a_record_starting_at_10_n_says_it_starts_loaded_at_10_n_and_for_how_long() -> None:
    # 10 N held for 30 s (rows every 0.5 s), a ramp down to 0 N, then 20 N
    t = np.arange(0.0, 120.0, 0.5)
    f = np.interp(t, [0.0, 30.0, 40.0, 80.0, 90.0, 120.0], [10.0, 10.0, 0.0, 0.0, 20.0, 20.0])
    r = np.where(f > 0, 1e4 / np.maximum(f, 1e-9), np.inf)
    s = start_load(t, r, f)
    assert s.loaded and s.source == "reference"
    assert s.force_n == 10.0 and s.n_rows == START_ROWS
    # threshold: max(2 % of 20 N, max(0.05 N, 1 % of 20 N)) = 0.4 N
    assert s.threshold_n == pytest.approx(0.4)
    # the ramp leaves 10 N by more than 0.4 N after 30 + 0.4 x 10 / 10 = 30.4 s: first row at 30.5 s
    assert s.held_s == pytest.approx(30.5)
    words = s.sentence()
    assert words.startswith("the record starts loaded at 10 N")
    assert "held for 30.5 s" in words and "load history before the record is unknown" in words
    assert s.as_json()["loaded"] is True and s.as_json()["force_n"] == 10.0


def test_a_record_starting_at_rest_with_load_cell_noise_starts_at_rest() -> None:
    text = "time_s,resistance_ohm,force_n\n" + "".join(
        f"{k},inf,{-0.0002 if k % 2 else 0.0001}\n" for k in range(6)
    )
    text += "6,5000,3\n7,5000,3\n"
    ch = parse_record(text).channel()
    s = channel_start_load(ch)
    assert not s.loaded
    # rows 0-4 read 1e-4, 0 (-0.0002 read as 0 N), 1e-4, 0, 1e-4: the median is 1e-4 N
    assert ch.zero_noise_rows == 3 and s.force_n == 0.0001
    # threshold: max(2 % of 3 N, 0.05 N) = 0.06 N
    assert "starts at rest" in s.sentence() and "threshold of 0.06 N" in s.sentence()


def test_a_light_start_within_the_threshold_is_at_rest_and_above_it_is_loaded() -> None:
    t = np.arange(20.0)
    f = np.full(20, 0.3)
    f[10:] = 20.0  # full scale 20 N: threshold 0.4 N
    r = 1e4 / f
    assert start_threshold_n(f) == pytest.approx(0.4)
    assert not start_load(t, r, f).loaded
    f[:10] = 0.5
    assert start_load(t, r, f).loaded


def test_without_a_reference_a_start_far_below_the_unloaded_resistance_is_loaded() -> None:
    t = np.arange(40.0)
    r = np.full(40, np.inf)
    r[:8] = 2e3  # loaded at the start, open afterwards
    s = start_load(t, r)
    assert s.loaded and s.source == "resistance" and math.isnan(s.force_n)
    assert "starts loaded (load unknown)" in s.sentence() and "open circuit" in s.sentence()
    # with a calibration, at what load: F = 2e4 / R
    with_cal = start_load(t, r, force_of=lambda ohm: 2e4 / ohm)
    assert with_cal.force_n == pytest.approx(10.0)
    assert "starts loaded at about 10 N" in with_cal.sentence()


def test_without_a_reference_a_start_near_the_unloaded_level_is_not_loaded() -> None:
    t = np.arange(40.0)
    r = np.full(40, 1e6)  # a leakage path caps the unloaded resistance at 1 Mohm
    r[20:30] = 5e3
    r[:5] = 2e5  # 5 x below 1 Mohm: not the 10 x of a clear load
    s = start_load(t, r)
    assert not s.loaded and s.unloaded_ohm == 1e6
    assert "near its unloaded level" in s.sentence()
    r[:5] = 9e4  # 11 x below
    assert start_load(t, r).loaded


def test_an_empty_series_has_no_start() -> None:
    with pytest.raises(ValueError, match="no start"):
        start_load(np.zeros(0), np.zeros(0))
