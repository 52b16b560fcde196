"""The poll loop: one asyncio task per bus, publishing immutable snapshots.

Each bus task connects its transport (``gateway.modbus.transport.Transport``: the pymodbus
client in production, an in-process virtual bus in unit tests), then every
``poll_interval_s`` (0: back to back, each cycle as soon as the last one ends) polls each of
its devices that is not backing off: the coalesced reads of ``read_plan``, one
request at a time, each retried up to ``retries`` times on a timeout or a garbled answer.
The registers go through the pure ``processor`` and a new device snapshot is published
after every device poll.

The conversion of a poll (decode, drift-corrected forces, snapshot) is a ``Conversion`` of
three steps. When the bus has more requests to make at once (back-to-back polling, or the
next device of the cycle), each step runs while a device works on the answer to one of
them, so the CPU work hides in time the bus task would spend waiting; before the task
sleeps, whatever is left runs at once. Every poll is converted, in order, exactly once.

Failure handling:

* a device that does not answer is marked stale (last values kept) and is tried again
  after a jittered back-off that grows per failure, so a dead device costs its bus little;
* a lost or refused connection closes the transport and reconnects after
  ``uniform(0, b)`` seconds ("full jitter"), b doubling from ``backoff_initial_s`` to
  ``backoff_max_s``: no busy loop and no synchronized reconnect storm. b starts again from
  ``backoff_initial_s`` only once a poll succeeds, not at a mere connect: a device that takes
  the connection (and the set-up writes) and then drops it is written to ever less often,
  down to once per ``backoff_max_s / 2`` on average. The device whose request lost the
  connection keeps its own wait across the reconnect (``DeviceRunner.dropped``), so the other
  devices of its bus are polled meanwhile, and their successful polls do not cut its wait;
* buses are independent tasks, so nothing on one bus can stall another;
* nothing a device sends can end a bus task: every unexpected error is logged, counted
  as a decode error and the loop goes on.

``reload`` swaps in a new configuration; channels whose device, index, effects and
parameters are unchanged keep their creep state (``DeviceProcessor.carry_state``).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import random
import time
from collections.abc import Awaitable, Callable, Sequence
from dataclasses import dataclass, field

from ..config import BusConfig, DeviceConfig
from ..errors import (
    DecodeError,
    DeviceConnectionError,
    DeviceError,
    DeviceExceptionResponse,
    DeviceMismatchError,
    DeviceTimeoutError,
)
from ..modbus.backends import open_transport
from ..modbus.image import RegisterSpace
from ..modbus.plan import MERGE_GAP, ReadRequest, device_plan
from ..modbus.register_map import MAX_READ_REGISTERS
from ..modbus.transport import Transport
from .conversion import Conversion
from .counters import DeviceCounters, Tally
from .identity import needs_preparing, prepare_device
from .processor import ClockHealth, DeviceProcessor, DeviceState
from .snapshot import DeviceSnapshot

log = logging.getLogger(__name__)

#: Back-to-back cycles between two explicit yields to the event loop (a cycle that reads a
#: device yields while it waits; the yield is for a bus that answers without waiting).
YIELD_EVERY_CYCLES = 16

#: Modbus exception 6 (server device busy) is worth a retry; other exceptions are not.
RETRYABLE_EXCEPTION_CODES = frozenset({6})


def error_reason(exc: BaseException) -> str:
    """The ``reason`` label of a read error."""
    if isinstance(exc, DeviceConnectionError):
        return "connection"
    if isinstance(exc, DeviceTimeoutError):
        return "timeout"
    if isinstance(exc, DeviceExceptionResponse):
        return "exception"
    if isinstance(exc, DeviceMismatchError):
        return "mismatch"
    return "decode"


def _power_of_two(n: int) -> bool:
    """Whether ``n`` is 1, 2, 4, 8...: when a repeated failure is logged again."""
    return n > 0 and n & (n - 1) == 0


@dataclass
class DeviceRunner:
    """Mutable bookkeeping of one device inside its bus task (never shared across threads)."""

    config: DeviceConfig
    processor: DeviceProcessor
    plan: tuple[ReadRequest, ...]  # what one poll reads (see ``device_plan``)
    state: DeviceState
    max_read_registers: int = MAX_READ_REGISTERS
    merge_gap: int = MERGE_GAP  # 0 once the device refused a merged read
    clock: bool = True  # False once the device refused the clock registers
    verified: bool = False  # the device's checks passed on this connection
    tally: Tally = field(default_factory=Tally)
    failures: int = 0
    #: connections lost during this device's own requests since its last successful poll: its
    #: wait survives the reconnect, so it does not take the connection down again at once
    dropped: int = 0
    next_attempt: float = 0.0
    last_error: str | None = None
    pending: Conversion | None = None  # read but not yet converted

    @property
    def counters(self) -> DeviceCounters:
        return self.tally.freeze()


class BusWorker:
    """The poll loop of one bus."""

    def __init__(
        self,
        bus: BusConfig,
        runners: list[DeviceRunner],
        publish: Callable[[DeviceRunner, DeviceSnapshot], None],
        *,
        transport_factory: Callable[[BusConfig], Transport] = open_transport,
        derivations: Callable[[], Sequence[Callable[[DeviceSnapshot], object]]] = tuple,
        rng: random.Random | None = None,
        wall_clock: Callable[[], float] = time.time,
        monotonic: Callable[[], float] = time.monotonic,
    ) -> None:
        self.bus = bus
        #: how the loop waits between cycles and before a reconnect (tests simulate time)
        self.sleep: Callable[[float], Awaitable[None]] = asyncio.sleep
        self.runners = runners
        self._publish = publish
        self._derivations = derivations
        self.transport = transport_factory(bus)
        self._quiet_s = self.transport.quiet_after_send_s
        self._rng = rng or random.Random()
        self._wall = wall_clock
        self._mono = monotonic
        self.task: asyncio.Task[None] | None = None
        self._stopping = False
        self.connect_failures = 0  # connects refused in a row (for the log)
        #: connections refused or lost since the last successful poll: the reconnect back-off
        self.failed_connections = 0

    @property
    def name(self) -> str:
        return self.bus.name

    # ------------------------------------------------------------------ backoff
    def _jitter(self, failures: int) -> float:
        """Full-jitter back-off: uniform(0, min(max, initial * 2^(failures-1))), with a
        floor of a tenth of ``backoff_initial_s`` so it can never spin."""
        initial = float(self.bus.backoff_initial_s)
        return max(0.1 * initial, self._rng.uniform(0.0, self._backoff_cap(failures)))

    def _backoff_cap(self, failures: int) -> float:
        """The upper end of the back-off after ``failures`` failures in a row (s)."""
        initial = float(self.bus.backoff_initial_s)
        return min(float(self.bus.backoff_max_s), initial * 2.0 ** min(max(failures - 1, 0), 30))

    # ------------------------------------------------------------------ requests
    async def _read(self, runner: DeviceRunner, req: ReadRequest) -> list[int]:
        """One request of the read plan with bounded retries (timeouts, garbled answers,
        busy exceptions). Counts every attempt and every failure."""
        attempts = 1 + max(0, int(self.bus.retries))
        dev = runner.config
        last: DeviceError | None = None
        for attempt in range(attempts):
            runner.tally.read()
            try:
                return await self.transport.read(dev.device_id, req)
            except DeviceError as exc:
                runner.tally.error(error_reason(exc))
                last = exc
                if isinstance(exc, DeviceConnectionError):
                    raise
                if (
                    isinstance(exc, DeviceExceptionResponse)
                    and exc.exception_code not in RETRYABLE_EXCEPTION_CODES
                ):
                    raise
                if attempt + 1 < attempts and self.transport.is_serial_framing:
                    # let a late answer to this request arrive and be discarded, so that
                    # it cannot be taken for the answer to the retry (RTU has no ids)
                    await asyncio.sleep(min(0.5 * float(self.bus.timeout_s), 0.2))
        assert last is not None
        raise last

    async def poll_device(self, runner: DeviceRunner) -> bool:
        """Read one device once and queue its registers for conversion; True if the reads
        succeeded.

        The conversion (decode + model) of a poll is deferred: it runs right after the
        next request on this bus has been sent, while the device works on the answer, so
        the CPU work of one poll overlaps the wait for the next (``settle_now`` or the end of
        a poll cycle runs it at once when no request follows). Conversions of one device
        are applied in poll order, each before anything else is published for it.

        Raises ``DeviceConnectionError`` (after publishing a stale snapshot) when the bus
        connection is gone, so that the caller reconnects.
        """
        t0 = time.monotonic()  # for the duration only (scheduling uses self._mono)
        try:
            reads: list[tuple[RegisterSpace, int, list[int]]] = []
            last = len(runner.plan) - 1
            for k, req in enumerate(runner.plan):
                try:
                    if self._has_pending():
                        regs = await self._read_overlapping(runner, req, all_steps=k == last)
                    else:
                        regs = await self._read(runner, req)
                except DeviceExceptionResponse as exc:
                    if exc.exception_code != 2 or not self._fall_back(runner, req):
                        raise
                    return await self.poll_device(runner)
                reads.append((req.kind, req.address, regs))
        except DeviceError as exc:  # already counted per request
            self.settle_now(runner)
            self._fail(runner, exc)
            if isinstance(exc, DeviceConnectionError):
                raise
            return False
        self.settle_now(runner)
        runner.pending = Conversion(
            runner.processor,
            runner.state,
            reads,
            self._wall(),
            self._mono(),
            time.monotonic() - t0,
            derive=self._derivations(),
        )
        return True

    async def _read_overlapping(
        self, runner: DeviceRunner, req: ReadRequest, *, all_steps: bool
    ) -> list[int]:
        """``_read``, with deferred conversion steps run while the device answers: one step
        per request, and on the poll's last request (``all_steps``) every step left, since no
        later request of the poll would overlap them.

        The first step is a timer due when the request is out (at once over a network, after
        the request's own wire time on a serial line); the event loop runs a due timer on its
        next pass, after that pass's I/O callbacks. By then the request has been written:
        the read runs without suspending up to the wait for the answer. Each further step
        follows on the next pass (``call_soon``), so an answer that comes in meanwhile waits
        for one step at most. On a serial line the wait also leaves the CPU to whatever
        carries the bytes (a relay such as socat, in tests) while they go out. Should the
        read suspend earlier, the first step merely runs before the send.
        """
        loop = asyncio.get_running_loop()
        loop.call_at(loop.time() + self._quiet_s, self._step_pending, all_steps)
        return await self._read(runner, req)

    def _has_pending(self) -> bool:
        return any(r.pending is not None for r in self.runners)

    def _step_pending(self, all_steps: bool = False) -> None:
        """One step of the oldest deferred conversion on this bus; with ``all_steps`` the next
        on the event loop's next pass, while any is left."""
        for runner in self.runners:
            if runner.pending is not None:
                self._advance(runner, to_end=False)
                if all_steps and self._has_pending():
                    asyncio.get_running_loop().call_soon(self._step_pending, True)
                return

    def settle_all(self) -> None:
        """Convert and publish every deferred poll of this bus now."""
        for runner in self.runners:
            self.settle_now(runner)

    def settle_now(self, runner: DeviceRunner) -> None:
        """Convert and publish the device's deferred poll (if any) now."""
        self._advance(runner, to_end=True)

    def _advance(self, runner: DeviceRunner, to_end: bool) -> None:
        """Run one step (or all) of the device's deferred conversion; publish it once done.
        Never raises: a failed conversion marks the device, not the bus task."""
        conversion = runner.pending
        if conversion is None:
            return
        try:
            done = conversion.step()
            while to_end and not done:
                done = conversion.step()
        except Exception as exc:  # bad data must never end the loop
            runner.pending = None
            if not isinstance(exc, DeviceError):
                log.error("device %s: conversion failed", runner.config.name, exc_info=exc)
                exc = DecodeError(f"conversion failed: {exc}")
            runner.tally.error("decode")
            self._fail(runner, exc)
            return
        if conversion.result is None:
            return
        runner.pending = None
        before = runner.state.clock
        snap, runner.state = conversion.result
        if runner.state.clock != before:
            self._log_clock(runner, before, runner.state.clock)
        runner.failures = 0
        runner.dropped = 0
        runner.next_attempt = 0.0
        runner.last_error = None
        self.failed_connections = 0
        runner.tally.poll(conversion.duration_s)
        self._publish(runner, snap)

    def _fall_back(self, runner: DeviceRunner, req: ReadRequest) -> bool:
        """After exception 2 (illegal address): drop the clock, then the merging. True if
        the plan changed (and the poll is worth repeating)."""
        name = runner.config.name
        clock = runner.config.registers.clock
        if runner.clock and "device_time" in req.purpose and clock is not None:
            log.warning(
                "device %s: the clock configured at %s registers %d..%d (clock.address) answered exception 2 "
                "(illegal data address); timing creep with the host clock",
                name,
                clock.table,
                clock.address,
                clock.address + clock.registers - 1,
            )
            runner.clock = False
        elif runner.merge_gap > 0 and req.count > 1:
            log.info(
                "device %s refused a merged read of %d registers; reading blocks separately", name, req.count
            )
            runner.merge_gap = 0
        else:
            return False
        runner.plan = device_plan(runner.config, runner.max_read_registers, runner.merge_gap, runner.clock)
        return True

    async def _verify(self, runner: DeviceRunner) -> bool:
        """Run the device's checks once per connection (``identity.verify_device``); True if
        it may be polled. Raises ``DeviceConnectionError`` when the connection is gone."""
        if not needs_preparing(runner.config):
            runner.verified = True
            return True
        runner.tally.read()
        try:
            await prepare_device(self.transport, runner.config)
        except DeviceError as exc:
            runner.tally.error(error_reason(exc))
            self.settle_now(runner)
            self._fail(runner, exc)
            if isinstance(exc, DeviceConnectionError):
                raise
            return False
        runner.verified = True
        return True

    def _log_clock(self, runner: DeviceRunner, before: ClockHealth, after: ClockHealth) -> None:
        """Say once when a device clock misbehaves, and when the host clock takes over."""
        name = runner.config.name
        clock = runner.config.registers.clock
        where = (
            f"{clock.table} registers {clock.address}..{clock.address + clock.registers - 1}" if clock else ""
        )
        if after.fallback is not None and before.fallback is None:
            why = (
                "has not advanced while polls succeed"
                if after.fallback == "stuck"
                else f"went back {after.backwards} times"
            )
            log.warning(
                "device %s: the device clock (%s) %s; timing creep with the host clock from now on "
                '(check clock.address, or set clock = "host")',
                name,
                where,
                why,
            )
        elif after.backwards > before.backwards and before.backwards == 0:
            log.warning(
                "device %s: the device clock (%s) went back (device restart?); one step timed by the host",
                name,
                where,
            )

    def _unprefixed(self, message: str) -> str:
        """``message`` without the ``bus 'NAME': `` the transport's errors start with, for a
        log line that already names the bus."""
        prefix = f"bus {self.name!r}: "
        return message[len(prefix) :] if message.startswith(prefix) else message

    def _fail(self, runner: DeviceRunner, exc: BaseException) -> None:
        runner.failures += 1
        runner.next_attempt = self._mono() + self._jitter(runner.failures)
        message = str(exc)
        if message != runner.last_error:
            log.warning("device %s on bus %s: %s", runner.config.name, self.name, self._unprefixed(message))
        runner.last_error = message
        snap, runner.state = runner.processor.stale(runner.state, self._wall(), message)
        self._publish(runner, snap)

    # ------------------------------------------------------------------ loop
    async def _connect(self) -> bool:
        try:
            await self.transport.connect()
        except DeviceConnectionError as exc:
            self.connect_failures += 1
            self.failed_connections += 1
            for runner in self.runners:
                self.settle_now(runner)
                runner.tally.read()
                runner.tally.error("connection")
                self._fail_quiet(runner, exc)
            if _power_of_two(self.connect_failures):
                log.warning(
                    "bus %s: %s (attempt %d)", self.name, self._unprefixed(str(exc)), self.connect_failures
                )
            return False
        if self.connect_failures:
            log.info("bus %s: reconnected after %d failed attempts", self.name, self.connect_failures)
        elif self.failed_connections == 0:
            log.info("bus %s: connected to %s", self.name, self.transport.target)
        elif _power_of_two(self.failed_connections):
            log.warning(
                "bus %s: connected again, but %d connection(s) in a row were lost before a poll "
                "succeeded; the next reconnect waits up to %g s",
                self.name,
                self.failed_connections,
                self._backoff_cap(self.failed_connections + 1),
            )
        self.connect_failures = 0
        for runner in self.runners:
            if not runner.dropped:
                runner.next_attempt = 0.0
            runner.verified = False
        return True

    def _fail_quiet(self, runner: DeviceRunner, exc: BaseException) -> None:
        runner.failures += 1
        runner.last_error = str(exc)
        snap, runner.state = runner.processor.stale(runner.state, self._wall(), str(exc))
        self._publish(runner, snap)

    async def poll_cycle(self, *, settle: bool = True) -> None:
        """Poll every device that is due once (connecting first if needed). With ``settle``
        the last conversions run before returning; without, they wait to overlap the first
        request of the next cycle (back-to-back polling)."""
        try:
            if not self.transport.connected and not await self._connect():
                return
            for runner in self.runners:
                if self._mono() < runner.next_attempt:
                    continue
                try:
                    if not runner.verified and not await self._verify(runner):
                        continue
                    await self.poll_device(runner)
                except DeviceConnectionError:
                    self.failed_connections += 1
                    runner.dropped += 1
                    runner.next_attempt = self._mono() + self._jitter(runner.dropped)
                    await self.transport.close()
                    return
        finally:
            if settle:
                self.settle_all()

    async def run(self) -> None:
        """Poll forever (until cancelled)."""
        interval = float(self.bus.poll_interval_s)
        next_cycle = self._mono()
        back_to_back = 0
        while not self._stopping:
            try:
                # a cycle due at once (the bus is busy back to back) overlaps the previous
                # cycle's last conversions with its first request
                await self.poll_cycle(settle=False)
            except asyncio.CancelledError:
                self.settle_all()
                raise
            except Exception:  # the loop must survive anything
                log.exception("bus %s: unexpected error in the poll cycle", self.name)
                self.failed_connections += 1
                with contextlib.suppress(Exception):
                    await self.transport.close()
            now = self._mono()
            if not self.transport.connected:
                delay = self._jitter(self.failed_connections or 1)
                next_cycle = now + delay
            else:
                next_cycle += interval
                if next_cycle < now:  # overran: start again from now, no catch-up burst
                    next_cycle = now
                # every device backing off: nothing to poll before the first is due (with
                # poll_interval_s = 0 the loop would otherwise spin)
                next_cycle = max(next_cycle, self._first_due())
            if next_cycle > now:
                self.settle_all()
                # the conversions just run took time of their own: wake at next_cycle, not
                # that much after it (which would make every cycle late by its conversions)
                await self.sleep(max(0.0, next_cycle - self._mono()))
                back_to_back = 0
            else:
                # a cycle that waited on a device has let the loop run; one that never waited
                # (an in-process bus) must still let it run now and then
                back_to_back += 1
                if back_to_back >= YIELD_EVERY_CYCLES:
                    back_to_back = 0
                    await asyncio.sleep(0)

    def _first_due(self) -> float:
        """When the first device of the bus may be polled again (its back-off; monotonic s)."""
        return min((r.next_attempt for r in self.runners), default=0.0)

    def start(self) -> None:
        self._stopping = False
        self.task = asyncio.create_task(self.run(), name=f"tactile-bus-{self.name}")

    async def stop(self) -> None:
        """End the task and close the transport. Cancels until the task is done: on Python
        3.11 ``asyncio.wait_for`` (used inside pymodbus) can swallow a cancellation that
        races with a response, so one ``cancel()`` is not always enough; the stop flag
        ends the loop in that case too."""
        self._stopping = True
        task, self.task = self.task, None
        while task is not None and not task.done():
            task.cancel()
            await asyncio.wait({task}, timeout=1.0)
        if task is not None and not task.cancelled() and task.exception() is not None:
            log.error("bus %s: poll task failed", self.name, exc_info=task.exception())
        await self.close()

    async def close(self) -> None:
        """Convert the deferred polls, close the transport."""
        self.settle_all()
        await self.transport.close()
