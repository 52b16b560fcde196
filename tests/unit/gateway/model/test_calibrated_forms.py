"""One calibration form, read the same through every path: a [line] table, a [curve] line, the
line ``calibrate --model line`` writes; a [lookup] table and a [curve] lookup beyond their end
knots; the recovery time constant and the equilibrium start, by hand."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from gateway.config import ChannelConfig, DeviceConfig, RegisterMap
from gateway.config.layout import GridLayout
from gateway.modbus.image import RawSample
from gateway.model import PAPER_EFFECTS, Divider, ForceStatus, SensorParams
from gateway.model.calibrated import CurveChannel, channel_from_table, curve_from_table, line_channel
from gateway.model.drift import Drift, kelvin_unit_series
from gateway.model.static_curves import LineCurve, LookupCurve, PowerLawCurve
from gateway.model.tracker import CurveSet, track_series
from gateway.runtime.processor import DeviceProcessor
from gateway.runtime.snapshot import ChannelStatus

RESISTANCES = st.one_of(
    st.floats(1.0, 14.0).map(lambda e: 10.0**e),  # from a near short to a nearly open sensor
    st.sampled_from([math.inf, 1e12, 1e300]),
)


def _device(channels: list[CurveChannel]) -> DeviceConfig:
    n = len(channels)
    return DeviceConfig(
        name="arr", device_id=1, encoding="float32", n_channels=n, registers=RegisterMap(),
        front_end=Divider(), allow_write=False, layout=GridLayout(n, 1, 2.5, 2.5), calibration=None,
        channels=tuple(
            ChannelConfig(i, f"ch{i:02d}", float(i), 0.0, True, PAPER_EFFECTS, SensorParams(), None, c)
            for i, c in enumerate(channels)
        ),
    )  # fmt: skip


def _read(channels: list[CurveChannel], r: float) -> tuple[list[float], list[int]]:
    """Force (N) and ``ForceStatus`` of every channel read at ``r`` by the tracker."""
    cset = CurveSet(channels)
    f, s, _, e, _ = cset.track(np.full(len(channels), r), cset.initial_state(), 0.0)
    status = np.where(e, np.int8(ForceStatus.EXTRAPOLATED), s)
    return f.tolist(), status.tolist()


@settings(max_examples=300, deadline=None)
@given(
    slope=st.floats(1e-6, 1e-4),
    intercept=st.floats(-2e-5, 2e-5),
    low=st.floats(0.05, 2.0),
    span=st.floats(1.5, 20.0),
    r=RESISTANCES,
)
def test_a_line_reads_the_same_through_every_path(
    slope: float, intercept: float, low: float, span: float, r: float
) -> None:
    """The line calibrate writes (``line_channel``: its range starts above a phantom force), its
    [line] table, the same line as a [curve] table, and the processor: one force, one status,
    from a short to an open sensor. A nearly open sensor never reads a force."""
    written = line_channel(LineCurve(slope, intercept), low, low * span)
    as_line = channel_from_table("line", written.table(), 0.01, 1.0)
    assert as_line == written
    as_curve = curve_from_table(
        {"kind": "line", **written.curve.table(), "force_min_n": written.force_min_n,
         "force_max_n": written.force_max_n}
    )  # fmt: skip
    forces, statuses = _read([written, as_line, as_curve], r)
    assert forces[0] == forces[1] == forces[2] or all(math.isnan(f) for f in forces)
    assert statuses[0] == statuses[1] == statuses[2]
    proc = DeviceProcessor(_device([as_line, as_curve]), "bus", 0.1)
    bits = np.zeros(2, dtype=np.bool_)  # with fault bitmaps the rails are readings
    snap, _ = proc.process(
        proc.initial_state(), RawSample(resistance_ohm=np.full(2, r), open_bits=bits), 0, 0
    )
    assert snap.status[0] == snap.status[1]
    assert snap.force_n[0] == snap.force_n[1] or np.isnan(snap.force_n).all()
    if r >= 1e12:  # nearly open or open: never a phantom force (at most what 1 pS means)
        assert max(forces) <= 1e-12 / slope * (1.0 + 1e-9)
        if written.zero_conductance_force_n > 0.0:
            assert statuses == [ForceStatus.NO_CONTACT] * 3 and forces == [0.0] * 3
            assert ChannelStatus(int(snap.status[0])).label == "no_contact"


def test_the_phantom_line_of_the_issue_reads_no_contact_on_every_path() -> None:
    """Slope 2e-5 S/N, intercept -1e-5 S, a sensor at 1e12 ohm: 0 N no contact as a [line]
    table and as a [curve] line (before, the curve read 0.5 N there)."""
    line = LineCurve(2e-5, -1e-5)
    assert line.force_at_zero_conductance_n == pytest.approx(0.5)
    written = line_channel(line, 0.1, 5.0)
    assert written.force_min_n == pytest.approx(0.55)  # 1.1 x 0.5 N
    curve = curve_from_table({"kind": "line", **line.table(), "force_min_n": 0.55, "force_max_n": 5.0})
    forces, statuses = _read([written, curve], 1e12)
    assert forces == [0.0, 0.0] and statuses == [ForceStatus.NO_CONTACT] * 2
    with pytest.raises(ValueError, match=r"zero conductance at 0\.5 N"):
        curve_from_table({"kind": "line", **line.table(), "force_min_n": 0.3, "force_max_n": 5.0})


@settings(max_examples=200, deadline=None)
@given(
    knots=st.lists(st.integers(0, 100), min_size=3, max_size=8, unique=True),
    r=st.floats(0.0, 12.0).map(lambda e: 10.0**e),
)
def test_a_lookup_reads_the_same_as_a_table_and_a_curve_beyond_its_end_knots(
    knots: list[float], r: float
) -> None:
    """A lookup fitted by calibrate (``LookupCurve.fit``), written as a [lookup] table, and the
    same knots as a [curve] lookup: the same force inside and beyond the end knots (along the end
    segments, never flat), the same status; and the ranking's reading (``track_series``) too."""
    f_knots = np.sort(np.asarray(knots, dtype=np.float64))[::-1] * 0.1 + 0.5
    r_knots = np.logspace(3, 3 + len(knots) - 1, len(knots))
    rows_r = np.repeat(r_knots, 4)
    rows_f = np.repeat(f_knots, 4)
    lookup = LookupCurve.fit(rows_f, rows_r)
    table = channel_from_table("lookup", lookup.table(), 0.0, 0.0)
    curve = curve_from_table(
        {
            "kind": "lookup",
            **lookup.table(),
            "force_min_n": table.force_min_n,
            "force_max_n": table.force_max_n,
        }
    )
    forces, statuses = _read([table, curve], r)
    assert forces[0] == forces[1] and statuses[0] == statuses[1]
    ranked, _ = track_series(table, [r], [0.0])
    assert ranked[0] == forces[0]
    # beyond the end knots along the end segments, never flat
    if r > 1.01 * r_knots[-1]:
        assert forces[0] < lookup.force_n[-1] or statuses[0] == ForceStatus.NO_CONTACT
    if r < r_knots[0] / 1.01:
        assert forces[0] > lookup.force_n[0]


