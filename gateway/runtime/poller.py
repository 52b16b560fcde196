"""The poller: every bus of a configuration, and the snapshot it publishes.

A ``Poller`` runs one ``bus.BusWorker`` task per bus, gathers the device snapshots the
workers produce into one ``GatewaySnapshot`` (a new one after every device poll) and hands it
to a ``SnapshotHolder``, which the exporter, the recorder and the terminal view read from
any thread. ``reload`` swaps in a new configuration: channels whose device, index, effects
and parameters are unchanged keep their creep state (``DeviceProcessor.carry_state``), and
what was learnt about a device (no clock, no merged reads) carries over. ``poll_once``
polls every device once, for ``tactile-gateway poll-once``.
"""

from __future__ import annotations

import asyncio
import logging
import random
import threading
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, replace

from ..config import BusConfig, GatewayConfig
from ..modbus.backends import open_transport
from ..modbus.plan import MERGE_GAP, device_plan
from ..modbus.transport import Transport
from .bus import BusWorker, DeviceRunner
from .counters import DeviceCounters, Tally
from .processor import DeviceProcessor
from .snapshot import DeviceSnapshot, GatewaySnapshot

log = logging.getLogger(__name__)


#: What a subscriber derives from every device snapshot (a module-level function).
Derivation = Callable[[DeviceSnapshot], object]


class SnapshotHolder:
    """Holds the latest ``GatewaySnapshot``; safe to read from any thread (the exporter's).

    ``subscribe`` registers a callback run (in the poller's thread) after each publish; a
    subscriber that derives something from every device snapshot (the page's stream and MQTT
    publish each poll's ``Frame`` and its encodings) names those functions in ``derive``, and
    the poll loop computes them (``DeviceSnapshot.derived``, once per snapshot) while it waits
    for the next answer, instead of the subscriber's thread computing them while the poll
    loop needs the CPU.
    """

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._snapshot = GatewaySnapshot()
        self._callbacks: list[Callable[[GatewaySnapshot], None]] = []
        self._derive: list[Callable[[], Sequence[Derivation]]] = []

    def get(self) -> GatewaySnapshot:
        with self._lock:
            return self._snapshot

    def publish(self, snapshot: GatewaySnapshot) -> None:
        with self._lock:
            self._snapshot = snapshot
            callbacks = list(self._callbacks)
        for cb in callbacks:
            try:
                cb(snapshot)
            except Exception:
                log.exception("snapshot subscriber failed")

    def subscribe(
        self,
        callback: Callable[[GatewaySnapshot], None],
        *,
        derive: Sequence[Derivation] = (),
        derive_now: Callable[[], Sequence[Derivation]] | None = None,
    ) -> None:
        """Run ``callback`` after each publish. ``derive``: the functions the subscriber
        applies to every device snapshot (``DeviceSnapshot.derived``); or ``derive_now``, asked
        at each poll which they are now (a publisher whose settings can change)."""
        if callable(derive) or isinstance(derive, str):
            raise TypeError("derive: a sequence of functions (one function: derive=(fn,))")
        fixed = tuple(derive)
        source = derive_now if derive_now is not None else (lambda: fixed)
        with self._lock:
            self._callbacks.append(callback)
            self._derive.append(source)

    @property
    def derivations(self) -> tuple[Derivation, ...]:
        """What the subscribers derive from every device snapshot now (module-level
        functions, each once)."""
        out: list[Derivation] = []
        for source in self._derive:
            out.extend(fn for fn in source() if fn not in out)
        return tuple(out)


@dataclass(frozen=True)
class ReloadReport:
    """What a reload changed."""

    devices_added: tuple[str, ...]
    devices_removed: tuple[str, ...]
    channels_kept: int
    channels_reset: int


