"""The one typed Frame of a snapshot against numbers: a hand-built two-channel snapshot (one
NaN force, one stale channel) -> the Frame's fields, the MQTT JSON and the page's JSON,
literally; the one NaN policy; and the snapshot's lazy values computed exactly once however
many threads ask at once (a wrapped model counts its inversions; no sleeps)."""

from __future__ import annotations

import dataclasses
import json
import math
import sys
import threading
from collections.abc import Callable, Iterator
from types import MappingProxyType, SimpleNamespace
from typing import Any, cast

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from numpy.typing import ArrayLike

from gateway.model import SensorModel, SensorParams
from gateway.mqtt.payload import encode_binary, encode_json, frame_dict
from gateway.runtime.counters import DeviceCounters
from gateway.runtime.frame import Frame, frame_of
from gateway.runtime.snapshot import ChannelStatus, DeviceSnapshot, StaticEstimate, finite_or_none
from gateway.web.frames import encode_frame, frame_json


class ReciprocalModel:
    """A stand-in model whose static inversion is F = 1000 ohm N / R (counted)."""

    def __init__(self) -> None:
        self.calls = 0

    def has(self, effect: str) -> bool:
        return False

    def invert(
        self, resistance_ohm: ArrayLike, state: object, temperature_c: object, guess_n: ArrayLike
    ) -> SimpleNamespace:
        self.calls += 1
        return SimpleNamespace(force_n=1000.0 / np.asarray(resistance_ohm, dtype=np.float64))


def two_channels(model: object | None = None) -> DeviceSnapshot:
    """Channel a1 ok at 1.2500004 N (800 ohm); channel b2 stale, force NaN (1234.56789149 ohm)."""
    resistance = np.array([800.0, 1234.56789149])
    force = np.array([1.2500004, math.nan])
    valued = np.array([True, False])
    static = StaticEstimate(
        groups=((np.array([0, 1], dtype=np.intp), cast(SensorModel, model or ReciprocalModel())),),
        resistance_ohm=resistance,
        temperature_c=None,
        valued=valued,
        guess_n=force,
    )
    return DeviceSnapshot(
        device="arr",
        bus="rtu0",
        channel_index=np.array([0, 3], dtype=np.int64),
        channel_names=("a1", "b2"),
        x_mm=np.array([0.0, 2.5]),
        y_mm=np.array([0.0, 5.0]),
        resistance_ohm=resistance,
        force_n=force,
        static_estimate=static,
        reference_force_n=np.full(2, math.nan),
        status=np.array([ChannelStatus.OK, ChannelStatus.STALE], dtype=np.int8),
        up=True,
        timestamp_s=1_700_000_000.1234567,
        last_success_timestamp_s=1_699_999_999.5,
        device_time_s=12.5,
        poll_interval_s=0.05,
        total_force_n=1.2500004,
        center_of_pressure_mm=(0.0, 0.0),
        channels_in_contact=1,
        contact_area_mm2=6.25,
        peak_channel="a1",
        peak_force_n=1.2500004,
    )


def test_the_frame_of_a_hand_built_snapshot_field_by_field() -> None:
    assert frame_of(two_channels()) == Frame(
        device="arr",
        up=True,
        error=None,
        host_time_s=1_700_000_000.123457,
        device_time_s=12.5,
        last_success_time_s=1_699_999_999.5,
        poll_interval_s=0.05,
        channel_names=("a1", "b2"),
        force_n=(1.25, None),
        force_static_n=(1.25, None),  # 1000 / 800; the stale channel carries no force
        resistance_ohm=(800.0, 1234.567891),
        status=(ChannelStatus.OK, ChannelStatus.STALE),
        total_force_n=1.25,
        center_of_pressure_mm=(0.0, 0.0),
        contact_area_mm2=6.25,
        channels_in_contact=1,
        peak_channel="a1",
        peak_force_n=1.25,
    )


def test_the_mqtt_json_of_the_frame_byte_for_byte() -> None:
    assert encode_json(frame_dict(two_channels(), 7)) == (
        b'{"sequence":7,"device":"arr","host_time_s":1700000000.123457,"device_time_s":12.5,'
        b'"up":true,"total_force_n":1.25,"center_of_pressure_mm":[0.0,0.0],"contact_area_mm2":6.25,'
        b'"channels_in_contact":1,"channels":["a1","b2"],"force_n":[1.25,null],'
        b'"force_static_n":[1.25,null],"resistance_ohm":[800.0,1234.567891],"status":["ok","stale"]}'
    )


def test_the_page_json_of_the_frame_byte_for_byte() -> None:
    counters = DeviceCounters(
        reads_total=9, polls_total=8, read_errors_total=MappingProxyType({"timeout": 2, "decode": 1})
    )
    assert encode_frame(two_channels(), 42, counters) == (
        b'{"device":"arr","seq":42,"t":1700000000.123457,"device_time_s":12.5,'
        b'"last_success_t":1699999999.5,"up":true,"error":null,"force_n":[1.25,null],"status":[0,5],'
        b'"total_force_n":1.25,"cop_mm":[0.0,0.0],"contact_area_mm2":6.25,"channels_in_contact":1,'
        b'"peak_channel":"a1","peak_force_n":1.25,"poll_interval_s":0.05,"polls_total":8,'
        b'"reads_total":9,"read_errors_total":3,"rois":[]}'
    )


