"""``gateway.config``: loading, validation messages, defaults, and the read plan."""

from __future__ import annotations

import itertools
import math
from dataclasses import replace
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from gateway.config import (
    DeviceConfig,
    GatewayConfig,
    MetricsConfig,
    RegisterMap,
    TlsConfig,
    load_config,
    parse_config,
)
from gateway.errors import ConfigError
from gateway.modbus.plan import ReadRequest, block_registers, read_plan
from gateway.modbus.register_map import register_blocks
from gateway.model import PAPER_EFFECTS, Divider, SensorParams

REPO = Path(__file__).resolve().parents[4]
SOURCE = Path("/cfg/gateway.toml")

BASE = """\
[metrics]
address = "127.0.0.1:9830"

[[bus]]
name = "bench"
kind = "tcp"
host = "127.0.0.1"
port = 5020

[[bus.device]]
name = "array1"
device_id = 1
channels = 16
"""

RTU = """\
[[bus]]
name = "line"
kind = "rtu"
serial_port = "/dev/ttyUSB0"

[[bus.device]]
name = "rtu1"
device_id = 1
channels = 4
"""


def with_bus(extra: str) -> str:
    """BASE with ``extra`` keys in the [[bus]] table."""
    return BASE.replace("port = 5020\n", f"port = 5020\n{extra}\n")


def with_device(extra: str) -> str:
    """BASE with ``extra`` keys (or sub-tables) at the end of the [[bus.device]] table."""
    return BASE + extra + "\n"


def replaced(old: str, new: str, text: str = BASE) -> str:
    assert old in text, old
    return text.replace(old, new)


def parse(text: str, source: Path | None = SOURCE) -> GatewayConfig:
    return parse_config(text, source=source)


