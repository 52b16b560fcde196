"""What the gateway does with a device, in words: where its values come from, what turns them
into force, which effects are tracked and by which clock, where each channel's parameters
come from, and which forces rest on assumed circuit values rather than on a calibration.
A ``ratio`` front end (``gateway.model.RatioFrontEnd``) assumes no circuit value: its
readings are in units of the board's unknown reference resistor, so its forces rest on a
calibration: a channel without one reads ``uncalibrated``, no force (the default parameters
are in ohm and do not apply), and the lines say how to calibrate it.

``check-config`` and ``poll-once`` print these lines, so a user can see whether drift
correction is on without reading the code.
"""

from __future__ import annotations

from collections import Counter

from ..config import DeviceConfig, Encoding
from ..model import RatioFrontEnd
from ..model.curves import CurveChannel

__all__ = ["device_summary"]

_SOURCE_TEXT = {
    "defaults": "the defaults (docs/parameters.md)",
    "config": "the device's [bus.device.model.params]",
    "calibration": "the calibration file",
    "channel": "the channel's own entry",
}


def _clock(device: DeviceConfig) -> str:
    clock = device.registers.clock
    if clock is None:
        return "timed by the host's monotonic clock"
    return f"timed by the device clock ({clock.table} {clock.address}, {clock.unit}; the host's if it stalls)"


def _values(device: DeviceConfig) -> str:
    frame = device.registers.frame
    if frame is not None:
        return f"values: {frame.describe()}"
    regs = device.registers
    if device.encoding is Encoding.ADC:
        return f"values: ADC counts, uint16, {regs.table} registers {regs.adc_address}+{device.n_channels}"
    span = f"{regs.float_address}+{2 * device.n_channels}"
    return f"values: resistance in ohm, float32, {regs.table} registers {span}"


def _tracking(device: DeviceConfig) -> list[str]:
    """One line per way channels are read, with the effects tracked and the clock."""
    chans = device.enabled_channels
    if device.encoding is Encoding.OUTPUT:
        drift = device.output_drift
        if drift is None or not drift.active:
            return [
                f"force: the device's own calibrated output, passed through "
                f"({len(chans)} channels; no drift correction)"
            ]
        return [
            f"force: the device's own calibrated output with drift correction ({drift.form}), "
            f"{_clock(device)} ({len(chans)} channels)"
        ]
    lines = []
    by_way: Counter[str] = Counter()
    for ch in chans:
        if isinstance(ch.conversion, CurveChannel) and ch.conversion.table_kind != "curve":
            way = f"calibration {ch.conversion.table_kind} (static: no drift correction)"
        elif isinstance(ch.conversion, CurveChannel):
            way = f"calibration curve {ch.conversion.describe()}"
            if ch.conversion.drift.active:
                way += f" (drift correction on, {_clock(device)})"
            else:
                way += " (no drift correction)"
        elif device.needs_calibration(ch):
            way = "none: reads `uncalibrated` (r/R_ref without a calibration; see `assumes:`)"
        else:
            tracked = [e for e in ch.effects if e in ("creep", "hysteresis", "creep2", "temperature")]
            dynamic = [e for e in tracked if e != "temperature"]
            way = f"physical model, effects {', '.join(ch.effects)}"
            way += (
                f" (drift correction on: {', '.join(dynamic)}, {_clock(device)})"
                if dynamic
                else " (no drift correction)"
            )
        by_way[way] += 1
    for way, count in by_way.items():
        lines.append(f"force: {way}: {count} channel{'s' if count != 1 else ''}")
    return lines


def _sources(device: DeviceConfig) -> str:
    if device.encoding is Encoding.OUTPUT:
        return "parameters: none of ours (the device turns its readings into force with its own table)"
    counts: Counter[tuple[str, ...]] = Counter(ch.params_source for ch in device.channels)
    parts = [
        f"{n} from {' + '.join(_SOURCE_TEXT[s] for s in source)}" for source, n in sorted(counts.items())
    ]
    return "parameters: " + "; ".join(parts)


def _assumptions(device: DeviceConfig) -> str:
    """Which forces rest on assumed circuit values, which on a calibration."""
    chans = device.enabled_channels
    if device.encoding is Encoding.OUTPUT:
        return "assumes: nothing of the circuit (the device reports force itself)"
    calibrated = sum(1 for ch in chans if "calibration" in ch.params_source)
    rest = len(chans) - calibrated
    if device.encoding is Encoding.ADC and isinstance(device.front_end, RatioFrontEnd):
        return _ratio_assumptions(device, device.front_end, calibrated)
    circuit = (
        "the front end's values (reference resistor, full scale)"
        if device.encoding is Encoding.ADC
        else "nothing of the circuit (the device reports ohm)"
    )
    if not rest:
        return f"assumes: {circuit}; forces rest on the calibration of every channel"
    if calibrated:
        return f"assumes: {circuit}; {calibrated} channels calibrated, {rest} on default parameters"
    return f"assumes: {circuit} and the default sensor parameters: no channel is calibrated (see `calibrate`)"


def _ratio_assumptions(device: DeviceConfig, front_end: RatioFrontEnd, calibrated: int) -> str:
    """A ratio front end assumes only the divider's topology; its readings are in units of the
    unknown reference resistor, where the default sensor parameters (ohm) mean nothing: a
    channel without a calibration or parameters of its own reads ``uncalibrated`` (no force)."""
    side = (
        "rise with load: sensor on the high side"
        if front_end.rises_with_load
        else ("fall with load: sensor below a pull-up")
    )
    flag = "true" if front_end.rises_with_load else "false"
    circuit = (
        f"nothing of the circuit but its topology (rises_with_load = {flag}: counts {side}); "
        "readings are relative, in units of the unknown reference resistor"
    )
    chans = device.enabled_channels
    needing = sum(1 for ch in chans if device.needs_calibration(ch))
    given = len(chans) - calibrated - needing
    parts = [f"{calibrated} channels calibrated"] if calibrated else []
    if given:
        parts.append(f"{given} on parameters given in the configuration (in units of R_ref)")
    if not needing:
        if not given:
            return f"assumes: {circuit}; forces rest on the calibration of every channel"
        return f"assumes: {circuit}; " + ", ".join(parts)
    how = (
        f"{needing} channels read `uncalibrated` (no force: the default sensor parameters are in ohm "
        "and do not apply) until calibrated: record them under known loads "
        "(`tactile-gateway record -c CONFIG --duration S --out RECORD.csv`), then "
        "`tactile-gateway calibrate RECORD.csv --model auto --out CAL.toml --install CONFIG`"
    )
    lead = ", ".join(parts) + ", " if parts else "no channel is calibrated: "
    return f"assumes: {circuit}; {lead}{how}"


def device_summary(device: DeviceConfig) -> list[str]:
    """The lines (module docstring), without indentation."""
    lines = [_values(device), *_tracking(device), _sources(device), _assumptions(device)]
    for w in device.registers.setup:
        lines.append(f"set-up at connect: {w.describe()}")
    for name, writes in device.registers.actions:
        lines.append(f"action {name}: " + "; ".join(w.describe() for w in writes))
    if not device.registers.setup and not device.registers.actions:
        lines.append("writes: none (nothing is ever written to this device)")
    return lines
