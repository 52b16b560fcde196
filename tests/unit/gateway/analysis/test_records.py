"""The strict record reader: every malformed file names file, line and column."""

from __future__ import annotations

import io
import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from gateway.analysis.records import RecordWriter, format_record, parse_record, read_record, write_record
from gateway.errors import RecordError

GOOD = """# sensor: linqstat-7
# source: bench 2
time_s,channel,resistance_ohm,force_n,temperature_c,comment
0.0,a,1.5e5,0.0,25.0,start
0.0,b,inf,0.0,25.0,
0.5,a,9.9e4,1.0,25.1,x
0.5,b,1.2e5,0.5,25.1,
1.0,a,9.8e4,1.0,25.2,
"""


def test_good_record_is_read_with_metadata_and_channels(tmp_path: Path) -> None:
    path = tmp_path / "r.csv"
    path.write_text(GOOD)
    rec = read_record(path, require_force=True)
    assert rec.metadata == {"sensor": "linqstat-7", "source": "bench 2"}
    assert list(rec.channels) == ["a", "b"]
    assert rec.extra_columns == ("comment",)
    a = rec.channel("a")
    np.testing.assert_array_equal(a.time_s, [0.0, 0.5, 1.0])
    np.testing.assert_array_equal(a.resistance_ohm, [1.5e5, 9.9e4, 9.8e4])
    assert a.line.tolist() == [4, 6, 8]
    b = rec.channel("b")
    assert math.isinf(b.resistance_ohm[0])
    assert b.unusable_counts() == {"open_circuit": 1, "zero_force": 1}
    assert b.usable_for_fit().tolist() == [False, True]


def test_column_order_is_free_and_channel_is_optional() -> None:
    rec = parse_record("resistance_ohm,time_s\n100,0\n90,1\n")
    ch = rec.channel()
    assert ch.name == "0"
    assert ch.force_n is None and ch.temperature_c is None
    np.testing.assert_array_equal(ch.resistance_ohm, [100.0, 90.0])


BAD = [
    ("", "no header row"),
    ("# only: metadata\n", "no header row"),
    ("time_s,force_n\n0,1\n", "r.csv:1: missing required column 'resistance_ohm'"),
    ("resistance_ohm,force_n\n1,1\n", "r.csv:1: missing required column 'time_s'"),
    ("time_s,resistance_ohm\n", "no data rows after the header on line 1"),
    ("time_s,resistance_ohm,time_s\n0,1,0\n", "r.csv:1: column 3: duplicate column 'time_s'"),
    ("time_s,resistance_ohm\n0,abc\n", "r.csv:2: column 2 (resistance_ohm): 'abc' is not a number"),
    ("time_s,resistance_ohm\nzero,1\n", "r.csv:2: column 1 (time_s): 'zero' is not a number"),
    ("time_s,resistance_ohm\n0,-5\n", "r.csv:2: column 2 (resistance_ohm): '-5' must be > 0"),
    ("time_s,resistance_ohm\n0,0\n", "r.csv:2: column 2 (resistance_ohm): '0' must be > 0"),
    ("time_s,resistance_ohm\n0,nan\n", "r.csv:2: column 2 (resistance_ohm): NaN is not a value"),
    ("time_s,resistance_ohm\n0,1\n1,1,3\n", "r.csv:3: 3 fields, the header has 2"),
    (
        "# a: b\ntime_s,resistance_ohm\n1,1\n0.5,1\n",
        "r.csv:4: column 1 (time_s): time goes backwards in channel '0'",
    ),
    ("time_s,resistance_ohm\ninf,1\n", "r.csv:2: column 1 (time_s): inf is not a finite time"),
    (
        "time_s,resistance_ohm,force_n\n0,1,-1\n",
        "r.csv:2: column 3 (force_n): -1.0 is below 0 N by more than the load-cell zero-noise tolerance "
        "of 0.05 N",
    ),
    ("time_s,resistance_ohm,force_n\n0,1,inf\n", "r.csv:2: column 3 (force_n): 'inf' is not finite"),
    ("time_s,channel,resistance_ohm\n0,,1\n", "r.csv:2: column 2 (channel): empty channel name"),
    (
        "time_s,resistance_ohm,temperature_c\n0,1,inf\n",
        "r.csv:2: column 3 (temperature_c): not a finite temperature",
    ),
]


