"""Records of the same simulated polls, CSV and MCAP, read back row for row to the same
values (issue 34 §6); and ``tactile-gateway record --format mcap`` through Modbus TCP writes
a file the ``mcap`` reader and the ROS 2 decoder open."""

from __future__ import annotations

import asyncio
import io
import sys
from pathlib import Path

import numpy as np
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from waiting import until

from gateway.analysis.recorder import LiveRecorder
from gateway.analysis.records import read_record
from gateway.atomic import AtomicFile
from gateway.config import load_config
from gateway.runtime.poller import Poller, SnapshotHolder
from sim_device import ArrayConfig, SimArray, serve_tcp

BIN = Path(sys.executable).parent
POLLS = 40


def _config(tmp_path: Path, port: int) -> Path:
    path = tmp_path / "gateway.toml"
    path.write_text(
        f'[[bus]]\nname = "sim"\nkind = "tcp"\nhost = "127.0.0.1"\nport = {port}\npoll_interval_s = 0.01\n\n'
        '[[bus.device]]\nname = "arr"\ndevice_id = 1\nprofile = "tactile-sim"\nchannels = 8\ncolumns = 4\n'
        "[bus.device.registers]\nforce_reference_address = 1000\ntemperature_address = 1600\n"
    )
    return path


async def test_csv_and_mcap_records_of_the_same_polls_read_back_row_for_row(tmp_path: Path) -> None:
    array = SimArray(ArrayConfig(channels=8, columns=4, scenario="indentation", speed=20.0, seed=5))
    csv_path, mcap_path = tmp_path / "same.csv", tmp_path / "same.mcap"
    async with serve_tcp([array], host="127.0.0.1", port=0) as server:
        config = load_config(_config(tmp_path, server.port))
        meta = {"source": "test", "config": "gateway.toml"}
        with AtomicFile(csv_path) as csv_out, AtomicFile(mcap_path) as mcap_out:
            as_csv = LiveRecorder(csv_out.text, config, metadata=meta)
            as_mcap = LiveRecorder(mcap_out, config, metadata=meta, record_format="mcap")
            holder = SnapshotHolder()
            holder.subscribe(as_csv)
            holder.subscribe(as_mcap)
            async with Poller(config, holder):
                await until(lambda: as_mcap.stats.polls >= POLLS, 60.0, "the gateway polls the array")
            for recorder, out in ((as_csv, csv_out), (as_mcap, mcap_out)):
                recorder.close()
                out.commit()
    assert as_csv.stats == as_mcap.stats
    csv_rec, mcap_rec = read_record(csv_path), read_record(mcap_path)
    assert list(mcap_rec.channels) == list(csv_rec.channels) == [f"ch{k:02d}" for k in range(8)]
    assert mcap_rec.metadata == csv_rec.metadata == meta
    for name, ch in csv_rec.channels.items():
        other = mcap_rec.channels[name]
        assert ch.n_samples >= POLLS and other.n_samples == ch.n_samples, name
        for column in ("time_s", "resistance_ohm", "force_n", "temperature_c"):
            a, b = getattr(ch, column), getattr(other, column)
            assert a is not None and b is not None and a.tolist() == b.tolist(), (name, column)
    ch = mcap_rec.channel("ch00")
    assert ch.force_n is not None and np.all(ch.force_n >= 0.0) and np.all(np.diff(ch.time_s) > 0.0)
    summary = make_reader(io.BytesIO(mcap_path.read_bytes())).get_summary()
    assert summary is not None and summary.statistics is not None
    assert summary.statistics.message_count == as_mcap.stats.polls  # one message per poll


async def test_record_format_mcap_through_modbus(tmp_path: Path) -> None:
    array = SimArray(ArrayConfig(channels=8, columns=4, scenario="indentation", speed=20.0, seed=9))
    out = tmp_path / "run.bin"  # the format from --format, not the name
    async with serve_tcp([array], host="127.0.0.1", port=0) as server:
        config = _config(tmp_path, server.port)
        cmd = [str(BIN / "tactile-gateway"), "record", "-c", str(config), "--duration", "1.5"]
        cmd += ["--out", str(out), "--format", "mcap"]
        proc = await asyncio.create_subprocess_exec(
            *cmd, stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.PIPE
        )
        try:
            stdout, stderr = await asyncio.wait_for(proc.communicate(), 60.0)
        except TimeoutError:
            proc.kill()
            await proc.wait()
            raise
    assert proc.returncode == 0, stderr.decode()
    assert f"to {out}" in stdout.decode() and "Traceback" not in stderr.decode()
    record = read_record(out)
    assert list(record.channels) == [f"ch{k:02d}" for k in range(8)]
    assert record.metadata["source"] == "tactile-gateway record" and record.metadata["config"] == str(config)
    polls = record.channel("ch00").n_samples
    reader = make_reader(io.BytesIO(out.read_bytes()), decoder_factories=[DecoderFactory()])
    decoded = [(c.topic, m) for _, c, _, m in reader.iter_decoded_messages()]
    assert len(decoded) == polls >= 3
    assert {topic for topic, _ in decoded} == {"/tactile_record"}
    times = [m.time_s for _, m in decoded]
    assert times == record.channel("ch00").time_s.tolist()
    assert [list(m.resistance_ohm)[1] for _, m in decoded] == record.channel("ch01").resistance_ohm.tolist()
