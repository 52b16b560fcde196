"""The simulated hand (``docs/register-map-hand.md``): 1,062 piezoresistive taxels in 17 regions,
six joints, served as holding registers (``sim_device.hand_server`` puts it on Modbus).

Physics: each region is a ``SimArray`` of the paper's sensor (creep, part-to-part spread,
the world effects), converted at 30 Hz (``FRAME_PERIOD_S``): the registers change once a
frame, whatever the reads. Read-out: each taxel is driven at a fixed voltage and its current
measured by a transimpedance stage into a 16-bit converter, so the raw value is proportional
to the taxel's conductance: ``raw = round(65535 R_f / r + offset + noise)`` with ``R_f =
FEEDBACK_OHM`` (1 kohm), about 0 unloaded (r is infinite), rising with pressure. ``offset``
is each taxel's own reading at rest (``rest_offset_lsb``: uniform in 0..2x it, default 0): a
preloaded skin or a leaking board, which a real hand has and a zero must take off. Values from 0xFF00
up are the hand's codes, never pressures: a taxel whose conversion reaches 0xFF00 (r below
about 1.004 kohm, some 24 N on a nominal taxel) reads the saturation code (0xFFFF by default).

Field faults: a dead taxel reads 0, a frozen one a constant, a stuck one the saturation code
(stuck at the rail), from the first frame on.

Joints: the angle moves toward its set point at ``ANGLE_RATE_PER_S`` per mille a second of
device time and stops when the finger's force reaches its set point. The actual force of a
joint is the true force on its finger's regions (the thumb's for both thumb joints), in
centinewtons. Status code (``hand_map.STATUS_CODES``): fault if an error bit other than stall
is set, stall if the stall bit is, force reached, grasping while moving, idle otherwise.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Iterable, Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray

from . import hand_map as hm
from .array import SimArray
from .config import ArrayConfig
from .hand_scenarios import HandScenario, TaxelSpec, load_hand_scenario
from .maps import VENDOR_NAME, package_version

FRAME_RATE_HZ = 30.0
FRAME_PERIOD_S = 1.0 / FRAME_RATE_HZ
FEEDBACK_OHM = 1000.0
#: The largest mean offset at rest a taxel may be given (LSB).
MAX_REST_OFFSET_LSB = 10000.0
FULL_SCALE = 0xFFFF
ANGLE_RATE_PER_S = 1000.0
#: Bound on the joint steps of one catch-up (a long idle is crossed in coarser steps).
MAX_JOINT_STEPS = 3000
#: Regions whose force each joint feels.
JOINT_GROUPS = ("little", "ring", "middle", "index", "thumb", "thumb")


class HandWriteError(Exception):
    """A write the hand answers with Modbus exception ``code`` (2: address, 3: value)."""

    def __init__(self, code: int, message: str) -> None:
        super().__init__(message)
        self.code = code


def raw_from_resistance(
    resistance_ohm: NDArray[np.float64], noise_lsb: NDArray[np.float64] | float, saturation_code: int
) -> NDArray[np.int64]:
    """Raw values of taxels of resistance ``resistance_ohm`` (inf: unloaded): 65535 R_f / r plus
    noise, rounded, at least 0; from 0xFF00 up: ``saturation_code``."""
    with np.errstate(divide="ignore"):
        ideal = FULL_SCALE * FEEDBACK_OHM / np.asarray(resistance_ohm, dtype=np.float64)
    raw = np.rint(np.clip(ideal + noise_lsb, 0.0, float(FULL_SCALE))).astype(np.int64)
    raw[raw >= hm.SPECIAL_FROM] = saturation_code
    return raw


class HandDevice:
    """The hand's state and registers (no I/O); ``clock`` is wall seconds (tests inject one)."""

    def __init__(
        self,
        scenario: str | HandScenario = "idle",
        *,
        layout: hm.Layout | None = None,
        seed: int = 1,
        speed: float = 1.0,
        noise_lsb: float = 2.0,
        rest_offset_lsb: float = 0.0,
        saturation_code: int = hm.SATURATION_CODE,
        dead: Iterable[TaxelSpec] = (),
        frozen: Iterable[TaxelSpec] = (),
        stuck: Iterable[TaxelSpec] = (),
        device_id: int = 1,
        clock: Callable[[], float] | None = None,
        **array_options: Any,
    ) -> None:
        if not hm.SPECIAL_FROM <= saturation_code <= 0xFFFF:
            raise ValueError(f"saturation code {saturation_code} must be within 0xFF00..0xFFFF")
        if not (math.isfinite(noise_lsb) and noise_lsb >= 0.0):
            raise ValueError(f"noise_lsb = {noise_lsb!r} must be >= 0")
        if not (math.isfinite(rest_offset_lsb) and 0.0 <= rest_offset_lsb <= MAX_REST_OFFSET_LSB):
            raise ValueError(
                f"rest_offset_lsb = {rest_offset_lsb!r} must be within 0..{MAX_REST_OFFSET_LSB:g} LSB"
            )
        self.scenario = scenario if isinstance(scenario, HandScenario) else load_hand_scenario(scenario)
        self.layout = layout or hm.Layout()
        self.device_id = device_id
        self.speed = float(speed)
        self.noise_lsb = float(noise_lsb)
        self.saturation_code = saturation_code
        self._clock = clock or time.monotonic
        self.arrays: dict[str, SimArray] = {}
        for k, r in enumerate(hm.REGIONS):
            config = ArrayConfig(
                channels=r.size,
                columns=r.columns,
                pitch_mm=2.5,
                seed=seed * 100 + k,
                scenario=self.scenario.regions[r.name],
                speed=speed,
                noise_lsb_rms=0.0,
                sample_period_s=FRAME_PERIOD_S,
                **array_options,
            )
            self.arrays[r.name] = SimArray(config, device_id, clock=self._clock)
        self._rng = np.random.default_rng([seed, device_id, 34])
        # each taxel's own reading at rest (the skin's preload, the board's leak), fixed for
        # the hand's life: uniform in 0..2 rest_offset_lsb, from its own stream
        offsets = np.random.default_rng([seed, device_id, 35])
        self.rest_offset_lsb = float(rest_offset_lsb)
        self._offsets = {r.name: offsets.uniform(0.0, 2.0 * self.rest_offset_lsb, r.size) for r in hm.REGIONS}
        self._dead = self._masks([*self.scenario.dead, *dead])
        self._stuck = self._masks([*self.scenario.stuck, *stuck])
        self._frozen_specs = [*self.scenario.frozen, *frozen]
        self._frozen = self._masks(self._frozen_specs)
        self._frozen_values: dict[str, NDArray[np.int64]] = {}
        self._where = {
            self.layout.region_address(r) + i: (r.name, i) for r in hm.REGIONS for i in range(r.size)
        }
        self._frame = -1
        self._taxels: dict[str, NDArray[np.int64]] = {}
        self.angle_set = [0] * hm.N_JOINTS
        self.force_set_cn = [0] * hm.N_JOINTS
        self.angle_actual = [0.0] * hm.N_JOINTS
        self.errors = [0] * hm.N_JOINTS
        self.force_calibrations = 0
        self._joint_t = 0.0
        self._refresh()

    def identity(self) -> dict[str, str]:
        """Device identification objects (Modbus function 43 / MEI 14), by name: a hand."""
        return {
            "VendorName": VENDOR_NAME,
            "ProductCode": "TSA-HAND",
            "MajorMinorRevision": package_version(),
            "ProductName": "Simulated dexterous hand with a tactile skin",
            "ModelName": f"hand {hm.N_TAXELS} taxels in {len(hm.REGIONS)} regions",
        }

    @staticmethod
    def _masks(specs: Sequence[TaxelSpec]) -> dict[str, NDArray[np.bool_]]:
        masks = {r.name: np.zeros(r.size, dtype=bool) for r in hm.REGIONS}
        for spec in specs:
            masks[spec.region][list(spec.indices())] = True
        return masks

    # ------------------------------------------------------------------ clock and frames
    @property
    def device_time_s(self) -> float:
        return self.arrays["palm"].device_time_s

    @property
    def frame_index(self) -> int:
        """Frames converted since start: the registers change when it does (30 Hz)."""
        return math.floor(self.device_time_s * FRAME_RATE_HZ + 1e-9)

    def _refresh(self) -> None:
        frame = self.frame_index
        if frame == self._frame:
            return
        self._frame = frame
        until = frame * FRAME_PERIOD_S
        for r in hm.REGIONS:
            array = self.arrays[r.name]
            array.advance(until)
            latest = array.latest()
            noise = self.noise_lsb * self._rng.standard_normal(r.size) if self.noise_lsb > 0 else 0.0
            noise = noise + self._offsets[r.name]
            raw = raw_from_resistance(latest.true_resistance_ohm[0], noise, self.saturation_code)
            frozen = self._frozen[r.name]
            if frozen.any():
                if r.name not in self._frozen_values:
                    self._frozen_values[r.name] = raw.copy()
                    for spec in self._frozen_specs:
                        if spec.region == r.name and spec.value is not None:
                            self._frozen_values[r.name][list(spec.indices())] = spec.value
                raw = np.where(frozen, self._frozen_values[r.name], raw)
            raw[self._dead[r.name]] = 0
            raw[self._stuck[r.name]] = self.saturation_code
            self._taxels[r.name] = raw
        self._move_joints(until)

    def taxels(self, name: str) -> NDArray[np.int64]:
        """The raw values of region ``name`` (row-major) in the current frame."""
        self._refresh()
        return self._taxels[name].copy()

    def true_force_n(self, name: str) -> NDArray[np.float64]:
        """The true force on each taxel of region ``name`` in the current frame (N)."""
        self._refresh()
        return np.asarray(self.arrays[name].latest().force_n[0], dtype=np.float64)

    # ------------------------------------------------------------------ joints
    def _group_force_cn(self, group: str) -> int:
        total = sum(
            float(self.arrays[r.name].latest().force_n[0].sum()) for r in hm.REGIONS if r.group == group
        )
        return min(round(total * 100.0), 0xFFFF)

    def force_actual_cn(self) -> list[int]:
        self._refresh()
        return [self._group_force_cn(g) for g in JOINT_GROUPS]

    def _force_reached(self, j: int, forces: Sequence[int] | NDArray[np.int64]) -> bool:
        return self.force_set_cn[j] > 0 and forces[j] >= self.force_set_cn[j]

    def _group_forces_cn(self, times_s: NDArray[np.float64]) -> NDArray[np.int64]:
        """Each joint's force (cN) at device times ``times_s``, shape (T, joints)."""
        by_group = {g: np.zeros(times_s.shape[0]) for g in hm.PUBLIC_BLOCK_BYTES}
        for r in hm.REGIONS:
            by_group[r.group] += self.arrays[r.name].scenario.force_n(times_s).sum(axis=1)
        cn = np.stack([by_group[g] for g in JOINT_GROUPS], axis=1) * 100.0
        return np.minimum(np.rint(cn), 0xFFFF).astype(np.int64)

    def _move_joints(self, until_s: float) -> None:
        """Step the joints frame by frame (at most ``MAX_JOINT_STEPS`` steps) up to ``until_s``."""
        dt = until_s - self._joint_t
        if dt <= 0.0:
            return
        steps = min(max(round(dt / FRAME_PERIOD_S), 1), MAX_JOINT_STEPS)
        times = self._joint_t + dt * np.arange(1, steps + 1) / steps
        forces = self._group_forces_cn(times)
        step = ANGLE_RATE_PER_S * dt / steps
        for k in range(steps):
            for j in range(hm.N_JOINTS):
                if self.errors[j] or self._force_reached(j, forces[k]):
                    continue
                target, now = float(self.angle_set[j]), self.angle_actual[j]
                self.angle_actual[j] = min(now + step, target) if target > now else max(now - step, target)
        self._joint_t = until_s

    def status_codes(self) -> list[int]:
        self._refresh()
        forces = self.force_actual_cn()
        out = []
        for j in range(hm.N_JOINTS):
            bits = self.errors[j]
            if bits & ~1:
                out.append(4)
            elif bits & 1:
                out.append(3)
            elif self._force_reached(j, forces):
                out.append(2)
            elif round(self.angle_actual[j]) != self.angle_set[j]:
                out.append(1)
            else:
                out.append(0)
        return out

    def set_error(self, joint: str, bit: str, on: bool = True) -> None:
        """Set (or clear) error ``bit`` (a name of ``hand_map.ERROR_BITS``) of ``joint``."""
        if joint not in hm.JOINTS:
            raise ValueError(f"no joint {joint!r} (joints: {', '.join(hm.JOINTS)})")
        names = {v: k for k, v in hm.ERROR_BITS.items()}
        if bit not in names:
            raise ValueError(f"no error bit {bit!r} (bits: {', '.join(names)})")
        self._refresh()
        j, mask = hm.JOINTS.index(joint), 1 << names[bit]
        self.errors[j] = self.errors[j] | mask if on else self.errors[j] & ~mask

    # ------------------------------------------------------------------ registers
    def control_registers(self) -> list[int]:
        """Holding registers ``CONTROL_FIRST .. CONTROL_LAST``."""
        self._refresh()
        regs = [0] * (hm.CONTROL_LAST - hm.CONTROL_FIRST + 1)

        def put(address: int, values: Sequence[int]) -> None:
            at = address - hm.CONTROL_FIRST
            regs[at : at + len(values)] = list(values)

        put(hm.HR_ANGLE_SET, self.angle_set)
        put(hm.HR_FORCE_SET, self.force_set_cn)
        put(hm.HR_ANGLE_ACTUAL, [round(a) for a in self.angle_actual])
        put(hm.HR_FORCE_ACTUAL, self.force_actual_cn())
        put(hm.HR_STATUS, self.status_codes())
        put(hm.HR_ERRORS, self.errors)
        return regs

    def read(self, address: int, count: int) -> list[int]:
        """``count`` holding registers from ``address`` (each must be mapped: ``is_mapped``)."""
        self._refresh()
        control = self.control_registers() if address <= hm.CONTROL_LAST else []
        out: list[int] = []
        for a in range(address, address + count):
            if hm.CONTROL_FIRST <= a <= hm.CONTROL_LAST:
                out.append(control[a - hm.CONTROL_FIRST])
                continue
            out.append(self._taxel_at(a))
        return out

    def _taxel_at(self, address: int) -> int:
        where = self._where.get(address)
        if where is None:
            raise HandWriteError(2, f"holding register {address} is not mapped")
        return int(self._taxels[where[0]][where[1]])

    def write(self, address: int, values: Sequence[int]) -> None:
        """Apply a write of holding registers, all or nothing; ``HandWriteError`` if refused."""
        changes: list[tuple[int, int]] = []
        for k, value in enumerate(values):
            a = address + k
            if hm.HR_ANGLE_SET <= a < hm.HR_ANGLE_SET + hm.N_JOINTS:
                limit = hm.ANGLE_MAX
            elif hm.HR_FORCE_SET <= a < hm.HR_FORCE_SET + hm.N_JOINTS:
                limit = hm.FORCE_SET_MAX_CN
            elif a == hm.HR_FORCE_CALIBRATE:
                limit = 0xFFFF
            else:
                raise HandWriteError(2, f"holding register {a} is not writable")
            if not 0 <= value <= limit:
                raise HandWriteError(3, f"value {value} not allowed in holding register {a} (0..{limit})")
            changes.append((a, int(value)))
        self._refresh()
        for a, value in changes:
            if a == hm.HR_FORCE_CALIBRATE:
                self.force_calibrations += 1
            elif a < hm.HR_FORCE_SET:
                self.angle_set[a - hm.HR_ANGLE_SET] = value
            else:
                self.force_set_cn[a - hm.HR_FORCE_SET] = value
