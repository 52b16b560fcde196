"""``compute_tare`` on synthetic polls of the acme-at6x6 array (12-bit low-side divider,
10 kohm pull-up: r = 10k * c / (4095 - c)), and ``set_device_array``, which writes the result
into the configuration file keeping its comments (or refuses and leaves it untouched)."""

from __future__ import annotations

import math
import re
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from gateway.analysis.tare import (
    MIN_POLLS,
    ChannelSeries,
    TareError,
    compute_tare,
    compute_tare_series,
    index_ranges,
)
from gateway.config import DeviceConfig, load_config, parse_config
from gateway.config.editor import set_device_array
from gateway.errors import ConfigError
from gateway.modbus.image import RawSample

CONFIG = """\
[[bus]]
name = "jaw"
kind = "tcp"
host = "127.0.0.1"

[[bus.device]]
name = "jaw"
device_id = 1
profile = "acme-at6x6"
"""
N = 36
REST = 3895  # counts at rest: 10k * 3895 / (4095 - 3895) = 194750 ohm
REST_OHM = 194_750.0
#: a zero-sum noise cycle of 5 polls; 30 polls hold it 6 times, each third of them twice
CYCLE = np.array([-2, -1, 0, 1, 2])
#: its standard deviation over 30 polls: sqrt(6 * (4 + 1 + 0 + 1 + 4) / 29) = sqrt(60 / 29)
CYCLE_STD = math.sqrt(60.0 / 29.0)


def acme(text: str = CONFIG) -> DeviceConfig:
    return parse_config(text, source=Path("/cfg/gateway.toml")).buses[0].devices[0]


def still(n_polls: int = 30) -> np.ndarray:
    """Counts of an array at rest, (polls, channels): 3895 with a zero-mean noise of +-2
    counts, the cycle shifted per channel; every third of 30 polls averages exactly 3895."""
    k = np.arange(n_polls)
    return np.array([REST + CYCLE[(k + ch) % 5] for ch in range(N)]).T


def samples(counts: np.ndarray) -> list[RawSample]:
    return [RawSample(counts=np.asarray(row, dtype=np.uint16)) for row in counts]


def refusal(device: DeviceConfig, polls: Sequence[RawSample], **limits: Any) -> str:
    with pytest.raises(TareError) as err:
        compute_tare(device, polls, **limits)
    return str(err.value)


# --------------------------------------------------------------------------- compute_tare
def test_a_still_unloaded_array_gives_its_baselines() -> None:
    result = compute_tare(acme(), samples(still()))
    assert result.key == "baseline_counts"
    assert result.values == (3895.0,) * N
    assert result.n_polls == 30 and result.notes == ()
    np.testing.assert_allclose(result.resistance_ohm, REST_OHM, rtol=1e-12)
    np.testing.assert_allclose(result.noise, CYCLE_STD, rtol=1e-12)
    # what the model reads at 194.75 kohm without the tare: about 0.119 N on every channel
    np.testing.assert_allclose(result.force_before_n, 0.1186, atol=5e-4)


def test_the_baseline_is_the_rounded_mean() -> None:
    counts = still()
    counts[:, 4] += 1  # 3896 on ch04
    counts[::2, 9] += 1  # ch09 alternates +1 / 0: mean 3895.5, rounded half to even: 3896
    counts[:10:3, 11] -= 1  # ch11: 4 of 30 polls one lower: mean 3894.87 -> 3895
    result = compute_tare(acme(), samples(counts))
    assert result.values[4] == 3896.0 and result.values[9] == 3896.0 and result.values[11] == 3895.0
    # the resistance is that of the mean, not of the rounded value:
    # ch09: 10k * 3895.5 / 199.5 = 195263.16 ohm
    assert result.resistance_ohm[9] == pytest.approx(10000.0 * 3895.5 / 199.5, rel=1e-12)


def test_a_drifting_channel_is_refused_by_name() -> None:
    counts = still()
    # ch07 ramps 10 counts over the window: round(10 k / 29), k = 0..29; its first third
    # averages 15 / 10 = 1.5, its last third 85 / 10 = 8.5 above 3890: a drift of +7 counts
    counts[:, 7] = 3890 + np.rint(10 * np.arange(30) / 29).astype(int)
    message = refusal(acme(), samples(counts))
    assert message.startswith("the array is moving: ch07 (+7 counts over the sampling window) (first third")
    assert "allowed: 2 counts or 4 standard errors" in message and "wiring" not in message
    assert message.endswith("nothing was written")
    assert "ch06" not in message and "ch08" not in message


