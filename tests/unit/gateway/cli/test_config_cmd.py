"""``tactile-gateway check-config`` and ``tactile-gateway channels ...`` through click's runner."""

from __future__ import annotations

import difflib
import stat
import tomllib
from pathlib import Path

import pytest
from click.testing import CliRunner, Result

from gateway.cli import main
from gateway.config import load_config
from gateway.model import RatioFrontEnd

CONFIG = """\
# Bench gateway: keep this comment.
[metrics]
address = "127.0.0.1:9830"   # loopback only

[[bus]]
name = "bench"      # the bench bus
kind = "tcp"
host = "127.0.0.1"
port = 5020

[[bus.device]]
name = "array1"     # left hand
device_id = 1
profile = "tactile-sim"
channels = 16

[bus.device.registers]
status_address = 16   # bitmaps

[[bus.device.channel]]
index = 0
name = "tip"        # fingertip
params = { r0_ohm = 190e3, force_max_n = 5.0 }  # from calibration run 3

[[bus.device]]
name = "array2"
device_id = 2
profile = "tactile-sim"
encoding = "float32"
channels = 4

[[bus.device.channel]]
index = 1
name = "tip"
"""


def run(*args: str) -> Result:
    return CliRunner().invoke(main, list(args))


@pytest.fixture
def config_file(tmp_path: Path) -> Path:
    path = tmp_path / "gateway.toml"
    path.write_text(CONFIG)
    path.chmod(0o640)
    return path


def device(path: Path, name: str = "array1") -> object:
    return load_config(path).find_device(name)[1]


def removed_lines(before: str, after: str) -> list[str]:
    """Lines of ``before`` that are not in ``after`` (comments and layout must survive an edit)."""
    return [
        line[2:] for line in difflib.ndiff(before.splitlines(), after.splitlines()) if line.startswith("- ")
    ]


# ----------------------------------------------------------------------------------------------
# check-config


def test_check_config_prints_the_read_plan(config_file: Path) -> None:
    result = run("check-config", "-c", str(config_file))
    assert result.exit_code == 0, result.output
    out = result.stdout
    assert f"{config_file}: OK (1 bus, 2 devices, 20 channels)" in out
    assert "bus bench: tcp 127.0.0.1:5020" in out
    # what the poller reads: the device clock, the three status bitmaps in one read (every
    # register between them exists), and the channel block
    assert "device array1 (id 1, adc, 16 channels, 16 enabled): 3 requests, 53 registers per poll" in out
    assert "    input 2..5 (4 registers): device_time" in out
    assert "    input 16..48 (33 registers): status" in out
    assert "    input 100..115 (16 registers): adc" in out
    assert "device array2 (id 2, float32, 4 channels, 4 enabled): 3 requests, 45 registers per poll" in out
    assert "    input 400..407 (8 registers): float" in out


def test_check_config_splits_reads_by_max_read_registers(config_file: Path) -> None:
    config_file.write_text(CONFIG.replace("port = 5020", "port = 5020\nmax_read_registers = 5"))
    result = run("check-config", "-c", str(config_file))
    assert result.exit_code == 0, result.output
    assert "input 400..403 (4 registers): float" in result.stdout
    assert "input 404..407 (4 registers): float" in result.stdout
    assert "input 100..104 (5 registers): adc" in result.stdout


def test_check_config_rtu_bus_line(tmp_path: Path) -> None:
    path = tmp_path / "rtu.toml"
    path.write_text(
        '[[bus]]\nname = "line"\nkind = "rtu"\nserial_port = "/dev/ttyUSB0"\nbaudrate = 9600\n'
        '[[bus.device]]\nname = "a"\ndevice_id = 3\nprofile = "tactile-sim"\nchannels = 1\n'
    )
    result = run("check-config", "-c", str(path))
    assert result.exit_code == 0, result.output
    assert "bus line: rtu /dev/ttyUSB0 9600 8E1" in result.stdout


def test_check_config_invalid_exits_2_with_the_message_on_stderr(config_file: Path) -> None:
    config_file.write_text(CONFIG.replace("channels = 16", "channels = 3000"))
    result = run("check-config", "-c", str(config_file))
    assert result.exit_code == 2
    assert result.stdout == ""
    assert result.stderr.strip() == (
        f"{config_file}: bus[0].device[0].channels: 3000 is out of range; allowed: 1..2048"
    )
    assert "Traceback" not in result.output


def test_check_config_missing_file(tmp_path: Path) -> None:
    result = run("check-config", "-c", str(tmp_path / "absent.toml"))
    assert result.exit_code == 2
    assert "cannot read the configuration file" in result.stderr
    assert "Traceback" not in result.output


