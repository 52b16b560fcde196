"""A record's channel count is bounded, and messages that name channels stay short (issue 33 §9).

A 21.7 MB record of 1.2 million one-row channels took 2.26 GB of memory and ended in a 24 MB
one-line error listing every channel. The reader now refuses the first channel past
``MAX_RECORD_CHANNELS``, and every message that names a record's channels shows a few.
"""

from __future__ import annotations

from pathlib import Path

import pytest
from click.testing import CliRunner

from gateway.analysis.records import MAX_RECORD_CHANNELS, names_text, parse_record
from gateway.cli import main
from gateway.errors import RecordError

#: A message naming channels stays under this many characters, however many there are.
SHORT = 400


def one_row_channels(n: int, name_chars: int = 8) -> str:
    """A record of ``n`` channels of one row each, names ``name_chars`` long."""
    rows = "".join(f"{k},{'c' * max(name_chars - 7, 1)}{k:07d},1000.0\n" for k in range(n))
    return "time_s,channel,resistance_ohm\n" + rows


def test_the_limit_is_stated_and_generous_for_a_gateway() -> None:
    # a device has at most 256 channels; a record of 16 such devices is read
    assert MAX_RECORD_CHANNELS == 4096


def test_a_record_at_the_limit_is_read() -> None:
    record = parse_record(one_row_channels(MAX_RECORD_CHANNELS))
    assert len(record.channels) == MAX_RECORD_CHANNELS


def test_the_first_channel_past_the_limit_is_refused_naming_its_line() -> None:
    with pytest.raises(RecordError) as info:
        parse_record(one_row_channels(MAX_RECORD_CHANNELS + 1), Path("many.csv"))
    message = str(info.value)
    # the header is line 1, channel k on line k + 2: the 4097th channel on line 4098
    assert message.startswith(f"many.csv:{MAX_RECORD_CHANNELS + 2}: ")
    assert f"more than {MAX_RECORD_CHANNELS} channels" in message and len(message) < SHORT


def test_a_record_of_a_million_channels_stops_at_the_limit() -> None:
    # the rows past the limit are not read: the refusal names line 4098, not the last line
    with pytest.raises(RecordError, match=rf"^<record>:{MAX_RECORD_CHANNELS + 2}: "):
        parse_record(one_row_channels(200_000))


def test_names_text_shows_a_few_names_and_counts_the_rest() -> None:
    assert names_text([]) == "none"
    assert names_text(["a", "b"]) == "a, b"
    many = [f"ch{k}" for k in range(100)]
    assert names_text(many) == "ch0, ch1, ch2, ch3, ch4, ch5, ch6, ch7 and 92 more"
    long = ["x" * 10_000, "y"]
    text = names_text(long)
    assert len(text) < 100 and text.endswith(", y") and "..." in text


def test_a_record_of_many_long_named_channels_gives_a_short_message() -> None:
    record = parse_record(one_row_channels(MAX_RECORD_CHANNELS, name_chars=200))
    with pytest.raises(RecordError) as info:
        record.channel()
    assert len(str(info.value)) < SHORT and f"{MAX_RECORD_CHANNELS} channels" in str(info.value)
    with pytest.raises(RecordError) as info:
        record.channel("nope")
    assert len(str(info.value)) < SHORT


def test_apply_on_a_record_past_the_limit_exits_with_a_short_message(tmp_path: Path) -> None:
    cal, record = tmp_path / "cal.toml", tmp_path / "run.csv"
    cal.write_text('[line."c1"]\nslope_s_per_n = 1e-5\nintercept_s = 0.0\n', encoding="utf-8")
    record.write_text(one_row_channels(MAX_RECORD_CHANNELS + 10, name_chars=200), encoding="utf-8")
    result = CliRunner().invoke(main, ["apply", str(cal), str(record), "--out", str(tmp_path / "o.csv")])
    assert result.exit_code == 2 and "channels" in result.output
    assert len(result.output) < SHORT + 400, result.output[:600]


def test_apply_at_the_limit_names_a_few_unmapped_channels(tmp_path: Path) -> None:
    # was a 1.67 MB message listing all 4,096 names of 200 characters, twice
    cal, record = tmp_path / "cal.toml", tmp_path / "run.csv"
    cal.write_text('[line."c1"]\nslope_s_per_n = 1e-5\nintercept_s = 0.0\n', encoding="utf-8")
    record.write_text(one_row_channels(MAX_RECORD_CHANNELS, name_chars=200), encoding="utf-8")
    result = CliRunner().invoke(main, ["apply", str(cal), str(record), "--out", str(tmp_path / "o.csv")])
    assert result.exit_code == 2 and "no calibration table" in result.output
    assert f"and {MAX_RECORD_CHANNELS - 8} more" in result.output
    assert len(result.output) < 2 * SHORT + 400, len(result.output)
