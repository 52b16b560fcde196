"""``tactile_gateway_asyncio_tasks``: the tasks alive in the gateway's event loop.

Every poll loop, server connection and stream client is a task; a count that grows over a
long run is a leak (``make soak`` samples it beside RSS, file descriptors and threads).
"""

from __future__ import annotations

import asyncio
from collections.abc import Iterator

from prometheus_client.core import GaugeMetricFamily, Metric

__all__ = ["EventLoopCollector"]


class EventLoopCollector:
    """A collector of the task count of one event loop (safe to call from the scrape thread)."""

    def __init__(self, loop: asyncio.AbstractEventLoop) -> None:
        self._loop = loop

    def collect(self) -> Iterator[Metric]:
        yield GaugeMetricFamily(
            "tactile_gateway_asyncio_tasks",
            "Tasks alive in the gateway's asyncio event loop (growth over a long run is a leak).",
            value=len(asyncio.all_tasks(self._loop)),
        )
