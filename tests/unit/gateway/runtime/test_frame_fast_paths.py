"""The frame's and the static estimate's fast paths equal their plain definitions.

``Frame.of`` rounds the three per-channel arrays in one pass and maps statuses through a
table; ``StaticEstimate.evaluate`` inverts one in-order group without gathering and hands
the guess to the inversion's own clipping. Both are checked here value for value against
definitions written out in the test: ``round(x, 6)`` or None per element, ``ChannelStatus(s)``
per status, and a per-channel inversion with the guess cleaned as before, whose forces the
forward model maps back onto the measured resistances.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from gateway.model import SensorModel, SensorParams
from gateway.runtime.frame import Frame
from gateway.runtime.snapshot import ChannelStatus, DeviceSnapshot, StaticEstimate

ANY_FLOAT = st.floats(allow_nan=True, allow_infinity=True, width=64) | st.sampled_from(
    [0.0, -0.0, 0.0000005, 2.675, -1e-7, 1e300, 4.5e9 + 0.0000005]
)


def _plain(values: list[float]) -> tuple[float | None, ...]:
    return tuple(round(v, 6) if math.isfinite(v) else None for v in values)


def _same(got: tuple[float | None, ...], want: tuple[float | None, ...]) -> bool:
    """None for None, equal values and the sign of a zero kept."""
    return len(got) == len(want) and all(
        (g is None and w is None)
        or (g is not None and w is not None and g == w and math.copysign(1.0, g) == math.copysign(1.0, w))
        for g, w in zip(got, want, strict=True)
    )


class GivenStatic:
    """A stand-in estimate whose static forces are given (the frame only reads them)."""

    def __init__(self, force_n: np.ndarray) -> None:
        self.force_n = force_n

    def evaluate(self) -> np.ndarray:
        return self.force_n


def _snapshot(
    force: list[float], static: list[float], resistance: list[float], status: list[int]
) -> DeviceSnapshot:
    n = len(force)
    return DeviceSnapshot(
        device="arr",
        bus="b",
        channel_index=np.arange(n, dtype=np.int64),
        channel_names=tuple(f"c{i}" for i in range(n)),
        x_mm=np.zeros(n),
        y_mm=np.zeros(n),
        resistance_ohm=np.array(resistance, dtype=np.float64),
        force_n=np.array(force, dtype=np.float64),
        static_estimate=GivenStatic(np.array(static, dtype=np.float64)),  # type: ignore[arg-type]
        reference_force_n=np.full(n, math.nan),
        status=np.array(status, dtype=np.int8),
        up=True,
        timestamp_s=1_700_000_000.1234567,
        last_success_timestamp_s=None,
        device_time_s=math.nan,
        poll_interval_s=0.05,
    )


@settings(max_examples=300)
@given(st.data(), st.integers(1, 70))
def test_the_frame_rounds_every_channel_as_round_does(data: st.DataObject, n: int) -> None:
    floats = st.lists(ANY_FLOAT, min_size=n, max_size=n)
    force, static, resistance = data.draw(floats), data.draw(floats), data.draw(floats)
    status = data.draw(st.lists(st.sampled_from([int(s) for s in ChannelStatus]), min_size=n, max_size=n))
    frame = Frame.of(_snapshot(force, static, resistance, status))
    assert _same(frame.force_n, _plain(force))
    assert _same(frame.force_static_n, _plain(static))
    assert _same(frame.resistance_ohm, _plain(resistance))
    assert frame.status == tuple(ChannelStatus(s) for s in status)
    assert all(type(s) is ChannelStatus for s in frame.status)
    assert frame.channel_names == tuple(f"c{i}" for i in range(n))


MODEL = SensorModel("tunneling,contact,creep", [SensorParams()] * 8)
FORCES = st.floats(0.06, 9.9)  # inside the default force range, 0.05..10 N


def _model(n: int) -> SensorModel:
    return SensorModel("tunneling,contact,creep", [SensorParams()] * n)


def _reference_static(est: StaticEstimate) -> np.ndarray:
    """The previous definition: channel groups gathered, the guess cleaned to 0 N where it is
    not finite and clipped at 0 N below."""
    out = np.full(len(est.resistance_ohm), np.nan)
    guess = np.where(np.isfinite(est.guess_n), np.maximum(est.guess_n, 0.0), 0.0)
    for idx, model in est.groups:
        with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
            out[idx] = model.invert(est.resistance_ohm[idx], None, None, guess_n=guess[idx]).force_n
    return np.where(est.valued & np.isfinite(out), out, np.nan)


@settings(max_examples=200)
@given(
    st.lists(FORCES, min_size=8, max_size=8),
    st.lists(st.floats(allow_nan=True, allow_infinity=True) | FORCES, min_size=8, max_size=8),
    st.lists(st.booleans(), min_size=8, max_size=8),
    st.sampled_from(["whole", "reversed", "two"]),
)
def test_the_static_estimate_equals_its_plain_definition(
    force_n: list[float], guess_n: list[float], valued: list[bool], grouping: str
) -> None:
    r = MODEL.resistance(np.array(force_n))
    r[0], r[1] = math.nan, -5.0  # invalid readings stay NaN
    idx = np.arange(8, dtype=np.intp)
    parts = {"whole": [idx], "reversed": [idx[::-1].copy()], "two": [idx[:3], idx[3:]]}[grouping]
    # a model per group: the same parameters for every channel, so MODEL checks every force
    groups = tuple((i, MODEL if len(i) == 8 else _model(len(i))) for i in parts)
    est = StaticEstimate(groups, r, None, np.array(valued), np.array(guess_n))
    got = est.evaluate()
    want = _reference_static(est)
    assert np.array_equal(got, want, equal_nan=True)
    ok = np.array(valued) & np.isfinite(got)
    assert not ok[:2].any()
    # the forward model gives back the measured resistance (Newton stops at steps of 1e-5 in
    # ln F, leaving ~1e-10; 1e-8 relative is far above that and far below a 6th decimal)
    back = MODEL.resistance(np.where(ok, got, 1.0))
    assert np.allclose(back[ok], r[ok], rtol=1e-8, atol=0.0)


def test_a_copy_of_a_frame_snapshot_rounds_alike() -> None:
    snap = _snapshot([1.2500004, -0.0], [math.inf, 2.675], [800.0, math.nan], [0, 1])
    frame = Frame.of(dataclasses.replace(snap))
    assert frame.force_n == (1.25, -0.0) and frame.force_static_n == (None, 2.675)
    assert frame.resistance_ohm == (800.0, None)
