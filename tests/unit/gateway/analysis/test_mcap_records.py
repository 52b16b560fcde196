"""MCAP records (issue 34 §6): the writer's file reads back to the same ``Record`` as the CSV
form of the same rows; the file is checked independently with the ``mcap`` reader and
``mcap-ros2-support``'s decoder; bad files get a one-line ``RecordError``."""

from __future__ import annotations

import io
import math
import os
import struct
import threading
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from mcap.reader import make_reader
from mcap.writer import Writer
from mcap_ros2.decoder import DecoderFactory

from gateway.analysis import records as records_module
from gateway.analysis.mcap_records import MCAP_MAGIC, SCHEMA_NAME, McapRecordWriter
from gateway.analysis.recorder import LiveRecorder, is_record_file, record_path_ok
from gateway.analysis.records import Record, RecordError, RecordWriter, read_record
from gateway.atomic import AtomicFile
from gateway.config import ChannelConfig, DeviceConfig, RegisterMap, bus_config_for, gateway_config_for
from gateway.config.layout import GridLayout
from gateway.modbus.image import RawSample
from gateway.model import PAPER_EFFECTS, Divider, SensorParams
from gateway.runtime.processor import DeviceProcessor
from gateway.runtime.snapshot import GatewaySnapshot

Row = tuple[float, str, float, float | None, float | None]


def _write(
    path: Path, fmt: str, rows: Sequence[Row], meta: dict[str, str], force: bool, temp: bool, levels: int = 0
) -> None:
    with AtomicFile(path) as out:
        writer: RecordWriter | McapRecordWriter
        if fmt == "mcap":
            writer = McapRecordWriter(out, meta, has_force=force, has_temperature=temp, device_levels=levels)
        else:
            writer = RecordWriter(out.text, meta, has_force=force, has_temperature=temp)
        for row in rows:
            writer.row(*row)
        writer.close()
        out.commit()


def _table(record: Record) -> dict[str, list[tuple[float, ...]]]:
    """Every channel's rows as tuples of its columns, in order (the record's content)."""
    out = {}
    for name, ch in record.channels.items():
        cols = [ch.time_s, ch.resistance_ohm]
        cols += [ch.force_n] if ch.force_n is not None else []
        cols += [ch.temperature_c] if ch.temperature_c is not None else []
        out[name] = [tuple(float(c[i]) for c in cols) for i in range(ch.n_samples)]
    return out


def _polls(n_polls: int, devices: Sequence[str], channels: int) -> list[Row]:
    """Rows of ``n_polls`` polls of each device, a recorder's order: per poll, device by device."""
    rows: list[Row] = []
    for p in range(n_polls):
        for d, dev in enumerate(devices):
            for k in range(channels):
                r = math.inf if (k + p) % 5 == 0 else 1e3 * (k + 1) + 17.25 * p + d
                rows.append((round(0.0333 * p, 6), f"{dev}/ch{k:02d}", r, 0.25 * p, 21.5 + 0.01 * k))
    return rows


def test_an_mcap_record_reads_back_as_the_csv_record_of_the_same_rows(tmp_path: Path) -> None:
    rows = _polls(20, ["left", "right"], 6)
    meta = {"source": "tactile-gateway record", "config": "hand.toml"}
    _write(tmp_path / "r.csv", "csv", rows, meta, True, True)
    _write(tmp_path / "r.mcap", "mcap", rows, meta, True, True, levels=1)
    csv_rec, mcap_rec = read_record(tmp_path / "r.csv"), read_record(tmp_path / "r.mcap")
    assert (
        list(mcap_rec.channels)
        == list(csv_rec.channels)
        == [f"{d}/ch{k:02d}" for d in ("left", "right") for k in range(6)]
    )
    assert _table(mcap_rec) == _table(csv_rec)
    assert mcap_rec.metadata == csv_rec.metadata == meta
    # hand-checked values: left/ch01 at poll 3: r = 2000 + 17.25 * 3, force 0.75 N, 21.51 degC
    assert _table(mcap_rec)["left/ch01"][3] == (0.0999, 2051.75, 0.75, 21.51)
    assert _table(mcap_rec)["left/ch00"][0][1] == math.inf  # an open circuit stays inf
    # a sample's position is its message: 2 devices a poll, left first
    assert mcap_rec.channels["right/ch00"].line.tolist() == [2 * p + 2 for p in range(20)]


