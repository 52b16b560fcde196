"""Metrics: the Prometheus collector over the snapshot and the HTTP server that serves it.

* ``collector``: ``SnapshotCollector`` / ``make_registry`` (the metric families);
* ``web_config``: the exporter-toolkit YAML (TLS, basic auth);
* ``server``: ``MetricsServer``, ``/metrics`` over HTTP(S).
"""

from .collector import SnapshotCollector, make_registry
from .server import MetricsServer
from .web_config import BasicAuth, WebConfig, load_web_config

__all__ = ["BasicAuth", "MetricsServer", "SnapshotCollector", "WebConfig", "load_web_config", "make_registry"]