def test_a_slow_creep_below_the_floor_is_not_drift() -> None:
    counts = still()
    counts[20:, 7] += 1  # the last third one count up: a drift of 1 < the 2-count floor
    result = compute_tare(acme(), samples(counts))
    assert result.values[7] == 3895.0  # mean 3895.33


def test_a_noisy_channel_is_refused_by_name() -> None:
    counts = still()
    # ch03 alternates 3895 +- 12: every third averages 3895 (no drift), std = 12 sqrt(30 / 29)
    counts[:, 3] = REST + 12 * np.where(np.arange(30) % 2 == 0, 1, -1)
    message = refusal(acme(), samples(counts))
    assert message.startswith(
        "too noisy over the sampling window: ch03 (std 12.2 counts); "
        "allowed: at most 8 counts (--max-noise); "
        "the array is still and unloaded, so check the wiring or shielding"
    )
    assert message.endswith("nothing was written")
    assert 12 * math.sqrt(30 / 29) == pytest.approx(12.205, abs=1e-3)
    # a higher limit lets it through (at the mean, 3895)
    result = compute_tare(acme(), samples(counts), max_noise_counts=12.5)
    assert result.values[3] == 3895.0 and result.noise[3] == pytest.approx(12 * math.sqrt(30 / 29))


def test_a_channel_the_model_reads_as_loaded_is_refused() -> None:
    counts = still()
    # ch10 at 3700 counts: 10k * 3700 / 395 = 93670.9 ohm, about 1.0 N (R(1 N) = 93.75 kohm)
    counts[:, 10] = 3700
    message = refusal(acme(), samples(counts))
    assert message.startswith(
        "the array is loaded over the sampling window: "
        "ch10 (1 N by the model at 9.367e+04 ohm, 2.1x the median conductance); "
        "allowed at rest: at most 0.5 N (--max-force) and 3x the median channel's conductance."
    )
    assert "(--channels 0-9,11-35)" in message
    assert message.endswith("nothing was written")
    # with a higher force limit, 93.67 kohm is still 2.08x the median conductance: accepted
    ratio = REST_OHM / (10000 * 3700 / 395)
    assert ratio == pytest.approx(2.079, abs=1e-3)
    assert compute_tare(acme(), samples(counts), max_force_n=2.0).values[10] == 3700.0


def test_a_channel_at_three_times_the_median_conductance_is_loaded() -> None:
    counts = still()
    # ch20 at 3412 counts: 10k * 3412 / 683 = 49956 ohm, 194750 / 49956 = 3.90x the median
    # channel's conductance (> 3x); the model's 1.9 N there is allowed by max_force_n = 100
    counts[:, 20] = 3412
    message = refusal(acme(), samples(counts), max_force_n=100.0)
    assert message.startswith(
        "the array is loaded over the sampling window: ch20 (1.9 N by the model at 4.996e+04 ohm, "
        "3.9x the median conductance)"
    )
    # ch21 at 3564 counts: 10k * 3564 / 531 = 67119 ohm, 2.90x: not loaded
    counts[:, 20] = REST
    counts[:, 21] = 3564
    ratio = REST_OHM / (10000 * 3564 / 531)
    assert ratio == pytest.approx(2.9016, abs=1e-4)
    assert compute_tare(acme(), samples(counts), max_force_n=100.0).values[21] == 3564.0


def test_fewer_than_min_polls_are_refused() -> None:
    assert MIN_POLLS == 10
    message = refusal(acme(), samples(still(9)))
    assert message.startswith("only 9 polls; a tare needs at least 10")
    assert compute_tare(acme(), samples(still(10))).n_polls == 10  # the limit itself
    # polls without counts (the wrong encoding) are not polls of this device
    floats = [RawSample(resistance_ohm=np.full(N, REST_OHM)) for _ in range(12)]
    assert "no values of this device's encoding" in refusal(acme(), floats)


def test_a_shorted_or_invalid_channel_is_faulty() -> None:
    counts = still()
    counts[:, 5] = 0  # low side: 0 counts is the short level (0 ohm)
    message = refusal(acme(), samples(counts))
    assert message.startswith("faulty at rest: ch05 (short);")
    assert message.endswith("nothing was written")
    counts[:, 5] = 5000  # above the 12-bit full scale: no reading
    assert refusal(acme(), samples(counts)).startswith("faulty at rest: ch05 (invalid);")


def test_many_channels_are_named_six_and_a_count() -> None:
    counts = still()
    counts[:, 0:8] = 0
    message = refusal(acme(), samples(counts))
    names = ", ".join(f"ch{i:02d} (short)" for i in range(6))
    assert message.startswith(f"faulty at rest: {names} and 2 more;")


