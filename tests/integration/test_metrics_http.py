"""/metrics over real HTTP(S): exposition format, last-poll values, TLS + basic auth; and the
``run`` / ``poll-once`` / ``demo`` commands as a user starts them."""

from __future__ import annotations

import asyncio
import base64
import json
import math
import os
import re
import signal
import ssl
import subprocess
import sys
import threading
import time
import urllib.error
import urllib.request
from collections.abc import Callable
from pathlib import Path

import bcrypt
import pytest
from click.testing import CliRunner
from netutil import free_port
from prometheus_client import CollectorRegistry
from prometheus_client.parser import text_string_to_metric_families
from test_gateway_tcp import array_device
from waiting import ManualClock, until

from gateway.cli import main
from gateway.config import bus_config_for, gateway_config_for
from gateway.metrics.collector import make_registry
from gateway.metrics.server import MetricsServer
from gateway.metrics.web_config import load_web_config
from gateway.runtime.poller import Poller, SnapshotHolder
from sim_device import ArrayConfig, SimArray, serve_tcp

GATEWAY = [sys.executable, "-c", "from gateway.cli import main; main()"]


def get(
    url: str, *, auth: tuple[str, str] | None = None, context: ssl.SSLContext | None = None
) -> tuple[int, str, dict[str, str]]:
    req = urllib.request.Request(url)
    if auth is not None:
        req.add_header("Authorization", "Basic " + base64.b64encode(f"{auth[0]}:{auth[1]}".encode()).decode())
    try:
        with urllib.request.urlopen(req, timeout=10, context=context) as resp:
            return resp.status, resp.read().decode(), dict(resp.headers)
    except urllib.error.HTTPError as exc:
        body = exc.read().decode()
        headers = dict(exc.headers)
        exc.close()
        return exc.code, body, headers


def samples(text: str) -> dict[tuple[str, tuple[tuple[str, str], ...]], float]:
    out = {}
    for fam in text_string_to_metric_families(text):
        for s in fam.samples:
            out[(s.name, tuple(sorted(s.labels.items())))] = float(s.value)
    return out


async def wait_until(cond: Callable[[], bool], timeout_s: float, what: str) -> None:
    await until(cond, timeout_s, what, step_s=0.05)


Samples = dict[tuple[str, tuple[tuple[str, str], ...]], float]


async def scrape(url: str) -> Samples:
    """The samples /metrics shows now ({} while it does not answer)."""
    try:
        status, text, _ = await asyncio.to_thread(get, url)
    except (urllib.error.URLError, ConnectionError):
        return {}
    return samples(text) if status == 200 else {}


async def scrape_until(
    url: str,
    shows: Callable[[Samples], bool],
    proc: asyncio.subprocess.Process,
    timeout_s: float,
    what: str,
    log: list[str] | None = None,
) -> Samples:
    """Scrape ``url`` until what it shows satisfies ``shows`` or ``proc`` has exited, and return
    the last scrape (the caller asserts on it); a time-out fails naming ``what``."""
    last: list[Samples] = [{}]

    async def check() -> bool:
        last[0] = await scrape(url)
        return shows(last[0]) or proc.returncode is not None

    try:
        await until(check, timeout_s, what, step_s=0.1)
    except AssertionError as exc:
        raise AssertionError(f"{exc}\n{''.join(log or [])}") from None
    return last[0]


def _array(
    scenario: str = "holds", speed: float = 60.0, clock: Callable[[], float] | None = None
) -> SimArray:
    return SimArray(
        ArrayConfig(channels=16, columns=4, pitch_mm=2.5, seed=1, scenario=scenario, speed=speed),
        1,
        clock=clock,
    )


