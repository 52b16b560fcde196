"""The text exposition of a snapshot, written directly: byte for byte what
``prometheus_client.generate_latest`` makes of ``SnapshotCollector``, several times faster.

A gateway of 32 arrays of 64 channels exposes about 25,500 series. Building a metric family
object per scrape and formatting every sample through ``generate_latest`` (label sorting and
escaping per sample) takes a few hundred milliseconds; here the families' HELP and TYPE lines
come once from the collector itself (an empty snapshot gives every family without samples),
the label part of each device's and channel's lines is built once per device layout and
cached, and values go through the same float formatting as the client library. The result is
cached per snapshot (by identity), so scrapes between two polls cost nothing.
``tests/unit/gateway/metrics/test_exposition.py`` checks the bytes against the client library
for many snapshots; ``bench_scrape`` measures both.
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable, Iterable
from functools import lru_cache
from typing import Final

from prometheus_client import CollectorRegistry, generate_latest
from prometheus_client.metrics_core import Metric
from prometheus_client.registry import Collector
from prometheus_client.utils import floatToGoString

from ..runtime.counters import READ_ERROR_REASONS
from ..runtime.snapshot import STATUS_LABELS, ChannelStatus, DeviceSnapshot, GatewaySnapshot
from .collector import SnapshotCollector

__all__ = ["SnapshotExposition", "SnapshotRegistry", "render"]


def _label(value: str) -> str:
    """A label value escaped as the text format wants it: backslash, newline, double quote."""
    return value.replace("\\", "\\\\").replace("\n", "\\n").replace('"', '\\"')


@lru_cache(maxsize=1)
def _headers() -> dict[str, str]:
    """``# HELP`` and ``# TYPE`` lines of every family, by family name as the collector names it."""
    out: dict[str, str] = {}
    for metric in SnapshotCollector(GatewaySnapshot).collect():
        name = metric.name + "_total" if metric.type == "counter" else metric.name
        doc = metric.documentation.replace("\\", r"\\").replace("\n", r"\n")
        out[metric.name] = f"# HELP {name} {doc}\n# TYPE {name} {metric.type}\n"
    return out


def _g(value: float) -> str:
    return str(floatToGoString(value))


@lru_cache(maxsize=4096)
def _channel_labels(device: str, channels: tuple[str, ...]) -> tuple[tuple[str, ...], ...]:
    """Per channel: the label parts ``channel="..",device=".."`` (sorted names, escaped)."""
    d = _label(device)
    return tuple((f'channel="{_label(c)}",device="{d}"',) for c in channels)


def _finite(x: float | None) -> bool:
    return x is not None and math.isfinite(x)


class SnapshotExposition:
    """Renders the snapshot ``source`` returns; caches the bytes of the last snapshot and each
    device's channel lines (a device whose snapshot did not change since the last scrape costs
    nothing). Between devices it lets other threads run (``time.sleep(0)``), so a scrape
    rendered in a worker thread never holds the interpreter for more than one device's lines
    and the poll loop keeps its schedule."""

    def __init__(self, source: Callable[[], GatewaySnapshot], *, yield_between_devices: bool = True) -> None:
        self._source = source
        self._yield = yield_between_devices
        self._lock = threading.Lock()
        self._cached: tuple[GatewaySnapshot, bytes] | None = None
        self._devices: dict[str, tuple[DeviceSnapshot, tuple[str, ...]]] = {}

    def __call__(self) -> bytes:
        snap = self._source()
        with self._lock:
            cached = self._cached
            if cached is not None and cached[0] is snap:
                return cached[1]
            body = self._render(snap).encode("utf-8")
            self._cached = (snap, body)
        return body

    def _render(self, snap: GatewaySnapshot) -> str:
        chunks: dict[str, tuple[str, ...]] = {}
        for name, dev in snap.devices.items():
            known = self._devices.get(name)
            if known is not None and known[0] is dev:
                chunks[name] = known[1]
                continue
            chunks[name] = _device_chunks(name, dev)
            self._devices[name] = (dev, chunks[name])
            if self._yield:
                time.sleep(0)  # let the poll loop's thread take the interpreter between devices
        for gone in set(self._devices) - set(snap.devices):
            del self._devices[gone]
        return _assemble(snap, chunks)


