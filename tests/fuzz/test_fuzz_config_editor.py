"""Fuzzing the channel editor ``gateway.config.editor`` (issue 16 §3): random ``KEY=VALUE``
assignments on a valid file. ``parse_assignment`` either gives an assignment or refuses with a
one-line ``ConfigError``; ``edit_channel`` either succeeds and the file still parses (and shows
the edit), or raises ``ConfigError`` and the file is byte for byte as it was.

The editor's refusal of an edit that would make the file invalid spans lines on purpose
("refused, <file> is unchanged: ...:" then the parser's message), so for ``edit_channel`` the
first line must name the file.
"""

from __future__ import annotations

from pathlib import Path

from fuzz_support import FUZZ, Tally
from hypothesis import given, settings
from hypothesis import strategies as st

from gateway.config import load_config
from gateway.config.editor import PLAIN_KEYS, Assignment, edit_channel, parse_assignment
from gateway.errors import ConfigError
from gateway.model import EFFECT_NAMES, parameter_names

CONFIG = """\
# keep me
[[bus]]
name = "bench"   # the bench bus
kind = "tcp"
host = "127.0.0.1"

[[bus.device]]
name = "arr"
device_id = 1
profile = "tactile-sim"
channels = 4
model = { params = { e0_pa = 16e6 } }

[[bus.device.channel]]
index = 0
name = "tip"   # fingertip
params = { r0_ohm = 190e3 }  # calibration run 3

[[bus.device]]
name = "inl"
device_id = 2
profile = "tactile-sim"
channels = 2
channel = [{ index = 1, name = "side", params = { r0_ohm = 2e5 } }]

# [[bus]]            a commented-out template
# name = "spare"
"""

KEYS = [*PLAIN_KEYS, *parameter_names()]
NUMBERS = [
    "0",
    "-0",
    "1",
    "-1",
    "2e5",
    "1e999",
    "-1e999",
    "inf",
    "-inf",
    "+inf",
    "nan",
    "NaN",
    "1_000",
    "0x10",
    "0o7",
    "0b1",
    "1e-320",
    "5e-324",
    "1.7976931348623157e308",
    "  3.5  ",
    "",
    " ",
    "1,5",
    "١٢",
    "½",
    "infinity",
    "1e5x",
    "True",
]
values = st.one_of(
    st.sampled_from(NUMBERS),
    st.floats(allow_nan=True, allow_infinity=True).map(repr),
    st.integers(min_value=-(10**30), max_value=10**30).map(str),
    st.sampled_from(["true", "false", "yes", "no", "on", "off", "1", "0", "maybe"]),
    st.lists(st.sampled_from([*EFFECT_NAMES, "bogus", "", " "]), max_size=4).map(",".join),
    st.text(max_size=20),
    st.sampled_from(["tip", "ch01", "side", "Tip!", "a" * 33, "ch00", "x y", '"q"', "a\nb", "a=b"]),
)
pairs = st.one_of(
    st.tuples(st.sampled_from(KEYS), values).map(lambda kv: f"{kv[0]}={kv[1]}"),
    st.tuples(st.text(max_size=10), values).map(lambda kv: f"{kv[0]}={kv[1]}"),
    st.text(max_size=20),
)

#: For edits: mostly known keys, so that most examples reach the editor.
edit_pairs = st.one_of(
    st.tuples(st.sampled_from(KEYS), values).map(lambda kv: f"{kv[0]}={kv[1]}"),
    st.tuples(st.sampled_from(KEYS), values).map(lambda kv: f"{kv[0]}={kv[1]}"),
    st.tuples(st.sampled_from(KEYS), st.floats(1e-12, 1e12).map(repr)).map(lambda kv: f"{kv[0]}={kv[1]}"),
    pairs,
)


def test_fuzz_parse_assignment() -> None:
    tally = Tally("editor: parse_assignment of random KEY=VALUE")

    @FUZZ
    @given(pairs)
    def run(pair: str) -> None:
        try:
            assignment = parse_assignment(pair)
        except ConfigError as exc:
            message = str(exc)
            assert message and "\n" not in message and "\r" not in message, repr(message)
            tally("refused")
            return
        assert isinstance(assignment, Assignment)
        tally("parsed")

    run()
    tally.report()


def test_fuzz_edit_channel_succeeds_or_leaves_the_file_byte_identical(tmp_path: Path) -> None:
    tally = Tally("editor: edit_channel with random assignments")
    path = tmp_path / "gateway.toml"
    original = CONFIG.encode("utf-8")

    @settings(FUZZ, max_examples=300)
    @given(
        st.lists(edit_pairs, min_size=1, max_size=3),
        st.sampled_from(["tip", "ch01", "ch03", "side", "ch00", "nope"]),
        st.sampled_from([None, "arr", "inl", "none"]),
    )
    def run(raw_pairs: list[str], channel: str, device: str | None) -> None:
        path.write_bytes(original)
        assignments = []
        for pair in raw_pairs:
            try:
                assignments.append(parse_assignment(pair))
            except ConfigError:
                continue
        if not assignments:
            tally("no valid assignment")
            return
        try:
            result = edit_channel(path, channel, device, assignments)
        except ConfigError as exc:
            first = str(exc).split("\n", 1)[0]
            assert str(path) in first, f"the first line does not name the file: {str(exc)!r}"
            assert path.read_bytes() == original, f"refused ({exc}) but the file changed"
            tally("refused")
            return
        # accepted: the file parses and the channel shows every assignment
        config = load_config(path)
        target = result.target
        edited = config.buses[target.bus_index].devices[target.device_index].channels[target.channel.index]
        assert edited == result.channel
        if result.changed:
            assert path.read_bytes() != original
        tally("edited" if result.changed else "already so")

    run()
    tally.report()
