"""The exporter-toolkit web configuration: TLS and HTTP basic auth of the /metrics server.

A YAML file in the Prometheus exporter-toolkit format (the subset the gateway supports)::

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

``load_web_config`` validates it (``ConfigError`` naming the file and key), as ``run`` and
``check-config`` both use it: the TLS key must be private to its owner (like web.yml) and
every hash must be a bcrypt hash that bcrypt accepts, at a cost of ``MIN_BCRYPT_COST`` (4) to
``MAX_BCRYPT_COST`` (12). ``BasicAuth`` checks an
``Authorization`` header against the bcrypt hashes (a verified pair is cached). An unknown
user costs one bcrypt check at the highest cost of the configured hashes, as a wrong password
for a real one does (a user whose hash is cheaper has its "no" padded with dummy checks to the
same bcrypt work); passwords are cut to bcrypt's 72 bytes, as Go's bcrypt (exporter-toolkit)
and bcrypt before 5.0 do, so any length gets a plain "no".
"""

from __future__ import annotations

import base64
import binascii
import hashlib
import hmac
import re
import ssl
import stat
import threading
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import bcrypt
import yaml

from ..errors import ConfigError
from ..keys import check_keys
from ..textfile import read_text_file

_CLIENT_AUTH = {
    "NoClientCert": ssl.CERT_NONE,
    "RequestClientCert": ssl.CERT_OPTIONAL,
    "RequireAnyClientCert": ssl.CERT_REQUIRED,
    "VerifyClientCertIfGiven": ssl.CERT_OPTIONAL,
    "RequireAndVerifyClientCert": ssl.CERT_REQUIRED,
}
_TLS_VERSIONS = {"TLS12": ssl.TLSVersion.TLSv1_2, "TLS13": ssl.TLSVersion.TLSv1_3}
#: $2a$/$2b$/$2y$, a two-digit cost, 22 characters of salt and 31 of hash (bcrypt's base64)
_BCRYPT_HASH = re.compile(r"\$2[aby]\$(\d\d)\$[./A-Za-z0-9]{53}")
#: bcrypt uses the first 72 bytes of a password; the rest never counted
BCRYPT_MAX_PASSWORD_BYTES = 72
#: the costs (log2 rounds) a hash may have: bcrypt's lowest, and one whose check takes about
#: 0.3 s on one core. Each step doubles a check: at 16 a wrong password costs 4 s, so a few
#: queued guesses hold unverified scrapers past their timeout, and a stop waits for a running
#: check (about 32 h at bcrypt's own limit of 31)
MIN_BCRYPT_COST = 4
MAX_BCRYPT_COST = 12
#: an HTTP header name: an RFC 9110 token
_HEADER_NAME = re.compile(r"[!#$%&'*+\-.^_`|~0-9A-Za-z]+")
_HEADER_NAME_RULE = "letters, digits and !#$%&'*+-.^_`|~ (an HTTP token), e.g. X-Frame-Options"
#: a header value: printable ASCII, spaces and tabs (never CR or LF, which would end the header)
_HEADER_VALUE = re.compile(r"[\t\x20-\x7e]*")
#: headers the server itself sets to frame the body or run the connection: configured, they
#: would cut or corrupt every response
_SERVER_HEADERS = (
    "Connection",
    "Content-Encoding",
    "Content-Length",
    "Content-Type",
    "Keep-Alive",
    "Proxy-Connection",
    "TE",
    "Trailer",
    "Transfer-Encoding",
    "Upgrade",
)


def bcrypt_cost(hashed: bytes) -> int:
    """The cost (log2 rounds) of a bcrypt hash that ``load_web_config`` accepted."""
    return int(hashed[4:6])


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
    check_keys(
        table,
        tuple(allowed),
        lambda key, message: _web_error(path, f"{where}.{key}" if where else str(key), message),
        "unknown key; allowed: {allowed}",
    )


