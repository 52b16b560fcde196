"""Prometheus exposition: a custom collector over the latest snapshot, and the /metrics server.

``SnapshotCollector`` builds fresh metric families from the immutable ``GatewaySnapshot``
at every scrape (no state of its own, no timestamps: Prometheus stamps the scrape). It is
registered into a registry the caller passes in. Absent values (open or stale-without-data
channels, no contact for the centre of pressure) are left out, never exported as NaN.

``MetricsServer`` serves ``/metrics`` from a thread (``http.server``), optionally with TLS
and HTTP basic auth configured by a web-config YAML file in the Prometheus
exporter-toolkit format::

    tls_server_config:
      cert_file: server.crt        # relative paths are relative to the YAML file
      key_file: server.key
      client_ca_file: ca.crt       # optional, with client_auth_type
      client_auth_type: RequireAndVerifyClientCert
      min_version: TLS12           # TLS12 (default) or TLS13
    basic_auth_users:
      prometheus: $2y$10$...       # bcrypt hash (htpasswd -nBC 10 "" | tr -d ':')
    http_server_config:
      headers: {X-Frame-Options: deny}
"""

from __future__ import annotations

import base64
import binascii
import hashlib
import hmac
import logging
import math
import socket
import ssl
import sys
import threading
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from typing import Any

import bcrypt
import yaml
from prometheus_client import CONTENT_TYPE_LATEST, CollectorRegistry, generate_latest
from prometheus_client.core import CounterMetricFamily, GaugeMetricFamily, HistogramMetricFamily
from prometheus_client.metrics_core import Metric

from .errors import ConfigError
from .pipeline import READ_ERROR_REASONS, STATUS_LABELS, ChannelStatus, GatewaySnapshot

log = logging.getLogger(__name__)

SnapshotSource = Callable[[], GatewaySnapshot]


def _finite(x: float | None) -> bool:
    return x is not None and math.isfinite(x)


def _bucket_label(bound: float) -> str:
    return "+Inf" if math.isinf(bound) else repr(float(bound))


