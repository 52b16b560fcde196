"""Issue 33 §10: a bcrypt cost above ``MAX_BCRYPT_COST`` is refused when the web config is
loaded (``run``, a reload, ``check-config``), with a message that states the allowed range.

Each step of cost doubles a check: at cost 16 a wrong password took 4 s, and at 31 a running
check would hold a stop for about 32 h."""

from __future__ import annotations

from pathlib import Path

import bcrypt
import pytest
from click.testing import CliRunner

from gateway.cli import main
from gateway.errors import ConfigError
from gateway.metrics.web_config import MAX_BCRYPT_COST, MIN_BCRYPT_COST, load_web_config

#: a well-formed hash at cost 04 (its salt is one bcrypt accepts); the cost is swapped in below
GOOD_04 = "$2b$04$abcdefghijklmnopqrstuu5x5U1jL3S0sqk5v1h3Zk3CqZkS0Q5eW"

CONFIG = """\
[metrics]
address = "127.0.0.1:9830"
web_config = "web.yml"

[[bus]]
name = "bench"
kind = "tcp"
host = "127.0.0.1"
port = 5020

[[bus.device]]
name = "array1"
device_id = 1
profile = "tactile-sim"
channels = 16
"""


def _with_cost(cost: int) -> str:
    return GOOD_04.replace("$04$", f"${cost:02d}$")


def _web(tmp_path: Path, hashed: str) -> Path:
    web = tmp_path / "web.yml"
    web.write_text(f"basic_auth_users:\n  prometheus: '{hashed}'\n", encoding="utf-8")
    web.chmod(0o600)
    return web


def test_the_bound_is_a_cost_whose_check_stays_well_under_a_scrape_timeout() -> None:
    # a check at cost c is 2^c rounds: cost 12 is 64 x cost 6; the bound must keep a queue of
    # a few checks well inside Prometheus' 10 s scrape timeout (0.3 s a check here at 12)
    assert MIN_BCRYPT_COST == 4
    assert 10 <= MAX_BCRYPT_COST <= 12


@pytest.mark.parametrize("cost", [13, 16, 31])
def test_a_cost_above_the_bound_is_refused_stating_the_range(tmp_path: Path, cost: int) -> None:
    hashed = _with_cost(cost)
    web = _web(tmp_path, hashed)
    with pytest.raises(ConfigError) as info:
        load_web_config(web)
    message = str(info.value)
    assert "basic_auth_users.prometheus" in message
    assert f"bcrypt cost {cost}" in message
    assert f"allowed: {MIN_BCRYPT_COST}..{MAX_BCRYPT_COST}" in message
    assert hashed not in message  # a secret is never echoed


def test_check_config_refuses_a_dear_cost_and_accepts_the_bound(tmp_path: Path) -> None:
    cfg = tmp_path / "gateway.toml"
    cfg.write_text(CONFIG, encoding="utf-8")
    cfg.chmod(0o600)
    _web(tmp_path, _with_cost(16))
    result = CliRunner().invoke(main, ["check-config", "-c", str(cfg)])
    assert result.exit_code == 2, result.output
    assert "Traceback" not in result.output
    assert "bcrypt cost 16" in result.output and f"allowed: 4..{MAX_BCRYPT_COST}" in result.output
    # a real hash at the bound (bcrypt made it, so its salt is valid) passes
    real = bcrypt.hashpw(b"s3cret", bcrypt.gensalt(rounds=MAX_BCRYPT_COST)).decode()
    _web(tmp_path, real.replace("$2b$", "$2y$"))
    result = CliRunner().invoke(main, ["check-config", "-c", str(cfg)])
    assert result.exit_code == 0, result.output
