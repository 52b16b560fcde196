"""SimArray: paper physics, electronics (eq. 18), noise, spread, channel modes, clock, registers."""

from __future__ import annotations

import time

import numpy as np
import pytest

from sim_device import ArrayConfig, ConfigError, SampleBatch, Scenario, SimArray
from sim_device import registers as reg
from sim_device.array import MAX_WORK
from sim_device.sensor import SimSensorParams


class Clock:
    """A manual wall clock for deterministic device time."""

    def __init__(self) -> None:
        self.now_s = 0.0

    def __call__(self) -> float:
        return self.now_s


def make(clock: Clock, **changes: object) -> SimArray:
    options: dict[str, object] = {"noise_lsb_rms": 0.0, "param_spread": False}
    options.update(changes)
    return SimArray(ArrayConfig(**options), clock=clock)  # type: ignore[arg-type]


def test_held_force_follows_the_paper_model_and_the_spec_table() -> None:
    clock = Clock()
    array = make(clock, scenario=Scenario.constant(2.0))
    r0 = array.latest().true_resistance_ohm[0, 0]
    assert r0 == pytest.approx(46.9e3, rel=2e-3)  # spec table, F = 2 N at t = 0
    clock.now_s = 600.0
    array.advance()
    r600 = array.latest().true_resistance_ohm[0, 0]
    drop = 1.0 - r600 / r0
    assert drop == pytest.approx(0.131, abs=5e-4)  # "R drop after 600 s hold": 13.1 %


def test_a_settled_scenario_starts_where_a_held_load_ends_and_does_not_drift() -> None:
    """``settled``: the load was carried long before t = 0; the resistance is the spec's
    after-600-s value (13.1 % below 46.9 kohm, the creep all but done: tau = mu1 / E1 = 100 s)
    from the first sample on, and stays."""
    clock = Clock()
    array = make(clock, scenario=Scenario.constant(2.0, settled=True))
    r0 = array.latest().true_resistance_ohm[0, 0]
    assert r0 == pytest.approx(46.9e3 * (1.0 - 0.131), rel=3e-3)
    clock.now_s = 600.0
    array.advance()
    assert array.latest().true_resistance_ohm[0, 0] == pytest.approx(r0, rel=1e-12)


def test_measured_resistance_is_eq18_of_the_counts() -> None:
    clock = Clock()
    array = make(clock, scenario=Scenario.constant(3.0), noise_lsb_rms=2.0, param_spread=True)
    clock.now_s = 5.0
    array.advance()
    b = array.latest()
    # eq. 18 by hand: V_o / V+ = R_ref / (R_ref + r), 16-bit ratiometric ADC
    ideal = 65535.0 * 10e3 / (10e3 + b.true_resistance_ohm[0])
    assert np.abs(b.adc_counts[0] - ideal).max() <= 12  # 2 LSB RMS noise, 6 sigma
    expected = 10e3 * (65535.0 / b.adc_counts[0] - 1.0)
    np.testing.assert_allclose(b.resistance_ohm[0], expected, rtol=1e-12)


def test_adc_noise_has_the_configured_rms() -> None:
    clock = Clock()
    array = make(clock, scenario=Scenario.constant(3.0), noise_lsb_rms=2.0)
    batches: list[SampleBatch] = []
    array.add_listener(batches.append)
    clock.now_s = 20.0
    array.advance()
    b = batches[0]
    ideal = 65535.0 * 10e3 / (10e3 + b.true_resistance_ohm)  # eq. 18, R_ref = 10 kohm, 16 bit
    residual = b.adc_counts - ideal
    assert residual.std() == pytest.approx(2.0, rel=0.05)
    assert abs(residual.mean()) < 0.05


def test_noise_and_spread_are_seeded() -> None:
    a = make(Clock(), scenario="holds", noise_lsb_rms=2.0, param_spread=True, seed=7)
    b = make(Clock(), scenario="holds", noise_lsb_rms=2.0, param_spread=True, seed=7)
    c = make(Clock(), scenario="holds", noise_lsb_rms=2.0, param_spread=True, seed=8)
    assert a.channel_params == b.channel_params and a.channel_params != c.channel_params
    np.testing.assert_array_equal(a.latest().adc_counts, b.latest().adc_counts)