# (id, configuration text, fragments the message must contain)
BAD_CONFIGS: list[tuple[str, str, tuple[str, ...]]] = [
    ("toml-syntax", BASE + "x = \n", ("invalid TOML at line 14, column 5", "Invalid value")),
    ("toml-duplicate-key", replaced("port = 5020", "port = 5020\nport = 5021"), ("invalid TOML at line 9",)),
    ("root-unknown-key", replaced("[[bus]]", "[[buses]]"), ("buses: unknown key; did you mean 'bus'?",)),
    (
        "metrics-unknown-key",
        replaced("address =", "adress ="),
        ("metrics.adress: unknown key; did you mean 'address'?",),
    ),
    (
        "metrics-no-port",
        replaced('"127.0.0.1:9830"', '"localhost"'),
        ("metrics.address", "HOST:PORT", "1..65535"),
    ),
    ("metrics-port-0", replaced(":9830", ":0"), ("metrics.address: port '0'", "allowed: 1..65535")),
    ("metrics-port-big", replaced(":9830", ":65536"), ("metrics.address", "allowed: 1..65535")),
    ("metrics-ipv6-brackets", replaced('"127.0.0.1:9830"', '"::1:9830"'), ("metrics.address", "[::1]:9830")),
    ("metrics-bad-host", replaced('"127.0.0.1:9830"', '"bad host:9830"'), ("metrics.address", "HOST:PORT")),
    (
        "metrics-type",
        replaced('"127.0.0.1:9830"', "9830"),
        ("metrics.address: expected a string", "got integer"),
    ),
    (
        "metrics-web-missing",
        replaced("[[bus]]", 'web_config = "web.yml"\n\n[[bus]]'),
        ("metrics.web_config",),
    ),
    (
        "bus-single-table",
        replaced("[[bus]]", "[bus]"),
        ("bus: expected an array of tables ([[bus]]), got a single table; write [[bus]]",),
    ),
    ("bus-none", '[metrics]\naddress = "127.0.0.1:9830"\n', ("bus: at least one [[bus]]",)),
    (
        "bus-name-missing",
        replaced('name = "bench"\n', ""),
        ("bus[0].name: required key is missing", "[a-z0-9_-]{1,32}"),
    ),
    (
        "bus-name-pattern",
        replaced('"bench"', '"Bench!"'),
        ("bus[0].name: 'Bench!' is not a name matching [a-z0-9_-]{1,32}",),
    ),
    ("bus-name-long", replaced('"bench"', '"' + "b" * 33 + '"'), ("bus[0].name", "[a-z0-9_-]{1,32}")),
    (
        "bus-kind-missing",
        replaced('kind = "tcp"\n', ""),
        ("bus[0].kind: required key is missing", "tcp | rtu"),
    ),
    (
        "bus-kind-typo",
        replaced('"tcp"', '"tpc"'),
        ("bus[0].kind: 'tpc' is not allowed; did you mean 'tcp'?", "tls"),
    ),
    (
        "bus-unknown-key",
        replaced("port = 5020", "prot = 5020"),
        ("bus[0].prot: unknown key; did you mean 'port'?",),
    ),
    ("bus-host-missing", replaced('host = "127.0.0.1"\n', ""), ("bus[0].host: required key is missing",)),
    ("bus-host-bad", replaced('"127.0.0.1"\nport', '"no such host"\nport'), ("bus[0].host: 'no such host'",)),
    ("bus-port-range", replaced("5020", "70000"), ("bus[0].port: 70000 is out of range; allowed: 1..65535",)),
    (
        "bus-port-type",
        replaced("5020", '"5020"'),
        ("bus[0].port: expected an integer in 1..65535, got string '5020'",),
    ),
    (
        "bus-port-float",
        replaced("5020", "5020.0"),
        ("bus[0].port: expected an integer in 1..65535, got float",),
    ),
    (
        "bus-serial-on-tcp",
        with_bus('serial_port = "/dev/ttyUSB0"'),
        ("bus[0].serial_port: not used by kind = 'tcp'; allowed only with kind rtu",),
    ),
    (
        "bus-host-on-rtu",
        replaced('serial_port = "/dev/ttyUSB0"', 'serial_port = "/dev/ttyUSB0"\nhost = "h"', RTU),
        ("bus[0].host: not used by kind = 'rtu'", "tcp, rtu-over-tcp, tls"),
    ),
    (
        "rtu-serial-missing",
        replaced('serial_port = "/dev/ttyUSB0"\n', "", RTU),
        ("bus[0].serial_port: required key",),
    ),
    (
        "rtu-baudrate",
        replaced('/dev/ttyUSB0"', '/dev/ttyUSB0"\nbaudrate = 12345', RTU),
        ("bus[0].baudrate: 12345 is not a standard rate; allowed: 1200, 2400", "921600"),
    ),
    (
        "rtu-parity",
        replaced('/dev/ttyUSB0"', '/dev/ttyUSB0"\nparity = "X"', RTU),
        ("bus[0].parity: 'X' is not allowed", "(allowed: N | E | O)"),
    ),
    (
        "rtu-stopbits",
        replaced('/dev/ttyUSB0"', '/dev/ttyUSB0"\nstopbits = 3', RTU),
        ("bus[0].stopbits: 3 is out of range; allowed: 1..2",),
    ),
    (
        "rtu-bytesize",
        replaced('/dev/ttyUSB0"', '/dev/ttyUSB0"\nbytesize = 9', RTU),
        ("bus[0].bytesize: 9 is out of range; allowed: 7..8",),
    ),
    (
        "rtu-shared-port",
        RTU + RTU.replace('"line"', '"line2"').replace('"rtu1"', '"rtu2"'),
        ("bus[1].serial_port: '/dev/ttyUSB0' is already used by bus[0]",),
    ),
    ("timeout-zero", with_bus("timeout_s = 0"), ("bus[0].timeout_s: 0 is out of range; allowed: (0, 60] s",)),
    (
        "timeout-big",
        with_bus("timeout_s = 61.0"),
        ("bus[0].timeout_s: 61.0 is out of range; allowed: (0, 60] s",),
    ),
    (
        "timeout-nan",
        with_bus("timeout_s = nan"),
        ("bus[0].timeout_s: nan is out of range; allowed: (0, 60] s",),
    ),
    (
        "timeout-bool",
        with_bus("timeout_s = true"),
        ("bus[0].timeout_s: expected a number in (0, 60] s, got boolean",),
    ),
    ("retries", with_bus("retries = 11"), ("bus[0].retries: 11 is out of range; allowed: 0..10",)),
    ("retries-negative", with_bus("retries = -1"), ("bus[0].retries: -1 is out of range; allowed: 0..10",)),
    (
        "poll-interval",
        with_bus("poll_interval_s = 0.0001"),
        ("bus[0].poll_interval_s", "allowed: [0.001, 3600] s"),
    ),
    ("max-read", with_bus("max_read_registers = 126"), ("bus[0].max_read_registers: 126", "allowed: 1..125")),
    (
        "max-read-zero",
        with_bus("max_read_registers = 0"),
        ("bus[0].max_read_registers: 0", "allowed: 1..125"),
    ),
    (
        "backoff-initial",
        with_bus("backoff_initial_s = 0"),
        ("bus[0].backoff_initial_s: 0", "allowed: (0, 60] s"),
    ),
    (
        "backoff-max-below",
        with_bus("backoff_max_s = 0.1"),
        ("bus[0].backoff_max_s: 0.1 is out of range; allowed: [0.5, 3600] s (>= backoff_initial_s)",),
    ),
    ("backoff-max-big", with_bus("backoff_max_s = 7200"), ("bus[0].backoff_max_s: 7200", "[0.5, 3600]")),
    (
        "tls-on-tcp",
        with_device("[bus.tls]\nverify = false"),
        ("bus[0].tls: [bus.tls] is not used by kind = 'tcp'; allowed only with kind tls",),
    ),
    (
        "tls-key-needs-cert",
        replaced('"tcp"', '"tls"', with_device('[bus.tls]\nkey_file = "k.pem"')),
        ("bus[0].tls.key_file: needs cert_file",),
    ),
    (
        "tls-ca-missing",
        replaced('"tcp"', '"tls"', with_device('[bus.tls]\nca_file = "ca.pem"')),
        ("bus[0].tls.ca_file: /cfg/ca.pem does not exist",),
    ),
    (
        "tls-unknown",
        replaced('"tcp"', '"tls"', with_device("[bus.tls]\nverfy = false")),
        ("bus[0].tls.verfy: unknown key; did you mean 'verify'?",),
    ),
    (
        "tls-verify-type",
        replaced('"tcp"', '"tls"', with_device('[bus.tls]\nverify = "no"')),
        ("bus[0].tls.verify: expected a boolean (true or false), got string 'no'",),
    ),
    ("device-none", BASE.split("[[bus.device]]")[0], ("bus[0].device: at least one [[bus.device]]",)),
    (
        "device-type",
        BASE.split("[[bus.device]]")[0] + 'device = "array1"\n',
        ("bus[0].device: expected an array of tables ([[bus.device]]), got string",),
    ),
    (
        "device-name-missing",
        replaced('name = "array1"\n', ""),
        ("bus[0].device[0].name: required key is missing",),
    ),
    (
        "device-unknown-key",
        with_device("chanels = 4"),
        ("bus[0].device[0].chanels: unknown key; did you mean 'channels'?",),
    ),
    (
        "device-id-zero",
        replaced("device_id = 1", "device_id = 0"),
        ("bus[0].device[0].device_id: 0 is out of range; allowed: 1..247",),
    ),
    (
        "device-id-big",
        replaced("device_id = 1", "device_id = 248"),
        ("bus[0].device[0].device_id: 248", "1..247"),
    ),
    (
        "device-id-missing",
        replaced("device_id = 1\n", ""),
        ("bus[0].device[0].device_id: required key is missing",),
    ),
    (
        "device-id-duplicate",
        BASE + '\n[[bus.device]]\nname = "array2"\ndevice_id = 1\nchannels = 4\n',
        ("bus[0].device[1].device_id: duplicate device_id 1 on bus 'bench'", "unique per bus"),
    ),
    (
        "device-name-duplicate",
        BASE + RTU.replace('"rtu1"', '"array1"'),
        ("bus[1].device[0].name: duplicate device name 'array1' (also bus[0].device[0].name)",),
    ),
    (
        "bus-name-duplicate",
        BASE + RTU.replace('"line"', '"bench"'),
        ("bus[1].name: duplicate bus name 'bench'",),
    ),
    (
        "encoding",
        with_device('encoding = "float"'),
        ("bus[0].device[0].encoding: 'float' is not allowed; did you mean 'float32'?", "adc | float32"),
    ),
    (
        "channels-zero",
        replaced("channels = 16", "channels = 0"),
        ("bus[0].device[0].channels: 0", "allowed: 1..256"),
    ),
    (
        "channels-big",
        replaced("channels = 16", "channels = 257"),
        ("bus[0].device[0].channels: 257", "1..256"),
    ),
    (
        "channels-missing",
        replaced("channels = 16\n", ""),
        ("bus[0].device[0].channels: required key is missing",),
    ),
    (
        "columns",
        with_device("columns = 17"),
        ("bus[0].device[0].columns: 17 is out of range; allowed: 1..16",),
    ),
    ("pitch", with_device("pitch_mm = 0"), ("bus[0].device[0].pitch_mm: 0", "allowed: (0, 1000] mm")),
    (
        "allow-write-type",
        with_device('allow_write = "yes"'),
        ("bus[0].device[0].allow_write: expected a boolean (true or false), got string 'yes'",),
    ),
    (
        "calibration-missing",
        with_device('calibration = "cal.toml"'),
        ("bus[0].device[0].calibration: /cfg/cal.toml does not exist",),
    ),
    (
        "adc-bits",
        with_device("[bus.device.divider]\nadc_bits = 20"),
        ("bus[0].device[0].divider.adc_bits: 20 is out of range; allowed: 8..16",),
    ),
    (
        "supply-negative",
        with_device("[bus.device.divider]\nsupply_v = -5.0"),
        ("bus[0].device[0].divider.supply_v: -5.0 is out of range; allowed: (0, inf) V",),
    ),
    (
        "reference-inf",
        with_device("[bus.device.divider]\nreference_ohm = inf"),
        ("bus[0].device[0].divider.reference_ohm: inf is out of range; allowed: (0, inf) ohm",),
    ),
    (
        "divider-unknown",
        with_device("[bus.device.divider]\nbits = 12"),
        ("bus[0].device[0].divider.bits: unknown key; did you mean 'adc_bits'?",),
    ),
    (
        "adc-address-fit",
        with_device("[bus.device.registers]\nadc_address = 65530"),
        ("bus[0].device[0].registers.adc_address: 65530 is out of range; allowed: 0..65520",),
    ),
    (
        "float-address-fit",
        with_device("[bus.device.registers]\nfloat_address = 65510"),
        ("bus[0].device[0].registers.float_address: 65510", "allowed: 0..65504"),
    ),
    (
        "status-address",
        with_device("[bus.device.registers]\nstatus_address = -2"),
        ("bus[0].device[0].registers.status_address: -2", "allowed: 0..65503, or -1 to disable"),
    ),
    (
        "word-order",
        with_device('[bus.device.registers]\nword_order = "middle"'),
        ("bus[0].device[0].registers.word_order: 'middle' is not allowed", "big | little"),
    ),
    (
        "register-overlap",
        with_device("[bus.device.registers]\nforce_reference_address = 110"),
        (
            "bus[0].device[0].registers.force_reference_address: ",
            "the force_reference block 110..141 overlaps the adc block 100..115",
        ),
    ),
    (
        "max-read-float",
        replaced("port = 5020", "port = 5020\nmax_read_registers = 1", with_device('encoding = "float32"')),
        ("bus[0].max_read_registers: 1 is too small for device 'array1'", "allowed: 2..125"),
    ),
    (
        "effects-unknown",
        with_device('[bus.device.model]\neffects = ["tunneling", "crep"]'),
        ("bus[0].device[0].model.effects[1]: unknown effect 'crep'; did you mean 'creep'?",),
    ),
    (
        "effects-type",
        with_device('[bus.device.model]\neffects = "creep"'),
        ("bus[0].device[0].model.effects: expected an array of effect names",),
    ),
    (
        "model-unknown",
        with_device('[bus.device.model]\neffect = ["creep"]'),
        ("bus[0].device[0].model.effect: unknown key; did you mean 'effects'?",),
    ),
    (
        "param-unknown",
        with_device("[bus.device.model.params]\nr0_ohn = 1.0"),
        ("bus[0].device[0].model.params.r0_ohn: unknown sensor parameter 'r0_ohn'; did you mean 'r0_ohm'?",),
    ),
    (
        "param-range",
        with_device("[bus.device.model.params]\nr0_ohm = -1.0"),
        (
            "bus[0].device[0].model.params.r0_ohm: ",
            "parameter r0_ohm = -1.0 is outside its allowed range (0, inf)",
        ),
    ),
    (
        "param-type",
        with_device('[bus.device.model.params]\nr0_ohm = "big"'),
        ("bus[0].device[0].model.params.r0_ohm: parameter r0_ohm must be a number, got str",),
    ),
    (
        "param-cross",
        with_device("[bus.device.model.params]\nforce_min_n = 5.0\nforce_max_n = 1.0"),
        ("bus[0].device[0].model.params: force_min_n (5 N) must be below force_max_n (1 N)",),
    ),
    (
        "channel-index-range",
        with_device("[[bus.device.channel]]\nindex = 16"),
        ("bus[0].device[0].channel[0].index: 16 is out of range; allowed: 0..15 (channels = 16)",),
    ),
    (
        "channel-index-missing",
        with_device('[[bus.device.channel]]\nname = "tip"'),
        ("bus[0].device[0].channel[0].index: required key is missing",),
    ),
    (
        "channel-index-duplicate",
        with_device("[[bus.device.channel]]\nindex = 3\n[[bus.device.channel]]\nindex = 3"),
        (
            "bus[0].device[0].channel[1].index: ",
            "duplicate channel index 3 (also bus[0].device[0].channel[0].index)",
        ),
    ),
    (
        "channel-name-duplicate",
        with_device(
            '[[bus.device.channel]]\nindex = 0\nname = "tip"\n[[bus.device.channel]]\nindex = 1\nname = "tip"'
        ),
        ("bus[0].device[0].channel[1].name: duplicate channel name 'tip': channels 0 and 1",),
    ),
    (
        "channel-name-default-clash",
        with_device('[[bus.device.channel]]\nindex = 0\nname = "ch05"'),
        ("bus[0].device[0].channel[0].name: duplicate channel name 'ch05': channels 0 and 5",),
    ),
    (
        "channel-name-pattern",
        with_device('[[bus.device.channel]]\nindex = 0\nname = "Tip"'),
        ("bus[0].device[0].channel[0].name: 'Tip' is not a name matching [a-z0-9_-]{1,32}",),
    ),
    (
        "channel-x",
        with_device("[[bus.device.channel]]\nindex = 0\nx_mm = 1e9"),
        ("bus[0].device[0].channel[0].x_mm: 1000000000.0 is out of range; allowed: [-10000, 10000] mm",),
    ),
    (
        "channel-unknown-key",
        with_device("[[bus.device.channel]]\nindex = 0\nenable = false"),
        ("bus[0].device[0].channel[0].enable: unknown key; did you mean 'enabled'?",),
    ),
    (
        "channel-effects",
        with_device('[[bus.device.channel]]\nindex = 0\neffects = ["leak"]'),
        ("bus[0].device[0].channel[0].effects[0]: unknown effect 'leak'; did you mean 'leakage'?",),
    ),
    (
        "channel-param",
        with_device("[[bus.device.channel]]\nindex = 2\nparams = { force_max_n = 0.0 }"),
        (
            "bus[0].device[0].channel[0].params.force_max_n: ",
            "parameter force_max_n = 0.0 is outside its allowed range (0, inf)",
        ),
    ),
    (
        "channel-param-cross",
        with_device("[[bus.device.channel]]\nindex = 2\nparams = { force_max_n = 0.01 }"),
        (
            "bus[0].device[0].channel[0].params: force_min_n (0.05 N) must be below force_max_n (0.01 N)",
            "index 2",
        ),
    ),
    (
        "channel-params-type",
        with_device("[[bus.device.channel]]\nindex = 2\nparams = 5"),
        ("bus[0].device[0].channel[0].params: expected a table",),
    ),
]


