"""Fuzzing ``gateway.config.parse_config`` / ``load_config`` (issue 16 §3): random TOML
documents built from the real keys with random values of random types, random text and
random bytes. Only ``ConfigError`` may escape, with a message of one line that names the file.
"""

from __future__ import annotations

import copy
import os
import subprocess
import sys
import textwrap
import tomllib
from pathlib import Path
from typing import Any

import pytest
import tomlkit
from fuzz_support import FUZZ, Tally, one_line_error, toml_values
from hypothesis import given
from hypothesis import strategies as st

from gateway.config import GatewayConfig, load_config, parse_config
from gateway.config.device import DEVICE_KEYS
from gateway.errors import ConfigError
from gateway.model import parameter_names

#: A valid configuration that uses every section: the fuzz mutates it key by key.
VALID: dict[str, Any] = {
    "metrics": {"address": "127.0.0.1:9830"},
    "mqtt": {"host": "broker", "port": 1883, "topic_prefix": "plant/tactile", "qos": 1},
    "bus": [
        {
            "name": "bench",
            "kind": "tcp",
            "host": "127.0.0.1",
            "port": 5020,
            "timeout_s": 0.5,
            "retries": 1,
            "poll_interval_s": 0.1,
            "device": [
                {
                    "name": "arr",
                    "device_id": 1,
                    "profile": "tactile-sim",
                    "channels": 4,
                    "registers": {"force_reference_address": 1000, "temperature_address": 2000},
                    "clock": {"address": 2, "registers": 4, "unit": "ms"},
                    "front_end": {"kind": "high_side", "supply_v": 5.0, "reference_ohm": 1e4, "adc_bits": 16},
                    "layout": {"columns": 2, "pitch_mm": 2.5},
                    "checks": {"channel_count": {"table": "holding", "address": 0}},
                    "model": {"effects": ["tunneling", "contact", "creep"], "params": {"e0_pa": 16e6}},
                    "baseline_ohm": [2e5, 2e5, 2e5, 2e5],
                    "channel": [{"index": 0, "name": "tip", "x_mm": 1.0, "params": {"r0_ohm": 1.9e5}}],
                },
                {
                    "name": "flt",
                    "device_id": 2,
                    "encoding": "float32",
                    "channels": 3,
                    "registers": {"float_address": 400, "word_order": "little", "byte_order": "big"},
                    "divider": {"supply_v": 5.0, "reference_ohm": 1e4, "adc_bits": 12},
                },
            ],
        },
        {
            "name": "line",
            "kind": "rtu",
            "serial_port": "/dev/ttyUSB0",
            "baudrate": 19200,
            "parity": "E",
            "device": [
                {
                    "name": "rtu1",
                    "device_id": 1,
                    "channels": 2,
                    "registers": {"adc_address": 100, "status_address": 16, "table": "holding"},
                    "front_end": {
                        "kind": "transimpedance",
                        "bias_v": 0.5,
                        "feedback_ohm": 1e4,
                        "adc_reference_v": 3.3,
                        "adc_bits": 12,
                    },
                }
            ],
        },
    ],
}

