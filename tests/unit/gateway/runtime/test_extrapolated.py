"""The calibrated force range is not a blindfold: a channel calibrated on a bench's 0.5-5 N
holds reads 0.3 N and 8 N as forces flagged ``extrapolated`` (not 0 N ``no_contact`` and 5 N
``saturated``), whether it is read by the physical model, a line, a lookup or a curve; at
rest it reads 0 N ``no_contact``. Each channel comes from a calibration file as ``calibrate``
writes it, read through the gateway's configuration."""

from __future__ import annotations

import math
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from gateway.analysis.calibration import model_force_range
from gateway.config import DeviceConfig, parse_config
from gateway.errors import ConfigError
from gateway.modbus.image import RawSample
from gateway.model import SensorModel, SensorParams
from gateway.runtime.processor import DeviceProcessor
from gateway.runtime.snapshot import ChannelStatus

PAPER = ("tunneling", "contact", "creep")
TRUE = SensorParams(r0_ohm=225e3, e0_pa=13.5e6, rho2_ohm_m=0.85, e1_pa=140e6, mu1_pa_s=1.2e10)
CALIBRATED = (0.5, 5.0)  # N: the bench's holds
#: held loads (N), each for ``HOLD_S`` at 10 Hz: below, inside and above the calibrated range, rest
HOLDS = (0.3, 2.0, 8.0, 0.0)
HOLD_S = 20.0
EXPECTED = ("extrapolated", "ok", "extrapolated", "no_contact")
M, N = 2e-5, 1e-6  # the line: S/N, S
K, EXPONENT, A1, TAU = 1e-4, 0.8, 0.2, 5.0  # the curve: G = k x^n, one creep element
#: the lookup: F linear in ln R, 2.25 N per decade, 5 N at 1 kohm to 0.5 N at 100 kohm
LOOKUP_R = (1e3, 1e4, 1e5)
LOOKUP_F = (5.0, 2.75, 0.5)
#: the device reports fault bitmaps that flag nothing: a sensor open at rest (+inf ohm) is a
#: reading, no current, not an open circuit
NOT_OPEN = np.array([False])


def _params_lines(low_n: float, high_n: float) -> str:
    return "\n".join(
        f"{name} = {getattr(TRUE, name)!r}" for name in ("r0_ohm", "e0_pa", "rho2_ohm_m", "e1_pa", "mu1_pa_s")
    ) + (f"\nforce_min_n = {low_n!r}\nforce_max_n = {high_n!r}\n")


def _calibrated_lines() -> str:
    return f"calibrated_min_n = {CALIBRATED[0]!r}\ncalibrated_max_n = {CALIBRATED[1]!r}\n"


def _device(tmp_path: Path, calibration: str) -> DeviceConfig:
    cal = tmp_path / "cal.toml"
    cal.write_text(calibration)
    config = parse_config(
        f"""
[[bus]]
name = "bench"
kind = "tcp"
host = "127.0.0.1"
port = 5020
[[bus.device]]
name = "array1"
device_id = 1
profile = "tactile-sim"
encoding = "float32"
channels = 1
calibration = "{cal}"
[[bus.device.channel]]
index = 0
name = "tip"
""",
        tmp_path / "gateway.toml",
    )
    return config.buses[0].devices[0]


