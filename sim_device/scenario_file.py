"""Scenario files: a TOML description of loads, temperatures and faults into a ``Scenario``.

The format is documented in ``docs/scenarios.md`` and in ``sim_device.scenarios``; every error
is a ``ScenarioError`` naming the source and the key. ``parse_scenario`` returns a
``ScenarioSpec``; ``Scenario.from_toml`` (above this module) binds it to the layout.
"""

from __future__ import annotations

import difflib
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

from .builtin_scenarios import builtin_indentation
from .profiles import ProfileBuilder, ScenarioError
from .scenario_parts import (
    DEFAULT_TEMPERATURE_C,
    FORCE_RANGE_N,
    TEMPERATURE_RANGE_C,
    VALID_EXCEPTION_CODES,
    ArrayLayout,
    FaultEvent,
    ForceSource,
    Indentation,
    ScenarioSpec,
    TemperatureProgram,
    UniformLoad,
)

_TOP_KEYS = (
    "name",
    "description",
    "repeat",
    "settled",
    "base_temperature_c",
    "load",
    "indentation",
    "temperature",
    "fault",
)
_FAULT_FIELDS = ("delay_s", "no_response", "exception_code", "garble", "drop_connection")
_CHANNEL_MODES = ("normal", "open", "short")


@dataclass
class _Ctx:
    source: str
    path: list[str] = field(default_factory=list)

    def key(self, *parts: str) -> str:
        return ".".join([*self.path, *parts]).replace(".[", "[")

    def error(self, key: str, message: str) -> ScenarioError:
        where = f"{self.source}: {key}: " if key else f"{self.source}: "
        return ScenarioError(where + message)


def _unknown_keys(table: Mapping[str, Any], allowed: Sequence[str], ctx: _Ctx, prefix: str) -> None:
    # the simulator's own copy of ``gateway.keys.check_keys``: sim_device never imports gateway
    for key in table:
        if key not in allowed:
            close = difflib.get_close_matches(key, list(allowed), n=1)
            hint = f" (did you mean {close[0]!r}?)" if close else ""
            raise ctx.error(
                f"{prefix}{'.' if prefix else ''}{key}", f"unknown key{hint}; allowed: {', '.join(allowed)}"
            )


def _number(
    table: Mapping[str, Any], key: str, ctx: _Ctx, prefix: str, default: float | None = None
) -> float:
    where = f"{prefix}.{key}" if prefix else key
    if key not in table:
        if default is None:
            raise ctx.error(where, "missing required key")
        return default
    value = table[key]
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise ctx.error(where, f"must be a finite number, got {value!r}")
    return float(value)


def _positive(
    table: Mapping[str, Any], key: str, ctx: _Ctx, prefix: str, default: float | None = None
) -> float:
    value = _number(table, key, ctx, prefix, default)
    if value <= 0.0:
        raise ctx.error(f"{prefix}.{key}" if prefix else key, f"must be > 0, got {value:g}")
    return value


def _pair(
    table: Mapping[str, Any], key: str, ctx: _Ctx, prefix: str, default: tuple[float, float]
) -> tuple[float, float]:
    if key not in table:
        return default
    value = table[key]
    ok = isinstance(value, list) and len(value) == 2
    ok = ok and all(
        not isinstance(v, bool) and isinstance(v, int | float) and math.isfinite(v) for v in value
    )
    if not ok:
        raise ctx.error(f"{prefix}.{key}", f"must be a list of two numbers [x, y] in mm, got {value!r}")
    return (float(value[0]), float(value[1]))


def _channels(table: Mapping[str, Any], ctx: _Ctx, prefix: str, n: int) -> tuple[int, ...] | None:
    value = table.get("channels", "all")
    if value == "all":
        return None
    if not isinstance(value, list) or not value:
        raise ctx.error(
            f"{prefix}.channels", f'must be "all" or a non-empty list of channel indices, got {value!r}'
        )
    for c in value:
        if isinstance(c, bool) or not isinstance(c, int) or not 0 <= c < n:
            raise ctx.error(f"{prefix}.channels", f"channel {c!r} is not an integer in 0..{n - 1}")
    return tuple(value)


