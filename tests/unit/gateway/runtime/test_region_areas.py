"""Contact area on a device made of regions of different pitch: each cell in contact counts its
own region's pitch x pitch (hand-computed), in a poll and in a replay (``view``)."""

from __future__ import annotations

import numpy as np

from gateway.config import parse_config
from gateway.modbus.image import RawSample
from gateway.runtime.processor import DeviceProcessor
from gateway.runtime.replay import ChannelSeries, held_snapshots

CONFIG = """
[[bus]]
name = "b"
kind = "tcp"
host = "127.0.0.1"
port = 502
[[bus.device]]
name = "skin"
device_id = 1
[bus.device.frame]
quantity = "counts"
table = "holding"
[bus.device.front_end]
kind = "high_side"
supply_v = 5.0
reference_ohm = 10000.0
adc_bits = 16
[[bus.device.region]]
name = "fine"
address = 0
rows = 2
columns = 2
pitch_mm = 2.0
[[bus.device.region]]
name = "coarse"
address = 4
rows = 2
columns = 2
pitch_mm = 5.0
x_mm = 20.0
"""


def test_each_cell_in_contact_counts_its_own_regions_area() -> None:
    device = parse_config(CONFIG).buses[0].devices[0]
    assert device.cell_areas_mm2 == (4.0, 4.0, 4.0, 4.0, 25.0, 25.0, 25.0, 25.0)
    proc = DeviceProcessor(device, "b", 0.1)
    # high side: counts rise with load; 0 reads open, mid-scale a loaded cell
    counts = np.array([40000, 40000, 0, 0, 40000, 0, 0, 0], dtype=np.uint16)
    snap, _ = proc.process(proc.initial_state(), RawSample(counts=counts), 1e3, 0.0)
    assert snap.channels_in_contact == 3
    assert snap.contact_area_mm2 == 2 * 4.0 + 25.0
    r = np.asarray(snap.resistance_ohm, dtype=np.float64)
    r = np.where(np.isnan(r), np.inf, r)  # open: no resistance reported, +inf ohm read
    t = np.array([0.0, 0.1, 0.2])
    series = [ChannelSeries(t, np.full(3, r[k])) for k in range(device.n_channels)]
    replayed, _ = held_snapshots(DeviceProcessor(device, "b", 0.1), series)
    assert [s.contact_area_mm2 for s in replayed] == [33.0, 33.0, 33.0]
