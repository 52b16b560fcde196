"""Reading TOML tables with precise errors: typed getters that raise ``ConfigError``.

Every message names the file, the key path (``bus[0].device[1].divider.adc_bits``) and the
allowed range or values; an unknown key gets a "did you mean" suggestion.
"""

from __future__ import annotations

import json
import os
import re
import stat
import tomllib
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, Final, TypeVar

from ..errors import ConfigError
from ..keys import check_keys, suggest
from ..model.params import Interval
from ..textfile import MAX_FILE_BYTES, read_text_file

__all__ = [
    "MAX_FILE_BYTES",
    "REQUIRED",
    "Context",
    "Required",
    "Table",
    "join_key",
    "parse_toml",
    "read_text_file",
    "show_value",
    "suggest",
    "type_name",
]

_NAME_RE: Final = re.compile(r"[a-z0-9_-]{1,32}")
_NAME_RULE: Final = "a name matching [a-z0-9_-]{1,32}"
_BARE_KEY_RE: Final = re.compile(r"[A-Za-z0-9_-]+")


class Required:
    def __repr__(self) -> str:
        return "REQUIRED"


REQUIRED: Final = Required()
#: The words a key allows: ``str``, or one ``keys.Choice`` enum's members.
_Word = TypeVar("_Word", bound=str)


def type_name(value: object) -> str:
    if isinstance(value, bool):
        return "boolean"
    if isinstance(value, int):
        return "integer"
    if isinstance(value, float):
        return "float"
    if isinstance(value, str):
        return "string"
    if isinstance(value, list):
        return "array"
    if isinstance(value, dict):
        return "table"
    return "date/time"


def show_value(value: object) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return repr(value)
    if isinstance(value, dict):
        return "{...}"
    if isinstance(value, list):
        return "[...]"
    return str(value)


def join_key(path: str, key: str) -> str:
    # a quoted key as TOML writes it: quotes, backslashes and control characters escaped, so
    # that a message naming it stays one line
    shown = key if _BARE_KEY_RE.fullmatch(key) else json.dumps(key, ensure_ascii=False)
    return f"{path}.{shown}" if path else shown


class Context:
    """What every message needs: the file, and the directory relative paths start from."""

    def __init__(self, source: Path | None) -> None:
        self.source = source
        self.label = str(source) if source is not None else "<string>"
        base = source.parent if source is not None else Path.cwd()
        self.base_dir = Path(os.path.abspath(base))

    def error(self, path: str, message: str) -> ConfigError:
        return ConfigError(f"{self.label}: {path}: {message}" if path else f"{self.label}: {message}")

    def resolve(self, text: str) -> Path:
        p = Path(text).expanduser()
        return Path(os.path.abspath(p if p.is_absolute() else self.base_dir / p))


class Table:
    """A TOML table being read: typed getters that raise ``ConfigError`` with the key path."""

    def __init__(self, ctx: Context, data: Mapping[str, Any], path: str, allowed: Sequence[str]) -> None:
        self.ctx = ctx
        self.data = data
        self.path = path
        check_keys(data, allowed, lambda key, message: ctx.error(join_key(path, key), message))

    def at(self, key: str) -> str:
        return join_key(self.path, key)

    def has(self, key: str) -> bool:
        return key in self.data

    def error(self, key: str, message: str) -> ConfigError:
        return self.ctx.error(self.at(key), message)

    def _get(self, key: str, default: object, expected: str) -> Any:
        if key in self.data:
            return self.data[key]
        if default is REQUIRED:
            raise self.error(key, f"required key is missing; expected {expected}")
        return default

    def _wrong_type(self, key: str, value: object, expected: str) -> ConfigError:
        return self.error(key, f"expected {expected}, got {type_name(value)} {show_value(value)}")

    def integer(self, key: str, default: int | Required, low: int, high: int, unit: str = "") -> int:
        expected = f"an integer in {low}..{high}{unit}"
        value = self._get(key, default, expected)
        if isinstance(value, bool) or not isinstance(value, int):
            raise self._wrong_type(key, value, expected)
        if not low <= value <= high:
            raise self.error(key, f"{value} is out of range; allowed: {low}..{high}{unit}")
        return value

    def optional_address(self, key: str, default: int | None, high: int) -> int | None:
        """An address 0..high, or -1 (or absent with a ``None`` default) for "not present"."""
        expected = f"an integer in 0..{high}, or -1 to disable"
        if key not in self.data:
            return default
        value = self.data[key]
        if isinstance(value, bool) or not isinstance(value, int):
            raise self._wrong_type(key, value, expected)
        if value == -1:
            return None
        if not 0 <= value <= high:
            raise self.error(key, f"{value} is out of range; allowed: 0..{high}, or -1 to disable")
        return value

    def number(self, key: str, default: float | Required, interval: Interval, unit: str = "") -> float:
        expected = f"a number in {interval.describe()}{unit}"
        value = self._get(key, default, expected)
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise self._wrong_type(key, value, expected)
        number = float(value)
        if not interval.contains(number):
            raise self.error(
                key, f"{show_value(value)} is out of range; allowed: {interval.describe()}{unit}"
            )
        return number

    def boolean(self, key: str, default: bool) -> bool:
        value = self._get(key, default, "true or false")
        if not isinstance(value, bool):
            raise self._wrong_type(key, value, "a boolean (true or false)")
        return value

    def string(self, key: str, default: str | Required | None, expected: str = "a string") -> str | None:
        value = self._get(key, default, expected)
        if value is None:
            return None
        if not isinstance(value, str):
            raise self._wrong_type(key, value, expected)
        return value

    def required_string(self, key: str, expected: str = "a string") -> str:
        value = self.string(key, REQUIRED, expected)
        assert value is not None  # a required key is never None
        return value

    def choice(self, key: str, default: str | Required, choices: Sequence[_Word]) -> _Word:
        """The value of ``key``: the one of ``choices`` it spells (a ``keys.Choice`` member
        when they are one enum's), ``default`` (spelt the same) when absent."""
        listed = " | ".join(choices)
        expected = f"one of {listed}"
        value = self._get(key, default, expected)
        if not isinstance(value, str):
            raise self._wrong_type(key, value, expected)
        if value not in choices:
            raise self.error(
                key, f"{value!r} is not allowed{suggest(value, choices, 0.3)} (allowed: {listed})"
            )
        return choices[choices.index(value)]

    def name(self, key: str) -> str:
        value = self.required_string(key, _NAME_RULE)
        if not _NAME_RE.fullmatch(value):
            raise self.error(key, f"{value!r} is not {_NAME_RULE}")
        return value

    def path_value(self, key: str) -> Path | None:
        value = self.string(key, None, "a file path (string)")
        if value is None:
            return None
        if not value.strip():
            raise self.error(key, "expected a file path, got an empty string")
        return self.ctx.resolve(value)

    def table(self, key: str, allowed: Sequence[str], header: str) -> Table:
        value = self.data.get(key, {})
        if not isinstance(value, dict):
            raise self._wrong_type(key, value, f"a table ({header})")
        return Table(self.ctx, value, self.at(key), allowed)

    def raw_table(self, key: str, header: str) -> dict[str, Any]:
        value = self.data.get(key, {})
        if not isinstance(value, dict):
            raise self._wrong_type(key, value, f"a table ({header})")
        return value

    def tables(self, key: str, header: str) -> list[tuple[str, dict[str, Any]]]:
        """An array of tables, as (key path, table) pairs."""
        value = self.data.get(key, [])
        if isinstance(value, dict):
            raise self.error(
                key, f"expected an array of tables ({header}), got a single table; write {header}"
            )
        if not isinstance(value, list):
            raise self._wrong_type(key, value, f"an array of tables ({header})")
        out: list[tuple[str, dict[str, Any]]] = []
        for i, item in enumerate(value):
            if not isinstance(item, dict):
                raise self.ctx.error(
                    f"{self.at(key)}[{i}]", f"expected a table, got {type_name(item)} {show_value(item)}"
                )
            out.append((f"{self.at(key)}[{i}]", item))
        return out


