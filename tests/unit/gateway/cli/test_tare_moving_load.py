"""``tactile-gateway tare --moving-load`` end to end through click, on an acme-at6x6 array (12-bit
low-side divider, 10 kohm pull-up: r = 10k * c / (4095 - c)) under a load that moves: a bar
three columns wide sweeps the grid once in 36 s, so channel i (column g = i % 6) is loaded while
``(t - 6 g) mod 36 < 18`` s and at every moment 18 channels are loaded. Each channel has its own
hand-set baseline; ch14 also carries a resting part and is never unloaded.

From a record (ohm): the plain tare refuses, the moving-load tare writes every channel's own
baseline, ch14 as "none", and says when each was taken. Live (counts): the sampler is replaced
by hand-built polls, so the spans and the default window are checked exactly."""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from click.testing import CliRunner, Result

from gateway.cli import main, tare_cmd
from gateway.config import BusConfig, DeviceConfig, load_config
from gateway.modbus.image import RawSample

N = 36
DT_S = 0.1
POLLS = 360
TIME_S: np.ndarray[Any, np.dtype[np.float64]] = DT_S * np.arange(POLLS, dtype=np.float64)
BASE = np.array([3880 + 3 * (i % 7) for i in range(N)])  # counts
BASE_OHM = 10_000.0 * BASE / (4095 - BASE)
LOAD = 3300  # 41509 ohm
STUCK = 14  # never unloaded: at most 3500 counts, 58824 ohm
CYCLE = np.array([-2, -1, 0, 1, 2])  # zero-sum noise (counts)

CONFIG = """\
# the user's 6x6 board
[[bus]]
name = "lab"
kind = "tcp"
host = "127.0.0.1"

[[bus.device]]
name = "jaw"   # the left jaw
device_id = 1
profile = "acme-at6x6"
"""


def loaded(i: int) -> np.ndarray:
    return ((TIME_S - 6.0 * (i % 6)) % 36.0) < 18.0 - 1e-9


def counts() -> np.ndarray:
    """(polls, channels) of the moving load, +-2 counts of zero-sum noise."""
    out = np.empty((POLLS, N))
    k = np.arange(POLLS)
    for i in range(N):
        noise = CYCLE[(k + i) % 5]
        out[:, i] = np.where(loaded(i), LOAD, BASE[i]) + noise
    out[:, STUCK] = np.minimum(out[:, STUCK], 3500 + CYCLE[k % 5])
    return out


def write_record(tmp_path: Path) -> Path:
    """The same load as resistances (ohm), one row per channel and poll."""
    c = counts()
    r = 10_000.0 * c / (4095 - c)
    rows = ["# source: a test", "time_s,channel,resistance_ohm"]
    for k in range(POLLS):
        rows.extend(f"{TIME_S[k]:.1f},ch{i:02d},{r[k, i]:.2f}" for i in range(N))
    path = tmp_path / "walk.csv"
    path.write_text("\n".join(rows) + "\n", encoding="utf-8")
    return path


def config(tmp_path: Path) -> Path:
    path = tmp_path / "gateway.toml"
    path.write_text(CONFIG, encoding="utf-8")
    return path


def tare(path: Path, *args: str) -> Result:
    return CliRunner().invoke(main, ["tare", "-c", str(path), *args])


def array_block(text: str, key: str) -> list[str]:
    block = re.search(rf"^{key} = \[\n(.*?)\n\]", text, re.M | re.S)
    assert block is not None, text
    return [v.strip() for v in block.group(1).replace("\n", " ").split(",") if v.strip()]


@pytest.fixture
def sampled(monkeypatch: pytest.MonkeyPatch) -> list[float]:
    """The live sampler answers the hand-built polls at host times 1000 s + 0.1 s k; the
    durations it was asked for are recorded."""
    asked: list[float] = []
    c = counts()

    async def fake(bus: BusConfig, device: DeviceConfig, duration_s: float) -> list[tuple[float, RawSample]]:
        asked.append(duration_s)
        return [(1000.0 + TIME_S[k], RawSample(counts=c[k].astype(np.uint16))) for k in range(POLLS)]

    monkeypatch.setattr(tare_cmd, "sample_device", fake)
    return asked


