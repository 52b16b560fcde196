"""``run`` gives the page the configuration in force, so that /api/devices carries each
device's cell area and disabled channels (and follows a reload)."""

from __future__ import annotations

from gateway.cli.run_cmd import _page
from gateway.config import GatewayConfig
from gateway.config.builders import bus_config_for, device_config_for, gateway_config_for
from gateway.model import SensorParams
from gateway.runtime.poller import SnapshotHolder


def _config(name: str, pitch_mm: float) -> GatewayConfig:
    device = device_config_for(name, 1, [SensorParams()] * 4, 2, pitch_mm)
    return gateway_config_for([bus_config_for("b", "tcp", [device], host="127.0.0.1", port=5020)])


def test_the_page_reads_the_running_configuration_and_follows_a_reload() -> None:
    first, second = _config("arr", 2.5), _config("pad", 4.0)
    running = [first]
    page = _page(SnapshotHolder(), first, True, running)
    assert page is not None and page.device_configs is not None
    assert [d.name for d in page.device_configs()] == ["arr"]
    running[0] = second  # what serve() does on a reload
    assert [d.name for d in page.device_configs()] == ["pad"]
    assert _page(SnapshotHolder(), first, False, running) is None
