"""Shared fixtures of the integration tests: real processes and ports on loopback; and the
markers of the modules that carry none themselves (pyproject.toml registers them)."""

from __future__ import annotations

import shutil
import signal
import subprocess
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

HERE = Path(__file__).resolve().parent

#: Markers by module, for the modules here that do not set ``pytestmark`` themselves (so their
#: authors need not edit them). A browser, a broker or a real prometheus makes a test slow.
MODULE_MARKERS: dict[str, tuple[str, ...]] = {
    "test_web_page.py": ("browser", "slow"),
    "test_web_playback.py": ("browser", "slow"),
    "test_mqtt.py": ("broker", "slow"),
    "test_mqtt_subscribe.py": ("broker", "slow"),
    "test_deploy_prometheus.py": ("prometheus",),  # promtool and systemd-analyze: quick
    # gateway or simulator processes, or scenarios played for many seconds
    "test_record_and_paper.py": ("slow",),
    "test_calibration_roundtrip.py": ("slow",),
    "test_scan_sim.py": ("slow",),
    "test_skin60_gateway.py": ("slow",),
    "test_sim_rawgrid.py": ("slow",),
    "test_apply_live.py": ("slow",),
    "test_gateway_faults.py": ("slow",),  # each fault watched over a 1.5 s window
}

#: Single tests, of modules not marked slow as a whole, that take over ~2 s (measured with
#: --durations on the 2-core machine, 2026-11-25), by module (every parameter of each).
SLOW_TESTS: dict[str, frozenset[str]] = {
    "test_gateway_tcp.py": frozenset(
        {"test_holds_drift_corrected_over_tcp", "test_reload_keeps_the_creep_state_of_unchanged_channels"}
    ),
    "test_metrics_security.py": frozenset(
        {"test_hundreds_of_idle_and_slow_clients_cost_no_threads_and_do_not_delay_a_scrape"}
    ),
    "test_rawgrid_gateway.py": frozenset(
        {
            "test_a_clock_configured_on_registers_that_do_not_count_is_caught",
            "test_the_rawgrid_array_through_its_profile_tare_layout_and_a_ten_minute_hold",
        }
    ),
    "test_http_hostile.py": frozenset({"test_a_stream_client_that_stops_reading_is_cut_off"}),
}


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """Mark the integration tests by module (MODULE_MARKERS), by name (SLOW_TESTS) and by
    what they use: a socat pty pair (the ``pty_pair`` fixture) is a serial test."""
    for item in items:
        path = Path(str(item.path))
        if path.parent != HERE:
            continue
        names = list(MODULE_MARKERS.get(path.name, ()))
        if getattr(item, "originalname", item.name) in SLOW_TESTS.get(path.name, ()):
            names.append("slow")
        if "pty_pair" in getattr(item, "fixturenames", ()):
            names.append("serial")
        for name in names:
            item.add_marker(getattr(pytest.mark, name))


@pytest.fixture
def pty_pair(tmp_path: Path) -> Iterator[tuple[str, str]]:
    """Two linked pseudo-terminals from socat (a serial line); socat is stopped at teardown."""
    socat = shutil.which("socat")
    if socat is None:
        pytest.fail("socat is not installed: `make test` installs it (Debian package socat)")
    a, b = tmp_path / "a", tmp_path / "b"
    proc = subprocess.Popen(
        [socat, "-d", "-d", f"pty,raw,echo=0,link={a}", f"pty,raw,echo=0,link={b}"],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
    )
    try:
        deadline = time.monotonic() + 10.0
        while not (a.exists() and b.exists()):
            if proc.poll() is not None or time.monotonic() > deadline:
                err = proc.stderr.read().decode() if proc.stderr and proc.poll() is not None else ""
                pytest.fail(f"socat did not create the pty pair (exit code {proc.poll()}): {err}")
            time.sleep(0.01)
        yield str(a), str(b)
    finally:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(timeout=5)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
        if proc.stderr:
            proc.stderr.close()
