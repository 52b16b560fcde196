"""Unknown keys: the one check every table reader of the gateway runs on a table's keys.

``check_keys`` raises, for the first key of a table that is not allowed, the error its reader
makes of a message naming the key, the closest allowed key ("did you mean") and the allowed
keys. The message is ``UNKNOWN_KEY`` unless a reader keeps its own wording (a template with the
same fields), so every file's messages stay as they are.

A leaf of ``gateway/`` (it imports nothing of ours), usable by every room but ``model``, which
imports nothing of ours at all: ``model.conversion`` keeps its own three-line check and its
``ConversionError`` names the key. ``sim_device`` never imports ``gateway`` and keeps its own
copy (``sim_device.scenario_file``).
"""

from __future__ import annotations

import difflib
from collections.abc import Callable, Iterable, Sequence
from enum import StrEnum
from typing import Final, TypeVar

__all__ = ["UNKNOWN_KEY", "Choice", "check_keys", "choice_of", "suggest"]

#: The message of an unknown key. Fields: ``{key}`` (the key, quoted), ``{hint}`` ("; did you
#: mean 'x'?" or nothing) and ``{allowed}`` (the allowed keys, comma separated).
UNKNOWN_KEY: Final = "unknown key{hint} (allowed keys: {allowed})"


def suggest(word: str, choices: Iterable[str], cutoff: float = 0.6) -> str:
    """``"; did you mean 'x'?"`` for the choice closest to ``word``, or ``""``."""
    close = difflib.get_close_matches(word, list(choices), n=1, cutoff=cutoff)
    return f"; did you mean {close[0]!r}?" if close else ""


def check_keys(
    keys: Iterable[str],
    allowed: Sequence[str],
    error: Callable[[str, str], Exception],
    template: str = UNKNOWN_KEY,
    *,
    shown: Sequence[str] | None = None,
) -> None:
    """Raise ``error(key, message)`` for the first of ``keys`` not in ``allowed``.

    ``template`` words the message (``UNKNOWN_KEY``'s fields); ``shown`` are the keys it lists
    when not all of ``allowed`` (default: ``allowed``)."""
    for key in keys:
        if key not in allowed:
            hint = suggest(key, allowed) if isinstance(key, str) else ""
            listed = ", ".join(allowed if shown is None else shown)
            raise error(key, template.format(key=repr(key), hint=hint, allowed=listed))


class Choice(StrEnum):
    """The words one configuration key allows (a bus ``kind``, a device ``encoding``, a
    register ``table``), as the file spells them: a member equals its string (TOML's), shows
    as it (``'tcp'`` in a message, not ``<BusKind.TCP: 'tcp'>``), and a word that is none of
    them is a ``ValueError`` naming the closest and every allowed one, never a default."""

    def __repr__(self) -> str:
        return repr(self.value)

    @classmethod
    def _missing_(cls, value: object) -> Choice:
        words = [m.value for m in cls]
        hint = suggest(value, words) if isinstance(value, str) else ""
        raise ValueError(f"{value!r} is not allowed{hint}; allowed: {', '.join(map(repr, words))}")


_Word = TypeVar("_Word", bound=Choice)


def choice_of(kind: type[_Word], value: object, name: str) -> _Word:
    """``value`` as a member of ``kind``; otherwise a ``ValueError`` that starts with ``name``
    (``"kind: 'tpc' is not allowed; did you mean 'tcp'?; allowed: ..."``), a value that is not
    a string included."""
    if isinstance(value, str):
        try:
            return kind(value)
        except ValueError as exc:
            raise ValueError(f"{name}: {exc}") from None
    raise ValueError(f"{name}: {value!r} is not allowed; allowed: {', '.join(repr(m.value) for m in kind)}")