#: Keys each table of the schema knows (docs/configuration.md), by the path to the table.
KEYS: dict[tuple[Any, ...], tuple[str, ...]] = {
    (): ("metrics", "bus", "mqtt"),
    ("metrics",): ("address", "web_config"),
    ("mqtt",): (
        "host",
        "port",
        "tls",
        "username",
        "password_file",
        "client_id",
        "topic_prefix",
        "gateway",
        "qos",
        "max_rate_hz",
        "encoding",
        "protocol",
        "queue_frames",
    ),
    ("bus", 0): (
        "name",
        "kind",
        "host",
        "port",
        "serial_port",
        "baudrate",
        "parity",
        "stopbits",
        "bytesize",
        "timeout_s",
        "retries",
        "poll_interval_s",
        "max_read_registers",
        "backoff_initial_s",
        "backoff_max_s",
        "tls",
        "device",
    ),
    ("bus", 1): (
        "name",
        "kind",
        "serial_port",
        "baudrate",
        "parity",
        "stopbits",
        "bytesize",
        "serial_client",
        "poll_interval_s",
        "host",
        "port",
    ),
    ("bus", 0, "device", 0): DEVICE_KEYS,
    ("bus", 0, "device", 1): DEVICE_KEYS,
    ("bus", 1, "device", 0): DEVICE_KEYS,
    ("bus", 0, "device", 0, "registers"): (
        "table",
        "adc_address",
        "float_address",
        "word_order",
        "byte_order",
        "status_address",
        "force_reference_address",
        "temperature_address",
    ),
    ("bus", 0, "device", 1, "registers"): ("float_address", "word_order", "byte_order", "status_address"),
    ("bus", 0, "device", 0, "clock"): ("address", "registers", "unit", "tick_s", "table"),
    ("bus", 0, "device", 0, "front_end"): (
        "kind",
        "supply_v",
        "reference_ohm",
        "adc_bits",
        "adc_reference_v",
        "adc_offset_counts",
        "bias_v",
        "feedback_ohm",
        "output_offset_v",
        "rises_with_load",
    ),
    ("bus", 1, "device", 0, "front_end"): (
        "kind",
        "bias_v",
        "feedback_ohm",
        "output_offset_v",
        "adc_bits",
        "adc_reference_v",
        "adc_offset_counts",
    ),
    ("bus", 0, "device", 1, "divider"): ("supply_v", "reference_ohm", "adc_bits"),
    ("bus", 0, "device", 0, "layout"): ("columns", "pitch_mm", "pitch_x_mm", "pitch_y_mm", "origin", "order"),
    ("bus", 0, "device", 0, "checks"): ("registers", "channel_count", "identification"),
    ("bus", 0, "device", 0, "model"): ("effects", "params"),
    ("bus", 0, "device", 0, "model", "params"): tuple(parameter_names()),
    ("bus", 0, "device", 0, "channel", 0): ("index", "name", "x_mm", "y_mm", "enabled", "effects", "params"),
    ("bus", 0, "device", 0, "channel", 0, "params"): tuple(parameter_names()),
}
TABLES = sorted(KEYS, key=repr)

#: One edit: (table, key, value or None to delete it).
edits = st.lists(
    st.tuples(
        st.sampled_from(TABLES),
        st.one_of(st.none(), st.text(min_size=1, max_size=12)),  # None: a known key of that table
        st.data(),
        st.one_of(st.none(), toml_values(2)),  # None: delete the key
    ),
    min_size=1,
    max_size=4,
)


def _table(doc: dict[str, Any], path: tuple[Any, ...]) -> dict[str, Any] | None:
    node: Any = doc
    for part in path:
        try:
            node = node[part]
        except (KeyError, IndexError, TypeError):
            return None
    return node if isinstance(node, dict) else None


def dump(doc: dict[str, Any]) -> str | None:
    """TOML text of ``doc``, or None when tomlkit cannot write it (not what is tested)."""
    try:
        text = tomlkit.dumps(doc)
        tomllib.loads(text)
    except Exception:
        return None
    return text


def check_parse(tally: Tally, text: str, source: Path) -> None:
    try:
        config = parse_config(text, source=source)
    except ConfigError as exc:
        one_line_error(str(exc), f"{source}:")
        tally("refused")
        return
    assert isinstance(config, GatewayConfig)
    tally("accepted")


def test_fuzz_valid_document_with_random_edits(tmp_path: Path) -> None:
    tally = Tally("config parser: valid document, random key edits")
    source = tmp_path / "gateway.toml"
    check_parse(Tally("baseline"), dump(VALID) or "", source)  # the base itself parses

    @FUZZ
    @given(edits)
    def run(changes: list[tuple[tuple[Any, ...], str | None, st.DataObject, object]]) -> None:
        doc = copy.deepcopy(VALID)
        for path, key, data, value in changes:
            table = _table(doc, path)
            if table is None:
                continue
            name = key if key is not None else data.draw(st.sampled_from(KEYS[path]))
            if value is None:
                table.pop(name, None)
            else:
                table[name] = value
        text = dump(doc)
        if text is None:
            tally("not writable as TOML")
            return
        check_parse(tally, text, source)

    run()
    tally.report()


@st.composite
def toml_like_text(draw: st.DrawFn) -> str:
    """Text that looks like TOML: lines of real keys, headers and random values, or junk."""
    keys = sorted({k for ks in KEYS.values() for k in ks})
    headers = [
        "[metrics]",
        "[[bus]]",
        "[[bus.device]]",
        "[bus.device.registers]",
        "[bus.device.clock]",
        "[bus.device.front_end]",
        "[[bus.device.channel]]",
        "[mqtt]",
        "[bus.tls]",
        "[bus]",
        "[[metrics]]",
        "[bus.device]",
        "[[bus.device.model.params]]",
        "[",
        "[[",
        "]]",
    ]
    lines = []
    for _ in range(draw(st.integers(0, 25))):
        kind = draw(st.sampled_from(["header", "key", "junk"]))
        if kind == "header":
            lines.append(draw(st.sampled_from(headers)))
        elif kind == "key":
            value = draw(toml_values(1))
            try:
                shown = tomlkit.item(value).as_string()  # type: ignore[arg-type]
            except Exception:
                shown = repr(value)
            lines.append(f"{draw(st.sampled_from(keys))} = {shown}")
        else:
            lines.append(draw(st.text(max_size=30)))
    return "\n".join(lines)


