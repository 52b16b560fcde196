"""Scenarios of the simulated hand (``sim_device.hand``): one ``Scenario`` per region, plus the
taxels that are dead, frozen or stuck.

A hand scenario is

- a hand built-in (``HAND_SCENARIOS``): ``grasp`` (the palm pressed while the finger tips and
  pads touch and release), ``slide`` (a probe sliding along the palm and the index pad: a
  moving contact), ``palm-held`` (the palm loaded from long before t = 0, everything else
  idle: a zero taken now must leave no force on the idle taxels);
- any array built-in (``tactile-sim scenarios``), applied to every region on its own grid;
- a TOML file (``docs/scenarios.md``, "The hand"): ``name``, ``description``, the lists
  ``dead``, ``frozen`` and ``stuck`` (taxel specs, ``parse_taxel_specs``) and one
  ``[region.NAME]`` table per loaded region holding an array scenario's keys for that grid
  (regions not named are idle).

Taxel specs: ``REGION`` (every taxel of it) or ``REGION:INDEX`` (row-major in the region), and
for ``frozen`` an optional ``=VALUE`` (the raw value it stays at; without it, the value it
had on the first frame).
"""

from __future__ import annotations

import tomllib
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from .builtin_scenarios import builtin_indentation
from .hand_map import REGIONS, Region, region
from .profiles import ProfileBuilder, ScenarioError
from .scenario_file import parse_scenario
from .scenario_parts import ArrayLayout, ScenarioSpec, UniformLoad
from .scenarios import Scenario

#: Pitch of every sub-grid in the simulation (mm); the public facts give none.
PITCH_MM = 2.5
#: Force per palm taxel when the palm is pressed (N).
PALM_PRESS_N = 0.5
#: Peak force per finger tip or pad taxel when a finger touches (N).
TOUCH_N = 0.8


@dataclass(frozen=True)
class TaxelSpec:
    """Taxels of one region: ``index`` None for all of them; ``value`` a frozen raw value."""

    region: str
    index: int | None = None
    value: int | None = None

    def indices(self) -> range:
        size = region(self.region).size
        return range(size) if self.index is None else range(self.index, self.index + 1)


def parse_taxel_specs(text: str | Sequence[str], what: str, allow_value: bool = False) -> list[TaxelSpec]:
    """``"thumb-pad,middle-tip:4"`` (or a list of such items) as ``TaxelSpec``s; ``ValueError``
    with a precise message if an item names no region or taxel."""
    items = text.split(",") if isinstance(text, str) else list(text)
    out: list[TaxelSpec] = []
    for raw in items:
        if not isinstance(raw, str):
            raise ValueError(f"{what}: {raw!r} is not a taxel spec (REGION or REGION:INDEX)")
        item = raw.strip()
        if not item:
            continue
        value: int | None = None
        if "=" in item:
            if not allow_value:
                raise ValueError(f"{what}: {item!r}: only frozen taxels take =VALUE")
            item, _, value_text = item.partition("=")
            try:
                value = int(value_text, 0)
            except ValueError:
                raise ValueError(f"{what}: value {value_text!r} is not an integer") from None
            if not 0 <= value <= 0xFFFF:
                raise ValueError(f"{what}: value {value} is outside 0..65535")
        name, sep, index_text = item.partition(":")
        try:
            reg = region(name)
        except KeyError as exc:
            raise ValueError(f"{what}: {exc.args[0]}") from None
        index: int | None = None
        if sep:
            try:
                index = int(index_text)
            except ValueError:
                raise ValueError(f"{what}: taxel index {index_text!r} is not an integer") from None
            if not 0 <= index < reg.size:
                raise ValueError(f"{what}: {name} has taxels 0..{reg.size - 1}, not {index}")
        out.append(TaxelSpec(name, index, value))
    return out


@dataclass(frozen=True)
class HandScenario:
    """A scenario per region (by name) and the taxel faults it declares."""

    name: str
    regions: Mapping[str, Scenario]
    description: str = ""
    dead: tuple[TaxelSpec, ...] = field(default=())
    frozen: tuple[TaxelSpec, ...] = field(default=())
    stuck: tuple[TaxelSpec, ...] = field(default=())


def region_layout(r: Region) -> ArrayLayout:
    return ArrayLayout(channels=r.size, columns=r.columns, pitch_mm=PITCH_MM)


def _idle(r: Region) -> Scenario:
    return Scenario.builtin("idle", region_layout(r))