@pytest.mark.parametrize(
    ("text", "fragments"), [(t, f) for _, t, f in BAD_CONFIGS], ids=[i for i, _, _ in BAD_CONFIGS]
)
def test_bad_config_is_refused_with_a_precise_message(text: str, fragments: tuple[str, ...]) -> None:
    with pytest.raises(ConfigError) as info:
        parse(text)
    message = str(info.value)
    assert message.startswith(f"{SOURCE}: "), message
    for fragment in fragments:
        assert fragment in message, f"{fragment!r} not in {message!r}"


def test_the_table_is_large_and_its_ids_unique() -> None:
    ids = [i for i, _, _ in BAD_CONFIGS]
    assert len(ids) >= 25
    assert len(set(ids)) == len(ids)


def test_message_without_a_file_says_string() -> None:
    with pytest.raises(ConfigError, match=r"^<string>: bus\[0\]\.port: 0 is out of range"):
        parse_config(replaced("5020", "0"))


# ----------------------------------------------------------------------------------------------
# Valid configurations and defaults


def test_minimal_config_gets_every_default() -> None:
    config = parse(BASE)
    assert config.source == SOURCE
    assert config.metrics == MetricsConfig("127.0.0.1", 9830, None)
    (bus,) = config.buses
    assert (bus.name, bus.kind, bus.host, bus.port, bus.serial_port, bus.tls) == (
        "bench",
        "tcp",
        "127.0.0.1",
        5020,
        None,
        None,
    )
    assert (bus.timeout_s, bus.retries, bus.poll_interval_s) == (1.0, 2, 0.1)
    assert (bus.max_read_registers, bus.backoff_initial_s, bus.backoff_max_s) == (125, 0.5, 30.0)
    (dev,) = bus.devices
    assert (dev.name, dev.device_id, dev.encoding, dev.n_channels) == ("array1", 1, "adc", 16)
    assert dev.registers == RegisterMap()
    assert dev.registers.status_address == 16 and dev.registers.force_reference_address is None
    assert dev.divider == Divider()
    assert (dev.allow_write, dev.columns, dev.pitch_mm, dev.calibration) == (False, 4, 2.5, None)
    assert [ch.name for ch in dev.channels] == [f"ch{i:02d}" for i in range(16)]
    assert all(
        ch.enabled and ch.effects == PAPER_EFFECTS and ch.params == SensorParams() for ch in dev.channels
    )
    assert (dev.channels[6].x_mm, dev.channels[6].y_mm) == (5.0, 2.5)
    assert (dev.channels[15].x_mm, dev.channels[15].y_mm) == (7.5, 7.5)


