"""The register table of ``tactile-gateway scan``: registers ``ROW`` to a line, those that
changed marked, and the live view that redraws it on a terminal every round.
"""

from __future__ import annotations

import shutil
from collections.abc import Mapping
from typing import TextIO

from ..modbus.scan_read import Registers

#: Registers per row of the table.
ROW = 10


def _cell(value: int | None, in_range: bool, marked: bool, ansi: bool) -> str:
    text = "      " if not in_range else ("    --" if value is None else f"{value:6d}")
    if marked and ansi:
        return f"\x1b[7m{text}\x1b[0m "
    return text + ("*" if marked else " ")


def render_table(
    data: Mapping[str, Mapping[int, int | None]], marked: set[tuple[str, int]], ansi: bool
) -> list[str]:
    """The registers ``ROW`` to a line, unreadable ones as ``--``; ``marked`` ones in reverse
    video (``ansi``) or followed by ``*``. Consecutive rows without a readable register
    shrink to one line."""
    lines: list[str] = []
    for table, values in data.items():
        if not values:
            continue
        if lines:
            lines.append("")
        lines.append(f"{table:>7} " + " ".join(f"{'+' + str(k):>6}" for k in range(ROW)))
        rows: dict[int, list[int]] = {}
        for a in sorted(values):
            rows.setdefault(a // ROW, []).append(a)
        blank: list[int] = []  # consecutive rows without a readable register
        for row in [*sorted(rows), None]:
            readable = row is not None and any(values[a] is not None for a in rows[row])
            if row is not None and not readable and (not blank or blank[-1] == row - 1):
                blank.append(row)
                continue
            if len(blank) == 1:
                lines.append(_row_line(table, blank[0], values, marked, ansi))
            elif blank:
                lines.append(f"{rows[blank[0]][0]:>7}-{rows[blank[-1]][-1]}: unreadable")
            blank = [] if readable or row is None else [row]
            if readable and row is not None:
                lines.append(_row_line(table, row, values, marked, ansi))
    return lines


def _row_line(
    table: str, row: int, values: Mapping[int, int | None], marked: set[tuple[str, int]], ansi: bool
) -> str:
    cells = [
        _cell(values.get(a), a in values, (table, a) in marked, ansi)
        for a in range(row * ROW, row * ROW + ROW)
    ]
    return f"{row * ROW:>7} " + "".join(cells).rstrip()


def changed_between(
    now: Mapping[str, Mapping[int, int | None]], before: Registers | None
) -> set[tuple[str, int]]:
    """Registers read in both rounds with different values."""
    if before is None:
        return set()
    return {
        (table, a)
        for table, values in now.items()
        for a, v in values.items()
        if v is not None and before.get(table, {}).get(a) is not None and before[table][a] != v
    }


class LiveView:
    """Redraws the table on a terminal every round (ANSI), changes in reverse video; cut to
    the terminal's height (``truncated`` then: the full table is printed at the end)."""

    def __init__(self, out: TextIO, title: str, rounds: int, height: int | None = None) -> None:
        self.out = out
        self.title = title
        self.rounds = rounds
        self.height = height if height is not None else shutil.get_terminal_size().lines
        self.last: Registers | None = None
        self.truncated = False

    def __call__(self, k: int, data: Registers, previous: Registers | None) -> None:
        table = render_table(data, changed_between(data, previous), ansi=True)
        room = max(1, self.height - 5)
        if len(table) > room:
            self.truncated = True
            table = [*table[: room - 1], "  ... (the whole table follows at the end)"]
        lines = [f"{self.title}: round {k} of {self.rounds} (Ctrl-C stops and analyses)", "", *table]
        lines += ["", "reverse video: changed since the previous round; --: unreadable"]
        clear = "\x1b[2J" if self.last is None else ""
        self.out.write(clear + "\x1b[H" + "\x1b[K\n".join(lines) + "\x1b[K\n\x1b[J")
        self.out.flush()
        self.last = data
