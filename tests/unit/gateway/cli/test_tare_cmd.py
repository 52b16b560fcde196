"""``tactile-gateway tare`` end to end through click: a loaded acme-at6x6 array on the
in-process virtual bus (12-bit low-side divider, 10 kohm pull-up: r = 10k * c / (4095 - c)),
``--channels`` writing only the chosen channels, ``--from-record`` taking the baselines from a
record written here without polling the device, and the refusals (one line, exit 2, the file
byte for byte as it was)."""

from __future__ import annotations

import functools
import re
from pathlib import Path

import pytest
from click.testing import CliRunner, Result

from gateway.cli import main, tare_cmd
from gateway.config import load_config
from gateway.config.schema import BusConfig
from gateway.modbus.virtual import VirtualDevice, VirtualTransport
from gateway.runtime.sampler import sample_device

N = 36
REST = 3895  # 10k * 3895 / 200 = 194750 ohm: the empty cell
LOADED = 3700  # 10k * 3700 / 395 = 93670.9 ohm: 1.0 N by the default model
BLOB = (14, 15, 20, 21)
UNLOADED = "0-13,16-19,22-35"

HEAD = """\
# the user's 6x6 board
[[bus]]
name = "lab"   # the bench bus
kind = "tcp"
host = "127.0.0.1"
poll_interval_s = 0.01

[[bus.device]]
name = "jaw"   # the left jaw
device_id = 1
profile = "acme-at6x6"
"""
TAIL = """
# the model of the cells
[bus.device.model]
effects = ["tunneling", "contact", "creep"]  # the paper's
"""
HAND = "# written by hand\nbaseline_counts = [{}]\n".format(", ".join(["4000"] * N))


def virtual_array(counts: list[int]) -> VirtualDevice:
    """An acme-at6x6 board: its product id, channel count and identification, and ``counts``."""
    dev = VirtualDevice()
    dev.set_input(0, [0x5447])
    dev.set_input(8, [N])
    dev.set_input(32, counts)
    dev.identification.update({"VendorName": "Acme Tactile", "ProductCode": "AT-6x6"})
    return dev


def blob() -> list[int]:
    return [LOADED if ch in BLOB else REST for ch in range(N)]


@pytest.fixture
def board(monkeypatch: pytest.MonkeyPatch) -> VirtualTransport:
    """``tare`` samples this virtual bus: the board with a blob on the middle four cells."""
    transport = VirtualTransport(devices={1: virtual_array(blob())})

    def factory(bus: BusConfig) -> VirtualTransport:
        return transport

    monkeypatch.setattr(
        tare_cmd, "sample_device", functools.partial(sample_device, transport_factory=factory)
    )
    return transport


@pytest.fixture
def no_device(monkeypatch: pytest.MonkeyPatch) -> list[str]:
    """Any poll of the device is recorded here (and fails): a record mode must make none."""
    calls: list[str] = []

    async def forbidden(*args: object, **kwargs: object) -> None:
        calls.append("sampled")
        raise AssertionError("the device was sampled")

    monkeypatch.setattr(tare_cmd, "sample_device", forbidden)
    return calls


def write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "gateway.toml"
    path.write_text(text, encoding="utf-8")
    return path


def tare(path: Path, *args: str) -> Result:
    return CliRunner().invoke(main, ["tare", "-c", str(path), *args])


def refused(result: Result, start: str) -> str:
    assert result.exit_code == 2, result.output
    lines = result.stderr.splitlines()
    assert len(lines) == 1, lines
    assert lines[0].startswith(start), lines[0]
    assert lines[0].endswith("nothing was written"), lines[0]
    return lines[0]


def array_block(text: str, key: str) -> list[str]:
    block = re.search(rf"^{key} = \[\n(.*?)\n\]", text, re.M | re.S)
    assert block is not None, text
    return [v.strip() for v in block.group(1).replace("\n", " ").split(",") if v.strip()]


# --------------------------------------------------------------------------- --channels
def test_a_loaded_array_is_refused_as_loaded_and_the_file_is_unchanged(
    tmp_path: Path, board: VirtualTransport
) -> None:
    path = write(tmp_path, HEAD + HAND + TAIL)
    before = path.read_bytes()
    one = "1 N by the model at 9.367e+04 ohm, 2.1x the median conductance"
    line = refused(
        tare(path, "--seconds", "0.5"),
        f"tare: device jaw: the array is loaded over the 0.5 s sampled: ch14 ({one}), ch15 ({one}), "
        f"ch20 ({one}), ch21 ({one}); allowed at rest: at most 0.5 N (--max-force)",
    )
    assert f"(--channels {UNLOADED})" in line and "--from-record" in line and "--device-zero" in line
    # a load that moves makes the --channels list stale: the moving-load tare is named too
    assert "if the load moves, zero each channel from its own unloaded moments (--moving-load)" in line
    assert "wiring" not in line
    assert path.read_bytes() == before
    assert board.writes == []  # a tare never writes to the device