def test_metrics_defaults_when_the_table_is_absent() -> None:
    config = parse(BASE.split("\n", 3)[3])
    assert config.metrics == MetricsConfig()


def test_ipv6_metrics_address_and_host() -> None:
    config = parse(replaced('"127.0.0.1:9830"', '"[::1]:9831"', replaced('"127.0.0.1"\n', '"::1"\n')))
    assert (config.metrics.host, config.metrics.port) == ("::1", 9831)
    assert config.buses[0].host == "::1"
    assert config.buses[0].endpoint == "[::1]:5020"


def test_port_defaults_depend_on_the_kind() -> None:
    tcp = parse(replaced("port = 5020\n", ""))
    tls = parse(replaced('"tcp"', '"tls"', replaced("port = 5020\n", "")))
    over = parse(replaced('"tcp"', '"rtu-over-tcp"'))
    assert tcp.buses[0].port == 502
    assert tls.buses[0].port == 802
    assert tls.buses[0].tls == TlsConfig(None, None, None, None, True)
    assert over.buses[0].kind == "rtu-over-tcp"


def test_rtu_bus_defaults_and_values() -> None:
    config = parse(RTU)
    bus = config.buses[0]
    assert (bus.host, bus.port, bus.serial_port) == (None, None, "/dev/ttyUSB0")
    assert (bus.baudrate, bus.parity, bus.stopbits, bus.bytesize) == (19200, "E", 1, 8)
    custom = parse(
        replaced('"/dev/ttyUSB0"', '"/dev/ttyUSB0"\nbaudrate = 115200\nparity = "N"\nstopbits = 2', RTU)
    )
    assert (custom.buses[0].baudrate, custom.buses[0].parity, custom.buses[0].stopbits) == (115200, "N", 2)
    assert custom.buses[0].endpoint == "/dev/ttyUSB0"


