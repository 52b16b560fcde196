"""The text exposition of a snapshot, written directly from the table of families
(``families.FAMILIES``): byte for byte what ``prometheus_client.generate_latest`` makes of
``SnapshotCollector`` (which builds its families from the same table), several times faster.

A gateway of 32 arrays of 64 channels exposes about 27,700 series. Building a metric family
object per scrape and formatting every sample through ``generate_latest`` (label sorting and
escaping per sample) takes a few hundred milliseconds; here each family's HELP and TYPE lines
are written once from the table, the part of a line before its value (name and labels, sorted
and escaped) is cached per series, values are formatted as the client library formats them
(``repr`` of the float where that is what ``floatToGoString`` gives), and a device's lines are
kept until its snapshot or counters change. The result is cached per snapshot (by identity),
so scrapes between two polls cost nothing.
``tests/unit/gateway/metrics/test_exposition.py`` checks exact lines for known values and the
bytes against the client library for many snapshots; ``bench_scrape`` measures both.
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable, Iterable
from typing import Final

from prometheus_client import CollectorRegistry, generate_latest
from prometheus_client.metrics_core import Metric
from prometheus_client.registry import Collector
from prometheus_client.utils import floatToGoString

from ..runtime.counters import DeviceCounters
from ..runtime.snapshot import DeviceSnapshot, GatewaySnapshot
from .collector import SnapshotCollector
from .families import FAMILIES, Family

__all__ = ["SnapshotExposition", "SnapshotRegistry", "render"]


def _label(value: str) -> str:
    """A label value escaped as the text format wants it: backslash, newline, double quote."""
    return value.replace("\\", "\\\\").replace("\n", "\\n").replace('"', '\\"')


def _header(family: Family) -> str:
    """The ``# HELP`` and ``# TYPE`` lines of ``family`` (HELP escaped as the client library does)."""
    doc = family.help.replace("\\", r"\\").replace("\n", r"\n")
    return f"# HELP {family.name} {doc}\n# TYPE {family.name} {family.type}\n"


def _g(value: float) -> str:
    """``floatToGoString(value)``: for a float between -1e6 and 1e6 that is its ``repr`` (Go
    switches to exponents from 1e6 up, Python from 1e16; infinities and NaN are spelled
    differently), which costs a third of the general function."""
    if type(value) is float and -1e6 < value < 1e6:
        return repr(value)
    return str(floatToGoString(value))


class _Heads(dict[tuple[str, ...], str]):
    """Per family, the part of each series' line before its value (``name{labels} ``), by label
    values: the labels sorted by name and escaped once per series, not once per scrape (a dict,
    so that a hit costs one lookup in C)."""

    LIMIT: Final = 1 << 18  # series kept per family; beyond, the cache starts over

    def __init__(self, name: str, labels: tuple[str, ...]) -> None:
        super().__init__()
        self._name = name
        self._labels = labels
        self._order = sorted(range(len(labels)), key=labels.__getitem__)

    def __missing__(self, values: tuple[str, ...]) -> str:
        if len(self) >= self.LIMIT:
            self.clear()
        parts = ",".join(f'{self._labels[k]}="{_label(values[k])}"' for k in self._order)
        head = self[values] = f"{self._name}{{{parts}}} " if parts else f"{self._name} "
        return head


_HEADERS: Final = tuple(_header(f) for f in FAMILIES)
_HEADS: Final[tuple[tuple[_Heads, ...], ...]] = tuple(
    (_Heads(f.name + "_bucket", (*f.labels, "le")), _Heads(f.name + "_count", f.labels),
     _Heads(f.name + "_sum", f.labels))
    if f.type == "histogram" else (_Heads(f.name, f.labels),)
    for f in FAMILIES
)  # fmt: skip
#: Per family, its buckets' ``le`` values (+Inf last); empty for the other types.
_LES: Final = tuple(
    tuple("+Inf" if math.isinf(b) else repr(float(b)) for b in (*f.buckets, math.inf))
    if f.type == "histogram"
    else ()
    for f in FAMILIES
)


def _family_lines(k: int, device: str, dev: DeviceSnapshot, counters: DeviceCounters | None) -> str:
    """The lines of family ``FAMILIES[k]`` for one device, joined."""
    family = FAMILIES[k]
    out: list[str] = []
    if family.samples is not None:
        heads = _HEADS[k][0]
        g = _g
        # ``g`` inlined for the common case (its docstring): a call per sample costs a tenth
        out = [
            heads[values] + (repr(value) if type(value) is float and -1e6 < value < 1e6 else g(value)) + "\n"
            for values, value in family.samples(device, dev, counters)
        ]
    elif family.histograms is not None:
        bucket, count, total = _HEADS[k]
        les = _LES[k]
        for values, data in family.histograms(device, dev, counters):
            for le, c in zip(les, data.bucket_counts, strict=True):
                out.append(f"{bucket[(*values, le)]}{_g(float(c))}\n")
            out.append(f"{count[values]}{_g(float(data.bucket_counts[-1]))}\n")
            out.append(f"{total[values]}{_g(data.sum)}\n")
    return "".join(out)


def _device_chunks(name: str, dev: DeviceSnapshot, counters: DeviceCounters | None) -> tuple[str, ...]:
    """One device's lines of each family, joined per family."""
    return tuple(_family_lines(k, name, dev, counters) for k in range(len(FAMILIES)))


def _assemble(snap: GatewaySnapshot, chunks: dict[str, tuple[str, ...]]) -> str:
    names = sorted(snap.devices)
    out: list[str] = []
    for k, header in enumerate(_HEADERS):
        out.append(header)
        out.extend(chunks[name][k] for name in names)
    return "".join(out)


def render(snap: GatewaySnapshot) -> str:
    """The text exposition of ``snap`` (see the module docstring)."""
    chunks = {name: _device_chunks(name, dev, snap.counters.get(name)) for name, dev in snap.devices.items()}
    return _assemble(snap, chunks)


class SnapshotExposition:
    """Renders the snapshot ``source`` returns; caches the bytes of the last snapshot and each
    device's lines (a device whose snapshot and counters did not change since the last scrape
    costs nothing). Between devices it lets other threads run (``time.sleep(0)``), so a scrape
    rendered in a worker thread never holds the interpreter for more than one device's lines
    and the poll loop keeps its schedule."""

    def __init__(self, source: Callable[[], GatewaySnapshot], *, yield_between_devices: bool = True) -> None:
        self._source = source
        self._yield = yield_between_devices
        self._lock = threading.Lock()
        self._cached: tuple[GatewaySnapshot, bytes] | None = None
        self._devices: dict[str, tuple[DeviceSnapshot, DeviceCounters | None, tuple[str, ...]]] = {}

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
            counters = snap.counters.get(name)
            known = self._devices.get(name)
            if known is not None and known[0] is dev and known[1] is counters:
                chunks[name] = known[2]
                continue
            chunks[name] = _device_chunks(name, dev, counters)
            self._devices[name] = (dev, counters, chunks[name])
            if self._yield:
                time.sleep(0)  # let the poll loop's thread take the interpreter between devices
        for gone in set(self._devices) - set(snap.devices):
            del self._devices[gone]
        return _assemble(snap, chunks)


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
