"""Regions of interest (issue 35 item 3): ``[[bus.device.roi]]`` read and checked, and each
region's sum, peak, contact area and centre of pressure per poll, in the snapshot, the frame
JSON and the metrics, against hand-computed numbers."""

from __future__ import annotations

import json
import math
from dataclasses import replace

import numpy as np
import pytest
from prometheus_client import CollectorRegistry, generate_latest

from gateway.config import ChannelConfig, DeviceConfig, Encoding, GatewayConfig, RegisterMap, parse_config
from gateway.config.layout import GridLayout
from gateway.config.rois import Roi
from gateway.errors import ConfigError
from gateway.metrics.collector import make_registry
from gateway.modbus.image import RawSample
from gateway.model import PAPER_EFFECTS, Divider, SensorParams
from gateway.model.conversion import line_conversion
from gateway.mqtt.payload import decode_binary, encode_binary, encode_json_frame, frame_dict
from gateway.runtime.processor import DeviceProcessor
from gateway.runtime.replay import ChannelSeries, held_snapshots
from gateway.runtime.snapshot import DeviceSnapshot, GatewaySnapshot
from gateway.web.frames import encode_frame

PITCH_MM = 2.5
CELL_MM2 = PITCH_MM * PITCH_MM  # 6.25
M, N = 2e-5, 1e-6  # the line conversion: 1 / r = M * F + N