def _parse_steps(
    table: Mapping[str, Any], ctx: _Ctx, prefix: str, unit: str, initial: float, allowed: tuple[float, float]
) -> ProfileBuilder:
    value_key = "force_n" if unit == "n" else "temperature_c"
    step_key, ramp_key, rate_key, amp_key = (
        f"step_{unit}",
        f"ramp_{unit}",
        f"rate_{unit}_per_s",
        f"sine_amplitude_{unit}",
    )
    builder = ProfileBuilder(initial)
    steps = table.get("steps", [])
    if not isinstance(steps, list):
        raise ctx.error(f"{prefix}.steps", "must be a list of inline tables")
    for k, step in enumerate(steps):
        where = f"{prefix}.steps[{k}]"
        if not isinstance(step, dict):
            raise ctx.error(where, f"must be an inline table such as {{ hold_s = 10 }}, got {step!r}")
        actions = [a for a in ("hold_s", step_key, ramp_key, amp_key) if a in step]
        if len(actions) != 1:
            raise ctx.error(
                where, f"needs exactly one of hold_s, {step_key}, {ramp_key}, {amp_key}; got {sorted(step)}"
            )
        action = actions[0]
        try:
            if action == "hold_s":
                _unknown_keys(step, ("hold_s", value_key), ctx, where)
                duration = _number(step, "hold_s", ctx, where)
                if duration < 0:
                    raise ctx.error(f"{where}.hold_s", f"must be >= 0, got {duration:g}")
                target = _number(step, value_key, ctx, where) if value_key in step else None
                builder.hold(duration, target)
            elif action == step_key:
                _unknown_keys(step, (step_key,), ctx, where)
                builder.step(_number(step, step_key, ctx, where))
            elif action == ramp_key:
                _unknown_keys(step, (ramp_key, rate_key, "duration_s"), ctx, where)
                target = _number(step, ramp_key, ctx, where)
                if (rate_key in step) == ("duration_s" in step):
                    raise ctx.error(where, f"a ramp needs exactly one of {rate_key} or duration_s")
                if rate_key in step:
                    builder.ramp(target, rate_per_s=_positive(step, rate_key, ctx, where))
                else:
                    builder.ramp(target, duration_s=_number(step, "duration_s", ctx, where))
            else:
                _unknown_keys(step, (amp_key, "period_s", "cycles", "duration_s"), ctx, where)
                amplitude = _number(step, amp_key, ctx, where)
                period = _positive(step, "period_s", ctx, where)
                if ("cycles" in step) == ("duration_s" in step):
                    raise ctx.error(where, "a sine needs exactly one of cycles or duration_s")
                if "cycles" in step:
                    builder.sine(amplitude, period, cycles=_positive(step, "cycles", ctx, where))
                else:
                    builder.sine(amplitude, period, duration_s=_positive(step, "duration_s", ctx, where))
        except ScenarioError as exc:
            if str(exc).startswith(ctx.source):
                raise
            raise ctx.error(where, str(exc)) from exc
        lo, hi = builder.values_range()
        if lo < allowed[0] or hi > allowed[1]:
            raise ctx.error(
                where, f"reaches {lo:g}..{hi:g}, outside the allowed {allowed[0]:g}..{allowed[1]:g}"
            )
    return builder