async def test_scrape_parses_and_carries_the_last_poll() -> None:
    threads_before = set(threading.enumerate())
    array = _array()
    async with serve_tcp([array], host="127.0.0.1", port=0) as sim:
        bus = bus_config_for("tcp", "tcp", [array_device(array, "arr")], host="127.0.0.1", port=sim.port,
                             poll_interval_s=0.02)  # fmt: skip
        holder = SnapshotHolder()
        registry = make_registry(holder.get, CollectorRegistry())
        poller = Poller(gateway_config_for([bus]), holder)
        with MetricsServer(registry, "127.0.0.1", 0) as server:
            async with poller:
                # wait for a loaded hold (0.5 N from 10 s device time)
                await wait_until(
                    lambda: (d := holder.get().devices.get("arr")) is not None and d.total_force_n > 1.0,
                    10,
                    "load on the array",
                )
            snap = holder.get()  # the poller is stopped: this is the last poll
            status, text, headers = await asyncio.to_thread(get, server.url)
    assert status == 200
    assert headers["Content-Type"].startswith("text/plain")
    values = samples(text)
    dev = snap.devices["arr"]
    for ch in dev.channels():
        key = (("channel", ch.name), ("device", "arr"))
        assert ch.force_n is not None
        assert values[("tactile_force_newtons", key)] == pytest.approx(ch.force_n, rel=1e-12)
        assert values[("tactile_resistance_ohms", key)] == pytest.approx(ch.resistance_ohm, rel=1e-12)
        assert values[("tactile_force_static_newtons", key)] == pytest.approx(ch.force_static_n, rel=1e-12)
    assert values[("tactile_device_up", (("device", "arr"),))] == 1.0
    assert values[("tactile_array_total_force_newtons", (("device", "arr"),))] == pytest.approx(
        dev.total_force_n
    )
    reads = values[("tactile_reads_total", (("device", "arr"),))]
    assert reads == snap.counters["arr"].reads_total > 10
    assert (
        values[("tactile_poll_duration_seconds_count", (("device", "arr"),))]
        == snap.counters["arr"].polls_total
    )
    assert all(math.isfinite(v) for v in values.values())
    leaked = [t for t in threading.enumerate() if t not in threads_before and t.is_alive()]
    assert not [t for t in leaked if t.name.startswith(("tactile", "Thread"))], leaked


def _openssl(*args: str, cwd: Path) -> None:
    subprocess.run(["openssl", *args], cwd=cwd, check=True, capture_output=True, timeout=60)


def test_tls_and_basic_auth(tmp_path: Path) -> None:
    _openssl("req", "-x509", "-newkey", "rsa:2048", "-nodes", "-keyout", "server.key", "-out", "server.crt",
             "-days", "2", "-subj", "/CN=127.0.0.1", "-addext", "subjectAltName=IP:127.0.0.1",
             cwd=tmp_path)  # fmt: skip
    hashed = bcrypt.hashpw(b"correct horse", bcrypt.gensalt(rounds=6)).decode().replace("$2b$", "$2y$")
    web = tmp_path / "web.yml"
    web.write_text(
        "tls_server_config:\n  cert_file: server.crt\n  key_file: server.key\n"
        f"basic_auth_users:\n  prometheus: '{hashed}'\n"
    )
    config = load_web_config(web)
    holder = SnapshotHolder()
    registry = make_registry(holder.get, CollectorRegistry())
    trust = ssl.create_default_context(cafile=str(tmp_path / "server.crt"))
    with MetricsServer(registry, "127.0.0.1", 0, config) as server:
        assert server.url.startswith("https://")
        ok = get(server.url, auth=("prometheus", "correct horse"), context=trust)
        wrong = get(server.url, auth=("prometheus", "wrong"), context=trust)
        unknown = get(server.url, auth=("admin", "correct horse"), context=trust)
        missing = get(server.url, context=trust)
        with pytest.raises(urllib.error.URLError, match="CERTIFICATE_VERIFY_FAILED"):
            get(server.url, auth=("prometheus", "correct horse"), context=ssl.create_default_context())
        plain = server.url.replace("https://", "http://")
        with pytest.raises((urllib.error.URLError, ConnectionError, http_client_errors())):
            get(plain, auth=("prometheus", "correct horse"))
    assert ok[0] == 200
    list(text_string_to_metric_families(ok[1]))  # valid exposition format
    for code, _, headers in (wrong, unknown, missing):
        assert code == 401
        assert headers["WWW-Authenticate"].startswith("Basic ")


def http_client_errors() -> type[Exception]:
    import http.client

    return http.client.HTTPException


def _write_config(
    path: Path, metrics_port: int, sim_port: int, poll_interval_s: float, channels: int = 16
) -> None:
    path.write_text(
        f"""
[metrics]
address = "127.0.0.1:{metrics_port}"

[[bus]]
name = "sim"
kind = "tcp"
host = "127.0.0.1"
port = {sim_port}
timeout_s = 0.5
retries = 1
poll_interval_s = {poll_interval_s}
backoff_initial_s = 0.1
backoff_max_s = 1.0

[[bus.device]]
name = "array1"
device_id = 1
profile = "tactile-sim"
encoding = "adc"
channels = {channels}
columns = 4
"""
    )


