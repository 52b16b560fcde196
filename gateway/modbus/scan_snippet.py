"""Presenting a scan (pure): constants grouped into runs, text in their bytes, and the TOML
snippet for a ``[[bus.device]]`` table from the best suggestions.
"""

from __future__ import annotations

from collections.abc import Iterable

from .scan_types import ConstantRegister, ScanResult

#: Constant registers the snippet suggests as identity checks.
IDENTITY_CHECKS = 3


def count_register(result: ScanResult) -> ConstantRegister | None:
    """A constant register that reads the best frame's length, the channel count: in the
    frame's table first, then the nearest to the frame."""
    frame = result.best_frame
    if frame is None:
        return None
    counts = [c for c in result.constants if c.value == frame.count]
    counts.sort(key=lambda c: (c.table != frame.table, abs(c.address - frame.address)))
    return counts[0] if counts else None


def identity_registers(result: ScanResult) -> list[ConstantRegister]:
    """Constant registers to check at connect: the first non-zero ones other than the
    channel count (identification and version candidates, to be checked by a person)."""
    count = count_register(result)
    found = [c for c in result.constants if c.value != 0 and c != count]
    return found[:IDENTITY_CHECKS]


def constant_runs(constants: Iterable[ConstantRegister]) -> list[tuple[str, int, list[int]]]:
    """Constants grouped into runs of consecutive addresses: (table, first address, values)."""
    runs: list[tuple[str, int, list[int]]] = []
    for c in constants:
        if runs and runs[-1][0] == c.table and runs[-1][1] + len(runs[-1][2]) == c.address:
            runs[-1][2].append(c.value)
        else:
            runs.append((c.table, c.address, [c.value]))
    return runs


def printable_text(values: Iterable[int]) -> list[str]:
    """Stretches of text in the registers' bytes (high byte first): at least two letters,
    digits or ``space . _ - /`` with a letter among them, as vendor or product codes are
    kept. Float32 and counter words rarely spell that much by chance."""
    found: list[str] = []
    current = ""
    for byte in (b for v in values for b in ((v >> 8) & 0xFF, v & 0xFF)):
        char = chr(byte)
        if char.isascii() and (char.isalnum() or char in " ._-/"):
            current += char
            continue
        found.append(current)
        current = ""
    found.append(current)
    return [t.strip() for t in found if len(t.strip()) >= 2 and any(c.isalpha() for c in t)]


def _toml_float(x: float) -> str:
    """Three significant digits, always a TOML float (``0.01``, ``2.0``, ``1e-05``)."""
    return repr(float(f"{x:.3g}"))


def config_snippet(result: ScanResult, device_id: int | None = None) -> str | None:
    """TOML text for the device's table from the best frame (and the best clock, if any);
    None without a frame candidate. A starting point to check, not a finished configuration."""
    frame = result.best_frame
    if frame is None:
        return None
    lines = ["[[bus.device]]"]
    if device_id is not None:
        lines.append(f"device_id = {device_id}")
    lines += [
        'encoding = "adc"',
        f"channels = {frame.count}",
        "",
        "[bus.device.registers]",
        f'table = "{frame.table}"',
        f"adc_address = {frame.address}",
        "",
        "# the read-out circuit does not show in the registers: check kind, supply and resistor",
        "# against the board (docs/front-ends.md)",
        "[bus.device.front_end]",
        'kind = "high_side"             # or "low_side" (pull-up), "transimpedance"',
        "supply_v = 3.3",
        "reference_ohm = 10000.0",
        f"adc_bits = {frame.bits}              # the smallest width that holds the codes seen",
    ]
    clock = result.best_clock
    if clock is not None:
        lines += [
            "",
            "[bus.device.clock]",
            f'table = "{clock.table}"',
            f"address = {clock.address}",
            f"registers = {clock.registers}",
            f'unit = "{clock.unit}"' if clock.unit is not None else f"tick_s = {_toml_float(clock.tick_s)}",
        ]
    lines += _checks(result)
    return "\n".join(lines) + "\n"


def _checks(result: ScanResult) -> list[str]:
    """The ``[bus.device.checks]`` table from the constant registers (none: no lines)."""
    identity, count = identity_registers(result), count_register(result)
    if not identity and count is None:
        return []
    lines = ["", "[bus.device.checks]"]
    if identity:
        lines += [
            "# constant during the scan: keep those that identify the board (product id, version),",
            "# drop settings that may change",
            "registers = [",
        ]
        lines += [
            f'    {{ what = "identifier", table = "{c.table}", address = {c.address}, '
            f"value = 0x{c.value:04X} }},"
            for c in identity
        ]
        lines.append("]")
    if count is not None:
        lines.append(
            f'channel_count = {{ table = "{count.table}", address = {count.address} }}'
            f"   # reads {count.value}, the frame's length"
        )
    return lines
