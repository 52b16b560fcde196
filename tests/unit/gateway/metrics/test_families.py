"""The table of metric families against numbers: a hand-built snapshot with known values (two
devices, one stale and never polled; a channel whose force is NaN) and the exact lines the
exposition writes for it, HELP and TYPE included. Both writers read the same table, so these
tests, not the comparison of the two, are what catch a wrong value."""

from __future__ import annotations

import math
import shutil
import subprocess
from pathlib import Path

import numpy as np
from hypothesis import given
from hypothesis import strategies as st
from prometheus_client import CollectorRegistry, generate_latest
from prometheus_client.utils import floatToGoString

from gateway.metrics.collector import make_registry
from gateway.metrics.exposition import _g, render
from gateway.metrics.families import FAMILIES
from gateway.runtime.counters import Tally
from gateway.runtime.snapshot import ChannelStatus, DeviceSnapshot, GatewaySnapshot

NAN = math.nan


def _device(name: str, **values: object) -> DeviceSnapshot:
    n = len(values["channel_names"])  # type: ignore[arg-type]
    fields: dict[str, object] = {
        "device": name,
        "bus": "bus0",
        "channel_index": np.arange(n, dtype=np.int64),
        "static_estimate": None,  # no static inversion: tactile_force_static_newtons is absent
        "reference_force_n": np.full(n, NAN),
        "timestamp_s": 1_700_000_000.5,
        "device_time_s": None,
    }
    fields.update(values)
    return DeviceSnapshot(**fields)  # type: ignore[arg-type]


def _known() -> GatewaySnapshot:
    """``left``: 3 channels, ch00 pressed (1.5 N), ch01 an invalid value (NaN force: status
    error), ch02 at rest; ``right``: 2 channels, stale, never polled, no counters."""
    left = _device(
        "left",
        channel_names=("ch00", "ch01", "ch02"),
        x_mm=np.array([1.0, 3.5, 1.0]),
        y_mm=np.array([2.0, 2.0, 4.5]),
        resistance_ohm=np.array([2000.0, NAN, 150000.0]),
        force_n=np.array([1.5, NAN, 0.0]),
        reference_force_n=np.array([1.25, NAN, NAN]),
        status=np.array([ChannelStatus.OK, ChannelStatus.ERROR, ChannelStatus.NO_CONTACT], dtype=np.int8),
        up=True,
        last_success_timestamp_s=1_700_000_000.5,
        poll_interval_s=0.05,
        total_force_n=1.5,
        center_of_pressure_mm=(1.0, 2.0),
        channels_in_contact=1,
        contact_area_mm2=6.25,
        clock_faults=(("stuck", 2), ("backwards", 0)),
        clock_fallback="the device clock stalled",
    )
    right = _device(
        "right",
        channel_names=("ch00", "ch01"),
        x_mm=np.array([0.0, 2.5]),
        y_mm=np.array([0.0, 0.0]),
        resistance_ohm=np.full(2, NAN),
        force_n=np.full(2, NAN),
        status=np.full(2, ChannelStatus.STALE, dtype=np.int8),
        up=False,
        last_success_timestamp_s=None,
        poll_interval_s=0.2,
        error="timeout",
    )
    tally = Tally()
    for _ in range(10):
        tally.read()
    tally.error("timeout")
    tally.error("decode")
    tally.poll(0.0625)  # s, bucket 0.1
    tally.poll(0.001953125)  # s, bucket 0.0025
    tally.poll(NAN)  # a poll, not observed
    return GatewaySnapshot.build({"right": right, "left": left}, {"left": tally.freeze()}, 3)


def _block(text: str, name: str) -> list[str]:
    """The lines of family ``name``: its HELP and TYPE lines, then its samples."""
    lines = text.splitlines()
    start = lines.index(next(line for line in lines if line.startswith(f"# HELP {name} ")))
    end = next((k for k in range(start + 1, len(lines)) if lines[k].startswith("# HELP ")), len(lines))
    return lines[start:end]


def _samples(text: str, name: str) -> list[str]:
    return [line for line in _block(text, name) if not line.startswith("#")]