@pytest.mark.slow  # a gateway process
async def test_run_command_serves_reloads_and_stops(tmp_path: Path) -> None:
    array = _array(speed=1.0)
    async with serve_tcp([array], host="127.0.0.1", port=0) as sim:
        port = free_port()
        cfg = tmp_path / "gateway.toml"
        _write_config(cfg, port, sim.port, 0.05)
        proc = await asyncio.create_subprocess_exec(
            *GATEWAY, "run", "-c", str(cfg), stderr=asyncio.subprocess.PIPE, stdout=asyncio.subprocess.DEVNULL
        )
        log: list[str] = []

        async def read_log() -> None:
            assert proc.stderr is not None
            while line := await proc.stderr.readline():
                log.append(line.decode())

        reader = asyncio.create_task(read_log())
        url = f"http://127.0.0.1:{port}/metrics"
        up_key = ("tactile_device_up", (("device", "array1"),))
        interval_key = ("tactile_poll_interval_seconds", (("device", "array1"),))
        reads_key = ("tactile_reads_total", (("device", "array1"),))
        try:
            values = await scrape_until(url, lambda v: v.get(up_key) == 1.0, proc, 15, "the device up", log)
            assert values.get(up_key) == 1.0, f"gateway did not come up: {''.join(log)}"
            assert values[interval_key] == 0.05
            # SIGHUP with a changed poll interval: applied, still up
            _write_config(cfg, port, sim.port, 0.1)
            proc.send_signal(signal.SIGHUP)
            await wait_until(lambda: any("reloaded" in line for line in log), 10, "reload logged")
            values = await scrape(url)
            assert values[interval_key] == 0.1
            # SIGHUP with a broken file: logged, the old configuration keeps running
            cfg.write_text("[[bus]]\nname = 'sim'\nkind = 'carrier-pigeon'\n")
            proc.send_signal(signal.SIGHUP)
            await wait_until(lambda: any("reload failed" in line for line in log), 10, "failed reload logged")
            # SIGHUP with files Python's TOML parser fails on beyond syntax (issue 24 §1): an
            # integer of 5,001 digits (ValueError) and arrays nested 500 deep (RecursionError)
            for hostile, reason in (("1" * 5001, "too long"), ("[" * 500 + "]" * 500, "nested too deeply")):
                cfg.write_text(f"x = {hostile}\n")
                proc.send_signal(signal.SIGHUP)

                def failed_or_exited(reason: str = reason) -> bool:
                    logged = any("reload failed" in line and reason in line for line in log)
                    return logged or proc.returncode is not None

                await wait_until(failed_or_exited, 10, f"failed reload logged ({reason})")
                assert proc.returncode is None, "".join(log)
            reads0 = (await scrape(url))[reads_key]
            # the gateway keeps polling after the reloads: its read counter moves on
            values = await scrape_until(
                url, lambda v: v.get(reads_key, reads0) > reads0, proc, 10, "another read of the device", log
            )
            assert values[up_key] == 1.0
            assert values[reads_key] > reads0
            proc.send_signal(signal.SIGTERM)
            code = await asyncio.wait_for(proc.wait(), timeout=10)
            assert code == 0, "".join(log)
        finally:
            if proc.returncode is None:
                proc.kill()
                await proc.wait()
            await reader
    assert any("stopped" in line for line in log)


def test_run_with_a_bad_config_exits_2(tmp_path: Path) -> None:
    cfg = tmp_path / "bad.toml"
    cfg.write_text("[metrics]\naddress = 'nowhere'\n")
    result = CliRunner().invoke(main, ["run", "-c", str(cfg)])
    assert result.exit_code == 2, result.output
    assert "bad.toml" in result.output and "address" in result.output


def test_poll_once_unreachable_device_lists_stale_channels_and_exits_1(tmp_path: Path) -> None:
    cfg = tmp_path / "gateway.toml"
    _write_config(cfg, free_port(), free_port(), 0.05, channels=4)
    result = CliRunner().invoke(main, ["poll-once", "-c", str(cfg), "--json"])
    assert result.exit_code == 1, result.output
    data = json.loads(result.stdout)
    dev = data["devices"][0]
    assert dev["device"] == "array1" and dev["up"] is False
    assert [c["status"] for c in dev["channels"]] == ["stale"] * 4
    assert all(c["force_n"] is None for c in dev["channels"])


