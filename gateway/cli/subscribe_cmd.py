"""``tactile-gateway subscribe``: print or record the frames a gateway publishes to MQTT.

Thin: ``gateway.mqtt.subscriber`` has the protocol (topics, decoding, gaps, the client);
this module parses the options, prints, and wires the record writer of
``gateway.analysis.records`` (``docs/record-format.md``).

With ``--out`` the record is written to a temporary file beside the target while frames
arrive and renamed over it at the end (also after Ctrl-C), so the target is never half a
record. Columns: ``time_s`` (the device clock when the frame has one, else the host's,
from each stream's first frame), ``channel`` and ``resistance_ohm``. Frames carry no
reference force and no temperature, so the record has no ``force_n`` / ``temperature_c``:
the gateway's force estimate is not a reference (``force_n`` in the format is the force a
reference applied).
"""

from __future__ import annotations

import datetime
import json
import math
import signal
import sys
import time
from pathlib import Path
from types import FrameType

import click

from ..analysis.recorder import record_path_ok
from ..analysis.records import channel_name_problem, open_record_writer, record_format_for
from ..atomic import AtomicFile
from ..errors import ConfigError
from ..mqtt.subscribe_settings import SESSION_EXPIRY_S
from ..mqtt.subscriber import (
    PENDING_BYTES_LIMIT,
    Frame,
    FrameStream,
    SubscribeError,
    SubscribeSettings,
    frame_clock_s,
    in_contact,
    parse_broker,
    read_password_file,
    recordable,
    run_subscriber,
)
from .common import finite_seconds

_NAMES_SHOWN = 8


def _line(frame: Frame) -> str:
    f = frame.fields
    names = in_contact(f)
    shown = " ".join(names[:_NAMES_SHOWN]) + (
        f" +{len(names) - _NAMES_SHOWN}" if len(names) > _NAMES_SHOWN else ""
    )
    total = float(f.get("total_force_n") or 0.0)
    state = "" if f.get("up", True) else "  DOWN"
    return (
        f"{frame.gateway}/{frame.device}  seq {frame.sequence}  total {total:9.4f} N  "
        f"contact {len(names)}/{len(f['channels'])}{': ' + shown if shown else ''}{state}"
    )


class _Recorder:
    """Frames to record rows, streamed into a temporary file renamed at ``close``."""

    def __init__(self, path: Path, label_gateway: bool, label_device: bool, meta: dict[str, str]) -> None:
        self.path = path
        self.file = AtomicFile(path)
        self.label_gateway, self.label_device = label_gateway, label_device
        # x.mcap: MCAP, a topic per gateway/device the labels name
        levels = int(label_gateway) + int(label_device)
        self.writer = open_record_writer(self.file, record_format_for(path), meta, device_levels=levels)
        self.t0: dict[tuple[str, str], float] = {}
        self.last: dict[tuple[str, str], float] = {}
        self.rows = 0
        self.skipped_rows = 0
        self.backwards = 0
        self.unwritable = 0  # frames refused: a channel label a record cannot hold
        self.notices: list[str] = []

    def label(self, frame: Frame, channel: str) -> str:
        parts = [frame.gateway] if self.label_gateway else []
        parts += [frame.device] if self.label_device else []
        return "/".join([*parts, channel])

    def add(self, frame: Frame) -> None:
        rows, skipped = recordable(frame.fields)
        self.skipped_rows += skipped
        if not rows:
            return
        labels = [self.label(frame, channel) for channel, _ in rows]
        problem = _labels_problem(labels)
        if problem is not None:
            # the whole frame, not some of its channels: the record holds whole frames only
            self.unwritable += 1
            self.skipped_rows += len(rows)
            if self.unwritable == 1:
                self.notices.append(
                    f"{(frame.gateway + '/' + frame.device)[:80]!r}: frame {frame.sequence} not recorded: "
                    f"{problem} (further such frames are counted)"
                )
            return
        clock = frame_clock_s(frame.fields)
        t0 = self.t0.setdefault(frame.key, clock)
        t = round(clock - t0, 6)  # microseconds: the device clock counts milliseconds
        if t < self.last.get(frame.key, -math.inf):
            self.backwards += 1  # the record's time may not go backwards within a channel
            self.skipped_rows += len(rows)
            return
        self.last[frame.key] = t
        for label, (_, r) in zip(labels, rows, strict=True):
            self.writer.row(t, label, r)
        self.rows += len(rows)
        self.writer.flush()

    def close(self, keep: bool) -> None:
        """Put the record in place (``keep``) or leave the target as it was."""
        if keep:
            self.writer.close()
            self.file.commit()
        else:
            self.file.discard()


