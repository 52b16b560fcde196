"""What a device table says about the wire: its register map, its clock, the checks made at
connect, and that the blocks a poll reads do not overlap (``device.parse_device`` uses it)."""

from __future__ import annotations

from typing import Final

from ..errors import ConfigError, DecodeError
from ..modbus.decode import order_parts
from ..modbus.register_map import (
    BYTE_ORDERS,
    CLOCK_REGISTERS,
    CLOCK_UNITS,
    FRAME_QUANTITIES,
    FRAME_TABLES,
    FRAME_TYPE_WIDTHS,
    IDENTIFICATION_FIELDS,
    MAX_ADDRESS,
    REGISTER_TABLES,
    DeviceChecks,
    DeviceClock,
    DeviceWrite,
    Encoding,
    FrameBlock,
    FrameQuantity,
    FrameTable,
    RegisterCheck,
    RegisterMap,
    ValueFrame,
    register_blocks,
    status_span,
)
from ..modbus.special_codes import SpecialCodes
from ..modbus.vendor_fc import VendorRead
from ..model.params import Interval
from .regions import RegionSet
from .schema import DeviceConfig
from .tables import REQUIRED, Context, Table, join_key, show_value, type_name

__all__ = [
    "CHECK_KEYS",
    "CLOCK_KEYS",
    "FRAME_KEYS",
    "REGISTER_KEYS",
    "check_overlaps",
    "parse_actions",
    "parse_checks",
    "parse_clock",
    "parse_frame",
    "parse_registers",
    "parse_setup",
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
FRAME_KEYS: Final = (
    "quantity",
    "unit",
    "type",
    "order",
    "scale",
    "offset",
    "table",
    "function_code",
    "request",
    "address",
    "values",
    "blocks",
    "row_select_address",
    "drift",
    "special",
)
_SPECIAL_KEYS: Final = ("saturated", "error", "saturated_from", "error_from")
#: The raw integer range of each value type a special code may name.
_RAW_RANGES: Final = {
    "uint16": (0, 0xFFFF),
    "int16": (-0x8000, 0x7FFF),
    "uint32": (0, 0xFFFF_FFFF),
    "int32": (-0x8000_0000, 0x7FFF_FFFF),
}
_BLOCK_KEYS: Final = ("address", "values", "row")
_REQUEST_KEYS: Final = ("address_bytes", "count_bytes", "count_unit", "byte_count_bytes")
_WRITE_KEYS: Final = ("what", "address", "value", "values", "function", "verify")
#: The byte orders of a frame's values (Telegraf's names; ``decode.order_parts``).
FRAME_ORDERS: Final = (
    "ABCD", "CDAB", "BADC", "DCBA", "AB", "BA", "ABCDEFGH", "HGFEDCBA", "BADCFEHG", "GHEFCDAB"
)  # fmt: skip
#: Default units of each quantity.
_DEFAULT_UNITS: Final = {
    FrameQuantity.COUNTS: "counts",
    FrameQuantity.RESISTANCE: "ohm",
    FrameQuantity.FORCE: "N",
    FrameQuantity.PRESSURE: "kPa",
}
_ANY_NUMBER: Final = Interval(-1e300, 1e300, low_inclusive=True)
_COUNT_CHECK_KEYS: Final = ("table", "address")


def parse_registers(
    table: Table, n: int, encoding: Encoding, profile: str | None, frame: ValueFrame | None = None
) -> RegisterMap:
    """``[bus.device.registers]``; with a ``frame`` the channel values come from it, and the
    table may give only the status, reference, temperature and clock addresses."""
    span = status_span(n)
    value_key = "adc_address" if encoding == Encoding.ADC else "float_address"
    if frame is not None:
        for key in ("adc_address", "float_address"):
            if table.has(key):
                raise table.error(
                    key, "the device's [bus.device.frame] says where its values are; drop this key"
                )
    elif not table.has(value_key):
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
        status_address=table.optional_address("status_address", None, MAX_ADDRESS + 1 - span),
        force_reference_address=table.optional_address(
            "force_reference_address", None, MAX_ADDRESS + 1 - 2 * n
        ),
        temperature_address=table.optional_address("temperature_address", None, MAX_ADDRESS + 1 - 2 * n),
        clock=None,
        table=table.choice("table", "input", REGISTER_TABLES),
        frame=frame,
    )


