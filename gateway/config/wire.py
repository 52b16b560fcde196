"""What a device table says about the wire: its register map, its clock, the checks made at
connect, and that the blocks a poll reads do not overlap (``device.parse_device`` uses it)."""

from __future__ import annotations

from typing import Final

from ..modbus.register_map import (
    BYTE_ORDERS,
    CLOCK_REGISTERS,
    CLOCK_UNITS,
    IDENTIFICATION_FIELDS,
    MAX_ADDRESS,
    REGISTER_TABLES,
    STATUS_BITMAP_STRIDE,
    DeviceChecks,
    DeviceClock,
    RegisterCheck,
    RegisterMap,
    register_blocks,
    status_registers,
)
from ..model.params import Interval
from .schema import DeviceConfig
from .tables import REQUIRED, Context, Table, show_value, type_name

__all__ = [
    "CHECK_KEYS",
    "CLOCK_KEYS",
    "REGISTER_KEYS",
    "check_overlaps",
    "parse_checks",
    "parse_clock",
    "parse_registers",
]

REGISTER_KEYS: Final = (
    "table",
    "adc_address",
    "float_address",
    "word_order",
    "byte_order",
    "status_address",
    "force_reference_address",
    "temperature_address",
)
CLOCK_KEYS: Final = ("address", "registers", "unit", "tick_s", "table")
CHECK_KEYS: Final = ("registers", "channel_count", "identification")
_REGISTER_CHECK_KEYS: Final = ("what", "table", "address", "value")
_COUNT_CHECK_KEYS: Final = ("table", "address")


def parse_registers(table: Table, n: int, encoding: str, profile: str | None) -> RegisterMap:
    status_span = 2 * STATUS_BITMAP_STRIDE + status_registers(n)
    value_key = "adc_address" if encoding == "adc" else "float_address"
    if not table.has(value_key):
        hint = f" ({profile} does not give it)" if profile else ""
        raise table.error(
            value_key,
            f"required key is missing{hint}: where the device keeps its {encoding} values; name a "
            'profile (profile = "tactile-sim" for the simulator, docs/profiles.md) or give '
            f"[bus.device.registers] {value_key} (`tactile-gateway scan` finds it)",
        )
    defaults = RegisterMap()
    return RegisterMap(
        adc_address=table.integer(
            "adc_address", defaults.adc_address, 0, MAX_ADDRESS + 1 - n, f" (the {n}-register ADC block)"
        ),
        float_address=table.integer(
            "float_address",
            defaults.float_address,
            0,
            MAX_ADDRESS + 1 - 2 * n,
            f" (the {2 * n}-register float32 block)",
        ),
        word_order=table.choice("word_order", "big", BYTE_ORDERS),
        byte_order=table.choice("byte_order", "big", BYTE_ORDERS),
        status_address=table.optional_address("status_address", None, MAX_ADDRESS + 1 - status_span),
        force_reference_address=table.optional_address(
            "force_reference_address", None, MAX_ADDRESS + 1 - 2 * n
        ),
        temperature_address=table.optional_address("temperature_address", None, MAX_ADDRESS + 1 - 2 * n),
        clock=None,
        table=table.choice("table", "input", REGISTER_TABLES),
    )


def parse_clock(ctx: Context, path: str, value: object) -> DeviceClock | None:
    """``clock = "host"`` (the host's monotonic clock) or a table naming the register."""
    if value is None or value == "host":
        return None
    if not isinstance(value, dict):
        raise ctx.error(
            path,
            f'expected "host" or a table {{ address = ..., registers = 1 | 2 | 4, unit = "ms" }}, '
            f"got {type_name(value)} {show_value(value)}",
        )
    table = Table(ctx, value, path, CLOCK_KEYS)
    registers = table.integer("registers", REQUIRED, 1, 4, " (1, 2 or 4: a 16, 32 or 64-bit counter)")
    if registers not in CLOCK_REGISTERS:
        raise table.error(
            "registers", f"{registers} is not allowed; allowed: 1, 2, 4 (16, 32 or 64-bit counter)"
        )
    address = table.integer("address", REQUIRED, 0, MAX_ADDRESS + 1 - registers)
    if table.has("unit") and table.has("tick_s"):
        raise table.error("tick_s", "give unit or tick_s, not both")
    if table.has("tick_s"):
        tick_s = table.number("tick_s", REQUIRED, Interval(0.0, 3600.0, low_inclusive=False), " s")
    else:
        tick_s = CLOCK_UNITS[table.choice("unit", REQUIRED, tuple(CLOCK_UNITS))]
    return DeviceClock(address, registers, tick_s, table.choice("table", "input", REGISTER_TABLES))


def parse_checks(table: Table, n: int) -> DeviceChecks:
    ctx = table.ctx
    registers: list[RegisterCheck] = []
    for rpath, item in table.tables("registers", "registers = [{ what = ..., address = ..., value = ... }]"):
        entry = Table(ctx, item, rpath, _REGISTER_CHECK_KEYS)
        registers.append(
            RegisterCheck(
                what=entry.string("what", "register", "a short description") or "register",
                table=entry.choice("table", "input", REGISTER_TABLES),
                address=entry.integer("address", REQUIRED, 0, MAX_ADDRESS),
                value=entry.integer("value", REQUIRED, 0, 0xFFFF),
            )
        )
    if table.has("channel_count"):
        count = table.table(
            "channel_count", _COUNT_CHECK_KEYS, "channel_count = { table = ..., address = ... }"
        )
        registers.append(
            RegisterCheck(
                what="channel count",
                table=count.choice("table", "holding", REGISTER_TABLES),
                address=count.integer("address", REQUIRED, 0, MAX_ADDRESS),
                value=n,
            )
        )
    ident = table.table("identification", IDENTIFICATION_FIELDS, "identification = { product_code = ... }")
    expected = tuple(
        (key, ident.required_string(key, "the text the device reports"))
        for key in IDENTIFICATION_FIELDS
        if ident.has(key)
    )
    return DeviceChecks(tuple(registers), expected)


def check_overlaps(ctx: Context, path: str, device: DeviceConfig) -> None:
    keys = {
        "status": "status_address",
        "adc": "adc_address",
        "float": "float_address",
        "force_reference": "force_reference_address",
        "temperature": "temperature_address",
        "device_time": "address",
    }
    blocks = register_blocks(device)
    for i, later in enumerate(blocks):
        for earlier in blocks[:i]:
            if later.kind == earlier.kind and later.address <= earlier.end and earlier.address <= later.end:
                # the clock is the block a user adds over a map, so it carries the blame
                blamed, other = (earlier, later) if earlier.purpose == "device_time" else (later, earlier)
                table = "clock" if blamed.purpose == "device_time" else "registers"
                raise ctx.error(
                    f"{path}.{table}.{keys[blamed.purpose]}",
                    f"the {blamed.name} block {blamed.address}..{blamed.end} overlaps the {other.name} block "
                    f"{other.address}..{other.end}; register blocks must not overlap",
                )
