"""``[line.<name>]`` / ``[lookup.<name>]`` tables of a calibration file: parsed, refused, read."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from gateway.analysis.records import format_record, write_record
from gateway.cli import main
from gateway.config import DeviceConfig, parse_config
from gateway.errors import ConfigError
from gateway.modbus.image import RawSample
from gateway.model import SensorModel, SensorParams
from gateway.model.conversion import line_conversion, lookup_conversion
from gateway.model.static_curves import LineCurve
from gateway.runtime.processor import DeviceProcessor
from gateway.runtime.snapshot import ChannelStatus


def _device(tmp_path: Path, calibration: str) -> DeviceConfig:
    cal = tmp_path / "cal.toml"
    cal.write_text(calibration)
    config = parse_config(
        f"""
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
""",
        tmp_path / "gateway.toml",
    )
    return config.buses[0].devices[0]


LINE = """
[channel."tip"]
force_min_n = 0.2
force_max_n = 12.0

[line."tip"]
slope_s_per_n = 2e-5
intercept_s = 1e-6
held_out_force_rms_n = 0.1
"""


def test_a_line_table_gives_the_channel_a_line_with_its_force_range(tmp_path: Path) -> None:
    dev = _device(tmp_path, LINE)
    assert dev.channel("tip").conversion == line_conversion(2e-5, 1e-6, 0.2, 12.0)
    assert dev.channel("ch01").conversion is None
    own = LINE.replace("intercept_s = 1e-6", "intercept_s = 1e-6\nforce_min_n = 0.1\nforce_max_n = 5")
    assert _device(tmp_path, own).channel("tip").conversion == line_conversion(2e-5, 1e-6, 0.1, 5.0)


def test_a_lookup_table_gives_the_channel_a_lookup(tmp_path: Path) -> None:
    dev = _device(tmp_path, '[lookup."ch01"]\nresistance_ohm = [1e3, 1e4, 1e5]\nforce_n = [8, 2, 0.5]\n')
    assert dev.channel("ch01").conversion == lookup_conversion((1e3, 1e4, 1e5), (8.0, 2.0, 0.5))
    assert dev.channel("tip").conversion is None


@pytest.mark.parametrize(
    ("text", "where", "message"),
    [
        ('[line."tpi"]\nslope_s_per_n = 1e-5\nintercept_s = 0\n', "line.tpi", "did you mean 'tip'?"),
        ('[lookup."ch1"]\nresistance_ohm = [1, 2]\nforce_n = [2, 1]\n', "lookup.ch1", "did you mean 'ch01'?"),
        ('[line."tip"]\nslope_s_per_n = -1e-5\nintercept_s = 0\n', "line.tip.slope_s_per_n", "(0, inf) S/N"),
        ('[line."tip"]\nslope_s_per_n = nan\nintercept_s = 0\n', "line.tip.slope_s_per_n", "finite"),
        ('[line."tip"]\nslope_s_per_n = 1e-5\n', "line.tip.intercept_s", "required key is missing"),
        ('[line."tip"]\nslope_s_per_n = 1e-5\nintercept_s = 0\nslop = 1\n', "line.tip.slop", "unknown key"),
        ('[line."tip"]\nslope_s_per_n = "1e-5"\nintercept_s = 0\n', "line.tip.slope_s_per_n", "finite"),
        (
            '[lookup."tip"]\nresistance_ohm = [1e3, 1e3]\nforce_n = [2, 1]\n',
            "lookup.tip.resistance_ohm[1]",
            "strictly increasing",
        ),
        (
            '[lookup."tip"]\nresistance_ohm = [1e3]\nforce_n = [2]\n',
            "lookup.tip.resistance_ohm",
            "at least 2",
        ),
        ('[lookup."tip"]\nresistance_ohm = 5\nforce_n = [2]\n', "lookup.tip.resistance_ohm", "an array"),
        (
            '[lookup."tip"]\nresistance_ohm = [1, 2]\nforce_n = [1, 2]\n',
            "lookup.tip.force_n[1]",
            "non-increasing",
        ),
        (
            '[line."tip"]\nslope_s_per_n = 1e-5\nintercept_s = 0\n'
            '[lookup."tip"]\nresistance_ohm = [1, 2]\nforce_n = [2, 1]\n',
            "lookup.tip",
            "keep one",
        ),
        ("line = 3\n", "line", "expected tables [line.<name>]"),
        ("[line]\ntip = 3\n", "line.tip", "expected a table"),
    ],
)
def test_bad_tables_name_the_file_and_key(tmp_path: Path, text: str, where: str, message: str) -> None:
    with pytest.raises(ConfigError) as info:
        _device(tmp_path, text)
    shown = str(info.value)
    assert f"{tmp_path / 'cal.toml'}: {where}: " in shown, shown
    assert message in shown
    assert f"(calibration file of bus[0].device[0].calibration in {tmp_path / 'gateway.toml'})" in shown


def _simulated_record(path: Path) -> None:
    params = SensorParams(r0_ohm=225e3, e0_pa=13.5e6, rho2_ohm_m=0.85, e1_pa=140e6, mu1_pa_s=1.2e10)
    rng = np.random.default_rng(5)
    levels = [0.0, 0.3, 1.0, 0.0, 2.0, 4.0, 0.5, 6.0, 0.0, 3.0, 8.0, 1.5, 0.0]
    t = np.arange(0.0, 200.0 * len(levels), 0.5)
    f = np.array(levels)[np.minimum((t // 200.0).astype(int), len(levels) - 1)]
    out, _ = SensorModel(("tunneling", "contact", "creep"), params).simulate(f[:, None], t)
    r = out.total_ohm[:, 0] * np.exp(0.01 * rng.standard_normal(t.size))
    write_record(path, format_record({"sensor": "test"}, ["tip"], t, r[:, None], force_n=f[:, None]))


def test_calibrate_model_line_file_reads_through_the_processor(tmp_path: Path) -> None:
    record = tmp_path / "bench.csv"
    _simulated_record(record)
    out = tmp_path / "written.toml"
    result = CliRunner().invoke(main, ["calibrate", str(record), "--model", "line", "--out", str(out)])
    assert result.exit_code == 0, result.output
    text = out.read_text()
    assert '[line."tip"]' in text
    m = float(re.search(r"slope_s_per_n = (\S+)", text).group(1))  # type: ignore[union-attr]
    n = float(re.search(r"intercept_s = (\S+)", text).group(1))  # type: ignore[union-attr]

    dev = _device(tmp_path, text)
    line = dev.channel("tip").conversion
    assert line is not None and line.table_kind == "line" and isinstance(line.curve, LineCurve)
    assert (line.curve.slope_s_per_n, line.curve.intercept_s) == (m, n)
    # this record's line has n < 0: it starts at 1.1 x its zero-conductance force -n/m, above the
    # record's lowest force (the channel's force_min_n), so a sensor at rest reads no contact
    assert n < 0
    assert line.force_min_n == pytest.approx(1.1 * -n / m, rel=1e-12)
    assert line.force_min_n > dev.channel("tip").params.force_min_n
    assert dev.channel("ch01").conversion is None

    proc = DeviceProcessor(dev, "bench", 0.1)
    force = 0.5 * (line.force_min_n + line.force_max_n)
    r_line = 1.0 / (m * force + n)
    r_phys = SensorModel(dev.channel("ch01").effects, [dev.channel("ch01").params]).resistance(
        np.array([2.0])
    )
    r = np.array([r_line, r_phys[0]])
    counts = dev.front_end.counts(dev.front_end.output_voltage(r))
    snap, _ = proc.process(proc.rested_state(), RawSample(counts=counts), 0.0, 0.0)
    assert [ChannelStatus(s).label for s in snap.status] == ["ok", "ok"]
    # through the ADC: the reading is the line at the quantized resistance
    r_read = dev.front_end.resistance(counts)[0][0]
    assert snap.force_n[0] == pytest.approx((1.0 / r_read - n) / m, rel=1e-12)
    assert snap.force_n[0] == pytest.approx(force, rel=0.02)
    assert snap.force_n[1] == pytest.approx(2.0, rel=0.02)
