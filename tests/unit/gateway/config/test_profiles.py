"""Device profiles and what a ``[[bus.device]]`` table makes of them: the shipped profiles,
overrides key by key, profile files, the clock, checks and baselines (hand-computed values)."""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path

import pytest

from gateway.config import DeviceConfig, parse_config
from gateway.config.layout import GridLayout
from gateway.config.profiles import builtin_profiles
from gateway.errors import ConfigError
from gateway.modbus.register_map import DeviceChecks, DeviceClock, RegisterCheck
from gateway.model import Divider, LowSideDivider, SensorParams, Transimpedance

SOURCE = Path("/cfg/gateway.toml")
DEV = "bus[0].device[0]"
HEAD = """\
[[bus]]
name = "jaw"
kind = "tcp"
host = "127.0.0.1"

[[bus.device]]
name = "jaw"
device_id = 1
"""
ACME = 'profile = "acme-at6x6"\n'
#: a device that names its own map and front end (no profile)
OWN = """\
channels = 4
[bus.device.registers]
adc_address = 100
[bus.device.front_end]
kind = "low_side"
supply_v = 3.3
reference_ohm = 10000.0
adc_bits = 12
"""


def device(extra: str, source: Path = SOURCE) -> DeviceConfig:
    return parse_config(HEAD + extra, source=source).buses[0].devices[0]


def refusal(extra: str, source: Path = SOURCE) -> str:
    with pytest.raises(ConfigError) as err:
        device(extra, source)
    return str(err.value)


def values(items: Sequence[object]) -> str:
    return "[" + ", ".join(str(v) for v in items) + "]"


# --------------------------------------------------------------------------- shipped profiles
def test_the_shipped_profiles_are_listed_with_their_descriptions() -> None:
    shipped = builtin_profiles()
    assert list(shipped) == [
        "acme-at6x6", "dexhand-1062", "dfrobot-6x6", "generic-adc", "skin60-counts", "skin60-mn",
        "tactile-sim",
    ]  # fmt: skip
    assert shipped["acme-at6x6"] == "Acme Tactile AT-6x6, 36 cells, 12-bit low-side divider"
    assert shipped["tactile-sim"] == "tactile-gateway simulated array (docs/register-map.md)"
    assert all(shipped.values())


def test_acme_at6x6_gives_its_map_front_end_layout_and_checks() -> None:
    dev = device(ACME)
    assert dev.profile == "profile 'acme-at6x6'"
    assert dev.encoding == "adc" and dev.n_channels == 36 and len(dev.channels) == 36
    regs = dev.registers
    assert regs.adc_address == 32 and regs.table == "input"
    assert regs.clock is None  # no clock: the host clock times the samples
    assert regs.status_address is None and regs.force_reference_address is None
    assert regs.temperature_address is None
    assert dev.front_end == LowSideDivider(supply_v=3.3, reference_ohm=10000.0, adc_bits=12)
    assert dev.front_end.full_scale == 4095
    assert dev.layout == GridLayout(36, 6, 5.0, 5.0, "bottom-left", "row-major")
    assert dev.checks == DeviceChecks(
        (
            RegisterCheck("product id", "input", 0, 0x5447),
            RegisterCheck("channel count", "input", 8, 36),
        ),
        (("vendor_name", "Acme Tactile"), ("product_code", "AT-6x6")),
    )
    assert 0x5447 == 21575
    # bottom-left, row-major, 6 x 6 at 5 mm: ch00 bottom-left (0, 25), ch05 bottom-right
    # (25, 25), ch06 one row up (0, 20), ch35 top-right (25, 0)
    positions = {c.name: (c.x_mm, c.y_mm) for c in dev.channels}
    assert positions["ch00"] == (0.0, 25.0)
    assert positions["ch05"] == (25.0, 25.0)
    assert positions["ch06"] == (0.0, 20.0)
    assert positions["ch35"] == (25.0, 0.0)
    assert all(c.baseline_ohm is None for c in dev.channels)


