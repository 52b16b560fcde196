"""``make soak``: the gateway against the simulator for a long run with faults on a schedule.

The gateway runs as its own process (``tactile-gateway run``), so its resident memory, open
file descriptors and threads are its own (read from /proc). The simulator (``tactile-sim
run``) plays a repeating load cycle on 16 channels and, from a generated scenario file, a
fault every ``FAULT_EVERY_S``: no answer (the device switched off and on), answers later than
the gateway's timeout, garbled frames, dropped connections and exception responses. The driver
sends SIGHUP every ``RELOAD_EVERY_S`` and scrapes ``/metrics`` every second (each scrape a new
connection that goes away).

It reports, every minute and at the end:
* RSS (MB), open fds and threads, sampled every 5 s, and the gateway's asyncio tasks
  (``tactile_gateway_asyncio_tasks``, scraped); growth after warm-up (the first quarter)
  by a least-squares slope, extrapolated per hour;
* the polls: successful reads, read errors by reason, and the reads that are neither;
* after each recovery from a fault, the largest |force - reference| over channels once
  settled (reference unchanged and the device up for ``SETTLE_S``), against 0.1 N.

Usage: ``python -m bench.soak [--minutes 20] [--report docs/reliability.md]``
"""

from __future__ import annotations

import argparse
import os
import re
import signal
import socket
import subprocess
import sys
import tempfile
import time
import urllib.request
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

BIN = Path(sys.executable).parent
FAULT_EVERY_S = 45.0
FAULT_LENGTH_S = 6.0
RELOAD_EVERY_S = 100.0
SETTLE_S = 8.0
TOLERANCE_N = 0.1
FAULT_KINDS = (
    ("no_response", "no_response = true"),
    ("slow", "delay_s = 0.8"),
    ("garbled", "garble = true"),
    ("dropped", "drop_connection = true"),
    ("exception", "exception_code = 4"),
)


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _scenario(path: Path, duration_s: float) -> None:
    lines = [
        'name = "soak"',
        "repeat = true",
        "[[load]]",
        'channels = "all"',
        "initial_n = 0.0",
        "steps = [ { hold_s = 30 }, { hold_s = 90, force_n = 2.0 }, { ramp_n = 4.0, duration_s = 10 },",
        "  { hold_s = 90 }, { step_n = 0.0 }, { hold_s = 30 } ]",
    ]
    t = FAULT_EVERY_S
    k = 0
    while t < duration_s + 120:
        _, spec = FAULT_KINDS[k % len(FAULT_KINDS)]
        lines += ["[[fault]]", f"at_s = {t:.1f}", f"until_s = {t + FAULT_LENGTH_S:.1f}", spec]
        t += FAULT_EVERY_S
        k += 1
    path.write_text("\n".join(lines) + "\n")


def _config(path: Path, sim_port: int, metrics_port: int) -> None:
    path.write_text(
        f'[metrics]\naddress = "127.0.0.1:{metrics_port}"\n\n'
        f'[[bus]]\nname = "sim"\nkind = "tcp"\nhost = "127.0.0.1"\nport = {sim_port}\n'
        "poll_interval_s = 0.05\ntimeout_s = 0.5\nretries = 1\n"
        "backoff_initial_s = 0.2\nbackoff_max_s = 2.0\n\n"
        '[[bus.device]]\nname = "arr"\ndevice_id = 1\nprofile = "tactile-sim"\nchannels = 16\ncolumns = 4\n'
        "[bus.device.registers]\nforce_reference_address = 1000\n"
    )
    path.chmod(0o600)


def _proc(pid: int) -> tuple[float, int, int]:
    """RSS (MB), open fds, threads of a process."""
    status = Path(f"/proc/{pid}/status").read_text()
    rss_kb = int(re.search(r"VmRSS:\s+(\d+)", status).group(1))  # type: ignore[union-attr]
    threads = int(re.search(r"Threads:\s+(\d+)", status).group(1))  # type: ignore[union-attr]
    fds = len(os.listdir(f"/proc/{pid}/fd"))
    return rss_kb / 1024.0, fds, threads


_SAMPLE = re.compile(r"^(\w+)(?:\{([^}]*)\})? (\S+)$")


