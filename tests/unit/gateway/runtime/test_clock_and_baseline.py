"""The processor's device-clock health, unloaded baselines and saturated front-end codes.

The time step a poll's creep relaxation used is observed through its result: a processor whose
device clock behaves must give, bit for bit or to rounding, the forces and creep state of a
processor without a clock fed host times equal to the steps the clock should have produced.
A constant resistance (a held load) is fed, so every step changes the creep state.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence

import numpy as np
import pytest

from gateway.config import ChannelConfig, DeviceConfig, RegisterMap
from gateway.config.layout import GridLayout
from gateway.modbus.image import RawSample
from gateway.modbus.register_map import DeviceClock
from gateway.model import (
    PAPER_EFFECTS,
    Divider,
    DividerStatus,
    FrontEnd,
    LowSideDivider,
    SensorModel,
    SensorParams,
)
from gateway.runtime.clock import CLOCK_MAX_BACKWARD_JUMPS, CLOCK_STUCK_AFTER_S
from gateway.runtime.processor import (
    DeviceProcessor,
    DeviceState,
    state_arrays,
)
from gateway.runtime.snapshot import ChannelStatus, DeviceSnapshot

PARAMS = SensorParams()
MODEL = SensorModel(PAPER_EFFECTS, [PARAMS])
MS64 = DeviceClock(2, 4, 1e-3)  # uint64 milliseconds
MS16 = DeviceClock(2, 1, 1e-3)  # a 16-bit millisecond counter: wraps after 65.536 s


def r_of(force_n: float) -> float:
    """The model's resistance of a freshly loaded sensor (ohm)."""
    return float(MODEL.resistance(np.array([force_n]))[0])


R_2N = r_of(2.0)  # about 46.9 kohm (docs/parameters.md)


def make_device(
    n: int = 2,
    clock: DeviceClock | None = MS64,
    encoding: str = "float32",
    baselines: Sequence[float | None] | None = None,
    front_end: FrontEnd | None = None,
) -> DeviceConfig:
    channels = tuple(
        ChannelConfig(
            i,
            f"ch{i:02d}",
            float(i),
            0.0,
            True,
            PAPER_EFFECTS,
            PARAMS,
            None if baselines is None else baselines[i],
        )
        for i in range(n)
    )
    return DeviceConfig(
        name="arr",
        device_id=1,
        encoding=encoding,
        n_channels=n,
        registers=RegisterMap(clock=clock),
        front_end=front_end or Divider(),
        channels=channels,
        allow_write=False,
        layout=GridLayout(n, n, 1.0, 1.0),
        calibration=None,
    )


def held(n: int = 2, ticks: int | None = None, clock: DeviceClock = MS64) -> RawSample:
    """A poll of a held 2 N (constant resistance), with the device clock at ``ticks``."""
    r = np.full(n, R_2N)
    if ticks is None:
        return RawSample(resistance_ohm=r)
    return RawSample(resistance_ohm=r, device_time_s=ticks * clock.tick_s, device_ticks=ticks)


def run(
    proc: DeviceProcessor, polls: Sequence[tuple[RawSample, float]]
) -> tuple[list[DeviceSnapshot], DeviceState]:
    state = proc.rested_state()
    snaps = []
    for raw, host_s in polls:
        snap, state = proc.process(state, raw, 1_700_000_000.0 + host_s, host_s)
        snaps.append(snap)
    return snaps, state


def host_reference(host_times: Sequence[float], n: int = 2) -> tuple[list[DeviceSnapshot], DeviceState]:
    """The same held load on a device without a clock, polled at ``host_times``."""
    proc = DeviceProcessor(make_device(n, clock=None), "bus", 0.1)
    return run(proc, [(held(n), t) for t in host_times])


def assert_same_creep(a: DeviceState, b: DeviceState, snap_a: DeviceSnapshot, snap_b: DeviceSnapshot) -> None:
    for x, y in zip(state_arrays(a.model_state), state_arrays(b.model_state), strict=True):
        np.testing.assert_allclose(x, y, rtol=1e-12, atol=0.0)
    np.testing.assert_allclose(snap_a.force_n, snap_b.force_n, rtol=1e-12, atol=0.0)


def faults(snap: DeviceSnapshot) -> dict[str, int]:
    return dict(snap.clock_faults)