def parse_frame(table: Table, n: int, max_read: int, regions: RegionSet | None = None) -> ValueFrame | None:
    """``[bus.device.frame]``: the channel values' own layout, or None when absent.

    ``address`` + ``values`` (default: every channel) is a one-block frame; ``blocks`` lists
    several, each the next channels in order. A device made of ``regions`` has one block per
    region, ``regions.value_stride`` registers from value to value (the table, which may then
    be absent, says only what the values are and where they are read)."""
    if not table.data and regions is None:
        return None
    quantity = table.choice("quantity", "counts", tuple(FRAME_QUANTITIES))
    unit = table.choice("unit", _DEFAULT_UNITS[quantity], tuple(FRAME_QUANTITIES[quantity]))
    value_type = table.choice("type", "uint16", tuple(FRAME_TYPE_WIDTHS))
    order = table.choice("order", "ABCD", FRAME_ORDERS)
    try:
        order_parts(order, value_type)
    except DecodeError as exc:
        raise table.error("order", str(exc)) from None
    scale = table.number("scale", 1.0, _ANY_NUMBER)
    if scale == 0.0:
        raise table.error(
            "scale", "0 is out of range; allowed: any number but 0 (value = raw x scale + offset)"
        )
    offset = table.number("offset", 0.0, _ANY_NUMBER)
    source = table.choice("table", "input", FRAME_TABLES)
    vendor = None
    if source == FrameTable.VENDOR:
        code = table.integer("function_code", REQUIRED, 1, 127, " (a vendor-defined function code)")
        request = table.table("request", _REQUEST_KEYS, "request = { address_bytes = 2, count_bytes = 2 }")
        try:
            vendor = VendorRead(
                code,
                address_bytes=request.integer("address_bytes", 2, 0, 2, " bytes"),
                count_bytes=request.integer("count_bytes", 2, 0, 2, " bytes"),
                count_unit=request.choice("count_unit", "registers", ("registers", "bytes")),
                byte_count_bytes=request.integer("byte_count_bytes", 1, 1, 2, " bytes"),
            )
        except ConfigError as exc:
            raise table.error("function_code", str(exc)) from None
    else:
        for key in ("function_code", "request"):
            if table.has(key):
                raise table.error(key, f'only a vendor read has a {key} (table = "vendor")')
    width = FRAME_TYPE_WIDTHS[value_type]
    row_select = table.optional_address("row_select_address", None, MAX_ADDRESS)
    blocks: list[FrameBlock] = []
    if regions is not None:
        for key in ("address", "values", "blocks", "row_select_address"):
            if table.has(key):
                raise table.error(
                    key, "the regions say where the values are ([[bus.device.region]] address); drop this key"
                )
        if vendor is not None and regions.value_stride != width:
            raise table.error("table", "a vendor read answers its values back to back: no value_stride")
        blocks.extend(regions.blocks())
    elif table.has("blocks"):
        for key in ("address", "values"):
            if table.has(key):
                raise table.error(key, "give address and values, or blocks, not both")
        for bpath, item in table.tables("blocks", "blocks = [{ address = ..., values = ... }]"):
            entry = Table(table.ctx, item, bpath, _BLOCK_KEYS)
            values = entry.integer("values", REQUIRED, 1, n, f" (channels = {n})")
            blocks.append(_frame_block(entry, values, width, vendor is not None, max_read, row_select))
    else:
        values = table.integer("values", n, 1, n, f" (channels = {n})")
        if table.has("row"):
            raise table.error("row", "a row belongs to a block: blocks = [{ address, values, row }]")
        blocks.append(_frame_block(table, values, width, vendor is not None, max_read, None))
    total = sum(b.values for b in blocks)
    if total != n:
        raise table.error(
            "blocks" if table.has("blocks") else "values",
            f"the frame's blocks carry {total} values for channels = {n}; they must carry one per channel",
        )
    if row_select is None and any(b.row is not None for b in blocks):
        raise table.error(
            "row_select_address", "required key is missing: blocks name rows; where is the row written?"
        )
    if row_select is not None and any(b.row is None for b in blocks):
        raise table.error("blocks", "with row_select_address every block names its row (row = 0, 1, ...)")
    special = _parse_special(table, value_type)
    try:
        return ValueFrame(
            quantity,
            unit,
            value_type,
            order,
            scale,
            offset,
            source,
            tuple(blocks),
            vendor,
            row_select,
            0 if regions is None or regions.value_stride == width else regions.value_stride,
            special,
        )
    except ConfigError as exc:
        raise table.ctx.error(table.path, str(exc)) from None


def _parse_special(frame: Table, value_type: str) -> SpecialCodes | None:
    """``special = { saturated = [...], saturated_from = N, error = [...], error_from = N }``:
    raw integers (before scale and offset) that are codes, not readings."""
    if not frame.has("special"):
        return None
    table = frame.table("special", _SPECIAL_KEYS, "special = { saturated = [65535], error_from = 65280 }")
    if value_type not in _RAW_RANGES:
        raise frame.error("special", f"special codes are integers; a {value_type} frame has none")
    low, high = _RAW_RANGES[value_type]
    lists: dict[str, tuple[int, ...]] = {}
    for key in ("saturated", "error"):
        raw = table.data.get(key, [])
        if not isinstance(raw, list):
            raise table.error(key, f"expected an array of integers in {low}..{high}, got {show_value(raw)}")
        for i, value in enumerate(raw):
            if isinstance(value, bool) or not isinstance(value, int):
                raise table.ctx.error(
                    f"{table.at(key)}[{i}]", f"expected an integer in {low}..{high}, got {show_value(value)}"
                )
            if not low <= value <= high:
                raise table.ctx.error(
                    f"{table.at(key)}[{i}]",
                    f"{value} is out of range; allowed: {low}..{high} (a raw {value_type})",
                )
        lists[key] = tuple(int(v) for v in raw)
    saturated_from = table.integer("saturated_from", high, low, high) if table.has("saturated_from") else None
    error_from = table.integer("error_from", high, low, high) if table.has("error_from") else None
    special = SpecialCodes(lists["saturated"], lists["error"], saturated_from, error_from)
    return special if special.describe() else None