def test_a_channel_open_at_rest_is_recorded_with_a_note() -> None:
    counts = still()
    counts[:, 12] = 4095  # low side: full scale is an open sensor
    result = compute_tare(acme(), samples(counts))
    assert result.values[12] == 4095.0 and math.isinf(result.resistance_ohm[12])
    assert math.isnan(result.force_before_n[12])
    assert len(result.notes) == 1 and result.notes[0].startswith("ch12 (open) read at a rail at rest")
    # the baseline goes back through the configuration as an infinite resistance
    text = CONFIG + f"baseline_counts = [{', '.join(str(int(v)) for v in result.values)}]\n"
    assert math.isinf(acme(text).channels[12].baseline_ohm or 0.0)


def test_a_float_device_is_tared_in_ohm() -> None:
    sim = 'profile = "tactile-sim"\nchannels = 4\nencoding = "float32"'
    device = acme(CONFIG.replace('profile = "acme-at6x6"', sim))
    # +-0.2 % around 194750 ohm, the zero-sum cycle shifted per channel
    rows = [
        RawSample(resistance_ohm=REST_OHM * (1 + 0.001 * CYCLE[(i + np.arange(4)) % 5])) for i in range(30)
    ]
    result = compute_tare(device, rows)
    assert result.key == "baseline_ohm"
    np.testing.assert_allclose(result.values, REST_OHM, rtol=1e-12)
    # 2 % of the reading is the noise limit: +-3 % swings are too noisy
    noisy = [RawSample(resistance_ohm=REST_OHM * (1 + 0.03 * (-1) ** i) * np.ones(4)) for i in range(30)]
    # std of +-3 % over 30 polls: 3 sqrt(30 / 29) = 3.05 % of the mean, 194750 ohm
    assert refusal(device, noisy).startswith(
        "too noisy over the sampling window: ch00 (std 3.05 % of 1.948e+05 ohm)"
    )
    assert "allowed: at most 2 % of the reading" in refusal(device, noisy)


@pytest.mark.parametrize("case", ["few polls", "wrong encoding", "drift", "noise", "loaded", "faulty"])
def test_every_refusal_says_nothing_was_written(case: str) -> None:
    counts = still()
    polls = samples(counts)
    if case == "few polls":
        polls = polls[: MIN_POLLS - 1]
    elif case == "wrong encoding":
        polls = [RawSample(resistance_ohm=np.full(N, REST_OHM)) for _ in range(12)]
    elif case == "drift":
        counts[:, 1] = 3880 + np.arange(30)
        polls = samples(counts)
    elif case == "noise":
        counts[:, 1] = REST + 20 * (-1) ** np.arange(30)
        polls = samples(counts)
    elif case == "loaded":
        counts[:, 1] = 3500
        polls = samples(counts)
    else:
        counts[:, 1] = 0
        polls = samples(counts)
    assert refusal(acme(), polls).endswith("; nothing was written")


# --------------------------------------------------------------------------- the cause, in order
BLOB = [14, 15, 20, 21]  # a blob resting on the middle 2 x 2 cells


def busy() -> np.ndarray:
    """The user's array: a blob loads the middle four cells (3700 counts, 1.0 N each by the
    model) and their readings scatter +-12 counts (std 12.2 > the 8-count noise limit)."""
    counts = still()
    for ch in BLOB:
        counts[:, ch] = 3700 + 12 * np.where(np.arange(30) % 2 == 0, 1, -1)
    return counts


def test_a_loaded_noisy_array_is_called_loaded_not_noisy() -> None:
    message = refusal(acme(), samples(busy()))
    # 3700 counts: 10k * 3700 / 395 = 93670.9 ohm; 194750 / 93670.9 = 2.08x the median conductance
    one = "1 N by the model at 9.367e+04 ohm, 2.1x the median conductance"
    assert message.startswith(
        "the array is loaded over the sampling window: "
        f"ch14 ({one}), ch15 ({one}), ch20 ({one}), ch21 ({one}); "
        "allowed at rest: at most 0.5 N (--max-force) and 3x the median channel's conductance."
    )
    # the ways out: the unloaded channels by index, a record, the device's own zero
    assert "tare only the unloaded channels (--channels 0-13,16-19,22-35)" in message
    assert "--from-record RECORD.csv --start-s S --end-s E" in message
    assert "--device-zero" in message
    assert "noisy" not in message and "wiring" not in message and "shielding" not in message
    assert message.endswith("; nothing was written")