def test_fuzz_random_text(tmp_path: Path) -> None:
    tally = Tally("config parser: random TOML-like text")
    source = tmp_path / "gateway.toml"

    @FUZZ
    @given(st.one_of(toml_like_text(), st.text(max_size=300)))
    def run(text: str) -> None:
        check_parse(tally, text, source)

    run()
    tally.report()


def test_fuzz_random_bytes_in_a_file(tmp_path: Path) -> None:
    tally = Tally("config parser: random bytes read from a file")
    source = tmp_path / "gateway.toml"

    @FUZZ
    @given(
        st.one_of(
            st.binary(max_size=400),
            toml_like_text().map(lambda t: t.encode("utf-8")),
            st.tuples(toml_like_text(), st.binary(min_size=1, max_size=8)).map(
                lambda p: p[0].encode("utf-8") + p[1]
            ),
        )
    )
    def run(data: bytes) -> None:
        source.write_bytes(data)
        try:
            load_config(source)
        except ConfigError as exc:
            one_line_error(str(exc), f"{source}:")
            tally("refused")
            return
        tally("accepted")

    run()
    tally.report()


#: Device files named where a file is expected: refused unread (never read without limit).
DEVICE_FILES = ("/dev/zero", "/dev/urandom")


@pytest.mark.parametrize(
    "key",
    [
        "profile",
        "calibration",
    ],
)
@pytest.mark.parametrize("device_file", DEVICE_FILES)
def test_a_device_file_named_as_a_profile_or_calibration_is_refused_not_read(
    tmp_path: Path, key: str, device_file: str
) -> None:
    """Found by the fuzz (a path such as /dev/zero among the strings): a profile or
    calibration file is read without a size limit or a regular-file check, so
    ``profile = "/dev/zero"`` reads until memory runs out. Run in a child process with a
    1 GiB address-space limit and a 20 s timeout, so that the bug cannot hurt the machine."""
    value = f'"{device_file}"'
    text = textwrap.dedent(f"""\
        [[bus]]
        name = "bench"
        kind = "tcp"
        host = "127.0.0.1"

        [[bus.device]]
        name = "arr"
        device_id = 1
        {"profile = " + value if key == "profile" else 'profile = "tactile-sim"'}
        channels = 4
        {"calibration = " + value if key == "calibration" else ""}
        """)
    source = tmp_path / "gateway.toml"
    source.write_text(text, encoding="utf-8")
    child = textwrap.dedent(f"""\
        import resource, sys
        resource.setrlimit(resource.RLIMIT_AS, (1 << 30, 1 << 30))
        from gateway.config import load_config
        from gateway.errors import ConfigError
        try:
            load_config({str(source)!r})
        except ConfigError as exc:
            print("ConfigError:", exc)
            sys.exit(0)
        except BaseException as exc:
            print("other:", type(exc).__name__, exc)
            sys.exit(3)
        print("accepted")
        sys.exit(4)
        """)
    try:
        done = subprocess.run(
            [sys.executable, "-c", child],
            capture_output=True,
            text=True,
            timeout=20,
            env={**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[2])},
        )
    except subprocess.TimeoutExpired:
        pytest.fail(f"{key} = {value}: still reading after 20 s")
    out = done.stdout.strip()
    assert done.returncode == 0, f"{key} = {value}: {out or done.stderr[-500:]}"
    message = out.removeprefix("ConfigError: ")
    one_line_error(message, f"{source}:")
    assert device_file in message, message


def test_an_unknown_key_with_a_newline_is_named_on_one_line(tmp_path: Path) -> None:
    """Found by the fuzz: a quoted key holding a newline (``"\\n" = 0``) was named with the
    raw newline, so the refusal spanned two lines."""
    source = tmp_path / "gateway.toml"
    with pytest.raises(ConfigError) as caught:
        parse_config('[metrics]\n"a\\nb\\\\c\\"d" = 1\n', source=source)
    one_line_error(str(caught.value), f"{source}:")
    assert 'metrics."a\\nb\\\\c\\"d": unknown key' in str(caught.value)
