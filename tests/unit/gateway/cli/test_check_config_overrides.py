"""``tactile-gateway check-config`` lists every key that overrides a device's calibration (the
channel, the key, the config's value and where, the calibrated value and where), and refuses
one that contradicts it without saying so."""

from __future__ import annotations

from pathlib import Path

from click.testing import CliRunner

from gateway.cli import main

CAL = '[meta]\neffects = ["tunneling", "contact", "hysteresis"]\n\n[channel.tip]\nr0_ohm = 187500.0\n'
CONFIG = """\
[[bus]]
name = "bench"
kind = "tcp"
host = "127.0.0.1"
port = 5020

[[bus.device]]
name = "array1"
device_id = 1
profile = "tactile-sim"
channels = 4
calibration = "cal.toml"

[bus.device.model]
effects = ["tunneling", "contact", "creep"]
override_calibration = ["effects"]

[[bus.device.channel]]
index = 0
name = "tip"
params = { r0_ohm = 190000.0 }
override = ["r0_ohm"]
"""


def test_check_config_lists_every_override(tmp_path: Path) -> None:
    (tmp_path / "cal.toml").write_text(CAL)
    config = tmp_path / "gateway.toml"
    config.write_text(CONFIG)
    result = CliRunner().invoke(main, ["check-config", "-c", str(config)])
    assert result.exit_code == 0, result.output
    cal = tmp_path / "cal.toml"
    lines = result.output.splitlines()
    start = lines.index(
        "    calibration overrides (2; the config's value is read, as override / override_calibration say):"
    )
    assert lines[start + 1 : start + 3] == [
        "      tip: r0_ohm = 190000.0 (bus[0].device[0].channel[0].params.r0_ohm) over the calibrated "
        f"187500.0 ({cal} [channel.tip] r0_ohm)",
        '      tip: effects = ["tunneling", "contact", "creep"] (bus[0].device[0].model.effects) over the '
        f'calibrated ["tunneling", "contact", "hysteresis"] ({cal} [meta] effects)',
    ]


def test_check_config_of_a_calibration_without_overrides_says_none(tmp_path: Path) -> None:
    (tmp_path / "cal.toml").write_text(CAL)
    config = tmp_path / "gateway.toml"
    text = CONFIG.replace('override_calibration = ["effects"]\n', "").replace(
        'effects = ["tunneling", "contact", "creep"]\n', ""
    )
    config.write_text(text.replace('params = { r0_ohm = 190000.0 }\noverride = ["r0_ohm"]\n', ""))
    result = CliRunner().invoke(main, ["check-config", "-c", str(config)])
    assert result.exit_code == 0, result.output
    assert (
        "    calibration overrides: none (every calibrated channel is read with the calibration's values)"
        in (result.output)
    )


def test_check_config_refuses_a_contradiction_without_override(tmp_path: Path) -> None:
    (tmp_path / "cal.toml").write_text(CAL)
    config = tmp_path / "gateway.toml"
    config.write_text(CONFIG.replace('override = ["r0_ohm"]\n', ""))
    result = CliRunner().invoke(main, ["check-config", "-c", str(config)])
    assert result.exit_code == 2
    assert (
        "channel tip: bus[0].device[0].channel[0].params.r0_ohm = 190000.0 in the config, 187500.0 in the "
        f"calibration ({tmp_path / 'cal.toml'} [channel.tip] r0_ohm)"
    ) in result.output


def test_channels_set_on_a_calibrated_channel_needs_the_override(tmp_path: Path) -> None:
    (tmp_path / "cal.toml").write_text(CAL)
    config = tmp_path / "gateway.toml"
    text = CONFIG.replace('override_calibration = ["effects"]\n', "").replace(
        'effects = ["tunneling", "contact", "creep"]\n', ""
    )
    text = text.replace('params = { r0_ohm = 190000.0 }\noverride = ["r0_ohm"]\n', "")
    config.write_text(text)
    refused = CliRunner().invoke(main, ["channels", "set", "tip", "r0_ohm=2e5", "-c", str(config)])
    assert refused.exit_code == 2 and config.read_text() == text
    assert "channel[0].params.r0_ohm = 200000.0 in the config, 187500.0 in the calibration" in refused.output
    result = CliRunner().invoke(
        main, ["channels", "set", "tip", "r0_ohm=2e5", "override=r0_ohm", "-c", str(config)]
    )
    assert result.exit_code == 0, result.output
    assert 'r0_ohm = 2e5, override = ["r0_ohm"]' in result.output
    listed = CliRunner().invoke(main, ["check-config", "-c", str(config)])
    assert (
        "      tip: r0_ohm = 200000.0 (bus[0].device[0].channel[0].params.r0_ohm) over the calibrated "
        "187500.0"
    ) in listed.output
