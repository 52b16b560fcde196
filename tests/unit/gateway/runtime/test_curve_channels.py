"""Channels read through a curve with drift correction (``CurveChannel`` conversions) in the
runtime: ``DeviceProcessor.process`` tracks them, keeps their state, and a calibration file's
``[curve."name"]`` table gives them."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from gateway.config import ChannelConfig, DeviceConfig, RegisterMap, parse_config
from gateway.config.layout import GridLayout
from gateway.errors import ConfigError
from gateway.modbus.image import RawSample
from gateway.model import PAPER_EFFECTS, Divider, SensorModel, SensorParams
from gateway.model.conversion import Conversion, line_conversion
from gateway.model.curves import CurveChannel, Drift, LineCurve, LookupCurve, PowerLawCurve
from gateway.runtime.processor import DeviceProcessor, DeviceState
from gateway.runtime.snapshot import ChannelStatus, DeviceSnapshot

K, N = 1e-4, 0.8  # G = k F^n
A1, TAU = 0.2, 5.0
CREEP = CurveChannel(PowerLawCurve(K, N), Drift(creep_fraction=A1, creep_tau_s=TAU))
LINE = line_conversion(slope_s_per_n=2e-5, intercept_s=1e-6, force_min_n=0.05, force_max_n=10.0)


def make_device(
    conversions: list[Conversion | None],
    params: list[SensorParams] | None = None,
    baseline_ohm: list[float | None] | None = None,
) -> DeviceConfig:
    n = len(conversions)
    channels = tuple(
        ChannelConfig(
            index=i,
            name=f"ch{i:02d}",
            x_mm=float(i),
            y_mm=0.0,
            enabled=True,
            effects=PAPER_EFFECTS,
            params=SensorParams() if params is None else params[i],
            baseline_ohm=None if baseline_ohm is None else baseline_ohm[i],
            conversion=conversions[i],
        )
        for i in range(n)
    )
    return DeviceConfig(
        name="arr",
        device_id=1,
        encoding="float32",
        n_channels=n,
        registers=RegisterMap(),
        front_end=Divider(),
        channels=channels,
        allow_write=False,
        layout=GridLayout(n, n, 2.5, 2.5),
        calibration=None,
    )


def r_power(x: float) -> float:
    """The resistance at which the power law reads the apparent force x."""
    return 1.0 / (K * x**N)


def crept(force: float, since_s: float) -> float:
    """The apparent force under ``force`` held since ``since_s`` ago (one Kelvin element; the
    tracker's steps telescope to the closed form, see test_curves)."""
    return force * (1.0 + A1 * (1.0 - math.exp(-since_s / TAU)))


def feed(
    proc: DeviceProcessor,
    state: DeviceState,
    rows: list[list[float]],
    times: list[float],
) -> tuple[list[DeviceSnapshot], DeviceState]:
    snaps = []
    for r, t in zip(rows, times, strict=True):
        snap, state = proc.process(state, RawSample(resistance_ohm=np.array(r)), 1e9 + t, t)
        snaps.append(snap)
    return snaps, state


def labels(snap: DeviceSnapshot) -> list[str]:
    return [ChannelStatus(s).label for s in snap.status]


def test_a_held_step_reads_the_applied_force_while_the_static_one_creeps() -> None:
    proc = DeviceProcessor(make_device([CREEP]), "bus", 0.1)
    times = [0.0, 0.1, 0.5, 1.0, 2.0, 5.0, 10.0, 30.0, 60.0]
    snaps, state = feed(proc, proc.rested_state(), [[r_power(crept(2.0, t))] for t in times], times)
    for snap, t in zip(snaps, times, strict=True):
        assert labels(snap) == ["ok"]
        assert snap.force_n[0] == pytest.approx(2.0, rel=1e-12)
        assert snap.force_static_n[0] == pytest.approx(crept(2.0, t), rel=1e-12)
        assert snap.total_force_n == pytest.approx(2.0, rel=1e-12)
    # the static estimate ends 2 x 0.2 (1 - e^-12) = 0.39999 N above
    assert snaps[-1].force_static_n[0] - 2.0 == pytest.approx(0.4 * (1.0 - math.exp(-12.0)), rel=1e-9)
    assert state.curve_state is not None
    assert state.curve_state.z1[0] == pytest.approx(0.4 * (1.0 - math.exp(-12.0)), rel=1e-12)


def test_mixed_device_physics_line_and_curve_each_read_right() -> None:
    model = SensorModel(PAPER_EFFECTS, [SensorParams()])
    r_phys = float(model.resistance(np.array([2.0]))[0])
    r_line = 1.0 / (2e-5 * 3.0 + 1e-6)  # 3 N on the line
    mixed = DeviceProcessor(make_device([None, LINE, CREEP, None]), "bus", 0.1)
    plain = DeviceProcessor(make_device([None, None]), "bus", 0.1)
    assert mixed.curves is not None and mixed.curves.positions.tolist() == [1, 2]
    sm, sp = mixed.rested_state(), plain.rested_state()
    for k, t in enumerate([0.0, 1.0, 5.0, 30.0]):
        phys = [r_phys * (1.0 - 0.01 * k), r_phys * 1.2]
        snap_m, sm = mixed.process(
            sm, RawSample(resistance_ohm=np.array([phys[0], r_line, r_power(crept(1.5, t)), phys[1]])), t, t
        )
        snap_p, sp = plain.process(sp, RawSample(resistance_ohm=np.array(phys)), t, t)
        assert labels(snap_m) == ["ok"] * 4
        # the physics channels read exactly what a device of physics channels alone reads
        np.testing.assert_array_equal(snap_m.force_n[[0, 3]], snap_p.force_n)
        np.testing.assert_array_equal(snap_m.force_static_n[[0, 3]], snap_p.force_static_n)
        assert snap_m.force_n[1] == pytest.approx(3.0, rel=1e-9)
        assert snap_m.force_static_n[1] == snap_m.force_n[1]
        assert snap_m.force_n[2] == pytest.approx(1.5, rel=1e-12)
        assert snap_m.force_static_n[2] == pytest.approx(crept(1.5, t), rel=1e-12)
        assert snap_m.total_force_n == pytest.approx(float(np.sum(snap_m.force_n)), rel=1e-12)
    assert 0.0 < snap_m.force_n[0] < 2.0  # the physics channel's load fell with its resistance rising
    assert sm.model_state is not None


def test_statuses_of_curve_channels() -> None:
    kinds = [CREEP, CurveChannel(LineCurve(2e-5, 1e-6)), CurveChannel(LookupCurve((1e3, 1e4), (4.0, 1.0)))]
    proc = DeviceProcessor(make_device(list(kinds)), "bus", 0.1)
    bad = {
        math.inf: "open",  # no fault bitmaps: the +inf rail is an open circuit
        math.nan: "error",
        -5.0: "error",
        0.0: "short",
    }
    for r, label in bad.items():
        snap, _ = proc.process(proc.rested_state(), RawSample(resistance_ohm=np.full(3, r)), 0.0, 0.0)
        assert labels(snap) == [label] * 3, r
        assert np.isnan(snap.force_n).all() and snap.total_force_n == 0.0
    # the line below its intercept and the lookup beyond its last knot read <= 0 N: no contact
    rs = np.array([r_power(1.0), 1.0 / 0.5e-6, 1e5])
    snap, _ = proc.process(proc.rested_state(), RawSample(resistance_ohm=rs), 0.0, 0.0)
    assert labels(snap) == ["ok", "no_contact", "no_contact"]
    np.testing.assert_allclose(snap.force_n, [1.0, 0.0, 0.0], rtol=1e-12)
    assert snap.channels_in_contact == 1


def test_open_at_rest_with_fault_bitmaps_reads_no_contact() -> None:
    """With bitmaps that do not flag the channel, the +inf rail is a reading: no current, an
    open sensor at rest: 0 N, no contact (as for a physics channel), never a force > 0."""
    # n = 2: a conductance of 1 / 1.8e308 ohm would read (5.6e-305)^(1/2) = 7.5e-153 N > 0,
    # and an offset 0.2 N more: neither is a load
    square = CurveChannel(PowerLawCurve(1e-4, 2.0), offset_n=0.2, force_min_n=0.5)
    proc = DeviceProcessor(make_device([square, CREEP, CREEP, None]), "bus", 0.1)
    raw = RawSample(resistance_ohm=np.full(4, math.inf), open_bits=np.array([False, False, True, False]))
    snap, _ = proc.process(proc.rested_state(), raw, 0.0, 0.0)
    assert labels(snap) == ["no_contact", "no_contact", "open", "no_contact"]
    assert snap.force_n[0] == 0.0 and snap.force_n[1] == 0.0
    assert snap.channels_in_contact == 0 and snap.total_force_n == 0.0


def test_an_invalid_sample_keeps_the_curve_state_and_the_next_one_reads_right() -> None:
    proc = DeviceProcessor(make_device([CREEP]), "bus", 0.1)
    rows = [[r_power(crept(2.0, 0.0))], [math.nan], [r_power(crept(2.0, 3.0))]]
    snaps, _ = feed(proc, proc.rested_state(), rows, [0.0, 1.0, 3.0])
    assert [labels(s)[0] for s in snaps] == ["ok", "error", "ok"]
    assert snaps[2].force_n[0] == pytest.approx(2.0, rel=1e-12)


def test_carry_state_keeps_the_curve_state_only_while_the_curves_are_unchanged() -> None:
    dev = make_device([None, CREEP])
    old = DeviceProcessor(dev, "bus", 0.1)
    times = [0.0, 1.0, 2.0, 4.0]
    rows = [[1e5, r_power(crept(2.0, t))] for t in times]
    _, state = feed(old, old.rested_state(), rows, times)
    assert state.curve_state is not None and state.curve_state.z1[0] > 0.0

    # a reload with the same configuration: the drift state carries over, the force stays F
    same = DeviceProcessor(make_device([None, CREEP]), "bus", 0.1)
    kept = same.carry_state(old, state)
    assert kept.curve_state is state.curve_state
    snaps, _ = feed(same, kept, [[1e5, r_power(crept(2.0, 10.0))]], [10.0])
    assert snaps[0].force_n[1] == pytest.approx(2.0, rel=1e-12)

    # another channel's parameters changed: the curve channel still keeps its state
    other = DeviceProcessor(
        make_device([None, CREEP], params=[SensorParams(r0_ohm=2e5), SensorParams()]), "bus", 0.1
    )
    assert other.carry_state(old, state).curve_state is state.curve_state

    # the curve changed: its state is not known, so the first sample reads the equilibrium at
    # its load: the static force over 1 + a
    changed = CurveChannel(PowerLawCurve(K, N), Drift(creep_fraction=0.1, creep_tau_s=TAU))
    new = DeviceProcessor(make_device([None, changed]), "bus", 0.1)
    fresh = new.carry_state(old, state)
    assert fresh.curve_state is None
    snaps, _ = feed(new, fresh, [[1e5, r_power(crept(2.0, 10.0))]], [10.0])
    assert snaps[0].force_n[1] == pytest.approx(crept(2.0, 10.0) / 1.1, rel=1e-12)


# ---------------------------------------------------------------- calibration files


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
channels = 2
calibration = "{cal}"
[[bus.device.channel]]
index = 0
name = "tip"
""",
        tmp_path / "gateway.toml",
    )
    return config.buses[0].devices[0]


CURVE_TABLE = """
[curve."tip"]
kind = "power_law"
coefficient_s = 1e-4
exponent = 0.8
creep_fraction = 0.2
creep_tau_s = 5.0
force_min_n = 0.1
force_max_n = 12.0
held_out_force_rms_n = 0.03
"""


def test_a_curve_table_gives_the_channel_its_curve_and_the_runtime_tracks_it(tmp_path: Path) -> None:
    dev = _device(tmp_path, CURVE_TABLE)
    assert dev.channel("tip").conversion == CurveChannel(
        PowerLawCurve(1e-4, 0.8),
        Drift(creep_fraction=0.2, creep_tau_s=5.0),
        force_min_n=0.1,
        force_max_n=12.0,
    )
    assert dev.channel("ch01").conversion is None
    proc = DeviceProcessor(dev, "bench", 0.1)
    fe = dev.front_end
    state = proc.rested_state()
    r_phys = float(
        SensorModel(dev.channel("ch01").effects, [dev.channel("ch01").params]).resistance(np.array([2.0]))[0]
    )
    for t in (0.0, 2.0, 8.0):
        counts = fe.counts(fe.output_voltage(np.array([r_power(crept(3.0, t)), r_phys])))
        snap, state = proc.process(state, RawSample(counts=counts), t, t)
        assert labels(snap) == ["ok", "ok"]
        # through the ADC: the curve at the quantized resistance, tracked; within the ADC's step
        assert snap.force_n[0] == pytest.approx(3.0, rel=0.02)
        assert snap.force_static_n[0] == pytest.approx(crept(3.0, t), rel=0.02)
    assert snap.force_static_n[0] - snap.force_n[0] > 0.4 * 3.0 * 0.2  # the creep it took off


@pytest.mark.parametrize(
    ("table", "where", "allowed"),
    [
        (CURVE_TABLE.replace("exponent = 0.8", "exponent = -0.8"), "curve.tip.exponent", "allowed: (0, 10]"),
        (
            CURVE_TABLE.replace("creep_fraction = 0.2", "creep_fraction = 7"),
            "curve.tip.creep_fraction",
            "[-0.9, 5.0]",
        ),
        (CURVE_TABLE.replace("kind = ", "knid = "), "curve.tip.kind", "allowed: power_law, line, lookup"),
        (CURVE_TABLE + "slope = 1\n", "curve.tip.slope", "unknown key"),
        (
            CURVE_TABLE.replace("coefficient_s = 1e-4\n", ""),
            "curve.tip.coefficient_s",
            "required key is missing",
        ),
        (
            '[curve."tip"]\nkind = "lookup"\nresistance_ohm = [1e3, 1e3]\nforce_n = [2, 1]\n',
            "curve.tip.resistance_ohm[1]",
            "strictly increasing",
        ),
        ('[curve."tpi"]\nkind = "line"\n', "curve.tpi", "did you mean 'tip'?"),
        (
            CURVE_TABLE + '[lookup."tip"]\nresistance_ohm = [1e3, 1e4]\nforce_n = [2, 1]\n',
            "curve.tip",
            "keep one",
        ),
    ],
)
def test_a_bad_curve_table_names_the_file_and_the_key(
    tmp_path: Path, table: str, where: str, allowed: str
) -> None:
    with pytest.raises(ConfigError) as info:
        _device(tmp_path, table)
    shown = str(info.value)
    assert f"{tmp_path / 'cal.toml'}: {where}: " in shown, shown
    assert allowed in shown, shown
    assert f"(calibration file of bus[0].device[0].calibration in {tmp_path / 'gateway.toml'})" in shown


def test_a_starting_gateway_reads_a_loaded_settled_sensor_at_its_load_on_every_kind_of_channel() -> None:
    """A gateway that starts on a sensor already loaded (its history not known) reads it from the
    equilibrium at that load, on a physics channel and a curve channel alike; one known to have
    been at rest (``rested_state``) reads the same resistances as a load just applied."""
    model = SensorModel(PAPER_EFFECTS, [SensorParams()])
    r_phys = float(model.held_step(np.array([3.0]), np.array([1e9])).total_ohm[0])
    r_curve = r_power(crept(1.5, math.inf))
    proc = DeviceProcessor(make_device([None, CREEP]), "bus", 0.1)
    times = [0.0, 0.1, 1.0, 10.0]
    rows = [[r_phys, r_curve]] * len(times)
    started, _ = feed(proc, proc.initial_state(), rows, times)
    for snap in started:
        assert labels(snap) == ["ok", "ok"]
        assert snap.force_n[0] == pytest.approx(3.0, rel=1e-6)
        assert snap.force_n[1] == pytest.approx(1.5, rel=1e-12)
    rested, _ = feed(proc, proc.rested_state(), rows, times)
    assert rested[0].force_n[0] > 3.0 * 1.01 and rested[0].force_n[1] > 1.5 * 1.1
