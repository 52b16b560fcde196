"""A lookup table is interpolated in the domain it was given in (issue 33 §16).

A vendor's force table is linear in the ADC counts between its knots. Given in counts
(``[lookup.<name>] counts = [...]``) it is read linearly in the counts of the device's front
end: 193 counts between the knots (0 counts, 0 N) and (410 counts, 0.1 N) read
0.1 x 193 / 410 = 47.07 mN. The same knots turned into ohm and read in ln R, as a table in
``resistance_ohm`` is (what ``calibrate`` writes), read 87 mN there. Tables in
``resistance_ohm`` keep reading exactly as before: linear in ln R between their knots.

The device: a high-side divider, 5 V, 10 kohm, 12 bit (FS = 4095): r = 10k (4095 / code - 1).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from gateway.config import DeviceConfig, parse_config
from gateway.config.calibration_file import check_calibration_file
from gateway.errors import ConfigError
from gateway.modbus.image import RawSample
from gateway.model.calibrated import CurveChannel
from gateway.model.static_curves import LookupCurve
from gateway.runtime.processor import DeviceProcessor
from gateway.runtime.snapshot import ChannelStatus

FS = 4095
R_REF = 10e3
COUNTS = (0.0, 410.0, 819.0)  # a vendor table's knots (counts), linear between them
FORCE_N = (0.0, 0.1, 0.3)


def _ohm(code: float) -> float:
    """The high-side divider's resistance at an exact code (ohm)."""
    return R_REF * (FS / code - 1.0)


def _device(tmp_path: Path, table: str, encoding: str = "") -> DeviceConfig:
    (tmp_path / "cal.toml").write_text(table)
    config = parse_config(
        f"""
[[bus]]
name = "bench"
kind = "tcp"
host = "127.0.0.1"
port = 5020
[[bus.device]]
name = "skin"
device_id = 1
profile = "generic-adc"
channels = 2
registers.adc_address = 0
calibration = "{tmp_path / "cal.toml"}"
{encoding}
[bus.device.front_end]
kind = "high_side"
supply_v = 5.0
reference_ohm = {R_REF!r}
adc_bits = 12
""",
        tmp_path / "gateway.toml",
    )
    return config.buses[0].devices[0]


def _read(device: DeviceConfig, code: int) -> tuple[float, int]:
    proc = DeviceProcessor(device, "bench", 0.1)
    raw = RawSample(counts=np.array([code, 0], dtype=np.uint16))
    snap, _ = proc.process(proc.rested_state(), raw, 1000.0, 0.0)
    return float(snap.force_n[0]), int(snap.status[0])


COUNTS_TABLE = f"[lookup.ch00]\ncounts = {list(COUNTS)!r}\nforce_n = {list(FORCE_N)!r}\n"


@pytest.mark.parametrize(
    ("code", "expected_n", "status"),
    [
        (193, 0.1 * 193 / 410, ChannelStatus.OK),  # 47.07 mN
        (410, 0.1, ChannelStatus.OK),  # a knot
        (600, 0.1 + 0.2 * (600 - 410) / (819 - 410), ChannelStatus.OK),
        # beyond the last knot along the end segment, outside the table's forces
        (1000, 0.3 + 0.2 * (1000 - 819) / (819 - 410), ChannelStatus.EXTRAPOLATED),
    ],
)
def test_a_table_in_counts_is_linear_in_counts(
    tmp_path: Path, code: int, expected_n: float, status: int
) -> None:
    force_n, got = _read(_device(tmp_path, COUNTS_TABLE), code)
    assert math.isclose(force_n, expected_n, rel_tol=1e-9), (force_n, expected_n)
    assert got == status


def test_a_table_in_counts_on_a_front_end_whose_counts_fall_with_load(tmp_path: Path) -> None:
    """A ratio front end read low side (counts fall with load): forces fall with the counts;
    1500 counts between (1000, 0.2 N) and (3000, 0 N) read 0.2 - 0.2 x 500 / 2000 = 0.15 N."""
    table = "[lookup.ch00]\ncounts = [1000.0, 3000.0]\nforce_n = [0.2, 0.0]\n"
    (tmp_path / "cal.toml").write_text(table)
    config = parse_config(
        f"""
[[bus]]
name = "bench"
kind = "tcp"
host = "127.0.0.1"
port = 5020
[[bus.device]]
name = "skin"
device_id = 1
profile = "generic-adc"
channels = 2
registers.adc_address = 0
calibration = "{tmp_path / "cal.toml"}"
[bus.device.front_end]
kind = "ratio"
adc_bits = 12
rises_with_load = false
""",
        tmp_path / "gateway.toml",
    )
    force_n, status = _read(config.buses[0].devices[0], 1500)
    assert math.isclose(force_n, 0.15, rel_tol=1e-9) and status == ChannelStatus.OK


