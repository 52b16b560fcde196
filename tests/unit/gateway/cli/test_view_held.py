"""``view`` of a record whose channels are sampled at their own times (issue 33 §8): at a
device sample where a channel has no row, the page shows that channel's last reading
(sample-and-hold: its force and status), not an error; before a channel's first row it has
nothing to show (``error``). Every frame equals the sample-and-hold of what the replay read at
each row (``runtime.replay.replay``, the per-row results ``apply`` writes)."""

from __future__ import annotations

import math
import tempfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from gateway.analysis.records import read_record
from gateway.cli.view_cmd import fallback_device, load_playback, record_snapshots
from gateway.runtime.processor import DeviceProcessor
from gateway.runtime.replay import ChannelSeries, replay
from gateway.runtime.snapshot import IN_CONTACT, ChannelStatus, array_quantities
from gateway.web.frames import frame_json
from gateway.web.playback import page_frames

OK, ERROR = int(ChannelStatus.OK), int(ChannelStatus.ERROR)


def _write(path: Path, rows: list[tuple[float, str, float]]) -> Path:
    text = "time_s,channel,resistance_ohm\n" + "".join(f"{t!r},{c},{r!r}\n" for t, c, r in rows)
    path.write_text(text, encoding="utf-8")
    return path


def test_a_channel_without_a_row_at_a_time_keeps_its_last_reading(tmp_path: Path) -> None:
    rows = [(0.0, "a", 20e3), (0.1, "b", 50e3), (0.2, "a", 20e3), (0.3, "b", 50e3), (0.4, "a", 30e3)]
    pb = load_playback(_write(tmp_path / "rec.csv", rows), None, None)
    assert [f["t"] for f in pb.frames] == [0.0, 0.1, 0.2, 0.3, 0.4]
    status = [f["status"] for f in pb.frames]
    force = [f["force_n"] for f in pb.frames]
    # b has no reading before 0.1 s: nothing to show; afterwards each channel holds its last one
    assert status == [[OK, ERROR], [OK, OK], [OK, OK], [OK, OK], [OK, OK]]
    assert force[0][1] is None
    a0, b1, a2, a4 = force[0][0], force[1][1], force[2][0], force[4][0]
    assert a0 is not None and b1 is not None and a2 is not None and a4 is not None
    assert a0 > b1 > 0.0  # 20 kohm presses harder than 50 kohm
    assert force[1][0] == a0 and force[2][1] == b1 and force[3][0] == a2
    assert force[4][1] == force[3][1] and a4 < a2  # a's resistance rose
    for f in pb.frames:
        shown = [v for v in f["force_n"] if v is not None]
        assert f["total_force_n"] == round(math.fsum(shown), 6)
        assert f["channels_in_contact"] == len(shown)


times_and_rows = st.lists(
    st.tuples(st.sampled_from((0.0, 0.01, 0.25, 2.0)), st.sampled_from(("a", "b", "c")),
              st.sampled_from((15e3, 40e3, 160e3, math.inf))),
    min_size=1, max_size=30,
)  # fmt: skip


@settings(max_examples=30, deadline=None)
@given(times_and_rows)
def test_every_frame_is_the_sample_and_hold_of_the_rows(rows: list[tuple[float, str, float]]) -> None:
    steps = np.cumsum([step for step, _, _ in rows])
    record_rows = [(float(t), c, r) for t, (_, c, r) in zip(steps.tolist(), rows, strict=True)]
    with tempfile.TemporaryDirectory() as tmp:
        path = _write(Path(tmp) / "rec.csv", record_rows)
        record = read_record(path)
        pb = load_playback(path, None, None)
    device = fallback_device(record)
    names = list(record.channels)
    series = [ChannelSeries(record.channels[n].time_s, record.channels[n].resistance_ohm) for n in names]
    results, n_device = replay(DeviceProcessor(device, "record", 0.1), series)
    # by hand: device samples in time order, the k-th row of a channel at a time in the k-th
    keys = []
    seen: dict[tuple[str, float], int] = {}
    for t, c, _ in record_rows:
        k = seen.get((c, t), 0)
        seen[(c, t)] = k + 1
        keys.append((t, k))
    samples = sorted(set(keys))
    assert n_device == len(samples) == len(pb.frames) == pb.samples_total
    row_of = {n: 0 for n in names}
    shown: dict[str, tuple[float | None, int]] = {n: (None, ERROR) for n in names}
    by_sample: dict[tuple[float, int], list[str]] = {}
    for (_, c, _), key in zip(record_rows, keys, strict=True):
        by_sample.setdefault(key, []).append(c)
    for frame, key in zip(pb.frames, samples, strict=True):
        for c in by_sample[key]:
            i = row_of[c]
            row_of[c] += 1
            j = names.index(c)
            f = float(results[j].force_n[i])
            shown[c] = (round(f, 6) if math.isfinite(f) else None, int(results[j].status[i]))
        assert frame["t"] == round(key[0], 6)
        assert frame["force_n"] == [shown[n][0] for n in names]
        assert frame["status"] == [shown[n][1] for n in names]
        in_contact = [
            v for n in names if (v := shown[n][0]) is not None and v > 0 and IN_CONTACT[shown[n][1]]
        ]
        assert frame["channels_in_contact"] == len(in_contact)
        assert math.isclose(frame["total_force_n"], math.fsum(in_contact), rel_tol=1e-9, abs_tol=1e-5)


