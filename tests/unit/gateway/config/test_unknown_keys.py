"""``gateway.keys.check_keys``: the one unknown-key check of the gateway, in each reader's words."""

from __future__ import annotations

from pathlib import Path

import pytest

from gateway.config.editor import parse_assignment
from gateway.config.tables import Context, Table
from gateway.errors import ConfigError
from gateway.keys import UNKNOWN_KEY, check_keys, suggest
from gateway.metrics.web_config import load_web_config


class _Unknown(Exception):
    pass


def _raised(keys: list[str], allowed: tuple[str, ...], template: str = UNKNOWN_KEY) -> _Unknown:
    with pytest.raises(_Unknown) as info:
        check_keys(keys, allowed, lambda key, message: _Unknown(key, message), template)
    return info.value


def test_the_first_unknown_key_is_named_with_the_closest_allowed_one() -> None:
    err = _raised(["port", "adress", "bogus"], ("port", "address"))
    assert err.args == ("adress", "unknown key; did you mean 'address'? (allowed keys: port, address)")
    assert _raised(["zzz"], ("port",)).args == ("zzz", "unknown key (allowed keys: port)")
    check_keys(["port"], ("port", "address"), lambda key, message: _Unknown(key, message))  # all allowed
    assert suggest("prot", ["port"]) == "; did you mean 'port'?" and suggest("x", ["port"]) == ""


def test_a_reader_keeps_its_own_words() -> None:
    assert (
        _raised(["x"], ("a", "b"), "unknown key; allowed: {allowed}").args[1] == "unknown key; allowed: a, b"
    )
    with pytest.raises(_Unknown) as info:
        check_keys(
            ["x_m"], ("x_mm", "r0_ohm"), lambda k, m: _Unknown(m), "{key}{hint}: {allowed}", shown=("x_mm",)
        )
    assert info.value.args == ("'x_m'; did you mean 'x_mm'?: x_mm",)


def test_the_readers_messages_are_unchanged(tmp_path: Path) -> None:
    with pytest.raises(ConfigError) as table:
        Table(Context(Path("c.toml")), {"prot": 1}, "bus[0]", ("port", "baudrate"))
    assert str(table.value) == (
        "c.toml: bus[0].prot: unknown key; did you mean 'port'? (allowed keys: port, baudrate)"
    )
    with pytest.raises(ConfigError) as editor:
        parse_assignment("x_m=1")
    assert str(editor.value) == (
        "unknown key 'x_m'; did you mean 'x_mm'? "
        "(allowed: name, x_mm, y_mm, enabled, effects, override, or a sensor parameter such as r0_ohm)"
    )
    web = tmp_path / "web.yml"
    web.write_text("bogus: 1\n", encoding="utf-8")
    with pytest.raises(ConfigError) as web_err:
        load_web_config(web)
    assert str(web_err.value).startswith(f"{web}: bogus: unknown key; allowed: ")
