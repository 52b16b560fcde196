"""Issue 24 §7: ``check-config`` (``load_web_config``) refuses the response headers that would
break ``run``: a value holding CR or LF, a name that is not an HTTP token, and the headers the
server sets itself (a configured ``Content-Length`` cut every body); each message states the
allowed form."""

from __future__ import annotations

from pathlib import Path

import pytest

from gateway.errors import ConfigError
from gateway.metrics.web_config import load_web_config


def web_config(tmp_path: Path, headers: str) -> Path:
    path = tmp_path / "web.yml"
    path.write_text(f"http_server_config:\n  headers:\n{headers}")
    path.chmod(0o600)
    return path


@pytest.mark.parametrize(
    ("headers", "fragments"),
    [
        ('    X-Evil: "a\\r\\nSet-Cookie: x=1"\n', ("headers.X-Evil", "'\\r'", "no CR or LF")),
        ('    X-Evil: "a\\nb"\n', ("headers.X-Evil", "'\\n'", "printable ASCII")),
        ('    "Bad Name": x\n', ("invalid header name 'Bad Name'", "HTTP token")),
        ('    "X-A:b": x\n', ("invalid header name 'X-A:b'", "HTTP token")),
        ("    Content-Length: 3\n", ("headers.Content-Length", "the server sets Content-Length", "allowed")),
        ("    transfer-encoding: chunked\n", ("headers.transfer-encoding", "allowed")),
        ("    X-Map: {a: 1}\n", ("headers.X-Map", "expected a header value")),
    ],
    ids=["crlf", "lf", "space-in-name", "colon-in-name", "content-length", "transfer-encoding", "mapping"],
)
def test_headers_that_break_run_are_refused(tmp_path: Path, headers: str, fragments: tuple[str, ...]) -> None:
    path = web_config(tmp_path, headers)
    with pytest.raises(ConfigError) as info:
        load_web_config(path)
    message = str(info.value)
    assert message.startswith(f"{path}: http_server_config.headers.")
    for fragment in fragments:
        assert fragment in message, message


def test_ordinary_headers_pass(tmp_path: Path) -> None:
    path = web_config(
        tmp_path,
        "    X-Frame-Options: deny\n"
        "    Content-Security-Policy: \"default-src 'self'; frame-ancestors 'none'\"\n"
        "    Strict-Transport-Security: max-age=31536000\n"
        "    X-Count: 3\n",
    )
    assert dict(load_web_config(path).headers) == {
        "X-Frame-Options": "deny",
        "Content-Security-Policy": "default-src 'self'; frame-ancestors 'none'",
        "Strict-Transport-Security": "max-age=31536000",
        "X-Count": "3",
    }
