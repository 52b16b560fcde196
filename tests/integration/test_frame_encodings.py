"""Every value encoding and byte order round-trips through a simulated device: a pymodbus 3.16
server holds registers written by the simulator's own encoder (``sim_device.encodings``, from
Telegraf's documentation, independent of the gateway), and the gateway reads them over Modbus
TCP through a ``[bus.device.frame]`` of that type and order, scale and offset included, from
holding and input registers. Expected values are the raw values times scale plus offset,
computed here."""

from __future__ import annotations

import contextlib

import pytest
from pymodbus.simulator import DataType, SimData, SimDevice

from gateway.config import GatewayConfig, parse_config
from gateway.runtime.sampler import sample_device
from sim_device.encodings import encode
from sim_device.modbus_server import serve_device_tcp

#: raw values per type (the extremes of the integer types included), and a scale and offset
CASES: dict[str, tuple[list[float], float, float]] = {
    "uint16": ([0, 1, 1234, 65535], 0.001, 0.0),
    "int16": ([-32768, -1, 0, 32767], 0.01, 5.0),
    "uint32": ([0, 70000, 4294967295, 123456789], 1e-6, 0.0),
    "int32": ([-2147483648, -1, 0, 2147483647], 1.0, -10.0),
    "float32": ([1.5, -0.25, 3.0e38, 0.0], 2.0, 0.0),
    "float64": ([1.5, -2.5e-300, 1.0e300, 3.141592653589793], 1.0, 1.0),
}
ORDERS = ("ABCD", "CDAB", "BADC", "DCBA")
WIDTH = {"uint16": 1, "int16": 1, "uint32": 2, "int32": 2, "float32": 2, "float64": 4}
#: each case's first register: 16 registers apart, one case per (type, order)
LAYOUT = {(t, o): 16 * k for k, (t, o) in enumerate((t, o) for t in CASES for o in ORDERS)}


def serve(registers: list[int]) -> contextlib.AbstractAsyncContextManager[int]:
    """The same registers as holding and input registers of device 1, over Modbus TCP."""
    table = [SimData(0, values=registers, datatype=DataType.REGISTERS)]
    bits = [SimData(0, count=16, values=False, datatype=DataType.BITS)]
    return serve_device_tcp(SimDevice(id=1, simdata=(bits, bits, table, table)))


def image() -> list[int]:
    regs = [0] * (16 * len(LAYOUT))
    for (value_type, order), address in LAYOUT.items():
        words = encode(CASES[value_type][0], value_type, order)
        regs[address : address + len(words)] = words
    return regs


def device_config(port: int, value_type: str, order: str, table: str) -> GatewayConfig:
    _, scale, offset = CASES[value_type]
    address = LAYOUT[(value_type, order)]
    frame = f'type = "{value_type}"\norder = "{order}"\nscale = {scale!r}\noffset = {offset!r}\n'
    return parse_config(_frame_text(port, frame + f'table = "{table}"\naddress = {address}'))


async def test_every_type_and_order_round_trips_through_a_simulated_device() -> None:
    checked = 0
    async with serve(image()) as port:
        for (value_type, order), _ in LAYOUT.items():
            table = "holding" if checked % 2 else "input"
            cfg = device_config(port, value_type, order, table)
            bus = cfg.buses[0]
            samples = await sample_device(bus, bus.devices[0], 0.0)
            counts = samples[0][1].counts
            raw, scale, offset = CASES[value_type]
            expected = [v * scale + offset for v in raw]
            where = f"{value_type} {order} ({table})"
            assert counts is not None, where
            if value_type == "float32":  # single precision on the wire
                assert counts.tolist() == pytest.approx(expected, rel=1e-7), where
            else:
                assert counts.tolist() == pytest.approx(expected, rel=1e-15, abs=0.0), where
            checked += 1
    assert checked == 24


async def test_telegraf_style_example_a_scaled_int16_and_a_cdab_float32() -> None:
    """Telegraf's README examples, as a user copies them: an INT16 voltage with byte_order "AB"
    and scale 0.1 (raw 2305 reads 230.5), and a FLOAT32 with byte_order "CDAB"."""
    regs = encode([2305, 2310, 2299, 0], "int16", "AB") + [0] * 12
    regs += encode([50.0, 49.5, 0.125, -1.0], "float32", "CDAB")
    async with serve(regs) as port:
        voltage = parse_config(
            _frame_text(port, 'type = "int16"\norder = "AB"\nscale = 0.1\ntable = "holding"\naddress = 0')
        )
        frequency = parse_config(
            _frame_text(port, 'type = "float32"\norder = "CDAB"\ntable = "input"\naddress = 16')
        )
        volts = (await sample_device(voltage.buses[0], voltage.buses[0].devices[0], 0.0))[0][1].counts
        hertz = (await sample_device(frequency.buses[0], frequency.buses[0].devices[0], 0.0))[0][1].counts
    assert volts is not None and volts.tolist() == pytest.approx([230.5, 231.0, 229.9, 0.0], rel=1e-12)
    assert hertz is not None and hertz.tolist() == [50.0, 49.5, 0.125, -1.0]


def _frame_text(port: int, frame: str) -> str:
    return f"""
[[bus]]
name = "line"
kind = "tcp"
host = "127.0.0.1"
port = {port}

[[bus.device]]
name = "arr"
device_id = 1
channels = 4
columns = 2
pitch_mm = 2.5

[bus.device.front_end]
kind = "high_side"
reference_ohm = 10000.0
supply_v = 3.3
adc_reference_v = 3.3
adc_bits = 16

[bus.device.frame]
quantity = "counts"
{frame}
"""