_CHANNEL_FAMILIES: Final = (
    "tactile_force_newtons",
    "tactile_force_static_newtons",
    "tactile_reference_force_newtons",
    "tactile_resistance_ohms",
    "tactile_channel_status",
    "tactile_channel_position_mm",
)


def _device_chunks(name: str, dev: DeviceSnapshot) -> tuple[str, ...]:
    """One device's lines of each per-channel family, joined."""
    lines: tuple[list[str], ...] = tuple([] for _ in _CHANNEL_FAMILIES)
    _channel_lines(name, dev, *lines)
    return tuple("".join(part) for part in lines)


def _assemble(snap: GatewaySnapshot, chunks: dict[str, tuple[str, ...]]) -> str:
    h = _headers()
    names = sorted(snap.devices)
    out: list[str] = []
    for k, family in enumerate(_CHANNEL_FAMILIES):
        out.append(h[family])
        out.extend(chunks[name][k] for name in names)
    out += _device_lines(snap, names, [snap.devices[n] for n in names], h)
    return "".join(out)


def render(snap: GatewaySnapshot) -> str:
    """The text exposition of ``snap`` (see the module docstring)."""
    return _assemble(snap, {name: _device_chunks(name, dev) for name, dev in snap.devices.items()})


def _channel_lines(
    name: str,
    dev: DeviceSnapshot,
    force: list[str],
    static: list[str],
    reference: list[str],
    resistance: list[str],
    status: list[str],
    position: list[str],
) -> None:
    labels = _channel_labels(name, dev.channel_names)
    f = dev.force_n.tolist()
    fs = dev.force_static_n.tolist()
    ref = dev.reference_force_n.tolist()
    r = dev.resistance_ohm.tolist()
    st = dev.status.tolist()
    x = dev.x_mm.tolist()
    y = dev.y_mm.tolist()
    d = _label(name)
    for k, (lab,) in enumerate(labels):
        if math.isfinite(f[k]):
            force.append(f"tactile_force_newtons{{{lab}}} {_g(f[k])}\n")
        if math.isfinite(fs[k]):
            static.append(f"tactile_force_static_newtons{{{lab}}} {_g(fs[k])}\n")
        if math.isfinite(ref[k]):
            reference.append(f"tactile_reference_force_newtons{{{lab}}} {_g(ref[k])}\n")
        if math.isfinite(r[k]):
            resistance.append(f"tactile_resistance_ohms{{{lab}}} {_g(r[k])}\n")
        current = int(st[k])
        for s in ChannelStatus:
            value = "1.0" if current == int(s) else "0.0"
            status.append(f'tactile_channel_status{{{lab},status="{STATUS_LABELS[int(s)]}"}} {value}\n')
        channel_part = lab.split(",device=")[0]
        position.append(f'tactile_channel_position_mm{{axis="x",{channel_part},device="{d}"}} {_g(x[k])}\n')
        position.append(f'tactile_channel_position_mm{{axis="y",{channel_part},device="{d}"}} {_g(y[k])}\n')


