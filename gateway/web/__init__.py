"""The live pressure-map page and the frame API of the gateway's HTTP server.

* ``frames``: the JSON of a device's layout and of one poll (a frame);
* ``hub``: ``FrameHub``, every poll numbered and fanned out to stream and page clients
  without holding up the poller (bounded queues, newest frame wins for the page);
* ``app``: ``WebPage``, the aiohttp routes (``/``, ``/static/*``, ``/api/...``).
"""

from .app import WebPage
from .hub import FrameHub, PageQueue, StreamQueue

__all__ = ["FrameHub", "PageQueue", "StreamQueue", "WebPage"]
