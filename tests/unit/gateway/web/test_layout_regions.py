"""The layout of a device made of regions (``layout_json``): each region's name, group, grid,
drawn place, box and pitch (mm), and its channels as drawn, hand-computed from the
configuration; a device without regions has none."""

from __future__ import annotations

import json

from web_snapshots import device

from gateway.config import parse_config
from gateway.web.frames import layout_json

CONFIG = """
[[bus]]
name = "b"
kind = "tcp"
host = "127.0.0.1"
port = 502

[[bus.device]]
name = "arr"
device_id = 1
channels = 14
[bus.device.frame]
quantity = "counts"
table = "holding"
type = "uint16"
[bus.device.front_end]
kind = "ratio"
adc_bits = 16

[[bus.device.region]]
name = "tip"
group = "index"
address = 0
rows = 2
columns = 3
x_mm = 10.0
y_mm = 0.0

[[bus.device.region]]
name = "pad"
group = "index"
address = 100
rows = 3
columns = 2
pitch_mm = 2.0
x_mm = 0.0
y_mm = 10.0
rotation_deg = 90

[[bus.device.region]]
name = "palm"
address = 200
rows = 1
columns = 2
x_mm = 0.0
y_mm = 30.0
"""


def test_the_layout_carries_each_region_in_its_drawn_place() -> None:
    config = parse_config(CONFIG).buses[0].devices[0]
    layout = layout_json(device(forces=(0.0,) * 14), 5.0, config)
    json.dumps(layout, allow_nan=False)
    regions = {r["name"]: r for r in layout["regions"]}
    assert list(regions) == ["tip", "pad", "palm"]
    tip, pad, palm = regions["tip"], regions["pad"], regions["palm"]
    assert (tip["group"], tip["rows"], tip["columns"], tip["rotation_deg"]) == ("index", 2, 3, 0)
    # a 2 x 3 grid at 2.5 mm, its top-left cell centred at (10, 0): cells one pitch wide
    assert tip["box_mm"] == [8.75, -1.25, 16.25, 3.75] and tip["pitch_mm"] == [2.5, 2.5]
    assert tip["cells"] == [[0, 1, 2], [3, 4, 5]]
    # 3 x 2 at 2 mm turned a quarter clockwise: drawn 3 wide (the rows) and 2 high (the columns),
    # its first row on the right; cell (u, v) = (2 col, 2 row) at (0 + 4 - v, 10 + u)
    assert pad["box_mm"] == [-1.0, 9.0, 5.0, 13.0] and pad["pitch_mm"] == [2.0, 2.0]
    assert pad["cells"] == [[10, 8, 6], [11, 9, 7]] and pad["rotation_deg"] == 90
    assert (pad["x_mm"], pad["y_mm"]) == (0.0, 10.0)
    # no group given: its own
    assert palm["group"] == "palm" and palm["cells"] == [[12, 13]]
    assert palm["box_mm"] == [-1.25, 28.75, 3.75, 31.25]
    assert layout["groups"] == [
        {"name": "index", "regions": ["tip", "pad"]},
        {"name": "palm", "regions": ["palm"]},
    ]


def test_a_device_without_regions_has_none_in_its_layout() -> None:
    assert layout_json(device(), 5.0)["regions"] == []
    assert layout_json(device(), 5.0)["groups"] == []
