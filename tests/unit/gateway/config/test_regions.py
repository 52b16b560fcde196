"""Devices made of regions (``[[bus.device.region]]``): channel names and drawn positions
(hand-computed, after each rotation), register addresses in registers or bytes with a value
stride, and the precise refusals (overlaps, duplicates, counts, channel budget, odd bytes,
regions drawn over each other)."""

from __future__ import annotations

import re

import pytest

from gateway.config import GatewayConfig, parse_config
from gateway.config.regions import Region
from gateway.config.schema import MAX_CHANNELS
from gateway.errors import ConfigError

HEAD = """
[[bus]]
name = "line"
kind = "tcp"
host = "127.0.0.1"
port = 502

[[bus.device]]
name = "hand"
device_id = 1
{device}

[bus.device.frame]
quantity = "counts"
table = "holding"
{frame}

[bus.device.front_end]
kind = "high_side"
supply_v = 5.0
reference_ohm = 10000.0
adc_bits = 16
"""


def region(name: str, **keys: object) -> str:
    lines = [f'name = "{name}"']
    for key, value in keys.items():
        lines.append(f"{key} = {value!r}" if not isinstance(value, str) else f'{key} = "{value}"')
    return "[[bus.device.region]]\n" + "\n".join(lines) + "\n"


def config(*regions: str, device: str = "", frame: str = "") -> GatewayConfig:
    return parse_config(HEAD.format(device=device, frame=frame) + "\n".join(regions))


def refusal(*regions: str, device: str = "", frame: str = "") -> str:
    with pytest.raises(ConfigError) as info:
        config(*regions, device=device, frame=frame)
    return str(info.value)


def test_regions_give_the_channels_their_names_and_drawn_positions_after_rotation() -> None:
    # 2 x 3 cells each; pitch 2 mm across, 3 mm down
    common = {"rows": 2, "columns": 3, "pitch_x_mm": 2.0, "pitch_y_mm": 3.0}
    cfg = config(
        region("a", address=0, x_mm=10.0, y_mm=20.0, rotation_deg=0, **common),
        region("b", address=6, x_mm=0.0, y_mm=40.0, rotation_deg=90, **common),
        region("c", address=12, x_mm=50.0, y_mm=0.0, rotation_deg=180, **common),
        region("d", address=18, x_mm=70.0, y_mm=0.0, rotation_deg=270, **common),
    )
    dev = cfg.buses[0].devices[0]
    assert dev.n_channels == 24
    assert [r.name for r in dev.regions] == ["a", "b", "c", "d"]
    assert [(r.first_channel, r.n_channels, r.address) for r in dev.regions] == [
        (0, 6, 0),
        (6, 6, 6),
        (12, 6, 12),
        (18, 6, 18),
    ]
    assert dev.regions[1].channel_slice == slice(6, 12)
    pos = {ch.name: (ch.x_mm, ch.y_mm) for ch in dev.channels}
    # unrotated: cell (row, col) at (x + 2 col, y + 3 row)
    assert pos["a-r0c0"] == (10.0, 20.0)
    assert pos["a-r1c2"] == (14.0, 23.0)
    # 90 deg clockwise on the drawing (y down): (u, v) -> (-v, u), shifted so the drawn
    # top-left cell is at (x, y): x = 0 + 3 (rows-1) - 3 row, y = 40 + 2 col
    assert pos["b-r0c0"] == (3.0, 40.0)
    assert pos["b-r0c2"] == (3.0, 44.0)
    assert pos["b-r1c0"] == (0.0, 40.0)
    assert pos["b-r1c2"] == (0.0, 44.0)
    # 180 deg: x = 50 + 2 (2 - col), y = 0 + 3 (1 - row)
    assert pos["c-r0c0"] == (54.0, 3.0)
    assert pos["c-r1c2"] == (50.0, 0.0)
    # 270 deg: (u, v) -> (v, -u): x = 70 + 3 row, y = 0 + 2 (2 - col)
    assert pos["d-r0c0"] == (70.0, 4.0)
    assert pos["d-r1c0"] == (73.0, 4.0)
    assert pos["d-r0c2"] == (70.0, 0.0)
    # channels are the regions' taxels in region order, row-major within a region
    assert [ch.name for ch in dev.channels[:7]] == [
        "a-r0c0", "a-r0c1", "a-r0c2", "a-r1c0", "a-r1c1", "a-r1c2", "b-r0c0"
    ]  # fmt: skip


def test_a_region_s_order_and_origin_say_which_cell_each_value_is() -> None:
    cfg = config(
        region("p", address=0, rows=2, columns=3, pitch_mm=1.0, order="column-major", origin="bottom-left")
    )
    names = [ch.name for ch in cfg.buses[0].devices[0].channels]
    # column-major from the bottom-left: up the first column, then the next
    assert names == ["p-r1c0", "p-r0c0", "p-r1c1", "p-r0c1", "p-r1c2", "p-r0c2"]
    assert cfg.buses[0].devices[0].regions[0].group == "p"


def test_regions_without_a_place_are_drawn_one_below_the_other() -> None:
    cfg = config(
        region("top", address=0, rows=2, columns=2, pitch_mm=2.0),
        region("next", address=4, rows=1, columns=2, pitch_mm=2.0),
    )
    top, below = cfg.buses[0].devices[0].regions
    assert (top.x_mm, top.y_mm) == (0.0, 0.0)
    # the first region's cells reach y = 2 (+1 mm half a cell); one pitch of air, then the next
    assert (below.x_mm, below.y_mm) == (0.0, 6.0)


