"""What the CSV and the MCAP form of a measurement record share (``docs/record-format.md``):
the rule for a channel name, channel names in a message, and which form a path asks for.
Imported by ``records`` (which re-exports them) and ``mcap_records``, which do not import each
other round a loop."""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path

#: The forms a record is written in (``record --format``): CSV text, or MCAP (``mcap_records``).
RECORD_FORMATS: tuple[str, ...] = ("csv", "mcap")

#: How many names a message lists (``names_text``), and how much of each name it shows.
NAMES_SHOWN = 8
NAME_CHARS_SHOWN = 32


def names_text(names: Iterable[str], shown: int = NAMES_SHOWN) -> str:
    """Channel names for a message: the first ``shown``, each cut to ``NAME_CHARS_SHOWN``
    characters, then how many more there are ("none" for no names). A message that names a
    record's channels stays a line however many (and however long) they are."""
    listed: list[str] = []
    more = 0
    for name in names:
        if len(listed) < shown:
            cut = NAME_CHARS_SHOWN - 3
            listed.append(name if len(name) <= NAME_CHARS_SHOWN else f"{name[:cut]}...")
        else:
            more += 1
    if not listed:
        return "none"
    return ", ".join(listed) + (f" and {more} more" if more else "")


def channel_name_problem(name: str) -> str | None:
    """Why ``name`` cannot stand as a channel in a record and read back as itself, or None.
    The writer does not quote: a comma, a quote or a line break would split or end the row
    (and could forge rows), white space at either end is stripped by the reader, and a
    character that is not printable (a control, a format or a separator character, a lone
    surrogate) is not text a record holds. The MCAP form keeps the same rule, so that every
    record converts between the two forms."""
    if not name:
        return "empty"
    if "," in name or '"' in name:
        return "a comma or a quote in it"
    if not name.isprintable():
        return "a line break, control or other non-printable character in it"
    if name != name.strip():
        return "white space at its start or end"
    return None


def record_format_for(path: Path, given: str | None = None) -> str:
    """The form of a record to write at ``path``: ``given``, else ``mcap`` for a name ending
    in ``.mcap``, else ``csv``."""
    if given is not None:
        return given
    return "mcap" if path.suffix.lower() == ".mcap" else "csv"