def parse_toml(ctx: Context, text: str, what: str) -> dict[str, Any]:
    """The TOML ``text`` of a ``what`` (a leading UTF-8 byte order mark is allowed); every
    parse failure, including those tomllib does not report as TOML errors (an integer of more
    than 4300 digits, values nested too deeply), is a ``ConfigError`` naming the file."""
    text = text.removeprefix("\ufeff")
    try:
        return tomllib.loads(text)
    except RecursionError:
        raise ctx.error(
            "", f"invalid {what}: arrays or inline tables nested too deeply for TOML to be read"
        ) from None
    except tomllib.TOMLDecodeError as exc:
        message = str(exc)
        found = re.search(r"\s*\(at line (\d+), column (\d+)\)$", message)
        if found:
            reason = message[: found.start()]
            raise ctx.error("", f"invalid TOML at line {found[1]}, column {found[2]}: {reason}") from None
        if "end of document" in message:
            line = text.count("\n") + 1
            raise ctx.error("", f"invalid TOML at line {line} (end of {what}): {message}") from None
        raise ctx.error("", f"invalid TOML: {message}") from None
    except ValueError as exc:  # int(): "Exceeds the limit (4300 digits) for integer string conversion"
        reason = str(exc).split(";")[0]
        long = re.search(r"[0-9_]{4301,}", text)
        where = f" at line {text.count(chr(10), 0, long.start()) + 1}" if long else ""
        raise ctx.error("", f"invalid TOML{where}: a number too long to read ({reason})") from None


def show_path(file: Path) -> str:
    """A path as a message prints it: as it is, or quoted with its control characters escaped
    (JSON) when it holds any, so that a message naming it stays one line."""
    text = str(file)
    return text if text.isprintable() else json.dumps(text, ensure_ascii=False)


def check_private(ctx: Context, path: str, file: Path, what: str) -> None:
    """Refuse a secret-holding file that users other than its owner can access."""
    shown = show_path(file)
    try:
        mode = stat.S_IMODE(file.stat().st_mode)
    except FileNotFoundError:
        raise ctx.error(path, f"{shown} does not exist ({what})") from None
    except OSError as exc:
        raise ctx.error(path, f"cannot access {shown}: {exc.strerror or exc}") from None
    if not file.is_file():
        raise ctx.error(path, f"{shown} is not a regular file ({what})")
    if mode & 0o077:
        raise ctx.error(
            path,
            f"{shown} holds secrets ({what}) but is accessible to other users (mode {mode:04o}; allowed: "
            f"no group/other permissions, e.g. 0600): run `chmod 600 {shown}`",
        )


def check_exists(ctx: Context, path: str, file: Path, what: str) -> None:
    shown = show_path(file)
    if not file.exists():
        raise ctx.error(path, f"{shown} does not exist ({what})")
    if not file.is_file():
        raise ctx.error(path, f"{shown} is not a regular file ({what})")