def _scrape(port: int) -> dict[tuple[str, str], float]:
    with urllib.request.urlopen(f"http://127.0.0.1:{port}/metrics", timeout=5) as response:
        text = response.read().decode()
    out: dict[tuple[str, str], float] = {}
    for line in text.splitlines():
        m = _SAMPLE.match(line)
        if m:
            out[(m.group(1), m.group(2) or "")] = float(m.group(3))
    return out


@dataclass
class Recovery:
    started_s: float
    worst_n: float = 0.0
    settled_samples: int = 0


@dataclass
class Soak:
    samples: list[tuple[float, float, int, int]] = field(default_factory=list)
    #: (elapsed s, tasks alive in the gateway's event loop), from tactile_gateway_asyncio_tasks
    tasks: list[tuple[float, float]] = field(default_factory=list)
    recoveries: list[Recovery] = field(default_factory=list)
    scrapes: int = 0
    scrape_failures: int = 0
    reloads: int = 0


def _forces(metrics: dict[tuple[str, str], float]) -> tuple[dict[str, float], dict[str, float], bool]:
    force: dict[str, float] = {}
    reference: dict[str, float] = {}
    up = metrics.get(("tactile_device_up", 'device="arr"'), 0.0) == 1.0
    for (name, labels), value in metrics.items():
        channel = re.search(r'channel="([^"]+)"', labels)
        if channel is None:
            continue
        if name == "tactile_force_newtons":
            force[channel.group(1)] = value
        elif name == "tactile_reference_force_newtons":
            reference[channel.group(1)] = value
    return force, reference, up


def run(minutes: float) -> tuple[Soak, dict[tuple[str, str], float]]:
    duration_s = minutes * 60.0
    soak = Soak()
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        sim_port, metrics_port = _free_port(), _free_port()
        _scenario(folder / "soak.toml", duration_s)
        _config(folder / "gateway.toml", sim_port, metrics_port)
        sim = subprocess.Popen(
            [str(BIN / "tactile-sim"), "run", "--tcp", f"127.0.0.1:{sim_port}", "--channels", "16",
             "--scenario", str(folder / "soak.toml"), "--no-spread"],
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
        )  # fmt: skip
        time.sleep(1.0)
        gateway = subprocess.Popen(
            [str(BIN / "tactile-gateway"), "run", "-c", str(folder / "gateway.toml"),
             "--log-level", "warning"],
            stdout=subprocess.DEVNULL, stderr=open(folder / "gateway.log", "w"),  # noqa: SIM115
        )  # fmt: skip
        t0 = time.monotonic()
        last_reload = t0
        history: list[tuple[float, dict[str, float], bool]] = []
        up_since: float | None = None
        final: dict[tuple[str, str], float] = {}
        try:
            while (now := time.monotonic()) - t0 < duration_s:
                elapsed = now - t0
                if elapsed >= 10.0 and (not soak.samples or elapsed - soak.samples[-1][0] >= 5.0):
                    rss, fds, threads = _proc(gateway.pid)
                    soak.samples.append((elapsed, rss, fds, threads))
                    if len(soak.samples) % 12 == 0:
                        print(
                            f"{elapsed / 60:5.1f} min: RSS {rss:.1f} MB, {fds} fds, {threads} threads",
                            flush=True,
                        )
                if now - last_reload >= RELOAD_EVERY_S:
                    gateway.send_signal(signal.SIGHUP)
                    soak.reloads += 1
                    last_reload = now
                try:
                    metrics = _scrape(metrics_port)
                    soak.scrapes += 1
                    final = metrics
                    tasks = metrics.get(("tactile_gateway_asyncio_tasks", ""))
                    if tasks is not None and (not soak.tasks or elapsed - soak.tasks[-1][0] >= 5.0):
                        soak.tasks.append((elapsed, tasks))
                except OSError:
                    soak.scrape_failures += 1
                    time.sleep(1.0)
                    continue
                force, reference, up = _forces(metrics)
                if not up:
                    if up_since is not None:
                        soak.recoveries.append(Recovery(started_s=elapsed))
                    up_since = None
                elif up_since is None:
                    up_since = elapsed
                    if not soak.recoveries:
                        soak.recoveries.append(Recovery(started_s=elapsed))
                history.append((elapsed, reference, up))
                recent = [h for h in history if h[0] >= elapsed - SETTLE_S]
                settled = (
                    up_since is not None
                    and elapsed - up_since >= SETTLE_S
                    and len(recent) >= 3
                    and all(h[2] and h[1] == reference for h in recent)
                )
                if settled and soak.recoveries:
                    errors = [abs(force[c] - reference[c]) for c in reference if c in force]
                    if errors:
                        r = soak.recoveries[-1]
                        r.worst_n = max(r.worst_n, max(errors))
                        r.settled_samples += 1
                history = [h for h in history if h[0] >= elapsed - 2 * SETTLE_S]
                time.sleep(max(0.0, 1.0 - (time.monotonic() - now)))
        finally:
            gateway.send_signal(signal.SIGTERM)
            try:
                gateway.wait(timeout=20)
            except subprocess.TimeoutExpired:
                gateway.kill()
            sim.terminate()
            sim.wait(timeout=20)
    return soak, final


