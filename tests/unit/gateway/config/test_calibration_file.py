"""The calibration file has one owner: ``CalibrationFile.to_toml`` writes what
``load_calibration`` (the gateway's own reading of a device's ``calibration``) reads back."""

from __future__ import annotations

import math
import tomllib
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from gateway.config import parse_config
from gateway.config.calibration_file import (
    CalibrationFile,
    ChannelCalibration,
    ConversionTable,
    check_calibration_file,
    load_calibration,
    set_table_values,
)
from gateway.config.tables import Context
from gateway.errors import ConfigError
from gateway.model.conversion import CONVERSION_KINDS
from gateway.model.effects import EFFECT_NAMES, parse_effects
from gateway.model.params import PARAMETER_RANGES

#: Text a record path or channel name may hold: quotes, backslashes, newlines, control and
#: non-ASCII characters (no surrogates: TOML is UTF-8).
TEXT = st.text(st.characters(exclude_categories=["Cs"]), max_size=12)
AWKWARD = st.sampled_from(['a"b', "back\\slash", "two\nlines", "tab\tcr\r", "ünï — 测", "\x00\x7f", ""])
NAMES = st.one_of(AWKWARD, TEXT)
FINITE = st.floats(allow_nan=False, allow_infinity=False)
NUMBER = st.one_of(st.floats(allow_nan=False), st.sampled_from([0.0, -0.0, 5e-324, 1.7976931348623157e308]))


def _in_range(name: str) -> st.SearchStrategy[float]:
    r = PARAMETER_RANGES[name]
    return st.floats(
        min_value=r.low,
        max_value=r.high,
        exclude_min=not r.low_inclusive,
        exclude_max=not r.high_inclusive,
        allow_nan=False,
    )


PARAMS = st.lists(st.sampled_from(sorted(PARAMETER_RANGES)), unique=True, max_size=5).flatmap(
    lambda names: st.fixed_dictionaries({n: _in_range(n) for n in names})
)


@st.composite
def _calibrated_range(draw: st.DrawFn) -> tuple[float, float]:
    low = draw(st.floats(min_value=0.0, max_value=1e300, allow_nan=False))
    high = draw(st.one_of(st.just(math.inf), st.floats(min_value=low, max_value=math.inf, exclude_min=True)))
    return low, high


CHANNELS = st.builds(
    ChannelCalibration,
    PARAMS,
    st.none() | st.floats(min_value=0.0, max_value=1e308, exclude_min=True),
    st.none() | _calibrated_range(),
    st.fixed_dictionaries({}, optional={"": st.tuples(NAMES)}),
)
VALUE = st.one_of(
    NUMBER, st.integers(-(2**63), 2**63 - 1), NAMES, st.booleans(), st.lists(NUMBER, max_size=4)
)
CONVERSIONS = st.builds(
    ConversionTable, st.sampled_from(CONVERSION_KINDS), st.dictionaries(NAMES, VALUE, max_size=4)
)
FILES = st.builds(
    CalibrationFile,
    st.dictionaries(NAMES, CHANNELS, max_size=3),
    st.dictionaries(NAMES, CONVERSIONS, max_size=3),
    st.none() | NAMES,
    # [meta] effects as the reader gives them back: valid names, canonical order
    st.none() | st.lists(st.sampled_from(EFFECT_NAMES), max_size=4).map(parse_effects),
    st.lists(NAMES, max_size=2).map(tuple),
    st.lists(NAMES, max_size=2).map(tuple),
)


def _same(a: object, b: object) -> bool:
    """Equal, with -0.0 and 0.0 told apart (``==`` does not)."""
    if isinstance(a, float) and isinstance(b, float):
        return a == b and math.copysign(1.0, a) == math.copysign(1.0, b)
    if isinstance(a, list | tuple) and isinstance(b, list | tuple):
        return len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b, strict=True))
    return type(a) is type(b) and a == b


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(FILES)
def test_a_calibration_file_reads_back_as_written(tmp_path: Path, cal: CalibrationFile) -> None:
    path = tmp_path / "cal.toml"
    path.write_text(cal.to_toml(), encoding="utf-8")
    back = load_calibration(path, [*cal.channels, *cal.conversions])
    assert back == cal
    assert back.record == cal.record and back.effects == cal.effects
    for name, table in cal.conversions.items():  # floats exact, ints stay ints, -0.0 stays -0.0
        assert all(_same(table.values[k], back.conversions[name].values[k]) for k in table.values)
    # the file groups the conversion tables by kind ([line], [lookup], [curve]), and so reads them
    assert set(back.channel_names()) == set(cal.channel_names())
    assert (
        back.to_toml()
        == CalibrationFile(back.channels, back.conversions, back.record, back.effects).to_toml()
    )
    if cal.channels or cal.conversions or cal.record is not None or cal.effects is not None:
        assert check_calibration_file(path) == cal


