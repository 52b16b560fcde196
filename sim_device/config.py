"""Configuration of one simulated array: geometry, clock, electronics, sensors and world effects.

Part-to-part spread
-------------------
Real sensors of one batch differ. With ``param_spread=True`` every channel draws its own
parameters around the project defaults (``SimSensorParams()``, the Linqstat set of
``docs/parameters.md``), uniformly and reproducibly from ``seed`` and the device id
(``DEFAULT_SPREAD``):

====================  ==========
parameter             spread
====================  ==========
``r0_ohm``            ±15 %
``e0_pa``             ±10 %
``e1_pa``             ±10 %
``mu1_pa_s``          ±10 %
``rho2_ohm_m``        ±10 %
====================  ==========

``param_spread`` may also be a mapping ``{parameter name: relative half-width}``. Parameters
can instead be given per channel (``channel_params``, one ``SimSensorParams`` per channel, or a
single one for all channels); then no spread is applied.

World effects
-------------
The paper's physics (tunneling + contact + creep, eq. 2-17) is always on. ``world_effects``
switches on further effects of the simulated world (see ``sim_device.world``): ``creep2``,
``hysteresis``, ``temperature``, ``series_resistance``, ``leakage``.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, fields, replace
from typing import Any

import numpy as np

from .scenarios import ArrayLayout, Scenario
from .sensor import SensorParamsError, SimSensorParams

#: The paper's effects (always on) and those the simulated world can add, by their names in
#: the record format (``docs/record-format.md``).
PAPER_EFFECTS: tuple[str, ...] = ("tunneling", "contact", "creep")
WORLD_EFFECTS: tuple[str, ...] = ("creep2", "hysteresis", "temperature", "series_resistance", "leakage")

#: Default part-to-part spread: parameter -> relative half-width of a uniform distribution.
DEFAULT_SPREAD: dict[str, float] = {
    "r0_ohm": 0.15,
    "e0_pa": 0.10,
    "e1_pa": 0.10,
    "mu1_pa_s": 0.10,
    "rho2_ohm_m": 0.10,
}

#: Allowed ranges of the electronics settings (the holding-register limits).
ELECTRONICS_LIMITS: dict[str, tuple[float, float]] = {
    "adc_bits": (8, 16),
    "supply_v": (0.5, 24.0),
    "reference_ohm": (10.0, 1e7),
    "sample_period_s": (0.001, 10.0),
    "noise_lsb_rms": (0.0, 1000.0),
}


#: The register maps the simulator serves: ``docs/register-map.md`` (the default) and
#: ``docs/register-map-rawgrid.md`` (``sim_device.maps``, ``sim_device.rawgrid``).
REGISTER_MAPS: tuple[str, ...] = ("tactile-sim", "rawgrid")
#: The rawgrid board's fixed read-out: 12-bit ADC, 3.3 V rail, 10 kohm pull-up.
RAWGRID_BOARD: dict[str, float] = {"adc_bits": 12, "supply_v": 3.3, "reference_ohm": 10e3}
#: Default board leakage of the rawgrid read-out, in parallel with each sensor (ohm).
DEFAULT_BOARD_LEAKAGE_OHM = 195e3


class ConfigError(ValueError):
    """An array configuration value is invalid; the message names the field."""


def check_electronics(name: str, value: float) -> float:
    """Validate one electronics setting against ``ELECTRONICS_LIMITS``; returns it as float."""
    low, high = ELECTRONICS_LIMITS[name]
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise ConfigError(f"{name} must be a finite number, got {value!r}")
    if name == "adc_bits" and int(value) != value:
        raise ConfigError(f"adc_bits must be an integer, got {value!r}")
    if not low <= value <= high:
        raise ConfigError(f"{name} = {value!r} is outside the allowed {low:g}..{high:g}")
    return float(value)


def parse_world_effects(effects: str | Iterable[str]) -> tuple[str, ...]:
    """World effect names in canonical order; paper effects are accepted and dropped (always on)."""
    items = effects.split(",") if isinstance(effects, str) else list(effects)
    chosen: set[str] = set()
    for raw in items:
        name = str(raw).strip()
        if not name or name in PAPER_EFFECTS:
            continue
        if name not in WORLD_EFFECTS:
            import difflib

            close = difflib.get_close_matches(name, WORLD_EFFECTS, n=1, cutoff=0.4)
            hint = f"; did you mean {close[0]!r}?" if close else ""
            raise ConfigError(f"unknown world effect {name!r}{hint} (valid: {', '.join(WORLD_EFFECTS)})")
        chosen.add(name)
    return tuple(e for e in WORLD_EFFECTS if e in chosen)


@dataclass(frozen=True, kw_only=True)
class ArrayConfig:
    """Everything that defines one simulated array (all keyword arguments, SI units in names).

    ``scenario`` is a built-in name, the path of a TOML scenario file, or a ``Scenario``
    built for the same channel count. ``speed`` scales the device clock (60 plays a minute
    per wall-clock second). The electronics fields are the start values of the writable
    holding registers.

    ``register_map`` picks the wire format and read-out board (``REGISTER_MAPS``). The
    ``"rawgrid"`` board fixes its own read-out (``RAWGRID_BOARD``): there ``adc_bits``,
    ``supply_v`` and ``reference_ohm`` must keep their defaults or equal the board's values,
    and are not used; ``board_leakage_ohm`` (+inf: none) shunts each of its sensors and
    must keep its default with the default map, which has no such path.
    """

    channels: int = 16
    columns: int = 4
    pitch_mm: float = 2.5
    seed: int = 1
    scenario: str | Scenario = "idle"
    speed: float = 1.0
    noise_lsb_rms: float = 2.0
    #: relative RMS of log-normal noise on the sensor's own resistance (contact and
    #: tunneling fluctuations), applied before the divider; 0.01 is 1 % resistance noise
    sensor_noise_rel: float = 0.0
    world_effects: tuple[str, ...] = ()
    param_spread: bool | Mapping[str, float] = True
    channel_params: SimSensorParams | Sequence[SimSensorParams] | None = None
    sample_period_s: float = 0.01
    supply_v: float = 5.0
    reference_ohm: float = 10e3
    adc_bits: int = 16
    register_map: str = "tactile-sim"
    board_leakage_ohm: float = DEFAULT_BOARD_LEAKAGE_OHM

    def __post_init__(self) -> None:
        if (
            isinstance(self.channels, bool)
            or not isinstance(self.channels, int)
            or not 1 <= self.channels <= 256
        ):
            raise ConfigError(f"channels = {self.channels!r} must be an integer in 1..256")
        if (
            isinstance(self.columns, bool)
            or not isinstance(self.columns, int)
            or not 1 <= self.columns <= self.channels
        ):
            raise ConfigError(
                f"columns = {self.columns!r} must be an integer in 1..channels ({self.channels})"
            )
        if not (isinstance(self.pitch_mm, int | float) and math.isfinite(self.pitch_mm)):
            raise ConfigError(f"pitch_mm must be a number, got {self.pitch_mm!r}")
        if not 1 <= round(self.pitch_mm * 1000.0) <= 65535:
            raise ConfigError(
                f"pitch_mm = {self.pitch_mm!r} must be within 0.001..65.535 mm (register pitch_um)"
            )
        if not (
            isinstance(self.sensor_noise_rel, int | float)
            and math.isfinite(self.sensor_noise_rel)
            and 0.0 <= self.sensor_noise_rel <= 0.5
        ):
            raise ConfigError(f"sensor_noise_rel = {self.sensor_noise_rel!r} must be in [0, 0.5]")
        if isinstance(self.seed, bool) or not isinstance(self.seed, int) or self.seed < 0:
            raise ConfigError(f"seed = {self.seed!r} must be an integer >= 0")
        if not (
            isinstance(self.speed, int | float) and math.isfinite(self.speed) and 0.0 < self.speed <= 1e6
        ):
            raise ConfigError(f"speed = {self.speed!r} must be in (0, 1e6]")
        for name in ELECTRONICS_LIMITS:
            check_electronics(name, getattr(self, name))
        object.__setattr__(self, "world_effects", parse_world_effects(self.world_effects))
        object.__setattr__(self, "adc_bits", int(self.adc_bits))
        self._check_register_map()
        if isinstance(self.scenario, Scenario):
            if self.scenario.n_channels != self.channels:
                raise ConfigError(
                    f"scenario {self.scenario.name!r} is built for {self.scenario.n_channels} channels, "
                    f"the array has {self.channels}"
                )
        elif not isinstance(self.scenario, str) or not self.scenario:
            raise ConfigError(f"scenario must be a name, a TOML path or a Scenario, got {self.scenario!r}")
        spread = self._spread()
        for name, width in spread.items():
            if name not in {f.name for f in fields(SimSensorParams)}:
                raise ConfigError(f"param_spread names unknown sensor parameter {name!r}")
            if not (math.isfinite(width) and 0.0 <= width < 1.0):
                raise ConfigError(f"param_spread[{name!r}] = {width!r} must be in [0, 1)")
        cp = self.channel_params
        if cp is not None and not isinstance(cp, SimSensorParams):
            items = list(cp)
            if len(items) != self.channels or not all(isinstance(p, SimSensorParams) for p in items):
                raise ConfigError(f"channel_params must be one SimSensorParams or {self.channels} of them")
            object.__setattr__(self, "channel_params", tuple(items))

    def _check_register_map(self) -> None:
        if self.register_map not in REGISTER_MAPS:
            raise ConfigError(
                f"register_map = {self.register_map!r} must be one of {', '.join(REGISTER_MAPS)}"
            )
        leak = self.board_leakage_ohm
        if isinstance(leak, bool) or not isinstance(leak, int | float) or not leak > 0.0:
            raise ConfigError(f"board_leakage_ohm = {leak!r} must be > 0 (inf: no leakage)")
        object.__setattr__(self, "board_leakage_ohm", float(leak))
        if self.register_map == "tactile-sim" and leak != DEFAULT_BOARD_LEAKAGE_OHM:
            raise ConfigError("board_leakage_ohm applies to the rawgrid map only")
        if self.register_map == "rawgrid":
            for name, board in RAWGRID_BOARD.items():
                value = getattr(self, name)
                if value not in (board, ArrayConfig.__dataclass_fields__[name].default):
                    raise ConfigError(
                        f"{name} = {value!r}: the rawgrid board's read-out is fixed ({name} = {board:g})"
                    )

    @property
    def layout(self) -> ArrayLayout:
        return ArrayLayout(channels=self.channels, columns=self.columns, pitch_mm=float(self.pitch_mm))

    @property
    def rows(self) -> int:
        return self.layout.rows

    def _spread(self) -> dict[str, float]:
        if isinstance(self.param_spread, bool):
            return dict(DEFAULT_SPREAD) if self.param_spread else {}
        return {str(k): float(v) for k, v in self.param_spread.items()}

    def resolve_scenario(self) -> Scenario:
        """The scenario object for this array's layout (loads a file or a built-in)."""
        if isinstance(self.scenario, Scenario):
            return self.scenario
        return Scenario.load(self.scenario, self.layout)

    def sensor_params(self, device_id: int = 1) -> list[SimSensorParams]:
        """The true parameters of every channel (spread drawn from ``seed`` and ``device_id``)."""
        cp = self.channel_params
        if isinstance(cp, SimSensorParams):
            return [cp] * self.channels
        if cp is not None:
            return list(cp)
        base = SimSensorParams()
        spread = self._spread()
        if not spread:
            return [base] * self.channels
        rng = np.random.default_rng([self.seed, device_id, 0])
        names = sorted(spread)
        draws = rng.uniform(-1.0, 1.0, size=(self.channels, len(names)))
        out: list[SimSensorParams] = []
        for row in draws:
            overrides: dict[str, Any] = {
                name: getattr(base, name) * (1.0 + spread[name] * u)
                for name, u in zip(names, row, strict=True)
            }
            try:
                out.append(base.with_overrides(overrides))
            except SensorParamsError as exc:
                raise ConfigError(f"param_spread gives an invalid parameter: {exc}") from exc
        return out

    def with_changes(self, **changes: Any) -> ArrayConfig:
        """A copy with some fields replaced (validated again)."""
        return replace(self, **changes)