def test_backoff_max_default_follows_a_large_initial_backoff() -> None:
    assert parse(with_bus("backoff_initial_s = 45")).buses[0].backoff_max_s == 45.0


def test_full_device_config() -> None:
    text = with_device(
        """\
encoding = "float32"
columns = 8
pitch_mm = 4.0
allow_write = true
[bus.device.registers]
float_address = 400
word_order = "little"
status_address = -1
force_reference_address = 1000
temperature_address = 1600
[bus.device.divider]
supply_v = 3.3
reference_ohm = 4700
adc_bits = 12
[bus.device.model]
effects = ["creep", "leakage"]
[bus.device.model.params]
r0_ohm = 150000.0
force_max_n = 5
[[bus.device.channel]]
index = 9
name = "tip"
x_mm = -1.5
enabled = false
effects = []
params = { r0_ohm = 190000.0 }
"""
    )
    dev = parse(text).buses[0].devices[0]
    assert dev.encoding == "float32" and dev.allow_write
    assert dev.registers == RegisterMap(100, 400, "little", "big", None, 1000, 1600)
    assert dev.divider == Divider(3.3, 4700.0, 12)
    assert dev.channels[0].effects == ("tunneling", "creep", "leakage")
    assert dev.channels[0].params == SensorParams(r0_ohm=150000.0, force_max_n=5.0)
    tip = dev.channel("tip")
    assert (tip.index, tip.x_mm, tip.y_mm, tip.enabled, tip.effects) == (9, -1.5, 4.0, False, ("tunneling",))
    assert tip.params == SensorParams(r0_ohm=190000.0, force_max_n=5.0)
    assert [c.index for c in dev.enabled_channels] == [i for i in range(16) if i != 9]


