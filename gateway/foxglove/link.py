"""The Foxglove side of a running gateway: one publisher for the current ``[foxglove]``
settings and served devices (restarted when they change on reload, stopped when the section
goes)."""

from __future__ import annotations

import logging
import threading

from ..config import GatewayConfig
from ..runtime.snapshot import GatewaySnapshot
from .publisher import FoxglovePublisher

__all__ = ["FoxgloveLink"]

log = logging.getLogger(__name__)


def _served(config: GatewayConfig) -> tuple[object, ...]:
    """What the publisher is built from: the settings and the served devices' configurations."""
    settings = config.foxglove
    if settings is None:
        return ()
    return (settings, *(d for _, d in config.devices() if settings.serves(d.name)))


class FoxgloveLink:
    """Owns the publisher; ``on_snapshot`` goes to the poller's holder."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._publisher: FoxglovePublisher | None = None
        self._built_from: tuple[object, ...] = ()

    def apply(self, config: GatewayConfig) -> None:
        """Start, restart or stop the publisher for ``config``; ``OSError`` if the address
        cannot be served (the publisher is then off)."""
        wanted = _served(config)
        with self._lock:
            old = self._publisher
            if old is not None and wanted == self._built_from:
                return
            self._publisher, self._built_from = None, ()
        if old is not None:
            old.stop()
        if config.foxglove is None:
            return
        publisher = FoxglovePublisher(config).start()
        log.info(
            "serving Foxglove on ws://%s:%d (open it in Foxglove: Open connection, Foxglove WebSocket)",
            config.foxglove.host,
            publisher.port,
        )
        with self._lock:
            self._publisher, self._built_from = publisher, wanted

    @property
    def port(self) -> int | None:
        publisher = self._publisher
        return None if publisher is None else publisher.port

    def on_snapshot(self, snapshot: GatewaySnapshot) -> None:
        publisher = self._publisher
        if publisher is not None:
            publisher.on_snapshot(snapshot)

    def stop(self) -> None:
        with self._lock:
            old, self._publisher, self._built_from = self._publisher, None, ()
        if old is not None:
            old.stop()