def test_a_record_path_with_quotes_backslashes_newlines_and_non_ascii_is_escaped(tmp_path: Path) -> None:
    record = 'C:\\bench "run 2"\nsecond line/ünï.csv'
    cal = CalibrationFile(
        {"tip": ChannelCalibration({"r0_ohm": 1234.5}, 900.0, (0.5, math.inf))},
        {"tip": ConversionTable("line", {"slope_s_per_n": 2e-5, "intercept_s": -1e-6})},
        record=record,
        effects=("tunneling",),
        header=("from " + record,),
        meta_comments=("a note\nwith a newline",),
    )
    text = cal.to_toml()
    data = tomllib.loads(text)
    assert data["meta"]["record"] == record
    assert '[channel."tip"]' in text and '[line."tip"]' in text and "calibrated_max_n = inf" in text
    assert "# a note\\nwith a newline" in text  # a comment stays one line
    path = tmp_path / "cal.toml"
    path.write_text(text, encoding="utf-8")
    assert load_calibration(path) == cal


def test_the_gateway_reads_a_written_file_with_its_messages(tmp_path: Path) -> None:
    cal = tmp_path / "cal.toml"
    cal.write_text(
        CalibrationFile(
            {"tip": ChannelCalibration({"r0_ohm": 5000.0}, calibrated_range_n=(0.2, 8.0))}
        ).to_toml()
    )
    device = parse_config(_config(cal), tmp_path / "gateway.toml").buses[0].devices[0]
    tip = device.channels[0]
    assert tip.params.r0_ohm == 5000.0 and tip.calibrated_range_n == (0.2, 8.0)
    # a table naming no channel of the device: the file, the key path, and what named the file
    cal.write_text(CalibrationFile({"tap": ChannelCalibration({"r0_ohm": 5000.0})}).to_toml())
    with pytest.raises(ConfigError) as err:
        parse_config(_config(cal), tmp_path / "gateway.toml")
    assert f"{cal}: channel.tap: no channel 'tap' in this device" in str(err.value)
    assert "(calibration file of bus[0].device[0].calibration in" in str(err.value)
    with pytest.raises(ConfigError, match="does not exist"):
        load_calibration(tmp_path / "none.toml", ["tip"], named_at=(Context(tmp_path / "g.toml"), "k"))


def test_a_gateway_configuration_is_not_a_calibration_file(tmp_path: Path) -> None:
    config = tmp_path / "gateway.toml"
    config.write_text(_config(tmp_path / "cal.toml"))
    with pytest.raises(ConfigError, match="bus: not a table of a calibration file"):
        check_calibration_file(config)
    bad = tmp_path / "bad.toml"
    bad.write_text('[channel."tip"]\nr0_ohm = -1.0\n')
    with pytest.raises(ConfigError, match=r"channel\.tip\.r0_ohm: parameter r0_ohm = -1.0"):
        check_calibration_file(bad)


def test_set_table_values_changes_those_values_and_keeps_the_rest() -> None:
    text = '# head\n[curve."a b"]  # by hand\nkind = "line"\ngain = 1.0 # kept\n\n[meta]\nrecord = "x"\n'
    new = set_table_values(text, "curve", {"a b": {"gain": 0.5, "offset_n": -0.25}})
    assert new.splitlines()[:4] == [
        "# head",
        '[curve."a b"]  # by hand',
        'kind = "line"',
        "gain = 0.5 # kept",
    ]
    assert tomllib.loads(new)["curve"]["a b"] == {"kind": "line", "gain": 0.5, "offset_n": -0.25}
    with pytest.raises(KeyError):
        set_table_values(text, "curve", {"c": {"gain": 2.0}})


def _config(cal: Path) -> str:
    return f"""
[[bus]]
name = "bench"
kind = "tcp"
host = "127.0.0.1"
port = 5020
[[bus.device]]
name = "array1"
device_id = 1
profile = "tactile-sim"
channels = 2
calibration = "{cal}"
[[bus.device.channel]]
index = 0
name = "tip"
"""