def test_parameter_precedence_device_calibration_channel(tmp_path: Path) -> None:
    (tmp_path / "cal.toml").write_text(
        "[meta]\nnote = 'fit of 2025-01-31'\n\n[channel.tip]\nr0_ohm = 180000.0\ne0_pa = 14e6\n\n"
        "[channel.ch02]\nr0_ohm = 170000.0\n"
    )
    config_file = tmp_path / "gateway.toml"
    config_file.write_text(
        with_device(
            'calibration = "cal.toml"\n[bus.device.model.params]\nr0_ohm = 150000.0\ne1_pa = 2e8\n'
            '[[bus.device.channel]]\nindex = 0\nname = "tip"\nparams = { e0_pa = 16e6 }\n'
        )
    )
    dev = load_config(config_file).buses[0].devices[0]
    assert dev.calibration == tmp_path / "cal.toml"
    tip = dev.channel("tip").params
    assert (tip.r0_ohm, tip.e0_pa, tip.e1_pa) == (180000.0, 16e6, 2e8)  # calibration, channel, device
    assert dev.channel("ch02").params.r0_ohm == 170000.0
    assert dev.channel("ch01").params.r0_ohm == 150000.0


def test_calibration_errors_name_the_calibration_file(tmp_path: Path) -> None:
    (tmp_path / "cal.toml").write_text("[channel.tpi]\nr0_ohm = 1.0\n")
    config_file = tmp_path / "gateway.toml"
    config_file.write_text(
        with_device('calibration = "cal.toml"\n[[bus.device.channel]]\nindex = 0\nname = "tip"\n')
    )
    with pytest.raises(ConfigError) as info:
        load_config(config_file)
    message = str(info.value)
    assert message.startswith(f"{tmp_path / 'cal.toml'}: channel.tpi: no channel 'tpi'")
    assert "did you mean 'tip'?" in message
    assert f"calibration file of bus[0].device[0].calibration in {config_file}" in message
    (tmp_path / "cal.toml").write_text("[channel.tip]\nr0_ohm = 0.0\n")
    with pytest.raises(ConfigError, match=r"channel\.tip\.r0_ohm: parameter r0_ohm = 0\.0 is outside"):
        load_config(config_file)


def test_relative_paths_are_relative_to_the_config_file(tmp_path: Path) -> None:
    (tmp_path / "conf").mkdir()
    web = tmp_path / "conf" / "web.yml"
    web.write_text("basic_auth_users: {}\n")
    web.chmod(0o600)
    config_file = tmp_path / "conf" / "gateway.toml"
    config_file.write_text(replaced("[[bus]]", 'web_config = "web.yml"\n\n[[bus]]'))
    assert load_config(config_file).metrics.web_config == web


def test_many_channels_names_and_grid() -> None:
    dev = parse(replaced("channels = 16", "channels = 150")).buses[0].devices[0]
    assert dev.columns == 13
    assert dev.channels[149].name == "ch149"
    assert (dev.channels[14].x_mm, dev.channels[14].y_mm) == (2.5, 2.5)


def test_shipped_example_is_valid_and_polls_the_simulator() -> None:
    config = load_config(REPO / "examples" / "gateway.toml")
    (bus,) = config.buses
    assert (bus.kind, bus.host, bus.port) == ("tcp", "127.0.0.1", 5020)
    assert bus.devices[0].n_channels == 16


def test_shipped_example_rtu_section_is_valid_when_uncommented() -> None:
    lines = (REPO / "examples" / "gateway.toml").read_text().splitlines()
    start = lines.index("# [[bus]]")
    body = [line[2:] if line.startswith("# ") else "" if line == "#" else line for line in lines[start:]]
    config = parse_config("\n".join(lines[:start] + body), source=REPO / "examples" / "gateway.toml")
    rtu = config.buses[1]
    assert (rtu.kind, rtu.serial_port, rtu.baudrate, rtu.parity) == ("rtu", "/dev/ttyUSB0", 115200, "N")


def test_load_config_unreadable_file(tmp_path: Path) -> None:
    missing = tmp_path / "nope.toml"
    with pytest.raises(ConfigError, match=rf"^{missing}: cannot read the configuration file"):
        load_config(missing)


