"""Debian's real Prometheus scrapes the gateway, which polls the simulated array.

Three real processes on loopback: ``tactile-sim`` (a constant 2 N load on every channel),
``tactile-gateway run`` and ``prometheus`` with the project's alert rules and a temporary
data directory. The test queries Prometheus's HTTP API for the force series and the device's
``up``, stops the simulated array, and watches ``tactile_device_up`` drop to 0 and the
device-down alert go pending.
"""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
import urllib.parse
import urllib.request
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
from netutil import free_port
from waiting import wait_for

ROOT = Path(__file__).resolve().parents[2]
BIN = Path(sys.executable).parent

pytestmark = [pytest.mark.prometheus, pytest.mark.slow]


def _query(port: int, expr: str) -> list[dict[str, Any]]:
    url = f"http://127.0.0.1:{port}/api/v1/query?" + urllib.parse.urlencode({"query": expr})
    with urllib.request.urlopen(url, timeout=5) as resp:
        body = json.load(resp)
    assert body["status"] == "success", body
    return list(body["data"]["result"])


def _alerts(port: int) -> list[dict[str, Any]]:
    with urllib.request.urlopen(f"http://127.0.0.1:{port}/api/v1/alerts", timeout=5) as resp:
        return list(json.load(resp)["data"]["alerts"])


class Processes:
    def __init__(self, logs: Path) -> None:
        self.logs = logs
        self.running: dict[str, subprocess.Popen[bytes]] = {}

    def start(self, name: str, argv: list[str]) -> subprocess.Popen[bytes]:
        log = (self.logs / f"{name}.log").open("wb")
        proc = subprocess.Popen(argv, stdout=log, stderr=subprocess.STDOUT, cwd=self.logs)
        self.running[name] = proc
        return proc

    def stop(self, name: str) -> None:
        proc = self.running.pop(name)
        proc.terminate()
        try:
            proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()

    def check_running(self) -> None:
        """Fail at once, not at a time-out, if a process has exited (a port taken, a bad flag)."""
        for name, proc in self.running.items():
            if proc.poll() is not None:
                raise AssertionError(f"{name} exited with code {proc.returncode}")

    def wait(self, what: str, check: Callable[[], Any], timeout_s: float = 30.0) -> Any:
        """Poll ``check`` (a query; a refused connection counts as not yet) until it returns
        something truthy, while every process still runs."""

        def running_and(check: Callable[[], Any] = check) -> Any:
            self.check_running()
            return check()

        return wait_for(running_and, timeout_s, what, step_s=0.25, ignore=(OSError,))

    def log(self, name: str) -> str:
        return (self.logs / f"{name}.log").read_text(errors="replace")[-3000:]

    def stop_all(self) -> None:
        for name in list(self.running):
            self.stop(name)


@pytest.fixture
def procs(tmp_path: Path) -> Iterator[Processes]:
    p = Processes(tmp_path)
    try:
        yield p
    finally:
        p.stop_all()


def test_prometheus_scrapes_gateway_and_sees_the_device_go_down(tmp_path: Path, procs: Processes) -> None:
    prometheus = shutil.which("prometheus")
    assert prometheus, "Debian's prometheus is not installed: run `make test`, which installs it"
    sim_port, metrics_port, prom_port = free_port(), free_port(), free_port()

    scenario = tmp_path / "constant.toml"
    scenario.write_text(
        'name = "constant"\nsettled = true\n'
        '[[load]]\nchannels = "all"\nsteps = [ { hold_s = 3600, force_n = 2.0 } ]\n'
    )
    procs.start(
        "sim",
        [
            str(BIN / "tactile-sim"),
            "run",
            "--tcp",
            f"127.0.0.1:{sim_port}",
            "--channels",
            "4",
            "--scenario",
            str(scenario),
            "--speed",
            "1",
            "--no-spread",
        ],
    )
    config = tmp_path / "gateway.toml"
    config.write_text(
        f"""
[metrics]
address = "127.0.0.1:{metrics_port}"

[[bus]]
name = "sim"
kind = "tcp"
host = "127.0.0.1"
port = {sim_port}
timeout_s = 0.5
retries = 0
poll_interval_s = 0.2
backoff_initial_s = 0.2
backoff_max_s = 1.0

[[bus.device]]
name = "array1"
device_id = 1
profile = "tactile-sim"
channels = 4
columns = 2
"""
    )
    config.chmod(0o600)
    procs.start("gateway", [str(BIN / "tactile-gateway"), "run", "-c", str(config)])

    rules = tmp_path / "alerts.yml"
    shutil.copy(ROOT / "deploy" / "prometheus" / "alerts.yml", rules)
    prom_config = tmp_path / "prometheus.yml"
    prom_config.write_text(
        f"""
global:
  scrape_interval: 1s
  evaluation_interval: 1s
rule_files: ["{rules}"]
scrape_configs:
  - job_name: tactile-gateway
    static_configs:
      - targets: ["127.0.0.1:{metrics_port}"]
"""
    )
    procs.start(
        "prometheus",
        [
            prometheus,
            f"--config.file={prom_config}",
            f"--storage.tsdb.path={tmp_path / 'data'}",
            f"--web.listen-address=127.0.0.1:{prom_port}",
        ],
    )

    try:
        up = procs.wait(
            "tactile_device_up == 1 in Prometheus", lambda: _query(prom_port, "tactile_device_up == 1"), 60
        )
        assert up[0]["metric"]["device"] == "array1"
        forces = procs.wait(
            "four force series",
            lambda: (r := _query(prom_port, 'tactile_force_newtons{device="array1"}')) and len(r) == 4 and r,
        )
        values = sorted(float(r["value"][1]) for r in forces)
        print(f"\nforces scraped by Prometheus for a 2 N load: {values}")
        assert all(abs(v - 2.0) < 0.1 for v in values), values

        procs.stop("sim")
        down = procs.wait(
            "tactile_device_up == 0 after the array stopped",
            lambda: _query(prom_port, "tactile_device_up == 0"),
            30,
        )
        assert down[0]["metric"]["device"] == "array1"
        alert = procs.wait(
            "TactileDeviceDown pending",
            lambda: [a for a in _alerts(prom_port) if a["labels"]["alertname"] == "TactileDeviceDown"],
            30,
        )
        assert alert[0]["state"] == "pending", alert
        assert alert[0]["labels"]["device"] == "array1"
    except AssertionError as exc:
        raise AssertionError(
            f"{exc}\n--- gateway log ---\n{procs.log('gateway')}"
            f"\n--- prometheus log ---\n{procs.log('prometheus')}"
        ) from None