def test_a_gauge_per_channel_leaves_the_absent_values_out() -> None:
    text = render(_known())
    assert _block(text, "tactile_force_newtons") == [
        "# HELP tactile_force_newtons Drift-corrected force on the channel in newtons (N), from the last "
        "poll; absent when the channel has no valid value (open, short, error)",
        "# TYPE tactile_force_newtons gauge",
        'tactile_force_newtons{channel="ch00",device="left"} 1.5',
        'tactile_force_newtons{channel="ch02",device="left"} 0.0',
    ]
    assert _samples(text, "tactile_resistance_ohms") == [
        'tactile_resistance_ohms{channel="ch00",device="left"} 2000.0',
        'tactile_resistance_ohms{channel="ch02",device="left"} 150000.0',
    ]
    assert _samples(text, "tactile_reference_force_newtons") == [
        'tactile_reference_force_newtons{channel="ch00",device="left"} 1.25',
    ]
    assert _samples(text, "tactile_force_static_newtons") == []  # no static inversion: none
    # the stale device keeps its configured positions (labels sorted by name: axis first)
    assert _samples(text, "tactile_channel_position_mm")[-4:] == [
        'tactile_channel_position_mm{axis="x",channel="ch00",device="right"} 0.0',
        'tactile_channel_position_mm{axis="y",channel="ch00",device="right"} 0.0',
        'tactile_channel_position_mm{axis="x",channel="ch01",device="right"} 2.5',
        'tactile_channel_position_mm{axis="y",channel="ch01",device="right"} 0.0',
    ]


def test_the_status_has_one_series_per_status() -> None:
    lines = _samples(render(_known()), "tactile_channel_status")
    assert len(lines) == 5 * len(ChannelStatus)
    assert lines[: len(ChannelStatus)] == [
        f'tactile_channel_status{{channel="ch00",device="left",status="{s.label}"}} '
        + ("1.0" if s is ChannelStatus.OK else "0.0")
        for s in ChannelStatus
    ]
    ones = [line.split("{")[1].split("}")[0] for line in lines if line.endswith(" 1.0")]
    assert ones == [
        'channel="ch00",device="left",status="ok"',
        'channel="ch01",device="left",status="error"',
        'channel="ch02",device="left",status="no_contact"',
        'channel="ch00",device="right",status="stale"',
        'channel="ch01",device="right",status="stale"',
    ]


def test_device_up_and_the_device_gauges() -> None:
    text = render(_known())
    assert _block(text, "tactile_device_up") == [
        "# HELP tactile_device_up 1 if the device answered, 0 if not (dimensionless), from the last poll",
        "# TYPE tactile_device_up gauge",
        'tactile_device_up{device="left"} 1.0',
        'tactile_device_up{device="right"} 0.0',
    ]
    assert _samples(text, "tactile_last_poll_success_timestamp_seconds") == [
        'tactile_last_poll_success_timestamp_seconds{device="left"} 1.7000000005e+09',  # Go's format
    ]
    assert _samples(text, "tactile_poll_interval_seconds") == [
        'tactile_poll_interval_seconds{device="left"} 0.05',
        'tactile_poll_interval_seconds{device="right"} 0.2',
    ]
    assert _samples(text, "tactile_array_center_of_pressure_mm") == [
        'tactile_array_center_of_pressure_mm{axis="x",device="left"} 1.0',
        'tactile_array_center_of_pressure_mm{axis="y",device="left"} 2.0',
    ]
    assert _samples(text, "tactile_array_total_force_newtons") == [
        'tactile_array_total_force_newtons{device="left"} 1.5',
        'tactile_array_total_force_newtons{device="right"} 0.0',
    ]
    assert _samples(text, "tactile_array_contact_area_square_mm")[0].endswith(" 6.25")
    assert _samples(text, "tactile_array_channels_in_contact") == [
        'tactile_array_channels_in_contact{device="left"} 1.0',
        'tactile_array_channels_in_contact{device="right"} 0.0',
    ]
    assert _samples(text, "tactile_device_clock_fallback") == [
        'tactile_device_clock_fallback{device="left"} 1.0',
        'tactile_device_clock_fallback{device="right"} 0.0',
    ]