def test_check_config_toml_syntax_error_names_the_line(config_file: Path) -> None:
    config_file.write_text(CONFIG.replace('kind = "tcp"', 'kind = "tcp'))
    result = run("check-config", "-c", str(config_file))
    assert result.exit_code == 2
    assert f"{config_file}: invalid TOML at line 7" in result.stderr


def test_check_config_on_the_shipped_example() -> None:
    example = Path(__file__).resolve().parents[4] / "examples" / "gateway.toml"
    result = run("check-config", "-c", str(example))
    assert result.exit_code == 0, result.output
    assert "15 enabled" in result.stdout


RATIO_CONFIG = """\
[[bus]]
name = "bench"
kind = "tcp"
host = "127.0.0.1"
port = 5020

[[bus.device]]
name = "pad"
device_id = 1
profile = "tactile-sim"
channels = 4

[bus.device.front_end]
kind = "ratio"
adc_bits = 12
"""

RATIO_CIRCUIT = (
    "assumes: nothing of the circuit but its topology (rises_with_load = true: counts rise with load: "
    "sensor on the high side); readings are relative, in units of the unknown reference resistor; "
)


def test_check_config_of_a_ratio_front_end_says_what_rests_on_nothing(tmp_path: Path) -> None:
    path = tmp_path / "ratio.toml"
    path.write_text(RATIO_CONFIG)
    assert device(path, "pad").front_end == RatioFrontEnd(adc_bits=12, rises_with_load=True)  # type: ignore[attr-defined]
    result = run("check-config", "-c", str(path))
    assert result.exit_code == 0, result.output
    out = result.stdout
    assert (
        "    " + RATIO_CIRCUIT + "no channel is calibrated: 4 channels read `uncalibrated` (no force: the "
        "default sensor parameters are in ohm and do not apply) until calibrated: record them under known "
        "loads (`tactile-gateway record -c CONFIG --duration S --out RECORD.csv`), then "
        "`tactile-gateway calibrate RECORD.csv --model auto --out CAL.toml --install CONFIG`\n"
    ) in out
    no_force = "    force: none: reads `uncalibrated` (r/R_ref without a calibration; see `assumes:`): "
    no_force += "4 channels\n"
    assert no_force in out
    assert "    front end: ratio: r/R_ref = FS/code - 1 (counts rise with load" in out
    assert "reads 0.0002443 R_ref .. 4094 R_ref" in out and "no circuit value is assumed" in out
    assert "the front end's values (reference resistor, full scale)" not in out


def test_check_config_of_a_calibrated_ratio_front_end(tmp_path: Path) -> None:
    (tmp_path / "cal.toml").write_text('[meta]\nrecord = "r1"\n\n[channel."ch00"]\nr0_ohm = 20.0\n')
    path = tmp_path / "ratio.toml"
    text = RATIO_CONFIG.replace("channels = 4\n", 'channels = 4\ncalibration = "cal.toml"\n')
    path.write_text(text.replace("adc_bits = 12\n", "adc_bits = 12\nrises_with_load = false\n"))
    result = run("check-config", "-c", str(path))
    assert result.exit_code == 0, result.output
    assert (
        "assumes: nothing of the circuit but its topology (rises_with_load = false: counts fall with load: "
        "sensor below a pull-up); readings are relative, in units of the unknown reference resistor; "
        "1 channels calibrated, 3 channels read `uncalibrated` (no force: the default sensor parameters"
    ) in result.stdout
    assert "front end: ratio: r/R_ref = code/(FS - code) (counts fall with load" in result.stdout
    every = "".join(f'[channel."ch{i:02d}"]\nr0_ohm = 20.0\n' for i in range(4))
    (tmp_path / "cal.toml").write_text('[meta]\nrecord = "r1"\n\n' + every)
    result = run("check-config", "-c", str(path))
    assert result.exit_code == 0, result.output
    assert "sensor below a pull-up); readings are relative, in units of the unknown reference resistor; " in (
        result.stdout
    )
    assert "; forces rest on the calibration of every channel\n" in result.stdout


# ----------------------------------------------------------------------------------------------
# channels list / show


