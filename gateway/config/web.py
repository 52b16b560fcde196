"""The ``[web]`` section: what the page's server keeps of every device's past.

Keys: ``history_s`` (s, 0..3600, default 300; 0: none), the span of the per-poll summaries the
gateway keeps for ``/api/devices/{name}/history`` (total, peak, contact area, centre of
pressure and each region of interest's figures: no per-channel values), and ``export_s``
(s, 0..600, default 60; 0: none), the span of per-channel readings it keeps for
``/api/devices/{name}/export.csv`` (``docs/web.md``). Both are bounded in memory whatever the
poll rate (``web.hub``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Final

from ..errors import ConfigError
from ..model.params import Interval
from .tables import Context, Table

__all__ = ["EXPORT_S", "HISTORY_S", "WebSettings", "parse_web"]

HISTORY_S: Final = Interval(0.0, 3600.0, low_inclusive=True)
EXPORT_S: Final = Interval(0.0, 600.0, low_inclusive=True)
_KEYS: Final = ("history_s", "export_s")


@dataclass(frozen=True)
class WebSettings:
    """The page server's memory of the past (module docstring), in s; 0 turns one off."""

    history_s: float = 300.0
    export_s: float = 60.0

    def __post_init__(self) -> None:
        for key, value, interval in (
            ("history_s", self.history_s, HISTORY_S),
            ("export_s", self.export_s, EXPORT_S),
        ):
            if (
                isinstance(value, bool)
                or not isinstance(value, int | float)
                or not interval.contains(float(value))
            ):
                raise ConfigError(
                    f"web: {key}: {value!r} is out of range; allowed: {interval.describe()} s (0: off)"
                )


def parse_web(ctx: Context, root: Table) -> WebSettings:
    """The ``[web]`` table (every key optional; absent: the defaults)."""
    table = root.table("web", _KEYS, "[web]")
    return WebSettings(
        history_s=table.number("history_s", 300.0, HISTORY_S, " s (0: off)"),
        export_s=table.number("export_s", 60.0, EXPORT_S, " s (0: off)"),
    )
