"""``rails = "readings"`` (a robot hand's raw values: an unloaded taxel reads 0): the open rail is
no current at rest (no contact, 0 N), not an open circuit, under every front end, uncalibrated
ratio channels included; the short rail reads saturated. ``rails = "faults"`` (the default)
keeps the rails as faults."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from gateway.config import parse_config
from gateway.errors import ConfigError
from gateway.modbus.image import RawSample
from gateway.model import SensorModel, SensorParams
from gateway.runtime.processor import DeviceProcessor
from gateway.runtime.snapshot import ChannelStatus, DeviceSnapshot

FS = 65535


def _snapshot(tmp_path: Path, front_end: str, rails: str | None, counts: list[int]) -> DeviceSnapshot:
    rails_line = "" if rails is None else f'rails = "{rails}"'
    config = parse_config(
        f"""
[[bus]]
name = "b"
kind = "tcp"
host = "127.0.0.1"
port = 5020
[[bus.device]]
name = "hand"
device_id = 1
profile = "generic-adc"
channels = {len(counts)}
registers.adc_address = 0
{rails_line}
[bus.device.front_end]
{front_end}
""",
        tmp_path / "gateway.toml",
    )
    device = config.buses[0].devices[0]
    proc = DeviceProcessor(device, "b", 0.1)
    snap, _ = proc.process(
        proc.initial_state(), RawSample(counts=np.array(counts, dtype=np.uint16)), 1e3, 0.0
    )
    return snap


RATIO = 'kind = "ratio"\nadc_bits = 16'
#: raw = 65535 x 1 kohm / r: a conductance read-out in ohm, so the default model reads newtons
TRANSIMPEDANCE = (
    'kind = "transimpedance"\nbias_v = 1.0\nfeedback_ohm = 1000.0\nadc_bits = 16\nadc_reference_v = 1.0'
)


@pytest.mark.parametrize("front_end", [RATIO, TRANSIMPEDANCE])
def test_the_open_rail_is_an_open_circuit_by_default(tmp_path: Path, front_end: str) -> None:
    snap = _snapshot(tmp_path, front_end, None, [0, 0, 0, 0])
    assert (snap.status == ChannelStatus.OPEN).all()
    assert np.isnan(snap.force_n).all()


def test_as_readings_the_open_rail_is_rest_on_an_uncalibrated_ratio_channel(tmp_path: Path) -> None:
    snap = _snapshot(tmp_path, RATIO, "readings", [0, 490, 0, FS])
    # 0: no current, no contact at 0 N under any calibration; 490: a reading without a force
    rest, reading, saturated = ChannelStatus.NO_CONTACT, ChannelStatus.UNCALIBRATED, ChannelStatus.SATURATED
    assert snap.status.tolist() == [rest, reading, rest, saturated]
    assert snap.force_n[0] == 0.0 and snap.force_n[2] == 0.0
    assert np.isnan(snap.force_n[1]) and np.isnan(snap.force_n[3])  # no made-up force
    # r / R_ref = FS / code - 1 is still reported for the reading
    assert snap.resistance_ohm[1] == pytest.approx(FS / 490 - 1, rel=1e-12)
    assert snap.total_force_n == 0.0 and snap.channels_in_contact == 0


def test_as_readings_the_open_rail_is_rest_and_the_short_rail_saturated_in_ohm(tmp_path: Path) -> None:
    snap = _snapshot(tmp_path, TRANSIMPEDANCE, "readings", [0, 0, 8400, FS])
    assert snap.status[0] == ChannelStatus.NO_CONTACT and snap.force_n[0] == 0.0
    # 8400 counts: r = 65535 kohm / 8400 = 7.8 kohm, a load by the default model
    r_ohm = 65535 * 1000 / 8400
    assert snap.resistance_ohm[2] == pytest.approx(r_ohm, rel=1e-12)
    # round trip: a fresh channel starts settled at its reading, so the default sensor settled
    # at the force read gives back the reading's resistance
    force_n = float(snap.force_n[2])
    assert snap.status[2] == ChannelStatus.OK and force_n > 0.0
    model = SensorModel("tunneling,contact,creep", [SensorParams()])
    settled = model.settled_state(np.array([force_n]))
    assert float(model.resistance(np.array([force_n]), settled)[0]) == pytest.approx(r_ohm, rel=1e-6)
    # full scale: more load than the converter resolves; its force is the model's top, flagged
    assert snap.status[3] == ChannelStatus.SATURATED


def test_a_word_that_is_no_rail_meaning_is_refused_with_the_allowed_ones(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match=r"rails: 'reading' is not allowed.*allowed: faults \| readings"):
        _snapshot(tmp_path, RATIO, "reading", [0])