def test_channels_list(config_file: Path) -> None:
    result = run("channels", "list", "-c", str(config_file))
    assert result.exit_code == 0, result.output
    lines = result.stdout.splitlines()
    assert lines[0].startswith("device array1 (bus bench, id 1, 16 channels, 4 columns, pitch 2.5 mm)")
    tip = next(line for line in lines if " tip " in line)
    assert tip.split()[:5] == ["0", "tip", "0", "0", "yes"]
    assert tip.split()[-2:] == ["r0_ohm,", "force_max_n"]
    ch05 = next(line for line in lines if " ch05 " in line)
    assert ch05.split() == ["5", "ch05", "2.5", "2.5", "yes", "tunneling,contact,creep", "-"]
    assert any(line.startswith("device array2") for line in lines)


def test_channels_list_one_device(config_file: Path) -> None:
    result = run("channels", "list", "-c", str(config_file), "--device", "array2")
    assert result.exit_code == 0, result.output
    assert "array1" not in result.stdout
    assert len([line for line in result.stdout.splitlines() if "tunneling" in line]) == 4


def test_channels_show_with_sources(config_file: Path) -> None:
    result = run("channels", "show", "tip", "--device", "array1", "-c", str(config_file))
    assert result.exit_code == 0, result.output
    out = result.stdout
    assert "channel tip (index 0) of device array1 on bus bench" in out
    assert "r0_ohm                     = 190000       (channel)" in out
    assert "e0_pa                      = 1.5e+07      (default)" in out


def test_channels_show_ambiguous_name_needs_device(config_file: Path) -> None:
    result = run("channels", "show", "tip", "-c", str(config_file))
    assert result.exit_code == 2
    assert "channel 'tip' exists in devices array1, array2; choose one with --device NAME" in result.stderr


def test_channels_show_unknown_name_suggests(config_file: Path) -> None:
    result = run("channels", "show", "ch5", "--device", "array1", "-c", str(config_file))
    assert result.exit_code == 2
    assert "no channel 'ch5' of device 'array1'; did you mean" in result.stderr


def test_channels_unknown_device(config_file: Path) -> None:
    result = run("channels", "list", "--device", "aray1", "-c", str(config_file))
    assert result.exit_code == 2
    assert "no device 'aray1'; did you mean 'array1'?" in result.stderr


def test_channels_on_an_invalid_file(config_file: Path) -> None:
    config_file.write_text(CONFIG.replace("device_id = 2", "device_id = 1"))
    result = run("channels", "list", "-c", str(config_file))
    assert result.exit_code == 2
    assert "duplicate device_id 1" in result.stderr


# ----------------------------------------------------------------------------------------------
# channels set / enable / disable


def test_set_existing_entry_keeps_comments(config_file: Path) -> None:
    result = run(
        "channels", "set", "tip", "r0_ohm=2e5", "x_mm=1.25", "effects=contact, creep2",
        "-c", str(config_file), "--device", "array1",
    )  # fmt: skip
    assert result.exit_code == 0, result.output
    after = config_file.read_text()
    assert 'name = "tip"        # fingertip' in after
    assert "params = { r0_ohm = 2e5, force_max_n = 5.0 }  # from calibration run 3" in after
    assert removed_lines(CONFIG, after) == [
        "params = { r0_ohm = 190e3, force_max_n = 5.0 }  # from calibration run 3"
    ]
    tip = load_config(config_file).find_device("array1")[1].channel("tip")
    assert (tip.params.r0_ohm, tip.params.force_max_n, tip.x_mm) == (2e5, 5.0, 1.25)
    assert tip.effects == ("tunneling", "contact", "creep2")


def test_set_adds_an_entry_for_a_channel_without_one(config_file: Path) -> None:
    result = run("channels", "set", "ch07", "name=thumb", "e0_pa=16000000", "-c", str(config_file))
    assert result.exit_code == 0, result.output
    after = config_file.read_text()
    assert removed_lines(CONFIG, after) == []
    entries = tomllib.loads(after)["bus"][0]["device"][0]["channel"]
    assert entries[-1] == {"index": 7, "name": "thumb", "params": {"e0_pa": 16000000}}
    dev = load_config(config_file).find_device("array1")[1]
    thumb = dev.channel("thumb")
    assert (thumb.index, thumb.params.e0_pa, thumb.x_mm, thumb.y_mm) == (7, 16e6, 7.5, 2.5)
    # The other device is untouched.
    assert tomllib.loads(after)["bus"][0]["device"][1] == tomllib.loads(CONFIG)["bus"][0]["device"][1]