def test_byte_addresses_are_halved_and_the_stride_is_read_in_the_same_unit() -> None:
    # the public reading: byte addresses, one 16-bit value every 2 bytes
    byte = (
        config(
            region("index-tip", group="index", address=3000, rows=3, columns=3),
            region("index-nail", group="index", address=3018, rows=12, columns=8, x_mm=20.0),
            device='address_unit = "byte"\nvalue_stride = 2',
        )
        .buses[0]
        .devices[0]
    )
    assert [r.address for r in byte.regions] == [1500, 1509]
    assert [r.group for r in byte.regions] == ["index", "index"]
    frame = byte.registers.frame
    assert frame is not None
    assert [(b.address, b.values) for b in frame.blocks] == [(1500, 9), (1509, 96)]
    assert frame.value_stride == 1
    # the other reading: register addresses, each value in the first of two registers
    reg = (
        config(
            region("index-tip", address=3000, rows=3, columns=3),
            region("index-nail", address=3018, rows=12, columns=8, x_mm=20.0),
            device='address_unit = "register"\nvalue_stride = 2',
        )
        .buses[0]
        .devices[0]
    )
    frame = reg.registers.frame
    assert frame is not None and frame.value_stride == 2
    assert [(r.address, r.n_channels) for r in reg.regions] == [(3000, 9), (3018, 96)]


def test_an_odd_byte_address_is_refused_naming_it() -> None:
    message = refusal(
        region("tip", address=3001, rows=3, columns=3), device='address_unit = "byte"\nvalue_stride = 2'
    )
    assert "bus[0].device[0].region[0].address" in message
    assert "3001 is an odd byte address" in message


def test_a_stride_too_short_for_a_value_or_an_odd_byte_stride_is_refused() -> None:
    message = refusal(
        region("tip", address=0, rows=1, columns=2), device='address_unit = "byte"\nvalue_stride = 3'
    )
    assert "bus[0].device[0].value_stride: 3 bytes" in message and "even" in message
    message = refusal(
        region("tip", address=0, rows=1, columns=2), device="value_stride = 1", frame='type = "float32"'
    )
    assert "value_stride: 1 registers is shorter than one float32 value (2 registers)" in message


def test_regions_that_share_registers_are_refused_with_both_ranges() -> None:
    # bytes 3000..3017 are registers 1500..1508; bytes 3016.. start at register 1508
    message = refusal(
        region("tip", address=3000, rows=3, columns=3),
        region("nail", address=3016, rows=2, columns=2, x_mm=20.0),
        device='address_unit = "byte"\nvalue_stride = 2',
    )
    assert "bus[0].device[0].region[1].address" in message
    assert "region 'nail' (registers 1508..1511) overlaps region 'tip' (registers 1500..1508)" in message


def test_duplicate_region_names_and_wrong_counts_are_refused() -> None:
    message = refusal(
        region("tip", address=0, rows=1, columns=2), region("tip", address=10, rows=1, columns=2, x_mm=9.0)
    )
    assert "bus[0].device[0].region[1].name" in message and "duplicate region name 'tip'" in message
    message = refusal(region("tip", address=0, rows=3, columns=3, count=8))
    assert "bus[0].device[0].region[0].count: 8" in message and "rows x columns = 3 x 3 = 9" in message
    message = refusal(region("tip", address=0, rows=3, columns=3), device="channels = 10")
    assert "bus[0].device[0].channels: 10" in message and "the regions hold 9" in message


def test_more_channels_than_a_device_holds_is_refused_with_the_limit() -> None:
    rows = MAX_CHANNELS // 64 + 1
    message = refusal(
        region("a", address=0, rows=rows, columns=32, pitch_mm=1.0),
        region("b", address=20000, rows=rows, columns=32, pitch_mm=1.0, x_mm=100.0),
    )
    assert f"{2 * rows * 32} channels in all" in message and f"allowed: 1..{MAX_CHANNELS}" in message


def test_regions_drawn_over_each_other_are_refused() -> None:
    message = refusal(
        region("tip", address=0, rows=2, columns=2, pitch_mm=2.0, x_mm=0.0, y_mm=0.0),
        region("pad", address=10, rows=2, columns=2, pitch_mm=2.0, x_mm=3.0, y_mm=1.0),
    )
    assert "bus[0].device[0].region[1]" in message and "drawn over region 'tip'" in message


def test_bad_region_keys_name_their_allowed_values() -> None:
    message = refusal(region("tip", address=0, rows=2, columns=2, rotation_deg=45))
    assert re.search(r"region\[0\]\.rotation_deg: 45 is not allowed; allowed: 0, 90, 180, 270", message)
    message = refusal(region("tip", address=0, rows=0, columns=2))
    assert "region[0].rows: 0 is out of range; allowed: 1.." in message
    message = refusal(region("tip", address=0, rows=2, columns=2), frame="address = 0\nvalues = 4")
    assert "the regions say where the values are" in message


def test_a_device_without_regions_has_none() -> None:
    text = HEAD.format(device="channels = 4", frame="address = 0")
    dev = parse_config(text).buses[0].devices[0]
    assert dev.regions == ()
    assert [ch.name for ch in dev.channels] == ["ch00", "ch01", "ch02", "ch03"]


def test_region_is_a_frozen_value_that_checks_itself() -> None:
    r = Region("tip", "index", 9, 9, 3, 3, 2.0, 2.0, 0.0, 0.0, 0, 100)
    assert r.channel_slice == slice(9, 18)
    with pytest.raises(ConfigError, match=r"region 'tip': n_channels: 8 .* rows x columns = 9"):
        Region("tip", "index", 9, 8, 3, 3, 2.0, 2.0, 0.0, 0.0, 0, 100)
    with pytest.raises(ConfigError, match="rotation_deg: 30 is not allowed; allowed: 0, 90, 180, 270"):
        Region("tip", "index", 9, 9, 3, 3, 2.0, 2.0, 0.0, 0.0, 30, 100)