class SnapshotCollector:
    """Custom collector: every scrape reads the latest snapshot from ``source``."""

    def __init__(self, source: SnapshotSource) -> None:
        self._source = source

    def describe(self) -> Iterable[Metric]:
        return self._families(GatewaySnapshot())

    def collect(self) -> Iterable[Metric]:
        return self._families(self._source())

    @staticmethod
    def _families(snap: GatewaySnapshot) -> list[Metric]:
        from_poll = "from the last poll"
        force = GaugeMetricFamily(
            "tactile_force_newtons",
            f"Drift-corrected force on the channel in newtons (N), {from_poll}; absent when the "
            "channel has no valid value (open, short, error)",
            labels=["device", "channel"],
        )
        static = GaugeMetricFamily(
            "tactile_force_static_newtons",
            f"Force in newtons (N) by static inversion without creep state (diagnostic; overestimates "
            f"held forces as the sensor creeps), {from_poll}",
            labels=["device", "channel"],
        )
        resistance = GaugeMetricFamily(
            "tactile_resistance_ohms",
            f"Sensor resistance in ohms, {from_poll}; absent when open or invalid",
            labels=["device", "channel"],
        )
        status = GaugeMetricFamily(
            "tactile_channel_status",
            f"Channel status, 1 for the current status and 0 for the others (dimensionless), {from_poll}: "
            + ", ".join(STATUS_LABELS),
            labels=["device", "channel", "status"],
        )
        position = GaugeMetricFamily(
            "tactile_channel_position_mm",
            "Position of the channel on the array in millimetres (mm), from the configuration",
            labels=["device", "channel", "axis"],
        )
        up = GaugeMetricFamily(
            "tactile_device_up",
            f"1 if the device answered, 0 if not (dimensionless), {from_poll}",
            labels=["device"],
        )
        last_ok = GaugeMetricFamily(
            "tactile_last_poll_success_timestamp_seconds",
            "Unix time in seconds (s) of the last successful poll of the device",
            labels=["device"],
        )
        duration = HistogramMetricFamily(
            "tactile_poll_duration_seconds",
            "Duration in seconds (s) of successful polls of the device "
            "(all reads plus the CPU time of the conversion)",
            labels=["device"],
        )
        interval = GaugeMetricFamily(
            "tactile_poll_interval_seconds",
            "Configured poll interval of the device's bus in seconds (s)",
            labels=["device"],
        )
        reads = CounterMetricFamily(
            "tactile_reads_total",
            "Modbus read requests attempted for the device (count), retries included, up to the last poll",
            labels=["device"],
        )
        errors = CounterMetricFamily(
            "tactile_read_errors_total",
            "Failed Modbus read requests of the device by reason (count), up to the last poll: "
            "timeout, exception, connection, decode",
            labels=["device", "reason"],
        )
        total = GaugeMetricFamily(
            "tactile_array_total_force_newtons",
            f"Sum of the drift-corrected forces of the channels in contact in newtons (N), {from_poll}",
            labels=["device"],
        )
        cop = GaugeMetricFamily(
            "tactile_array_center_of_pressure_mm",
            f"Force-weighted centre of pressure on the array in millimetres (mm), {from_poll}; "
            "absent when no channel is in contact",
            labels=["device", "axis"],
        )
        area = GaugeMetricFamily(
            "tactile_array_contact_area_square_mm",
            "Contact area in square millimetres (mm^2): channels in contact times pitch squared, "
            + from_poll,
            labels=["device"],
        )
        in_contact = GaugeMetricFamily(
            "tactile_array_channels_in_contact",
            f"Number of channels in contact (count), {from_poll}",
            labels=["device"],
        )
        for name in sorted(snap.devices):
            dev = snap.devices[name]
            for ch in dev.channels():
                labels = [name, ch.name]
                if _finite(ch.force_n):
                    force.add_metric(labels, float(ch.force_n))  # type: ignore[arg-type]
                if _finite(ch.force_static_n):
                    static.add_metric(labels, float(ch.force_static_n))  # type: ignore[arg-type]
                if _finite(ch.resistance_ohm):
                    resistance.add_metric(labels, float(ch.resistance_ohm))  # type: ignore[arg-type]
                for s in ChannelStatus:
                    status.add_metric([*labels, s.label], 1.0 if ch.status == s else 0.0)
                position.add_metric([*labels, "x"], ch.x_mm)
                position.add_metric([*labels, "y"], ch.y_mm)
            up.add_metric([name], 1.0 if dev.up else 0.0)
            if _finite(dev.last_success_timestamp_s):
                last_ok.add_metric([name], float(dev.last_success_timestamp_s))  # type: ignore[arg-type]
            interval.add_metric([name], dev.poll_interval_s)
            total.add_metric([name], dev.total_force_n)
            if dev.center_of_pressure_mm is not None:
                x, y = dev.center_of_pressure_mm
                if math.isfinite(x) and math.isfinite(y):
                    cop.add_metric([name, "x"], x)
                    cop.add_metric([name, "y"], y)
            area.add_metric([name], dev.contact_area_mm2)
            in_contact.add_metric([name], float(dev.channels_in_contact))
            counters = snap.counters.get(name)
            if counters is not None:
                reads.add_metric([name], float(counters.reads_total))
                for reason in READ_ERROR_REASONS:
                    errors.add_metric([name, reason], float(counters.read_errors_total.get(reason, 0)))
                h = counters.poll_duration
                buckets = [
                    (_bucket_label(b), float(c))
                    for b, c in zip((*h.bounds, math.inf), h.bucket_counts, strict=True)
                ]
                duration.add_metric([name], buckets, h.sum)
        return [
            force,
            static,
            resistance,
            status,
            position,
            up,
            last_ok,
            duration,
            interval,
            reads,
            errors,
            total,
            cop,
            area,
            in_contact,
        ]


def make_registry(source: SnapshotSource, registry: CollectorRegistry | None = None) -> CollectorRegistry:
    """Register a ``SnapshotCollector`` into ``registry`` (a new one if None) and return it."""
    reg = registry if registry is not None else CollectorRegistry(auto_describe=False)
    reg.register(SnapshotCollector(source))
    return reg


