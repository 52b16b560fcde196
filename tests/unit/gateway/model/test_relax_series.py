"""``physics.relax_series`` (the Kelvin recurrence over a series) against a plain Python loop
of x[k] = T[k] + (x[k-1] - T[k]) exp(-dt[k] / tau), hand-computed closed forms, its limits,
and a count of the numpy work it does (one pass, however fast the decay)."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from gateway.model import physics
from gateway.model.physics import MIN_LOG_DECAY, relax_series


def _loop(dt_s: np.ndarray, tau_s: float, target: np.ndarray, x0: float) -> np.ndarray:
    """The recurrence row by row in Python floats, with the documented clamp of log a."""
    x = float(x0)
    out = []
    for dt, t in zip(dt_s.tolist(), target.tolist(), strict=True):
        a = math.exp(max(-dt / tau_s, MIN_LOG_DECAY))
        x = t + (x - t) * a
        out.append(x)
    return np.array(out)


def _irregular_dt_s(rows: int, seed: int) -> np.ndarray:
    """Spacing around 0.02 s with jitter, repeated timestamps (dt = 0) and a few 1 s gaps."""
    rng = np.random.default_rng(seed)
    dt = np.abs(rng.normal(0.02, 0.006, rows))
    dt[rng.random(rows) < 0.03] = 0.0
    dt[rng.random(rows) < 0.002] = 1.0
    return dt


def _positive_target(rows: int, channels: int, seed: int) -> np.ndarray:
    """A loading-like target: slow ramps plus steps, kept between 0.1 and 6 (x stays positive,
    so the comparison can be relative, element by element)."""
    rng = np.random.default_rng(seed)
    ramp = 3.0 + 2.5 * np.sin(np.arange(rows)[:, None] / rng.uniform(50, 3000, channels))
    steps = rng.choice([0.0, 0.4], size=(rows, channels), p=[0.9, 0.1])
    return np.asarray(ramp + steps)


@pytest.mark.parametrize("tau_s", [0.001, 0.05, 0.3, 1.0, 30.0, 1000.0])
def test_one_channel_equals_the_loop_at_fast_and_slow_creep(tau_s: float) -> None:
    dt = _irregular_dt_s(20_000, seed=1)
    target = _positive_target(dt.size, 1, seed=2)[:, 0]
    x, last = relax_series(-dt / tau_s, target, np.asarray(1.7))
    expected = _loop(dt, tau_s, target, 1.7)
    np.testing.assert_allclose(x, expected, rtol=1e-12, atol=0.0)
    assert x.shape == (dt.size,) and last.shape == ()
    assert float(last) == x[-1]


def test_channels_each_equal_their_own_loop() -> None:
    dt = _irregular_dt_s(12_000, seed=3)
    tau_s = np.array([0.02, 0.05, 0.3, 0.9, 7.0, 400.0])
    target = _positive_target(dt.size, tau_s.size, seed=4)
    x0 = np.array([0.0, 1.0, 2.0, 3.0, 4.0, 5.0])
    x, last = relax_series(-dt[:, None] / tau_s, target, x0)
    assert x.shape == target.shape and last.shape == (tau_s.size,)
    for ch in range(tau_s.size):
        expected = _loop(dt, float(tau_s[ch]), target[:, ch], float(x0[ch]))
        np.testing.assert_allclose(x[:, ch], expected, rtol=1e-12, atol=0.0, err_msg=f"channel {ch}")
    np.testing.assert_array_equal(last, x[-1])


@pytest.mark.parametrize("tau_s", [0.01, 0.4])
def test_one_log_decay_column_broadcasts_over_channels(tau_s: float) -> None:
    dt = _irregular_dt_s(3000, seed=5)
    target = _positive_target(dt.size, 3, seed=6)
    x, _ = relax_series((-dt / tau_s)[:, None], target, np.array([1.0, 2.0, 3.0]))
    assert x.shape == (dt.size, 3)
    for ch in range(3):
        np.testing.assert_allclose(x[:, ch], _loop(dt, tau_s, target[:, ch], ch + 1.0), rtol=1e-12)


def test_constant_step_is_the_geometric_closed_form() -> None:
    # a = exp(-dt / tau) each row: x[k] = T + (x0 - T) a^(k+1)
    dt, tau_s, t, x0 = 0.02, 0.07, 2.5, -1.0
    k = np.arange(5000)
    x, _ = relax_series(np.full(k.size, -dt / tau_s), np.full(k.size, t), np.asarray(x0))
    a = math.exp(-dt / tau_s)
    expected = t + (x0 - t) * a ** (k + 1.0)
    np.testing.assert_allclose(x, expected, rtol=1e-12)


def test_rows_without_time_keep_the_previous_value_exactly() -> None:
    dt = _irregular_dt_s(5000, seed=7)
    dt[100:140] = 0.0
    target = _positive_target(dt.size, 2, seed=8)
    x, _ = relax_series(-dt[:, None] / np.array([0.05, 50.0]), target, np.array([1.0, 1.0]))
    still = np.flatnonzero(dt == 0.0)
    still = still[still > 0]
    np.testing.assert_allclose(x[still], x[still - 1], rtol=4e-16, atol=0.0)


def test_infinite_time_constant_keeps_x0() -> None:
    target = _positive_target(4000, 2, seed=9)
    x, last = relax_series(np.zeros((4000, 1)), target, np.array([0.25, -3.0]))
    assert np.all(x == np.array([0.25, -3.0])) and np.all(last == np.array([0.25, -3.0]))
    x, _ = relax_series(-_irregular_dt_s(4000, seed=9) / 1e30, target[:, 0], np.asarray(0.25))
    np.testing.assert_allclose(x, 0.25, rtol=1e-15)


def test_vanishing_time_constant_follows_the_target_within_the_clamp() -> None:
    # log a = -dt / 1e-30 is clamped to MIN_LOG_DECAY: x[k] = T[k] + (x[k-1] - T[k]) e^-36
    dt = _irregular_dt_s(3000, seed=10) + 0.001
    target = _positive_target(dt.size, 1, seed=11)[:, 0]
    x, _ = relax_series(-dt / 1e-30, target, np.asarray(1e6))
    assert x[0] == pytest.approx(target[0] + (1e6 - target[0]) * math.exp(-36.0), rel=1e-15)
    previous = np.concatenate([[1e6], x[:-1]])
    bound = math.exp(-36.0) * np.abs(previous - target) + 4 * np.spacing(target)
    assert np.all(np.abs(x - target) <= bound)


def test_clamp_bounds_a_single_huge_decay() -> None:
    x, _ = relax_series(np.array([-1e9, -np.inf]), np.array([1.0, 2.0]), np.asarray(5.0))
    first = 1.0 + 4.0 * math.exp(-36.0)
    assert x[0] == pytest.approx(first, rel=1e-15)
    assert x[1] == pytest.approx(2.0 + (first - 2.0) * math.exp(-36.0), rel=1e-15)


def test_empty_series_returns_x0() -> None:
    x, last = relax_series(np.zeros((0, 3)), np.zeros((0, 3)), np.array([1.0, 2.0, 3.0]))
    assert x.shape == (0, 3)
    np.testing.assert_array_equal(last, [1.0, 2.0, 3.0])


def test_a_nan_row_spoils_only_its_channel_from_that_row_on() -> None:
    dt = _irregular_dt_s(2000, seed=12)
    log_a = np.stack([-dt / 0.01, -dt / 0.01], axis=1)
    log_a[700, 0] = np.nan
    x, _ = relax_series(log_a, np.ones_like(log_a), np.zeros(2))
    assert np.isfinite(x[:700, 0]).all() and np.isnan(x[700:, 0]).all()
    np.testing.assert_allclose(x[:, 1], _loop(dt, 0.01, np.ones(dt.size), 0.0), rtol=1e-12)


class _CountingNumpy:
    """Stands in for ``numpy`` inside ``physics``: counts the numpy calls made and the
    elements of the largest array each one is handed."""

    def __init__(self) -> None:
        self.calls = 0
        self.elements = 0

    def _count(self, fn: Any) -> Any:
        def counted(*args: Any, **kwargs: Any) -> Any:
            self.calls += 1
            sizes = [a.size for a in (*args, *kwargs.values()) if isinstance(a, np.ndarray)]
            self.elements += max(sizes, default=0)
            return fn(*args, **kwargs)

        return counted

    def __getattr__(self, name: str) -> Any:
        attr = getattr(np, name)
        if isinstance(attr, np.ufunc):
            return _CountingUfunc(self, attr)
        if callable(attr) and not isinstance(attr, type):
            return self._count(attr)
        return attr


class _CountingUfunc:
    def __init__(self, owner: _CountingNumpy, ufunc: np.ufunc) -> None:
        self._owner = owner
        self._ufunc = ufunc

    def __call__(self, *args: Any, **kwargs: Any) -> Any:
        return self._owner._count(self._ufunc)(*args, **kwargs)

    def __getattr__(self, name: str) -> Any:
        return self._owner._count(getattr(self._ufunc, name))


def _work(monkeypatch: pytest.MonkeyPatch, log_a: np.ndarray, target: np.ndarray) -> _CountingNumpy:
    counter = _CountingNumpy()
    with monkeypatch.context() as m:
        m.setattr(physics, "np", counter)
        relax_series(log_a, target, np.zeros(log_a.shape[1:]))
    return counter


@pytest.mark.parametrize("channels", [None, 8])
def test_fast_creep_over_a_long_series_costs_what_slow_creep_does(
    monkeypatch: pytest.MonkeyPatch, channels: int | None
) -> None:
    # 1e5 rows decay ~40,000 e-folds at tau = 0.05 s and 3.6e6 at 1e-4 s (36 a row, the clamp):
    # a scaled sum cut every 600 e-folds needs ~70 and ~6,000 chunks; one pass touches each row
    # a fixed number of times whatever tau.
    dt = _irregular_dt_s(100_000, seed=13)
    shape = (dt.size,) if channels is None else (dt.size, channels)
    log_dt = dt if channels is None else np.repeat(dt[:, None], channels, axis=1)
    target = np.ones(shape)
    rows_x_channels = float(np.prod(shape))
    slow = _work(monkeypatch, -log_dt / 1000.0, target)
    for tau_s in (0.05, 1e-4):
        fast = _work(monkeypatch, -log_dt / tau_s, target)
        assert fast.calls <= 2 * slow.calls + 20, (tau_s, fast.calls, slow.calls)
        assert fast.elements <= 1.5 * slow.elements, (tau_s, fast.elements, slow.elements)
        assert fast.elements <= 30 * rows_x_channels, (tau_s, fast.elements / rows_x_channels)
    x, _ = relax_series(-dt / 0.05, np.ones(dt.size) * 2.0, np.asarray(0.0))
    np.testing.assert_allclose(x, _loop(dt, 0.05, np.full(dt.size, 2.0), 0.0), rtol=1e-12)


_dts = st.lists(
    st.one_of(st.just(0.0), st.floats(0.0, 0.1), st.floats(0.015, 0.025)), min_size=1, max_size=300
)


@given(
    dt=_dts,
    log10_tau=st.floats(-4.0, 4.0),
    seed=st.integers(0, 2**32 - 1),
    x0=st.floats(-10.0, 10.0),
)
def test_random_series_equal_the_loop(dt: list[float], log10_tau: float, seed: int, x0: float) -> None:
    dt_s = np.array(dt)
    tau_s = 10.0**log10_tau
    target = np.random.default_rng(seed).uniform(-10.0, 10.0, dt_s.size)
    x, last = relax_series(-dt_s / tau_s, target, np.asarray(x0))
    expected = _loop(dt_s, tau_s, target, x0)
    np.testing.assert_allclose(x, expected, rtol=1e-12, atol=1e-12 * 10.0)
    assert float(last) == x[-1]


@given(dt=_dts, log10_tau=st.floats(-4.0, 4.0), seed=st.integers(0, 2**32 - 1), split=st.floats(0, 1))
def test_a_series_solved_in_two_parts_equals_it_solved_whole(
    dt: list[float], log10_tau: float, seed: int, split: float
) -> None:
    log_a = -np.array(dt)[:, None] / (10.0**log10_tau * np.array([1.0, 3.0]))
    target = np.random.default_rng(seed).uniform(0.0, 5.0, log_a.shape)
    cut = int(split * log_a.shape[0])
    whole, _ = relax_series(log_a, target, np.array([1.0, 4.0]))
    head, mid = relax_series(log_a[:cut], target[:cut], np.array([1.0, 4.0]))
    tail, _ = relax_series(log_a[cut:], target[cut:], mid)
    np.testing.assert_allclose(np.concatenate([head, tail]), whole, rtol=1e-12, atol=1e-12 * 5.0)
