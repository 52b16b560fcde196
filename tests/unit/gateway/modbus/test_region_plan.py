"""The reads of a device made of regions: each region a register block, long blocks split
into legal reads (hand-counted), distant blocks never merged across a wide gap, and a value
stride read as every stride-th register."""

from __future__ import annotations

import math

import numpy as np

from gateway.config import DeviceConfig, parse_config
from gateway.modbus.image import RegisterImage, decode_sample
from gateway.modbus.plan import MAX_GAP_REGISTERS, MERGE_GAP, device_plan, read_plan

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

[bus.device.front_end]
kind = "high_side"
supply_v = 5.0
reference_ohm = 10000.0
adc_bits = 16
"""


def device(regions: list[tuple[str, int, int, int]], extra: str = "") -> DeviceConfig:
    """Regions as (name, address, rows, columns), each drawn right of the last."""
    text = HEAD.format(device=extra)
    for k, (name, address, rows, columns) in enumerate(regions):
        text += (
            f'[[bus.device.region]]\nname = "{name}"\naddress = {address}\nrows = {rows}\n'
            f"columns = {columns}\npitch_mm = 1.0\nx_mm = {100.0 * k}\ny_mm = 0.0\n"
        )
    return parse_config(text).buses[0].devices[0]


def test_a_96_value_nail_at_stride_1_is_one_request() -> None:
    plan = read_plan(device([("nail", 3000, 12, 8)]), 125)
    assert [(r.kind, r.address, r.count) for r in plan] == [("holding", 3000, 96)]


def test_a_finger_block_of_185_values_takes_2_requests() -> None:
    # tip 3x3, nail 12x8, pad 10x8 back to back: 9 + 96 + 80 = 185 registers from 3000
    finger = device([("tip", 3000, 3, 3), ("nail", 3009, 12, 8), ("pad", 3105, 10, 8)])
    plan = read_plan(finger, 125)
    assert [(r.address, r.count) for r in plan] == [(3000, 125), (3125, 60)]
    # a bus that allows 50 registers per read: ceil(185 / 50) = 4
    assert [r.count for r in read_plan(finger, 50)] == [50, 50, 50, 35]


def test_a_value_stride_of_2_reads_every_other_register_and_splits_on_values() -> None:
    # the same finger, each value in the first register of two: 185 values over 369 registers;
    # a read of at most 125 registers holds 63 values (offsets 0, 2, ..., 124)
    finger = device(
        [("tip", 3000, 3, 3), ("nail", 3018, 12, 8), ("pad", 3210, 10, 8)],
        'address_unit = "register"\nvalue_stride = 2',
    )
    plan = read_plan(finger, 125)
    assert len(plan) == math.ceil(185 / 63) == 3
    assert [(r.address, r.count) for r in plan] == [(3000, 125), (3126, 125), (3252, 117)]
    assert sum((r.count + 1) // 2 for r in plan) == 185


def test_blocks_far_apart_are_not_merged_across_a_wide_gap() -> None:
    far = device([("a", 0, 2, 5), ("b", 10 + MERGE_GAP + 1, 2, 5)])
    assert [(r.address, r.count) for r in read_plan(far, 125, max_gap=MAX_GAP_REGISTERS)] == [
        (0, 10),
        (26, 10),
    ]
    assert [(r.address, r.count) for r in device_plan(far, 125, MERGE_GAP, clock=True)] == [(0, 10), (26, 10)]
    near = device([("a", 0, 2, 5), ("b", 10 + MAX_GAP_REGISTERS, 2, 5)])
    assert [(r.address, r.count) for r in read_plan(near, 125, max_gap=MAX_GAP_REGISTERS)] == [(0, 28)]


def test_strided_values_decode_into_their_regions_channels() -> None:
    dev = device([("a", 10, 1, 3), ("b", 40, 1, 2)], 'address_unit = "byte"\nvalue_stride = 4')
    # byte 10 = register 5, byte 40 = register 20; a value every 2 registers
    assert [r.address for r in dev.regions] == [5, 20]
    registers = np.full(30, 0xEEEE, dtype=np.uint16)
    registers[[5, 7, 9, 20, 22]] = [100, 200, 300, 400, 500]
    image = RegisterImage.from_reads([("holding", 0, registers)])
    sample = decode_sample(dev, image)
    assert sample.counts is not None
    assert sample.counts.tolist() == [100, 200, 300, 400, 500]
    assert [r.count for r in read_plan(dev, 125)] == [5, 3]


def test_a_block_split_over_two_reads_decodes_whole() -> None:
    # the nail (3009..3104) straddles the reads 3000..3124 and 3125..3184
    finger = device([("tip", 3000, 3, 3), ("nail", 3009, 12, 8), ("pad", 3105, 10, 8)])
    plan = read_plan(finger, 100)
    assert [(r.address, r.count) for r in plan] == [(3000, 100), (3100, 85)]
    values = np.arange(185, dtype=np.uint16) + 7
    image = RegisterImage.from_reads(
        [(r.kind, r.address, values[r.address - 3000 : r.end - 2999]) for r in plan]
    )
    sample = decode_sample(finger, image)
    assert sample.counts is not None and sample.counts.tolist() == values.tolist()
