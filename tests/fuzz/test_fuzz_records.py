"""Fuzzing the record reader ``gateway.analysis.records`` (issue 16 §3): binary garbage,
non-UTF-8 bytes, huge numbers, NaN and inf in every column, random headers and metadata
lines. Only ``RecordError`` may escape, with one line naming the file; an accepted record
holds no NaN, times are finite and non-decreasing per channel, resistances > 0.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
from fuzz_support import FUZZ, Tally, one_line_error
from hypothesis import given, settings
from hypothesis import strategies as st

from gateway.analysis.records import KNOWN_COLUMNS, Record, parse_record, read_record
from gateway.errors import RecordError

SPECIAL = [
    "nan",
    "NaN",
    "-nan",
    "inf",
    "-inf",
    "+inf",
    "Infinity",
    "1e999",
    "-1e999",
    "1e-999",
    "0",
    "-0",
    "9" * 400,
    "-" + "9" * 400,
    "1" + "0" * 5000,
    "0x10",
    "1_0",
    " 1 ",
    "",
    " ",
    "١",
    "1e",
    "e5",
    "5e-324",
    "1.7976931348623157e308",
    '"1"',
    '"a,b"',
    '"',
    "\x00",
    "\u2028",
]
cells = st.one_of(
    st.sampled_from(SPECIAL),
    st.floats(allow_nan=True, allow_infinity=True).map(repr),
    st.floats(min_value=0.0, max_value=1e6).map(repr),
    st.integers(min_value=-(10**40), max_value=10**40).map(str),
    st.sampled_from(["0", "1", "ch00", "a b"]),
    st.text(max_size=8),
)
column_names = st.one_of(
    st.sampled_from([*KNOWN_COLUMNS, "extra", " time_s ", "Time_s"]), st.text(max_size=8)
)

#: A valid cell of each known column, for row ``k`` (times increase with the row).
GOOD = {
    "time_s": lambda k: st.just(repr(0.1 * k)),
    "channel": lambda k: st.sampled_from(["0", "1", "a"]),
    "resistance_ohm": lambda k: st.one_of(st.floats(1e-3, 1e9).map(repr), st.just("inf")),
    "force_n": lambda k: st.floats(0.0, 100.0).map(repr),
    "temperature_c": lambda k: st.floats(-40.0, 120.0).map(repr),
}


@st.composite
def record_texts(draw: st.DrawFn) -> str:
    lines: list[str] = []
    for _ in range(draw(st.integers(0, 4))):  # metadata, comments, blank lines
        lines.append(
            draw(
                st.sampled_from(["# sensor: x", "#", "# :", "#a:b:c", "", "   ", "# key:"])
                | st.text(max_size=20).map(lambda t: "#" + t)
            )
        )
    if draw(st.integers(0, 4)):  # mostly a header with the required columns
        optional = ["channel", "force_n", "temperature_c"]
        header = ["time_s", "resistance_ohm", *optional[: draw(st.integers(0, 3))]]
        header += draw(st.lists(column_names, max_size=1))
        header = draw(st.permutations(header))
    else:
        header = draw(st.lists(column_names, min_size=0, max_size=6))
    lines.append(",".join(header))
    width = len(header)
    wild = draw(st.sampled_from([0.0, 0.02, 0.1, 0.5]))  # the share of random cells
    for k in range(draw(st.integers(0, 12))):
        n = width if draw(st.integers(0, 19)) else draw(st.integers(0, width + 2))
        row = []
        for i in range(n):
            name = header[i].strip() if i < width else ""
            if draw(st.floats(0, 1)) < wild or name not in GOOD:
                row.append(draw(cells))
            else:
                row.append(draw(GOOD[name](k)))
        lines.append(",".join(row))
    sep = draw(st.sampled_from(["\n", "\r\n", "\r"]))
    return draw(st.sampled_from(["", "\ufeff"])) + sep.join(lines) + draw(st.sampled_from(["", sep]))


def check_record(record: Record) -> None:
    assert record.channels
    for ch in record.channels.values():
        assert ch.n_samples > 0
        assert np.all(np.isfinite(ch.time_s)) and np.all(np.diff(ch.time_s) >= 0)
        assert not np.any(np.isnan(ch.resistance_ohm)) and np.all(ch.resistance_ohm > 0)
        if ch.force_n is not None:
            assert np.all(np.isfinite(ch.force_n)) and np.all(ch.force_n >= 0)
        if ch.temperature_c is not None:
            assert np.all(np.isfinite(ch.temperature_c))
        ch.usable_for_fit()
        ch.unusable_counts()


def test_fuzz_parse_record_text(tmp_path: Path) -> None:
    tally = Tally("records: parse_record of random record-like text")
    path = tmp_path / "rec.csv"

    @settings(FUZZ, max_examples=300)
    @given(st.one_of(record_texts(), record_texts(), st.text(max_size=200)), st.booleans())
    def run(text: str, require_force: bool) -> None:
        try:
            record = parse_record(text, path, require_force=require_force)
        except RecordError as exc:
            one_line_error(str(exc), f"{path}")
            tally("refused")
            return
        check_record(record)
        tally("accepted")

    run()
    tally.report()


def test_fuzz_read_record_bytes(tmp_path: Path) -> None:
    tally = Tally("records: read_record of random bytes")
    path = tmp_path / "rec.csv"

    @settings(FUZZ, max_examples=300)
    @given(
        st.one_of(
            st.binary(max_size=300),
            record_texts().map(lambda t: t.encode("utf-8")),
            st.tuples(record_texts(), st.binary(min_size=1, max_size=6), st.integers(0, 400)).map(
                lambda p: (lambda b: b[: p[2]] + p[1] + b[p[2] :])(p[0].encode("utf-8"))
            ),
            record_texts().map(lambda t: t.encode("utf-16")),
            record_texts().map(lambda t: t.encode("latin-1", errors="replace")),
        )
    )
    def run(data: bytes) -> None:
        path.write_bytes(data)
        try:
            record = read_record(path)
        except RecordError as exc:
            one_line_error(str(exc), f"{path}")
            tally("refused")
            return
        check_record(record)
        tally("accepted")

    run()
    tally.report()


def test_every_column_refuses_nan_and_the_required_ones_refuse_inf(tmp_path: Path) -> None:
    """NaN in any numeric column and inf where only a finite value makes sense are refused
    with the line and column; inf resistance (open circuit) is a value."""
    path = tmp_path / "rec.csv"
    header = "time_s,channel,resistance_ohm,force_n,temperature_c"
    good = ["0.5", "0", "1000", "1", "20"]
    count = 0
    for col in (0, 2, 3, 4):
        for bad in ("nan", "inf", "-inf", "1e999", "-1e999"):
            row = list(good)
            row[col] = bad
            text = f"{header}\n{','.join(row)}\n"
            count += 1
            if col == 2 and bad in ("inf", "1e999"):
                record = parse_record(text, path)
                assert math.isinf(record.channel().resistance_ohm[0])
                continue
            try:
                parse_record(text, path)
            except RecordError as exc:
                one_line_error(str(exc), f"{path}:2: column {col + 1}")
            else:
                raise AssertionError(f"accepted {bad} in column {col + 1}")
    print(f"FUZZ records: {count} NaN/inf cases")