# --------------------------------------------------------------------------- web config
_CLIENT_AUTH = {
    "NoClientCert": ssl.CERT_NONE,
    "RequestClientCert": ssl.CERT_OPTIONAL,
    "RequireAnyClientCert": ssl.CERT_REQUIRED,
    "VerifyClientCertIfGiven": ssl.CERT_OPTIONAL,
    "RequireAndVerifyClientCert": ssl.CERT_REQUIRED,
}
_TLS_VERSIONS = {"TLS12": ssl.TLSVersion.TLSv1_2, "TLS13": ssl.TLSVersion.TLSv1_3}


@dataclass(frozen=True)
class WebConfig:
    """Exporter-toolkit web configuration (the subset the gateway supports)."""

    cert_file: Path | None = None
    key_file: Path | None = None
    client_ca_file: Path | None = None
    client_auth_type: str = "NoClientCert"
    min_version: str = "TLS12"
    basic_auth_users: Mapping[str, bytes] = field(default_factory=dict)
    headers: Mapping[str, str] = field(default_factory=dict)

    @property
    def tls(self) -> bool:
        return self.cert_file is not None

    def ssl_context(self) -> ssl.SSLContext | None:
        if self.cert_file is None:
            return None
        ctx = ssl.SSLContext(ssl.PROTOCOL_TLS_SERVER)
        ctx.minimum_version = _TLS_VERSIONS[self.min_version]
        ctx.load_cert_chain(str(self.cert_file), str(self.key_file) if self.key_file else None)
        ctx.verify_mode = _CLIENT_AUTH[self.client_auth_type]
        if self.client_ca_file is not None:
            ctx.load_verify_locations(cafile=str(self.client_ca_file))
        return ctx


def _web_error(path: Path, key: str, message: str) -> ConfigError:
    return ConfigError(f"{path}: {key}: {message}")


def _check_keys(path: Path, where: str, table: Mapping[str, Any], allowed: Iterable[str]) -> None:
    allowed = tuple(allowed)
    for key in table:
        if key not in allowed:
            raise _web_error(
                path, f"{where}.{key}" if where else str(key), f"unknown key; allowed: {', '.join(allowed)}"
            )