@pytest.mark.slow  # a gateway process
async def test_poll_once_reads_a_device(tmp_path: Path) -> None:
    # The device stands at 18 s (the 0.5 N hold) on a clock the test holds, however long the
    # command takes to start: sleeping 0.3 s at 60x put it there only on an idle machine.
    clock = ManualClock()
    array = _array(scenario="holds", speed=60.0, clock=clock)
    clock.advance(18.0 / 60.0)
    assert array.true_force_n().min() == 0.5
    async with serve_tcp([array], host="127.0.0.1", port=0) as sim:
        cfg = tmp_path / "gateway.toml"
        _write_config(cfg, free_port(), sim.port, 0.05)
        proc = await asyncio.create_subprocess_exec(
            *GATEWAY,
            "poll-once",
            "-c",
            str(cfg),
            stdout=asyncio.subprocess.PIPE,
            stderr=asyncio.subprocess.PIPE,
        )
        out, err = await asyncio.wait_for(proc.communicate(), timeout=30)
    assert proc.returncode == 0, err.decode()
    text = out.decode()
    assert "device array1 on bus sim: up" in text
    assert text.count(" ok ") + text.count(" no_contact ") == 16, text


@pytest.mark.slow  # a gateway process
async def test_demo_shows_the_array_and_serves_metrics() -> None:
    # The demo runs until the test has seen the array up, then gets SIGINT: a fixed --duration
    # raced the scrapes on a busy machine (the demo could end before a scrape saw it up).
    port = free_port()
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    started = time.monotonic()
    proc = await asyncio.create_subprocess_exec(
        *GATEWAY, "demo", "--port", str(port), "--duration", "120",
        stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.PIPE, env=env,
    )  # fmt: skip
    printed: list[bytes] = []

    async def read_stdout() -> None:
        assert proc.stdout is not None
        while line := await proc.stdout.readline():
            printed.append(line)

    assert proc.stderr is not None
    reader, errors = asyncio.create_task(read_stdout()), asyncio.create_task(proc.stderr.read())
    try:
        url = f"http://127.0.0.1:{port}/metrics"
        up_key = ("tactile_device_up", (("device", "demo"),))
        polls_key = ("tactile_poll_duration_seconds_count", (("device", "demo"),))
        values = await scrape_until(url, lambda v: v.get(up_key) == 1.0, proc, 60, "the demo's array up")
        # a scrape or two of an up array (one more poll seen) and the demo's line saying so
        polls0 = values.get(polls_key, 0.0)
        values = await scrape_until(url, lambda v: v.get(polls_key, 0.0) > polls0, proc, 30, "another poll")
        await until(
            lambda: len(printed) >= 2 or proc.returncode is not None, 30, "the demo's line once it is up"
        )
        proc.send_signal(signal.SIGINT)
        await asyncio.wait_for(proc.wait(), timeout=30)
        ran_s = time.monotonic() - started
    finally:
        if proc.returncode is None:
            proc.kill()
            await proc.wait()
        await reader
        err = await errors
    out = b"".join(printed)
    assert proc.returncode == 0, err.decode()
    assert values.get(("tactile_device_up", (("device", "demo"),))) == 1.0
    lines = out.decode().splitlines()
    # not a terminal: the addresses once, a line once the array answers, then one every 5 s
    # (not a full frame 5 times a second)
    assert lines[0] == f"page on http://127.0.0.1:{port}/ - metrics on http://127.0.0.1:{port}/metrics"
    assert 2 <= len(lines) <= 2 + int(ran_s / 5.0) and "\x1b[" not in out.decode(), (lines, ran_s)
    for line in lines[1:]:
        assert re.fullmatch(
            r"\d\d:\d\d:\d\d demo (up|DOWN): total \d+\.\d{3} N, \d+ channels in contact, "
            r"centre of pressure .+",
            line,
        ), lines


@pytest.mark.slow  # two gateway processes, one runs 1.5 s
def test_demo_refuses_a_bad_host_in_one_line_and_takes_any_port() -> None:
    bad = subprocess.run(
        [*GATEWAY, "demo", "--host", "a b", "--duration", "1"], capture_output=True, text=True, timeout=60
    )
    assert bad.returncode == 2 and "cannot serve metrics on a b:9830" in bad.stderr
    assert "Traceback" not in bad.stderr
    ok = subprocess.run(
        [*GATEWAY, "demo", "--port", "0", "--duration", "1.5"], capture_output=True, text=True, timeout=60
    )
    assert ok.returncode == 0, ok.stderr
    assert ok.stdout.startswith("page on http://127.0.0.1:") and "Traceback" not in ok.stderr