def test_a_table_in_ohm_is_read_in_ln_r_as_before(tmp_path: Path) -> None:
    """The same vendor knots turned into ohm (the 0-count knot, an open sensor, as 1 count):
    read in ln R between 1 and 410 counts: 87 mN at 193 counts, not 47 mN."""
    r_knots = [_ohm(819.0), _ohm(410.0), _ohm(1.0)]  # increasing
    f_knots = [0.3, 0.1, 0.0]
    table = f"[lookup.ch00]\nresistance_ohm = {r_knots!r}\nforce_n = {f_knots!r}\n"
    force_n, status = _read(_device(tmp_path, table), 193)
    t = math.log(_ohm(193) / _ohm(1.0)) / math.log(_ohm(410.0) / _ohm(1.0))
    assert math.isclose(force_n, 0.1 * t, rel_tol=1e-9) and status == ChannelStatus.OK
    assert 0.086 < force_n < 0.088


def test_calibrate_s_lookup_reads_exactly_as_before(tmp_path: Path) -> None:
    """A lookup as ``calibrate`` writes it (``LookupCurve.fit``, ``CurveChannel.table``) reads
    linear in ln R between its knots, hand-computed, through the file and the gateway."""
    log_r = np.linspace(math.log(2e3), math.log(2e5), 400)
    force = 4.0 - 0.8 * (log_r - math.log(2e3))  # linear in ln R: 4 N at 2 kohm, 0.3 N at 200 kohm
    channel = CurveChannel(LookupCurve.fit(force, np.exp(log_r)), table_kind="lookup")
    body = channel.table()
    assert set(body) == {"resistance_ohm", "force_n"}
    lines = "".join(f"{k} = {v!r}\n" for k, v in body.items())
    device = _device(tmp_path, "[lookup.ch00]\n" + lines)
    knots_r, knots_f = body["resistance_ohm"], body["force_n"]
    assert isinstance(knots_r, list) and isinstance(knots_f, list)
    for code in (500, 900, 1800):
        r = _ohm(code)
        j = int(np.searchsorted(knots_r, r))
        t = math.log(r / knots_r[j - 1]) / math.log(knots_r[j] / knots_r[j - 1])
        expected = knots_f[j - 1] + t * (knots_f[j] - knots_f[j - 1])
        force_n, status = _read(device, code)
        assert math.isclose(force_n, expected, rel_tol=1e-12), (code, force_n, expected)
        assert status == ChannelStatus.OK


def test_a_counts_table_round_trips_and_is_checked(tmp_path: Path) -> None:
    device = _device(tmp_path, COUNTS_TABLE)
    conversion = device.channels[0].conversion
    assert conversion is not None
    assert conversion.table() == {"counts": list(COUNTS), "force_n": list(FORCE_N)}
    assert check_calibration_file(tmp_path / "cal.toml").conversions["ch00"].kind == "lookup"
    bad = {
        "[lookup.ch00]\ncounts = [0.0, 410.0, 300.0]\nforce_n = [0.0, 0.1, 0.3]\n": (
            "lookup.ch00.counts[2]: 300.0 after 410.0: counts must be strictly increasing"
        ),
        "[lookup.ch00]\ncounts = [0.0, 410.0, 819.0]\nforce_n = [0.3, 0.1, 0.0]\n": (
            "lookup.ch00.force_n[1]: 0.1 after 0.3: this front end's counts rise with load, "
            "so forces must not decrease with counts"
        ),
        "[lookup.ch00]\ncounts = [0.0, 410.0, 5000.0]\nforce_n = [0.0, 0.1, 0.3]\n": (
            "lookup.ch00.counts[2]: 5000.0 is out of range; allowed: [0, 4095] counts"
        ),
        "[lookup.ch00]\ncounts = [0.0, 410.0]\nresistance_ohm = [1.0, 2.0]\nforce_n = [0.0, 0.1]\n": (
            "lookup.ch00.counts: give resistance_ohm or counts, not both"
        ),
    }
    for text, message in bad.items():
        with pytest.raises(ConfigError, match=message.replace("[", r"\[").replace("]", r"\]")):
            _device(tmp_path, text)
    with pytest.raises(ConfigError, match=r"a table in ADC counts needs the device's ADC front end"):
        _device(tmp_path, COUNTS_TABLE, 'encoding = "float32"\nregisters.float_address = 0')
