"""The poll loop first: on a fast bus, the gateway's publishing threads yield the CPU to it.

A bus polled back to back (``poll_interval_s`` below ``FAST_POLL_INTERVAL_S``, 0 included)
waits on its device most of the time and must answer it at once: every microsecond between
a device's answer and the next request is lost line time. The MQTT publisher's thread and
the web server's thread (the page, the stream, ``/metrics``) encode and send frames; on one
busy core, a device's answer should not wait for them. When the configuration has a fast
bus, each of them calls ``yield_to_poll_loop`` as it starts, which lowers the calling
thread's scheduling priority by ``BACKGROUND_NICE`` (Linux schedules threads one by one: the
niceness of a thread id is its own; threads it starts inherit it). They still run whenever
the poll loop waits, so nothing is lost, only scheduled later (measured: 0.85 -> 0.93 of a
bare loop's frame rate, ``bench/bench_fast_rtu.py``). They do so only then: a lowered thread
also yields to every other busy process of the host, which a gateway polling ten times a
second has no reason to accept. Raising a niceness needs no privilege. Elsewhere (no
per-thread niceness) it does nothing.
"""

from __future__ import annotations

import logging
import os
import sys
import threading

from ..config import GatewayConfig

__all__ = ["BACKGROUND_NICE", "FAST_POLL_INTERVAL_S", "polls_fast", "yield_to_poll_loop"]

log = logging.getLogger(__name__)

#: How much lower than the poll loop the publishing threads run (nice steps; 19 at most).
BACKGROUND_NICE = 10
#: A bus polled more often than this (s between the starts of two polls) is a fast bus.
FAST_POLL_INTERVAL_S = 0.01


def polls_fast(config: GatewayConfig) -> bool:
    """Whether ``config`` has a fast bus: one polled more often than every
    ``FAST_POLL_INTERVAL_S`` (its ``poll_interval_s``, in s)."""
    return any(bus.poll_interval_s < FAST_POLL_INTERVAL_S for bus in config.buses)


def yield_to_poll_loop() -> int | None:
    """Lower the calling thread's priority by ``BACKGROUND_NICE``; its new niceness, or None
    where threads have no niceness of their own (not Linux) or the system refused."""
    if not sys.platform.startswith("linux"):
        return None
    tid = threading.get_native_id()
    try:
        nice = min(19, os.getpriority(os.PRIO_PROCESS, tid) + BACKGROUND_NICE)
        os.setpriority(os.PRIO_PROCESS, tid, nice)
    except OSError as exc:
        log.debug("could not lower the priority of thread %d: %s", tid, exc)
        return None
    return nice
