"""Shared pieces of the fuzz tests (issue 16 §3): example counters and value strategies.

Every fuzz test counts the examples it ran and prints the count (``pytest -s`` or ``-rP``
shows it), so that a report can say how much each edge was exercised.
"""

from __future__ import annotations

import datetime as dt
import math
import sys
from collections import Counter
from dataclasses import dataclass, field

from hypothesis import HealthCheck, settings
from hypothesis import strategies as st

#: Settings of every fuzz test: many examples, no deadline (a test checks what happens, not how
#: fast: on 2 shared cores under load an example can take seconds), no database (the tests
#: run from a clean tree and must not write into it).
FUZZ = settings(
    max_examples=250,
    deadline=None,
    database=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large, HealthCheck.filter_too_much],
)


@dataclass
class Tally:
    """Examples run, and outcomes by kind, of one fuzz test."""

    name: str
    examples: int = 0
    outcomes: Counter[str] = field(default_factory=Counter)

    def __call__(self, outcome: str) -> None:
        self.examples += 1
        self.outcomes[outcome] += 1

    def report(self, minimum: int = 100) -> None:
        shown = ", ".join(f"{k} {v}" for k, v in sorted(self.outcomes.items()))
        line = f"FUZZ {self.name}: {self.examples} examples ({shown})"
        print(line)
        sys.stderr.write(line + "\n")
        assert self.examples >= minimum, line


def one_line_error(message: str, label: str) -> None:
    """A clear error: one line that starts with ``label`` (the file it is about)."""
    assert message, "an empty error message"
    assert "\n" not in message and "\r" not in message, f"a message of more than one line: {message!r}"
    assert message.startswith(label), f"the message does not name {label!r} first: {message!r}"
    assert "Traceback" not in message, message


_special_floats = st.sampled_from(
    [math.nan, math.inf, -math.inf, 0.0, -0.0, 1e308, -1e308, 5e-324, 1e-300, 0.5, 1.0, 65535.0, 65536.0]
)
_special_ints = st.sampled_from(
    [0, -1, 1, 2, 15, 16, 125, 126, 247, 248, 255, 256, 65535, 65536, 2**31, 2**63 - 1, -(2**63)]
)

#: Any TOML scalar: integers (64-bit, TOML's range), floats (NaN, inf), strings, booleans, dates.
toml_scalars = st.one_of(
    st.integers(min_value=-(2**63), max_value=2**63 - 1),
    _special_ints,
    st.floats(allow_nan=True, allow_infinity=True),
    _special_floats,
    st.text(max_size=40),
    st.sampled_from(
        [
            "",
            " ",
            "host",
            "tcp",
            "rtu",
            "tls",
            "adc",
            "float32",
            "big",
            "little",
            "input",
            "holding",
            "high_side",
            "low_side",
            "transimpedance",
            "ms",
            "s",
            "us",
            "tactile-sim",
            "acme-at6x6",
            "generic-adc",
            "127.0.0.1:9830",
            "[::1]:9830",
            "127.0.0.1",
            "::1",
            "ch00",
            "tunneling",
            "creep",
            "contact",
            "json",
            "binary",
            "5",
            "3.1.1",
            "nonexistent.toml",
            "sub/none.toml",
            "/dev/null",
            "/",
            ".",
            "..",
            "~",
            "/etc/hostname",
            "a\nb",
            "\x00",
            "é" * 40,
        ]
    ),
    st.booleans(),
    st.datetimes(min_value=dt.datetime(1, 1, 1), max_value=dt.datetime(9999, 12, 31)),
    st.dates(),
    st.times(),
)


def toml_values(depth: int = 2) -> st.SearchStrategy[object]:
    """TOML values: scalars, arrays (mixed types) and tables, nested ``depth`` deep."""
    if depth <= 0:
        return toml_scalars
    inner = toml_values(depth - 1)
    return st.one_of(
        toml_scalars,
        st.lists(inner, max_size=5),
        st.dictionaries(st.text(min_size=1, max_size=12), inner, max_size=4),
    )