def test_the_unloaded_channels_of_a_loaded_array_are_tared_alone() -> None:
    rest = [c for c in range(N) if c not in BLOB]
    result = compute_tare(acme(), samples(busy()), channels=rest)
    assert result.channels == tuple(rest)
    assert result.values == (3895.0,) * 32
    assert len(result.resistance_ohm) == len(result.noise) == 32
    # one loaded channel among the chosen ones is refused, named by its own name
    message = refusal(acme(), samples(busy()), channels=[0, 1, 2, 3, 14])
    assert message.startswith("the array is loaded over the sampling window: ch14 (1 N by the model")
    assert "(--channels 0-3)" in message


def test_a_drift_with_times_gives_its_rate_and_comes_before_noise() -> None:
    counts = still()
    counts[:, 7] = 3890 + np.rint(10 * np.arange(30) / 29).astype(int)  # +7 counts (see above)
    counts[:, 3] = REST + 12 * np.where(np.arange(30) % 2 == 0, 1, -1)  # noisy, but second
    # polls every 0.1 s: the first third's mean time is 0.45 s, the last third's 2.45 s:
    # +7 counts in 2 s = +3.5 counts/s
    times = [0.1 * k for k in range(30)]
    message = refusal(acme(), samples(counts), times_s=times, window="the 3 s sampled")
    assert message.startswith("the array is moving: ch07 (+7 counts over the 3 s sampled, +3.5 counts/s)")
    assert "ch03" not in message and "wiring" not in message


def test_a_step_is_moving_not_noise() -> None:
    counts = still()
    # a load lands on ch07 half-way: 3895 for 15 polls, then 3865. Its std over the 30 polls
    # is 15 sqrt(30 / 29) = 15.3 counts, above the 8-count noise limit, but each third is flat
    # (+-2 counts): the first third reads 3895, the last 3865, a drift of -30 counts
    counts[15:, 7] -= 30
    message = refusal(acme(), samples(counts))
    assert message.startswith("the array is moving: ch07 (-30 counts over the sampling window)")
    assert "noisy" not in message and "wiring" not in message


def test_a_drift_in_ohm_is_given_in_percent_per_second() -> None:
    sim = 'profile = "tactile-sim"\nchannels = 4\nencoding = "float32"'
    device = acme(CONFIG.replace('profile = "acme-at6x6"', sim))
    # ch02 rises 0.1 % per poll, 30 polls 0.5 s apart: the thirds' means differ by 20 polls,
    # 2 % of 194750 ohm over 10 s: +2 % and +0.2 %/s (mean 1.0145 x 194750 -> +1.97 %)
    k = np.arange(30)
    series = [ChannelSeries(i, np.full(30, REST_OHM), 0.5 * k) for i in range(4)]
    series[2] = ChannelSeries(2, REST_OHM * (1 + 0.001 * k), 0.5 * k)
    with pytest.raises(TareError) as err:
        compute_tare_series(device, series, counts=False, window="0-14.5 s of r.csv")
    # drift 20 * 0.001 * 194750 = 3895 ohm over the mean 1.0145 * 194750: 1.971 %; per s / 10
    assert str(err.value).startswith("the array is moving: ch02 (+1.97 % over 0-14.5 s of r.csv, +0.197 %/s)")
    assert "allowed: 0.5 % of the reading or 4 standard errors" in str(err.value)


def test_a_record_window_with_too_few_rows_is_named() -> None:
    sim = 'profile = "tactile-sim"\nchannels = 4\nencoding = "float32"'
    device = acme(CONFIG.replace('profile = "acme-at6x6"', sim))
    series = [ChannelSeries(i, np.full(12 if i else 4, REST_OHM)) for i in range(4)]
    with pytest.raises(TareError) as err:
        compute_tare_series(device, series, counts=False, window="2-3 s of r.csv")
    assert str(err.value).startswith(
        "too few polls in 2-3 s of r.csv: ch00 (4 polls); a tare needs at least 10"
    )


def test_index_ranges() -> None:
    assert index_ranges([5, 0, 1, 2, 7, 8]) == "0-2,5,7-8"
    assert index_ranges([3]) == "3"


# --------------------------------------------------------------------------- set_device_array
FILE = """\
# a lab's grasper jaw
[[bus]]
name = "jaw"   # the bench bus
kind = "tcp"
host = "127.0.0.1"

[[bus.device]]
name = "jaw"   # the left jaw
device_id = 1
profile = "acme-at6x6"
# measured by hand last week
baseline_ohm = [{}]

# the model of the cells
[bus.device.model]
effects = ["tunneling", "contact", "creep"]  # the paper's
""".format(", ".join(["2e5"] * N))


