"""``gateway.config``: valid configurations, defaults, secrets and configurations built in code."""

from __future__ import annotations

from pathlib import Path

import pytest
from config_texts import BASE, REPO, RTU, SOURCE, parse, replaced, with_bus, with_device

from gateway.config import (
    MetricsConfig,
    RegisterMap,
    TlsConfig,
    load_config,
    parse_config,
)
from gateway.errors import ConfigError
from gateway.model import PAPER_EFFECTS, Divider, SensorParams

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
    assert dev.front_end == Divider()
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
    assert dev.front_end == Divider(3.3, 4700.0, 12)
    assert dev.channels[0].effects == ("tunneling", "creep", "leakage")
    assert dev.channels[0].params == SensorParams(r0_ohm=150000.0, force_max_n=5.0)
    tip = dev.channel("tip")
    assert (tip.index, tip.x_mm, tip.y_mm, tip.enabled, tip.effects) == (9, -1.5, 4.0, False, ("tunneling",))
    assert tip.params == SensorParams(r0_ohm=190000.0, force_max_n=5.0)
    assert [c.index for c in dev.enabled_channels] == [i for i in range(16) if i != 9]


def test_parameter_precedence_device_calibration_channel(tmp_path: Path) -> None:
    # Keys that do not contradict: the device's e1_pa, the calibration's r0_ohm, the channel's
    # own e0_pa (it overrides the calibration's, as its entry says). A key the config and the
    # calibration both set to different values without an override is refused
    # (test_calibration_overrides.py).
    (tmp_path / "cal.toml").write_text(
        "[meta]\nnote = 'fit of 2025-01-31'\n\n[channel.tip]\nr0_ohm = 180000.0\ne0_pa = 14e6\n\n"
        "[channel.ch02]\nr0_ohm = 170000.0\n"
    )
    config_file = tmp_path / "gateway.toml"
    config_file.write_text(
        with_device(
            'calibration = "cal.toml"\n[bus.device.model.params]\ne1_pa = 2e8\n'
            '[[bus.device.channel]]\nindex = 0\nname = "tip"\nparams = { e0_pa = 16e6 }\n'
            'override = ["e0_pa"]\n'
        )
    )
    dev = load_config(config_file).buses[0].devices[0]
    assert dev.calibration == tmp_path / "cal.toml"
    tip = dev.channel("tip").params
    assert (tip.r0_ohm, tip.e0_pa, tip.e1_pa) == (180000.0, 16e6, 2e8)  # calibration, channel, device
    assert (dev.channel("ch02").params.r0_ohm, dev.channel("ch02").params.e1_pa) == (170000.0, 2e8)
    assert dev.channel("ch01").params == SensorParams(e1_pa=2e8)


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


def test_configs_built_in_code_are_validated_like_files() -> None:
    """The demo, tests and benchmarks build their configurations in code; the builders go
    through the file parser's checks, so a bad value is refused with the same message."""
    from gateway.config import bus_config_for, device_config_for, gateway_config_for
    from gateway.model import Divider, SensorParams

    params = [SensorParams(), SensorParams(r0_ohm=1.5e5)]
    dev = device_config_for("arr", 3, params, 2, 2.5, front_end=Divider(3.3, 4.7e3, 12))
    assert [c.params.r0_ohm for c in dev.channels] == [SensorParams().r0_ohm, 1.5e5]
    assert [(c.name, c.x_mm, c.y_mm) for c in dev.channels] == [("ch00", 0.0, 0.0), ("ch01", 2.5, 0.0)]
    assert dev.front_end == Divider(3.3, 4.7e3, 12) and dev.registers == RegisterMap()
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


def test_load_config_reads_no_device_and_no_huge_file(tmp_path: Path) -> None:
    """``check-config -c /dev/zero`` once read without limit; a device or a file over the
    limit is refused before it is read."""
    from gateway.config.tables import MAX_FILE_BYTES

    with pytest.raises(ConfigError, match=r"^/dev/zero: not a regular file; a configuration file is a file$"):
        load_config(Path("/dev/zero"))
    huge = tmp_path / "huge.toml"
    with huge.open("wb") as f:
        f.truncate(MAX_FILE_BYTES + 1)  # sparse: no disk used
    with pytest.raises(ConfigError, match=r"larger than 4 MiB; too large for a configuration file"):
        load_config(huge)


def test_the_page_can_be_turned_off_in_the_metrics_section() -> None:
    assert parse(BASE).metrics.page is True
    off = parse(replaced('address = "127.0.0.1:9830"', 'address = "127.0.0.1:9830"\npage = false'))
    assert off.metrics.page is False
    with pytest.raises(
        ConfigError, match=r"metrics\.page: expected a boolean \(true or false\), got string 'no'"
    ):
        parse(replaced('address = "127.0.0.1:9830"', 'address = "127.0.0.1:9830"\npage = "no"'))


@pytest.mark.parametrize("key", ["web_config", "calibration", "profile"])
def test_a_path_with_a_newline_is_named_on_one_line(tmp_path: Path, key: str) -> None:
    # found by tests/fuzz/test_fuzz_config_parser.py: web_config = "0\n" printed the path raw,
    # a message of two lines
    if key == "web_config":
        text = BASE.replace('9830"\n', '9830"\nweb_config = "0\\n"\n')
    elif key == "profile":
        text = BASE.replace('profile = "tactile-sim"', 'profile = "0\\nx.toml"')
    else:
        text = BASE + 'calibration = "0\\nx"\n'
    assert text != BASE
    config = tmp_path / "gateway.toml"
    config.write_text(text, encoding="utf-8")
    with pytest.raises(ConfigError) as info:
        load_config(config)
    message = str(info.value)
    assert "\n" not in message and "does not exist" in message, message
    assert "\\n" in message  # the newline shown escaped