class Poller:
    """All buses of a ``GatewayConfig``: start, reload, stop, and a single-shot poll."""

    def __init__(
        self,
        config: GatewayConfig,
        holder: SnapshotHolder | None = None,
        *,
        transport_factory: Callable[[BusConfig], Transport] = open_transport,
        rng: random.Random | None = None,
        wall_clock: Callable[[], float] = time.time,
        monotonic: Callable[[], float] = time.monotonic,
    ) -> None:
        self.config = config
        self.holder = holder or SnapshotHolder()
        self._transport_factory = transport_factory
        self._rng = rng or random.Random()
        self._wall = wall_clock
        self._mono = monotonic
        self._devices: dict[str, DeviceSnapshot] = {}
        self._counters: dict[str, DeviceCounters] = {}
        self._sequence = 0
        self.workers: list[BusWorker] = self._build(config, {})
        self.running = False

    # ------------------------------------------------------------------ building
    def _build(self, config: GatewayConfig, old: dict[str, DeviceRunner]) -> list[BusWorker]:
        workers = []
        for bus in config.buses:
            runners = []
            for dev in bus.devices:
                processor = DeviceProcessor(dev, bus.name, bus.poll_interval_s)
                previous = old.get(dev.name)
                if previous is None:
                    state, tally = processor.initial_state(), Tally()
                else:
                    state = processor.carry_state(previous.processor, previous.state)
                    tally = previous.tally
                # what was learnt about the device (no clock, no merged reads) carries over
                gap = MERGE_GAP if previous is None else previous.merge_gap
                clock = True if previous is None else previous.clock
                plan = device_plan(dev, bus.max_read_registers, gap, clock)
                runners.append(
                    DeviceRunner(
                        dev,
                        processor,
                        plan,
                        state,
                        tally=tally,
                        max_read_registers=bus.max_read_registers,
                        merge_gap=gap,
                        clock=clock,
                    )
                )
            workers.append(
                BusWorker(
                    bus,
                    runners,
                    self._on_device_snapshot,
                    transport_factory=self._transport_factory,
                    derivations=lambda: self.holder.derivations,
                    rng=self._rng,
                    wall_clock=self._wall,
                    monotonic=self._mono,
                )
            )
        return workers

    def runners(self) -> Iterable[DeviceRunner]:
        for w in self.workers:
            yield from w.runners

    def _on_device_snapshot(self, runner: DeviceRunner, snap: DeviceSnapshot) -> None:
        self._devices[runner.config.name] = snap
        self._counters[runner.config.name] = runner.counters
        self._publish_all()

    def _publish_all(self) -> None:
        self._sequence += 1
        self.holder.publish(GatewaySnapshot.build(self._devices, self._counters, self._sequence))

    def _seed_snapshots(self) -> None:
        """Before the first poll every device is listed as stale, marked ``polled=False``: a
        placeholder, not an observation (the stream and MQTT do not publish it)."""
        names = {r.config.name for r in self.runners()}
        for name in list(self._devices):
            if name not in names:
                del self._devices[name]
                self._counters.pop(name, None)
        for runner in self.runners():
            if runner.config.name not in self._devices:
                snap, runner.state = runner.processor.stale(runner.state, self._wall(), "not polled yet")
                self._devices[runner.config.name] = replace(snap, polled=False)
            elif runner.state.last is None:
                snap, _ = runner.processor.stale(runner.state, self._wall(), "not polled yet")
                self._devices[runner.config.name] = replace(snap, polled=False)
            else:
                # the last values stand until the next poll, but what the configuration says
                # (interval, bus) is the new configuration's from the moment it is in force
                self._devices[runner.config.name] = replace(
                    self._devices[runner.config.name],
                    poll_interval_s=runner.processor.poll_interval_s,
                    bus=runner.processor.bus,
                )
            self._counters[runner.config.name] = runner.counters
        self._publish_all()

    # ------------------------------------------------------------------ lifecycle
    async def start(self) -> None:
        """Start one task per bus."""
        if self.running:
            return
        self._seed_snapshots()
        for w in self.workers:
            w.start()
        self.running = True

    async def stop(self) -> None:
        """Cancel the bus tasks and close every transport (idempotent)."""
        self.running = False
        await asyncio.gather(*(w.stop() for w in self.workers), return_exceptions=True)

    async def __aenter__(self) -> Poller:
        await self.start()
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.stop()

    async def reload(self, config: GatewayConfig) -> ReloadReport:
        """Replace the configuration. Channels whose physics is unchanged keep their creep
        state; counters of devices that stay are kept. Buses reconnect."""
        was_running = self.running
        await self.stop()
        old = {r.config.name: r for r in self.runners()}
        workers = self._build(config, old)
        new_runners = {r.config.name: r for w in workers for r in w.runners}
        kept = reset = 0
        for name, runner in new_runners.items():
            n = len(runner.processor.channels)
            k = runner.processor.kept_channels(old[name].processor) if name in old else 0
            kept += k
            reset += n - k
        report = ReloadReport(
            devices_added=tuple(sorted(set(new_runners) - set(old))),
            devices_removed=tuple(sorted(set(old) - set(new_runners))),
            channels_kept=kept,
            channels_reset=reset,
        )
        self.config = config
        self.workers = workers
        self._seed_snapshots()
        if was_running:
            for w in self.workers:
                w.start()
            self.running = True
        log.info(
            "configuration reloaded: %d channels keep their creep state, %d start relaxed; "
            "devices added %s, removed %s",
            kept,
            reset,
            list(report.devices_added),
            list(report.devices_removed),
        )
        return report

    async def poll_once(self) -> GatewaySnapshot:
        """Connect every bus, poll each device once (with retries), close; buses in parallel."""
        self._seed_snapshots()

        async def one(worker: BusWorker) -> None:
            try:
                await worker.poll_cycle()
            finally:
                await worker.close()

        await asyncio.gather(*(one(w) for w in self.workers))
        return self.holder.get()

    def snapshot(self) -> GatewaySnapshot:
        return self.holder.get()
