"""``gateway.modbus.plan``: the coalesced reads of a device's register map."""

from __future__ import annotations

import itertools
import math
from dataclasses import replace

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from gateway.config import DeviceConfig, RegisterMap, device_config_for
from gateway.modbus.plan import ReadRequest, block_registers, read_plan
from gateway.modbus.register_map import register_blocks
from gateway.model import SensorParams

# ----------------------------------------------------------------------------------------------
# Read plan


def device(
    n: int = 16,
    encoding: str = "adc",
    registers: RegisterMap | None = None,
) -> DeviceConfig:
    base = device_config_for("array1", 1, [SensorParams()] * n, min(4, n), 2.0)
    return replace(base, encoding=encoding, registers=registers or RegisterMap())


def test_plan_default_adc_device() -> None:
    plan = read_plan(device(), 125)
    assert plan == (
        ReadRequest("input", 16, 1, ("status",)),
        ReadRequest("input", 32, 1, ("status",)),
        ReadRequest("input", 48, 1, ("status",)),
        ReadRequest("input", 100, 16, ("adc",)),
    )


def test_plan_without_status_is_one_read() -> None:
    plan = read_plan(device(registers=RegisterMap(status_address=None)), 125)
    assert plan == (ReadRequest("input", 100, 16, ("adc",)),)


def test_plan_256_channels_merges_bitmaps_and_splits_the_adc_block() -> None:
    plan = read_plan(device(256), 125)
    assert plan == (
        ReadRequest("input", 16, 48, ("status",)),
        ReadRequest("input", 100, 125, ("adc",)),
        ReadRequest("input", 225, 125, ("adc",)),
        ReadRequest("input", 350, 6, ("adc",)),
    )


@pytest.mark.parametrize(("adc_address", "merged"), [(40, True), (41, True), (42, False)])
def test_plan_gap_of_at_most_8_registers_is_bridged(adc_address: int, merged: bool) -> None:
    regs = RegisterMap(adc_address=adc_address, status_address=0)
    plan = read_plan(device(registers=regs), 125)
    # Bitmaps at 0, 16, 32 (one register each, gaps of 15): the last one is 32.
    if merged:
        assert plan[-1] == ReadRequest("input", 32, adc_address + 16 - 32, ("status", "adc"))
        assert len(plan) == 3
    else:
        assert plan[-2:] == (
            ReadRequest("input", 32, 1, ("status",)),
            ReadRequest("input", adc_address, 16, ("adc",)),
        )


def test_plan_float_block_is_split_on_value_boundaries() -> None:
    plan = read_plan(device(64, "float32", RegisterMap(status_address=None)), 125)
    assert plan == (ReadRequest("input", 400, 124, ("float",)), ReadRequest("input", 524, 4, ("float",)))


def test_plan_odd_limit_with_floats_reads_whole_values() -> None:
    plan = read_plan(device(4, "float32", RegisterMap(status_address=None)), 3)
    assert [(r.address, r.count) for r in plan] == [(400, 2), (402, 2), (404, 2), (406, 2)]


def test_plan_bench_blocks_merge_when_adjacent() -> None:
    regs = RegisterMap(status_address=None, force_reference_address=1000, temperature_address=1036)
    plan = read_plan(device(16, "adc", regs), 125)
    # force 1000..1031, gap 1032..1035 (4 registers), temperature 1036..1067
    assert plan[-1] == ReadRequest("input", 1000, 68, ("force_reference", "temperature"))


def test_plan_limit_too_small_for_floats() -> None:
    with pytest.raises(ValueError, match="cannot hold a float32 value"):
        read_plan(device(4, "float32"), 1)
    adc_only = read_plan(device(4, "adc", RegisterMap(status_address=None)), 1)
    assert [(r.address, r.count) for r in adc_only] == [(100, 1), (101, 1), (102, 1), (103, 1)]


def test_block_registers_reassembles_split_reads() -> None:
    dev = device(64, "float32", RegisterMap(status_address=None))
    plan = read_plan(dev, 125)
    image = {a: a * 3 % 65536 for a in range(0, 1200)}
    responses = [(r, [image[a] for a in range(r.address, r.end + 1)]) for r in plan]
    (block,) = register_blocks(dev, clock=False)
    assert block_registers(block, responses) == [image[a] for a in range(400, 528)]
    with pytest.raises(ValueError, match="misses register 524"):
        block_registers(block, responses[:1])


@settings(max_examples=200, deadline=None)
@given(
    n=st.integers(1, 256),
    encoding=st.sampled_from(["adc", "float32"]),
    max_read=st.integers(2, 125),
    status=st.one_of(st.none(), st.integers(0, 300)),
    bench=st.booleans(),
    gap=st.integers(0, 12),
)
def test_plan_invariants(
    n: int, encoding: str, max_read: int, status: int | None, bench: bool, gap: int
) -> None:
    force = 2000 if bench else None
    temperature = 2000 + 2 * n + gap if bench else None
    regs = RegisterMap(
        adc_address=400, float_address=1000, status_address=status,
        force_reference_address=force, temperature_address=temperature,
    )  # fmt: skip
    dev = device(n, encoding, regs)
    plan = read_plan(dev, max_read)
    blocks = register_blocks(dev, clock=False)
    assert all(1 <= r.count <= max_read for r in plan)
    assert all(a.end < b.address for a, b in itertools.pairwise(plan))
    for block in blocks:
        for value in range(block.address, block.end + 1, block.value_registers):
            covering = [r for r in plan if r.address <= value <= r.end]
            assert len(covering) == 1
            assert covering[0].end >= value + block.value_registers - 1  # a float is never split
            assert block.purpose in covering[0].purpose
    # No read starts or ends in a gap between blocks.
    used = {a for b in blocks for a in range(b.address, b.end + 1)}
    assert all(r.address in used and r.end in used for r in plan)
    if bench and gap <= 8 and 4 * n + gap <= max_read - (max_read % 2):
        assert any(r.purpose == ("force_reference", "temperature") for r in plan)
    if status is None and not bench and encoding == "float32":
        assert len(plan) == math.ceil(2 * n / (max_read - max_read % 2))
