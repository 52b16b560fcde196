"""A file ``calibrate`` writes for a real record reads back in a gateway configuration with the
parameters the fit reported (``config.calibration_file``: one writer, one reader)."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

from click.testing import CliRunner

from gateway.cli import main
from gateway.config import parse_config
from gateway.config.calibration_file import load_calibration
from gateway.model.params import parameter_names

REAL = Path(__file__).resolve().parents[3] / "data" / "real"


def test_a_calibrate_file_of_a_real_record_loads_back_with_the_same_parameters(tmp_path: Path) -> None:
    # a record path the old f-string writer broke the file with: quotes, backslash, newline, non-ASCII
    record = tmp_path / 'bench "thick"\\run\n2 ünï.csv'
    shutil.copyfile(REAL / "tams_thick.csv", record)
    out = tmp_path / "cal.toml"
    result = CliRunner().invoke(main, ["calibrate", str(record), "--out", str(out), "--as", "pad3", "--json"])
    assert result.exit_code == 0, result.output
    (fit,) = json.loads(result.stdout)["calibrations"]
    text = out.read_text(encoding="utf-8")
    # the comments the file has always had are still there (tomlkit comments)
    assert text.startswith("# Written by `tactile-gateway calibrate`")
    assert "# reference zero offset fitted: " in text and "# model: physics, held-out force RMS" in text
    assert "# calibrated on " in text

    cal = load_calibration(out)
    assert cal.record == str(record) and cal.effects == tuple(fit["effects"])
    config = parse_config(
        f"""
[[bus]]
name = "bench"
kind = "tcp"
host = "127.0.0.1"
port = 5020
[[bus.device]]
name = "pad"
device_id = 1
profile = "tactile-sim"
channels = 2
calibration = "{out}"
[[bus.device.channel]]
index = 1
name = "pad3"
""",
        tmp_path / "gateway.toml",
    )
    (channel,) = [c for c in config.buses[0].devices[0].channels if c.name == "pad3"]
    known = set(parameter_names())
    fitted = {p["name"]: p["value"] for p in fit["parameters"] if p["name"] in known}
    assert fitted and {k: getattr(channel.params, k) for k in fitted} == fitted
    low, high = fit["model_force_range_n"]
    assert (channel.params.force_min_n, channel.params.force_max_n) == (low, high)
    assert channel.calibrated_range_n == tuple(fit["calibrated_range_n"])
    assert channel.conversion is None and channel.baseline_ohm is None
    # calibrate --out replaces the file it wrote (it is a calibration file)
    again = CliRunner().invoke(
        main, ["calibrate", str(record), "--out", str(out), "--as", "pad3", "--objective", "log-r",
               "--force-offset", "none", "--model", "line"],
    )  # fmt: skip
    assert again.exit_code == 0, again.output
    line = load_calibration(out, ["pad3"]).conversions["pad3"]
    assert line.kind == "line" and line.values["slope_s_per_n"] > 0