def test_part_to_part_spread_stays_within_the_documented_bounds() -> None:
    array = SimArray(ArrayConfig(channels=256, columns=16, param_spread=True))
    base = SimSensorParams()
    for name, width in (("r0_ohm", 0.15), ("e0_pa", 0.10), ("e1_pa", 0.10), ("mu1_pa_s", 0.10),
                        ("rho2_ohm_m", 0.10)):  # fmt: skip
        ratio = np.array([getattr(p, name) for p in array.channel_params]) / getattr(base, name)
        assert ratio.min() >= 1 - width and ratio.max() <= 1 + width
        assert np.ptp(ratio) > width, f"{name} must actually spread"
    assert all(p.hardness_pa == base.hardness_pa for p in array.channel_params)


def test_channel_params_given_per_channel() -> None:
    params = [SimSensorParams(r0_ohm=100e3 + 1e3 * i) for i in range(4)]
    array = SimArray(ArrayConfig(channels=4, columns=2, channel_params=params, scenario=Scenario.constant(
        1.0, ArrayConfig(channels=4, columns=2).layout)))  # fmt: skip
    assert array.channel_params == params
    with pytest.raises(ConfigError, match="channel_params"):
        ArrayConfig(channels=4, columns=2, channel_params=params[:3])


def test_open_and_short_channels() -> None:
    clock = Clock()
    array = make(clock, scenario=Scenario.constant(2.0), noise_lsb_rms=3.0)
    array.set_channel_mode(3, "open")
    array.set_channel_mode(17 % 16, "short")
    clock.now_s = 1.0
    regs = array.input_registers()
    b = array.latest()
    assert b.adc_counts[0, 3] == 0 and b.resistance_ohm[0, 3] == np.inf
    assert b.adc_counts[0, 1] == 65535 and b.resistance_ohm[0, 1] == 0.0
    assert regs[reg.IR_OPEN_BITMAP] == 1 << 3 and regs[reg.IR_SHORT_BITMAP] == 1 << 1
    assert regs[reg.IR_STATUS_SUMMARY] & 3 == 3
    assert array.holding_registers()[reg.HR_CHANNEL_MODE + 3] == 1
    array.set_channel_mode(3, 0)
    clock.now_s = 2.0
    assert array.input_registers()[reg.IR_OPEN_BITMAP] == 0
    with pytest.raises(ValueError, match="mode"):
        array.set_channel_mode(0, "broken")
    with pytest.raises(ValueError, match="index"):
        array.set_channel_mode(16, "open")


def test_unloaded_sensor_reads_open_and_saturated() -> None:
    array = make(Clock(), scenario="idle")
    regs = array.input_registers()
    assert array.latest().resistance_ohm[0, 0] == np.inf
    assert regs[reg.IR_SATURATED_BITMAP] == 0xFFFF and regs[reg.IR_OPEN_BITMAP] == 0
    assert regs[reg.IR_STATUS_SUMMARY] == reg.STATUS_ANY_SATURATED


def test_scheduled_channel_fault_applies_at_its_device_time() -> None:
    clock = Clock()
    array = make(clock, scenario=Scenario.constant(2.0))
    array.faults.schedule(1.005, until_s=2.0, channel=2, channel_mode="short")
    batches: list[SampleBatch] = []
    array.add_listener(batches.append)
    clock.now_s = 3.0
    array.advance()
    b = batches[-1]
    shorted = b.time_s[b.adc_counts[:, 2] == 65535]
    assert shorted.min() == pytest.approx(1.01) and shorted.max() == pytest.approx(1.99)
    assert array.modes[2] == 0


def test_clock_speed_and_sample_counter() -> None:
    clock = Clock()
    array = make(clock, speed=60.0, sample_period_s=0.01)
    clock.now_s = 2.0
    assert array.device_time_s == pytest.approx(120.0)
    regs = array.input_registers()
    assert array.sample_counter == 12001
    assert (regs[0] << 16) | regs[1] == 12001
    t_ms = sum(regs[reg.IR_DEVICE_TIME_MS + k] << (16 * (3 - k)) for k in range(4))
    assert t_ms == 120000


def test_true_force_at_current_device_time() -> None:
    clock = Clock()
    array = make(clock, scenario="holds", speed=10.0)
    clock.now_s = 20.0  # 200 s device time: the 2 N hold
    np.testing.assert_allclose(array.true_force_n(), 2.0)
    assert array.true_force_n().shape == (16,)


def test_long_idle_catch_up_is_bounded() -> None:
    clock = Clock()
    array = make(clock, scenario="sine", channels=64, columns=8, world_effects=("creep2", "hysteresis"))
    clock.now_s = 1e7
    start = time.perf_counter()
    due = array.advance()
    assert time.perf_counter() - start < 2.0
    assert due == 10**9 and array.sample_counter == 10**9 + 1
    assert array.last_sample_time_s == pytest.approx(1e7)
    assert due > MAX_WORK // 64
    assert np.isfinite(array.latest().true_resistance_ohm).all()


