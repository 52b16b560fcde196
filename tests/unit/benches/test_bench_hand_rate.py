"""``bench/bench_hand_rate.py`` without timing: the configuration it runs ``run`` on (the hand's
profile read through the simulator's circuit, every output on) and its CPU accounting."""

from __future__ import annotations

from pathlib import Path
from types import ModuleType

import pytest

from gateway.config import parse_config
from gateway.modbus.plan import MERGE_GAP, device_plan
from gateway.model import Transimpedance

REPO = Path(__file__).resolve().parents[3]


@pytest.fixture
def bench(monkeypatch: pytest.MonkeyPatch) -> ModuleType:
    monkeypatch.syspath_prepend(str(REPO))  # the benches are not an installed package
    import bench.bench_hand_rate as module

    return module


def test_the_bench_reads_the_hand_through_the_simulators_circuit_with_every_output(bench: ModuleType) -> None:
    config = parse_config(bench.config_text(5020, 1883, 9830, 8765, 1.0 / 30.0))
    (bus,) = config.buses
    (device,) = bus.devices
    assert bus.poll_interval_s == pytest.approx(1.0 / 30.0)
    assert (device.n_channels, len(device.regions)) == (1062, 17)
    # raw = 65535 x 1 kohm / r: a 1 V bias into 1 kohm feedback, 16 bits at 1 V
    assert device.front_end == Transimpedance(
        bias_v=1.0, feedback_ohm=1000.0, adc_bits=16, adc_reference_v=1.0
    )
    assert config.mqtt is not None and (config.mqtt.host, config.mqtt.port) == ("127.0.0.1", 1883)
    assert config.foxglove is not None and config.foxglove.port == 8765
    assert (config.metrics.port, config.metrics.page) == (9830, True)
    # bytes 3000..5123 are registers 1500..2561: 1,062 = 8 x 125 + 62, so 9 requests
    plan = device_plan(device, bus.max_read_registers, MERGE_GAP, True)
    assert [(r.address, r.count) for r in plan] == [(1500 + 125 * k, 125) for k in range(8)] + [(2500, 62)]
    assert {r.kind for r in plan} == {"holding"}


def test_cpu_per_poll_by_thread_or_process_largest_first(bench: ModuleType) -> None:
    before = {"MainThread": 1.0, "device": 2.0}
    after = {"MainThread": 1.5, "device": 2.2, "tactile-mqtt": 0.05, "idle": 0.0}
    # over 100 polls: 0.5 s -> 5.0 ms, 0.2 s -> 2.0 ms, 0.05 s -> 0.5 ms; nothing spent is left out
    assert bench._cpu_text(before, after, 100) == "MainThread 5.0, device 2.0, tactile-mqtt 0.5"