def test_tactile_sim_gives_the_simulator_map_and_clock() -> None:
    dev = device('profile = "tactile-sim"\nchannels = 16\n')
    regs = dev.registers
    assert (regs.adc_address, regs.float_address, regs.status_address) == (100, 400, 16)
    assert regs.clock == DeviceClock(2, 4, 1e-3, "input")
    assert dev.front_end == Divider(supply_v=5.0, reference_ohm=10000.0, adc_bits=16)
    assert dev.checks == DeviceChecks(
        (RegisterCheck("channel count", "holding", 0, 16),), (("product_code", "TSA-SIM"),)
    )
    # no columns anywhere: ceil(sqrt(16)) = 4 columns, 2.5 mm
    assert dev.layout == GridLayout(16, 4, 2.5, 2.5, "top-left", "row-major")


def test_generic_adc_needs_the_address_and_reads_a_high_side_divider() -> None:
    message = refusal('profile = "generic-adc"\nchannels = 8\n')
    assert f"{DEV}.registers.adc_address: required key is missing" in message
    dev = device('profile = "generic-adc"\nchannels = 8\n[bus.device.registers]\nadc_address = 0\n')
    assert dev.registers.adc_address == 0 and dev.registers.clock is None
    assert dev.front_end == Divider(supply_v=3.3, reference_ohm=10000.0, adc_bits=12)
    assert not dev.checks


# --------------------------------------------------------------------------- overrides
def test_a_register_key_overrides_only_itself() -> None:
    dev = device(ACME + "[bus.device.registers]\nadc_address = 64\n")
    assert dev.registers.adc_address == 64
    assert dev.registers.clock is None and dev.registers.status_address is None
    assert dev.front_end == LowSideDivider(3.3, 10000.0, 12)  # the rest as the profile says


def test_a_layout_key_overrides_only_itself() -> None:
    dev = device(ACME + '[bus.device.layout]\norigin = "top-left"\n')
    assert dev.layout == GridLayout(36, 6, 5.0, 5.0, "top-left", "row-major")
    assert (dev.channels[0].x_mm, dev.channels[0].y_mm) == (0.0, 0.0)  # now the top-left cell
    assert (dev.channels[7].x_mm, dev.channels[7].y_mm) == (5.0, 5.0)  # row 1, column 1


def test_top_level_columns_and_pitch_override_the_profile_layout() -> None:
    dev = device(ACME + "columns = 4\n")
    # 36 channels on 4 columns: 9 rows; origin and pitch still the profile's
    assert dev.layout == GridLayout(36, 4, 5.0, 5.0, "bottom-left", "row-major")
    assert (dev.channels[0].x_mm, dev.channels[0].y_mm) == (0.0, 40.0)  # row 8 of 9, 8 x 5 mm
    dev = device(ACME + "pitch_mm = 2.0\n")
    assert dev.layout == GridLayout(36, 6, 2.0, 2.0, "bottom-left", "row-major")
    dev = device(ACME + "[bus.device.layout]\ncolumns = 9\n")
    assert dev.layout.columns == 9 and dev.layout.rows == 4


def test_a_front_end_of_the_same_kind_merges_key_by_key() -> None:
    dev = device(ACME + "[bus.device.front_end]\nreference_ohm = 4700.0\n")
    assert dev.front_end == LowSideDivider(supply_v=3.3, reference_ohm=4700.0, adc_bits=12)
    dev = device(ACME + '[bus.device.front_end]\nkind = "low_side"\nadc_bits = 10\n')
    assert dev.front_end == LowSideDivider(supply_v=3.3, reference_ohm=10000.0, adc_bits=10)


def test_a_front_end_of_another_kind_replaces_the_profile_table() -> None:
    # merged, the profile's supply_v and reference_ohm would be unknown keys of a transimpedance
    dev = device(
        ACME
        + '[bus.device.front_end]\nkind = "transimpedance"\nbias_v = 0.5\nfeedback_ohm = 100000.0\n'
        + "adc_reference_v = 3.3\nadc_bits = 12\n"
    )
    assert dev.front_end == Transimpedance(
        bias_v=0.5, feedback_ohm=100000.0, adc_bits=12, adc_reference_v=3.3
    )
    # high_side with a key left out: the profile's value is not taken over
    message = refusal(
        ACME + '[bus.device.front_end]\nkind = "high_side"\nreference_ohm = 4700.0\nadc_bits = 12\n'
    )
    assert f"{DEV}.front_end.supply_v: required key is missing" in message


