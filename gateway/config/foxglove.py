"""The optional ``[foxglove]`` section: serve live frames over Foxglove's WebSocket protocol
(``docs/foxglove.md``).

Off unless the section is present. Keys: ``host`` (the address to listen on, default
``127.0.0.1``: this machine only), ``port`` (default 8765, Foxglove's; 0 lets the system pick
one, which the log says), ``devices`` (the names of the devices to serve; absent: all) and
``queue_frames`` (the bounded hand-off between polling and the server: the oldest frames are
dropped and counted when it is full).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Final

from ..errors import ConfigError
from .tables import Context, Table

__all__ = ["DEFAULT_FOXGLOVE_PORT", "FoxgloveConfig", "parse_foxglove"]

DEFAULT_FOXGLOVE_PORT: Final = 8765
MAX_QUEUE_FRAMES: Final = 100_000
_KEYS: Final = ("host", "port", "devices", "queue_frames")


@dataclass(frozen=True)
class FoxgloveConfig:
    """Where the Foxglove WebSocket server listens and what it serves (module docstring);
    ``devices`` None means every device."""

    host: str = "127.0.0.1"
    port: int = DEFAULT_FOXGLOVE_PORT
    devices: tuple[str, ...] | None = None
    queue_frames: int = 100

    def __post_init__(self) -> None:
        if not isinstance(self.host, str) or not self.host or any(c.isspace() for c in self.host):
            raise ConfigError(f"foxglove: host: {self.host!r} is not a host name or IP address")
        if isinstance(self.port, bool) or not isinstance(self.port, int) or not 0 <= self.port <= 65535:
            raise ConfigError(f"foxglove: port: {self.port!r} is out of range; allowed: 0..65535")
        if not 1 <= self.queue_frames <= MAX_QUEUE_FRAMES:
            raise ConfigError(
                f"foxglove: queue_frames: {self.queue_frames!r} is out of range; "
                f"allowed: 1..{MAX_QUEUE_FRAMES}"
            )

    def serves(self, device: str) -> bool:
        return self.devices is None or device in self.devices


def parse_foxglove(ctx: Context, root: Table, device_names: tuple[str, ...]) -> FoxgloveConfig | None:
    """The ``[foxglove]`` table, or None when absent; ``device_names`` are the configured
    devices (``devices`` may name only those)."""
    if not root.has("foxglove"):
        return None
    table = root.table("foxglove", _KEYS, "[foxglove]")
    host = table.string("host", "127.0.0.1", "the address to listen on, such as 127.0.0.1 or 0.0.0.0")
    assert host is not None  # a default is given
    if not host or any(c.isspace() for c in host):
        raise table.error("host", f"{host!r} is not a host name or IP address")
    port = table.integer("port", DEFAULT_FOXGLOVE_PORT, 0, 65535, " (0: any free port)")
    devices: tuple[str, ...] | None = None
    if table.has("devices"):
        value = table.data["devices"]
        if not isinstance(value, list) or not value or not all(isinstance(v, str) for v in value):
            raise table.error("devices", 'expected a non-empty list of device names, such as ["hand"]')
        unknown = [v for v in value if v not in device_names]
        if unknown:
            raise table.error(
                "devices",
                f"no device called {', '.join(repr(u) for u in unknown)}; "
                f"allowed: {', '.join(repr(d) for d in device_names)}",
            )
        if len(set(value)) != len(value):
            raise table.error("devices", "a device is named twice")
        devices = tuple(value)
    queue = table.integer("queue_frames", 100, 1, MAX_QUEUE_FRAMES, " frames")
    return FoxgloveConfig(host, port, devices, queue)
