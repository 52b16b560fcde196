"""The per-poll conversion: statuses, stale handling, NaN-free output, array quantities."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from gateway.config import ChannelConfig, DeviceConfig, RegisterMap
from gateway.config.layout import GridLayout
from gateway.errors import DecodeError
from gateway.modbus.decode import encode_bitmap, encode_float32
from gateway.modbus.image import RawSample, RegisterImage, decode_sample
from gateway.model import PAPER_EFFECTS, Divider, SensorModel, SensorParams
from gateway.runtime.counters import Tally
from gateway.runtime.processor import DeviceProcessor
from gateway.runtime.snapshot import ChannelStatus, array_quantities

DIVIDER = Divider()


def make_device(
    n: int = 4,
    columns: int = 2,
    pitch_mm: float = 2.5,
    encoding: str = "adc",
    effects: tuple[str, ...] = PAPER_EFFECTS,
    params: SensorParams | list[SensorParams] | None = None,
    name: str = "arr",
    enabled: tuple[bool, ...] | None = None,
    per_channel_effects: list[tuple[str, ...]] | None = None,
) -> DeviceConfig:
    plist = params if isinstance(params, list) else [params or SensorParams()] * n
    channels = tuple(
        ChannelConfig(
            index=i,
            name=f"ch{i:02d}",
            x_mm=(i % columns) * pitch_mm,
            y_mm=(i // columns) * pitch_mm,
            enabled=True if enabled is None else enabled[i],
            effects=per_channel_effects[i] if per_channel_effects else effects,
            params=plist[i],
        )
        for i in range(n)
    )
    return DeviceConfig(
        name=name,
        device_id=1,
        encoding=encoding,
        n_channels=n,
        registers=RegisterMap(),
        front_end=DIVIDER,
        channels=channels,
        allow_write=False,
        layout=GridLayout(n, columns, pitch_mm, pitch_mm),
        calibration=None,
    )


def counts_for(force_n: list[float], params: SensorParams | None = None) -> np.ndarray:
    model = SensorModel(PAPER_EFFECTS, [params or SensorParams()] * len(force_n))
    r = model.resistance(np.asarray(force_n))
    return DIVIDER.counts(DIVIDER.output_voltage(r))


def test_adc_forces_are_recovered_and_ok() -> None:
    dev = make_device()
    proc = DeviceProcessor(dev, "bus", 0.1)
    forces = [0.5, 1.0, 2.0, 5.0]
    snap, _ = proc.process(proc.rested_state(), RawSample(counts=counts_for(forces)), 1000.0, 0.0)
    assert snap.status.tolist() == [ChannelStatus.OK] * 4
    # 16-bit quantization of the divider: well under 1 % at these forces
    np.testing.assert_allclose(snap.force_n, forces, rtol=0.01)
    np.testing.assert_allclose(snap.force_static_n, forces, rtol=0.01)
    assert snap.up and snap.last_success_timestamp_s == 1000.0
    assert np.all(np.isfinite(snap.resistance_ohm))


def test_rails_give_open_and_short_without_values() -> None:
    dev = make_device()
    proc = DeviceProcessor(dev, "bus", 0.1)
    counts = counts_for([1.0, 1.0, 1.0, 1.0])
    counts[0] = 0  # open: no current through the sensor
    counts[1] = DIVIDER.full_scale  # short
    snap, _ = proc.process(proc.rested_state(), RawSample(counts=counts), 0.0, 0.0)
    assert snap.status[0] == ChannelStatus.OPEN
    assert snap.status[1] == ChannelStatus.SHORT
    assert math.isnan(snap.force_n[0]) and math.isnan(snap.force_n[1])
    assert math.isnan(snap.resistance_ohm[0])  # +inf is never exported
    assert snap.resistance_ohm[1] == 0.0
    views = snap.channels()
    assert views[0].force_n is None and views[0].resistance_ohm is None
    assert views[2].status == ChannelStatus.OK


def test_with_device_bitmaps_the_rails_are_readings_not_faults() -> None:
    dev = make_device()
    proc = DeviceProcessor(dev, "bus", 0.1)
    counts = counts_for([2.0, 2.0, 2.0, 2.0])
    state = proc.rested_state()
    _, state = proc.process(state, RawSample(counts=counts, device_time_s=0.0), 0.0, 0.0)
    counts[0] = 0  # unloaded: the contact is open at rest, no current
    counts[1] = DIVIDER.full_scale  # less resistance than one LSB resolves
    no_faults = np.zeros(4, dtype=bool)
    raw = RawSample(counts=counts, open_bits=no_faults, short_bits=no_faults, device_time_s=1.0)
    snap, state = proc.process(state, raw, 0.0, 0.0)
    assert snap.status[0] == ChannelStatus.NO_CONTACT and snap.force_n[0] == 0.0
    assert state.model_state.last_force_n[0] == 0.0  # the unload is recorded in the creep state
    assert snap.status[1] == ChannelStatus.SATURATED
    assert snap.force_n[1] == pytest.approx(SensorParams().force_max_n)
    assert math.isnan(snap.resistance_ohm[0]) and snap.resistance_ohm[1] == 0.0


def test_no_contact_and_saturated_from_the_model() -> None:
    dev = make_device()
    proc = DeviceProcessor(dev, "bus", 0.1)
    counts = counts_for([1.0, 1.0, 1.0, 1.0])
    counts[0] = 3  # about 218 Mohm: far above R(force_min)
    counts[1] = DIVIDER.full_scale - 3  # a few ohm: below R(force_max)
    snap, _ = proc.process(proc.rested_state(), RawSample(counts=counts), 0.0, 0.0)
    assert snap.status[0] == ChannelStatus.NO_CONTACT
    assert snap.force_n[0] == 0.0 and snap.force_static_n[0] == 0.0
    assert snap.status[1] == ChannelStatus.SATURATED
    assert snap.force_n[1] == pytest.approx(SensorParams().force_max_n)


def test_float32_encoding_statuses() -> None:
    dev = make_device(encoding="float32")
    proc = DeviceProcessor(dev, "bus", 0.1)
    r = np.array([np.inf, 0.0, np.nan, -5.0])
    snap, _ = proc.process(proc.rested_state(), RawSample(resistance_ohm=r), 0.0, 0.0)
    assert [ChannelStatus(s) for s in snap.status] == [
        ChannelStatus.OPEN,
        ChannelStatus.SHORT,
        ChannelStatus.ERROR,
        ChannelStatus.ERROR,
    ]
    assert np.all(np.isnan(snap.force_n))
    assert snap.channels_in_contact == 0 and snap.center_of_pressure_mm is None


def test_device_bitmaps_take_precedence() -> None:
    dev = make_device()
    proc = DeviceProcessor(dev, "bus", 0.1)
    counts = counts_for([1.0, 1.0, 1.0, 1.0])
    raw = RawSample(
        counts=counts,
        open_bits=np.array([True, False, False, False]),
        short_bits=np.array([False, True, False, False]),
        saturated_bits=np.array([False, False, True, False]),
    )
    snap, _ = proc.process(proc.rested_state(), raw, 0.0, 0.0)
    assert [ChannelStatus(s) for s in snap.status] == [
        ChannelStatus.OPEN,
        ChannelStatus.SHORT,
        ChannelStatus.SATURATED,
        ChannelStatus.OK,
    ]


def test_stale_keeps_last_values_and_marks_every_channel() -> None:
    dev = make_device()
    proc = DeviceProcessor(dev, "bus", 0.1)
    state = proc.rested_state()
    never, state = proc.stale(state, 5.0, "timeout")
    assert never.status.tolist() == [ChannelStatus.STALE] * 4
    assert not never.up and never.last_success_timestamp_s is None
    assert all(c.force_n is None for c in never.channels())
    good, state = proc.process(state, RawSample(counts=counts_for([0.5, 1, 2, 5])), 10.0, 1.0)
    stale, state2 = proc.stale(state, 11.0, "no answer")
    assert state2 is state  # the creep state does not advance without data
    assert stale.status.tolist() == [ChannelStatus.STALE] * 4
    assert not stale.up and stale.error == "no answer"
    np.testing.assert_array_equal(stale.force_n, good.force_n)
    assert stale.last_success_timestamp_s == 10.0 and stale.timestamp_s == 11.0


def test_snapshot_is_immutable() -> None:
    dev = make_device()
    proc = DeviceProcessor(dev, "bus", 0.1)
    snap, _ = proc.process(proc.rested_state(), RawSample(counts=counts_for([1, 1, 1, 1])), 0.0, 0.0)
    with pytest.raises(ValueError):
        snap.force_n[0] = 3.0
    with pytest.raises(dataclasses.FrozenInstanceError):
        snap.up = False  # type: ignore[misc]


def test_channel_views_never_contain_nan_or_inf() -> None:
    dev = make_device(encoding="float32")
    proc = DeviceProcessor(dev, "bus", 0.1)
    rng = np.random.default_rng(3)
    state = proc.rested_state()
    for k in range(30):
        r = rng.choice([np.nan, np.inf, -np.inf, 0.0, -1.0, 1e3, 5e4, 1e6, 1e12], size=4)
        snap, state = proc.process(state, RawSample(resistance_ohm=r, device_time_s=float(k)), 0.0, 0.0)
        for c in snap.channels():
            for v in (c.force_n, c.force_static_n, c.resistance_ohm):
                assert v is None or math.isfinite(v)
        assert math.isfinite(snap.total_force_n) and math.isfinite(snap.contact_area_mm2)
        if snap.center_of_pressure_mm is not None:
            assert all(math.isfinite(v) for v in snap.center_of_pressure_mm)


def test_array_quantities_hand_computed() -> None:
    # 2 x 2 grid, pitch 2.5 mm: ch00 (0, 0), ch01 (2.5, 0), ch02 (0, 2.5), ch03 (2.5, 2.5)
    x = np.array([0.0, 2.5, 0.0, 2.5])
    y = np.array([0.0, 0.0, 2.5, 2.5])
    force = np.array([1.0, 0.0, 3.0, np.nan])
    status = np.array(
        [ChannelStatus.OK, ChannelStatus.NO_CONTACT, ChannelStatus.SATURATED, ChannelStatus.OPEN]
    )
    q = array_quantities(force, status, x, y, 2.5 * 2.5)
    assert q.total_force_n == 4.0
    assert q.center_of_pressure_mm == (0.0, 1.875)  # y = 3 * 2.5 / 4
    assert q.channels_in_contact == 2
    assert q.contact_area_mm2 == 12.5  # 2 x 2.5^2
    assert q.peak_index == 2 and q.peak_force_n == 3.0


def test_array_quantities_without_contact_have_no_centre() -> None:
    q = array_quantities(np.zeros(3), np.full(3, ChannelStatus.NO_CONTACT), np.zeros(3), np.zeros(3), 1.0)
    assert q.center_of_pressure_mm is None and q.total_force_n == 0.0 and q.peak_index is None


def test_snapshot_array_quantities_from_processing() -> None:
    dev = make_device()
    proc = DeviceProcessor(dev, "bus", 0.1)
    counts = counts_for([2.0, 1.0, 1.0, 1.0])
    counts[1] = counts[2] = counts[3] = 3  # no contact
    snap, _ = proc.process(proc.rested_state(), RawSample(counts=counts), 0.0, 0.0)
    assert snap.channels_in_contact == 1
    assert snap.center_of_pressure_mm == (0.0, 0.0)
    assert snap.peak_channel == "ch00"
    assert snap.total_force_n == pytest.approx(2.0, rel=0.01)
    assert snap.contact_area_mm2 == pytest.approx(6.25)


def test_disabled_channels_are_left_out() -> None:
    dev = make_device(enabled=(True, False, True, False))
    proc = DeviceProcessor(dev, "bus", 0.1)
    snap, _ = proc.process(proc.rested_state(), RawSample(counts=counts_for([1, 2, 3, 4])), 0.0, 0.0)
    assert snap.channel_names == ("ch00", "ch02")
    np.testing.assert_allclose(snap.force_n, [1.0, 3.0], rtol=0.01)


def _held_counts(force_n: float, times_s: np.ndarray, params: SensorParams) -> np.ndarray:
    model = SensorModel(PAPER_EFFECTS, [params])
    out, _ = model.simulate(np.full((len(times_s), 1), force_n), times_s, t0_s=0.0)
    return DIVIDER.counts(DIVIDER.output_voltage(out.total_ohm[:, 0]))


def test_drift_corrected_force_stays_while_static_estimate_creeps() -> None:
    params = SensorParams()
    dev = make_device(n=1, columns=1)
    proc = DeviceProcessor(dev, "bus", 1.0)
    times = np.arange(0.0, 601.0, 5.0)
    counts = _held_counts(2.0, times, params)
    state = proc.rested_state()
    corrected, static = [], []
    for t, c in zip(times, counts, strict=True):
        # the host clock is frozen: the device clock alone must drive the creep state
        snap, state = proc.process(state, RawSample(counts=np.array([c]), device_time_s=float(t)), 0.0, 0.0)
        corrected.append(snap.force_n[0])
        static.append(snap.force_static_n[0])
    assert max(abs(f - 2.0) for f in corrected) < 0.01
    # the spec's table: the static reading after a 600 s hold at 2 N is 2.22 N
    assert static[-1] == pytest.approx(2.22, abs=0.02)
    assert static[-1] - static[1] > 0.15


def test_host_clock_is_used_without_device_clock_and_after_a_device_restart() -> None:
    dev = make_device(n=1, columns=1)
    proc = DeviceProcessor(dev, "bus", 1.0)
    counts = np.array([counts_for([2.0])[0]])
    state = proc.rested_state()
    _, state = proc.process(state, RawSample(counts=counts), 0.0, 100.0)
    assert not state.time_from_device and state.last_time_s == 100.0
    _, s1 = proc.process(state, RawSample(counts=counts), 0.0, 150.0)
    relaxed = s1.model_state.kv1_strain[0]
    assert relaxed > 0.0  # 50 s of host time relaxed the creep element
    # device clock that goes backwards (device restart): the host interval is used
    _, d1 = proc.process(state, RawSample(counts=counts, device_time_s=1000.0), 0.0, 150.0)
    _, d2 = proc.process(d1, RawSample(counts=counts, device_time_s=3.0), 0.0, 160.0)
    assert d2.last_time_s == 3.0 and d2.time_from_device


def test_channels_are_grouped_by_effect_set() -> None:
    effects = [PAPER_EFFECTS, ("tunneling",), PAPER_EFFECTS, ("tunneling",)]
    dev = make_device(per_channel_effects=effects)
    proc = DeviceProcessor(dev, "bus", 0.1)
    assert len(proc.groups) == 2
    assert sorted(idx.tolist() for idx, _ in proc.groups) == [[0, 2], [1, 3]]
    snap, _ = proc.process(proc.rested_state(), RawSample(counts=counts_for([1, 1, 1, 1])), 0.0, 0.0)
    assert snap.status.tolist() == [ChannelStatus.OK] * 4
    # the tunneling-only model reads the paper model's resistance differently
    assert abs(snap.force_n[1] - snap.force_n[0]) > 0.01


def test_reload_keeps_state_of_unchanged_channels_only() -> None:
    dev = make_device()
    proc = DeviceProcessor(dev, "bus", 0.1)
    state = proc.rested_state()
    counts = counts_for([2.0, 2.0, 2.0, 2.0])
    for t in range(0, 300, 10):
        _, state = proc.process(state, RawSample(counts=counts, device_time_s=float(t)), 0.0, 0.0)
    assert np.all(state.model_state.kv1_strain > 0)
    changed = list(dev.channels)
    changed[1] = dataclasses.replace(changed[1], params=SensorParams(r0_ohm=150e3))
    changed[2] = dataclasses.replace(changed[2], effects=("tunneling", "contact"))
    new_dev = dataclasses.replace(dev, channels=tuple(changed))
    new_proc = DeviceProcessor(new_dev, "bus", 0.1)
    carried = new_proc.carry_state(proc, state)
    kv = carried.model_state.kv1_strain
    assert kv[0] == state.model_state.kv1_strain[0] and kv[3] == state.model_state.kv1_strain[3]
    assert kv[1] == 0.0 and kv[2] == 0.0
    assert carried.last_time_s == state.last_time_s
    assert new_proc.kept_channels(proc) == 2


def test_decode_sample_from_registers() -> None:
    dev = make_device(n=4)
    counts = [100, 200, 300, 400]
    image = RegisterImage.from_reads(
        [
            (
                "input",
                2,
                [0, 0, 0, 1500] + [0] * 10 + encode_bitmap([True, False, False, False], 1) + [0] * 15,
            ),
            ("input", 32, [0] * 16 + encode_bitmap([False, False, False, True], 1)),
            ("input", 100, counts),
        ]
    )
    raw = decode_sample(dev, image)
    assert raw.counts is not None and raw.counts.tolist() == counts
    assert raw.device_time_s == 1.5
    assert raw.open_bits is not None and raw.open_bits.tolist() == [True, False, False, False]
    assert raw.short_bits is not None and not raw.short_bits.any()
    assert raw.saturated_bits is not None and raw.saturated_bits.tolist() == [False, False, False, True]
    with pytest.raises(DecodeError, match="ADC counts"):
        decode_sample(dev, RegisterImage.from_reads([("input", 100, counts[:3])]))
    fdev = make_device(n=2, encoding="float32")
    fimage = RegisterImage.from_reads([("input", 400, encode_float32([1e4, np.inf]))])
    fraw = decode_sample(fdev, fimage)
    assert fraw.resistance_ohm is not None and fraw.resistance_ohm.tolist() == [1e4, np.inf]
    assert fraw.device_time_s is None


def test_counters_and_histogram() -> None:
    tally = Tally()
    for event in ("read", "read", "timeout", 0.003, 0.2, math.nan):
        if event == "read":
            tally.read()
        elif event == "timeout":
            tally.error("timeout")
        else:
            tally.poll(float(event))
    c = tally.freeze()
    assert c.reads_total == 2 and c.polls_total == 3
    assert dict(c.read_errors_total) == {
        "timeout": 1,
        "exception": 0,
        "connection": 0,
        "decode": 0,
        "mismatch": 0,
    }
    h = c.poll_duration
    assert h.count == 2 and h.sum == pytest.approx(0.203)  # the NaN duration counts a poll, no value
    bounds = (*h.bounds, math.inf)
    assert h.bucket_counts[bounds.index(0.0025)] == 0
    assert h.bucket_counts[bounds.index(0.005)] == 1
    assert h.bucket_counts[bounds.index(0.25)] == 2
    assert h.bucket_counts[-1] == 2
    with pytest.raises(ValueError, match="gremlins"):
        tally.error("gremlins")


@settings(max_examples=50, deadline=None)
@given(st.lists(st.floats(min_value=0.0, max_value=50.0), max_size=60))
def test_tally_histogram_counts_every_duration_at_or_below_each_bound(durations: list[float]) -> None:
    tally = Tally()
    for d in durations:
        tally.poll(d)
    h = tally.freeze().poll_duration
    for bound, count in zip((*h.bounds, math.inf), h.bucket_counts, strict=True):
        assert count == sum(1 for d in durations if d <= bound)
    assert h.count == len(durations) and h.sum == pytest.approx(sum(durations))
    assert Tally(tally.freeze()).freeze().poll_duration == h  # carried over a reload


def test_read_plan_with_device_clock_and_backoff_bounds() -> None:
    import random

    from gateway.config import bus_config_for
    from gateway.modbus.plan import ReadRequest, device_plan, plan_with_device_time
    from gateway.runtime.bus import BusWorker

    dev = make_device(n=16, columns=4)
    plan = device_plan(dev, 125, 15, clock=True)
    # the clock is its own read (registers 7-15 do not exist); the bitmaps merge; then the ADC
    assert [(r.address, r.count) for r in plan] == [(2, 4), (16, 33), (100, 16)]
    assert [(r.address, r.count) for r in device_plan(dev, 125, 0, clock=False)] == [
        (16, 1),
        (32, 1),
        (48, 1),
        (100, 16),
    ]
    touching = (ReadRequest("input", 0, 2, ("x",)),)
    clock = dev.registers.clock
    assert clock is not None
    assert plan_with_device_time(touching, clock, 125) == (ReadRequest("input", 0, 6, ("device_time", "x")),)
    # a clock that joins a later read moves that read to the front: values follow the time
    later = (ReadRequest("holding", 0, 4, ("h",)), ReadRequest("input", 6, 10, ("y",)))
    assert plan_with_device_time(later, clock, 125) == (
        ReadRequest("input", 2, 14, ("device_time", "y")),
        ReadRequest("holding", 0, 4, ("h",)),
    )
    # a clock the map does not name is never read
    no_clock = dataclasses.replace(dev, registers=dataclasses.replace(dev.registers, clock=None))
    assert [(r.address, r.count) for r in device_plan(no_clock, 125, 15, clock=True)] == [(16, 33), (100, 16)]
    bus = bus_config_for(
        "b", "tcp", [dev], host="127.0.0.1", port=1, backoff_initial_s=0.5, backoff_max_s=4.0
    )
    worker = BusWorker(bus, [], lambda r, s: None, rng=random.Random(1))
    for failures, cap in [(1, 0.5), (2, 1.0), (3, 2.0), (4, 4.0), (30, 4.0)]:
        delays = [worker._jitter(failures) for _ in range(300)]
        assert min(delays) >= 0.05  # never a busy loop
        assert max(delays) <= cap
        assert max(delays) > 0.6 * cap  # full jitter spreads over the whole range


@pytest.mark.parametrize(
    ("bits", "hand"),
    [
        # r = R_ref (full_scale / counts - 1), R_ref = 4.7 kohm, worked by hand
        (10, {1: 4.7e3 * 1022, 512: 4.7e3 * 511 / 512, 1022: 4.7e3 / 1022}),
        (12, {1: 4.7e3 * 4094, 2048: 4.7e3 * 2047 / 2048, 4094: 4.7e3 / 4094}),
        (16, {1: 4.7e3 * 65534, 32768: 4.7e3 * 32767 / 32768, 65534: 4.7e3 / 65534}),
    ],
)
def test_register_lookup_tables_give_eq_18_by_hand(bits: int, hand: dict[int, float]) -> None:
    """Counts read from registers (uint16) are converted by lookup: the rails, a few counts
    worked by hand, register values above full scale invalid, and r falling with counts."""
    from gateway.runtime.status_tables import _adc_tables

    full_scale = 2**bits - 1
    tables = _adc_tables(Divider(5.0, 4.7e3, bits))
    for counts, r_ohm in hand.items():
        assert tables.model_ohm[counts] == pytest.approx(r_ohm, rel=1e-12)
        assert tables.report_ohm[counts] == pytest.approx(r_ohm, rel=1e-12)
        assert tables.status[counts] == 0  # DividerStatus.OK
    assert tables.model_ohm[0] == np.inf and np.isnan(tables.report_ohm[0]) and tables.status[0] == 1  # open
    assert tables.model_ohm[full_scale] == 0.0 and tables.status[full_scale] == 2  # short
    assert tables.model_with_bitmaps_ohm[0] == np.finfo(np.float64).max
    assert tables.model_with_bitmaps_ohm[full_scale] == np.finfo(np.float64).tiny
    beyond = slice(full_scale + 1, None)
    assert (tables.status[beyond] == 3).all() and np.isnan(tables.model_ohm[beyond]).all()  # INVALID
    assert tables.status[beyond].size == 0x10000 - 2**bits
    assert (np.diff(tables.model_ohm[1:full_scale]) < 0.0).all()


@pytest.mark.parametrize("bitmaps", [False, True])
def test_register_counts_convert_as_integer_counts(bitmaps: bool) -> None:
    """The lookup path (uint16 register values) and the formula path (int64 counts) give
    the same snapshot, rails and faults included."""
    dev = make_device(n=8, columns=4)
    proc = DeviceProcessor(dev, "bus", 0.1)
    counts = np.concatenate([counts_for([0.3, 1.0, 2.0, 6.0]), [0, 65535, 12, 65000]]).astype(np.int64)
    bits = np.zeros(8, dtype=bool)
    extra = {}
    if bitmaps:
        extra = {"open_bits": bits.copy(), "short_bits": bits.copy(), "saturated_bits": bits.copy()}
        extra["open_bits"][3] = True
    a, _ = proc.process(proc.rested_state(), RawSample(counts=counts, **extra), 0.0, 0.0)
    b, _ = proc.process(proc.rested_state(), RawSample(counts=counts.astype(np.uint16), **extra), 0.0, 0.0)
    np.testing.assert_array_equal(a.status, b.status)
    np.testing.assert_array_equal(a.force_n, b.force_n)
    np.testing.assert_array_equal(a.resistance_ohm, b.resistance_ohm)
    np.testing.assert_array_equal(a.force_static_n, b.force_static_n)
    assert len(set(a.status.tolist())) >= 3  # ok, open/no contact, short/saturated all met
