"""One simulated sensor array: clock, physics, electronics and register images (no I/O).

Physics per channel (SI units)
------------------------------
The paper's sensor as ``sim_device.sensor.PaperSensor`` writes it, independently of the
gateway: R = 2 R_con(F) + R0 (1 - eps) exp(-gamma s0 eps) with creeping strain
eps = F/(A E0(F)) + e_kv (eq. 13-17), the Kelvin strain integrated by Runge-Kutta; then the
world effects of ``sim_device.world``.

Register map
------------
``config.register_map`` picks the wire format and read-out board (``sim_device.maps``):
the default ``docs/register-map.md`` described below, or ``docs/register-map-rawgrid.md``
(a low-side divider with board leakage, 12-bit counts stored rows bottom-up). Physics,
scenarios and truth are the same for every map; ``true_force_n`` is always indexed by
physical channel (row-major, top row first) and ``register_channels`` tells which physical
channel each ADC register holds.

Electronics (paper Fig. 4b, eq. 18; default map)
------------------------------------------------
The sensor r and the fixed resistor R_ref form a divider, ``V_o = R_ref / (R_ref + r) V+``;
a ratiometric ADC converts ``counts = round(V_o / V+ (2^bits - 1) + noise)``, clipped to the
rails, with Gaussian noise of ``noise_lsb_rms`` LSB (seeded). The measured resistance is
``r = R_ref (V+ / V_o - 1)`` from the counts (``sim_device.electronics``): 0 counts reads
+inf (open), full scale reads 0 (short). A channel set open reads 0 counts, a shorted one
full scale, without noise (the input is clamped to a rail).

Clock
-----
Device time is ``speed * (clock() - start)`` seconds. Samples are taken every
``sample_period_s`` of device time; the physics is advanced lazily to the current device
time whenever registers are read (``advance``), integrating creep on the sample grid in one
batch for all pending samples (arrays (T, N); only the two-operation Kelvin recurrence steps
through the samples). If more than ``MAX_WORK / N`` samples are pending (a
long idle at high speed), the gap is crossed in that many coarser, equal steps so a read
never stalls; the sample counter still counts every conversion.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import replace

import numpy as np
from numpy.typing import NDArray

from .batch import SampleBatch as SampleBatch
from .config import ArrayConfig, check_electronics
from .faults import CHANNEL_MODES, FaultInjector
from .map_factory import make_map
from .maps import DeviceMap
from .registers import Electronics
from .scenarios import Scenario
from .sensor import PaperSensor, SimSensorParams
from .world import World

FloatArray = NDArray[np.float64]
Listener = Callable[[SampleBatch], None]

#: Bound on samples x channels simulated per catch-up (see the module docstring).
MAX_WORK = 400_000


class SimArray:
    """A simulated array of N piezoresistive sensors behind one Modbus device id."""

    def __init__(
        self,
        config: ArrayConfig | None = None,
        device_id: int = 1,
        *,
        clock: Callable[[], float] | None = None,
    ) -> None:
        self.config = config or ArrayConfig()
        if isinstance(device_id, bool) or not isinstance(device_id, int) or not 1 <= device_id <= 247:
            raise ValueError(f"device_id = {device_id!r} must be an integer in 1..247")
        self.device_id = device_id
        cfg = self.config
        self.layout = cfg.layout
        self.scenario: Scenario = cfg.resolve_scenario()
        self._params = cfg.sensor_params(device_id)
        self._sensor = PaperSensor(self._params)
        if self.scenario.settled:
            self._sensor.settle(self.scenario.force_n(np.zeros(1))[0])
        self._world = World(cfg.world_effects, self._params, self._sensor.gamma_s0)
        self._n = cfg.channels
        self._map: DeviceMap = make_map(cfg)
        self._electronics = self._map.electronics(cfg)
        self._modes = np.zeros(self._n, dtype=np.int8)
        self._rng = np.random.default_rng([cfg.seed, device_id, 1])
        self.faults = FaultInjector(seed=cfg.seed * 1000 + device_id)
        for event in self.scenario.faults:
            self.faults.schedule_event(event)
        self._clock = clock or time.monotonic
        self._wall0 = self._clock()
        self._listeners: list[Listener] = []
        self._version = 0
        self._image_version = -1
        self._image_words: list[int] = []
        self._counter = 0
        self._grid_t0 = 0.0
        self._grid_index = 0
        self._last_t = 0.0
        self._last_batch: SampleBatch
        self._process(np.zeros(1), 0.0, 1)

    # ------------------------------------------------------------------- properties
    @property
    def n_channels(self) -> int:
        return self._n

    @property
    def channel_params(self) -> list[SimSensorParams]:
        """The true parameters of every channel (after part-to-part spread)."""
        return list(self._params)

    @property
    def world_effects(self) -> tuple[str, ...]:
        return self.config.world_effects

    @property
    def device_time_s(self) -> float:
        """Current device time in s (wall clock since creation times ``speed``)."""
        return (self._clock() - self._wall0) * self.config.speed

    @property
    def sample_counter(self) -> int:
        """ADC conversions since start (not wrapped; the register wraps at 2^32)."""
        return self._counter

    @property
    def last_sample_time_s(self) -> float:
        return self._last_t

    @property
    def electronics(self) -> Electronics:
        return self._electronics

    @property
    def modes(self) -> NDArray[np.int8]:
        """Channel modes now: 0 normal, 1 open, 2 short."""
        return self._modes.copy()

    @property
    def version(self) -> int:
        """Changes whenever the register contents may have changed."""
        return self._version

    @property
    def model_name(self) -> str:
        return f"Linqstat {self.layout.rows}x{self.layout.columns}"

    @property
    def register_map(self) -> DeviceMap:
        """The wire format and read-out board this array serves (``config.register_map``)."""
        return self._map

    def identity(self) -> dict[str, str]:
        """Device identification objects (Modbus function 43 / MEI 14), by name."""
        return self._map.identity()

    def register_channels(self) -> NDArray[np.intp]:
        """Element k: the physical channel (row-major, top row first; the index of
        ``true_force_n``) whose ADC count the map stores at the k-th register of its ADC
        block. The identity for the default map; rows reversed for rawgrid."""
        return self._map.register_channels()

    def register_position(self, index: int) -> tuple[int, int]:
        """The physical (row, column) of the k-th register of the ADC block (row 0 on top)."""
        channel = int(self.register_channels()[index])
        return divmod(channel, self.layout.columns)

    # --------------------------------------------------------------------- truth
    def true_force_n(self) -> FloatArray:
        """True force of every channel (N) at the current device time, shape (N,)."""
        return self.scenario.force_n(np.array([self.device_time_s]))[0]

    def true_temperature_c(self) -> FloatArray:
        """True temperature of every channel (°C) at the current device time, shape (N,)."""
        return self.scenario.temperature_c(np.array([self.device_time_s]))[0]

    def latest(self) -> SampleBatch:
        """The latest ADC conversion (a one-sample batch); does not advance the clock."""
        return self._last_batch

    # ------------------------------------------------------------------- control
    def set_channel_mode(self, index: int, mode: str | int) -> None:
        """Set channel ``index`` to "normal", "open" or "short" (or 0, 1, 2) from now on."""
        if isinstance(index, bool) or not isinstance(index, int | np.integer) or not 0 <= index < self._n:
            raise ValueError(f"channel index {index!r} outside 0..{self._n - 1}")
        index = int(index)
        code = CHANNEL_MODES.get(mode) if isinstance(mode, str) else mode
        if code not in (0, 1, 2) or isinstance(code, bool):
            raise ValueError(f"channel mode {mode!r} must be one of {', '.join(CHANNEL_MODES)} or 0, 1, 2")
        self.advance()
        self._modes[index] = code
        self._version += 1

    def set_electronics(self, **changes: float) -> None:
        """Change divider/ADC settings (adc_bits, supply_v, reference_ohm, sample_period_s,
        noise_lsb_rms) from now on; the same limits as the holding registers apply."""
        checked = {}
        for name, value in changes.items():
            if name not in Electronics.__dataclass_fields__:
                raise ValueError(f"unknown electronics setting {name!r}")
            if name in self._map.fixed_electronics:
                raise ValueError(f"{name} is fixed by the {self._map.name} board")
            checked[name] = check_electronics(name, value)
        self.advance()
        self._apply_electronics(checked)

    def _apply_electronics(self, changes: dict[str, float]) -> None:
        if not changes:
            return
        if "adc_bits" in changes:
            changes = {**changes, "adc_bits": int(changes["adc_bits"])}
        old_period = self._electronics.sample_period_s
        self._electronics = replace(self._electronics, **changes)  # type: ignore[arg-type]
        if self._electronics.sample_period_s != old_period:
            self._grid_t0, self._grid_index = self._last_t, 0
        self._version += 1

    def add_listener(self, listener: Listener) -> None:
        """Call ``listener(batch)`` with every new batch of samples."""
        self._listeners.append(listener)

    def remove_listener(self, listener: Listener) -> None:
        if listener in self._listeners:
            self._listeners.remove(listener)

    # ------------------------------------------------------------------- physics
    def advance(self, until_s: float | None = None, *, exact: bool = False) -> int:
        """Simulate every conversion due up to ``until_s`` (default: now); returns their number.

        ``exact=True`` never uses coarse steps (for offline records); it works in chunks.
        """
        now = self.device_time_s if until_s is None else float(until_s)
        period = self._electronics.sample_period_s
        due = math.floor((now - self._grid_t0) / period + 1e-9) - self._grid_index
        if due <= 0:
            return 0
        max_steps = max(1, MAX_WORK // self._n)
        if not exact and due > max_steps:
            self._grid_index += due
            end_t = self._grid_t0 + self._grid_index * period
            step = (end_t - self._last_t) / max_steps
            times = np.asarray(self._last_t + step * np.arange(1, max_steps + 1), dtype=np.float64)
            times[-1] = end_t
            self._process(times, step, due)
            return due
        done = 0
        while done < due:
            k = min(max_steps, due - done)
            idx = self._grid_index + np.arange(1, k + 1)
            times = np.asarray(self._grid_t0 + idx * period, dtype=np.float64)
            self._grid_index += k
            self._process(times, period, k)
            done += k
        return due

    def _mode_series(self, times: FloatArray) -> NDArray[np.int8]:
        modes = np.broadcast_to(self._modes, (times.shape[0], self._n)).copy()
        for at_s, channel, code in self.faults.pop_channel_events(float(times[-1])):
            if channel >= self._n:
                continue
            modes[times >= at_s, channel] = code
            self._modes[channel] = code
        return modes

    def _process(self, times: FloatArray, dt_s: float, conversions: int) -> None:
        force = self.scenario.force_n(times)
        temperature = self.scenario.temperature_c(times)
        modes = self._mode_series(times)
        breakdown = self._sensor.run(force, times, self._last_t)
        true_r = self._world.apply(breakdown, force, temperature, dt_s)
        sensed_r = true_r
        if self.config.sensor_noise_rel > 0.0:
            sensed_r = true_r * np.exp(self.config.sensor_noise_rel * self._rng.standard_normal(true_r.shape))
        counts = self._convert(sensed_r, modes)
        measured = self._map.measured_ohm(counts, self._electronics)
        self._counter += conversions
        self._last_t = float(times[-1])
        batch = SampleBatch(self.device_id, times, counts, measured, true_r, force, temperature, modes)
        self._last_batch = batch.last() if times.shape[0] > 1 else batch
        self._version += 1
        for listener in list(self._listeners):
            listener(batch)

    def _convert(self, true_r: FloatArray, modes: NDArray[np.int8]) -> NDArray[np.int64]:
        """The map's divider + ADC: ratiometric counts with Gaussian noise, clipped to the rails."""
        e = self._electronics
        noise: FloatArray | float = 0.0
        if e.noise_lsb_rms > 0.0:
            noise = e.noise_lsb_rms * self._rng.standard_normal(true_r.shape)
        return self._map.convert(true_r, modes, e, noise)

    # ----------------------------------------------------------------- registers
    def input_registers(self) -> list[int]:
        """The map's input registers from address 0 after advancing to now (default map:
        0 .. 2200+2N-1, docs/register-map.md; rawgrid: 0 .. 32+N-1)."""
        self.advance()
        if self._image_version != self._version:
            self._image_words = self._map.input_image(self._last_batch, self._counter, self._electronics)
            self._image_version = self._version
        return self._image_words

    def holding_registers(self) -> list[int]:
        """Holding registers with the current configuration (default map: 0 .. 100+N-1;
        rawgrid has none: empty)."""
        return self._map.holding_image(self._electronics, self._modes)

    def write_holding(self, address: int, values: list[int]) -> None:
        """Apply a Modbus write of holding registers, or raise ``RegisterWriteError`` (no change)."""
        change = self._map.decode_write(self.holding_registers(), address, values)
        self.advance()
        self._apply_electronics(dict(change.electronics))
        for channel, code in change.modes.items():
            self._modes[channel] = code
        self._version += 1