def test_a_divider_table_replaces_the_profile_front_end() -> None:
    dev = device(ACME + "[bus.device.divider]\nsupply_v = 5.0\n")
    assert dev.front_end == Divider(supply_v=5.0, reference_ohm=10000.0, adc_bits=16)


def test_the_device_channel_count_wins_and_the_count_check_follows_it() -> None:
    dev = device(ACME + "channels = 12\n")
    assert dev.n_channels == 12 and dev.layout.rows == 2
    assert dev.checks.registers[1] == RegisterCheck("channel count", "input", 8, 12)


def test_checks_merge_key_by_key() -> None:
    dev = device(ACME + '[bus.device.checks]\nidentification = { product_code = "AT-6x6-B" }\n')
    # identification replaced as a whole key, the register checks kept from the profile
    assert dev.checks.identification == (("product_code", "AT-6x6-B"),)
    assert [c.what for c in dev.checks.registers] == ["product id", "channel count"]


def test_the_host_clock_overrides_a_profile_clock_and_a_clock_key_merges() -> None:
    assert device('profile = "tactile-sim"\nchannels = 4\nclock = "host"\n').registers.clock is None
    dev = device('profile = "tactile-sim"\nchannels = 4\n[bus.device.clock]\naddress = 10\n')
    assert dev.registers.clock == DeviceClock(10, 4, 1e-3, "input")  # registers and unit kept


# --------------------------------------------------------------------------- refusals
def test_an_unknown_profile_lists_the_shipped_ones_with_a_suggestion() -> None:
    message = refusal('profile = "acme-at6"\n')
    assert message == (
        f"{SOURCE}: {DEV}.profile: no profile 'acme-at6'; did you mean 'acme-at6x6'? "
        "(shipped profiles: acme-at6x6, dexhand-1062, dfrobot-6x6, generic-adc, skin60-counts, skin60-mn, "
        "tactile-sim; "
        "or the path of a profile file ending in .toml)"
    )
    message = refusal('profile = "zzzz"\n')
    assert (
        "no profile 'zzzz' (shipped profiles: acme-at6x6, dexhand-1062, dfrobot-6x6, generic-adc," in message
    )
    assert "did you mean" not in message


def test_a_profile_file_relative_to_the_config_file(tmp_path: Path) -> None:
    boards = tmp_path / "boards"
    boards.mkdir()
    (boards / "myboard.toml").write_text(
        'description = "my board"\nchannels = 4\n'
        "[registers]\nadc_address = 10\n"
        '[front_end]\nkind = "low_side"\nsupply_v = 5.0\nreference_ohm = 4700.0\nadc_bits = 10\n'
        '[layout]\ncolumns = 2\norigin = "top-right"\n'
        '[checks]\nchannel_count = { table = "input", address = 3 }\n',
        encoding="utf-8",
    )
    source = tmp_path / "gateway.toml"
    dev = device('profile = "boards/myboard.toml"\n', source)
    assert dev.profile == f"profile {str(boards / 'myboard.toml')!r}"
    assert dev.n_channels == 4 and dev.registers.adc_address == 10
    assert dev.front_end == LowSideDivider(supply_v=5.0, reference_ohm=4700.0, adc_bits=10)
    assert dev.layout == GridLayout(4, 2, 2.5, 2.5, "top-right", "row-major")
    assert dev.checks.registers == (RegisterCheck("channel count", "input", 3, 4),)
    # a name ending in .toml without a slash is a file too, beside the configuration
    (tmp_path / "flat.toml").write_text(
        (boards / "myboard.toml").read_text(encoding="utf-8"), encoding="utf-8"
    )
    assert device('profile = "flat.toml"\n', source).registers.adc_address == 10
    # missing file
    message = refusal('profile = "boards/nothere.toml"\n', source)
    assert f"{DEV}.profile: {boards / 'nothere.toml'} does not exist (device profile)" in message