def load_web_config(path: Path) -> WebConfig:
    """Parse and check a web-config YAML file (``ConfigError`` naming file and key)."""
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read web config: {exc}") from None
    try:
        data = yaml.safe_load(text) or {}
    except yaml.YAMLError as exc:
        raise ConfigError(f"{path}: invalid YAML: {exc}") from None
    if not isinstance(data, dict):
        raise ConfigError(f"{path}: expected a mapping at the top level")
    _check_keys(path, "", data, ("tls_server_config", "basic_auth_users", "http_server_config"))
    base = path.parent

    def file_key(table: Mapping[str, Any], where: str, key: str) -> Path | None:
        value = table.get(key)
        if value is None:
            return None
        if not isinstance(value, str) or not value:
            raise _web_error(path, f"{where}.{key}", "expected a file path")
        p = Path(value)
        p = p if p.is_absolute() else base / p
        if not p.is_file():
            raise _web_error(path, f"{where}.{key}", f"{p} does not exist")
        return p

    cert = key = client_ca = None
    auth_type, min_version = "NoClientCert", "TLS12"
    tls = data.get("tls_server_config")
    if tls is not None:
        if not isinstance(tls, dict):
            raise _web_error(path, "tls_server_config", "expected a mapping")
        _check_keys(
            path,
            "tls_server_config",
            tls,
            ("cert_file", "key_file", "client_ca_file", "client_auth_type", "min_version"),
        )
        cert = file_key(tls, "tls_server_config", "cert_file")
        key = file_key(tls, "tls_server_config", "key_file")
        client_ca = file_key(tls, "tls_server_config", "client_ca_file")
        if cert is None or key is None:
            raise _web_error(path, "tls_server_config", "cert_file and key_file are both required")
        auth_type = str(tls.get("client_auth_type", "NoClientCert"))
        if auth_type not in _CLIENT_AUTH:
            raise _web_error(
                path,
                "tls_server_config.client_auth_type",
                f"{auth_type!r}; allowed: {', '.join(_CLIENT_AUTH)}",
            )
        if auth_type == "RequireAndVerifyClientCert" and client_ca is None:
            raise _web_error(path, "tls_server_config.client_ca_file", f"required with {auth_type}")
        min_version = str(tls.get("min_version", "TLS12"))
        if min_version not in _TLS_VERSIONS:
            raise _web_error(
                path, "tls_server_config.min_version", f"{min_version!r}; allowed: {', '.join(_TLS_VERSIONS)}"
            )
    users: dict[str, bytes] = {}
    raw_users = data.get("basic_auth_users")
    if raw_users is not None:
        if not isinstance(raw_users, dict):
            raise _web_error(path, "basic_auth_users", "expected a mapping of user: bcrypt hash")
        for user, hashed in raw_users.items():
            if not isinstance(hashed, str) or not hashed.startswith(("$2a$", "$2b$", "$2y$")):
                raise _web_error(
                    path, f"basic_auth_users.{user}", "expected a bcrypt hash ($2a$/$2b$/$2y$...)"
                )
            users[str(user)] = hashed.encode()
    headers: dict[str, str] = {}
    http = data.get("http_server_config")
    if http is not None:
        if not isinstance(http, dict):
            raise _web_error(path, "http_server_config", "expected a mapping")
        _check_keys(path, "http_server_config", http, ("headers",))
        raw_headers = http.get("headers") or {}
        if not isinstance(raw_headers, dict):
            raise _web_error(path, "http_server_config.headers", "expected a mapping")
        headers = {str(k): str(v) for k, v in raw_headers.items()}
    config = WebConfig(cert, key, client_ca, auth_type, min_version, users, headers)
    try:
        config.ssl_context()
    except (ssl.SSLError, OSError) as exc:
        raise _web_error(path, "tls_server_config", f"cannot load the certificate/key: {exc}") from None
    return config


class BasicAuth:
    """Checks ``Authorization: Basic`` against bcrypt hashes; remembers verified pairs so
    that a scrape every few seconds does not pay a bcrypt check each time."""

    _DUMMY = bcrypt.hashpw(b"not a password", bcrypt.gensalt(rounds=4))

    def __init__(self, users: Mapping[str, bytes]) -> None:
        self._users = dict(users)
        self._verified: set[bytes] = set()
        self._lock = threading.Lock()

    def check(self, header: str | None) -> bool:
        if not header or not header.startswith("Basic "):
            return False
        try:
            decoded = base64.b64decode(header[6:].strip(), validate=True).decode("utf-8")
        except (binascii.Error, UnicodeDecodeError):
            return False
        user, sep, password = decoded.partition(":")
        if not sep:
            return False
        hashed = self._users.get(user)
        key = hashlib.sha256(b"%s\0%s\0%s" % (user.encode(), password.encode(), hashed or b"")).digest()
        with self._lock:
            if hashed is not None and any(hmac.compare_digest(key, k) for k in self._verified):
                return True
        if hashed is None:
            bcrypt.checkpw(password.encode(), self._DUMMY)  # same cost for unknown users
            return False
        try:
            ok = bcrypt.checkpw(password.encode(), hashed)
        except ValueError:
            return False
        if ok:
            with self._lock:
                self._verified.add(key)
        return ok


