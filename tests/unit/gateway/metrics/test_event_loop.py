"""``EventLoopCollector``: the task count of the gateway's event loop, read from another thread."""

from __future__ import annotations

import asyncio

from prometheus_client import CollectorRegistry, generate_latest

from gateway.metrics.event_loop import EventLoopCollector


async def test_the_task_count_follows_tasks_started_and_finished() -> None:
    loop = asyncio.get_running_loop()
    registry = CollectorRegistry()
    registry.register(EventLoopCollector(loop))

    async def scrape() -> float:
        # as the server scrapes: in an executor thread, not the loop's own
        text = (await loop.run_in_executor(None, generate_latest, registry)).decode()
        line = next(x for x in text.splitlines() if x.startswith("tactile_gateway_asyncio_tasks "))
        return float(line.split()[1])

    before = await scrape()
    assert before >= 1.0  # this test's own task
    stop = asyncio.Event()
    tasks = [asyncio.create_task(stop.wait()) for _ in range(5)]
    await asyncio.sleep(0)
    assert await scrape() == before + 5
    stop.set()
    await asyncio.gather(*tasks)
    assert await scrape() == before