@pytest.mark.parametrize(("text", "message"), BAD)
def test_malformed_records_name_file_line_and_column(tmp_path: Path, text: str, message: str) -> None:
    path = tmp_path / "r.csv"
    path.write_text(text)
    with pytest.raises(RecordError) as info:
        read_record(path)
    assert message in str(info.value)
    assert str(path) in str(info.value)


def test_fitting_needs_force(tmp_path: Path) -> None:
    path = tmp_path / "r.csv"
    path.write_text("time_s,resistance_ohm\n0,1\n")
    with pytest.raises(RecordError, match="missing required column 'force_n'"):
        read_record(path, require_force=True)


def test_missing_and_undecodable_files(tmp_path: Path) -> None:
    with pytest.raises(RecordError, match="no such file"):
        read_record(tmp_path / "absent.csv")
    bad = tmp_path / "latin1.csv"
    bad.write_bytes("time_s,resistance_ohm\n0,1\n# caf\xe9\n".encode("latin-1"))
    with pytest.raises(RecordError, match="not UTF-8"):
        read_record(bad)


def test_channel_lookup_suggests() -> None:
    rec = parse_record(GOOD)
    with pytest.raises(RecordError, match="no channel 'aa'; did you mean 'a'"):
        rec.channel("aa")
    with pytest.raises(RecordError, match="the record has 2 channels"):
        rec.channel()


def test_write_then_read_round_trip(tmp_path: Path) -> None:
    text = format_record(
        {"sensor": "sim"},
        ["c0", "c1"],
        [0.0, 0.1],
        [[1e5, math.inf], [9e4, 8e4]],
        force_n=[[0.5, 0.0], [1.0, 2.0]],
        temperature_c=[[25.0, 25.0], [25.5, 25.5]],
    )
    path = tmp_path / "out.csv"
    write_record(path, text)
    rec = read_record(path, require_force=True)
    assert rec.metadata == {"sensor": "sim"}
    assert math.isinf(rec.channel("c1").resistance_ohm[0])
    np.testing.assert_array_equal(rec.channel("c1").force_n, [0.0, 2.0])
    assert [p.name for p in tmp_path.iterdir()] == ["out.csv"]


def test_the_writer_writes_the_spec_header_and_exact_values() -> None:
    out = io.StringIO()
    writer = RecordWriter(out, {"sensor": "tip"}, has_force=True)
    writer.row(0.25, "tip", 1234.5, 2.0)
    writer.row(0.5, "tip", math.inf, 0.0)
    assert (
        out.getvalue()
        == "# sensor: tip\ntime_s,channel,resistance_ohm,force_n\n0.25,tip,1234.5,2.0\n0.5,tip,inf,0.0\n"
    )
    with pytest.raises(ValueError, match="force_n"):
        writer.row(0.75, "tip", 1.0)


@settings(max_examples=60, deadline=None)
@given(
    st.lists(
        st.tuples(
            st.floats(min_value=0.0, max_value=1e6),
            st.one_of(st.floats(min_value=1e-3, max_value=1e12), st.just(math.inf)),
            st.floats(min_value=0.0, max_value=1e3),
            st.floats(min_value=-50.0, max_value=150.0),
        ),
        min_size=1,
        max_size=20,
    )
)
def test_every_written_value_reads_back_as_the_same_double(
    rows: list[tuple[float, float, float, float]],
) -> None:
    rows = sorted(rows)  # time is non-decreasing within a channel
    out = io.StringIO()
    writer = RecordWriter(out, has_force=True, has_temperature=True)
    for t, r, f, temp in rows:
        writer.row(t, "a", r, f, temp)
    record = parse_record(out.getvalue()).channel("a")
    assert record.time_s.tolist() == [row[0] for row in rows]
    assert record.resistance_ohm.tolist() == [row[1] for row in rows]
    assert record.force_n is not None and record.force_n.tolist() == [row[2] for row in rows]
    assert record.temperature_c is not None and record.temperature_c.tolist() == [row[3] for row in rows]


def test_a_spreadsheet_byte_order_mark_is_not_part_of_the_first_column(tmp_path: Path) -> None:
    path = tmp_path / "excel.csv"
    path.write_text("time_s,resistance_ohm,force_n\n0,1000,1\n0.1,1100,1.5\n", encoding="utf-8-sig")
    assert path.read_bytes()[:3] == b"\xef\xbb\xbf"
    channel = read_record(path, require_force=True).channel()
    assert channel.n_samples == 2 and channel.resistance_ohm.tolist() == [1000.0, 1100.0]