def test_both_encodings_are_views_of_one_shared_frame() -> None:
    model = ReciprocalModel()
    snap = two_channels(model)
    frame = frame_of(snap)
    assert frame_of(snap) is frame
    assert frame_json(snap, 1, None) == frame_json(frame, 1, None)
    assert frame_dict(snap, 3) == frame_dict(frame, 3)
    encode_binary(frame_dict(snap, 3))
    assert model.calls == 1, "the static force is computed once for both encodings"
    copy = dataclasses.replace(snap, up=False)  # a new snapshot derives its own values
    assert frame_of(copy) is not frame and frame_of(copy).up is False


def test_one_nan_policy_for_values_and_lists() -> None:
    assert finite_or_none(1.23456789, 6) == 1.234568 and finite_or_none(2) == 2.0
    assert finite_or_none(np.float64(np.nan)) is None and finite_or_none(math.inf, 3) is None
    assert finite_or_none(None) is None and finite_or_none(-math.inf) is None
    assert finite_or_none(np.array([1.0, np.nan, np.inf, -0.5]), 1) == [1.0, None, None, -0.5]
    assert finite_or_none([0.1 + 0.2, math.nan]) == [0.30000000000000004, None]


class CountingModel(SensorModel):
    """A real model whose inversions are counted."""

    calls = 0

    def invert(self, *args: Any, **kwargs: Any) -> Any:
        type(self).calls += 1
        return super().invert(*args, **kwargs)


@pytest.fixture
def fast_switching() -> Iterator[None]:
    """Threads switch every microsecond, so that they interleave inside the computation."""
    old = sys.getswitchinterval()
    sys.setswitchinterval(1e-6)
    try:
        yield
    finally:
        sys.setswitchinterval(old)


def _all_at_once(n: int, read: Callable[[], object]) -> list[object]:
    barrier = threading.Barrier(n)
    results: list[object] = [None] * n

    def run(k: int) -> None:
        barrier.wait()
        results[k] = read()

    threads = [threading.Thread(target=run, args=(k,)) for k in range(n)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    return results


@pytest.mark.usefixtures("fast_switching")
def test_many_threads_reading_the_static_force_invert_exactly_once() -> None:
    model = CountingModel("tunneling,contact,creep", [SensorParams()] * 2)
    r = model.resistance(np.array([1.0, 2.0]))
    for _ in range(20):
        CountingModel.calls = 0
        snap = dataclasses.replace(
            two_channels(model),
            static_estimate=StaticEstimate(
                ((np.array([0, 1], dtype=np.intp), model),),
                r,
                None,
                np.array([True, True]),
                np.array([1.0, 2.0]),
            ),
        )
        results = _all_at_once(16, lambda snap=snap: snap.force_static_n)  # type: ignore[misc]
        assert CountingModel.calls == 1
        assert all(x is results[0] for x in results)
        static = cast(np.ndarray, results[0])
        np.testing.assert_allclose(static, [1.0, 2.0], rtol=1e-6)
        assert not static.flags.writeable


@pytest.mark.usefixtures("fast_switching")
def test_many_threads_asking_for_the_frame_build_it_exactly_once(monkeypatch: pytest.MonkeyPatch) -> None:
    builds = 0
    build = Frame.of

    def counted(snap: DeviceSnapshot) -> Frame:
        nonlocal builds
        builds += 1
        return build(snap)

    monkeypatch.setattr(Frame, "of", counted)
    for _ in range(20):
        builds = 0
        model = ReciprocalModel()
        snap = two_channels(model)
        frames = _all_at_once(16, lambda snap=snap: frame_of(snap))  # type: ignore[misc]
        assert builds == 1 and model.calls == 1
        assert all(f is frames[0] for f in frames)
        assert json.loads(encode_frame(cast(Frame, frames[0]), 1, None))["force_n"] == [1.25, None]


def _python_rounded(values: list[float], digits: int) -> list[float | None]:
    return [round(v, digits) if math.isfinite(v) else None for v in values]


def _same(got: list[float | None], want: list[float | None]) -> bool:
    """Equal value for value, None for None, and the sign of a zero kept (JSON prints -0.0)."""
    return len(got) == len(want) and all(
        (g is None and w is None)
        or (g is not None and w is not None and g == w and math.copysign(1.0, g) == math.copysign(1.0, w))
        for g, w in zip(got, want, strict=True)
    )


@given(
    st.lists(
        st.floats(allow_nan=True, allow_infinity=True, width=64)
        | st.integers(-(10**12), 10**12).map(
            lambda k: (k + 0.5) / 1e6  # exact halves of the 6th decimal, where rounding must tie-break
        ),
        min_size=1,
        max_size=80,
    ),
    st.integers(0, 9),
)
def test_an_array_rounds_as_round_does_value_for_value(values: list[float], digits: int) -> None:
    got = finite_or_none(np.array(values, dtype=np.float64), digits)
    assert _same(got, _python_rounded(values, digits)), (values, digits)


def test_array_rounding_at_hand_picked_values() -> None:
    values = [15.620000000000001, 0.0000005, 0.0000015, 0.0000025, -0.0000005, -0.0, 1.7e9 + 0.1234565,
              2.675, 1e300, math.nan, -math.inf]  # fmt: skip
    got = finite_or_none(np.array(values), 6)
    assert _same(got, _python_rounded(values, 6))
    assert got[0] == 15.62 and got[7] == 2.675 and got[8] == 1e300 and got[9:] == [None, None]
    assert got[5] == 0.0 and math.copysign(1.0, cast(float, got[5])) == -1.0
