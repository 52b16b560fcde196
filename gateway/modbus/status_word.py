"""A device's named status words: one 16-bit register read with every poll.

A word is either a set of named bits (``bits``: states such as grasping or force reached;
``errors``: faults such as stall or over-temperature) or an enumerated code (``codes``: idle,
grasping, fault, ...; ``error_codes`` the ones that are faults). ``StatusWord.read`` turns the
register's value into a ``StatusWordReading``: which named bits are set, which code it is,
and whether any of it is an error.
"""

from __future__ import annotations

from dataclasses import dataclass

from .image import RegisterImage
from .register_map import RegisterKind

__all__ = ["StatusWord", "StatusWordReading", "read_status_words"]


@dataclass(frozen=True)
class StatusWordReading:
    """One poll's value of a status word, with its labels (for the page and /metrics).

    ``bits`` holds each named bit as (bit, label, set, is an error bit); ``code`` is the
    label of an enumerated word's value (``None`` for a word of bits, or a value it does not
    name); ``value`` is None when the word could not be read this poll."""

    name: str
    value: int | None
    bits: tuple[tuple[int, str, bool, bool], ...] = ()
    code: str | None = None
    code_is_error: bool = False

    @property
    def error(self) -> bool:
        """Whether an error bit is set or the code is an error code."""
        return self.code_is_error or any(on and is_error for _, _, on, is_error in self.bits)


@dataclass(frozen=True)
class StatusWord:
    """Where a status word is (``table``, register ``address``) and what its bits or codes mean."""

    name: str
    table: RegisterKind
    address: int
    bits: tuple[tuple[int, str], ...] = ()
    errors: tuple[tuple[int, str], ...] = ()
    codes: tuple[tuple[int, str], ...] = ()
    error_codes: frozenset[int] = frozenset()

    def read(self, value: int | None) -> StatusWordReading:
        """The reading of the register's ``value`` (None: not read)."""
        named = sorted(
            [(b, label, False) for b, label in self.bits] + [(b, label, True) for b, label in self.errors]
        )
        bits = tuple((b, label, value is not None and bool(value >> b & 1), err) for b, label, err in named)
        code = None
        if self.codes and value is not None:
            code = dict(self.codes).get(value, f"code {value}")
        return StatusWordReading(
            self.name, value, bits, code, value is not None and bool(self.codes) and value in self.error_codes
        )


def read_status_words(words: tuple[StatusWord, ...], image: RegisterImage) -> tuple[StatusWordReading, ...]:
    """Each word's reading from one poll's registers (a word not read reads None)."""
    out = []
    for word in words:
        value = image.get(word.table, word.address, 1)
        out.append(word.read(None if value is None else int(value[0])))
    return tuple(out)