# --------------------------------------------------------------------------- the device clock
def test_the_creep_step_depends_on_the_time_step() -> None:
    # the premise of the comparisons below: a held 2 N read 3 s after loading reads less
    # than the same read 0.3 s after (creep lowers R), so a wrong step shows in the force
    _, slow = host_reference([0.0, 1.0, 2.0, 3.0])
    _, fast = host_reference([0.0, 0.1, 0.2, 0.3])
    assert slow.last is not None and fast.last is not None
    assert abs(slow.last.force_n[0] - fast.last.force_n[0]) > 1e-3 * fast.last.force_n[0]
    assert not np.array_equal(slow.model_state.kv1_strain, fast.model_state.kv1_strain)


def test_a_good_ms_clock_times_the_steps() -> None:
    # the device says 1 s per poll while the host sees 0.1 s: the device's 1 s steps are used
    proc = DeviceProcessor(make_device(), "bus", 0.1)
    polls = [(held(ticks=1000 * k), 0.1 * k) for k in range(4)]
    snaps, state = run(proc, polls)
    ref_snaps, ref = host_reference([0.0, 1.0, 2.0, 3.0])
    assert_same_creep(state, ref, snaps[-1], ref_snaps[-1])
    for k, snap in enumerate(snaps):
        assert snap.time_source == "device"
        assert snap.clock_fallback is None
        assert faults(snap) == {"stuck": 0, "backwards": 0}
        assert snap.device_time_s == pytest.approx(float(k))
    assert state.time_from_device and state.last_time_s == pytest.approx(3.0)


def test_a_clock_that_never_advances_is_stuck_after_the_limit() -> None:
    assert CLOCK_STUCK_AFTER_S == 2.0
    proc = DeviceProcessor(make_device(), "bus", 0.1)
    host = [0.0, 0.5, 1.0, 1.5, 2.0, 2.5, 3.0]
    snaps, state = run(proc, [(held(ticks=5000), t) for t in host])
    # up to 2.0 s without an advance (not more than the limit): still the device clock, a
    # zero step each time
    for snap in snaps[:5]:
        assert snap.time_source == "device" and snap.clock_fallback is None
        assert faults(snap) == {"stuck": 0, "backwards": 0}
    # at 2.5 s it is stuck: the host clock takes over for good
    for snap in snaps[5:]:
        assert snap.time_source == "host"
        assert snap.clock_fallback == "stuck"
        assert faults(snap) == {"stuck": 1, "backwards": 0}
    # the step at the fallback covers the 2.5 s since the clock last advanced (at host 0),
    # then 0.5 s host steps: the creep of a processor polled at 0, 2.5 and 3.0 s
    ref_snaps, ref = host_reference([0.0, 2.5, 3.0])
    assert_same_creep(state, ref, snaps[-1], ref_snaps[-1])


def test_the_fallback_step_starts_where_the_clock_last_advanced() -> None:
    # the clock advances 0.1 s twice (host 0.1 s too), then stops at host 0.2 s; at host 2.3 s
    # it has not advanced for 2.1 s > 2 s: stuck, and that poll's step is 2.3 - 0.2 = 2.1 s
    proc = DeviceProcessor(make_device(), "bus", 0.1)
    polls = [(held(ticks=0), 0.0), (held(ticks=100), 0.1), (held(ticks=200), 0.2)]
    polls += [(held(ticks=200), 1.2), (held(ticks=200), 2.2), (held(ticks=200), 2.3)]
    snaps, state = run(proc, polls)
    assert [s.clock_fallback for s in snaps] == [None] * 5 + ["stuck"]
    assert [s.time_source for s in snaps] == ["device"] * 5 + ["host"]
    ref_snaps, ref = host_reference([0.0, 0.1, 0.2, 2.3])
    assert_same_creep(state, ref, snaps[-1], ref_snaps[-1])
    # a step of only the last host interval (0.1 s) would be a different creep state
    _, short = host_reference([0.0, 0.1, 0.2, 0.3])
    assert not np.allclose(short.model_state.kv1_strain, state.model_state.kv1_strain, rtol=1e-6, atol=0.0)


