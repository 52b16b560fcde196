"""Issue 31 §6: a register table, a device's encoding and a frame's words are enums
(``keys.Choice``): they equal the configuration's strings, and a misspelt word is an error
naming every allowed one, never a read of the other table or a default."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import pytest

from gateway.errors import ConfigError
from gateway.modbus.plan import ReadRequest
from gateway.modbus.register_map import (
    Encoding,
    FrameBlock,
    FrameQuantity,
    FrameTable,
    RegisterKind,
    RegisterMap,
    ValueFrame,
    frame_space,
    register_blocks,
)
from gateway.modbus.virtual import VirtualDevice, VirtualTransport

ALLOWED_TABLES = "allowed: 'input', 'holding'"


def _bus() -> VirtualTransport:
    device = VirtualDevice()
    device.set_input(0, [5])
    device.set_holding(0, [7])
    return VirtualTransport("line", {1: device}, timeout_s=0.2)


async def test_a_misspelt_table_is_an_error_and_nothing_is_sent() -> None:
    vt = _bus()
    async with vt:
        with pytest.raises(
            ValueError, match=f"'inptu' is not allowed; did you mean 'input'\\?; {ALLOWED_TABLES}"
        ):
            await vt.read(1, ReadRequest("inptu", 0, 1, ("adc",)))
        misspelt: Any = "Holding"
        with pytest.raises(ValueError, match=ALLOWED_TABLES):
            await vt.read_registers(1, misspelt, 0, 1)
        assert await vt.read(1, ReadRequest("input", 0, 1, ("adc",))) == [5]
        assert await vt.read_registers(1, RegisterKind.HOLDING, 0, 1) == [7]
    assert vt.requests == [("input", 1, 0, 1), ("holding", 1, 0, 1)]


def test_a_vendor_space_has_no_register_table() -> None:
    with pytest.raises(ValueError, match="'fc0x42' is not allowed"):
        _ = ReadRequest("fc0x42", 0, 4, ("frame",)).table
    assert ReadRequest("holding@row3", 0, 4, ("frame",)).table is RegisterKind.HOLDING


def test_the_words_equal_the_file_strings_and_show_as_them() -> None:
    assert RegisterKind("input") is RegisterKind.INPUT and RegisterKind.INPUT == "input"
    assert (RegisterKind.INPUT.read_function, RegisterKind.HOLDING.read_function) == (4, 3)
    assert [str(e) for e in Encoding] == ["adc", "float32", "output"]
    assert repr(Encoding.ADC) == "'adc'" and f"{Encoding.FLOAT32}" == "float32"
    assert {"input": 1}[RegisterKind.INPUT] == 1  # a mapping keyed by the file's words


def test_tables_given_as_strings_become_members_and_a_misspelt_one_is_refused() -> None:
    regs = RegisterMap(table="holding")  # type: ignore[arg-type]
    assert regs.table is RegisterKind.HOLDING
    assert regs.clock is not None and regs.clock.table is RegisterKind.INPUT
    with pytest.raises(ConfigError, match=f"register map: table: 'Input' is not allowed.*{ALLOWED_TABLES}"):
        RegisterMap(table="Input")  # type: ignore[arg-type]
    with pytest.raises(ConfigError, match=f"register map: table: 4 is not allowed; {ALLOWED_TABLES}"):
        RegisterMap(table=4)  # type: ignore[arg-type]


def test_a_frame_names_its_quantity_and_table_by_member() -> None:
    frame = ValueFrame("force", "N", "uint16", "AB", 1.0, 0.0, "holding", (FrameBlock(0, 4),))  # type: ignore[arg-type]
    assert frame.quantity is FrameQuantity.FORCE and frame.table is FrameTable.HOLDING
    assert frame_space(frame.table) is RegisterKind.HOLDING
    assert frame_space(frame.table, row=2) == "holding@row2"


@dataclass(frozen=True)
class _Layout:
    encoding: Any
    n_channels: int
    registers: RegisterMap


def test_an_encoding_without_channel_registers_is_an_error_not_floats() -> None:
    regs = RegisterMap(status_address=None, clock=None)
    assert [b.name for b in register_blocks(_Layout(Encoding.ADC, 2, regs))] == ["adc"]
    assert [b.name for b in register_blocks(_Layout(Encoding.FLOAT32, 2, regs))] == ["float"]
    for encoding in ("adcc", Encoding.OUTPUT):
        with pytest.raises(ConfigError, match="has no channel registers without a frame"):
            register_blocks(_Layout(encoding, 2, regs))
