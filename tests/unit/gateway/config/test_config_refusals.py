"""``gateway.config``: every refused configuration gets a message naming the key and the reason."""

from __future__ import annotations

import pytest
from config_texts import BASE, RTU, SOURCE, parse, replaced, with_bus, with_device

from gateway.config import (
    parse_config,
)
from gateway.errors import ConfigError

# (id, configuration text, fragments the message must contain)
BAD_CONFIGS: list[tuple[str, str, tuple[str, ...]]] = [
    ("toml-syntax", BASE + "x = \n", ("invalid TOML at line 15, column 5", "Invalid value")),
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
        with_bus("poll_interval_s = -0.001"),
        ("bus[0].poll_interval_s", "allowed: [0, 3600] s"),
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
        BASE + '\n[[bus.device]]\nname = "array2"\ndevice_id = 1\nprofile = "tactile-sim"\nchannels = 4\n',
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
        ("bus[0].device[0].channels: 0", "allowed: 1..2048"),
    ),
    (
        "channels-big",
        replaced("channels = 16", "channels = 2049"),
        ("bus[0].device[0].channels: 2049", "1..2048"),
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
        "ratio-adc-bits-missing",
        with_device('[bus.device.front_end]\nkind = "ratio"'),
        ("bus[0].device[0].front_end.adc_bits: required key is missing; expected an integer in 8..16",),
    ),
    (
        "ratio-adc-bits-range",
        with_device('[bus.device.front_end]\nkind = "ratio"\nadc_bits = 20'),
        ("bus[0].device[0].front_end.adc_bits: 20 is out of range; allowed: 8..16",),
    ),
    (
        "ratio-rises-with-load-type",
        with_device('[bus.device.front_end]\nkind = "ratio"\nadc_bits = 12\nrises_with_load = 1'),
        ("bus[0].device[0].front_end.rises_with_load: expected a boolean (true or false), got integer 1",),
    ),
    (
        "ratio-offset-range",
        with_device('[bus.device.front_end]\nkind = "ratio"\nadc_bits = 12\nadc_offset_counts = 2047.5'),
        (
            "bus[0].device[0].front_end.adc_offset_counts: adc_offset_counts = 2047.5 must be in "
            "(-2047.5, 2047.5) counts (|offset| < full scale / 2 at 12 bit)",
        ),
    ),
    (
        "ratio-no-circuit-values",
        with_device('[bus.device.front_end]\nkind = "ratio"\nadc_bits = 12\nreference_ohm = 4700.0'),
        (
            "bus[0].device[0].front_end.reference_ohm: unknown key "
            "(allowed keys: kind, adc_bits, rises_with_load, adc_offset_counts)",
        ),
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
