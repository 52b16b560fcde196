"""Issue 16 §5 (security of the /metrics server): basic auth that reveals no usernames and
takes any password length, a private TLS key, and malformed bcrypt hashes refused at load."""

from __future__ import annotations

import base64
import subprocess
import time
from collections.abc import Callable
from pathlib import Path

import bcrypt
import pytest

from gateway.errors import ConfigError
from gateway.metrics.web_config import BasicAuth, load_web_config


def header(user: str, password: str | bytes) -> str:
    pw = password.encode() if isinstance(password, str) else password
    return "Basic " + base64.b64encode(user.encode() + b":" + pw).decode()


@pytest.fixture
def bcrypt_costs(monkeypatch: pytest.MonkeyPatch) -> list[int]:
    """The cost of every hash bcrypt.checkpw is asked to check (the bcrypt work done)."""
    costs: list[int] = []
    real = bcrypt.checkpw

    def spy(password: bytes, hashed: bytes) -> bool:
        costs.append(int(hashed[4:6]))
        return real(password, hashed)

    monkeypatch.setattr(bcrypt, "checkpw", spy)
    return costs


def test_an_unknown_user_costs_the_bcrypt_work_of_a_real_one(bcrypt_costs: list[int]) -> None:
    real = bcrypt.hashpw(b"s3cret", bcrypt.gensalt(rounds=9)).replace(b"$2b$", b"$2y$")
    cheap = bcrypt.hashpw(b"other", bcrypt.gensalt(rounds=4))
    auth = BasicAuth({"prom": real, "ci": cheap})
    bcrypt_costs.clear()
    assert not auth.check(header("prom", "wrong"))
    assert not auth.check(header("nobody", "wrong"))
    assert not auth.check(header("admin", "s3cret"))
    assert bcrypt_costs == [9, 9, 9]  # the unknown users cost the dearest configured hash
    # a wrong password for the cheaper user is padded to the same work: 2^4 + 2^4 + ... + 2^8 = 2^9
    bcrypt_costs.clear()
    assert not auth.check(header("ci", "wrong"))
    assert bcrypt_costs == [4, 4, 5, 6, 7, 8]
    assert sum(2**c for c in bcrypt_costs) == 2**9
    # a right password is not padded (it reveals nothing an attacker did not know)
    bcrypt_costs.clear()
    assert auth.check(header("ci", "other"))
    assert bcrypt_costs == [4]


def _fastest(check: Callable[[], object], tries: int = 4) -> float:
    best = float("inf")
    for _ in range(tries):
        t0 = time.perf_counter()
        check()
        best = min(best, time.perf_counter() - t0)
    return best


def test_an_unknown_user_takes_about_as_long_as_a_wrong_password() -> None:
    # cost 10 (~60 ms): the old dummy (cost 4) took ~1/64 of it; the fastest of a few tries
    # resists a busy machine, and the bound is generous
    auth = BasicAuth({"prom": bcrypt.hashpw(b"s3cret", bcrypt.gensalt(rounds=10))})
    known = _fastest(lambda: auth.check(header("prom", "wrong")))
    unknown = _fastest(lambda: auth.check(header("nobody", "wrong")))
    assert unknown > 0.4 * known, (unknown, known)


def test_any_password_length_gets_a_plain_no_without_revealing_the_user(bcrypt_costs: list[int]) -> None:
    password = b"p" * 72
    hashed = bcrypt.hashpw(password, bcrypt.gensalt(rounds=5))
    auth = BasicAuth({"prom": hashed})
    bcrypt_costs.clear()
    for length in (73, 100, 1000, 100_000):
        assert not auth.check(header("nobody", b"x" * length))  # was: ValueError from bcrypt
        assert not auth.check(header("prom", b"x" * length))
    # unknown and known users did the same bcrypt work for every length
    assert bcrypt_costs == [5] * 8
    # bcrypt (Go's as in exporter-toolkit, Python's before 5.0) only ever used 72 bytes: the same
    # answer for a longer password that starts with the right 72 bytes
    assert auth.check(header("prom", password + b"tail"))
    assert auth.check(header("prom", password))


def test_malformed_bcrypt_hashes_are_refused_at_load_naming_the_user(tmp_path: Path) -> None:
    good = "$2b$04$abcdefghijklmnopqrstuu5x5U1jL3S0sqk5v1h3Zk3CqZkS0Q5eW"
    web = tmp_path / "web.yml"
    for bad in (
        good[:40],  # truncated (a copy-paste cut)
        good + "x",  # too long
        good.replace("$04$", "$4$"),  # one-digit cost
        good.replace("$04$", "$99$"),  # cost out of range
        good[:10] + "!" + good[11:],  # not bcrypt's base64
        good[:28] + "v" + good[29:],  # salt with stray bits: bcrypt refuses it at every login
    ):
        web.write_text(f"basic_auth_users:\n  ok: '{good}'\n  prometheus: '{bad}'\n")
        with pytest.raises(ConfigError, match=r"basic_auth_users\.prometheus.*'prometheus'") as info:
            load_web_config(web)
        assert bad not in str(info.value)  # the hash is not echoed
    web.write_text("basic_auth_users:\n  prometheus: hunter2\n")
    with pytest.raises(ConfigError, match=r"basic_auth_users\.prometheus: expected a bcrypt hash"):
        load_web_config(web)
    web.write_text(f"basic_auth_users:\n  prometheus: '{good.replace('$2b$', '$2y$')}'\n")
    assert set(load_web_config(web).basic_auth_users) == {"prometheus"}


@pytest.fixture(scope="module")
def cert_and_key(tmp_path_factory: pytest.TempPathFactory) -> Path:
    where = tmp_path_factory.mktemp("tls")
    subprocess.run(
        ["openssl", "req", "-x509", "-newkey", "rsa:2048", "-nodes", "-keyout", "server.key", "-out",
         "server.crt", "-days", "2", "-subj", "/CN=127.0.0.1"],
        cwd=where, check=True, capture_output=True, timeout=60,
    )  # fmt: skip
    return where


@pytest.mark.parametrize("mode", [0o644, 0o640, 0o604, 0o660], ids=oct)
def test_a_tls_key_others_can_read_is_refused(cert_and_key: Path, tmp_path: Path, mode: int) -> None:
    key = tmp_path / "server.key"
    key.write_bytes((cert_and_key / "server.key").read_bytes())
    key.chmod(mode)
    web = tmp_path / "web.yml"
    cert = cert_and_key / "server.crt"
    web.write_text(f"tls_server_config:\n  cert_file: {cert}\n  key_file: server.key\n")
    with pytest.raises(ConfigError) as info:
        load_web_config(web)
    message = str(info.value)
    assert "tls_server_config.key_file" in message and str(key) in message
    assert f"mode {mode:04o}" in message and f"chmod 600 {key}" in message
    key.chmod(0o600)
    assert load_web_config(web).tls