def _labels_problem(labels: list[str]) -> str | None:
    """Why a frame's channel labels cannot be record rows that read back as received, or None."""
    for label in labels:
        problem = channel_name_problem(label)
        if problem is not None:
            return f"the channel {label[:80]!r} ({problem})"
    if len(set(labels)) != len(labels):
        return "two channels of one name"
    return None


def _fail(message: str) -> None:
    click.echo(f"tactile-gateway subscribe: {message}", err=True)
    sys.exit(1)


@click.command("subscribe")
@click.option(
    "--broker", required=True, metavar="HOST[:PORT]", help="the MQTT broker (port 1883, 8883 with TLS)"
)
@click.option("--tls-ca", type=click.Path(path_type=Path, dir_okay=False), help="CA certificate: use TLS")
@click.option("--username", default=None, help="user name at the broker")
@click.option(
    "--password-file",
    type=click.Path(path_type=Path, dir_okay=False),
    help="file with the password (mode 0600)",
)
@click.option("--prefix", default="tactile", show_default=True, help="the gateways' topic_prefix")
@click.option("--gateway", default="+", show_default=True, help="one gateway's topic level, or + for all")
@click.option("--device", default="+", show_default=True, help="one device name, or + for all")
@click.option(
    "--share",
    "share_group",
    default=None,
    help="receive frames through $share/GROUP/... (consumers split them)",
)
@click.option(
    "--out",
    "out_path",
    type=click.Path(path_type=Path, dir_okay=False),
    help="record to write (CSV; MCAP when it ends in .mcap)",
)
@click.option("--count", type=click.IntRange(min=1), default=None, help="stop after this many frames")
@click.option(
    "--duration",
    "duration_s",
    type=click.FloatRange(min=0.0, min_open=True),
    callback=finite_seconds,
    help="stop after seconds",
)
@click.option(
    "--client-id",
    "client_id",
    default="",
    help="the MQTT client id of the persistent session (default: one fixed per host and topic filters)",
)
@click.option(
    "--session-expiry",
    "session_expiry_s",
    type=click.IntRange(0, 4294967295),
    default=SESSION_EXPIRY_S,
    show_default=True,
    help="seconds the broker keeps the session (and queues frames) of a lost subscriber",
)
@click.option("--json", "as_json", is_flag=True, help="print each frame as one JSON object per line")
@click.option("--quiet", "-q", is_flag=True, help="print no frames (with --out)")
def subscribe(
    broker: str,
    tls_ca: Path | None,
    username: str | None,
    password_file: Path | None,
    prefix: str,
    gateway: str,
    device: str,
    share_group: str | None,
    out_path: Path | None,
    count: int | None,
    duration_s: float | None,
    client_id: str,
    session_expiry_s: int,
    as_json: bool,
    quiet: bool,
) -> None:
    """Print or record the frames gateways publish to an MQTT broker; report gaps in their sequence."""
    try:
        host, port = parse_broker(broker, tls_ca is not None)
        if password_file is not None and username is None:
            raise ConfigError("--password-file needs --username")
        password = read_password_file(password_file) if password_file is not None else None
        if tls_ca is not None and not tls_ca.is_file():
            raise ConfigError(f"--tls-ca: {tls_ca} does not exist or is not a file")
        settings = SubscribeSettings(
            host,
            port,
            tls_ca,
            username,
            password,
            prefix,
            gateway,
            device,
            share_group,
            client_id=client_id,
            session_expiry_s=session_expiry_s,
        )
        if out_path is not None:
            record_path_ok(out_path)
    except (ConfigError, ValueError) as exc:
        _fail(str(exc))
        return
    stream = FrameStream(prefix, pending_bytes_limit=PENDING_BYTES_LIMIT)
    recorder = None
    if out_path is not None:
        meta = {
            "source": "tactile-gateway subscribe",
            "broker": settings.where(),
            "topics": ", ".join(settings.topics()),
            "started": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
            "time": "device clock where the frame has one, else host clock",
        }
        try:
            recorder = _Recorder(out_path, gateway == "+", device == "+", meta)
        except OSError as exc:
            _fail(f"--out: cannot write beside {out_path}: {exc.strerror or exc}")
            return
    interrupted = False

    def stop_signal(signum: int, frame: FrameType | None) -> None:
        nonlocal interrupted
        interrupted = True

    def emit(frame: Frame) -> None:
        if frame.restarted:
            click.echo(
                f"{frame.gateway}/{frame.device}: sequence restarted at 1 (the publisher restarted)", err=True
            )
        if frame.missing_before:
            click.echo(
                f"{frame.gateway}/{frame.device}: gap: {frame.missing_before} frame(s) missing before "
                f"sequence {frame.sequence}",
                err=True,
            )
        if as_json:
            click.echo(json.dumps(frame.as_json(), separators=(",", ":")))
        elif not quiet:
            click.echo(_line(frame))
        if recorder is not None:
            recorder.add(frame)
            for note in recorder.notices:
                click.echo(note, err=True)
            recorder.notices.clear()

    delivered = 0

    def on_message(topic: str, payload: bytes) -> None:
        nonlocal delivered
        frames, notices = stream.feed(topic, payload)
        for note in notices:
            click.echo(note, err=True)
        for frame in frames:
            if count is not None and delivered >= count:
                return
            emit(frame)
            delivered += 1

    deadline = None if duration_s is None else time.monotonic() + duration_s

    def should_stop() -> bool:
        return (
            interrupted
            or (count is not None and delivered >= count)
            or (deadline is not None and time.monotonic() >= deadline)
        )

    old = {sig: signal.signal(sig, stop_signal) for sig in (signal.SIGINT, signal.SIGTERM)}
    error = None
    try:
        run_subscriber(settings, on_message, should_stop, lambda m: click.echo(m, err=True))
    except SubscribeError as exc:
        error = str(exc)
    except BaseException:
        # not expected (a bad message is a counted, reported frame): the frames received so
        # far are still the record, written whole, and no temporary file is left behind
        if recorder is not None:
            recorder.close(keep=stream.stats.frames > 0)
        raise
    finally:
        for sig, handler in old.items():
            signal.signal(sig, handler)
    if error is None:
        frames, notices = stream.flush()
        for note in notices:
            click.echo(note, err=True)
        for frame in frames:
            if count is None or delivered < count:
                emit(frame)
                delivered += 1
    if recorder is not None:
        recorder.close(keep=error is None or stream.stats.frames > 0)
    seq = stream.sequences
    summary = (
        f"{delivered} frame(s) from {len(stream.stats.devices)} device(s); {seq.missing} missing "
        f"in {seq.gaps} gap(s)"
    )
    extras = [
        f"{n} {what}"
        for n, what in (
            (seq.duplicates, "duplicate(s) dropped"),
            (seq.restarts, "restart(s)"),
            (stream.stats.undecodable, "undecodable message(s)"),
            (stream.stats.pending_dropped, "frame(s) dropped while waiting for a meta message"),
        )
        if n
    ]
    if recorder is not None:
        extras.append(f"{recorder.rows} rows to {out_path}")
        if recorder.skipped_rows:
            extras.append(f"{recorder.skipped_rows} channel samples without a resistance")
        if recorder.unwritable:
            extras.append(
                f"{recorder.unwritable} frame(s) not recorded (a channel name a record cannot hold: "
                "a comma, quote, line break, control character, white space at an end, or twice in a frame)"
            )
        if recorder.backwards:
            extras.append(f"{recorder.backwards} frame(s) not recorded (time went backwards)")
    if error is None or delivered:
        click.echo(summary + ("; " + "; ".join(extras) if extras else ""), err=True)
    if error is not None:
        _fail(error)