def test_a_profile_file_with_an_unknown_key_is_named_in_the_message(tmp_path: Path) -> None:
    profile = tmp_path / "board.toml"
    profile.write_text("chanels = 4\n[registers]\nadc_address = 10\n", encoding="utf-8")
    message = refusal('profile = "board.toml"\n', tmp_path / "gateway.toml")
    assert message.startswith(f"{profile}: chanels: unknown key; did you mean 'channels'?")
    # a device's own keys are not a profile's
    profile.write_text('name = "x"\n', encoding="utf-8")
    assert refusal('profile = "board.toml"\n', tmp_path / "gateway.toml").startswith(
        f"{profile}: name: unknown key"
    )
    profile.write_text("channels = = 4\n", encoding="utf-8")
    assert refusal('profile = "board.toml"\n', tmp_path / "gateway.toml").startswith(
        f"{profile}: invalid TOML at line 1"
    )


def test_a_device_without_profile_or_value_address_is_told_to_name_one() -> None:
    message = refusal(
        'channels = 4\n[bus.device.front_end]\nkind = "low_side"\nsupply_v = 3.3\n'
        "reference_ohm = 10000.0\nadc_bits = 12\n"
    )
    assert f"{DEV}.registers.adc_address: required key is missing" in message
    assert "name a profile" in message
    message = refusal('channels = 4\nencoding = "float32"\n')
    assert f"{DEV}.registers.float_address: required key is missing" in message
    assert "name a profile" in message


def test_an_adc_device_without_a_front_end_is_refused() -> None:
    message = refusal("channels = 4\n[bus.device.registers]\nadc_address = 100\n")
    assert f"{DEV}.front_end: required key is missing" in message
    assert "low_side" in message  # the kinds are listed
    # a float32 device needs none (its values are ohm)
    dev = device('channels = 4\nencoding = "float32"\n[bus.device.registers]\nfloat_address = 400\n')
    assert dev.encoding == "float32"


# --------------------------------------------------------------------------- the clock
@pytest.mark.parametrize(
    ("clock", "expected"),
    [
        ('"host"', None),
        ('{ address = 2, registers = 4, unit = "ms" }', DeviceClock(2, 4, 1e-3, "input")),
        ('{ address = 7, registers = 1, unit = "s" }', DeviceClock(7, 1, 1.0, "input")),
        (
            '{ address = 7, registers = 2, unit = "us", table = "holding" }',
            DeviceClock(7, 2, 1e-6, "holding"),
        ),
        ("{ address = 7, registers = 2, tick_s = 0.01 }", DeviceClock(7, 2, 0.01, "input")),
    ],
)
def test_clock_values(clock: str, expected: DeviceClock | None) -> None:
    dev = device(f"clock = {clock}\n" + OWN)
    assert dev.registers.clock == expected
    if expected is not None:
        assert dev.registers.clock is not None
        assert dev.registers.clock.modulus == 2 ** (16 * expected.registers)


@pytest.mark.parametrize(
    ("clock", "key", "text"),
    [
        (
            '{ address = 2, registers = 3, unit = "ms" }',
            "clock.registers",
            "3 is not allowed; allowed: 1, 2, 4",
        ),
        (
            '{ address = 2, registers = 8, unit = "ms" }',
            "clock.registers",
            "8 is out of range; allowed: 1..4",
        ),
        (
            '{ address = 2, registers = 2, unit = "ms", tick_s = 0.001 }',
            "clock.tick_s",
            "give unit or tick_s, not both",
        ),
        ('{ address = 2, registers = 2, unit = "min" }', "clock.unit", "'min' is not allowed"),
        ("{ address = 2, registers = 2 }", "clock.unit", "required key is missing"),
        ('{ registers = 2, unit = "ms" }', "clock.address", "required key is missing"),
        ('{ address = 65535, registers = 2, unit = "ms" }', "clock.address", "allowed: 0..65534"),
        (
            '{ address = 2, registers = 2, unit = "ms", adress = 3 }',
            "clock.adress",
            "did you mean 'address'?",
        ),
        ("{ address = 2, registers = 2, tick_s = 0.0 }", "clock.tick_s", "out of range"),
        ("5", "clock", 'expected "host" or a table'),
        ('"device"', "clock", 'expected "host" or a table'),
    ],
)
def test_clock_refusals_name_the_key(clock: str, key: str, text: str) -> None:
    message = refusal(f"clock = {clock}\n" + OWN)
    assert f"{DEV}.{key}: " in message and text in message


