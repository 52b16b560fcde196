"""The comment-keeping editor as a library: what it writes, what it refuses, what it keeps."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from gateway.config import load_config
from gateway.config.editor import (
    ParameterSources,
    edit_channel,
    find_channel,
    flag_assignment,
    parse_assignment,
)
from gateway.errors import ConfigError

CONFIG = """\
# keep me
[[bus]]
name = "bench"   # the bench bus
kind = "tcp"
host = "127.0.0.1"

[[bus.device]]
name = "arr"
device_id = 1
profile = "tactile-sim"
channels = 4
model = { params = { e0_pa = 16e6 } }

[[bus.device.channel]]
index = 0
name = "tip"   # fingertip
params = { r0_ohm = 190e3 }  # calibration run 3
"""


@pytest.fixture
def config_file(tmp_path: Path) -> Path:
    path = tmp_path / "gateway.toml"
    path.write_text(CONFIG, encoding="utf-8")
    return path


def test_an_edit_changes_only_its_value_and_keeps_every_comment(config_file: Path) -> None:
    result = edit_channel(
        config_file, "tip", None, [parse_assignment("r0_ohm=2e5"), parse_assignment("x_mm=1.5")]
    )
    assert result.changed and result.changes == "r0_ohm = 2e5, x_mm = 1.5"
    text = config_file.read_text(encoding="utf-8")
    # the value changed in place; x_mm joined the entry; every other byte is as it was
    assert text == CONFIG.replace(
        "r0_ohm = 190e3 }  # calibration run 3\n", "r0_ohm = 2e5 }  # calibration run 3\nx_mm = 1.5"
    )
    channel = load_config(config_file).buses[0].devices[0].channel("tip")
    assert channel.params.r0_ohm == 2e5 and channel.x_mm == 1.5 and channel.params.e0_pa == 16e6


def test_a_channel_without_an_entry_gets_a_new_table(config_file: Path) -> None:
    edit_channel(config_file, "ch02", None, [flag_assignment(False)])
    text = config_file.read_text(encoding="utf-8")
    assert text.startswith(CONFIG)
    assert text[len(CONFIG) :].strip() == "[[bus.device.channel]]\nindex = 2\nenabled = false"
    assert not load_config(config_file).buses[0].devices[0].channels[2].enabled


@pytest.mark.parametrize(
    ("assignment", "message"),
    [
        ("r0_ohm=-5", "r0_ohm"),  # outside (0, inf)
        ("name=ch01", "duplicate channel name 'ch01'"),
        ("x_mm=1e9", "x_mm"),
    ],
)
def test_a_refused_edit_leaves_the_file_byte_identical(
    config_file: Path, assignment: str, message: str
) -> None:
    before = config_file.read_bytes()
    with pytest.raises(ConfigError, match=f"refused, .* is unchanged(.|\\n)*{re.escape(message)}"):
        edit_channel(config_file, "tip", None, [parse_assignment(assignment)])
    assert config_file.read_bytes() == before


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("x_m=1", "unknown key 'x_m'; did you mean 'x_mm'?"),
        ("enabled=maybe", "expected true or false"),
        ("x_mm=abc", "expected a number"),
        ("x_mm=nan", "NaN is not allowed"),
        ("effects=creep,creeep", "did you mean 'creep'"),
        ("no-equals-sign", "is not KEY=VALUE"),
    ],
)
def test_bad_assignments_say_why(text: str, message: str) -> None:
    with pytest.raises(ConfigError, match=re.escape(message)):
        parse_assignment(text)


def test_finding_a_channel_suggests_the_closest_name(config_file: Path) -> None:
    config = load_config(config_file)
    assert find_channel(config, "tip", None).channel.index == 0
    with pytest.raises(ConfigError, match=re.escape("no channel 'tpi'; did you mean 'tip'?")):
        find_channel(config, "tpi", None)


def test_parameter_sources_name_where_each_value_comes_from(config_file: Path) -> None:
    config = load_config(config_file)
    target = find_channel(config, "tip", None)
    sources = ParameterSources(config_file.read_text(encoding="utf-8"), 0, 0, target.device).of(
        target.channel
    )
    assert sources["r0_ohm"] == "channel" and sources["e0_pa"] == "device" and sources["e1_pa"] == "default"


@settings(max_examples=30, deadline=None)
@given(st.floats(min_value=-1e4, max_value=1e4, allow_nan=False))
def test_any_position_in_range_is_written_and_read_back(
    tmp_path_factory: pytest.TempPathFactory, x: float
) -> None:
    path = tmp_path_factory.mktemp("edit") / "gateway.toml"
    path.write_text(CONFIG, encoding="utf-8")
    edit_channel(path, "tip", None, [parse_assignment(f"x_mm={x!r}")])
    assert load_config(path).buses[0].devices[0].channel("tip").x_mm == x


TEMPLATE = """
# A second bus: uncomment to use it.
# [[bus]]
# name = "line"
# kind = "tcp"
# host = "127.0.0.2"
#
# [[bus.device]]
# name = "other"
# device_id = 2
# profile = "tactile-sim"
# channels = 4
"""


def test_a_new_channel_entry_goes_above_a_commented_template(config_file: Path) -> None:
    """Appended after the template, the entry would move to the template's device once a
    user uncomments it, as the example file invites."""
    config_file.write_text(CONFIG + TEMPLATE, encoding="utf-8")
    edit_channel(config_file, "ch03", None, [parse_assignment("name=thumb")])
    text = config_file.read_text(encoding="utf-8")
    assert text.index('name = "thumb"') < text.index("# A second bus")
    assert text.endswith(TEMPLATE.rstrip("\n") + "\n\n") or text.endswith(TEMPLATE)
    uncommented = re.sub(r"(?m)^# ?(?=\[|\w+ =)", "", text)
    config_file.write_text(uncommented, encoding="utf-8")
    config = load_config(config_file)
    first, second = (bus.devices[0] for bus in config.buses)
    assert first.channels[3].name == "thumb" and [c.name for c in second.channels] == [
        f"ch{i:02d}" for i in range(4)
    ]


def test_a_read_only_configuration_is_not_replaced(config_file: Path) -> None:
    config_file.chmod(0o444)
    before = config_file.read_bytes()
    with pytest.raises(ConfigError, match=r"is read-only \(mode 0444\); refusing to replace it"):
        edit_channel(config_file, "tip", None, [parse_assignment("x_mm=3")])
    assert config_file.read_bytes() == before
    assert oct(config_file.stat().st_mode & 0o777) == "0o444"


def test_a_new_key_goes_above_a_commented_example_at_the_end_of_its_table(tmp_path: Path) -> None:
    text = CONFIG.replace(
        "params = { r0_ohm = 190e3 }  # calibration run 3\n",
        "# params = { r0_ohm = 190000.0 }   # an example, commented out\n\n"
        "[[bus.device.channel]]\nindex = 1\n",
    )
    path = tmp_path / "gateway.toml"
    path.write_text(text, encoding="utf-8")
    edit_channel(path, "tip", None, [flag_assignment(False)])
    new_text = path.read_text(encoding="utf-8")
    lines = new_text.splitlines()
    flag = lines.index("enabled = false")
    example = next(i for i, line in enumerate(lines) if line.startswith("# params"))
    assert lines[flag - 1] == 'name = "tip"   # fingertip'
    assert flag < example, new_text
    assert lines[example + 1 : example + 3] == ["", "[[bus.device.channel]]"]