# --------------------------------------------------------------------------- HTTP server
class _Server(ThreadingHTTPServer):
    # handler threads are joined by server_close (each is bounded by the handler timeout)
    daemon_threads = False
    block_on_close = True
    allow_reuse_address = True
    ssl_context: ssl.SSLContext | None = None

    def handle_error(self, request: Any, client_address: Any) -> None:
        exc = sys.exc_info()[1]
        if isinstance(exc, ssl.SSLError | ConnectionError | TimeoutError):
            # failed handshakes, plain HTTP on a TLS port, clients that hang up
            log.debug("http %s: %s", client_address[0], exc)
        else:
            log.error("http %s: error while serving", client_address[0], exc_info=exc)

    def get_request(self) -> tuple[socket.socket, Any]:
        sock, addr = super().get_request()
        if self.ssl_context is not None:
            # the handshake runs in the handler thread, so a slow client cannot block accept
            sock = self.ssl_context.wrap_socket(sock, server_side=True, do_handshake_on_connect=False)
        return sock, addr


class MetricsServer:
    """Serves ``registry`` on ``http(s)://host:port/metrics`` from a background thread."""

    def __init__(
        self,
        registry: CollectorRegistry,
        host: str = "127.0.0.1",
        port: int = 9830,
        web_config: WebConfig | None = None,
    ) -> None:
        self.registry = registry
        self.web_config = web_config or WebConfig()
        self._auth = BasicAuth(self.web_config.basic_auth_users) if self.web_config.basic_auth_users else None
        family = socket.AF_INET6 if ":" in host else socket.AF_INET
        server_cls = type("_BoundServer", (_Server,), {"address_family": family})
        self._httpd: _Server = server_cls((host, port), self._handler_class())
        self._httpd.ssl_context = self.web_config.ssl_context()
        self._thread: threading.Thread | None = None

    @property
    def host(self) -> str:
        return str(self._httpd.server_address[0])

    @property
    def port(self) -> int:
        return int(self._httpd.server_address[1])

    @property
    def url(self) -> str:
        scheme = "https" if self.web_config.tls else "http"
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"{scheme}://{host}:{self.port}/metrics"

    def _handler_class(self) -> type[BaseHTTPRequestHandler]:
        server = self

        class Handler(BaseHTTPRequestHandler):
            server_version = "tactile-gateway"
            timeout = 10.0

            def log_message(self, format: str, *args: Any) -> None:
                log.debug("http %s - " + format, self.client_address[0], *args)

            def _send(self, code: int, body: bytes, content_type: str, extra: Mapping[str, str] = {}) -> None:
                self.send_response(code)
                self.send_header("Content-Type", content_type)
                self.send_header("Content-Length", str(len(body)))
                for k, v in {**server.web_config.headers, **extra}.items():
                    self.send_header(k, v)
                self.end_headers()
                if self.command != "HEAD":
                    self.wfile.write(body)

            def do_GET(self) -> None:
                if server._auth is not None and not server._auth.check(self.headers.get("Authorization")):
                    self._send(
                        401,
                        b"Unauthorized\n",
                        "text/plain; charset=utf-8",
                        {"WWW-Authenticate": 'Basic realm="tactile-gateway"'},
                    )
                    return
                path = self.path.split("?", 1)[0]
                if path == "/metrics":
                    try:
                        body = generate_latest(server.registry)
                    except Exception:
                        log.exception("building the metrics failed")
                        self._send(500, b"metrics collection failed\n", "text/plain; charset=utf-8")
                        return
                    self._send(200, body, CONTENT_TYPE_LATEST)
                elif path == "/":
                    page = (
                        b'<html><body><h1>tactile-gateway</h1><a href="/metrics">metrics</a></body></html>\n'
                    )
                    self._send(200, page, "text/html; charset=utf-8")
                else:
                    self._send(404, b"Not found\n", "text/plain; charset=utf-8")

            do_HEAD = do_GET

        return Handler

    def start(self) -> MetricsServer:
        if self._thread is None:
            self._thread = threading.Thread(
                target=self._httpd.serve_forever,
                kwargs={"poll_interval": 0.2},
                name="tactile-metrics",
                daemon=True,
            )
            self._thread.start()
            log.info("serving metrics on %s", self.url)
        return self

    def stop(self) -> None:
        """Stop serving and close the socket; joins the server thread."""
        if self._thread is not None:
            self._httpd.shutdown()
            self._thread.join(timeout=5.0)
            self._thread = None
        self._httpd.server_close()

    def __enter__(self) -> MetricsServer:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()