def test_a_clock_overlapping_the_adc_block_is_refused() -> None:
    # ADC block 100..103 (4 channels), clock 102..103
    message = refusal('clock = { address = 102, registers = 2, unit = "ms" }\n' + OWN)
    assert "clock.address: the clock block 102..103 overlaps the adc block 100..103" in message
    assert "register blocks must not overlap" in message
    # the clock next to the block is fine
    dev = device('clock = { address = 98, registers = 2, unit = "ms" }\n' + OWN)
    assert dev.registers.clock == DeviceClock(98, 2, 1e-3)


def test_a_clock_added_over_a_profile_adc_block_names_the_clock_key() -> None:
    # acme's ADC block is 32..67 (36 channels from 32); the device adds a clock at 40..41. The
    # key to change is the one the device wrote, clock.address (registers.adc_address is the
    # profile's, not in this file)
    message = refusal(ACME + 'clock = { address = 40, registers = 2, unit = "ms" }\n')
    assert "overlaps" in message and "32..67" in message and "40..41" in message
    assert f"{DEV}.clock.address: " in message


# --------------------------------------------------------------------------- checks
def test_checks_are_parsed_in_order_with_their_defaults() -> None:
    dev = device(
        OWN
        + "[bus.device.checks]\n"
        + 'registers = [{ what = "firmware", table = "holding", address = 5, value = 0x0102 },'
        + " { address = 7, value = 1 }]\n"
        + "channel_count = { address = 9 }\n"
        + 'identification = { revision = "1.2", vendor_name = "X" }\n'
    )
    assert dev.checks.registers == (
        RegisterCheck("firmware", "holding", 5, 258),  # 0x0102 = 258
        RegisterCheck("register", "input", 7, 1),  # what and table default
        RegisterCheck("channel count", "holding", 9, 4),  # the channel count's table: holding
    )
    # identification in the order of IDENTIFICATION_FIELDS, not of the file
    assert dev.checks.identification == (("vendor_name", "X"), ("revision", "1.2"))


@pytest.mark.parametrize(
    ("checks", "key", "text"),
    [
        ("registers = [{ address = 5, value = 65536 }]", "checks.registers[0].value", "allowed: 0..65535"),
        ("registers = [{ address = 5 }]", "checks.registers[0].value", "required key is missing"),
        ("registers = [{ adress = 5, value = 1 }]", "checks.registers[0].adress", "did you mean 'address'?"),
        (
            'registers = [{ address = 5, value = 1, table = "coil" }]',
            "checks.registers[0].table",
            "not allowed",
        ),
        ("registers = { address = 5, value = 1 }", "checks.registers", "expected an array of tables"),
        ("channel_count = 8", "checks.channel_count", "expected a table"),
        ('identification = { vendor = "X" }', "checks.identification.vendor", "did you mean 'vendor_name'?"),
        ("identification = { product_code = 7 }", "checks.identification.product_code", "expected the text"),
        ("product = 1", "checks.product", "unknown key"),
    ],
)
def test_check_refusals_name_the_key(checks: str, key: str, text: str) -> None:
    message = refusal(OWN + f"[bus.device.checks]\n{checks}\n")
    assert f"{DEV}.{key}: " in message and text in message


# --------------------------------------------------------------------------- baselines
def test_baseline_counts_go_through_the_front_end() -> None:
    # low side, 12 bit, 10 kohm pull-up: r = 10k * c / (4095 - c)
    #   3895 -> 10k * 3895 / 200 = 194750 ohm
    #   3000 -> 10k * 3000 / 1095 = 27397.260... ohm
    #   2047.5 (half scale) -> 10k * 2047.5 / 2047.5 = 10 kohm
    #   4095 (full scale, the open level) -> inf: open at rest
    counts: list[object] = [3895] * 36
    counts[1], counts[2], counts[3] = 3000, 2047.5, 4095
    dev = device(ACME + f"baseline_counts = {values(counts)}\n")
    baselines = [c.baseline_ohm for c in dev.channels]
    assert baselines[0] == pytest.approx(194750.0, rel=1e-12)
    assert baselines[1] == pytest.approx(30_000_000.0 / 1095.0, rel=1e-12)
    assert baselines[1] == pytest.approx(27397.260274, rel=1e-9)
    assert baselines[2] == pytest.approx(10000.0, rel=1e-12)
    assert baselines[3] == math.inf
    assert all(b == pytest.approx(194750.0, rel=1e-12) for b in baselines[4:])