def test_the_counters() -> None:
    text = render(_known())
    assert _block(text, "tactile_read_errors_total") == [
        "# HELP tactile_read_errors_total Failed Modbus read requests of the device by reason (count), "
        "up to the last poll: timeout, exception, connection, decode, mismatch (the device is not the "
        "configured one)",
        "# TYPE tactile_read_errors_total counter",
        'tactile_read_errors_total{device="left",reason="timeout"} 1.0',
        'tactile_read_errors_total{device="left",reason="exception"} 0.0',
        'tactile_read_errors_total{device="left",reason="connection"} 0.0',
        'tactile_read_errors_total{device="left",reason="decode"} 1.0',
        'tactile_read_errors_total{device="left",reason="mismatch"} 0.0',
    ]
    assert _samples(text, "tactile_reads_total") == ['tactile_reads_total{device="left"} 10.0']
    assert _samples(text, "tactile_device_clock_faults_total") == [
        'tactile_device_clock_faults_total{device="left",kind="stuck"} 2.0',
        'tactile_device_clock_faults_total{device="left",kind="backwards"} 0.0',
    ]


def test_the_histogram_buckets_sum_and_count() -> None:
    counts = {0.001: 0, 0.0025: 1, 0.005: 1, 0.01: 1, 0.025: 1, 0.05: 1, 0.1: 2}
    counts |= {b: 2 for b in (0.25, 0.5, 1.0, 2.5, 5.0, 10.0)}
    assert _block(render(_known()), "tactile_poll_duration_seconds") == [
        "# HELP tactile_poll_duration_seconds Duration in seconds (s) of successful polls of the device "
        "(all reads plus the CPU time of the conversion)",
        "# TYPE tactile_poll_duration_seconds histogram",
        *(
            f'tactile_poll_duration_seconds_bucket{{device="left",le="{b!r}"}} {c}.0'
            for b, c in counts.items()
        ),
        'tactile_poll_duration_seconds_bucket{device="left",le="+Inf"} 2.0',
        'tactile_poll_duration_seconds_count{device="left"} 2.0',
        'tactile_poll_duration_seconds_sum{device="left"} 0.064453125',
    ]


def test_the_table_order_is_the_exposition_s_and_both_writers_agree() -> None:
    snap = _known()
    text = render(snap)
    helps = [line.split()[2] for line in text.splitlines() if line.startswith("# HELP ")]
    assert helps == [f.name for f in FAMILIES]
    assert len(set(helps)) == len(helps)
    assert text.encode() == generate_latest(
        make_registry(lambda: snap, CollectorRegistry(auto_describe=False))
    )


def test_label_values_are_escaped() -> None:
    odd = 'a"b\\c\nd'
    dev = _device(
        odd,
        channel_names=("x,device=y",),
        x_mm=np.array([0.5]),
        y_mm=np.array([0.0]),
        resistance_ohm=np.array([NAN]),
        force_n=np.array([NAN]),
        status=np.array([ChannelStatus.OPEN], dtype=np.int8),
        up=True,
        last_success_timestamp_s=None,
        poll_interval_s=1,  # an int: exported as a float
    )
    snap = GatewaySnapshot.build({odd: dev}, {}, 1)
    text = render(snap)
    assert 'tactile_device_up{device="a\\"b\\\\c\\nd"} 1.0\n' in text
    assert 'tactile_channel_position_mm{axis="x",channel="x,device=y",device="a\\"b\\\\c\\nd"} 0.5\n' in text
    assert 'tactile_poll_interval_seconds{device="a\\"b\\\\c\\nd"} 1.0\n' in text
    assert text.encode() == generate_latest(
        make_registry(lambda: snap, CollectorRegistry(auto_describe=False))
    )


def test_the_histogram_buckets_are_the_counters_own() -> None:
    (family,) = [f for f in FAMILIES if f.type == "histogram"]
    assert family.buckets == Tally().freeze().poll_duration.bounds
    assert all(f.name.endswith("_total") for f in FAMILIES if f.type == "counter")


@given(
    st.floats(allow_nan=True, allow_infinity=True)
    | st.sampled_from([0.0, -0.0, 1e6, -1e6, 999999.9999999999, 1e16, 1.7e9, 5e-324])
)
def test_value_formatting_is_the_client_library_s(value: float) -> None:
    assert _g(value) == floatToGoString(value)


def test_promtool_accepts_the_known_snapshot(tmp_path: Path) -> None:
    promtool = shutil.which("promtool")
    assert promtool is not None, "promtool (Debian prometheus) is installed by the Makefile"
    path = tmp_path / "metrics.txt"
    path.write_text(render(_known()))
    with path.open("rb") as f:
        result = subprocess.run(
            [promtool, "check", "metrics"], stdin=f, capture_output=True, text=True, timeout=60
        )
    assert result.returncode == 0, result.stdout + result.stderr