def parse_scenario(
    data: Mapping[str, Any], layout: ArrayLayout, source: str, default_name: str
) -> ScenarioSpec:
    """The scenario a parsed TOML table describes, for ``layout`` (``Scenario.from_toml`` binds it)."""
    ctx = _Ctx(source)
    _unknown_keys(data, _TOP_KEYS, ctx, "")
    name = data.get("name", default_name)
    description = data.get("description", "")
    if not isinstance(name, str) or not name:
        raise ctx.error("name", f"must be a non-empty string, got {name!r}")
    if not isinstance(description, str):
        raise ctx.error("description", f"must be a string, got {description!r}")
    repeat = data.get("repeat", False)
    if not isinstance(repeat, bool):
        raise ctx.error("repeat", f"must be true or false, got {repeat!r}")
    settled = data.get("settled", False)
    if not isinstance(settled, bool):
        raise ctx.error("settled", f"must be true or false, got {settled!r}")
    base_temp = _number(data, "base_temperature_c", ctx, "", DEFAULT_TEMPERATURE_C)
    if not TEMPERATURE_RANGE_C[0] <= base_temp <= TEMPERATURE_RANGE_C[1]:
        raise ctx.error("base_temperature_c", f"{base_temp:g} is outside {TEMPERATURE_RANGE_C}")
    n = layout.channels
    loads: list[ForceSource] = []
    for k, table in enumerate(_table_list(data, "load", ctx)):
        where = f"load[{k}]"
        _unknown_keys(table, ("channels", "gain", "initial_n", "steps"), ctx, where)
        chans = _channels(table, ctx, where, n)
        gain = _number(table, "gain", ctx, where, 1.0)
        if gain < 0:
            raise ctx.error(f"{where}.gain", f"must be >= 0, got {gain:g}")
        initial = _number(table, "initial_n", ctx, where, 0.0)
        if not FORCE_RANGE_N[0] <= initial <= FORCE_RANGE_N[1]:
            raise ctx.error(f"{where}.initial_n", f"{initial:g} N is outside {FORCE_RANGE_N}")
        builder = _parse_steps(table, ctx, where, "n", initial, FORCE_RANGE_N)
        loads.append(UniformLoad(builder.build(), chans, gain))
    for k, table in enumerate(_table_list(data, "indentation", ctx)):
        where = f"indentation[{k}]"
        allowed = (
            "force_n", "start_mm", "end_mm", "speed_mm_s", "sigma_mm", "inclusion_mm",
            "inclusion_sigma_mm", "inclusion_gain", "press_s", "rest_s", "repeat",
        )  # fmt: skip
        _unknown_keys(table, allowed, ctx, where)
        defaults = builtin_indentation(layout, "x", "").loads[0]
        assert isinstance(defaults, Indentation)
        force = _number(table, "force_n", ctx, where, defaults.peak_force_n)
        if not FORCE_RANGE_N[0] <= force <= FORCE_RANGE_N[1]:
            raise ctx.error(f"{where}.force_n", f"{force:g} N is outside {FORCE_RANGE_N}")
        rep = table.get("repeat", False)
        if not isinstance(rep, bool):
            raise ctx.error(f"{where}.repeat", f"must be true or false, got {rep!r}")
        try:
            loads.append(
                Indentation(
                    peak_force_n=force,
                    start_mm=_pair(table, "start_mm", ctx, where, defaults.start_mm),
                    end_mm=_pair(table, "end_mm", ctx, where, defaults.end_mm),
                    speed_mm_s=_positive(table, "speed_mm_s", ctx, where, defaults.speed_mm_s),
                    sigma_mm=_positive(table, "sigma_mm", ctx, where, defaults.sigma_mm),
                    inclusion_mm=_pair(table, "inclusion_mm", ctx, where, defaults.inclusion_mm),
                    inclusion_sigma_mm=_positive(
                        table, "inclusion_sigma_mm", ctx, where, defaults.inclusion_sigma_mm
                    ),
                    inclusion_gain=_number(table, "inclusion_gain", ctx, where, defaults.inclusion_gain),
                    press_s=_number(table, "press_s", ctx, where, defaults.press_s),
                    rest_s=_number(table, "rest_s", ctx, where, defaults.rest_s),
                    cell_area_mm2=layout.pitch_mm**2,
                    repeat=rep,
                )
            )
        except ScenarioError as exc:
            if str(exc).startswith(ctx.source):
                raise
            raise ctx.error(where, str(exc)) from exc
    temps: list[TemperatureProgram] = []
    for k, table in enumerate(_table_list(data, "temperature", ctx)):
        where = f"temperature[{k}]"
        _unknown_keys(table, ("channels", "initial_c", "steps"), ctx, where)
        chans = _channels(table, ctx, where, n)
        initial = _number(table, "initial_c", ctx, where, base_temp)
        builder = _parse_steps(table, ctx, where, "c", initial, TEMPERATURE_RANGE_C)
        temps.append(TemperatureProgram(builder.build(), chans))
    faults = [_parse_fault(t, ctx, f"fault[{k}]", n) for k, t in enumerate(_table_list(data, "fault", ctx))]
    return ScenarioSpec(
        name,
        loads=loads,
        temperatures=temps,
        description=description,
        repeat=repeat,
        base_temperature_c=base_temp,
        faults=faults,
        settled=settled,
    )