def test_baseline_ohm_is_taken_as_written() -> None:
    ohms: list[object] = [150000.0] * 36
    ohms[5] = "inf"
    dev = device(ACME + f"baseline_ohm = {values(ohms)}\n")
    assert [c.baseline_ohm for c in dev.channels] == [150000.0] * 5 + [math.inf] + [150000.0] * 30


@pytest.mark.parametrize(
    ("line", "key", "text"),
    [
        (
            f"baseline_counts = {values([3895] * 35)}",
            "baseline_counts",
            "expected an array of 36 numbers (one per channel, in index order), got 35 values",
        ),
        ("baseline_counts = 3895", "baseline_counts", "expected an array of 36 numbers"),
        (f"baseline_ohm = {values([1e5] * 37)}", "baseline_ohm", "got 37 values"),
        (
            f"baseline_counts = {values([3895] * 2 + ['nan'] + [3895] * 33)}",
            "baseline_counts[2]",
            "got float nan",
        ),
        (
            f"baseline_ohm = {values(['nan'] + [1e5] * 35)}",
            "baseline_ohm[0]",
            "(no baseline), got float nan",
        ),
        (f"baseline_ohm = {values([1e5] * 35 + ['true'])}", "baseline_ohm[35]", "got boolean true"),
        (f"baseline_ohm = {values([1e5] * 35 + [0.0])}", "baseline_ohm[35]", "allowed: (0, inf] ohm"),
        (f"baseline_ohm = {values([-1.0] + [1e5] * 35)}", "baseline_ohm[0]", "out of range"),
        (
            f"baseline_counts = {values([0] + [3895] * 35)}",  # the short level: 0 ohm
            "baseline_counts[0]",
            "0 counts is not an unloaded reading of this front end",
        ),
        (
            f"baseline_counts = {values([3895] * 35 + [5000])}",
            "baseline_counts[35]",
            "not an unloaded reading",
        ),
        (f"baseline_counts = {values([-3] + [3895] * 35)}", "baseline_counts[0]", "not an unloaded reading"),
    ],
)
def test_baseline_refusals_say_why(line: str, key: str, text: str) -> None:
    message = refusal(ACME + line + "\n")
    assert message.startswith(f"{SOURCE}: {DEV}.")
    assert key in message and text in message


def test_a_refused_baseline_value_is_named_by_its_key_path() -> None:
    # key paths elsewhere spell an array element as key[i] (checks.registers[0].value,
    # bus[0].device[0]); a quoted "baseline_counts[2]" would name a key of that literal name
    message = refusal(ACME + f"baseline_counts = {values([3895] * 2 + ['nan'] + [3895] * 33)}\n")
    assert (
        message
        == f'{SOURCE}: {DEV}.baseline_counts[2]: expected a number or "none" (no baseline), got float nan'
    )


def test_none_in_a_baseline_array_is_a_channel_without_a_baseline() -> None:
    """A partial tare writes "none" for the channels it did not zero: they keep no baseline (their
    idle reading stays guarded as no_zero), never inf (a baseline that lifts the guard)."""
    none, off = '"none"', '"off"'
    dev = device(ACME + f"baseline_counts = {values([3895] * 2 + [none] + [3895] * 33)}\n")
    assert dev.channels[2].baseline_ohm is None
    assert all(ch.baseline_ohm is not None for ch in dev.channels if ch.index != 2)
    # only that exact word: another string is refused, naming both spellings
    message = refusal(ACME + f"baseline_ohm = {values([1e5] * 35 + [off])}\n")
    assert message.endswith(
        "baseline_ohm[35]: expected a number or \"none\" (no baseline), got string 'off'"
    ), message


