"""``install_calibration`` (``calibrate --install``): a device's configuration names a
calibration file, every comment kept, atomically; refusals leave the file as it was."""

from __future__ import annotations

from pathlib import Path

import pytest

from gateway.config import load_config
from gateway.config.install import install_calibration
from gateway.errors import ConfigError
from gateway.model import PAPER_EFFECTS, SensorParams

CONFIG = """\
# Lab gateway: keep this comment.
[[bus]]
name = "bench"      # the bench bus
kind = "tcp"
host = "127.0.0.1"
port = 5020

[[bus.device]]
name = "array1"     # left hand
device_id = 1
profile = "tactile-sim"
channels = 4
# calibration = "old.toml"   # a template line

[bus.device.model]
# tunneling is always on
effects = ["tunneling", "contact", "creep"]   # the paper's

[bus.device.model.params]
r0_ohm = 200000.0   # the default, written out
e1_pa = 2e8         # every channel's

[[bus.device.channel]]
index = 0
name = "tip"        # fingertip
params = { r0_ohm = 190000.0 }  # set by hand before the calibration

[[bus.device]]
name = "array2"
device_id = 2
profile = "tactile-sim"
channels = 4
"""
CAL = """\
[meta]
effects = ["tunneling", "contact", "creep", "hysteresis"]

[channel.tip]
r0_ohm = 187500.0
"""


@pytest.fixture
def files(tmp_path: Path) -> tuple[Path, Path]:
    config = tmp_path / "lab" / "gateway.toml"
    config.parent.mkdir()
    config.write_text(CONFIG)
    cal = tmp_path / "cals" / "cal.toml"
    cal.parent.mkdir()
    cal.write_text(CAL)
    return config, cal


def _comments(text: str) -> list[str]:
    return [line[line.index("#") :] for line in text.splitlines() if "#" in line]


def test_install_with_replace_overrides_round_trip(files: tuple[Path, Path]) -> None:
    config, cal = files
    done = install_calibration(config, cal, "array1", replace_overrides=True)
    assert done.changed and done.previous is None and done.calibration == "../cals/cal.toml"
    text = config.read_text()
    assert 'calibration = "../cals/cal.toml"' in text
    # the contradicting keys are gone with their comments; every other comment is kept
    dropped = {(c.where, c.config_value) for c in done.dropped}
    assert dropped == {
        ("bus[0].device[0].channel[0].params.r0_ohm", 190000.0),
        ("bus[0].device[0].model.params.r0_ohm", 200000.0),
        ("bus[0].device[0].model.effects", PAPER_EFFECTS),
    }
    gone = {"# set by hand before the calibration", "# the default, written out", "# the paper's"}
    assert _comments(text) == [c for c in _comments(CONFIG) if c not in gone]
    assert "e1_pa = 2e8" in text and "params = {" not in text
    # the configuration now loads with the calibration: the tip reads its values and effects
    dev = load_config(config).buses[0].devices[0]
    assert dev.calibration == cal
    tip = dev.channel("tip")
    assert tip.params == SensorParams(r0_ohm=187500.0, e1_pa=2e8)
    assert tip.effects == ("tunneling", "contact", "creep", "hysteresis")
    assert (
        dev.channel("ch01").params == SensorParams(e1_pa=2e8) and dev.channel("ch01").effects == PAPER_EFFECTS
    )
    assert any(
        "dropped bus[0].device[0].channel[0].params.r0_ohm = 190000.0" in line for line in done.lines()
    )
    # a second install changes nothing
    again = install_calibration(config, cal, "array1")
    assert not again.changed and config.read_text() == text


def test_contradicting_keys_are_listed_and_nothing_is_written(files: tuple[Path, Path]) -> None:
    config, cal = files
    with pytest.raises(ConfigError) as info:
        install_calibration(config, cal, "array1")
    message = str(info.value)
    assert message.startswith(f"refused, {config} is unchanged: ")
    # every key that would be dropped, the device's r0_ohm too (uncovered once the channel's is gone)
    assert "channel[0].params.r0_ohm = 190000.0 in the config, 187500.0 in the calibration" in message
    assert "model.params.r0_ohm = 200000.0 in the config, 187500.0 in the calibration" in message
    assert 'model.effects = ["tunneling", "contact", "creep"] in the config' in message
    assert "--replace-overrides" in message
    assert config.read_text() == CONFIG


def test_a_device_key_that_other_channels_need_is_not_dropped(files: tuple[Path, Path]) -> None:
    config, cal = files
    text = CONFIG.replace("r0_ohm = 200000.0   # the default", "r0_ohm = 150000.0   # not the default")
    config.write_text(text)
    with pytest.raises(ConfigError, match=r"dropping the device's r0_ohm would change channel ch01"):
        install_calibration(config, cal, "array1", replace_overrides=True)
    assert config.read_text() == text


def test_an_existing_calibration_is_replaced_and_named_in_the_report(files: tuple[Path, Path]) -> None:
    config, cal = files
    text = CONFIG.replace(
        '# calibration = "old.toml"   # a template line', 'calibration = "old.toml"  # 2024'
    )
    text = text.replace("params = { r0_ohm = 190000.0 }  # set by hand before the calibration\n", "")
    text = text.replace('effects = ["tunneling", "contact", "creep"]   # the paper\'s\n', "")
    text = text.replace("r0_ohm = 200000.0   # the default, written out\n", "")
    (config.parent / "old.toml").write_text("[channel.tip]\nr0_ohm = 1e5\n")
    config.write_text(text)
    done = install_calibration(config, cal, "array1")
    assert done.previous == "old.toml" and done.dropped == ()
    assert 'calibration = "../cals/cal.toml"  # 2024' in config.read_text()  # the comment stays
    assert load_config(config).buses[0].devices[0].channel("tip").params.r0_ohm == 187500.0


@pytest.mark.parametrize(
    ("device", "expected"),
    [
        ("array3", r"no device 'array3'; did you mean 'array2'\? \(devices: array1, array2\)"),
        (None, r"2 devices \(array1, array2\): choose one with --device NAME"),
    ],
)
def test_an_unknown_or_unnamed_device_is_refused(
    files: tuple[Path, Path], device: str | None, expected: str
) -> None:
    config, cal = files
    with pytest.raises(ConfigError, match=expected):
        install_calibration(config, cal, device, replace_overrides=True)
    assert config.read_text() == CONFIG


def test_a_file_that_is_not_a_gateway_configuration_is_refused(files: tuple[Path, Path]) -> None:
    config, cal = files
    with pytest.raises(ConfigError, match=r"unchanged: a calibration file \(no \[\[bus\]\] table\)"):
        install_calibration(cal, cal, "array1")
    other = config.parent / "notes.toml"
    other.write_text("[server]\nport = 1\n")
    with pytest.raises(ConfigError, match=r"unchanged: not a gateway configuration \(no \[\[bus\]\] table\)"):
        install_calibration(other, cal, "array1")
    other.write_text("not = toml = at all\n")
    with pytest.raises(ConfigError, match=r"not a gateway configuration \(not TOML"):
        install_calibration(other, cal, "array1")
    assert cal.read_text() == CAL


def test_a_calibration_the_device_refuses_is_not_installed(files: tuple[Path, Path]) -> None:
    config, cal = files
    cal.write_text("[channel.thumb]\nr0_ohm = 1e5\n")
    with pytest.raises(
        ConfigError, match=r"unchanged: with this calibration the configuration is invalid:\n.*thumb"
    ):
        install_calibration(config, cal, "array1", replace_overrides=True)
    assert config.read_text() == CONFIG
