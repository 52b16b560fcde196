"""Issue 31 §6: the words of a configuration file (bus ``kind``, ``serial_client``, device
``encoding``, register ``table``) are read as enum members that equal the file's strings: the
file format is unchanged, and code compares members, never hand-typed strings."""

from __future__ import annotations

import pytest
from config_texts import BASE, RTU, parse, replaced

from gateway.config import BusKind, Encoding, SerialClient, bus_config_for
from gateway.errors import ConfigError
from gateway.keys import Choice
from gateway.modbus.register_map import RegisterKind


def test_a_file_s_words_are_read_as_members() -> None:
    text = replaced('kind = "tcp"', 'kind = "rtu-over-tcp"')
    text = replaced("channels = 16\n", 'channels = 16\nencoding = "float32"\n', text)
    config = parse(text + '\n[bus.device.registers]\ntable = "holding"\n')
    (bus,) = config.buses
    (device,) = bus.devices
    assert bus.kind is BusKind.RTU_OVER_TCP and bus.kind == "rtu-over-tcp"
    assert device.encoding is Encoding.FLOAT32 and device.encoding == "float32"
    assert device.registers.table is RegisterKind.HOLDING
    assert bus.serial_client is SerialClient.PYMODBUS


def test_an_rtu_line_and_its_serial_client() -> None:
    port = 'serial_port = "/dev/ttyUSB0"'
    line = RTU.replace(port, f'{port}\nserial_client = "direct"')
    (bus,) = parse(BASE.split("[[bus]]")[0] + line).buses
    assert bus.kind is BusKind.RTU and bus.serial_client is SerialClient.DIRECT
    assert bus.endpoint == "/dev/ttyUSB0"


def test_a_misspelt_word_is_refused_naming_the_closest_and_every_allowed_one() -> None:
    with pytest.raises(ConfigError, match=r"kind: 'tpc' is not allowed; did you mean 'tcp'\?") as exc:
        parse(replaced('kind = "tcp"', 'kind = "tpc"'))
    assert "tcp | rtu | rtu-over-tcp | tls" in str(exc.value)
    with pytest.raises(
        ValueError, match=r"'tpc' is not allowed; did you mean 'tcp'\?; allowed: 'tcp', 'rtu', "
    ):
        BusKind("tpc")
    with pytest.raises(ConfigError, match="'tpc' is not allowed"):
        bus_config_for("b", "tpc", [], host="127.0.0.1", port=502)


def test_every_word_enum_is_a_choice() -> None:
    for kind in (BusKind, SerialClient, Encoding, RegisterKind):
        assert issubclass(kind, Choice)
        assert all(kind(m.value) is m and repr(m) == repr(m.value) for m in kind)