def test_both_baseline_spellings_are_refused() -> None:
    message = refusal(
        ACME + f"baseline_counts = {values([3895] * 36)}\nbaseline_ohm = {values([1e5] * 36)}\n"
    )
    assert f"{DEV}.baseline_ohm: give baseline_counts or baseline_ohm, not both" in message


def test_baseline_counts_of_a_float_device_are_refused() -> None:
    message = refusal(
        'profile = "tactile-sim"\nchannels = 4\nencoding = "float32"\nbaseline_counts = [1, 2, 3, 4]\n'
    )
    assert f"{DEV}.baseline_counts: counts need an ADC front end" in message
    dev = device(
        'profile = "tactile-sim"\nchannels = 4\nencoding = "float32"\nbaseline_ohm = [1, 2, 3, 4.5]\n'
    )
    assert [c.baseline_ohm for c in dev.channels] == [1.0, 2.0, 3.0, 4.5]


def test_a_calibration_file_gives_baselines_by_channel(tmp_path: Path) -> None:
    (tmp_path / "cal.toml").write_text(
        "[channel.ch03]\nbaseline_ohm = 150000.0\nr0_ohm = 190e3\n\n[channel.ch07]\nbaseline_ohm = 2e6\n",
        encoding="utf-8",
    )
    dev = device(ACME + 'calibration = "cal.toml"\n', tmp_path / "gateway.toml")
    by_name = {c.name: c for c in dev.channels}
    assert by_name["ch03"].baseline_ohm == 150000.0
    assert by_name["ch03"].params.r0_ohm == 190e3  # baseline_ohm is not a sensor parameter
    assert by_name["ch07"].baseline_ohm == 2e6
    assert by_name["ch07"].params == SensorParams()
    assert [c.name for c in dev.channels if c.baseline_ohm is not None] == ["ch03", "ch07"]


@pytest.mark.parametrize("value", ["0.0", "-5.0", "inf", '"high"'])
def test_a_calibration_baseline_out_of_range_is_refused(tmp_path: Path, value: str) -> None:
    cal = tmp_path / "cal.toml"
    cal.write_text(f"[channel.ch03]\nbaseline_ohm = {value}\n", encoding="utf-8")
    message = refusal(ACME + 'calibration = "cal.toml"\n', tmp_path / "gateway.toml")
    assert message.startswith(f"{cal}: channel.ch03.baseline_ohm: ")
    assert "allowed: (0, inf) ohm" in message
    assert f"(calibration file of {DEV}.calibration in {tmp_path / 'gateway.toml'})" in message


def test_a_key_after_a_table_header_is_named_in_the_profile_file(tmp_path: Path) -> None:
    # docs/profiles.md once printed clock = ... after [registers]: TOML puts it in that table
    profile = tmp_path / "board.toml"
    profile.write_text(
        'channels = 4\n[registers]\nadc_address = 0\nclock = { address = 10, registers = 2, unit = "ms" }\n'
    )
    message = refusal('profile = "board.toml"\n', tmp_path / "gateway.toml")
    assert message.startswith(f"{profile}: registers.clock: unknown key"), message


def test_the_public_map_profiles_read_their_frames_writes_and_checks() -> None:
    """dfrobot-6x6: counts at input 7, ids and count checked, nothing written; skin60-mn: force
    in mN by function 0x42, its mode written and read back at connect, a zero action."""
    board = device('profile = "dfrobot-6x6"\n')
    frame = board.registers.frame
    assert frame is not None and (frame.quantity, frame.table, frame.blocks[0].address) == (
        "counts",
        "input",
        7,
    )
    assert board.n_channels == 36 and board.registers.setup == () and board.registers.actions == ()
    assert [(c.address, c.value) for c in board.checks.registers] == [(0, 0x3343), (1, 0x3343), (43, 36)]
    skin = device('profile = "skin60-mn"\n')
    frame = skin.registers.frame
    assert frame is not None and frame.vendor is not None and frame.vendor.function_code == 0x42
    assert (frame.quantity, frame.unit, skin.encoding, skin.n_channels) == ("force", "mN", "output", 60)
    assert [(w.address, w.values, w.verify) for w in skin.registers.setup] == [
        (2, (1,), True),
        (5, (0,), True),
    ]
    assert dict(skin.registers.actions)["zero"][0].address == 3