def _frame_block(
    entry: Table, values: int, width: int, vendor: bool, max_read: int, row_select: int | None
) -> FrameBlock:
    span = values * width
    if vendor:
        address = entry.integer("address", 0, 0, 0xFFFF, " (the read's start field)")
    else:
        address = entry.integer(
            "address", REQUIRED, 0, MAX_ADDRESS + 1 - span, f" (a block of {span} registers)"
        )
    row = entry.integer("row", 0, 0, 0xFFFF) if entry.has("row") else None
    if not vendor and (row is not None or row_select is not None) and span > max_read:
        raise entry.error(
            "values", f"{span} registers behind a row select need one read; allowed: at most {max_read}"
        )
    return FrameBlock(address, values, row)


def _parse_write(ctx: Context, path: str, item: dict[str, object]) -> DeviceWrite:
    entry = Table(ctx, item, path, _WRITE_KEYS)
    what = entry.string("what", "write", "a short description") or "write"
    if entry.has("value") == entry.has("values"):
        raise ctx.error(path, "give value (one register) or values (several), exactly one of them")
    values: tuple[int, ...]
    if entry.has("value"):
        values = (entry.integer("value", REQUIRED, 0, 0xFFFF),)
    else:
        raw = entry.data["values"]
        if (
            not isinstance(raw, list)
            or not raw
            or not all(isinstance(v, int) and not isinstance(v, bool) and 0 <= v <= 0xFFFF for v in raw)
        ):
            raise entry.error(
                "values", f"expected an array of 1..123 integers in 0..65535, got {show_value(raw)}"
            )
        values = tuple(int(v) for v in raw)
    function = entry.integer("function", 6 if len(values) == 1 else 16, 6, 16)
    if function not in (6, 16):
        raise entry.error("function", f"{function} is not allowed; allowed: 6 (one register), 16 (several)")
    if function == 6 and len(values) != 1:
        raise entry.error("function", "function 6 writes one register; use 16 for several")
    address = entry.integer("address", REQUIRED, 0, MAX_ADDRESS + 1 - len(values), " (a holding register)")
    return DeviceWrite(what, address, values, function, entry.boolean("verify", True))


def parse_setup(table: Table) -> tuple[DeviceWrite, ...]:
    """``[[bus.device.setup]]``: the writes made at every connect, in order."""
    return tuple(
        _parse_write(table.ctx, wpath, item) for wpath, item in table.tables("setup", "[[bus.device.setup]]")
    )


def parse_actions(table: Table) -> tuple[tuple[str, tuple[DeviceWrite, ...]], ...]:
    """``[bus.device.actions]``: name = [{ what, address, value }, ...], run on request."""
    raw = table.raw_table("actions", "[bus.device.actions]")
    out: list[tuple[str, tuple[DeviceWrite, ...]]] = []
    for name, steps in raw.items():
        apath = join_key(table.at("actions"), name)
        if not isinstance(steps, list) or not steps:
            raise table.ctx.error(
                apath,
                f"expected an array of writes [{{ address = ..., value = ... }}], got {show_value(steps)}",
            )
        writes = []
        for i, item in enumerate(steps):
            if not isinstance(item, dict):
                raise table.ctx.error(
                    f"{apath}[{i}]", f"expected a table, got {type_name(item)} {show_value(item)}"
                )
            writes.append(_parse_write(table.ctx, f"{apath}[{i}]", item))
        out.append((name, tuple(writes)))
    return tuple(out)


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
        "frame": "address",
    }
    blocks = register_blocks(device)
    for i, later in enumerate(blocks):
        for earlier in blocks[:i]:
            if later.kind == earlier.kind and later.address <= earlier.end and earlier.address <= later.end:
                # the clock is the block a user adds over a map, so it carries the blame
                blamed, other = (earlier, later) if earlier.purpose == "device_time" else (later, earlier)
                table = {"device_time": "clock", "frame": "frame"}.get(blamed.purpose, "registers")
                raise ctx.error(
                    f"{path}.{table}.{keys[blamed.purpose]}",
                    f"the {blamed.name} block {blamed.address}..{blamed.end} overlaps the {other.name} block "
                    f"{other.address}..{other.end}; register blocks must not overlap",
                )