def _table_list(data: Mapping[str, Any], key: str, ctx: _Ctx) -> list[dict[str, Any]]:
    value = data.get(key, [])
    if isinstance(value, dict):
        value = [value]
    if not isinstance(value, list) or not all(isinstance(v, dict) for v in value):
        raise ctx.error(key, f"must be an array of tables ([[{key}]])")
    return value


def _parse_fault(table: Mapping[str, Any], ctx: _Ctx, where: str, n: int) -> FaultEvent:
    _unknown_keys(table, ("at_s", "until_s", "channel", "channel_mode", *_FAULT_FIELDS), ctx, where)
    at_s = _number(table, "at_s", ctx, where)
    until = _number(table, "until_s", ctx, where) if "until_s" in table else None
    if until is not None and until <= at_s:
        raise ctx.error(f"{where}.until_s", f"must be after at_s ({at_s:g}), got {until:g}")
    changes: dict[str, Any] = {}
    channel = None
    if "channel_mode" in table:
        mode = table["channel_mode"]
        if mode not in _CHANNEL_MODES:
            raise ctx.error(
                f"{where}.channel_mode", f"must be one of {', '.join(_CHANNEL_MODES)}, got {mode!r}"
            )
        ch = table.get("channel")
        if isinstance(ch, bool) or not isinstance(ch, int) or not 0 <= ch < n:
            raise ctx.error(f"{where}.channel", f"channel_mode needs a channel in 0..{n - 1}, got {ch!r}")
        changes["channel_mode"] = mode
        channel = ch
    elif "channel" in table:
        raise ctx.error(f"{where}.channel", "channel is only used with channel_mode")
    if "delay_s" in table:
        delay = _number(table, "delay_s", ctx, where)
        if delay < 0:
            raise ctx.error(f"{where}.delay_s", f"must be >= 0, got {delay:g}")
        changes["delay_s"] = delay
    for key in ("no_response", "garble", "drop_connection"):
        if key in table:
            if not isinstance(table[key], bool):
                raise ctx.error(f"{where}.{key}", f"must be true or false, got {table[key]!r}")
            changes[key] = table[key]
    if "exception_code" in table:
        code = table["exception_code"]
        if isinstance(code, bool) or not isinstance(code, int) or code not in VALID_EXCEPTION_CODES:
            raise ctx.error(
                f"{where}.exception_code",
                f"must be a Modbus exception code {VALID_EXCEPTION_CODES}, got {code!r}",
            )
        changes["exception_code"] = code
    if not changes:
        raise ctx.error(where, "sets no fault; give channel_mode or one of " + ", ".join(_FAULT_FIELDS))
    return FaultEvent(at_s=at_s, changes=changes, until_s=until, channel=channel)


#: Modbus exception codes a device may answer with.