def _device_lines(
    snap: GatewaySnapshot, names: list[str], devices: list[DeviceSnapshot], h: dict[str, str]
) -> list[str]:
    up = [h["tactile_device_up"]]
    last_ok = [h["tactile_last_poll_success_timestamp_seconds"]]
    duration = [h["tactile_poll_duration_seconds"]]
    interval = [h["tactile_poll_interval_seconds"]]
    reads = [h["tactile_reads"]]
    errors = [h["tactile_read_errors"]]
    total = [h["tactile_array_total_force_newtons"]]
    cop = [h["tactile_array_center_of_pressure_mm"]]
    area = [h["tactile_array_contact_area_square_mm"]]
    in_contact = [h["tactile_array_channels_in_contact"]]
    clock_host = [h["tactile_device_clock_fallback"]]
    clock_faults = [h["tactile_device_clock_faults"]]
    for name, dev in zip(names, devices, strict=True):
        d = f'device="{_label(name)}"'
        up.append(f"tactile_device_up{{{d}}} {'1.0' if dev.up else '0.0'}\n")
        last = dev.last_success_timestamp_s
        if last is not None and math.isfinite(last):
            last_ok.append(f"tactile_last_poll_success_timestamp_seconds{{{d}}} {_g(last)}\n")
        interval.append(f"tactile_poll_interval_seconds{{{d}}} {_g(dev.poll_interval_s)}\n")
        total.append(f"tactile_array_total_force_newtons{{{d}}} {_g(dev.total_force_n)}\n")
        if dev.center_of_pressure_mm is not None:
            cx, cy = dev.center_of_pressure_mm
            if math.isfinite(cx) and math.isfinite(cy):
                cop.append(f'tactile_array_center_of_pressure_mm{{axis="x",{d}}} {_g(cx)}\n')
                cop.append(f'tactile_array_center_of_pressure_mm{{axis="y",{d}}} {_g(cy)}\n')
        area.append(f"tactile_array_contact_area_square_mm{{{d}}} {_g(dev.contact_area_mm2)}\n")
        in_contact.append(f"tactile_array_channels_in_contact{{{d}}} {_g(float(dev.channels_in_contact))}\n")
        clock_host.append(
            f"tactile_device_clock_fallback{{{d}}} {'1.0' if dev.clock_fallback is not None else '0.0'}\n"
        )
        for kind, count in dev.clock_faults:
            clock_faults.append(
                f'tactile_device_clock_faults_total{{{d},kind="{_label(kind)}"}} {_g(float(count))}\n'
            )
        counters = snap.counters.get(name)
        if counters is not None:
            reads.append(f"tactile_reads_total{{{d}}} {_g(float(counters.reads_total))}\n")
            for reason in READ_ERROR_REASONS:
                value = float(counters.read_errors_total.get(reason, 0))
                errors.append(f'tactile_read_errors_total{{{d},reason="{reason}"}} {_g(value)}\n')
            hist = counters.poll_duration
            for bound, count in zip((*hist.bounds, math.inf), hist.bucket_counts, strict=True):
                le = "+Inf" if math.isinf(bound) else repr(float(bound))
                duration.append(f'tactile_poll_duration_seconds_bucket{{{d},le="{le}"}} {_g(float(count))}\n')
            duration.append(
                f"tactile_poll_duration_seconds_count{{{d}}} {_g(float(hist.bucket_counts[-1]))}\n"
            )
            duration.append(f"tactile_poll_duration_seconds_sum{{{d}}} {_g(hist.sum)}\n")
    return [
        *up, *last_ok, *duration, *interval, *reads, *errors, *total, *cop, *area, *in_contact,
        *clock_host, *clock_faults,
    ]  # fmt: skip


class SnapshotRegistry(CollectorRegistry):
    """A registry holding the snapshot collector (for anything that walks collectors) whose
    ``render`` writes the snapshot's families directly (``SnapshotExposition``) and the other
    collectors registered into it (e.g. MQTT counters) through the client library."""

    def __init__(self, source: Callable[[], GatewaySnapshot]) -> None:
        super().__init__(auto_describe=False)
        self._snapshot_collector = SnapshotCollector(source)
        self.register(self._snapshot_collector)
        self._exposition = SnapshotExposition(source)
        self._others: list[Collector] = []

    def register(self, collector: Collector) -> None:
        super().register(collector)
        if collector is not getattr(self, "_snapshot_collector", None):
            self._others.append(collector)

    def unregister(self, collector: Collector) -> None:
        super().unregister(collector)
        if collector in self._others:
            self._others.remove(collector)

    def render(self) -> bytes:
        """The whole exposition: the snapshot's families, then the other collectors'."""
        body = self._exposition()
        if not self._others:
            return body
        return body + generate_latest(_Collectors(tuple(self._others)))


class _Collectors:
    """Just enough of a registry for ``generate_latest``: the families of some collectors."""

    def __init__(self, collectors: tuple[Collector, ...]) -> None:
        self._collectors = collectors

    def collect(self) -> Iterable[Metric]:
        for collector in self._collectors:
            yield from collector.collect()