def test_set_adds_the_channel_array_to_a_device_without_entries(tmp_path: Path) -> None:
    path = tmp_path / "g.toml"
    text = (
        '[[bus]]\nname = "b"\nkind = "tcp"\nhost = "h"\n\n[[bus.device]]\nname = "d"\ndevice_id = 1\n'
        'profile = "tactile-sim"\n'
        "channels = 4\n\n[bus.device.divider]\nadc_bits = 12   # 12-bit ADC\n\n"
        '[[bus]]\nname = "c"\nkind = "tcp"\nhost = "h2"\n\n'
        '[[bus.device]]\nname = "e"\ndevice_id = 1\nprofile = "tactile-sim"\nchannels = 2\n'
    )
    path.write_text(text)
    result = run("channels", "disable", "ch03", "-c", str(path))
    assert result.exit_code == 0, result.output
    after = path.read_text()
    assert removed_lines(text, after) == []
    data = tomllib.loads(after)
    assert data["bus"][0]["device"][0]["channel"] == [{"index": 3, "enabled": False}]
    assert "channel" not in data["bus"][1]["device"][0]
    assert not load_config(path).find_device("d")[1].channels[3].enabled


def test_disable_then_enable_round_trip(config_file: Path) -> None:
    assert run("channels", "disable", "ch12", "-c", str(config_file)).exit_code == 0
    assert not load_config(config_file).find_device("array1")[1].channels[12].enabled
    disabled = config_file.read_text()
    assert run("channels", "enable", "ch12", "-c", str(config_file)).exit_code == 0
    assert load_config(config_file).find_device("array1")[1].channels[12].enabled
    enabled = config_file.read_text()
    assert removed_lines(disabled, enabled) == ["enabled = false"]
    assert removed_lines(CONFIG, enabled) == []


def test_enable_with_device_for_an_ambiguous_name(config_file: Path) -> None:
    result = run("channels", "disable", "tip", "--device", "array2", "-c", str(config_file))
    assert result.exit_code == 0, result.output
    assert load_config(config_file).find_device("array1")[1].channel("tip").enabled
    assert not load_config(config_file).find_device("array2")[1].channel("tip").enabled


def test_rename_then_show_by_the_new_name(config_file: Path) -> None:
    result = run("channels", "set", "ch03", "name=pinky", "-c", str(config_file))
    assert result.exit_code == 2
    assert "channel 'ch03' exists in devices array1, array2; choose one with --device NAME" in result.stderr
    assert (
        run("channels", "set", "ch03", "name=pinky", "--device", "array1", "-c", str(config_file)).exit_code
        == 0
    )
    result = run("channels", "show", "pinky", "-c", str(config_file))
    assert result.exit_code == 0, result.output
    assert "channel pinky (index 3) of device array1" in result.stdout


def test_set_param_on_a_sub_table(tmp_path: Path) -> None:
    path = tmp_path / "g.toml"
    text = (
        '[[bus]]\nname = "b"\nkind = "tcp"\nhost = "h"\n'
        '[[bus.device]]\nname = "d"\ndevice_id = 1\nprofile = "tactile-sim"\nchannels = 2\n'
        "[[bus.device.channel]]\nindex = 1\n[bus.device.channel.params]\nr0_ohm = 1e5   # measured\n"
    )
    path.write_text(text)
    result = run("channels", "set", "ch01", "r0_ohm=1.1e5", "hardness_pa=3e7", "enabled=no", "-c", str(path))
    assert result.exit_code == 0, result.output
    after = path.read_text()
    assert "r0_ohm = 1.1e5   # measured" in after
    ch = load_config(path).find_device("d")[1].channels[1]
    assert (ch.params.r0_ohm, ch.params.hardness_pa, ch.enabled) == (1.1e5, 3e7, False)


@pytest.mark.parametrize(
    ("args", "fragment"),
    [
        (("set", "tip", "r0_ohm=-1"), "bus[0].device[0].channel[0].params.r0_ohm: parameter r0_ohm = -1"),
        (("set", "tip", "force_max_n=0.01"), "force_min_n (0.05 N) must be below force_max_n (0.01 N)"),
        (("set", "ch01", "name=tip"), "duplicate channel name 'tip'"),
        (("set", "ch01", "name=Big Name"), "'Big Name' is not a name matching [a-z0-9_-]{1,32}"),
        (("set", "ch01", "x_mm=1e9"), "allowed: [-10000, 10000] mm"),
        (("set", "ch01", "r0_ohn=5"), "unknown key 'r0_ohn'; did you mean 'r0_ohm'?"),
        (("set", "ch01", "effects=crep"), "unknown effect 'crep'; did you mean 'creep'?"),
        (("set", "ch01", "enabled=maybe"), "expected true or false"),
        (("set", "ch01", "x_mm=left"), "expected a number"),
        (("set", "ch01", "x_mm"), "is not KEY=VALUE"),
    ],
)
def test_refused_edit_leaves_the_file_byte_identical(
    config_file: Path, args: tuple[str, ...], fragment: str
) -> None:
    before = config_file.read_bytes()
    result = run("channels", *args, "--device", "array1", "-c", str(config_file))
    assert result.exit_code == 2
    assert fragment in result.stderr
    assert "Traceback" not in result.output
    assert config_file.read_bytes() == before
    assert [p.name for p in config_file.parent.iterdir()] == [config_file.name]