def _growth_per_hour(samples: list[tuple[float, float]]) -> float:
    t = np.array([s[0] for s in samples])
    v = np.array([s[1] for s in samples])
    if t.size < 3:
        return float("nan")
    slope = float(np.polyfit(t, v, 1)[0])
    return slope * 3600.0


def report(soak: Soak, final: dict[tuple[str, str], float], minutes: float) -> str:
    warm = [s for s in soak.samples if s[0] >= max(60.0, soak.samples[-1][0] / 4)]
    rss = _growth_per_hour([(s[0], s[1]) for s in warm])
    fds = _growth_per_hour([(s[0], float(s[2])) for s in warm])
    threads = _growth_per_hour([(s[0], float(s[3])) for s in warm])
    warm_start = warm[0][0] if warm else 0.0
    tasks = _growth_per_hour([s for s in soak.tasks if s[0] >= warm_start])
    reads = final.get(("tactile_reads_total", 'device="arr"'), float("nan"))
    errors = {
        labels.split('reason="')[1].rstrip('"'): v
        for (name, labels), v in final.items()
        if name == "tactile_read_errors_total" and 'device="arr"' in labels
    }
    polls = final.get(("tactile_poll_duration_seconds_count", 'device="arr"'), float("nan"))
    measured = [r for r in soak.recoveries if r.settled_samples]
    lines = [
        f"soak: {minutes:g} min, {soak.scrapes} scrapes ({soak.scrape_failures} failed), "
        f"{soak.reloads} SIGHUP reloads",
        f"RSS {soak.samples[0][1]:.1f} -> {soak.samples[-1][1]:.1f} MB (after warm-up {rss:+.2f} MB/h), "
        f"fds {soak.samples[0][2]} -> {soak.samples[-1][2]} ({fds:+.1f}/h), "
        f"threads {soak.samples[0][3]} -> {soak.samples[-1][3]} ({threads:+.1f}/h), "
        + (
            f"asyncio tasks {soak.tasks[0][1]:.0f} -> {soak.tasks[-1][1]:.0f} "
            f"(max {max(v for _, v in soak.tasks):.0f}, after warm-up {tasks:+.1f}/h)"
            if soak.tasks
            else "asyncio tasks: not scraped"
        ),
        f"reads {reads:.0f}, successful polls {polls:.0f}, errors by reason: "
        + ", ".join(f"{k} {v:.0f}" for k, v in sorted(errors.items())),
        f"recoveries measured: {len(measured)} of {len(soak.recoveries)}; worst settled |force - reference| "
        f"per recovery: max {max((r.worst_n for r in measured), default=float('nan')):.4f} N "
        f"(goal {TOLERANCE_N} N); {sum(r.worst_n > TOLERANCE_N for r in measured)} above",
    ]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser()
    parser.add_argument("--minutes", type=float, default=20.0)
    args = parser.parse_args(argv)
    soak, final = run(args.minutes)
    text = report(soak, final, args.minutes)
    print(text)
    measured = [r for r in soak.recoveries if r.settled_samples]
    ok = measured and all(r.worst_n <= TOLERANCE_N for r in measured)
    return 0 if ok else 1


if __name__ == "__main__":
    raise SystemExit(main())
