"""A zero under a load on a device made of regions (``tare_window.loaded_regions``): the 1,062-taxel
hand of the ``dexhand-1062`` profile read through a conductance front end (raw = 65535 x 1 kohm
/ r), each taxel with its own offset at rest, the palm loaded throughout the window. The palm
is named as loaded as a region and not zeroed; every other taxel is zeroed at its own offset
(however high), except a taxel under a point load; and ``--channels`` takes region and group
names."""

from __future__ import annotations

import numpy as np
import pytest

from gateway.analysis.tare import ChannelSeries
from gateway.analysis.tare_window import compute_window_tare
from gateway.cli.tare_cmd import parse_channels
from gateway.config import DeviceConfig, parse_config

N_POLLS = 40
PALM = range(950, 1062)  # the profile's last region, 14 x 8
PALM_LOAD_COUNTS = 490.0  # 0.5 N on a nominal taxel of the simulator


def hand() -> DeviceConfig:
    config = parse_config(
        """
[[bus]]
name = "b"
kind = "tcp"
host = "127.0.0.1"
port = 6000
[[bus.device]]
name = "hand"
device_id = 1
profile = "dexhand-1062"
[bus.device.front_end]
kind = "transimpedance"
bias_v = 1.0
feedback_ohm = 1000.0
adc_bits = 16
adc_reference_v = 1.0
"""
    )
    return config.buses[0].devices[0]


def series(offsets: np.ndarray, extra: dict[int, float], noise_lsb: float = 2.0) -> list[ChannelSeries]:
    """Each taxel at its offset plus ``extra`` (counts) throughout, with noise, 30 polls a second."""
    rng = np.random.default_rng(5)
    t = np.arange(N_POLLS) / 30.0
    out = []
    for k, offset in enumerate(offsets):
        level = offset + extra.get(k, 0.0)
        values = np.clip(np.rint(level + noise_lsb * rng.standard_normal(N_POLLS)), 0, 65535)
        out.append(ChannelSeries(k, values, t))
    return out


@pytest.mark.parametrize("spread_lsb", [0.0, 300.0])
def test_a_palm_loaded_throughout_is_left_unzeroed_as_a_region(spread_lsb: float) -> None:
    device = hand()
    offsets = np.random.default_rng(1).uniform(0.0, 2.0 * spread_lsb, 1062)
    point = 300  # a taxel of little-pad (105..184), pressed on its own: 3,000 counts, some 2 N
    extra = {k: PALM_LOAD_COUNTS for k in PALM} | {point: 3000.0}
    found = compute_window_tare(device, series(offsets, extra), counts=True)
    skipped = dict(found.skipped)
    assert sorted(skipped) == [point, *PALM]
    assert all("with its region: region palm's least loaded tenth conducts" in skipped[k] for k in PALM)
    assert "x the median conductance of its region" in skipped[point]
    zeroed = found.tare.channels
    assert len(zeroed) == 1062 - 113
    # each taxel zeroed at its own offset (counts), within the noise of a 40-poll mean
    values = np.array(found.tare.values)
    assert np.abs(values - np.rint(offsets[list(zeroed)])).max() <= 2.0


def test_the_high_offsets_of_an_idle_skin_are_zeroed_not_refused_as_forces() -> None:
    # offsets up to 1,200 counts read up to about 1.3 N by the default model: the per-taxel
    # force check (0.5 N) alone would refuse a third of them; each region's least loaded tenth
    # says it is at rest, and no taxel stands 3x above its region's median
    device = hand()
    offsets = np.random.default_rng(2).uniform(0.0, 1200.0, 1062)
    found = compute_window_tare(device, series(offsets, {}), counts=True)
    assert found.skipped == ()
    assert len(found.tare.channels) == 1062


def test_regions_and_groups_name_their_channels() -> None:
    device = hand()
    assert parse_channels("palm", device) == list(PALM)
    index = parse_channels("index", device)  # the group: tip, nail and pad
    assert len(index) == 185 and index == list(range(index[0], index[0] + 185))
    assert parse_channels("index-tip,palm-r0c0", device) == [*index[:9], 950]
    with pytest.raises(ValueError, match=r"no channel 'pinky'.*or region and group names \(e\.g\. palm\)"):
        parse_channels("pinky", device)