def test_channels_writes_only_those_and_keeps_the_others_and_every_comment(
    tmp_path: Path, board: VirtualTransport
) -> None:
    path = write(tmp_path, HEAD + HAND + TAIL)
    result = tare(path, "--seconds", "0.5", "--channels", "0-13,ch16,17-19,ch22,23-35")
    assert result.exit_code == 0, result.output
    assert "baseline_counts written for 32 of 36 channels" in result.output
    assert "note: the other 4 channels keep their baselines" in result.output
    text = path.read_text(encoding="utf-8")
    for comment in (
        "# the user's 6x6 board",
        "# the bench bus",
        "# the left jaw",
        "# written by hand",
        "# the paper's",
    ):
        assert comment in text, comment
    values = array_block(text, "baseline_counts")
    assert values == ["4000" if ch in BLOB else "3895" for ch in range(N)]
    assert text.count("baseline_counts") == 1 and "baseline_ohm" not in text
    # everything outside the array is as it was
    assert text.split("baseline_counts")[0] == (HEAD + "# written by hand\n")
    assert text.endswith(TAIL)
    channels = load_config(path).buses[0].devices[0].channels
    assert channels[0].baseline_ohm == pytest.approx(194_750.0, rel=1e-12)
    assert channels[14].baseline_ohm == pytest.approx(10_000 * 4000 / 95, rel=1e-12)  # kept: 421052.6 ohm


def test_channels_on_a_file_without_baselines_leave_the_others_uncorrected(
    tmp_path: Path, board: VirtualTransport
) -> None:
    path = write(tmp_path, HEAD + TAIL)
    result = tare(path, "--seconds", "0.5", "--channels", UNLOADED)
    assert result.exit_code == 0, result.output
    assert 'note: ch14, ch15, ch20, ch21 had no baseline: written as "none"' in result.output
    # the skipped channels keep no baseline ("none", never inf: inf would be a baseline, which
    # lifts their no_zero guard and reads an idle cell as a small force); the tared ones in ohm
    values = array_block(path.read_text(encoding="utf-8"), "baseline_ohm")
    assert values == ['"none"' if ch in BLOB else "194750" for ch in range(N)]
    channels = load_config(path).buses[0].devices[0].channels
    assert [ch.index for ch in channels if ch.baseline_ohm is None] == sorted(BLOB)
    assert all(ch.baseline_ohm == pytest.approx(194_750.0) for ch in channels if ch.index not in BLOB)
    # check-config counts only the channels with a baseline, and its range is finite
    checked = CliRunner().invoke(main, ["check-config", "-c", str(path)])
    assert checked.exit_code == 0, checked.output
    assert f"zero: {N - len(BLOB)} channel(s) with an unloaded baseline, 1.948e+05..1.948e+05 ohm" in (
        checked.output
    )


@pytest.mark.parametrize(
    ("spec", "start"),
    [
        (
            "ch00,ch99",
            "tare: --channels: no channel 'ch99' in device jaw; "
            "allowed: channel names (e.g. ch00), indices 0-35",
        ),
        ("0-36", "tare: --channels: '0-36' is out of range; allowed:"),
        ("0,,3", "tare: --channels '0,,3': an empty entry; allowed:"),
    ],
)
def test_a_bad_channel_list_is_one_line_and_nothing_is_sampled(
    tmp_path: Path, no_device: list[str], spec: str, start: str
) -> None:
    path = write(tmp_path, HEAD + HAND + TAIL)
    before = path.read_bytes()
    result = tare(path, "--channels", spec)
    assert result.exit_code == 2 and result.stderr.startswith(start), result.stderr
    assert len(result.stderr.splitlines()) == 1
    assert path.read_bytes() == before and no_device == []