def test_backward_jumps_are_counted_and_the_third_ends_the_device_clock() -> None:
    assert CLOCK_MAX_BACKWARD_JUMPS == 3
    proc = DeviceProcessor(make_device(), "bus", 0.1)
    ticks = [10_000, 11_000, 500, 1_500, 200, 1_200, 100, 1_100]
    host = [0.1 * k for k in range(len(ticks))]
    snaps, state = run(proc, [(held(ticks=t), h) for t, h in zip(ticks, host, strict=True)])
    assert [faults(s)["backwards"] for s in snaps] == [0, 0, 1, 1, 2, 2, 3, 3]
    assert [faults(s)["stuck"] for s in snaps] == [0] * 8
    assert [s.clock_fallback for s in snaps] == [None] * 6 + ["backwards"] * 2
    assert [s.time_source for s in snaps] == ["device"] * 6 + ["host"] * 2
    # steps: 0, 1 s (device), 0.1 s (host: the jump), 1 s, 0.1 s, 1 s, 0.1 s, 0.1 s (host)
    ref_snaps, ref = host_reference([0.0, 1.0, 1.1, 2.1, 2.2, 3.2, 3.3, 3.4])
    assert_same_creep(state, ref, snaps[-1], ref_snaps[-1])


def test_a_16_bit_ms_counter_wraps_without_a_jump() -> None:
    device = make_device(clock=MS16)
    proc = DeviceProcessor(device, "bus", 0.1)
    # 65530 -> 4 is (4 - 65530) mod 65536 = 10 ticks = 10 ms; then 4 -> 14, 10 ms again
    polls = [(held(ticks=65530, clock=MS16), 0.0), (held(ticks=4, clock=MS16), 0.5)]
    polls.append((held(ticks=14, clock=MS16), 1.0))
    snaps, state = run(proc, polls)
    assert all(faults(s) == {"stuck": 0, "backwards": 0} for s in snaps)
    assert all(s.time_source == "device" and s.clock_fallback is None for s in snaps)
    ref_snaps, ref = host_reference([0.0, 0.01, 0.02])
    assert_same_creep(state, ref, snaps[-1], ref_snaps[-1])


def test_a_16_bit_counter_that_leaps_far_beyond_the_host_step_is_a_jump() -> None:
    proc = DeviceProcessor(make_device(clock=MS16), "bus", 0.1)
    # 0 -> 30000 ticks is 30 s where the host saw 0.1 s: more than 10 x 0.1 + 1 s, a jump
    polls = [(held(ticks=0, clock=MS16), 0.0), (held(ticks=30_000, clock=MS16), 0.1)]
    snaps, state = run(proc, polls)
    assert faults(snaps[-1]) == {"stuck": 0, "backwards": 1}
    assert snaps[-1].clock_fallback is None
    ref_snaps, ref = host_reference([0.0, 0.1])  # the jump costs that step the host's 0.1 s
    assert_same_creep(state, ref, snaps[-1], ref_snaps[-1])


def test_a_map_with_a_clock_but_a_sample_without_one_is_unreadable() -> None:
    proc = DeviceProcessor(make_device(clock=MS64), "bus", 0.1)
    snaps, state = run(proc, [(held(), 0.0), (held(), 0.7), (held(), 1.4)])
    for snap in snaps:
        assert snap.clock_fallback == "unreadable"
        assert snap.time_source == "host"
        assert snap.device_time_s is None
    ref_snaps, ref = host_reference([0.0, 0.7, 1.4])
    assert_same_creep(state, ref, snaps[-1], ref_snaps[-1])


def test_a_map_without_a_clock_is_timed_by_the_host() -> None:
    proc = DeviceProcessor(make_device(clock=None), "bus", 0.1)
    # a sample that carries a device time anyway: nothing in the map says it is a clock
    raw = dataclasses.replace(held(), device_time_s=100.0, device_ticks=100_000)
    raw_later = dataclasses.replace(held(), device_time_s=500.0, device_ticks=500_000)
    snaps, state = run(proc, [(raw, 0.0), (raw_later, 0.3)])
    for snap in snaps:
        assert snap.clock_fallback is None
        assert snap.time_source == "host"
    ref_snaps, ref = host_reference([0.0, 0.3])
    assert_same_creep(state, ref, snaps[-1], ref_snaps[-1])


# --------------------------------------------------------------------------- baselines
BASELINES: list[float | None] = [None, 500e3, 2e6, 194_750.0]


def leaky(force_n: float, baseline_ohm: float) -> float:
    """What a channel with a parallel leak reads at ``force_n``: the model's R(0) is +inf (the
    contact is open at rest), so the leak is the whole baseline conductance 1/R_b:
    1/r = 1/R(F) + 1/R_b - 1/R(0) = 1/R(F) + 1/R_b."""
    return 1.0 / (1.0 / r_of(force_n) + 1.0 / baseline_ohm)


def test_the_paper_model_is_open_at_rest() -> None:
    assert math.isinf(r_of(0.0))  # R(0 N) = +inf: the leak is all of 1/R_b