def test_load_config_not_utf8(tmp_path: Path) -> None:
    bad = tmp_path / "latin1.toml"
    bad.write_bytes(BASE.replace("array1", "arr\xe4y").encode("latin-1"))
    with pytest.raises(ConfigError, match="not UTF-8"):
        load_config(bad)


# ----------------------------------------------------------------------------------------------
# Secrets must not be readable by other users


def _tls_config(tmp_path: Path) -> Path:
    for name in ("ca.pem", "client.pem", "client.key"):
        (tmp_path / name).write_text("-----BEGIN-----\n")
    config_file = tmp_path / "gateway.toml"
    config_file.write_text(
        with_device(
            '[bus.tls]\nca_file = "ca.pem"\ncert_file = "client.pem"\nkey_file = "client.key"\n'
            'server_hostname = "array1.local"\n'
        ).replace('"tcp"', '"tls"')
    )
    return config_file


@pytest.mark.parametrize("mode", [0o644, 0o640, 0o604, 0o610])
def test_readable_tls_key_is_refused(tmp_path: Path, mode: int) -> None:
    config_file = _tls_config(tmp_path)
    key = tmp_path / "client.key"
    key.chmod(mode)
    with pytest.raises(ConfigError) as info:
        load_config(config_file)
    message = str(info.value)
    assert message.startswith(f"{config_file}: bus[0].tls.key_file: {key}")
    assert f"mode {mode:04o}" in message
    assert f"run `chmod 600 {key}`" in message


def test_private_tls_key_is_accepted(tmp_path: Path) -> None:
    config_file = _tls_config(tmp_path)
    (tmp_path / "client.key").chmod(0o600)
    tls = load_config(config_file).buses[0].tls
    assert tls == TlsConfig(
        tmp_path / "ca.pem", tmp_path / "client.pem", tmp_path / "client.key", "array1.local", True
    )


def test_readable_web_config_is_refused(tmp_path: Path) -> None:
    web = tmp_path / "web.yml"
    web.write_text("basic_auth_users:\n  prom: $2b$12$hash\n")
    web.chmod(0o640)
    config_file = tmp_path / "gateway.toml"
    config_file.write_text(replaced("[[bus]]", 'web_config = "web.yml"\n\n[[bus]]'))
    with pytest.raises(ConfigError, match=rf"metrics\.web_config: .*mode 0640.*run `chmod 600 {web}`"):
        load_config(config_file)
    web.chmod(0o600)
    assert load_config(config_file).metrics.web_config == web


# ----------------------------------------------------------------------------------------------
# Read plan


def device(
    n: int = 16,
    encoding: str = "adc",
    registers: RegisterMap | None = None,
) -> DeviceConfig:
    base = parse(replaced("channels = 16", f"channels = {n}")).buses[0].devices[0]
    return replace(base, encoding=encoding, registers=registers or RegisterMap())


def test_plan_default_adc_device() -> None:
    plan = read_plan(device(), 125)
    assert plan == (
        ReadRequest("input", 16, 1, ("status",)),
        ReadRequest("input", 32, 1, ("status",)),
        ReadRequest("input", 48, 1, ("status",)),
        ReadRequest("input", 100, 16, ("adc",)),
    )


def test_plan_without_status_is_one_read() -> None:
    plan = read_plan(device(registers=RegisterMap(status_address=None)), 125)
    assert plan == (ReadRequest("input", 100, 16, ("adc",)),)


def test_plan_256_channels_merges_bitmaps_and_splits_the_adc_block() -> None:
    plan = read_plan(device(256), 125)
    assert plan == (
        ReadRequest("input", 16, 48, ("status",)),
        ReadRequest("input", 100, 125, ("adc",)),
        ReadRequest("input", 225, 125, ("adc",)),
        ReadRequest("input", 350, 6, ("adc",)),
    )


@pytest.mark.parametrize(("adc_address", "merged"), [(40, True), (41, True), (42, False)])
def test_plan_gap_of_at_most_8_registers_is_bridged(adc_address: int, merged: bool) -> None:
    regs = RegisterMap(adc_address=adc_address, status_address=0)
    plan = read_plan(device(registers=regs), 125)
    # Bitmaps at 0, 16, 32 (one register each, gaps of 15): the last one is 32.
    if merged:
        assert plan[-1] == ReadRequest("input", 32, adc_address + 16 - 32, ("status", "adc"))
        assert len(plan) == 3
    else:
        assert plan[-2:] == (
            ReadRequest("input", 32, 1, ("status",)),
            ReadRequest("input", adc_address, 16, ("adc",)),
        )


def test_plan_float_block_is_split_on_value_boundaries() -> None:
    plan = read_plan(device(64, "float32", RegisterMap(status_address=None)), 125)
    assert plan == (ReadRequest("input", 400, 124, ("float",)), ReadRequest("input", 524, 4, ("float",)))


def test_plan_odd_limit_with_floats_reads_whole_values() -> None:
    plan = read_plan(device(4, "float32", RegisterMap(status_address=None)), 3)
    assert [(r.address, r.count) for r in plan] == [(400, 2), (402, 2), (404, 2), (406, 2)]