def device_4x4(rois: tuple[Roi, ...], disabled: tuple[int, ...] = ()) -> DeviceConfig:
    line = line_conversion(M, N, 0.01, 50.0)
    channels = tuple(
        ChannelConfig(k, f"ch{k:02d}", (k % 4) * PITCH_MM, (k // 4) * PITCH_MM, k not in disabled,
                      PAPER_EFFECTS, SensorParams(), None, line)
        for k in range(16)
    )  # fmt: skip
    return DeviceConfig("arr", 1, Encoding.FLOAT32, 16, RegisterMap(), Divider(), channels, False,
                        GridLayout(16, 4, PITCH_MM, PITCH_MM), None, rois=rois)  # fmt: skip


def poll(device: DeviceConfig, forces: list[float]) -> DeviceSnapshot:
    proc = DeviceProcessor(device, "sim", 0.05)
    r = np.array([1.0 / (M * f + N) for f in forces])
    snap, _ = proc.process(proc.initial_state(), RawSample(resistance_ohm=r, device_time_s=0.05), 1e9, 1e9)
    return snap


# channel k at column k % 4, row k // 4; heel = channels 4, 5, 8, 9 (columns 0-1, rows 1-2)
FORCES = [0.0, 0.0, 0.0, 3.0, 1.0, 2.0, 0.0, 0.0, 0.5, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 4.0]
HEEL = Roi("heel", (4, 5, 8, 9))
EMPTY = Roi("toe", (0, 1, 2))

BASE = """\
[[bus]]
name = "bench"
kind = "tcp"
host = "127.0.0.1"
port = 5020

[[bus.device]]
name = "array1"
device_id = 1
profile = "tactile-sim"
channels = 16
"""


def with_device(extra: str) -> str:
    return BASE + extra + "\n"


def parse(text: str) -> GatewayConfig:
    return parse_config(text)


# ---------------------------------------------------------------- configuration


def test_rois_are_read_from_names_indices_and_ranges() -> None:
    text = with_device(
        '[[bus.device.roi]]\nname = "heel"\nchannels = ["4-5", "ch08", 9]\n'
        '[[bus.device.roi]]\nname = "all"\nchannels = ["0-15"]\n'
    )
    dev = parse(text).buses[0].devices[0]
    assert dev.rois == (Roi("heel", (4, 5, 8, 9)), Roi("all", tuple(range(16))))
    assert parse(with_device("")).buses[0].devices[0].rois == ()


HAND = """\
[[bus]]
name = "hand"
kind = "tcp"
host = "127.0.0.1"
port = 6000

[[bus.device]]
name = "hand"
device_id = 1
profile = "dexhand-1062"
"""


def test_a_region_or_group_name_selects_its_taxels() -> None:
    """On a device made of regions, ``channels = ["palm"]`` is every taxel of region palm (the
    dexhand-1062 profile: 112 taxels from channel 950), a group's name each of its regions."""
    text = HAND + '[[bus.device.roi]]\nname = "palm"\nchannels = ["palm"]\n'
    text += '[[bus.device.roi]]\nname = "tip"\nchannels = ["index-tip", "palm-r0c0"]\n'
    dev = parse(text).buses[0].devices[0]
    palm = next(r for r in dev.regions if r.name == "palm")
    tip = next(r for r in dev.regions if r.name == "index-tip")
    assert dev.rois[0].channels == tuple(range(palm.first_channel, palm.first_channel + palm.n_channels))
    assert len(dev.rois[0].channels) == 112
    assert dev.rois[1].channels == (*range(tip.first_channel, tip.first_channel + 9), palm.first_channel)


@pytest.mark.parametrize(
    ("roi", "message"),
    [
        ('name = "heel"\nchannels = ["ch99"]', "no channel 'ch99' in device array1; allowed: channel names"),
        ('name = "heel"\nchannels = ["12-16"]', "'12-16' is out of range; allowed: channel names "
         "(e.g. ch00), indices 0-15 or ranges A-B"),
        ('name = "heel"\nchannels = []', "expected a non-empty list of channel names"),
        ('name = "heel"\nchannels = "0-3"', "expected a non-empty list of channel names"),
        ('name = "Heel!"\nchannels = [1]', "is not a name matching [a-z0-9_-]{1,32}"),
        ('channels = [1]', "name: required key is missing"),
        ('name = "heel"\nchannels = [1]\nweight = 2', "weight"),
    ],
)  # fmt: skip
def test_a_bad_roi_is_refused_naming_its_key_and_what_is_allowed(roi: str, message: str) -> None:
    with pytest.raises(ConfigError) as err:
        parse(with_device(f"[[bus.device.roi]]\n{roi}\n"))
    assert "bus.device[0].roi[0]" in str(err.value) or "roi" in str(err.value)
    assert message in str(err.value)


def test_a_duplicate_roi_name_is_refused() -> None:
    text = with_device(
        '[[bus.device.roi]]\nname = "a"\nchannels = [1]\n[[bus.device.roi]]\nname = "a"\nchannels = [2]\n'
    )
    with pytest.raises(ConfigError, match="duplicate region of interest 'a'"):
        parse(text)


def test_a_roi_beyond_the_device_is_refused_in_code() -> None:
    with pytest.raises(ConfigError, match=r"channel 16 is out of range; allowed: 0\.\.15"):
        device_4x4((Roi("x", (15, 16)),))
    with pytest.raises(ConfigError, match="allowed: one or more"):
        Roi("x", ())


# ---------------------------------------------------------------- figures per poll


def test_a_rois_sum_peak_area_and_cop_are_those_over_its_cells() -> None:
    snap = poll(device_4x4((HEEL, EMPTY)), FORCES)
    heel, toe = snap.rois
    # by hand: forces 1, 2, 0.5 in contact (channel 9 reads 0 N: no contact)
    assert heel.name == "heel" and heel.channels == (4, 5, 8, 9)
    assert heel.force_n == pytest.approx(3.5, abs=1e-6)
    assert heel.peak_n == pytest.approx(2.0, abs=1e-6)
    assert heel.area_mm2 == pytest.approx(3 * CELL_MM2)
    # x: (1 * 0 + 2 * 2.5 + 0.5 * 0) / 3.5; y: (1 * 2.5 + 2 * 2.5 + 0.5 * 5) / 3.5
    assert heel.cop_mm == pytest.approx((5.0 / 3.5, 10.0 / 3.5), abs=1e-6)
    assert (toe.force_n, toe.peak_n, toe.area_mm2, toe.cop_mm) == (0.0, 0.0, 0.0, None)
    # the whole array is untouched by the regions
    assert snap.total_force_n == pytest.approx(10.5, abs=1e-6)


def test_a_disabled_channel_is_not_in_its_roi() -> None:
    snap = poll(device_4x4((HEEL,), disabled=(5,)), FORCES)
    (heel,) = snap.rois
    assert heel.channels == (4, 8, 9)
    assert heel.force_n == pytest.approx(1.5, abs=1e-6)
    assert heel.area_mm2 == pytest.approx(2 * CELL_MM2)


def test_the_frame_jsons_rois_equal_the_sums_over_their_cells_in_the_frame() -> None:
    snap = poll(device_4x4((HEEL, EMPTY)), FORCES)
    frame = json.loads(encode_frame(snap, 1, None))
    assert [r["name"] for r in frame["rois"]] == ["heel", "toe"]
    for roi in frame["rois"]:
        slots = roi["channels"]  # the frame's channel arrays hold every channel: index = slot
        cells = [frame["force_n"][k] for k in slots]
        touching = [f for f, k in zip(cells, slots, strict=True) if f is not None and f > 0
                    and frame["status"][k] == 0]  # fmt: skip
        assert roi["force_n"] == pytest.approx(math.fsum(touching), abs=1e-6)
        assert roi["peak_n"] == pytest.approx(max(touching, default=0.0), abs=1e-6)
        assert roi["area_mm2"] == pytest.approx(len(touching) * CELL_MM2)
    assert frame["rois"][0]["force_n"] == pytest.approx(3.5, abs=1e-6)
    assert frame["rois"][1]["cop_x_mm"] is None and frame["rois"][1]["cop_y_mm"] is None
    assert frame["rois"][0]["cop_x_mm"] == pytest.approx(5.0 / 3.5, abs=1e-6)
    assert json.loads(encode_frame(poll(device_4x4(()), FORCES), 1, None))["rois"] == []


def test_roi_metrics_are_in_base_units() -> None:
    snap = poll(device_4x4((HEEL, EMPTY)), FORCES)
    registry = make_registry(lambda: GatewaySnapshot.build({"arr": snap}, {}, 1), CollectorRegistry())
    text = generate_latest(registry).decode()

    def value(line_start: str) -> float:
        (line,) = [ln for ln in text.splitlines() if ln.startswith(line_start)]
        return float(line.rsplit(" ", 1)[1])

    assert value('tactile_roi_force_newtons{device="arr",roi="heel"}') == pytest.approx(3.5, abs=1e-6)
    assert value('tactile_roi_peak_force_newtons{device="arr",roi="heel"}') == pytest.approx(2.0, abs=1e-6)
    assert value('tactile_roi_contact_area_square_metres{device="arr",roi="heel"}') == pytest.approx(
        3 * CELL_MM2 * 1e-6
    )
    assert value('tactile_roi_center_of_pressure_metres{axis="x",device="arr",roi="heel"}') == pytest.approx(
        5.0 / 3.5 * 1e-3, abs=1e-9
    )
    assert value('tactile_roi_force_newtons{device="arr",roi="toe"}') == 0.0
    assert 'tactile_roi_center_of_pressure_metres{axis="x",device="arr",roi="toe"}' not in text


def test_a_snapshot_without_rois_has_none() -> None:
    snap = poll(device_4x4(()), FORCES)
    assert snap.rois == ()
    assert replace(snap).rois == ()


def test_the_mqtt_json_frame_carries_the_rois_and_the_binary_layout_does_not() -> None:
    snap = poll(device_4x4((HEEL,)), FORCES)
    fields = json.loads(encode_json_frame(snap, 3))
    (heel,) = fields["rois"]
    assert heel["name"] == "heel" and heel["channels"] == [4, 5, 8, 9]
    assert heel["force_n"] == pytest.approx(3.5, abs=1e-6)
    assert heel["area_mm2"] == pytest.approx(3 * CELL_MM2)
    assert "rois" not in decode_binary(encode_binary(frame_dict(snap, 3)))
    assert "rois" not in json.loads(encode_json_frame(poll(device_4x4(()), FORCES), 3))


def test_replayed_snapshots_carry_each_samples_own_rois() -> None:
    """A record played back (``view``): each held sample's regions are its own, not the last."""
    device = device_4x4((HEEL,))
    proc = DeviceProcessor(device, "record", 0.1)
    loads = [FORCES, [0.0] * 16]
    series = [
        ChannelSeries(np.array([0.0, 1.0]), np.array([1.0 / (M * f[k] + N) for f in loads]))
        for k in range(16)
    ]
    snaps, n = held_snapshots(proc, series)
    assert n == 2
    assert snaps[0].rois[0].force_n == pytest.approx(3.5, abs=1e-6)
    assert snaps[1].rois[0].force_n == 0.0 and snaps[1].rois[0].cop_mm is None


def test_check_config_lists_each_region_of_interest() -> None:
    from gateway.cli.config_cmd import _readout_lines

    lines = _readout_lines(device_4x4((HEEL, Roi("one", (7,)))))
    assert lines == [
        "    region of interest heel: 4 channels (ch04 .. ch09)",
        "    region of interest one: 1 channel (ch07)",
    ]
