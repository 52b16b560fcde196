"""The "rawgrid" map (docs/register-map-rawgrid.md): its read-out by hand, its register
image, the bottom-up storage order, and what it refuses.

The low-side divider, worked by hand (R_pu = 10 kohm pull-up, 12-bit ratiometric ADC, full
scale 4095, rounding half to even):

    r_node = r || R_leak = r R_leak / (r + R_leak)
    counts = round(4095 * r_node / (R_pu + r_node))
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from click.testing import CliRunner

from sim_device import ArrayConfig, ConfigError, Scenario, SimArray
from sim_device import registers as reg
from sim_device.cli import main
from sim_device.electronics import (
    LowSideDivider,
    low_side_counts,
    low_side_resistance_from_counts,
    parallel_ohm,
    pullup_fraction,
)
from sim_device.profiles import ProfileBuilder
from sim_device.rawgrid import storage_order
from sim_device.record import array_metadata
from sim_device.scenarios import UniformLoad

R_PU = 10e3
LEAK = 470e3
#: the board's default leakage, and an unloaded cell of that board: the open sensor leaves the
#: leakage alone, 4095 * 195 / 205 = 3895.24 -> 3895 (the model reads 195 kohm as 0.12 N)
BOARD_LEAK = 195e3
UNLOADED = 3895


class Clock:
    def __init__(self) -> None:
        self.now_s = 0.0

    def __call__(self) -> float:
        return self.now_s


def rawgrid(clock: Clock | None = None, **changes: object) -> SimArray:
    options: dict[str, object] = {"register_map": "rawgrid", "channels": 36, "columns": 6}
    options.update(changes)
    return SimArray(ArrayConfig(**options), clock=clock or Clock())  # type: ignore[arg-type]


def one_cell_loaded(layout_config: ArrayConfig, channel: int, force_n: float) -> Scenario:
    profile = ProfileBuilder(force_n).build()
    return Scenario("one-cell", layout_config.layout, loads=[UniformLoad(profile, channels=(channel,))])


# ------------------------------------------------------------------------ electronics
def test_parallel_resistances_by_hand() -> None:
    got = parallel_ohm(
        np.array([470e3, 10e3, math.inf, 0.0, math.inf, 30e3]),
        np.array([470e3, 470e3, 470e3, 470e3, math.inf, math.inf]),
    )
    # 470k || 470k = 235k; 10k || 470k = 4.7e9 / 480e3 = 9791.666...; inf || 470k = 470k;
    # 0 || 470k = 0; inf || inf = inf; 30k || inf = 30k
    np.testing.assert_allclose(got, [235e3, 4.7e9 / 480e3, 470e3, 0.0, math.inf, 30e3], rtol=1e-15)


def test_pullup_fraction_by_hand() -> None:
    got = pullup_fraction(np.array([10e3, 30e3, 0.0, math.inf, 90e3]), R_PU)
    # r / (10k + r): 0.5, 30/40 = 0.75, 0, open = 1, 90/100 = 0.9
    np.testing.assert_array_equal(got, [0.5, 0.75, 0.0, 1.0, 0.9])


@pytest.mark.parametrize(
    ("resistance_ohm", "leakage_ohm", "counts"),
    [
        (10e3, math.inf, 2048),  # 4095 / 2 = 2047.5: a tie, to the even 2048
        (30e3, math.inf, 3071),  # 4095 * 0.75 = 3071.25
        (math.inf, math.inf, 4095),  # open, no leakage: full scale
        (0.0, LEAK, 0),  # short: 0 V
        (math.inf, LEAK, 4010),  # open: 4095 * 470 / 480 = 4009.6875
        (10e3, LEAK, 2026),  # node 9791.67: 4095 * 47 / 95 = 2025.947
        (30e3, LEAK, 3023),  # node 30 * 470 / 500 = 28.2k: 4095 * 28.2 / 38.2 = 3023.02
        (470e3, LEAK, 3928),  # node 235k: 4095 * 235 / 245 = 3927.86
        (2e6, LEAK, 3990),  # node 470k || 2M = 380.567k: 4095 * 940000 / 964700 = 3990.15
    ],
)
def test_low_side_counts_by_hand(resistance_ohm: float, leakage_ohm: float, counts: int) -> None:
    assert low_side_counts(np.array([resistance_ohm]), R_PU, 12, leakage_ohm).tolist() == [counts]


def test_noise_is_added_before_rounding_and_clipping() -> None:
    opened = np.full(4, math.inf)  # 4009.6875 before noise, 4095.0 without leakage
    got = low_side_counts(opened, R_PU, 12, LEAK, np.array([0.0, -0.19, -0.18, 2.5]))
    assert got.tolist() == [4010, 4009, 4010, 4012]  # 4009.5 -> 4010 (even); 4009.4975; 4012.1875
    assert low_side_counts(np.array([math.inf]), R_PU, 12, math.inf, 7.0).tolist() == [4095]
    assert low_side_counts(np.array([0.0]), R_PU, 12, LEAK, -3.0).tolist() == [0]


@pytest.mark.parametrize(
    ("counts", "leakage_ohm", "resistance_ohm"),
    [
        (2048, math.inf, 10e3 * 2048 / 2047),  # node = R_pu c / (4095 - c)
        (3071, math.inf, 10e3 * 3071 / 1024),  # 29990.234...
        (0, math.inf, 0.0),
        (4095, math.inf, math.inf),
        (4095, LEAK, math.inf),
        (4010, LEAK, math.inf),  # node 10k * 4010 / 85 = 471.76k > 470k: only leakage, open
        # node 10k * 3023 / 1072 = 28199.6; sensor = node 470k / (470k - node) = 29999.6
        (3023, LEAK, 28199.62686567164 * 470e3 / (470e3 - 28199.62686567164)),
        # node 10k * 4009 / 86 = 466162.79; sensor = 466162.79 * 470k / 3837.21 = 57.1 Mohm
        (4009, LEAK, 10e3 * 4009 / 86 * 470e3 / (470e3 - 10e3 * 4009 / 86)),
    ],
)
def test_low_side_resistance_from_counts_by_hand(
    counts: int, leakage_ohm: float, resistance_ohm: float
) -> None:
    got = low_side_resistance_from_counts(np.array([counts]), R_PU, 12, leakage_ohm)
    np.testing.assert_allclose(got, [resistance_ohm], rtol=1e-12)


def test_the_divider_object_by_hand() -> None:
    board = LowSideDivider()
    assert (board.pullup_ohm, board.supply_v, board.adc_bits, board.leakage_ohm) == (
        10e3,
        3.3,
        12,
        BOARD_LEAK,
    )
    assert board.open_sensor_counts() == UNLOADED
    # V_o = 3.3 * 195 / 205 = 3.13902439 V; a 10 kohm sensor alone: 3.3 / 2 = 1.65 V
    np.testing.assert_allclose(board.output_v(np.array([math.inf])), [3.3 * 195 / 205], rtol=1e-15)
    assert LowSideDivider(leakage_ohm=math.inf).output_v(np.array([10e3])).tolist() == [1.65]
    assert LowSideDivider(leakage_ohm=math.inf).open_sensor_counts() == 4095
    assert board.counts(np.array([30e3])).tolist() == [
        2958
    ]  # node 30k || 195k = 26k: 4095 * 26 / 36 = 2957.5
    assert board.resistance_from_counts(np.array([4095])).tolist() == [math.inf]


# ---------------------------------------------------------------------- register image
def test_register_image_of_an_unloaded_array() -> None:
    array = rawgrid(noise_lsb_rms=0.0)
    image = array.input_registers()
    assert len(image) == 32 + 36
    assert image[0] == 0x5447 and image[1] == 0x0103
    assert image[2:6] == [0x0000, 0x0001, 0xE240, 0x0007]
    assert image[8] == 36
    assert image[32:] == [UNLOADED] * 36
    assert array.holding_registers() == []
    assert array.electronics.adc_bits == 12 and array.electronics.reference_ohm == 10e3
    assert array.identity() == {
        "VendorName": "Acme Tactile",
        "ProductCode": "AT-6x6",
        "MajorMinorRevision": "1.3",
    }


def test_unloaded_cells_read_the_documented_count_within_noise() -> None:
    clock = Clock()
    array = rawgrid(clock, noise_lsb_rms=2.0)
    clock.now_s = 10.0  # 1000 conversions of 36 channels
    samples = []
    array.add_listener(lambda batch: samples.append(batch.adc_counts))
    array.advance()
    counts = np.concatenate(samples)
    exact = 4095 * 195 / 205  # 3895.2439
    assert np.abs(counts - exact).max() <= 6 * 2.0 + 1  # 6 sigma and the rounding
    assert counts.mean() == pytest.approx(exact, abs=0.05)  # 36000 draws: sigma 0.011
    assert counts.std() == pytest.approx(math.sqrt(2.0**2 + 1 / 12), rel=0.03)
    words = array.input_registers()[32:]
    assert np.abs(np.array(words) - UNLOADED).max() <= 13
    # without leakage an open sensor reads full scale; a sensor's own leakage path (the
    # `leakage` world effect, 2 Mohm) joins the board's: 195k || 2M = 177.68 kohm,
    # 4095 * 177.68 / 187.68 = 3876.8
    assert rawgrid(noise_lsb_rms=0.0, board_leakage_ohm=math.inf).input_registers()[32:] == [4095] * 36
    with_leak = rawgrid(noise_lsb_rms=0.0, world_effects=("leakage",), param_spread=False)
    assert with_leak.input_registers()[32:] == [3877] * 36


def test_rows_are_stored_bottom_up() -> None:
    np.testing.assert_array_equal(
        storage_order(16, 4), [12, 13, 14, 15, 8, 9, 10, 11, 4, 5, 6, 7, 0, 1, 2, 3]
    )
    np.testing.assert_array_equal(storage_order(10, 4), [8, 9, 4, 5, 6, 7, 0, 1, 2, 3])  # short bottom row
    np.testing.assert_array_equal(storage_order(5, 1), [4, 3, 2, 1, 0])
    np.testing.assert_array_equal(storage_order(3, 3), [0, 1, 2])
    array = rawgrid()
    channels = array.register_channels()
    assert sorted(channels.tolist()) == list(range(36))
    assert [array.register_position(k) for k in (0, 5, 30, 35)] == [(5, 0), (5, 5), (0, 0), (0, 5)]
    assert [int(channels[k]) for k in (0, 5, 30, 35)] == [30, 35, 0, 5]
    default = SimArray(ArrayConfig(channels=36, columns=6))
    np.testing.assert_array_equal(default.register_channels(), np.arange(36))


@pytest.mark.parametrize(("channel", "register"), [(0, 62), (5, 67), (30, 32), (35, 37)])
def test_loading_one_physical_corner_changes_its_register(channel: int, register: int) -> None:
    config = ArrayConfig(
        register_map="rawgrid", channels=36, columns=6, noise_lsb_rms=0.0, param_spread=False
    )
    array = SimArray(config.with_changes(scenario=one_cell_loaded(config, channel, 2.0)), clock=Clock())
    force = array.true_force_n()  # truth by physical channel
    assert force[channel] == 2.0 and np.count_nonzero(force) == 1
    image = array.input_registers()
    changed = [addr for addr in range(32, 68) if image[addr] != UNLOADED]
    assert changed == [register]
    assert (
        image[register] == 3238
    )  # 2 N: sensor 46.90 kohm, node 46.90 || 195 = 37.81 kohm, 4095 * 37.81 / 47.81
    k = register - 32
    assert int(array.register_channels()[k]) == channel
    assert array.register_position(k) == divmod(channel, 6)
    # the truth, read in register order, lines up with the ADC block
    by_register = array.true_force_n()[array.register_channels()]
    assert np.flatnonzero(by_register).tolist() == [k]


def test_channel_modes_clamp_to_the_rails_of_the_low_side_divider() -> None:
    array = rawgrid(noise_lsb_rms=2.0)
    array.set_channel_mode(0, "open")  # physical top-left: register 62
    array.set_channel_mode(35, "short")  # physical bottom-right: register 37
    array.advance(1.0)
    image = array.input_registers()
    assert image[62] == 4095 and image[37] == 0
    assert array.latest().resistance_ohm[0, 0] == math.inf and array.latest().resistance_ohm[0, 35] == 0.0


def test_measured_resistance_takes_the_leakage_out() -> None:
    config = ArrayConfig(register_map="rawgrid", channels=4, columns=2, noise_lsb_rms=0.0, param_spread=False)
    array = SimArray(config.with_changes(scenario=Scenario.constant(5.0, config.layout)), clock=Clock())
    b = array.latest()
    node = 10e3 * b.adc_counts[0] / (4095 - b.adc_counts[0])
    np.testing.assert_allclose(b.resistance_ohm[0], node * BOARD_LEAK / (BOARD_LEAK - node), rtol=1e-12)
    np.testing.assert_allclose(b.resistance_ohm[0], b.true_resistance_ohm[0], rtol=0.01)  # one LSB


# ------------------------------------------------------------------------ refusals
def test_holding_registers_do_not_exist() -> None:
    array = rawgrid()
    for address, values in ((0, [1]), (1, [12]), (100, [1]), (5, [0, 0])):
        with pytest.raises(reg.RegisterWriteError) as info:
            array.write_holding(address, values)
        assert info.value.code == 2


def test_the_board_fixes_its_read_out() -> None:
    array = rawgrid()
    with pytest.raises(ValueError, match="fixed by the rawgrid board"):
        array.set_electronics(adc_bits=16)
    array.set_electronics(noise_lsb_rms=0.5, sample_period_s=0.02)
    assert array.electronics.noise_lsb_rms == 0.5 and array.electronics.adc_bits == 12


@pytest.mark.parametrize(
    ("changes", "message"),
    [
        ({"register_map": "modbus-42"}, "register_map"),
        ({"register_map": "rawgrid", "adc_bits": 14}, "fixed"),
        ({"register_map": "rawgrid", "supply_v": 12.0}, "fixed"),
        ({"register_map": "rawgrid", "reference_ohm": 4.7e3}, "fixed"),
        ({"register_map": "rawgrid", "board_leakage_ohm": 0.0}, "board_leakage_ohm"),
        ({"register_map": "rawgrid", "board_leakage_ohm": math.nan}, "board_leakage_ohm"),
        ({"register_map": "rawgrid", "board_leakage_ohm": "1e6"}, "board_leakage_ohm"),
        ({"board_leakage_ohm": 1e6}, "rawgrid map only"),
    ],
)
def test_bad_map_settings_are_refused(changes: dict[str, object], message: str) -> None:
    with pytest.raises(ConfigError, match=message):
        ArrayConfig(**changes)  # type: ignore[arg-type]


def test_board_values_and_defaults_are_accepted() -> None:
    for changes in (
        {},
        {"adc_bits": 12, "supply_v": 3.3, "reference_ohm": 10e3},
        {"board_leakage_ohm": math.inf},
    ):
        config = ArrayConfig(register_map="rawgrid", **changes)  # type: ignore[arg-type]
        assert SimArray(config).electronics.supply_v == 3.3


def test_record_metadata_names_the_map_only_when_not_the_default() -> None:
    meta = array_metadata(rawgrid(), 0.1)
    assert meta["register_map"] == "rawgrid" and meta["board_leakage_ohm"] == "195000"
    assert meta["adc_bits"] == 12 and meta["supply_v"] == "3.3"
    assert "register_map" not in array_metadata(SimArray(ArrayConfig()), 0.1)


def test_cli_refuses_a_bad_map_and_leakage_for_the_default_map() -> None:
    result = CliRunner().invoke(main, ["run", "--map", "nosuch"])
    assert result.exit_code == 2 and "--map" in result.output
    result = CliRunner().invoke(main, ["run", "--board-leakage-ohm", "1e6", "--stop-after", "0"])
    assert result.exit_code == 1 and "rawgrid map only" in result.output and "Traceback" not in result.output
    result = CliRunner().invoke(main, ["run", "--map", "rawgrid", "--board-leakage-ohm", "-5"])
    assert result.exit_code == 1 and "board_leakage_ohm" in result.output