def _check_private_key(path: Path, key: Path) -> None:
    """Refuse a TLS private key that users other than its owner can access (as web.yml)."""
    try:
        mode = stat.S_IMODE(key.stat().st_mode)
    except OSError as exc:
        where, why = "tls_server_config.key_file", exc.strerror or exc
        raise _web_error(path, where, f"cannot access {key}: {why}") from None
    if mode & 0o077:
        raise _web_error(
            path,
            "tls_server_config.key_file",
            f"{key} holds the TLS private key but is accessible to other users (mode {mode:04o}; allowed: "
            f"no group/other permissions, e.g. 0600): run `chmod 600 {key}`",
        )


def _check_hash(path: Path, user: str, hashed: object) -> bytes:
    """A bcrypt hash that bcrypt will accept at login (never echoed: it is a secret)."""
    where = f"basic_auth_users.{user}"
    hint = "e.g. from `htpasswd -nBC 10 \"\" | tr -d ':'`"
    if not isinstance(hashed, str) or not hashed.startswith(("$2a$", "$2b$", "$2y$")):
        raise _web_error(path, where, f"expected a bcrypt hash ($2a$/$2b$/$2y$...) for user {user!r}, {hint}")
    if _BCRYPT_HASH.fullmatch(hashed) is None:
        raise _web_error(
            path,
            where,
            f"malformed bcrypt hash for user {user!r} (expected $2y$<2-digit cost>$ and 53 characters "
            f"of salt and hash; every login would fail), {hint}",
        )
    cost = int(hashed[4:6])
    if not MIN_BCRYPT_COST <= cost <= MAX_BCRYPT_COST:
        raise _web_error(
            path,
            where,
            f"bcrypt cost {cost} for user {user!r} is out of range (allowed: {MIN_BCRYPT_COST}.."
            f"{MAX_BCRYPT_COST}; each step doubles the work of every login, and {MAX_BCRYPT_COST} takes "
            f"about 0.3 s), {hint}",
        )
    # the same salt at the lowest cost: does bcrypt accept it (salt bits)? ~1 ms, not a login
    try:
        bcrypt.checkpw(b"", f"$2b$04${hashed[7:]}".encode())
    except ValueError:
        raise _web_error(
            path, where, f"malformed bcrypt hash for user {user!r} (bcrypt refuses its salt), {hint}"
        ) from None
    return hashed.encode()


def _check_header(path: Path, name: str, value: object) -> str:
    """A header that the server can send as configured, on every response."""
    where = f"http_server_config.headers.{name}"
    if _HEADER_NAME.fullmatch(name) is None:
        raise _web_error(path, where, f"invalid header name {name!r}; allowed: {_HEADER_NAME_RULE}")
    if name.lower() in (h.lower() for h in _SERVER_HEADERS):
        raise _web_error(
            path,
            where,
            f"the server sets {name} itself (it frames the body or runs the connection); allowed: "
            f"any other header, not {', '.join(_SERVER_HEADERS)}",
        )
    if isinstance(value, (dict, list)) or value is None:
        raise _web_error(path, where, "expected a header value (a string)")
    text = str(value)
    if _HEADER_VALUE.fullmatch(text) is None:
        bad = next(c for c in text if _HEADER_VALUE.fullmatch(c) is None)
        raise _web_error(
            path,
            where,
            f"the value holds {bad!r}; allowed: printable ASCII characters, spaces and tabs on one line "
            "(no CR or LF)",
        )
    return text


def _one_line(exc: yaml.YAMLError) -> str:
    """PyYAML's message (several lines with a source excerpt) as one line with its position."""
    problem = getattr(exc, "problem", None) or str(exc).splitlines()[0]
    mark = getattr(exc, "problem_mark", None)
    where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark is not None else ""
    return " ".join(f"{problem}{where}".split())


