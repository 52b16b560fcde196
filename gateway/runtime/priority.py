"""The poll loop first: the gateway's publishing threads yield the CPU to it.

The poll loop waits on a device most of the time and must answer it at once: on a serial
line polled back to back, every microsecond between a device's answer and the next request
is lost line time. The MQTT publisher's thread and the web server's thread (the page, the
stream, ``/metrics``) encode and send frames; on a busy host, a device's answer should not
wait for them. Each of them calls ``yield_to_poll_loop`` when it starts, which lowers the
calling thread's scheduling priority by ``BACKGROUND_NICE`` (Linux schedules threads one by
one: the niceness of a thread id is its own; threads it starts inherit it). They still run
whenever the poll loop waits, so nothing is lost, only scheduled later. Raising a niceness
needs no privilege. Elsewhere (no per-thread niceness) it does nothing.
"""

from __future__ import annotations

import logging
import os
import sys
import threading

__all__ = ["BACKGROUND_NICE", "yield_to_poll_loop"]

log = logging.getLogger(__name__)

#: How much lower than the poll loop the publishing threads run (nice steps; 19 at most).
BACKGROUND_NICE = 10


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
