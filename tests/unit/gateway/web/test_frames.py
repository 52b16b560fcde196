"""Frame and layout encoding: strict JSON (no NaN), layout order, status codes, units."""

from __future__ import annotations

import json

from web_snapshots import device

from gateway.runtime.counters import DeviceCounters
from gateway.runtime.snapshot import STATUS_LABELS, ChannelStatus
from gateway.web.frames import encode_frame, layout_json, with_dropped


def test_a_frame_is_strict_json_with_absent_values_as_null() -> None:
    counters = DeviceCounters(reads_total=9, polls_total=8)
    frame = encode_frame(device(), 42, counters)
    assert b"NaN" not in frame and b"Infinity" not in frame
    data = json.loads(frame)
    assert data["device"] == "arr" and data["seq"] == 42
    assert data["force_n"] == [0.0, 1.5, None, 0.25]
    assert data["status"] == [
        ChannelStatus.NO_CONTACT,
        ChannelStatus.OK,
        ChannelStatus.OPEN,
        ChannelStatus.OK,
    ]
    assert data["cop_mm"] == [2.5, 0.357143]
    assert data["total_force_n"] == 1.75 and data["contact_area_mm2"] == 12.5
    assert data["polls_total"] == 8 and data["reads_total"] == 9 and data["read_errors_total"] == 0
    assert data["up"] is True and data["t"] == 1000.0 and data["device_time_s"] == 12.5


def test_a_stale_device_frame_says_so() -> None:
    data = json.loads(encode_frame(device(up=False), 3, None))
    assert data["up"] is False and data["error"] == "timeout"
    assert set(data["status"]) == {ChannelStatus.STALE}
    assert data["device_time_s"] is None and data["last_success_t"] == 995.0


def test_layout_lists_positions_units_and_status_labels() -> None:
    layout = layout_json(device(), 5.0)
    assert [(c["name"], c["x_mm"], c["y_mm"]) for c in layout["channels"]] == [
        ("ch00", 0.0, 0.0), ("ch01", 2.5, 0.0), ("ch02", 0.0, 2.5), ("ch03", 2.5, 2.5),
    ]  # fmt: skip
    assert layout["units"]["force"] == "N" and layout["units"]["position"] == "mm"
    assert layout["status_labels"] == list(STATUS_LABELS) and layout["status_labels"][5] == "stale"
    assert layout["scale_n"] == [0.0, 5.0]
    json.dumps(layout, allow_nan=False)


def test_with_dropped_prefixes_the_count_without_decoding() -> None:
    frame = encode_frame(device(), 1, None)
    data = json.loads(with_dropped(frame, 17))
    assert data["dropped"] == 17 and data == {**json.loads(frame), "dropped": 17}


def test_layout_gives_the_cell_area_and_disabled_channels_from_the_configuration() -> None:
    from gateway.config import ChannelConfig, DeviceConfig, RegisterMap
    from gateway.config.layout import GridLayout
    from gateway.model import PAPER_EFFECTS, Divider, SensorParams

    channels = tuple(
        ChannelConfig(k, f"ch{k:02d}", (k % 2) * 2.0, (k // 2) * 3.0, k != 1, PAPER_EFFECTS, SensorParams())
        for k in range(4)
    )
    config = DeviceConfig("arr", 1, "float32", 4, RegisterMap(), Divider(), channels, False,
                          GridLayout(4, 2, 2.0, 3.0), None)  # fmt: skip
    layout = layout_json(device(), 5.0, config)
    assert layout["cell_area_mm2"] == 6.0 and layout["units"]["pressure"] == "kPa"
    assert layout["disabled_channels"] == [{"index": 1, "name": "ch01", "x_mm": 2.0, "y_mm": 0.0}]


def test_without_the_configuration_the_cell_area_comes_from_the_positions() -> None:
    layout = layout_json(device(), 5.0)  # a 2 x 2 grid at a 2.5 mm pitch
    assert layout["cell_area_mm2"] == 6.25 and layout["disabled_channels"] is None