def test_plan_bench_blocks_merge_when_adjacent() -> None:
    regs = RegisterMap(status_address=None, force_reference_address=1000, temperature_address=1036)
    plan = read_plan(device(16, "adc", regs), 125)
    # force 1000..1031, gap 1032..1035 (4 registers), temperature 1036..1067
    assert plan[-1] == ReadRequest("input", 1000, 68, ("force_reference", "temperature"))


def test_plan_limit_too_small_for_floats() -> None:
    with pytest.raises(ValueError, match="cannot hold a float32 value"):
        read_plan(device(4, "float32"), 1)
    adc_only = read_plan(device(4, "adc", RegisterMap(status_address=None)), 1)
    assert [(r.address, r.count) for r in adc_only] == [(100, 1), (101, 1), (102, 1), (103, 1)]


def test_block_registers_reassembles_split_reads() -> None:
    dev = device(64, "float32", RegisterMap(status_address=None))
    plan = read_plan(dev, 125)
    image = {a: a * 3 % 65536 for a in range(0, 1200)}
    responses = [(r, [image[a] for a in range(r.address, r.end + 1)]) for r in plan]
    (block,) = register_blocks(dev)
    assert block_registers(block, responses) == [image[a] for a in range(400, 528)]
    with pytest.raises(ValueError, match="misses register 524"):
        block_registers(block, responses[:1])


@settings(max_examples=200, deadline=None)
@given(
    n=st.integers(1, 256),
    encoding=st.sampled_from(["adc", "float32"]),
    max_read=st.integers(2, 125),
    status=st.one_of(st.none(), st.integers(0, 300)),
    bench=st.booleans(),
    gap=st.integers(0, 12),
)
def test_plan_invariants(
    n: int, encoding: str, max_read: int, status: int | None, bench: bool, gap: int
) -> None:
    force = 2000 if bench else None
    temperature = 2000 + 2 * n + gap if bench else None
    regs = RegisterMap(
        adc_address=400, float_address=1000, status_address=status,
        force_reference_address=force, temperature_address=temperature,
    )  # fmt: skip
    dev = device(n, encoding, regs)
    plan = read_plan(dev, max_read)
    blocks = register_blocks(dev)
    assert all(1 <= r.count <= max_read for r in plan)
    assert all(a.end < b.address for a, b in itertools.pairwise(plan))
    for block in blocks:
        for value in range(block.address, block.end + 1, block.value_registers):
            covering = [r for r in plan if r.address <= value <= r.end]
            assert len(covering) == 1
            assert covering[0].end >= value + block.value_registers - 1  # a float is never split
            assert block.purpose in covering[0].purpose
    # No read starts or ends in a gap between blocks.
    used = {a for b in blocks for a in range(b.address, b.end + 1)}
    assert all(r.address in used and r.end in used for r in plan)
    if bench and gap <= 8 and 4 * n + gap <= max_read - (max_read % 2):
        assert any(r.purpose == ("force_reference", "temperature") for r in plan)
    if status is None and not bench and encoding == "float32":
        assert len(plan) == math.ceil(2 * n / (max_read - max_read % 2))


def test_configs_built_in_code_are_validated_like_files() -> None:
    """The demo, tests and benchmarks build their configurations in code; the builders go
    through the file parser's checks, so a bad value is refused with the same message."""
    from gateway.config import bus_config_for, device_config_for, gateway_config_for
    from gateway.model import Divider, SensorParams

    params = [SensorParams(), SensorParams(r0_ohm=1.5e5)]
    dev = device_config_for("arr", 3, params, 2, 2.5, divider=Divider(3.3, 4.7e3, 12))
    assert [c.params.r0_ohm for c in dev.channels] == [SensorParams().r0_ohm, 1.5e5]
    assert [(c.name, c.x_mm, c.y_mm) for c in dev.channels] == [("ch00", 0.0, 0.0), ("ch01", 2.5, 0.0)]
    assert dev.divider == Divider(3.3, 4.7e3, 12) and dev.registers == RegisterMap()
    bus = bus_config_for("b", "rtu", [dev], serial_port="/dev/ttyUSB0", baudrate=19200)
    assert (bus.baudrate, bus.parity, bus.devices) == (19200, "N", (dev,))
    config = gateway_config_for([bus], "::1", 9999)
    assert (config.metrics.host, config.metrics.port) == ("::1", 9999)

    with pytest.raises(ConfigError, match=r"device 'arr'\.pitch_mm"):
        device_config_for("arr", 3, params, 2, -1.0)
    with pytest.raises(ConfigError, match=r"device 'arr'\.device_id.*1\.\.247"):
        device_config_for("arr", 300, params, 2, 2.5)
    with pytest.raises(ConfigError, match=r"device 'arr'\.model\.effects\[1\].*did you mean 'creep'"):
        device_config_for("arr", 3, params, 2, 2.5, effects=("tunneling", "crepe"))
    with pytest.raises(ConfigError, match=r"bus 'b'\.baudrate.*not a standard rate"):
        bus_config_for("b", "rtu", [dev], serial_port="/dev/ttyUSB0", baudrate=12345)
    with pytest.raises(ConfigError, match=r"duplicate device_id 3"):
        bus_config_for("b", "tcp", [dev, dev], host="127.0.0.1")
    with pytest.raises(ConfigError, match="duplicate"):
        gateway_config_for([bus, bus])