def _loads() -> tuple[np.ndarray, np.ndarray]:
    t = np.arange(0.0, HOLD_S * len(HOLDS), 0.1)
    return t, np.array(HOLDS)[np.minimum((t // HOLD_S).astype(int), len(HOLDS) - 1)]


def _physics_ohm(t: np.ndarray, f: np.ndarray) -> np.ndarray:
    out, _ = SensorModel(PAPER, TRUE).simulate(f[:, None], t)
    return np.asarray(out.total_ohm[:, 0])


def _line_ohm(t: np.ndarray, f: np.ndarray) -> np.ndarray:
    return 1.0 / (M * f + N)


def _lookup_ohm(t: np.ndarray, f: np.ndarray) -> np.ndarray:
    return 1e3 * 10.0 ** ((5.0 - f) / 2.25)


def _curve_ohm(t: np.ndarray, f: np.ndarray) -> np.ndarray:
    """The apparent force x = F + z (z creeps towards a1 F with tau) through G = k x^n;
    at rest (0 N) an open sensor."""
    z, held, out = 0.0, 0.0, np.empty(t.size)
    for k in range(t.size):
        e = math.exp(-(t[k] - t[k - 1]) / TAU) if k else 1.0
        z = e * z + (1.0 - e) * A1 * held
        x = f[k] + z
        out[k] = math.inf if f[k] == 0.0 else 1.0 / (K * x**EXPONENT)
        held = f[k]
    return out


low_model, high_model = model_force_range(CALIBRATED)
PHYSICS = f'[channel."tip"]\n{_params_lines(low_model, high_model)}{_calibrated_lines()}'
LINE = (
    f'[channel."tip"]\nforce_min_n = 0.5\nforce_max_n = 5.0\n{_calibrated_lines()}'
    f'[line."tip"]\nslope_s_per_n = {M!r}\nintercept_s = {N!r}\nheld_out_force_rms_n = 0.05\n'
)
LOOKUP = (
    f'[channel."tip"]\nforce_min_n = 0.5\nforce_max_n = 5.0\n{_calibrated_lines()}'
    f'[lookup."tip"]\nresistance_ohm = {list(LOOKUP_R)!r}\nforce_n = {list(LOOKUP_F)!r}\n'
)
CURVE = (
    f'[channel."tip"]\nforce_min_n = 0.5\nforce_max_n = 5.0\n{_calibrated_lines()}'
    f'[curve."tip"]\nkind = "power_law"\ncoefficient_s = {K!r}\nexponent = {EXPONENT!r}\n'
    f"creep_fraction = {A1!r}\ncreep_tau_s = {TAU!r}\nforce_min_n = 0.5\nforce_max_n = 5.0\n"
)


@pytest.mark.parametrize(
    ("calibration", "resistance"),
    [(PHYSICS, _physics_ohm), (LINE, _line_ohm), (LOOKUP, _lookup_ohm), (CURVE, _curve_ohm)],
    ids=["physics", "line", "lookup", "curve"],
)
def test_held_loads_outside_the_calibrated_range_read_as_forces_flagged_extrapolated(
    tmp_path: Path, calibration: str, resistance: Callable[[np.ndarray, np.ndarray], np.ndarray]
) -> None:
    dev = _device(tmp_path, calibration)
    assert dev.channel("tip").calibrated_range_n == CALIBRATED
    proc = DeviceProcessor(dev, "bench", 0.1)
    t, f = _loads()
    r = resistance(t, f)
    state = proc.rested_state()  # the bench starts unloaded
    statuses: dict[float, set[str]] = {load: set() for load in HOLDS}
    forces: dict[float, list[float]] = {load: [] for load in HOLDS}
    for k in range(t.size):
        raw = RawSample(resistance_ohm=np.array([r[k]]), open_bits=NOT_OPEN)
        snap, state = proc.process(state, raw, 1e9 + t[k], t[k])
        statuses[f[k]].add(ChannelStatus(int(snap.status[0])).label)
        forces[f[k]].append(float(snap.force_n[0]))
        assert snap.channels_in_contact == (1 if f[k] > 0 else 0)
        assert snap.total_force_n == pytest.approx(f[k], abs=1e-9)
    # every sample of a hold, from its first: the creep is tracked (physics, curve) or absent
    for load, label in zip(HOLDS, EXPECTED, strict=True):
        assert statuses[load] == {label}, (load, statuses[load])
        np.testing.assert_allclose(forces[load], load, rtol=0, atol=1e-9)


@pytest.mark.parametrize(
    ("calibration", "resistance"),
    [(LINE, _line_ohm), (LOOKUP, _lookup_ohm), (CURVE, _curve_ohm)],
    ids=["line", "lookup", "curve"],
)
def test_a_line_lookup_or_curve_flags_outside_its_own_range_without_the_channel_s_keys(
    tmp_path: Path, calibration: str, resistance: Callable[[np.ndarray, np.ndarray], np.ndarray]
) -> None:
    """An older file (no calibrated_min_n/max_n): the line's, lookup's or curve's own range
    (0.5-5 N here) is the calibrated one."""
    dev = _device(tmp_path, calibration.replace(_calibrated_lines(), ""))
    assert dev.channel("tip").calibrated_range_n is None
    proc = DeviceProcessor(dev, "bench", 0.1)
    loads = np.array([0.3, 2.0, 8.0])
    t = np.arange(loads.size) * HOLD_S
    r = resistance(t, loads)
    state = proc.rested_state()  # the bench starts unloaded
    for k in range(loads.size):
        snap, state = proc.process(state, RawSample(resistance_ohm=r[k : k + 1]), 1e9 + t[k], t[k])
        assert ChannelStatus(int(snap.status[0])).label == EXPECTED[k]
        assert snap.force_n[0] == pytest.approx(loads[k], rel=1e-9)


def test_a_calibration_file_without_the_calibrated_range_reads_as_before(tmp_path: Path) -> None:
    """A physics channel of an older file (force_min_n/force_max_n = the record's 0.5-5 N, no
    calibrated_min_n/max_n) still reads 0 N no_contact below and 5 N saturated above."""
    dev = _device(tmp_path, f'[channel."tip"]\n{_params_lines(*CALIBRATED)}')
    assert dev.channel("tip").calibrated_range_n is None
    proc = DeviceProcessor(dev, "bench", 0.1)
    t, f = _loads()
    r = _physics_ohm(t, f)
    state = proc.rested_state()  # the bench starts unloaded
    seen: dict[float, set[tuple[str, float]]] = {load: set() for load in HOLDS}
    for k in range(t.size):
        snap, state = proc.process(
            state, RawSample(resistance_ohm=np.array([r[k]]), open_bits=NOT_OPEN), 1e9 + t[k], t[k]
        )
        if t[k] % HOLD_S >= 2.0 and f[k] != 2.0:
            seen[f[k]].add((ChannelStatus(int(snap.status[0])).label, float(snap.force_n[0])))
    assert seen[0.3] == {("no_contact", 0.0)}
    assert seen[8.0] == {("saturated", 5.0)}
    assert seen[0.0] == {("no_contact", 0.0)}


def test_the_device_s_saturated_bit_turns_an_extrapolated_force_saturated(tmp_path: Path) -> None:
    proc = DeviceProcessor(_device(tmp_path, LINE), "bench", 0.1)
    r = np.array([_line_ohm(np.zeros(1), np.array([8.0]))[0]])
    snap, _ = proc.process(proc.initial_state(), RawSample(resistance_ohm=r), 1e9, 0.0)
    assert ChannelStatus(int(snap.status[0])) == ChannelStatus.EXTRAPOLATED
    raw = RawSample(resistance_ohm=r, saturated_bits=np.array([True]))
    snap, _ = proc.process(proc.initial_state(), raw, 1e9, 0.0)
    assert ChannelStatus(int(snap.status[0])) == ChannelStatus.SATURATED


@pytest.mark.parametrize(
    ("lines", "key", "allowed"),
    [
        ("calibrated_min_n = -0.5\n", "calibrated_min_n", "[0, inf) N"),
        ("calibrated_max_n = 0\n", "calibrated_max_n", "(0, inf] N"),
        ('calibrated_max_n = "5"\n', "calibrated_max_n", "(0, inf] N"),
        (
            "calibrated_min_n = 5.0\ncalibrated_max_n = 0.5\n",
            "calibrated_max_n",
            "(calibrated_min_n = 5.0, inf] N",
        ),
    ],
)
def test_a_bad_calibrated_range_names_the_file_and_the_key(
    tmp_path: Path, lines: str, key: str, allowed: str
) -> None:
    with pytest.raises(ConfigError) as info:
        _device(tmp_path, f'[channel."tip"]\nr0_ohm = 2e5\n{lines}')
    message = str(info.value)
    assert f"cal.toml: channel.tip.{key}" in message and allowed in message, message


def test_one_bound_alone_leaves_the_other_open(tmp_path: Path) -> None:
    dev = _device(tmp_path, '[channel."tip"]\ncalibrated_max_n = 5.0\n')
    assert dev.channel("tip").calibrated_range_n == (0.0, 5.0)
