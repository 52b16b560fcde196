"""Issue 24 §1 and §8: files that Python's parsers fail on with errors other than a syntax error
(an integer of more than 4300 digits: ``ValueError``; values nested hundreds deep:
``RecursionError``) are a ``ConfigError`` naming the file, in every file the gateway reads
(configuration, profile, calibration, web config); a UTF-8 byte order mark is accepted."""

from __future__ import annotations

from pathlib import Path

import pytest
from click.testing import CliRunner
from config_texts import BASE

from gateway.cli import main
from gateway.cli.run_cmd import _load
from gateway.config import load_config
from gateway.errors import ConfigError
from gateway.model import SensorParams
from sim_device.scenarios import Scenario, ScenarioError

BIG_INT = "1" * 5001
DEEP_TOML = "[" * 500 + "]" * 500
DEEP_YAML = "[" * 2000 + "]" * 2000

#: (id, a value that breaks Python's TOML parser, what the message must say)
HOSTILE_VALUES = [
    ("5001-digits", BIG_INT, "a number too long to read"),
    ("nested-500-deep", DEEP_TOML, "nested too deeply"),
]


def _write(path: Path, text: str) -> Path:
    path.write_text(text, encoding="utf-8")
    path.chmod(0o600)
    return path


@pytest.mark.parametrize(
    ("value", "expected"), [v[1:] for v in HOSTILE_VALUES], ids=[v[0] for v in HOSTILE_VALUES]
)
def test_a_hostile_configuration_is_a_config_error_naming_the_file(
    tmp_path: Path, value: str, expected: str
) -> None:
    cfg = _write(tmp_path / "gateway.toml", BASE + f"extra = {value}\n")
    with pytest.raises(ConfigError) as info:
        load_config(cfg)
    assert str(cfg) in str(info.value) and expected in str(info.value)
    with pytest.raises(ConfigError):  # what run and a SIGHUP reload call
        _load(cfg)
    result = CliRunner().invoke(main, ["check-config", "-c", str(cfg)])
    assert result.exit_code == 2, result.output
    assert result.exception is None or isinstance(result.exception, SystemExit)
    assert "Traceback" not in result.output and expected in result.output


@pytest.mark.parametrize(
    ("value", "expected"), [v[1:] for v in HOSTILE_VALUES], ids=[v[0] for v in HOSTILE_VALUES]
)
def test_a_hostile_profile_or_calibration_file_is_a_config_error_naming_it(
    tmp_path: Path, value: str, expected: str
) -> None:
    profile = _write(tmp_path / "my-array.toml", f"description = {value}\n")
    cfg = _write(
        tmp_path / "gateway.toml", BASE.replace('profile = "tactile-sim"', 'profile = "my-array.toml"')
    )
    with pytest.raises(ConfigError) as info:
        load_config(cfg)
    assert str(profile) in str(info.value) and expected in str(info.value)

    cal = _write(tmp_path / "cal.toml", f"[channel.ch00]\nr0_ohm = {value}\n")
    cfg = _write(tmp_path / "gateway.toml", BASE + 'calibration = "cal.toml"\n')
    with pytest.raises(ConfigError) as info:
        load_config(cfg)
    assert str(cal) in str(info.value) and expected in str(info.value)


@pytest.mark.parametrize("value", [f"X-Big: {BIG_INT}", f"X-Deep: {DEEP_YAML}"], ids=["5001-digits", "deep"])
def test_a_hostile_web_config_is_a_config_error_naming_it(tmp_path: Path, value: str) -> None:
    web = _write(tmp_path / "web.yml", f"http_server_config:\n  headers:\n    {value}\n")
    cfg = _write(tmp_path / "gateway.toml", BASE.replace("[[bus]]", 'web_config = "web.yml"\n\n[[bus]]', 1))
    with pytest.raises(ConfigError) as info:
        _load(cfg)
    assert str(web) in str(info.value) and "invalid YAML" in str(info.value)


def test_hostile_sensor_parameters_and_scenarios_are_their_own_errors() -> None:
    for value in (BIG_INT, DEEP_TOML):
        with pytest.raises(ValueError, match="invalid TOML"):  # ParameterError is a ValueError
            SensorParams.from_toml(f"r0_ohm = {value}\n")
        with pytest.raises(ScenarioError, match="invalid TOML"):
            Scenario.from_toml(f"name = {value}\n", source="s.toml")


def test_a_utf8_byte_order_mark_is_accepted(tmp_path: Path) -> None:
    cal = tmp_path / "cal.toml"
    cal.write_bytes(b"\xef\xbb\xbf[channel.ch00]\nr0_ohm = 150000.0\n")
    cfg = tmp_path / "gateway.toml"
    cfg.write_bytes(b"\xef\xbb\xbf" + (BASE + 'calibration = "cal.toml"\n').encode())
    cfg.chmod(0o600)
    config = load_config(cfg)
    assert config.buses[0].devices[0].name == "array1"
    result = CliRunner().invoke(main, ["check-config", "-c", str(cfg)])
    assert result.exit_code == 0, result.output
    result = CliRunner().invoke(main, ["channels", "list", "-c", str(cfg)])
    assert result.exit_code == 0, result.output
    assert SensorParams.from_toml("\ufeffr0_ohm = 150000.0\n").r0_ohm == 150000.0