def test_exact_advance_matches_stepwise_advance() -> None:
    c1, c2 = Clock(), Clock()
    one = make(c1, scenario="cycles", world_effects=("creep2", "hysteresis"), noise_lsb_rms=0.0)
    many = make(c2, scenario="cycles", world_effects=("creep2", "hysteresis"), noise_lsb_rms=0.0)
    one.advance(50.0, exact=True)
    for t in np.arange(0.37, 50.0, 0.37):
        many.advance(float(t))
    many.advance(50.0)
    np.testing.assert_allclose(one.latest().true_resistance_ohm, many.latest().true_resistance_ohm, rtol=1e-9)


def test_sample_period_change_regrids() -> None:
    clock = Clock()
    array = make(clock, sample_period_s=0.01)
    clock.now_s = 1.0
    array.advance()
    array.set_electronics(sample_period_s=0.5)
    clock.now_s = 3.0
    assert array.advance() == 4
    assert array.last_sample_time_s == pytest.approx(3.0)
    with pytest.raises(ConfigError):
        array.set_electronics(sample_period_s=0.0)


def test_holding_write_validation_leaves_state_unchanged() -> None:
    clock = Clock()
    array = make(clock)
    before = array.holding_registers()
    bad = [
        (reg.HR_CHANNEL_COUNT, [4], reg.ILLEGAL_ADDRESS),
        (reg.HR_PITCH_UM, [1], reg.ILLEGAL_ADDRESS),
        (reg.HR_ADC_BITS, [17], reg.ILLEGAL_VALUE),
        (reg.HR_ADC_BITS, [7], reg.ILLEGAL_VALUE),
        (reg.HR_SUPPLY_V, [0x4000], reg.ILLEGAL_VALUE),  # half a float32
        (reg.HR_SUPPLY_V + 1, [0, 0], reg.ILLEGAL_VALUE),  # straddles two floats
        (reg.HR_SUPPLY_V, reg.float32_words([30.0]), reg.ILLEGAL_VALUE),
        (reg.HR_REFERENCE_OHM, reg.float32_words([float("nan")]), reg.ILLEGAL_VALUE),
        (reg.HR_SAMPLE_PERIOD_S, reg.float32_words([0.0001]), reg.ILLEGAL_VALUE),
        (reg.HR_NOISE_LSB_RMS, reg.float32_words([-1.0]), reg.ILLEGAL_VALUE),
        (reg.HR_CHANNEL_MODE, [3], reg.ILLEGAL_VALUE),
        (reg.HR_CHANNEL_MODE + 15, [0, 0], reg.ILLEGAL_ADDRESS),
        (reg.HR_ADC_BITS, [12, *reg.float32_words([99.0])], reg.ILLEGAL_VALUE),  # one bad value spoils all
    ]
    for address, values, code in bad:
        with pytest.raises(reg.RegisterWriteError) as info:
            array.write_holding(address, values)
        assert info.value.code == code, (address, values)
        assert array.holding_registers() == before
    array.write_holding(reg.HR_ADC_BITS, [12, *reg.float32_words([3.3])])
    assert array.electronics.adc_bits == 12 and array.electronics.supply_v == pytest.approx(3.3)
    clock.now_s = 0.5
    array.advance()
    assert array.latest().adc_counts.max() <= 4095
    array.write_holding(reg.HR_CHANNEL_MODE + 2, [1, 2])
    assert list(array.modes[2:4]) == [1, 2]


def test_register_encodings() -> None:
    words = reg.float32_words([1.0, float("inf")])
    assert words == [0x3F80, 0, 0x7F80, 0]
    assert reg.words_float32(words[:2]) == 1.0
    flags = np.zeros(40, dtype=bool)
    flags[[0, 17, 39]] = True
    bitmap = reg.bitmap_words(flags)
    assert bitmap.shape == (16,) and list(bitmap[:3]) == [1, 2, 1 << 7]


