"""A calibrated channel is read with the calibration's parameters and ``[meta] effects``; a
configuration key that contradicts them is refused, naming both values, unless the
configuration says it overrides them (``override`` / ``override_calibration``)."""

from __future__ import annotations

import tomllib
from pathlib import Path

import pytest
from config_texts import with_device

from gateway.config import load_config
from gateway.config.calibration_file import calibrated_device, load_calibration
from gateway.config.device import device_overrides
from gateway.config.overrides import CalibrationConflictError
from gateway.config.schema import DeviceConfig
from gateway.config.tables import Context
from gateway.errors import ConfigError
from gateway.model import PAPER_EFFECTS, SensorParams
from gateway.runtime.processor import DeviceProcessor

HYSTERESIS = ("tunneling", "contact", "creep", "hysteresis")
CAL = """\
[meta]
effects = ["tunneling", "contact", "creep", "hysteresis"]

[channel.tip]
r0_ohm = 187500.0
e0_pa = 14e6
"""
TIP = '[[bus.device.channel]]\nindex = 0\nname = "tip"\n'


def _load(tmp_path: Path, device_keys: str, cal: str = CAL) -> DeviceConfig:
    (tmp_path / "cal.toml").write_text(cal)
    config = tmp_path / "gateway.toml"
    config.write_text(with_device('calibration = "cal.toml"\n' + device_keys))
    return load_config(config).buses[0].devices[0]


def _refusal(tmp_path: Path, device_keys: str, cal: str = CAL) -> str:
    with pytest.raises(CalibrationConflictError) as info:
        _load(tmp_path, device_keys, cal)
    return str(info.value)


def test_a_calibration_with_hysteresis_reads_its_channel_with_hysteresis(tmp_path: Path) -> None:
    dev = _load(tmp_path, TIP)
    tip, other = dev.channel("tip"), dev.channel("ch01")
    assert tip.effects == HYSTERESIS and tip.params == SensorParams(r0_ohm=187500.0, e0_pa=14e6)
    assert other.effects == PAPER_EFFECTS and other.params == SensorParams()  # no table: the device's
    # the runtime's physical model of the tip has hysteresis, the other channels' not
    groups = {
        tuple(ks): model.effects for ks, model in DeviceProcessor(dev, bus="b", poll_interval_s=1.0).groups
    }
    assert groups[(0,)] == HYSTERESIS
    assert all(effects == PAPER_EFFECTS for ks, effects in groups.items() if ks != (0,))


def test_a_file_without_meta_effects_leaves_the_device_effects(tmp_path: Path) -> None:
    cal = "[channel.tip]\nr0_ohm = 187500.0\n"
    dev = _load(tmp_path, TIP + '[bus.device.model]\neffects = ["tunneling", "leakage"]\n', cal)
    assert dev.channel("tip").effects == ("tunneling", "leakage")


def test_meta_effects_equal_to_the_config_are_no_contradiction(tmp_path: Path) -> None:
    # listed in another order: the same effects
    keys = TIP + '[bus.device.model]\neffects = ["hysteresis", "creep", "contact"]\n'
    keys += "[bus.device.model.params]\nr0_ohm = 187500.0\n"
    dev = _load(tmp_path, keys)
    assert dev.channel("tip").effects == HYSTERESIS and dev.channel("tip").params.r0_ohm == 187500.0


def test_a_channel_param_that_contradicts_names_both_values(tmp_path: Path) -> None:
    message = _refusal(tmp_path, TIP + "params = { r0_ohm = 190000.0 }\n")
    config, cal = tmp_path / "gateway.toml", tmp_path / "cal.toml"
    assert message.startswith(f"{config}: bus[0].device[0].calibration: 1 key of the config contradicts")
    assert (
        "channel tip: bus[0].device[0].channel[0].params.r0_ohm = 190000.0 in the config, "
        f"187500.0 in the calibration ({cal} [channel.tip] r0_ohm)"
    ) in message
    assert 'override = ["r0_ohm"] in the channel' in message and "override_calibration" not in message


def test_device_params_and_effects_that_contradict_name_both_values(tmp_path: Path) -> None:
    keys = TIP + '[bus.device.model]\neffects = ["tunneling", "contact", "creep"]\n'
    keys += "[bus.device.model.params]\nr0_ohm = 150000.0\nforce_max_n = 5.0\n"
    message = _refusal(tmp_path, keys)
    cal = tmp_path / "cal.toml"
    assert "2 keys of the config contradict" in message
    assert (
        f"bus[0].device[0].model.params.r0_ohm = 150000.0 in the config, 187500.0 in the calibration "
        f"({cal} [channel.tip] r0_ohm)"
    ) in message
    assert (
        'bus[0].device[0].model.effects = ["tunneling", "contact", "creep"] in the config, '
        f'["tunneling", "contact", "creep", "hysteresis"] in the calibration ({cal} [meta] effects)'
    ) in message
    assert "force_max_n" not in message  # the calibration does not set it: the device's is read
    assert 'override_calibration = ["effects", "r0_ohm"] in [bus.device.model]' in message
    with pytest.raises(CalibrationConflictError) as info:
        _load(tmp_path, keys)
    found = {(c.key, c.level, c.config_value, c.calibrated_value) for c in info.value.contradictions}
    assert found == {
        ("r0_ohm", "device", 150000.0, 187500.0),
        ("effects", "device", PAPER_EFFECTS, HYSTERESIS),
    }


