"""The report of ``tactile-gateway scan``: identification, notes and the suggestions of
``gateway.modbus.scan`` as text, or the whole scan as JSON.
"""

from __future__ import annotations

from typing import Any

from ..modbus.scan import ScanResult, config_snippet, constant_runs, printable_text
from ..modbus.scan_read import ScanRun
from ..modbus.scan_snippet import count_register

#: Frame candidates listed.
SHOWN_FRAMES = 5


def _values_text(values: list[int]) -> str:
    if len(values) >= 4 and len(set(values)) == 1:
        return f"0x{values[0]:04X} x{len(values)}"
    shown = " ".join(f"0x{v:04X}" for v in values[:12])
    return shown + (f" ... ({len(values) - 12} more)" if len(values) > 12 else "")


def _span(table: str, address: int, count: int) -> str:
    return f"{table} {address}" if count == 1 else f"{table} {address}-{address + count - 1}"


def report_lines(result: ScanResult, run: ScanRun, device_id: int) -> list[str]:
    """Identification, notes and suggestions as text."""
    lines: list[str] = []
    if run.identification:
        lines.append("identification (FC 43/14):")
        lines += [f"  {name}: {value}" for name, value in run.identification.items()]
    else:
        lines.append("identification (FC 43/14): no answer")
    lines += [f"note: {n}" for n in run.notes]
    if result.snapshots < 3:
        lines.append(f"note: {result.snapshots} round(s): clocks need 3, changes need 2 (--rounds)")
    lines += ["", "ADC frame candidates, best first:"]
    for i, f in enumerate(result.frames[:SHOWN_FRAMES], 1):
        kind = ", reads as float32 pairs (encoding float32?)" if f.float_like else ""
        lines.append(
            f"  {i}. {_span(f.table, f.address, f.count)}: {f.count} registers, {f.bits}-bit codes "
            f"(max {f.maximum}), {f.changed} of {f.count} changed, score {f.score:g}{kind}"
        )
    if not result.frames:
        lines.append("  none: no run of 4 or more readable registers that changes")
    lines.append("clock candidates:")
    for c in result.clocks:
        lines.append(
            f"  {_span(c.table, c.address, c.registers)}: {c.type_name} rising {c.rate_per_s:.4g}/s: "
            f"{c.description}"
        )
    if not result.clocks:
        lines.append("  none: no register rises steadily with time")
    lines.append("constant registers (identification/version candidates):")
    for table, address, values in constant_runs(result.constants):
        text = printable_text(values)
        quoted = "  text " + ", ".join(f'"{t}"' for t in text) if text else ""
        lines.append(f"  {_span(table, address, len(values))}: {_values_text(values)}{quoted}")
    if not result.constants:
        lines.append("  none")
    count = count_register(result)
    if count is not None:
        lines.append(f"  {count.table} {count.address} reads {count.value}: the channel count of frame 1?")
    snippet = config_snippet(result, device_id)
    if snippet is not None:
        lines += [
            "",
            "suggested configuration (a starting point: check it with tactile-gateway check-config):",
        ]
        lines += snippet.rstrip("\n").split("\n")
    return lines


def report_json(result: ScanResult, run: ScanRun, device_id: int, target: str) -> dict[str, Any]:
    """A JSON-ready view of the scan."""
    registers: dict[str, list[dict[str, Any]]] = {t: [] for t in result.tables}
    for s in result.registers:
        registers[s.table].append(
            {
                "address": s.address,
                "readable": s.readable,
                "min": s.minimum,
                "max": s.maximum,
                "distinct": s.distinct,
                "changed": s.changed,
                "last": s.last,
            }
        )
    return {
        "device_id": device_id,
        "target": target,
        "rounds": result.snapshots,
        "identification": run.identification,
        "notes": run.notes,
        "registers": registers,
        "frames": [
            {
                "table": f.table,
                "address": f.address,
                "count": f.count,
                "bits": f.bits,
                "changed": f.changed,
                "max": f.maximum,
                "score": f.score,
                "float_like": f.float_like,
            }
            for f in result.frames
        ],
        "clocks": [
            {
                "table": c.table,
                "address": c.address,
                "registers": c.registers,
                "type": c.type_name,
                "rate_per_s": c.rate_per_s,
                "unit": c.unit,
                "tick_s": c.tick_s,
                "description": c.description,
            }
            for c in result.clocks
        ],
        "constants": [
            {"table": c.table, "address": c.address, "value": c.value, "hex": f"0x{c.value:04X}"}
            for c in result.constants
        ],
        "config": config_snippet(result, device_id),
    }