def test_recovery_follows_its_own_time_constant_by_hand() -> None:
    """a = 0.25, loading tau 2 s, recovery tau 8 s: 4 N held from t = 1 s to 10 s (samples every
    second, from rest), then unloaded. The element charges as 1 - e^(-t/2) and, from z(11) =
    1 - e^-5 = 0.993262 (the interval ending at 11 s still held 4 N), recovers as e^(-(t - 11)/8):
    z(19) = 0.993262 / e = 0.365401. The tracker reads the applied force throughout."""
    a, tau, rec, k = 0.25, 2.0, 8.0, 1e-4
    t = np.arange(0.0, 31.0)
    applied = np.where((t >= 1) & (t <= 10), 4.0, 0.0)
    held = np.concatenate([[0.0], applied[:-1]])
    z = a * kelvin_unit_series(held, np.diff(t, prepend=t[0]), tau, rec, 0.0)
    assert z[11] == pytest.approx(1.0 - math.exp(-5.0), rel=1e-12)
    assert z[19] == pytest.approx((1.0 - math.exp(-5.0)) * math.exp(-1.0), rel=1e-12)
    assert z[19] == pytest.approx(0.365401, abs=1e-6)
    x = applied + z
    with np.errstate(divide="ignore"):
        r = 1.0 / (k * x)
    ch = CurveChannel(
        PowerLawCurve(k, 1.0), Drift(creep_fraction=a, creep_tau_s=tau, creep_recovery_tau_s=rec)
    )
    force, static = track_series(ch, r, t, from_rest=True)
    np.testing.assert_allclose(force, applied, atol=1e-12)
    assert static[19] == pytest.approx(0.365401, abs=1e-6)  # a static curve reads the recovery
    # a symmetric element (recovery = loading) would have recovered 4 x faster: it misreads
    sym = CurveChannel(PowerLawCurve(k, 1.0), Drift(creep_fraction=a, creep_tau_s=tau))
    sym_force, _ = track_series(sym, r, t, from_rest=True)
    # (its own element recovers by t = 19 s to z(11) e^-4 = 0.0182 of the sensor's 0.3654: the
    # rest reads as a load that is not there, fed back through the held force)
    assert sym_force[19] > 0.2 and np.all(sym_force[12:] > 0.0)