# --------------------------------------------------------------------------- --from-record
def record(tmp_path: Path, names: list[str] | None = None) -> Path:
    """21 polls 0.1 s apart (0-2 s); at 1.05 s a blob lands on ch14: 93670.9 ohm from then on."""
    names = names if names is not None else [f"ch{i:02d}" for i in range(N)]
    rows = ["# source: a test", "time_s,channel,resistance_ohm"]
    for k in range(21):
        t = round(0.1 * k, 1)
        for i, name in enumerate(names):
            r = 93670.9 if (i == 14 and t > 1.05) else 194750.0
            rows.append(f"{t},{name},{r}")
    path = tmp_path / "rec.csv"
    path.write_text("\n".join(rows) + "\n", encoding="utf-8")
    return path


def test_from_record_takes_the_unloaded_window_and_polls_nothing(
    tmp_path: Path, no_device: list[str]
) -> None:
    path = write(tmp_path, HEAD + HAND + TAIL)
    rec = record(tmp_path)
    result = tare(path, "--from-record", str(rec), "--start-s", "0", "--end-s", "1")
    assert result.exit_code == 0, result.output
    assert no_device == []
    assert "baseline_ohm written for 36 of 36 channels (11 polls;" in result.output
    text = path.read_text(encoding="utf-8")
    assert array_block(text, "baseline_ohm") == ["194750"] * N
    assert "baseline_counts" not in text and "# written by hand" in text
    assert re.search(r"^\].*# tare: 0-1 s of rec\.csv$", text, re.M)


def test_from_record_over_a_loaded_moment_names_the_window(tmp_path: Path, no_device: list[str]) -> None:
    path = write(tmp_path, HEAD + HAND + TAIL)
    before = path.read_bytes()
    rec = record(tmp_path)
    # the whole record (the default): ch14 averages (11 x 194750 + 10 x 93670.9) / 21 = 146616.1
    # ohm, 0.44 N by the model and 1.33x the median conductance: not loaded, but moving: its
    # first third (0-0.6 s) reads 194750, its last (1.4-2 s) 93670.9: -101079.1 ohm, -68.9 % of
    # the mean, in 1.7 - 0.3 = 1.4 s: -49.2 %/s. A step, not noise: each third is flat.
    refused(
        tare(path, "--from-record", str(rec)),
        "tare: device jaw: the array is moving: ch14 (-68.9 % over 0-2 s of rec.csv, -49.2 %/s) (first third",
    )
    assert path.read_bytes() == before
    # the loaded second: 1.1-2 s
    line = refused(
        tare(path, "--from-record", str(rec), "--start-s", "1.1", "--end-s", "2"),
        "tare: device jaw: the array is loaded over 1.1-2 s of rec.csv: "
        "ch14 (1 N by the model at 9.367e+04 ohm, "
        "2.1x the median conductance)",
    )
    assert "(--channels 0-13,15-35)" in line
    assert path.read_bytes() == before and no_device == []


@pytest.mark.parametrize(
    ("args", "start"),
    [
        (
            ["--start-s", "5", "--end-s", "6"],
            "tare: the window 5-6 s of rec.csv holds no rows of ch00 (the record spans 0-2 s)",
        ),
        (
            ["--start-s", "1", "--end-s", "1"],
            "tare: the window 1-1 s of rec.csv is empty: --end-s must be after --start-s",
        ),
        (
            ["--channels", "ch00", "--start-s", "0", "--end-s", "0.5"],
            "tare: device jaw: too few polls in 0-0.5 s of rec.csv: ch00 (6 polls)",
        ),
    ],
)
def test_a_bad_window_is_one_line(tmp_path: Path, no_device: list[str], args: list[str], start: str) -> None:
    path = write(tmp_path, HEAD + HAND + TAIL)
    before = path.read_bytes()
    refused(tare(path, "--from-record", str(record(tmp_path)), *args), start)
    assert path.read_bytes() == before and no_device == []


def test_a_record_of_another_devices_channels_is_refused(tmp_path: Path, no_device: list[str]) -> None:
    path = write(tmp_path, HEAD + HAND + TAIL)
    before = path.read_bytes()
    rec = record(tmp_path, ["tip", "heel"])
    refused(
        tare(path, "--from-record", str(rec)),
        "tare: " + str(rec) + ": channels tip, heel are not channels of device jaw (ch00..ch35); "
        "a record of another device?",
    )
    assert path.read_bytes() == before and no_device == []


def test_a_window_without_a_record_is_refused(tmp_path: Path, no_device: list[str]) -> None:
    path = write(tmp_path, HEAD + TAIL)
    result = tare(path, "--start-s", "1")
    assert result.exit_code == 2
    assert (
        result.stderr
        == "tare: --start-s and --end-s choose a window of a record: give --from-record RECORD.csv\n"
    )
    assert no_device == []