def test_a_field_over_the_csv_limit_is_a_record_error(tmp_path: Path) -> None:
    path = tmp_path / "huge-field.csv"
    path.write_text("time_s,resistance_ohm\n0," + "1" * 200_000 + "\n")
    with pytest.raises(RecordError, match=r"not a readable CSV record: field larger than field limit"):
        read_record(path)


def test_a_header_with_a_newline_inside_a_quoted_name_is_named_on_one_line() -> None:
    """Found by the fuzz test: a quoted header field holding a newline made a two-line message."""
    with pytest.raises(RecordError) as caught:
        parse_record('time_s,"0.0\n0.1",nan\n0,1,2\n')
    message = str(caught.value)
    assert "\n" not in message and "missing required column 'resistance_ohm'" in message
    assert "0.0\\n0.1" in message


@pytest.mark.parametrize("newline", ["\n", "\r\n", "\r"])
def test_unix_windows_and_old_mac_line_endings_read_the_same(newline: str) -> None:
    """The reader walks the text line by line (no list of every line); each ending reads alike,
    and a quoted field that spans lines stays one field."""
    lines = [
        "# source: bench",
        "time_s,channel,resistance_ohm,force_n,note",
        "0,a,100,1,x",
        '0.5,a,inf,0,"two',
        'lines"',
    ]
    record = parse_record(newline.join(lines) + newline)
    ch = record.channel("a")
    assert record.metadata == {"source": "bench"} and record.extra_columns == ("note",)
    assert ch.time_s.tolist() == [0.0, 0.5] and ch.resistance_ohm.tolist() == [100.0, math.inf]
    assert ch.force_n is not None and ch.force_n.tolist() == [1.0, 0.0]
    assert ch.line.tolist() == [3, 4]


# ----------------------------------------------------------------- load-cell zero noise
#: A bench's record: at rest the load cell reads a little below 0 N.
BENCH = """# sensor: bench
time_s,channel,resistance_ohm,force_n
0.0,a,inf,-0.0002
0.0,b,inf,0.0
0.5,a,inf,0.0001
0.5,b,inf,-0.0001
1.0,a,2e4,3.0
1.0,b,3e4,2.0
1.5,a,inf,-0.0002
1.5,b,inf,-0.03
"""


def test_a_reference_force_slightly_below_zero_is_zero_noise_read_as_0_n_and_counted() -> None:
    rec = parse_record(BENCH)
    a, b = rec.channel("a"), rec.channel("b")
    assert a.force_n is not None and b.force_n is not None
    assert a.force_n.tolist() == [0.0, 0.0001, 3.0, 0.0]
    assert b.force_n.tolist() == [0.0, 0.0, 2.0, 0.0]
    assert (a.zero_noise_rows, a.zero_noise_min_n) == (2, -0.0002)
    assert (b.zero_noise_rows, b.zero_noise_min_n) == (2, -0.03)
    assert rec.zero_noise_rows == 4
    # full scale 3 N: 1 % is 0.03 N, below the 0.05 N floor
    assert a.zero_noise_tolerance_n == 0.05
    note = a.zero_noise_note()
    assert note is not None
    assert "channel a: 2 rows of reference below 0 N accepted as load-cell zero noise" in note
    assert "-0.0002 N" in note and "0.05 N" in note and "read as 0 N" in note
    assert rec.zero_noise_notes() == [note, b.zero_noise_note()]
    # the rows read as 0 N are unloaded rows, counted as such
    assert a.unusable_counts() == {"open_circuit": 3, "zero_force": 2}


def test_a_record_without_negative_forces_has_no_note() -> None:
    ch = parse_record(GOOD).channel("a")
    assert ch.zero_noise_rows == 0 and ch.zero_noise_note() is None