def test_a_channel_effects_list_that_contradicts_is_refused(tmp_path: Path) -> None:
    message = _refusal(tmp_path, TIP + 'effects = ["tunneling"]\n')
    assert 'bus[0].device[0].channel[0].effects = ["tunneling"] in the config' in message
    assert "[meta] effects" in message and 'override = ["effects"]' in message


def test_the_channel_own_key_is_the_channel_contradiction_not_the_device(tmp_path: Path) -> None:
    # the channel sets r0_ohm itself and overrides: the device's r0_ohm takes no part in it
    keys = TIP + 'params = { r0_ohm = 190000.0 }\noverride = ["r0_ohm"]\n'
    keys += "[bus.device.model.params]\nr0_ohm = 150000.0\n"
    dev = _load(tmp_path, keys)
    assert dev.channel("tip").params.r0_ohm == 190000.0
    assert dev.channel("ch01").params.r0_ohm == 150000.0


def test_explicit_overrides_are_read_and_listed(tmp_path: Path) -> None:
    keys = TIP + 'params = { r0_ohm = 190000.0 }\noverride = ["r0_ohm"]\n'
    keys += '[bus.device.model]\neffects = ["tunneling", "contact", "creep"]\n'
    keys += 'override_calibration = ["effects", "e0_pa"]\n'
    keys += "[bus.device.model.params]\ne0_pa = 15e6\n"
    dev = _load(tmp_path, keys)
    tip = dev.channel("tip")
    assert (tip.params.r0_ohm, tip.params.e0_pa, tip.effects) == (190000.0, 15e6, PAPER_EFFECTS)
    config = tmp_path / "gateway.toml"
    raw = tomllib.loads(config.read_text())["bus"][0]["device"][0]
    found = device_overrides(Context(config), "bus[0].device[0]", raw)
    listed = {(c.channel, c.key, c.level, c.config_value, c.calibrated_value) for c in found}
    assert listed == {
        ("tip", "r0_ohm", "channel", 190000.0, 187500.0),
        ("tip", "e0_pa", "device", 15e6, 14e6),
        ("tip", "effects", "device", PAPER_EFFECTS, HYSTERESIS),
    }
    assert all(c.overridden for c in found)


def test_an_override_of_a_key_the_table_does_not_set_is_refused(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match=r"channel\[0\]\.override\[0\]: 'r0_ohm' is not set here"):
        _load(tmp_path, TIP + 'override = ["r0_ohm"]\n')
    with pytest.raises(ConfigError, match=r"model\.override_calibration\[0\]: 'effects' is not set here"):
        _load(tmp_path, '[bus.device.model]\noverride_calibration = ["effects"]\n')
    with pytest.raises(ConfigError, match=r"override\[0\]: 'r0_ohn' is not a sensor parameter.*'r0_ohm'"):
        _load(tmp_path, TIP + 'params = { r0_ohm = 1e5 }\noverride = ["r0_ohn"]\n')
    with pytest.raises(ConfigError, match=r"channel\[0\]\.override: expected an array"):
        _load(tmp_path, TIP + 'params = { r0_ohm = 1e5 }\noverride = "r0_ohm"\n')


def test_a_line_channel_takes_no_effects_so_none_contradict(tmp_path: Path) -> None:
    cal = CAL + "\n[line.tip]\nslope_s_per_n = 2e-5\nintercept_s = 1e-6\n"
    dev = _load(tmp_path, TIP + 'effects = ["tunneling"]\n', cal)
    assert dev.channel("tip").conversion is not None
    assert dev.channel("tip").effects == ("tunneling",)


@pytest.mark.parametrize(
    ("meta", "where", "what"),
    [
        ('effects = "creep"', "meta.effects", "expected an array of effect names"),
        ('effects = ["creep", 3]', r"meta.effects\[1\]", "expected an effect name"),
        ('effects = ["hysterisis"]', r"meta.effects\[0\]", "hysteresis"),
    ],
)
def test_invalid_meta_effects_are_refused_naming_the_file(
    tmp_path: Path, meta: str, where: str, what: str
) -> None:
    cal = f"[meta]\n{meta}\n[channel.tip]\nr0_ohm = 187500.0\n"
    with pytest.raises(ConfigError, match=rf"cal\.toml: {where}: .*{what}"):
        _load(tmp_path, TIP, cal)


def test_apply_reads_with_the_calibration_effects(tmp_path: Path) -> None:
    (tmp_path / "cal.toml").write_text(CAL)
    assert load_calibration(tmp_path / "cal.toml").effects == HYSTERESIS
    dev = calibrated_device(tmp_path / "cal.toml", ["tip"])
    assert dev.channel("tip").effects == HYSTERESIS
    assert dev.channel("tip").params == SensorParams(r0_ohm=187500.0, e0_pa=14e6)
    # the same channel read live (a device that names the file): the same effects and parameters
    live = _load(tmp_path, TIP).channel("tip")
    assert (live.effects, live.params) == (dev.channel("tip").effects, dev.channel("tip").params)
    # an apply device told other effects than the file's contradicts it, as a device would
    with pytest.raises(ConfigError, match=r'model\.effects = \["tunneling"\] in the config'):
        calibrated_device(tmp_path / "cal.toml", ["tip"], effects=("tunneling",))