def test_float_block_and_bench_blocks_match_the_latest_sample() -> None:
    clock = Clock()
    array = make(clock, scenario="holds", noise_lsb_rms=2.0, param_spread=True, speed=10.0)
    clock.now_s = 13.0
    regs = array.input_registers()
    b = array.latest()
    n = array.n_channels

    def floats(address: int) -> np.ndarray:
        raw = np.array(regs[address : address + 2 * n], dtype=">u2")
        return raw.view(">f4").astype(np.float64)

    np.testing.assert_array_equal(regs[reg.IR_ADC_COUNTS : reg.IR_ADC_COUNTS + n], b.adc_counts[0])
    np.testing.assert_array_equal(floats(reg.IR_RESISTANCE), b.resistance_ohm[0].astype(np.float32))
    np.testing.assert_array_equal(floats(reg.IR_TRUE_FORCE), b.force_n[0].astype(np.float32))
    np.testing.assert_array_equal(floats(reg.IR_TEMPERATURE), np.float32(25.0))
    np.testing.assert_array_equal(floats(reg.IR_TRUE_RESISTANCE), b.true_resistance_ohm[0].astype(np.float32))
    assert len(regs) == reg.input_size(n)


def test_identity_and_config_errors() -> None:
    array = SimArray(ArrayConfig(channels=12, columns=4))
    ident = array.identity()
    assert ident["ModelName"] == "Linqstat 3x4" and ident["ProductCode"] == "TSA-SIM"
    assert ident["VendorName"] == "Tactile Gateway Project"
    for bad in ({"channels": 0}, {"channels": 300}, {"columns": 17}, {"adc_bits": 20}, {"speed": 0.0},
                {"supply_v": 30.0}, {"world_effects": ("creep3",)}, {"pitch_mm": 70.0}):  # fmt: skip
        with pytest.raises(ConfigError):
            ArrayConfig(**bad)
    with pytest.raises(ValueError, match="device_id"):
        SimArray(ArrayConfig(), device_id=0)
    assert ArrayConfig(world_effects="creep,creep2").world_effects == ("creep2",)  # type: ignore[arg-type]


def test_sensor_noise_is_relative_and_log_normal() -> None:
    import numpy as np

    from sim_device import ArrayConfig
    from sim_device.record import record_offline

    cfg = ArrayConfig(
        channels=1, columns=1, scenario="holds", noise_lsb_rms=0.0, sensor_noise_rel=0.01, param_spread=False
    )
    rec = record_offline(cfg, duration_s=200.0, record_period_s=0.5)
    loaded = (rec.force_n > 0) & np.isfinite(rec.resistance_ohm)
    clean = record_offline(cfg.with_changes(sensor_noise_rel=0.0), duration_s=200.0, record_period_s=0.5)
    ratio = np.log(rec.resistance_ohm[loaded] / clean.resistance_ohm[loaded])
    assert 0.008 < float(np.std(ratio)) < 0.012
    assert abs(float(np.mean(ratio))) < 0.003


def test_sensor_noise_is_validated() -> None:
    import pytest

    from sim_device import ArrayConfig
    from sim_device.config import ConfigError

    with pytest.raises(ConfigError, match=r"sensor_noise_rel = 0.9 must be in \[0, 0.5\]"):
        ArrayConfig(sensor_noise_rel=0.9)


def test_a_clock_read_latches_the_frame_for_the_reads_that_follow() -> None:
    import asyncio

    from sim_device.pymodbus_device import LATCH_S, Binding

    clock, wall = Clock(), Clock()
    array = make(clock, speed=100.0, sample_period_s=0.01)
    binding = Binding(array, wall=wall)
    registers = [0] * reg.input_size(array.n_channels)

    def read(address: int, count: int) -> list[int]:
        assert asyncio.run(binding.action(4, 0, address, count, registers, None)) is None
        return registers[address : address + count]

    def counter() -> int:
        words = read(reg.IR_SAMPLE_COUNTER, 2)
        return (words[0] << 16) | words[1]

    clock.now_s = 1.0
    t_ms = read(reg.IR_DEVICE_TIME_MS, 4)[3]
    assert t_ms == 100_000 % 65536
    latched = counter()
    assert latched == 10_001  # 100 s of device time at 10 ms, plus the conversion at 0
    clock.now_s = 1.5  # 50 s of device time later, within the latch
    wall.now_s = LATCH_S * 0.99
    assert counter() == latched
    wall.now_s = LATCH_S * 1.01  # the latch has expired: live again
    assert counter() == 15_001
    clock.now_s = 2.0
    wall.now_s = 10.0
    read(reg.IR_DEVICE_TIME_MS - 1, 2)  # any read that covers a clock register latches anew
    assert counter() == 20_001
    clock.now_s = 3.0
    assert counter() == 20_001