def test_invalid_edit_message_says_refused(config_file: Path) -> None:
    result = run("channels", "set", "tip", "r0_ohm=0", "--device", "array1", "-c", str(config_file))
    assert result.exit_code == 2
    assert result.stderr.startswith(
        f"refused, {config_file} is unchanged: the edit would make the configuration"
    )


def test_edit_keeps_mode_and_leaves_no_temporary_files(config_file: Path) -> None:
    for args in (("disable", "ch09"), ("set", "ch09", "y_mm=3"), ("enable", "ch09")):
        result = run("channels", *args, "-c", str(config_file))
        assert result.exit_code == 0, result.output
    assert stat.S_IMODE(config_file.stat().st_mode) == 0o640
    assert [p.name for p in config_file.parent.iterdir()] == [config_file.name]
    assert load_config(config_file).find_device("array1")[1].channels[9].y_mm == 3.0


def test_edit_reports_what_changed(config_file: Path) -> None:
    result = run("channels", "set", "ch09", "x_mm=3", "-c", str(config_file))
    assert result.exit_code == 0, result.output
    assert result.stdout.strip() == f"{config_file}: channel ch09 (index 9) of device array1: x_mm = 3"


def test_edit_of_inline_device_tables(tmp_path: Path) -> None:
    path = tmp_path / "inline.toml"
    text = (
        '[[bus]]\nname = "b"\nkind = "tcp"\nhost = "h"\n'
        "device = [\n"
        '  { name = "d", device_id = 1, profile = "tactile-sim", channels = 4, '
        'channel = [{ index = 0, name = "a" }] },  # inline\n'
        "]\n"
    )
    path.write_text(text)
    assert run("channels", "set", "ch02", "x_mm=3", "-c", str(path)).exit_code == 0
    assert run("channels", "set", "a", "r0_ohm=3e5", "-c", str(path)).exit_code == 0
    after = path.read_text()
    assert "# inline" in after
    dev = load_config(path).find_device("d")[1]
    assert (dev.channels[2].x_mm, dev.channels[0].params.r0_ohm) == (3.0, 3e5)


def test_list_and_show_mark_calibrated_parameters(config_file: Path) -> None:
    (config_file.parent / "cal.toml").write_text('[meta]\nrecord = "r1"\n\n[channel."ch04"]\ne0_pa = 1.4e7\n')
    config_file.write_text(CONFIG.replace("channels = 16\n", 'channels = 16\ncalibration = "cal.toml"\n'))
    listed = run("channels", "list", "--device", "array1", "-c", str(config_file))
    assert listed.exit_code == 0, listed.output
    ch04 = next(line for line in listed.stdout.splitlines() if " ch04 " in line)
    assert ch04.endswith("e0_pa (cal)")
    shown = run("channels", "show", "ch04", "--device", "array1", "-c", str(config_file))
    assert "e0_pa                      = 1.4e+07      (calibration)" in shown.stdout


COUNTS_WITH_ZERO = """\
[[bus]]
name = "lab"
kind = "tcp"
host = "127.0.0.1"

[[bus.device]]
name = "skin"
device_id = 1
profile = "{profile}"
[bus.device.actions]
zero = [{{ what = "dynamic zero", address = 3, value = 1, verify = false }}]
"""


@pytest.mark.parametrize(("profile", "suggested"), [("skin60-counts", False), ("skin60-mn", True)])
def test_device_zero_is_suggested_only_where_the_device_outputs_its_own_zeroed_value(
    tmp_path: Path, profile: str, suggested: bool
) -> None:
    # a device-zeroed counts channel reads 0 counts, which the divider takes for an open sensor
    path = tmp_path / "gateway.toml"
    path.write_text(COUNTS_WITH_ZERO.format(profile=profile))
    result = CliRunner().invoke(main, ["check-config", "-c", str(path)])
    assert result.exit_code == 0, result.output
    (zero,) = [line for line in result.output.splitlines() if line.strip().startswith("zero:")]
    assert ("not `tare --device-zero`" in zero) is not suggested, zero
    assert ("`tare --device-zero` runs its zero action" in zero) is suggested, zero
    assert "or `tare --device-zero`" not in zero, zero