def test_a_reading_at_the_baseline_is_no_contact() -> None:
    proc = DeviceProcessor(make_device(4, clock=None, baselines=BASELINES), "bus", 0.1)
    r = np.array([r_of(1.0), 500e3, 2e6, 194_750.0])
    snap, _ = proc.process(proc.rested_state(), RawSample(resistance_ohm=r), 0.0, 0.0)
    assert snap.status[1:].tolist() == [ChannelStatus.NO_CONTACT] * 3
    assert snap.force_n[1:].tolist() == [0.0, 0.0, 0.0]
    assert snap.status[0] == ChannelStatus.OK
    # the reported resistance is what the device read, not the corrected one
    np.testing.assert_array_equal(snap.resistance_ohm, r)
    # without the baselines the same readings are a load: 194.75 kohm reads about 0.12 N
    plain = DeviceProcessor(make_device(4, clock=None), "bus", 0.1)
    before, _ = plain.process(plain.rested_state(), RawSample(resistance_ohm=r), 0.0, 0.0)
    assert before.force_n[3] > 0.1 and before.status[3] == ChannelStatus.OK


def test_a_reading_above_the_baseline_is_no_contact() -> None:
    # less conductance than the leak alone (600 kohm against a 500 kohm baseline): 0 N
    proc = DeviceProcessor(make_device(4, clock=None, baselines=BASELINES), "bus", 0.1)
    r = np.array([r_of(1.0), 600e3, 1e9, 1e7])
    snap, _ = proc.process(proc.rested_state(), RawSample(resistance_ohm=r), 0.0, 0.0)
    assert snap.status[1:].tolist() == [ChannelStatus.NO_CONTACT] * 3
    assert snap.force_n[1:].tolist() == [0.0, 0.0, 0.0]


@pytest.mark.parametrize("force_n", [0.1, 0.5, 1.0, 2.0, 5.0, 9.0])
def test_a_loaded_channel_with_a_leak_reads_its_force(force_n: float) -> None:
    proc = DeviceProcessor(make_device(4, clock=None, baselines=BASELINES), "bus", 0.1)
    r = np.array([r_of(force_n)] + [leaky(force_n, b) for b in (500e3, 2e6, 194_750.0)])
    snap, _ = proc.process(proc.rested_state(), RawSample(resistance_ohm=r), 0.0, 0.0)  # dt = 0
    assert snap.status.tolist() == [ChannelStatus.OK] * 4
    np.testing.assert_allclose(snap.force_n, force_n, rtol=1e-6)
    np.testing.assert_allclose(snap.force_static_n, force_n, rtol=1e-6)
    # uncorrected, the 194.75 kohm leak adds to the force
    plain = DeviceProcessor(make_device(4, clock=None), "bus", 0.1)
    before, _ = plain.process(plain.rested_state(), RawSample(resistance_ohm=r), 0.0, 0.0)
    assert before.force_n[3] > force_n * (1 + 1e-3)


def test_channels_without_a_baseline_are_bitwise_unchanged() -> None:
    # ch01 has a 500 kohm baseline, ch03 an infinite one (open at rest: no leak to take off)
    with_b = DeviceProcessor(make_device(4, clock=MS64, baselines=[None, 5e5, None, math.inf]), "bus", 0.1)
    plain = DeviceProcessor(make_device(4, clock=MS64), "bus", 0.1)
    s_b, s_plain, s_fed = with_b.rested_state(), plain.rested_state(), plain.rested_state()
    rng = np.random.default_rng(3)
    others = [0, 2, 3]
    for k in range(12):
        r = r_of(float(rng.uniform(0.2, 8.0))) * rng.uniform(0.9, 1.1, 4)
        r[others[k % 3]] = [np.inf, 0.0, np.nan, 1e12][k % 4]  # rails and invalid values too
        raw = RawSample(resistance_ohm=r, device_time_s=0.25 * k, device_ticks=250 * k)
        a, s_b = with_b.process(s_b, raw, 0.0, 0.1 * k)
        b, s_plain = plain.process(s_plain, raw, 0.0, 0.1 * k)
        # what reaches the model, the reported resistance and the status: bit for bit
        assert a.static_estimate is not None and b.static_estimate is not None
        for i in others:
            assert a.status[i] == b.status[i]
            assert np.array_equal(a.resistance_ohm[i : i + 1], b.resistance_ohm[i : i + 1], equal_nan=True)
            assert np.array_equal(
                a.static_estimate.resistance_ohm[i : i + 1],
                b.static_estimate.resistance_ohm[i : i + 1],
                equal_nan=True,
            )
        # the leak taken off ch01 by hand: 1/r' = 1/r - 1/R_b (R(0) = inf); fed to the plain
        # processor, everything (forces, creep state) is the same bit for bit
        corrected = r.copy()
        corrected[1] = 1.0 / (1.0 / r[1] - 1.0 / 5e5)
        c, s_fed = plain.process(s_fed, dataclasses.replace(raw, resistance_ohm=corrected), 0.0, 0.1 * k)
        assert np.array_equal(a.force_n, c.force_n, equal_nan=True)
        assert np.array_equal(a.status, c.status)
        for x, y in zip(state_arrays(s_b.model_state), state_arrays(s_fed.model_state), strict=True):
            assert np.array_equal(x, y, equal_nan=True)
        # against the uncorrected device the other channels' forces agree to the solver's
        # precision (its Newton iterations run until every channel of the array converged)
        np.testing.assert_allclose(a.force_n[others], b.force_n[others], rtol=1e-9, atol=0.0)


