"""The 1,062-taxel hand (profile ``dexhand-1062``): conversion time of one poll.

One poll's registers (17 regions, every taxel moving, a few at special codes, a few frozen)
are decoded and converted as the poller does (``decode_sample`` + ``DeviceProcessor.process``:
special codes, the dead-taxel tracker, statuses, totals), back to back for
``BENCH_SECONDS`` (default 5) seconds; goal <= 1 ms per poll. The dead-taxel tracker's step
alone and the decoding are timed too. The profile's channels are uncalibrated (a ``ratio``
front end): no model runs for them (their force would be thrown away).
"""

from __future__ import annotations

import os
import time

import numpy as np

from gateway.config import DeviceConfig, parse_config
from gateway.modbus.image import RegisterImage, decode_sample
from gateway.runtime.dead_taxels import DeadTaxelTracker, tracker_for
from gateway.runtime.processor import DeviceProcessor

SECONDS = float(os.environ.get("BENCH_SECONDS", "5"))
GOAL_US = 1000.0
HAND = """
[[bus]]
name = "hand"
kind = "tcp"
host = "127.0.0.1"
port = 6000

[[bus.device]]
name = "hand"
device_id = 1
profile = "dexhand-1062"
"""
#: The same hand read through a known circuit (the simulator's: raw = 65535 x 1 kohm / r), so the
#: paper's model with drift correction (creep) runs for every taxel.
HAND_DRIFT = (
    HAND
    + """
[bus.device.front_end]
kind = "transimpedance"
bias_v = 1.0
feedback_ohm = 1000.0
adc_bits = 16
adc_reference_v = 1.0
"""
)


def _images(n: int, first: int, count: int = 64) -> list[RegisterImage]:
    """``count`` polls of the hand's registers: a random walk in 100..30000, taxel 7 frozen,
    taxel 20 at a special code."""
    rng = np.random.default_rng(1)
    values = rng.integers(100, 30000, size=n).astype(np.int64)
    out = []
    for _ in range(count):
        values = np.clip(values + rng.integers(-50, 51, size=n), 100, 30000)
        regs = values.astype(np.uint16)
        regs[7] = 1234
        regs[20] = 65535
        out.append(RegisterImage.from_reads([("holding", first, regs)]))
    return out


def _per_poll_us(step: object, n_images: int) -> float:
    assert callable(step)
    polls = 0
    start = time.perf_counter()
    while time.perf_counter() - start < SECONDS:
        step(polls % n_images)
        polls += 1
    return 1e6 * (time.perf_counter() - start) / polls


def _poll_us(config: str) -> tuple[float, DeviceConfig, DeviceProcessor, list[RegisterImage]]:
    """The time of one poll (decode + ``process``, us) of the hand ``config`` describes, with
    the device, its processor and the polled images."""
    device = parse_config(config).buses[0].devices[0]
    images = _images(device.n_channels, device.regions[0].address)
    processor = DeviceProcessor(device, "hand", 1.0 / 30.0)
    state = [processor.initial_state()]
    clock = [100.0]

    def step(k: int) -> None:
        clock[0] += 1.0 / 30.0
        raw = decode_sample(device, images[k])
        _, state[0] = processor.process(state[0], raw, 1.7e9 + clock[0], clock[0])

    return _per_poll_us(step, len(images)), device, processor, images


def _verdict(us: float) -> str:
    return (
        f"{us:8.1f} us/poll (goal <= {GOAL_US:.0f} us: {'ok' if us <= GOAL_US else 'SLOWER than the goal'})"
    )


def bench_drift_corrected() -> None:
    us, _, _, _ = _poll_us(HAND_DRIFT)
    print(
        "  the same poll read in ohm with drift correction (the model with creep on every taxel): "
        + _verdict(us)
    )


def bench_conversion() -> None:
    us, device, processor, images = _poll_us(HAND)
    clock = [100.0]
    print(
        f"  one {device.n_channels}-channel poll ({len(device.regions)} regions), decode + conversion + "
        f"special codes + dead taxels: {_verdict(us)}"
    )
    decode_us = _per_poll_us(lambda k: decode_sample(device, images[k]), len(images))
    print(f"  of which decoding the 17 blocks and their special codes: {decode_us:8.1f} us/poll")
    tracker = tracker_for(device, processor.index)
    assert isinstance(tracker, DeadTaxelTracker)
    values = [np.asarray(decode_sample(device, im).counts, dtype=np.float64) for im in images]
    dead_state = [tracker.initial_state(device.n_channels)]

    def track(k: int) -> None:
        clock[0] += 1.0 / 30.0
        dead_state[0], _ = tracker.update(dead_state[0], values[k], clock[0])

    print(f"  the dead-taxel tracker's step alone: {_per_poll_us(track, len(values)):8.1f} us/poll")


def main() -> None:
    bench_conversion()
    bench_drift_corrected()


if __name__ == "__main__":
    main()
