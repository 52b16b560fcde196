"""One poll's registers on their way to a snapshot, in steps the bus task runs while a device
works on the next answer (see ``bus``)."""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import replace

from ..modbus.image import RegisterImage, RegisterSpace, decode_sample
from ..modbus.status_word import read_status_words
from .processor import DeviceProcessor, DeviceState
from .snapshot import DeviceSnapshot

__all__ = ["Conversion"]

log = logging.getLogger(__name__)


class Conversion:
    """One poll's registers on their way to a snapshot, in three steps: decode, track
    (resistances and drift-corrected forces), finish (statuses, array quantities, the
    snapshot), and with ``derive`` a fourth: what the poller's subscribers derive from every
    snapshot (its published ``Frame``, its encodings), computed once
    (``DeviceSnapshot.derived``). The poller runs one step at a time while a device works on
    an answer.

    ``wall_time_s`` (Unix) and ``host_time_s`` (monotonic) are taken when the reads end, so
    that the result does not depend on when the steps run. ``state`` is the device state
    the conversion starts from: conversions of one device run one after the other.
    """

    def __init__(
        self,
        processor: DeviceProcessor,
        state: DeviceState,
        reads: list[tuple[RegisterSpace, int, list[int]]],
        wall_time_s: float,
        host_time_s: float,
        reads_duration_s: float,
        *,
        derive: Sequence[Callable[[DeviceSnapshot], object]] = (),
    ) -> None:
        self._steps = self._run(processor, state, reads, wall_time_s, host_time_s, derive)
        self.result: tuple[DeviceSnapshot, DeviceState] | None = None
        self.duration_s = reads_duration_s  # reads, plus the time spent in each step

    @staticmethod
    def _run(
        processor: DeviceProcessor,
        state: DeviceState,
        reads: list[tuple[RegisterSpace, int, list[int]]],
        wall_time_s: float,
        host_time_s: float,
        derive: Sequence[Callable[[DeviceSnapshot], object]],
    ) -> Iterator[tuple[DeviceSnapshot, DeviceState] | None]:
        image = RegisterImage.from_reads(reads)
        raw = decode_sample(processor.device, image)
        yield None
        tracked = processor.track(state, raw, wall_time_s, host_time_s)
        yield None
        result = processor.finish(tracked)
        if processor.device.status_words:  # the device's named status words, with its forces
            words = read_status_words(processor.device.status_words, image)
            result = (replace(result[0], status_words=words), result[1])
        if derive:
            yield None
            for fn in derive:
                try:
                    result[0].derived(fn)
                except Exception as exc:  # the subscriber's own thread meets it again and reports it
                    log.debug("%s of a snapshot of %s failed: %s", fn.__name__, processor.device.name, exc)
        yield result

    def step(self) -> bool:
        """Run the next step; True once the result is there. Raises what a step raises."""
        if self.result is None:
            t0 = time.monotonic()
            try:
                self.result = next(self._steps)
            finally:
                self.duration_s += time.monotonic() - t0
        return self.result is not None