def load_web_config(path: Path) -> WebConfig:
    """Parse and check a web-config YAML file (``ConfigError`` naming file and key)."""
    text = read_text_file(path, "web config")
    try:
        data = yaml.safe_load(text) or {}
    except yaml.YAMLError as exc:
        raise ConfigError(f"{path}: invalid YAML: {_one_line(exc)}") from None
    except RecursionError:
        raise ConfigError(f"{path}: invalid YAML: lists or mappings nested too deeply") from None
    except ValueError as exc:  # int(): an integer of more than 4300 digits
        raise ConfigError(f"{path}: invalid YAML: {str(exc).split(';')[0]}") from None
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
        _check_private_key(path, key)
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
            users[str(user)] = _check_hash(path, str(user), hashed)
    headers: dict[str, str] = {}
    http = data.get("http_server_config")
    if http is not None:
        if not isinstance(http, dict):
            raise _web_error(path, "http_server_config", "expected a mapping")
        _check_keys(path, "http_server_config", http, ("headers",))
        raw_headers = http.get("headers") or {}
        if not isinstance(raw_headers, dict):
            raise _web_error(path, "http_server_config.headers", "expected a mapping")
        headers = {str(k): _check_header(path, str(k), v) for k, v in raw_headers.items()}
    config = WebConfig(cert, key, client_ca, auth_type, min_version, users, headers)
    try:
        config.ssl_context()
    except (ssl.SSLError, OSError) as exc:
        raise _web_error(path, "tls_server_config", f"cannot load the certificate/key: {exc}") from None
    return config


class BasicAuth:
    """Checks ``Authorization: Basic`` against bcrypt hashes; remembers verified pairs so
    that a scrape every few seconds does not pay a bcrypt check each time.

    ``cached`` is the cheap part (no bcrypt), for the event loop; ``check`` may run bcrypt.
    An unknown user is checked against a dummy hash at the highest cost of the configured
    ones, so that its answer takes as long as a wrong password for a real user. Passwords are
    cut to 72 bytes (bcrypt never used more; bcrypt 5 raises on longer ones).
    """

    def __init__(self, users: Mapping[str, bytes]) -> None:
        self._users = dict(users)
        self._verified: set[bytes] = set()
        self._lock = threading.Lock()
        #: the cost of the dummy hash: that of the dearest configured hash
        self.dummy_cost = max((bcrypt_cost(h) for h in self._users.values()), default=4)
        # salts at each cost up to that one, with a hash no password gives (bcrypt only
        # recomputes and compares)
        self._dummies = {c: bcrypt.gensalt(rounds=c) + b"." * 31 for c in range(4, self.dummy_cost + 1)}
        self._dummy = self._dummies[self.dummy_cost]

    @staticmethod
    def _credentials(header: str | None) -> tuple[str, bytes] | None:
        if not header or not header.startswith("Basic "):
            return None
        try:
            decoded = base64.b64decode(header[6:].strip(), validate=True)
            user_bytes, sep, password = decoded.partition(b":")
            user = user_bytes.decode("utf-8")
        except (binascii.Error, UnicodeDecodeError):
            return None
        if not sep:
            return None
        return user, password

    def _key(self, user: str, password: bytes, hashed: bytes) -> bytes:
        return hashlib.sha256(b"%s\0%s\0%s" % (user.encode(), password, hashed)).digest()

    def cached(self, header: str | None) -> bool:
        """True if this user:password pair was verified before (no bcrypt: cheap)."""
        creds = self._credentials(header)
        if creds is None:
            return False
        hashed = self._users.get(creds[0])
        if hashed is None:
            return False
        key = self._key(creds[0], creds[1], hashed)
        with self._lock:
            return any(hmac.compare_digest(key, k) for k in self._verified)

    def check(self, header: str | None) -> bool:
        """Whether the header carries a configured user and its password (may run bcrypt)."""
        creds = self._credentials(header)
        if creds is None:
            return False
        user, password = creds
        if self.cached(header):
            return True
        hashed = self._users.get(user)
        secret = password[:BCRYPT_MAX_PASSWORD_BYTES]
        try:
            if hashed is None:
                bcrypt.checkpw(secret, self._dummy)  # as dear as a real user's check
                return False
            ok = bcrypt.checkpw(secret, hashed)
            if not ok:
                # a cheaper hash's "no" is padded to the dearest one's work: 2^c + 2^c + ...
                # + 2^(max-1) = 2^max, so no configured user answers faster than an unknown one
                for cost in range(bcrypt_cost(hashed), self.dummy_cost):
                    bcrypt.checkpw(secret, self._dummies[cost])
        except ValueError:  # not expected: hashes are checked at load, passwords cut to 72 bytes
            return False
        if ok:
            with self._lock:
                self._verified.add(self._key(user, password, hashed))
        return ok
