"""The tracking inversion's work per sample: the channels not solved (no contact, saturated,
invalid) stand in at a range end, where under the creep state's strain their root may lie just
outside the bracket; they must not keep the solved ones iterating. On the 1,062-taxel hand read
in ohm (the simulator's circuit) with drift correction, every poll took the bracketed Newton's
60 sweeps (64 evaluations a poll); now the plain steps from the previous force suffice."""

from __future__ import annotations

import numpy as np
import pytest

from gateway.config import parse_config
from gateway.modbus.image import RegisterImage, decode_sample
from gateway.model.evaluator import ResistanceEvaluator
from gateway.runtime.processor import DeviceProcessor

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
[bus.device.front_end]
kind = "transimpedance"
bias_v = 1.0
feedback_ohm = 1000.0
adc_bits = 16
adc_reference_v = 1.0
"""


def test_a_poll_of_the_hand_takes_a_few_newton_steps(monkeypatch: pytest.MonkeyPatch) -> None:
    device = parse_config(HAND).buses[0].devices[0]
    first = device.regions[0].address
    rng = np.random.default_rng(1)
    values = rng.integers(0, 30000, size=device.n_channels)
    values[:100] = 0  # idle taxels: no contact
    processor = DeviceProcessor(device, "hand", 1.0 / 30.0)
    state = processor.initial_state()
    calls = []
    real = ResistanceEvaluator.log_gap_and_slope

    def counted(self: ResistanceEvaluator, *args: object) -> object:
        calls.append(1)
        return real(self, *args)  # type: ignore[arg-type]

    monkeypatch.setattr(ResistanceEvaluator, "log_gap_and_slope", counted)
    per_poll = []
    for k in range(20):
        values = np.clip(values + rng.integers(-50, 51, size=values.size), 0, 30000)
        values[:100] = 0
        image = RegisterImage.from_reads([("holding", first, values.astype(np.uint16))])
        before = len(calls)
        snap, state = processor.process(state, decode_sample(device, image), 1.7e9 + k / 30, 100.0 + k / 30)
        per_poll.append(len(calls) - before)
        assert np.all(snap.force_n[:100] == 0.0)
        assert np.all(np.isfinite(snap.force_n[100:]))
    # the first poll starts every channel from its equilibrium; after it, a few plain steps
    assert max(per_poll[2:]) <= 6, per_poll