def test_a_record_that_starts_loaded_reads_its_load_from_the_first_sample() -> None:
    """A sensor held at 4 N long enough to settle (a = 0.2): it reads x = 4.8 N throughout.
    From the equilibrium at the first load the tracker reads 4 N from the first sample; from
    rest it would read 4.8 N first and fall to 4 N with tau."""
    a, tau, k = 0.2, 5.0, 1e-4
    t = np.arange(0.0, 30.0, 0.5)
    r = np.full(t.size, 1.0 / (k * 4.8))
    ch = CurveChannel(PowerLawCurve(k, 1.0), Drift(creep_fraction=a, creep_tau_s=tau))
    force, _ = track_series(ch, r, t)
    np.testing.assert_allclose(force, 4.0, rtol=1e-12)
    from_rest, _ = track_series(ch, r, t, from_rest=True)
    assert from_rest[0] == pytest.approx(4.8, rel=1e-12) and from_rest[-1] < 4.01
    cset = CurveSet([ch])
    state = cset.initial_state()
    for k_row in range(t.size):
        f, _, _, _, state = cset.track(r[k_row : k_row + 1], state, 0.5 if k_row else 0.0)
        assert f[0] == pytest.approx(4.0, rel=1e-12)


def _sensor_with_sensitivity(
    applied: np.ndarray, t: np.ndarray, c: float, tau: float, rec: float
) -> tuple[np.ndarray, np.ndarray]:
    """A plain loop of the forward model from rest: u -> c x_prev (loading tau while c x_prev
    lies beyond u in c's direction, else rec), x = F exp(u). Returns (x, u)."""
    u, x_prev, xs, us = 0.0, 0.0, [], []
    for k in range(t.size):
        if k:
            target = c * x_prev
            tau_k = tau if (target - u) * c > 0 else rec
            u = target + (u - target) * math.exp(-(t[k] - t[k - 1]) / tau_k)
        x = applied[k] * math.exp(u)
        xs.append(x)
        us.append(u)
        x_prev = x
    return np.array(xs), np.array(us)


def test_the_sensitivity_element_reads_a_low_load_after_a_high_one() -> None:
    """c = -0.02 /N, loading tau 2 s, recovery tau 10 s (the real FSR's shape: its sensitivity
    falls under a held high load and recovers at a low one). 25 N held for 20 s from rest, then
    3.3 N: the sensor reads the 3.3 N hold about 40 % low at first and recovers towards it
    with 10 s; the tracker reads the applied force throughout, also above 1 / (e |c|) = 18 N
    (an element driven by the estimate would run away there); an additive Kelvin element that
    reads the high hold the same reads the low one several newtons high."""
    c, tau, rec, k = -0.02, 2.0, 10.0, 1e-4
    t = np.arange(0.0, 60.0, 1.0)
    applied = np.where(t < 1, 0.0, np.where(t <= 20, 25.0, 3.3))
    x, u = _sensor_with_sensitivity(applied, t, c, tau, rec)
    # at the end of the high hold u settles where u = c x = c 25 exp(u): about -0.34
    assert u[20] == pytest.approx(c * x[19], rel=1e-3)
    assert 0.55 < x[21] / 3.3 < 0.75 and x[31] > x[21] and x[-1] / 3.3 > 0.9
    with np.errstate(divide="ignore"):
        r = 1.0 / (k * x)
    drift = Drift(sensitivity_per_n=c, sensitivity_tau_s=tau, sensitivity_recovery_tau_s=rec)
    ch = CurveChannel(PowerLawCurve(k, 1.0), drift)
    assert ch.drift.form == "sensitivity" and ch.drift.n_parameters == 3
    force, static = track_series(ch, r, t, from_rest=True)
    np.testing.assert_allclose(force, applied, rtol=1e-12, atol=1e-12)
    assert static[21] == pytest.approx(x[21], rel=1e-12)
    cset = CurveSet([ch])
    state = cset.rested_state()
    for i in range(t.size):
        f, _, _, _, state = cset.track(r[i : i + 1], state, 1.0 if i else 0.0)
        assert f[0] == pytest.approx(applied[i], rel=1e-12, abs=1e-12)
    # the additive element that reads the end of the high hold the same: a = x(20) / 25 - 1
    a = float(x[20] / 25.0 - 1.0)
    additive = CurveChannel(PowerLawCurve(k, 1.0), Drift(creep_fraction=a, creep_tau_s=tau))
    wrong, _ = track_series(additive, r, t, from_rest=True)
    assert wrong[21] - 3.3 > 3.0


def test_a_sensor_that_starts_loaded_with_a_sensitivity_element_reads_its_load() -> None:
    """Settled at 20 N with c = -0.01 /N: x = 20 exp(c x) (x = 16.97 N) throughout; the
    equilibrium start F = x / exp(c x) reads 20 N from the first sample."""
    ch = CurveChannel(PowerLawCurve(1e-4, 1.0), Drift(sensitivity_per_n=-0.01, sensitivity_tau_s=3.0))
    x = 20.0
    for _ in range(200):
        x = 20.0 * math.exp(-0.01 * x)
    t = np.arange(0.0, 10.0, 0.1)
    force, _ = track_series(ch, np.full(t.size, 1.0 / (1e-4 * x)), t)
    np.testing.assert_allclose(force, 20.0, rtol=1e-9)
