"""``tactile-gateway calibrate ... --out CAL --install CONFIG --device NAME``: the calibration
is named in the device's configuration (comments kept), or the refusal says why and leaves the
configuration as it was."""

from __future__ import annotations

import json
import tomllib
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner, Result

from gateway.analysis.records import format_record, write_record
from gateway.cli import main
from gateway.config import load_config
from gateway.model import SensorModel, SensorParams

CONFIG = """\
# Lab gateway: keep this comment.
[[bus]]
name = "bench"
kind = "tcp"
host = "127.0.0.1"
port = 5020

[[bus.device]]
name = "array1"     # left hand
device_id = 1
profile = "tactile-sim"
channels = 4

[[bus.device.channel]]
index = 0
name = "tip"        # fingertip
params = { r0_ohm = 190000.0 }  # set by hand
"""
CAL = '[meta]\neffects = ["tunneling", "contact", "hysteresis"]\n\n[channel.tip]\nr0_ohm = 187500.0\n'


def run(*args: str) -> Result:
    return CliRunner().invoke(main, list(args))


@pytest.fixture
def config(tmp_path: Path) -> Path:
    path = tmp_path / "gateway.toml"
    path.write_text(CONFIG)
    return path


@pytest.mark.parametrize(
    ("args", "expected"),
    [
        (["--out", "c.toml", "--device", "array1"], "--device and --replace-overrides go with --install"),
        (["--out", "c.toml", "--replace-overrides"], "--device and --replace-overrides go with --install"),
        (["--install", "gateway.toml"], "--install needs --out CAL.toml"),
        (["--update", "c.toml", "--install", "gateway.toml", "--out", "d.toml"], "--install goes with"),
    ],
)
def test_option_misuse_is_a_usage_error(config: Path, args: list[str], expected: str) -> None:
    result = run(
        "calibrate", str(config.parent / "bench.csv"), *[a.replace("gateway.toml", str(config)) for a in args]
    )
    assert result.exit_code == 2 and expected in result.output
    assert config.read_text() == CONFIG


def test_the_target_is_checked_before_any_fit(config: Path) -> None:
    out = config.parent / "cal.toml"
    # the record does not exist: the device is refused first, nothing is written
    result = run(
        "calibrate",
        str(config.parent / "bench.csv"),
        "--out",
        str(out),
        "--install",
        str(config),
        "--device",
        "arrayx",
    )
    assert result.exit_code == 2
    assert "no device 'arrayx'; did you mean 'array1'?" in result.output and "Traceback" not in result.output
    assert not out.exists() and config.read_text() == CONFIG


def test_install_an_existing_calibration_file(config: Path) -> None:
    cal = config.parent / "cal.toml"
    cal.write_text(CAL)
    refused = run("calibrate", "--out", str(cal), "--install", str(config), "--device", "array1")
    assert refused.exit_code == 2
    assert "params.r0_ohm = 190000.0 in the config, 187500.0 in the calibration" in refused.output
    assert config.read_text() == CONFIG
    result = run(
        "calibrate",
        "--out",
        str(cal),
        "--install",
        str(config),
        "--device",
        "array1",
        "--replace-overrides",
        "--json",
    )
    assert result.exit_code == 0, result.output
    installed = json.loads(result.output)["installed"]
    assert (installed["device"], installed["calibration"], installed["previous"]) == (
        "array1",
        "cal.toml",
        None,
    )
    assert installed["dropped"] == [
        {
            "channel": "tip",
            "key": "r0_ohm",
            "where": "bus[0].device[0].channel[0].params.r0_ohm",
            "config_value": 190000.0,
            "calibrated_value": 187500.0,
        }
    ]
    text = config.read_text()
    assert "# Lab gateway: keep this comment." in text and "# fingertip" in text and "# left hand" in text
    tip = load_config(config).buses[0].devices[0].channel("tip")
    assert (tip.params.r0_ohm, tip.effects) == (187500.0, ("tunneling", "contact", "hysteresis"))


def test_install_only_refuses_a_file_that_is_not_a_calibration(config: Path) -> None:
    other = config.parent / "other.toml"
    other.write_text(CONFIG)
    result = run("calibrate", "--out", str(other), "--install", str(config), "--device", "array1")
    assert result.exit_code == 2 and "is not a calibration file to install" in result.output
    assert config.read_text() == CONFIG


def _record(path: Path) -> None:
    """A simulated bench record of channel ``tip``: steps with holds, 1 % noise."""
    params = SensorParams(r0_ohm=225e3, e0_pa=13.5e6, rho2_ohm_m=0.85, e1_pa=140e6, mu1_pa_s=1.2e10)
    levels = [0.0, 0.3, 1.0, 0.0, 2.0, 4.0, 0.5, 6.0, 0.0, 3.0, 8.0, 1.5, 0.0]
    t = np.arange(0.0, 100.0 * len(levels), 1.0)
    f = np.array(levels)[np.minimum((t // 100.0).astype(int), len(levels) - 1)]
    out, _ = SensorModel(("tunneling", "contact", "creep"), params).simulate(f[:, None], t)
    r = out.total_ohm[:, 0] * np.exp(0.01 * np.random.default_rng(5).standard_normal(t.size))
    write_record(path, format_record({"sensor": "test"}, ["tip"], t, r[:, None], force_n=f[:, None]))


def test_record_calibrate_install_then_the_config_reads_the_calibration(config: Path) -> None:
    record, cal = config.parent / "bench.csv", config.parent / "cal.toml"
    _record(record)
    fit = ["--objective", "log-r", "--force-offset", "none", "--out", str(cal), "--install", str(config)]
    result = run("calibrate", str(record), *fit, "--device", "array1", "--replace-overrides")
    assert result.exit_code == 0, result.output
    assert f'{config}: device array1: calibration = "cal.toml" (was: none)' in result.output
    assert f"{config}: dropped bus[0].device[0].channel[0].params.r0_ohm = 190000.0" in result.output
    written = tomllib.loads(cal.read_text())
    tip = load_config(config).buses[0].devices[0].channel("tip")
    # the channel reads exactly what the calibration says, parameters and effects
    for key, value in written["channel"]["tip"].items():
        if key not in ("calibrated_min_n", "calibrated_max_n", "baseline_ohm"):
            assert getattr(tip.params, key) == value, key
    assert tip.effects == tuple(written["meta"]["effects"])
    assert "# fingertip" in config.read_text() and "# set by hand" not in config.read_text()