@pytest.fixture
def config_file(tmp_path: Path) -> Path:
    path = tmp_path / "gateway.toml"
    path.write_text(FILE, encoding="utf-8")
    return path


def comments(text: str) -> list[str]:
    return [line[line.index("#") :] for line in text.splitlines() if "#" in line]


def test_the_array_replaces_the_other_key_and_keeps_every_comment(config_file: Path) -> None:
    assert load_config(config_file).buses[0].devices[0].channels[0].baseline_ohm == 2e5
    values = [3895.0] * N
    device = set_device_array(
        config_file, "jaw", "baseline_counts", values, replaces=("baseline_ohm",), comment="tare: 30 polls"
    )
    text = config_file.read_text(encoding="utf-8")
    assert "baseline_ohm" not in text
    for comment in comments(FILE):
        assert comment in text, comment
    # one grid row (6 columns) per line, integers as integers
    block = re.search(r"^baseline_counts = \[\n(.*?)\n\]", text, re.M | re.S)
    assert block is not None
    assert block.group(1).splitlines() == ["    3895, 3895, 3895, 3895, 3895, 3895,"] * 6
    assert re.search(r"^\].*# tare: 30 polls$", text, re.M)
    # the returned device and the file re-read both have the baselines: 194750 ohm each
    for dev in (device, load_config(config_file).buses[0].devices[0]):
        assert [c.baseline_ohm for c in dev.channels] == pytest.approx([REST_OHM] * N, rel=1e-12)
        assert dev.layout.origin == "bottom-left"  # the rest of the device as it was


def test_the_values_are_aligned_and_keep_their_spelling(config_file: Path) -> None:
    values = [3895.0] * N
    values[0] = 3895.5
    values[35] = 3900.0
    set_device_array(config_file, "jaw", "baseline_counts", values, replaces=("baseline_ohm",))
    text = config_file.read_text(encoding="utf-8")
    block = re.search(r"^baseline_counts = \[\n(.*?)\n\]", text, re.M | re.S)
    assert block is not None
    rows = block.group(1).splitlines()
    assert len(rows) == 6
    # the widest value (3895.5, 6 characters) sets the width of every column
    assert rows[0] == "    3895.5,   3895,   3895,   3895,   3895,   3895,"
    assert rows[5] == "      3895,   3895,   3895,   3895,   3895,   3900,"
    baselines = [c.baseline_ohm for c in load_config(config_file).buses[0].devices[0].channels]
    assert baselines[0] == pytest.approx(10000 * 3895.5 / 199.5, rel=1e-12)
    assert baselines[35] == pytest.approx(10000 * 3900 / 195, rel=1e-12)  # 200000 ohm


def test_a_key_the_device_already_has_is_rewritten_in_place(config_file: Path) -> None:
    set_device_array(config_file, "jaw", "baseline_ohm", [1.5e5] * N)
    text = config_file.read_text(encoding="utf-8")
    assert text.count("baseline_ohm") == 1
    assert text.index("# measured by hand last week") < text.index("baseline_ohm")
    assert text.index("baseline_ohm") < text.index("[bus.device.model]")
    assert [c.baseline_ohm for c in load_config(config_file).buses[0].devices[0].channels] == [1.5e5] * N


@pytest.mark.parametrize(
    ("device", "key", "values", "replaces", "reason"),
    [
        ("jaw", "baseline_counts", [3895.0] * 35, ("baseline_ohm",), "expected an array of 36 numbers"),
        ("jaw", "baseline_counts", [3895.0] * N, (), "give baseline_counts or baseline_ohm, not both"),
        ("jaw", "baseline_counts", [0.0] * N, ("baseline_ohm",), "is not an unloaded reading"),
        ("jaw", "baseline_ohm", [0.0] * N, (), "out of range"),
        ("jow", "baseline_counts", [3895.0] * N, ("baseline_ohm",), "no device 'jow'; did you mean 'jaw'?"),
    ],
)
def test_a_refused_edit_leaves_the_file_byte_for_byte(
    config_file: Path, device: str, key: str, values: list[float], replaces: tuple[str, ...], reason: str
) -> None:
    before = config_file.read_bytes()
    with pytest.raises(ConfigError) as err:
        set_device_array(config_file, device, key, values, replaces=replaces, comment="tare")
    assert reason in str(err.value)
    if device == "jaw":
        assert str(err.value).startswith(f"refused, {config_file} is unchanged")
    assert config_file.read_bytes() == before
    assert sorted(p.name for p in config_file.parent.iterdir()) == ["gateway.toml"]  # no temp file left