def _grasp(r: Region) -> Scenario:
    layout = region_layout(r)
    if r.name == "palm":
        press = ProfileBuilder(0.0).hold(1.0).ramp(PALM_PRESS_N, duration_s=1.0).hold(10.0)
        press.ramp(0.0, duration_s=1.0).hold(2.0)
        spec = ScenarioSpec("grasp", loads=[UniformLoad(press.build(repeat=True))], repeat=True)
        return Scenario.from_spec(spec, layout)
    if r.name.endswith(("-tip", "-pad")):
        touch = ProfileBuilder(0.0).hold(3.0).ramp(TOUCH_N, duration_s=0.5).hold(2.0)
        touch.ramp(0.0, duration_s=0.5).hold(1.0).ramp(TOUCH_N, duration_s=0.5).hold(2.0)
        touch.ramp(0.0, duration_s=0.5).hold(5.0)
        spec = ScenarioSpec("grasp", loads=[UniformLoad(touch.build(repeat=True))], repeat=True)
        return Scenario.from_spec(spec, layout)
    return _idle(r)


def _slide(r: Region) -> Scenario:
    if r.name in ("palm", "index-pad"):
        return Scenario.from_spec(builtin_indentation(region_layout(r), "slide", ""), region_layout(r))
    return _idle(r)


def _palm_held(r: Region) -> Scenario:
    if r.name == "palm":
        return Scenario.constant(PALM_PRESS_N, region_layout(r), settled=True)
    return _idle(r)


#: Hand built-ins: name -> (description, scenario of a region).
HAND_SCENARIOS: dict[str, tuple[str, Callable[[Region], Scenario]]] = {
    "grasp": (
        f"the palm pressed ({PALM_PRESS_N:g} N a taxel, 10 s of every 15 s) while the finger tips and "
        f"pads touch and release ({TOUCH_N:g} N a taxel, twice every 15 s); nails idle (repeats)",
        _grasp,
    ),
    "slide": ("a 3 N probe sliding along the middle row of the palm and of the index pad (repeats)", _slide),
    "palm-held": (
        f"the palm held at {PALM_PRESS_N:g} N a taxel since long before t = 0 (settled), the rest idle",
        _palm_held,
    ),
}


def load_hand_scenario(spec: str) -> HandScenario:
    """A hand built-in, an array built-in on every region, or a hand TOML file."""
    text = str(spec)
    if text.endswith(".toml") or Path(text).is_file():
        return _from_file(Path(text))
    if text in HAND_SCENARIOS:
        description, factory = HAND_SCENARIOS[text]
        return HandScenario(text, {r.name: factory(r) for r in REGIONS}, description)
    try:
        regions = {r.name: Scenario.builtin(text, region_layout(r)) for r in REGIONS}
    except ScenarioError as exc:
        raise ScenarioError(f"{exc} or a hand scenario ({', '.join(HAND_SCENARIOS)})") from None
    return HandScenario(text, regions, regions["palm"].description)


_TOP_KEYS = ("name", "description", "dead", "frozen", "stuck", "region")


def _from_file(path: Path) -> HandScenario:
    source = str(path)
    try:
        data: dict[str, Any] = tomllib.loads(path.read_text(encoding="utf-8"))
    except OSError as exc:
        raise ScenarioError(f"{source}: cannot read scenario file: {exc.strerror or exc}") from None
    except tomllib.TOMLDecodeError as exc:
        raise ScenarioError(f"{source}: invalid TOML: {exc}") from None
    for key in data:
        if key not in _TOP_KEYS:
            raise ScenarioError(f"{source}: {key}: unknown key; allowed: {', '.join(_TOP_KEYS)}")
    tables = data.get("region", {})
    if not isinstance(tables, dict):
        raise ScenarioError(f"{source}: region: must be tables [region.NAME]")
    regions: dict[str, Scenario] = {}
    for name, table in tables.items():
        try:
            r = region(name)
        except KeyError as exc:
            raise ScenarioError(f"{source}: region.{name}: {exc.args[0]}") from None
        if not isinstance(table, dict):
            raise ScenarioError(f"{source}: region.{name}: must be a table")
        layout = region_layout(r)
        regions[name] = Scenario.from_spec(
            parse_scenario(table, layout, f"{source}: region.{name}", name), layout
        )
    for r in REGIONS:
        regions.setdefault(r.name, _idle(r))
    faults: dict[str, tuple[TaxelSpec, ...]] = {}
    for key in ("dead", "frozen", "stuck"):
        items = data.get(key, [])
        if not isinstance(items, list):
            raise ScenarioError(f"{source}: {key}: must be a list of taxel specs")
        try:
            faults[key] = tuple(parse_taxel_specs(items, f"{source}: {key}", allow_value=key == "frozen"))
        except ValueError as exc:
            raise ScenarioError(str(exc)) from None
    name = data.get("name", path.stem)
    description = data.get("description", "")
    if not isinstance(name, str) or not isinstance(description, str):
        raise ScenarioError(f"{source}: name and description must be strings")
    return HandScenario(name, regions, description, faults["dead"], faults["frozen"], faults["stuck"])