def test_the_frames_of_held_snapshots_are_the_live_frames_and_quantities(tmp_path: Path) -> None:
    """``playback.page_frames`` (rounded over all snapshots at once) equals ``frame_json`` of
    each snapshot, and each held snapshot's array quantities are ``array_quantities`` of its
    readings: the page draws a playback as it draws a live poll."""
    rows = [(0.1 * k, "abc"[k % 3], (15e3, 40e3, math.inf, 160e3, 7e3)[k % 5]) for k in range(40)]
    rows += [(4.0, "a", 20e3), (4.0, "a", 25e3), (4.0, "b", math.inf)]  # a time repeated by a
    record = read_record(_write(tmp_path / "rec.csv", rows))
    device = fallback_device(record)
    snaps, has_reference, n_samples = record_snapshots(record, device)
    assert not has_reference and n_samples == len(snaps) == 42
    slow = [
        {**frame_json(s, seq, None), "reference_total_force_n": None} for seq, s in enumerate(snaps, start=1)
    ]
    assert page_frames(snaps, has_reference=False) == slow
    assert [f["force_n"] for f in slow] == [[round(v, 6) if math.isfinite(v) else None for v in s.force_n]
                                            for s in snaps]  # fmt: skip
    area = device.layout.cell_area_mm2
    for s in snaps:
        q = array_quantities(s.force_n, s.status, s.x_mm, s.y_mm, area)
        peak = None if q.peak_index is None else s.channel_names[q.peak_index]
        assert (s.channels_in_contact, s.peak_channel) == (q.channels_in_contact, peak)
        assert math.isclose(s.total_force_n, q.total_force_n, rel_tol=1e-12, abs_tol=1e-15)
        assert s.contact_area_mm2 == q.contact_area_mm2 and s.peak_force_n == q.peak_force_n
        if q.center_of_pressure_mm is None:
            assert s.center_of_pressure_mm is None
        else:
            assert s.center_of_pressure_mm == pytest.approx(q.center_of_pressure_mm, rel=1e-12, abs=1e-12)
    # the last sample: a's second reading at 4 s, b's at 4 s (no current: no contact), c held
    last, held = snaps[-1], snaps[-3]
    assert [int(v) for v in last.status] == [OK, int(ChannelStatus.NO_CONTACT), OK]
    assert last.force_n[1] == 0.0 and last.force_n[2] == held.force_n[2] > 0.0
    assert last.force_n[0] < snaps[-2].force_n[0]  # 25 kohm after 20 kohm


def test_a_thinned_record_keeps_the_count_and_holds_every_channel(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """30 rows over three channels, each its own time, thinned to at most 7 frames: the page
    says 30 device samples, and the last frame (always kept) shows each channel's last reading,
    not one channel's reading beside errors."""
    from gateway.cli import view_cmd
    from gateway.web import playback

    monkeypatch.setattr(view_cmd, "thin", lambda n: playback.thin(n, 7))
    rows = [(0.1 * k, "abc"[k % 3], (15e3, 40e3, 160e3)[k % 3]) for k in range(30)]
    pb = load_playback(_write(tmp_path / "rec.csv", rows), None, None)
    assert pb.samples_total == 30 and len(pb.frames) <= 7
    last = pb.frames[-1]
    assert last["t"] == 2.9 and last["status"] == [OK, OK, OK]
    a, b, c = last["force_n"]
    assert a is not None and b is not None and c is not None and a > b > c > 0.0  # 15 < 40 < 160 kohm
    assert last["channels_in_contact"] == 3
