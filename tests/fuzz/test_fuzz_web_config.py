"""Fuzzing the web-config loader ``gateway.metrics.web_config.load_web_config`` (issue 16 §3):
random YAML documents built from the real keys, random text and random bytes. Only
``ConfigError`` may escape, its first line naming the file.

The loader's "invalid YAML" refusal quotes PyYAML's message, which spans lines (the problem,
then where it is); those are counted apart ("refused, several lines") so the report shows
them, and only their first line is held to the rule.
"""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml
from fuzz_support import FUZZ, Tally
from hypothesis import given, settings
from hypothesis import strategies as st

from gateway.errors import ConfigError
from gateway.metrics.web_config import WebConfig, load_web_config

FILES = ["cert.pem", "key.pem", "ca.pem", "missing.pem", "", "/", ".", "/dev/null", "sub", "\x00x"]
scalars = st.one_of(
    st.sampled_from(FILES),
    st.sampled_from(
        [
            "NoClientCert",
            "RequireAndVerifyClientCert",
            "RequestClientCert",
            "TLS12",
            "TLS13",
            "TLS10",
            "$2b$12$" + "a" * 53,
            "$2y$10$short",
            "$2a$",
            "plain",
            "deny",
        ]
    ),
    st.none(),
    st.booleans(),
    st.integers(),
    st.floats(),
    st.text(max_size=20),
)
values = st.recursive(
    scalars,
    lambda inner: st.one_of(
        st.lists(inner, max_size=3),
        st.dictionaries(st.one_of(st.text(max_size=8), st.integers()), inner, max_size=3),
    ),
    max_leaves=8,
)
TLS_KEYS = ["cert_file", "key_file", "client_ca_file", "client_auth_type", "min_version", "bogus"]
documents = st.one_of(
    values,
    st.fixed_dictionaries(
        {},
        optional={
            "tls_server_config": st.one_of(
                values, st.dictionaries(st.sampled_from(TLS_KEYS), values, max_size=6)
            ),
            "basic_auth_users": st.one_of(values, st.dictionaries(st.text(max_size=8), values, max_size=3)),
            "http_server_config": st.one_of(
                values,
                st.fixed_dictionaries({}, optional={"headers": values, "bogus": values}),
            ),
            "bogus": values,
        },
    ),
)


@pytest.fixture
def web_dir(tmp_path: Path) -> Path:
    """A directory with files the documents name: PEM-looking garbage, an empty file."""
    (tmp_path / "cert.pem").write_text("-----BEGIN CERTIFICATE-----\nnot one\n-----END CERTIFICATE-----\n")
    (tmp_path / "key.pem").write_bytes(b"\x00\xff garbage")
    (tmp_path / "ca.pem").write_text("")
    (tmp_path / "sub").mkdir()
    return tmp_path


def check(tally: Tally, path: Path) -> None:
    try:
        config = load_web_config(path)
    except ConfigError as exc:
        message = str(exc)
        first = message.split("\n", 1)[0]
        assert first.startswith(f"{path}: "), f"the first line does not name the file: {message!r}"
        tally("refused" if "\n" not in message else "refused, several lines")
        return
    assert isinstance(config, WebConfig)
    tally("accepted")


def test_fuzz_yaml_documents(web_dir: Path) -> None:
    tally = Tally("web config: random YAML documents")
    path = web_dir / "web.yml"

    @settings(FUZZ, max_examples=300)
    @given(documents)
    def run(document: object) -> None:
        try:
            text = yaml.safe_dump(document, allow_unicode=True)
        except yaml.YAMLError:
            tally("not writable as YAML")
            return
        path.write_text(text, encoding="utf-8")
        check(tally, path)

    run()
    tally.report()


def test_fuzz_yaml_text(web_dir: Path) -> None:
    tally = Tally("web config: random text")
    path = web_dir / "web.yml"
    lines = st.sampled_from(
        [
            "tls_server_config:",
            "  cert_file: cert.pem",
            "  key_file: key.pem",
            "basic_auth_users:",
            "  u: $2b$12$abc",
            "http_server_config:",
            "  headers:",
            "    X: y",
            "- a",
            "&a [*a]",
            "*b",
            "{",
            "}",
            "? x",
            "!!python/object:os.system",
            "!!binary AAAA",
            "%YAML 1.1",
            "---",
            "...",
            "\t",
            "key: 'unclosed",
        ]
    )

    @settings(FUZZ, max_examples=300)
    @given(st.one_of(st.lists(st.one_of(lines, st.text(max_size=12)), max_size=10).map("\n".join), st.text()))
    def run(text: str) -> None:
        path.write_text(text, encoding="utf-8", errors="surrogatepass")
        check(tally, path)

    run()
    tally.report()


def test_fuzz_yaml_bytes(web_dir: Path) -> None:
    """Random bytes: the file is read as UTF-8, and bytes that are not refuse as ConfigError."""
    tally = Tally("web config: random bytes")
    path = web_dir / "web.yml"

    @settings(FUZZ, max_examples=250)
    @given(
        st.one_of(st.binary(max_size=100), st.binary(max_size=20).map(lambda b: b"basic_auth_users:\n  " + b))
    )
    def run(data: bytes) -> None:
        path.write_bytes(data)
        check(tally, path)

    run()
    tally.report()


def test_non_utf8_web_config_is_a_config_error(web_dir: Path) -> None:
    """The fuzz's smallest failing case, as a plain test (it was a UnicodeDecodeError)."""
    path = web_dir / "web.yml"
    path.write_bytes(b"\x80")
    with pytest.raises(ConfigError, match=r"web\.yml: not UTF-8 text \(byte 0\)"):
        load_web_config(path)


def test_invalid_yaml_is_refused_in_one_line(web_dir: Path) -> None:
    path = web_dir / "web.yml"
    path.write_text("basic_auth_users:\n  u: [\n", encoding="utf-8")
    with pytest.raises(ConfigError) as caught:
        load_web_config(path)
    assert "\n" not in str(caught.value), str(caught.value)
