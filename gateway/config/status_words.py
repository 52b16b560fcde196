"""``[[bus.device.status_word]]``: a device's named status words, read with every poll.

Each word is one 16-bit register (``table`` holding or input, the device's map's table by
default; ``address`` counted in the device's ``address_unit``: a byte address is register =
byte / 2). It is either named bits, ``bits = { 0 = "grasping", 1 = "force reached" }`` (states)
and ``errors = { 0 = "stall", 1 = "over-temperature" }`` (faults: the page draws them in red),
bits 0..15, each named once; or an enumerated code, ``codes = { 0 = "idle", 3 = "fault" }`` with
``error_codes = [3]``, codes 0..65535. The words go to the read plan (``register_blocks``), the
snapshot (``DeviceSnapshot.status_words``), the page and ``/metrics``.
"""

from __future__ import annotations

from typing import Any, Final

from ..modbus.register_map import MAX_ADDRESS, RegisterKind, RegisterMap
from ..modbus.status_word import StatusWord
from .tables import REQUIRED, Context, Table

__all__ = ["STATUS_WORD_KEYS", "parse_status_words"]

STATUS_WORD_KEYS: Final = ("name", "table", "address", "bits", "errors", "codes", "error_codes")
MAX_BIT: Final = 15
MAX_CODE: Final = 0xFFFF
#: the most status words of one device (each is one more register in every poll)
MAX_STATUS_WORDS: Final = 64


def _labels(table: Table, key: str, high: int, what: str) -> tuple[tuple[int, str], ...]:
    """A table of number = "label" (TOML keys are strings: "3" is 3)."""
    raw = table.data.get(key)
    if raw is None:
        return ()
    if not isinstance(raw, dict) or not raw:
        raise table.error(key, f'expected a table of {what} = "label", for example {{ 0 = "label" }}')
    out: list[tuple[int, str]] = []
    for k, label in raw.items():
        try:
            number = int(str(k), 0)
        except ValueError:
            raise table.error(key, f"{k!r} is not a {what}; allowed: 0..{high}") from None
        if not 0 <= number <= high:
            raise table.error(key, f"{what} {number} is out of range; allowed: 0..{high}")
        if not isinstance(label, str) or not label.strip():
            raise table.error(key, f"{what} {number}: expected a non-empty label (string), got {label!r}")
        out.append((number, label.strip()))
    return tuple(sorted(out))


def parse_status_words(
    ctx: Context, device: Table, registers: RegisterMap, unit: str
) -> tuple[StatusWord, ...]:
    """The device's ``[[bus.device.status_word]]`` (``unit``: its ``address_unit``); a word's
    table is by default the one its frame is read from (else the register map's)."""
    frame_table = registers.frame.table.value if registers.frame is not None else None
    default_table = RegisterKind(frame_table) if frame_table in ("holding", "input") else registers.table
    items = device.tables("status_word", "[[bus.device.status_word]]")
    if len(items) > MAX_STATUS_WORDS:
        raise device.error("status_word", f"{len(items)} status words; allowed: 0..{MAX_STATUS_WORDS}")
    words: list[StatusWord] = []
    seen: dict[str, str] = {}
    per_register = 2 if unit == "byte" else 1
    for path, item in items:
        table = Table(ctx, item, path, STATUS_WORD_KEYS)
        name = table.name("name")
        if name in seen:
            raise table.error("name", f"duplicate status word {name!r} (also {seen[name]}); names are unique")
        seen[name] = table.at("name")
        kind = RegisterKind(table.choice("table", default_table.value, tuple(k.value for k in RegisterKind)))
        raw_address = table.integer("address", REQUIRED, 0, (MAX_ADDRESS + 1) * per_register - 1, f" {unit}s")
        if unit == "byte" and raw_address % 2:
            raise table.error(
                "address",
                f"{raw_address} is an odd byte address; a register starts at an even byte "
                "(register = byte / 2)",
            )
        bits = _labels(table, "bits", MAX_BIT, "bit")
        errors = _labels(table, "errors", MAX_BIT, "bit")
        codes = _labels(table, "codes", MAX_CODE, "code")
        both = sorted({b for b, _ in bits} & {b for b, _ in errors})
        if both:
            raise table.error(
                "errors", f"bit {both[0]} is named in bits and in errors; a bit is one or the other"
            )
        if codes and (bits or errors):
            raise table.error(
                "codes", "a word is named bits (bits, errors) or an enumerated code (codes), not both"
            )
        if not (codes or bits or errors):
            raise table.error(
                "name", "give bits and/or errors (named bits 0..15), or codes (values 0..65535)"
            )
        error_codes = _error_codes(table, codes)
        words.append(StatusWord(name, kind, raw_address // per_register, bits, errors, codes, error_codes))
    return tuple(words)


def _error_codes(table: Table, codes: tuple[tuple[int, str], ...]) -> frozenset[int]:
    raw: Any = table.data.get("error_codes", [])
    if not isinstance(raw, list) or any(isinstance(c, bool) or not isinstance(c, int) for c in raw):
        raise table.error("error_codes", "expected a list of codes (integers 0..65535), for example [3, 4]")
    named = {c for c, _ in codes}
    for c in raw:
        if c not in named:
            raise table.error(
                "error_codes",
                f"{c} is not one of the codes named in codes; allowed: {sorted(named) or 'none'}",
            )
    return frozenset(raw)