def test_an_adc_channel_at_its_baseline_counts_is_no_contact() -> None:
    # low side, 12 bit, 10 kohm pull-up: 3895 counts = 10k * 3895 / (4095 - 3895) = 194750 ohm
    front_end = LowSideDivider(supply_v=3.3, reference_ohm=10000.0, adc_bits=12)
    r, status = front_end.resistance(np.array([3895]))
    assert r[0] == pytest.approx(194_750.0, rel=1e-12) and status[0] == DividerStatus.OK
    device = make_device(2, clock=None, encoding="adc", baselines=[194_750.0, None], front_end=front_end)
    proc = DeviceProcessor(device, "bus", 0.1)
    counts = np.array([3895, 3895], dtype=np.uint16)  # register values: the lookup path
    snap, _ = proc.process(proc.rested_state(), RawSample(counts=counts), 0.0, 0.0)
    # without a zero the leak reads as force at the converter's idle floor (3895 >= 4095 -
    # 0.06 x 4095 = 3849.3): shown, flagged no_zero, not counted
    assert snap.status.tolist() == [ChannelStatus.NO_CONTACT, ChannelStatus.NO_ZERO]
    assert snap.force_n[0] == 0.0
    assert snap.force_n[1] == pytest.approx(0.1186, abs=5e-4)
    assert snap.total_force_n == 0.0 and snap.channels_in_contact == 0


# --------------------------------------------------------------------------- saturated codes
def test_a_saturated_front_end_code_is_a_saturated_channel_without_a_force() -> None:
    # a 5 V pull-up read by a 3.3 V converter: full scale (4095) is not the open level
    # (that lies beyond full scale) but the bound R_ref * Vref / (V+ - Vref)
    # = 10k * 3.3 / 1.7 = 19411.76 ohm: SATURATED
    front_end = LowSideDivider(supply_v=5.0, reference_ohm=10000.0, adc_bits=12, adc_reference_v=3.3)
    r, status = front_end.resistance(np.array([4095]))
    assert status[0] == DividerStatus.SATURATED
    assert r[0] == pytest.approx(10000.0 * 3.3 / 1.7, rel=1e-12)
    # 2000 counts: yk = 2000 * 3.3 / 5 = 1320, r = 10k * 1320 / (4095 - 1320) = 4756.8 ohm
    r_ok, status_ok = front_end.resistance(np.array([2000]))
    assert status_ok[0] == DividerStatus.OK and r_ok[0] == pytest.approx(1.32e7 / 2775, rel=1e-12)
    device = make_device(2, clock=None, encoding="adc", front_end=front_end)
    proc = DeviceProcessor(device, "bus", 0.1)
    for counts in (
        np.array([4095, 2000], dtype=np.uint16),  # register values (lookup tables)
        np.array([4095, 2000], dtype=np.int64),  # computed counts
    ):
        for bits in (None, np.zeros(2, dtype=bool)):  # without and with (clear) fault bitmaps
            raw = RawSample(counts=counts, open_bits=bits, short_bits=bits)
            snap, _ = proc.process(proc.rested_state(), raw, 0.0, 0.0)
            assert snap.status[0] == ChannelStatus.SATURATED
            assert math.isnan(snap.force_n[0])
            assert snap.channels()[0].force_n is None
            assert snap.status[1] == ChannelStatus.OK and math.isfinite(snap.force_n[1])
            assert snap.channels_in_contact == 1 and snap.peak_channel == "ch01"
            assert snap.total_force_n == pytest.approx(float(snap.force_n[1]))