def test_a_record_of_a_moving_load_is_zeroed_channel_by_channel(tmp_path: Path) -> None:
    path = config(tmp_path)
    rec = write_record(tmp_path)
    plain = tare(path, "--from-record", str(rec))
    assert plain.exit_code == 2 and "nothing was written" in plain.stderr
    assert path.read_text(encoding="utf-8") == CONFIG

    result = tare(path, "--moving-load", "--from-record", str(rec))
    assert result.exit_code == 0, result.output
    out = result.output
    assert (
        "device jaw: baseline_ohm written for 35 of 36 channels, each from its own still, unloaded "
        "stretch of 0-35.9 s of walk.csv" in out
    )
    # when: ch00 (column 0) is unloaded 18-35.9 s, ch05 (column 5) 12-29.9 s, ch01 24-35.9 s
    assert re.search(r"^  ch00: 1\.80\d\de\+05 ohm at 18-35\.9 s \(180 polls\)$", out, re.M), out
    assert re.search(r"^  ch05: 1\.94\d\de\+05 ohm at 12-29\.9 s \(180 polls\)$", out, re.M), out
    assert re.search(r"^  ch01: .* at 24-35\.9 s \(120 polls\)$", out, re.M), out
    assert "not zeroed: ch14 (loaded throughout 0-35.9 s of walk.csv: at its least loaded (30-35.9 s" in out
    assert 'ch14 had no baseline: written as "none"' in out
    text = path.read_text(encoding="utf-8")
    assert text.startswith(CONFIG)  # every line and comment kept
    assert re.search(r"^\].*# tare --moving-load: 0-35\.9 s of walk\.csv$", text, re.M)
    values = array_block(text, "baseline_ohm")
    assert values[STUCK] == '"none"'
    channels = load_config(path).buses[0].devices[0].channels
    assert channels[STUCK].baseline_ohm is None
    for i in range(N):
        if i != STUCK:
            # the noise of +-2 counts is +-1 % in ohm, zero-sum in counts; the mean of its
            # resistances is within 0.1 % of the baseline's resistance
            assert channels[i].baseline_ohm == pytest.approx(BASE_OHM[i], rel=1e-3), i
    checked = CliRunner().invoke(main, ["check-config", "-c", str(path)])
    assert checked.exit_code == 0, checked.output
    assert "zero: 35 channel(s) with an unloaded baseline" in checked.output


def test_live_the_moving_load_is_sampled_and_zeroed_in_counts(tmp_path: Path, sampled: list[float]) -> None:
    """The file has counts baselines written by hand: the tared channels get their own, ch14
    keeps its 4000 (not zeroed, its old baseline stays)."""
    path = tmp_path / "gateway.toml"
    path.write_text(CONFIG + "baseline_counts = [{}]\n".format(", ".join(["4000"] * N)), encoding="utf-8")
    result = tare(path, "--moving-load", "--seconds", "36")
    assert result.exit_code == 0, result.output
    assert sampled == [36.0]
    out = result.output
    assert "for 36 s; the load may move: each channel must rest, still and unloaded, for 10 polls" in out
    assert "baseline_counts written for 35 of 36 channels, each from its own still, unloaded stretch " in out
    # times from the first poll (host time 1000 s)
    assert re.search(r"^  ch00: 3880 counts \(1\.805e\+05 ohm\) at 18-35\.9 s \(180 polls\)$", out, re.M), out
    values = array_block(path.read_text(encoding="utf-8"), "baseline_counts")
    assert values == ["4000" if i == STUCK else str(BASE[i]) for i in range(N)]
    assert "not zeroed: ch14 (loaded throughout the 36 s sampled: at its least loaded (30-35.9 s" in out
    assert "note: the other 1 channels keep their baselines" in out


def test_the_moving_load_window_defaults_to_30_s(tmp_path: Path, sampled: list[float]) -> None:
    assert tare(config(tmp_path), "--moving-load").exit_code == 0
    assert tare(config(tmp_path), "--seconds", "2").exit_code == 2  # plain: the array is loaded
    assert sampled == [30.0, 2.0]


def test_nothing_rested_is_one_line_and_nothing_is_written(tmp_path: Path) -> None:
    path = config(tmp_path)
    rec = write_record(tmp_path)
    result = tare(path, "--moving-load", "--from-record", str(rec), "--channels", "14", "--end-s", "20")
    assert result.exit_code == 2
    lines = result.stderr.splitlines()
    assert len(lines) == 1, lines
    assert lines[0].startswith(
        "tare: device jaw: no channel rested in 0-20 s of walk.csv: ch14 (loaded throughout"
    )
    assert lines[0].endswith("nothing was written")
    assert path.read_text(encoding="utf-8") == CONFIG


def test_moving_load_tares_only_the_chosen_channels(tmp_path: Path) -> None:
    """--channels with --moving-load: ch00 and ch05 zeroed at their own moments, the others
    untouched ("none": the file had no baselines)."""
    path = config(tmp_path)
    result = tare(path, "--moving-load", "--from-record", str(write_record(tmp_path)), "--channels", "ch00,5")
    assert result.exit_code == 0, result.output
    assert "baseline_ohm written for 2 of 36 channels" in result.output
    assert re.search(r"^  ch00: .* at 18-35\.9 s \(180 polls\)$", result.output, re.M), result.output
    assert re.search(r"^  ch05: .* at 12-29\.9 s \(180 polls\)$", result.output, re.M), result.output
    values = array_block(path.read_text(encoding="utf-8"), "baseline_ohm")
    assert [i for i, v in enumerate(values) if v != '"none"'] == [0, 5]


def test_moving_load_and_device_zero_are_refused_together(tmp_path: Path, sampled: list[float]) -> None:
    result = tare(config(tmp_path), "--moving-load", "--device-zero")
    assert result.exit_code == 2 and sampled == []
    assert result.stderr == (
        "tare: --moving-load takes baselines from samples, --device-zero has the device zero "
        "itself: choose one\n"
    )