def test_the_file_is_standard_mcap_read_by_the_mcap_reader_and_the_ros2_decoder(tmp_path: Path) -> None:
    rows = _polls(12, ["left", "right"], 4)
    _write(tmp_path / "r.mcap", "mcap", rows, {"source": "test"}, True, False, levels=1)
    with open(tmp_path / "r.mcap", "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        assert reader.get_header().profile == "ros2"
        summary = reader.get_summary()
        assert summary is not None and summary.statistics is not None
        assert [(s.name, s.encoding) for s in summary.schemas.values()] == [(SCHEMA_NAME, "ros2msg")]
        topics = sorted((c.topic, c.message_encoding) for c in summary.channels.values())
        assert topics == [("/tactile_record/left", "cdr"), ("/tactile_record/right", "cdr")]
        assert summary.statistics.message_count == 24  # 12 polls x 2 devices, one message each
        assert summary.chunk_indexes and all(ci.message_index_offsets for ci in summary.chunk_indexes)
        assert [m.name for m in reader.iter_metadata()] == ["tactile_record"]
        decoded = list(reader.iter_decoded_messages())
    assert len(decoded) == 24
    _, channel, message, msg = decoded[3]  # poll 1, right
    assert channel.topic == "/tactile_record/right" and msg.header.frame_id == "right"
    assert msg.time_s == 0.0333 and list(msg.channel) == [f"right/ch{k:02d}" for k in range(4)]
    assert list(msg.resistance_ohm) == [1001.0 + 17.25, 2001.0 + 17.25, 3001.0 + 17.25, 4001.0 + 17.25]
    assert list(msg.force_n) == [0.25] * 4 and list(msg.temperature_c) == []  # no temperature column
    # log time: the start of the record plus time_s, in ns
    t0 = decoded[0][2].log_time
    assert message.log_time - t0 == 33_300_000
    assert msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec == message.log_time


def test_one_message_per_poll_whatever_slashes_the_channel_names_hold(tmp_path: Path) -> None:
    """A hand's taxels named region/taxel, regions interleaved: one device, one message a poll."""
    regions = ["thumb/tip", "palm", "index/pad"]
    rows: list[Row] = [
        (0.1 * p, f"{regions[k % 3]}/t{k:02d}", 1000.0 + k, None, None) for p in range(5) for k in range(9)
    ]
    _write(tmp_path / "h.mcap", "mcap", rows, {}, False, False)
    with open(tmp_path / "h.mcap", "rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None and summary.statistics is not None
    assert summary.statistics.message_count == 5
    assert [c.topic for c in summary.channels.values()] == ["/tactile_record"]
    assert list(read_record(tmp_path / "h.mcap").channels) == [name for _, name, *_ in rows[:9]]
    # the devices of gateway/device/channel labels (subscribe's): a topic each
    labelled: list[Row] = [(0.0, f"gw/{d}/c{k}", 5.0, None, None) for d in ("a", "b") for k in range(3)]
    _write(tmp_path / "s.mcap", "mcap", labelled, {}, False, False, levels=2)
    with open(tmp_path / "s.mcap", "rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None and summary.statistics is not None
    assert sorted(c.topic for c in summary.channels.values()) == [
        "/tactile_record/gw/a",
        "/tactile_record/gw/b",
    ]
    assert summary.statistics.message_count == 2


finite_r = st.floats(min_value=1e-3, max_value=1e12, allow_nan=False)
names = st.text(alphabet="abcxyz019_/-. ", min_size=1, max_size=12).filter(
    lambda s: s == s.strip() and not s.endswith("/")
)


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    channels=st.lists(names, min_size=1, max_size=6, unique=True),
    steps=st.lists(st.floats(min_value=0.0, max_value=100.0, allow_nan=False), min_size=1, max_size=12),
    data=st.data(),
    force=st.booleans(),
    temp=st.booleans(),
    compression=st.sampled_from(["zstd", "lz4", "none"]),
)
def test_writer_then_reader_round_trips_every_value(
    tmp_path: Path,
    channels: list[str],
    steps: list[float],
    data: st.DataObject,
    force: bool,
    temp: bool,
    compression: str,
) -> None:
    times = np.cumsum(steps).tolist()
    rows: list[Row] = []
    for t in times:
        for name in channels:
            r = data.draw(st.one_of(finite_r, st.just(math.inf)))
            f = data.draw(st.floats(min_value=0.0, max_value=1e3)) if force else None
            c = data.draw(st.floats(min_value=-40.0, max_value=150.0)) if temp else None
            rows.append((t, name, r, f, c))
    path = tmp_path / "h.mcap"
    with AtomicFile(path) as out:
        writer = McapRecordWriter(
            out, {"k": "v"}, has_force=force, has_temperature=temp, compression=compression
        )  # type: ignore[arg-type]
        for row in rows:
            writer.row(*row)
        writer.close()
        out.commit()
    record = read_record(path)
    expected: dict[str, list[tuple[float, ...]]] = {name: [] for name in channels}
    for t, name, r, f, c in rows:
        expected[name].append((t, r, *((f,) if force else ()), *((c,) if temp else ())))
    assert list(record.channels) == channels
    assert _table(record) == expected
    assert record.metadata == {"k": "v"}


def _small_mcap(tmp_path: Path) -> bytes:
    path = tmp_path / "s.mcap"
    _write(path, "mcap", _polls(5, ["a"], 3), {"source": "x"}, True, True)
    return path.read_bytes()


def _one_line_error(path: Path, **kw: int) -> str:
    with pytest.raises(RecordError) as err:
        read_record(path, **kw)  # type: ignore[arg-type]
    text = str(err.value)
    assert "\n" not in text and str(path) in text and "Traceback" not in text
    return text


def test_a_truncated_mcap_record_is_a_one_line_error(tmp_path: Path) -> None:
    whole = _small_mcap(tmp_path)
    bad = tmp_path / "cut.mcap"
    for cut in sorted({8, 9, 30, len(whole) // 3, len(whole) // 2, len(whole) - 9, len(whole) - 1}):
        bad.write_bytes(whole[:cut])
        assert "MCAP record" in _one_line_error(bad), cut


def test_wrong_magic_in_an_mcap_file_is_refused_by_name(tmp_path: Path) -> None:
    whole = _small_mcap(tmp_path)
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(b"\x89MCAP1\r\n" + whole[8:])
    assert "not an MCAP file" in _one_line_error(bad)
    # detected by its content, not its name: an MCAP record named .csv reads as MCAP
    (tmp_path / "named.csv").write_bytes(whole)
    assert read_record(tmp_path / "named.csv").channels.keys() == {"a/ch00", "a/ch01", "a/ch02"}


def test_a_huge_mcap_record_is_refused_by_the_size_limits(tmp_path: Path) -> None:
    path = tmp_path / "big.mcap"
    rows = [(float(i), f"ch{k}", 1000.0, None, None) for i in range(400) for k in range(50)]
    _write(path, "mcap", rows, {}, False, False)
    size = path.stat().st_size
    assert "larger than the limit" in _one_line_error(path, max_bytes=size - 1)
    # zstd squeezes the repeated rows: a small file whose chunks decompress past the limit
    text = _one_line_error(path, max_bytes=size + 1)
    assert "decompressed is past the limit" in text


@settings(max_examples=80, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(at=st.integers(min_value=8, max_value=10_000), value=st.integers(min_value=0, max_value=255))
def test_a_damaged_mcap_record_is_a_record_error_never_a_traceback(
    tmp_path: Path, at: int, value: int
) -> None:
    whole = bytearray(_small_mcap(tmp_path))
    at %= len(whole)
    whole[at] = value
    path = tmp_path / "damaged.mcap"
    path.write_bytes(bytes(whole))
    try:
        record = read_record(path)
    except RecordError as exc:
        assert "\n" not in str(exc)
    else:  # a byte that changes nothing the reader checks (a value, padding) still reads
        assert record.channels


def test_an_mcap_file_without_record_messages_is_refused(tmp_path: Path) -> None:
    buf = io.BytesIO()
    writer = Writer(buf)
    writer.start()
    schema = writer.register_schema("other/msg/Thing", "ros2msg", b"int32 x")
    channel = writer.register_channel("/thing", "cdr", schema)
    writer.add_message(channel, 1, b"\x00\x01\x00\x00\x05\x00\x00\x00", 1)
    writer.finish()
    path = tmp_path / "other.mcap"
    path.write_bytes(buf.getvalue())
    assert f"no messages of schema {SCHEMA_NAME}" in _one_line_error(path)


def test_mcap_records_keep_the_csv_checks(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    path = tmp_path / "r.mcap"
    _write(path, "mcap", [(1.0, "a", 5.0, None, None), (0.5, "a", 5.0, None, None)], {}, False, False)
    assert (
        "message 2 (/tactile_record): time goes backwards in channel 'a' (0.5 after 1.0"
        in _one_line_error(path)
    )
    _write(path, "mcap", [(0.0, "a", math.nan, None, None)], {}, False, False)
    assert "resistance_ohm nan must be > 0" in _one_line_error(path)
    _write(path, "mcap", [(0.0, "a", 5.0, None, None)], {}, False, False)
    with pytest.raises(RecordError, match="no force_n"):
        read_record(path, require_force=True)
    rows: list[Row] = [(0.0, f"c{k}", 5.0, None, None) for k in range(4)]
    _write(path, "mcap", rows, {}, False, False)
    monkeypatch.setattr(records_module, "MAX_RECORD_CHANNELS", 3)
    assert "channel 'c3' makes more than 3 channels" in _one_line_error(path)


def test_load_cell_zero_noise_reads_as_in_csv(tmp_path: Path) -> None:
    noisy: list[Row] = [(0.0, "a", 5.0, -0.01, None), (1.0, "a", 4.0, 10.0, None)]
    for fmt in ("csv", "mcap"):
        _write(tmp_path / f"z.{fmt}", fmt, noisy, {}, True, False)
    ch_csv, ch_mcap = (read_record(tmp_path / f"z.{fmt}").channel() for fmt in ("csv", "mcap"))
    assert ch_mcap.force_n is not None and ch_mcap.force_n.tolist() == [0.0, 10.0]
    assert ch_mcap.zero_noise_rows == ch_csv.zero_noise_rows == 1
    _write(
        tmp_path / "z.mcap",
        "mcap",
        [(0.0, "a", 5.0, -5.0, None), (1.0, "a", 4.0, 10.0, None)],
        {},
        True,
        False,
    )
    assert "message 1: force_n: -5.0 is below 0 N" in _one_line_error(tmp_path / "z.mcap")


def test_a_named_pipe_is_refused_without_waiting(tmp_path: Path) -> None:
    fifo = tmp_path / "pipe.mcap"
    os.mkfifo(fifo)
    result: list[str] = []

    def read() -> None:
        try:
            read_record(fifo)
        except RecordError as exc:
            result.append(str(exc))

    thread = threading.Thread(target=read)
    thread.start()
    thread.join(timeout=30.0)
    if thread.is_alive():  # unblock the reader so that the test does not leak a thread
        with open(fifo, "wb"):
            pass
        thread.join()
        pytest.fail("read_record waited on a named pipe")
    assert result and "not a regular file" in result[0]


def test_an_mcap_record_counts_as_a_record_that_out_may_replace(tmp_path: Path) -> None:
    path = tmp_path / "old.mcap"
    path.write_bytes(_small_mcap(tmp_path))
    assert is_record_file(path)
    record_path_ok(path, replace_record=True)  # no error: an earlier record is replaced
    other = tmp_path / "other.mcap"
    buf = io.BytesIO()
    writer = Writer(buf)
    writer.start(library="someone else")
    writer.finish()
    other.write_bytes(buf.getvalue())
    assert not is_record_file(other)
    with pytest.raises(ValueError, match="not a record"):
        record_path_ok(other, replace_record=True)
    assert struct.pack("<8B", 137, 77, 67, 65, 80, 48, 13, 10) == MCAP_MAGIC


def test_a_live_record_of_two_devices_has_a_topic_per_device(tmp_path: Path) -> None:
    """The live recorder labels device/channel; the MCAP form puts each device on its topic and
    reads back as the CSV form of the same snapshots."""

    def device(name: str, unit: int) -> DeviceConfig:
        channels = tuple(
            ChannelConfig(k, f"ch{k:02d}", 2.5 * k, 0.0, True, PAPER_EFFECTS, SensorParams(), None, None)
            for k in range(3)
        )
        return DeviceConfig(
            name,
            unit,
            "float32",
            3,
            RegisterMap(),
            Divider(),
            channels,
            False,
            GridLayout(3, 3, 2.5, 2.5),
            None,
        )

    devices = [device("left", 1), device("right", 2)]
    config = gateway_config_for([bus_config_for("b", "tcp", devices, host="127.0.0.1", port=5020)])
    procs = [DeviceProcessor(d, "b", 0.1) for d in devices]
    states = [p.initial_state() for p in procs]
    paths = [tmp_path / "two.csv", tmp_path / "two.mcap"]
    files = [AtomicFile(p) for p in paths]
    recorders = [
        LiveRecorder(files[0].text, config),
        LiveRecorder(files[1], config, record_format="mcap"),
    ]
    for poll in range(4):
        snaps = {}
        for d, proc in enumerate(procs):
            r = np.array([2e4 + 100.0 * poll + 10.0 * d, 3e4, 4e4 + poll])
            sample = RawSample(resistance_ohm=r, device_time_s=5.0 + 0.5 * poll)
            snap, states[d] = proc.process(states[d], sample, 1e9 + poll, 0.0)
            snaps[devices[d].name] = snap
        for recorder in recorders:
            recorder(GatewaySnapshot.build(snaps, {}, poll + 1))
    for recorder, out in zip(recorders, files, strict=True):
        recorder.close()
        out.commit()
    csv_rec, mcap_rec = (read_record(p) for p in paths)
    assert _table(mcap_rec) == _table(csv_rec)
    assert list(mcap_rec.channels) == [f"{d}/ch{k:02d}" for d in ("left", "right") for k in range(3)]
    assert _table(mcap_rec)["right/ch00"][2] == (1.0, 2e4 + 200.0 + 10.0)  # hand-computed: poll 2, right
    with open(paths[1], "rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None and summary.statistics is not None
    assert sorted(c.topic for c in summary.channels.values()) == [
        "/tactile_record/left",
        "/tactile_record/right",
    ]
    assert summary.statistics.message_count == 8  # 4 polls x 2 devices