def test_the_tolerance_is_one_percent_of_the_full_scale_above_5_n() -> None:
    """49 N full scale: the tolerance is 0.49 N; -0.4 N is noise, -0.6 N is refused."""
    rec = parse_record("time_s,resistance_ohm,force_n\n0,inf,-0.4\n1,1e3,49\n")
    ch = rec.channel()
    assert ch.zero_noise_tolerance_n == pytest.approx(0.49)
    assert ch.zero_noise_rows == 1 and ch.force_n is not None and ch.force_n[0] == 0.0
    with pytest.raises(RecordError) as info:
        parse_record("time_s,resistance_ohm,force_n\n0,inf,-0.6\n1,1e3,49\n", Path("r.csv"))
    assert str(info.value).startswith("r.csv:2: column 3 (force_n): -0.6 is below 0 N by more than")
    assert "tolerance of 0.49 N" in str(info.value) and "49 N" in str(info.value)


def test_a_force_of_minus_5_n_is_refused_naming_line_column_and_tolerance(tmp_path: Path) -> None:
    path = tmp_path / "r.csv"
    text = BENCH.replace("1.0,b,3e4,2.0", "1.0,b,3e4,-5") + "2.0,a,inf,-7\n"
    path.write_text(text)
    with pytest.raises(RecordError) as info:
        read_record(path)
    message = str(info.value)
    # the first one in file order (line 8), not the lowest (-7 N on line 11)
    assert message.startswith(f"{path}:8: column 4 (force_n): -5.0 is below 0 N by more than the load-cell")
    assert "tolerance of 0.05 N (the larger of 0.05 N and 1 % of the record's largest" in message
    assert "\n" not in message


@settings(max_examples=60, deadline=None)
@given(
    full_scale=st.floats(0.01, 500.0),
    shares=st.lists(st.floats(0.0, 2.0), min_size=1, max_size=6),
)
def test_property_forces_within_the_tolerance_load_and_beyond_it_are_refused(
    full_scale: float, shares: list[float]
) -> None:
    """Forces of -share x tolerance: accepted and counted when every share <= 1 (minus a
    rounding margin), refused when one exceeds 1 (plus a margin)."""
    tol = max(0.05, 0.01 * full_scale)
    shares = [s for s in shares if abs(s - 1.0) > 1e-6]
    rows = [f"{k},inf,{-s * tol!r}" for k, s in enumerate(shares)] + [f"{len(shares)},1e3,{full_scale!r}"]
    text = "time_s,resistance_ohm,force_n\n" + "\n".join(rows) + "\n"
    if all(s < 1.0 for s in shares):
        ch = parse_record(text).channel()
        # a share so small that -share x tolerance underflows to -0.0 is a force of 0 N, not below
        assert ch.zero_noise_rows == sum(1 for s in shares if -s * tol < 0.0)
        assert ch.force_n is not None and np.all(ch.force_n >= 0.0)
        assert ch.zero_noise_tolerance_n == pytest.approx(tol)
    else:
        with pytest.raises(RecordError, match="zero-noise tolerance"):
            parse_record(text)


def test_the_writer_writes_extra_columns_empty_for_no_value_and_metadata_on_one_line() -> None:
    out = io.StringIO()
    writer = RecordWriter(
        out, {"note": "two\nlines  and\ttabs"}, has_force=True, extra_columns=("force_tracked_n", "status")
    )
    writer.row(0.5, "tip", 1234.5, 2.0, extra=(1.75, "ok"))
    writer.row(1.0, "tip", math.inf, 0.0, extra=(math.nan, "open"))
    assert out.getvalue() == (
        "# note: two lines and tabs\n"
        "time_s,channel,resistance_ohm,force_n,force_tracked_n,status\n"
        "0.5,tip,1234.5,2.0,1.75,ok\n"
        "1.0,tip,inf,0.0,,open\n"
    )
    back = parse_record(out.getvalue())
    assert back.metadata == {"note": "two lines and tabs"}
    assert back.extra_columns == ("force_tracked_n", "status")
    with pytest.raises(ValueError, match="give 2 values, got 1"):
        writer.row(1.5, "tip", 1.0, 0.0, extra=(1.0,))
    with pytest.raises(ValueError, match="no comma, quote or line break"):
        writer.row(1.5, "tip", 1.0, 0.0, extra=(1.0, "a,b"))


@pytest.mark.parametrize("extra", [("force_n",), ("x", "x"), ("a,b",), ("",)])
def test_the_writer_refuses_extra_columns_that_would_not_read_back(extra: tuple[str, ...]) -> None:
    with pytest.raises(ValueError, match="each must be new, once"):
        RecordWriter(io.StringIO(), has_force=True, extra_columns=extra)
