"""Docs that run: every command and configuration block of README.md and docs/*.md, as printed.

Each fenced block is classified by its language:

- ``sh``, ``bash``, ``console``: commands. ``$ `` prompts are stripped (in a ``console`` block
  only the prompted lines are commands, the rest is output); comment lines and trailing
  ``# ...`` comments are dropped. Every command must exit 0 without a traceback.
- ``toml``: configurations. A block with a ``[[bus]]`` table is a complete gateway
  configuration and is checked with ``tactile-gateway check-config``.
- anything else (output, JSON, YAML, Python, diagrams) is not run.

A doc says what the test cannot see with an HTML comment on the line before the block:

- ``<!-- docs-test: skip (reason) -->``: not run (e.g. it needs real hardware); the reason is
  required.
- ``<!-- docs-test: fragment of WHAT (reason) -->``: a TOML block that is part of a file, not
  a file; WHAT is required.
- ``<!-- docs-test: file NAME -->``: a TOML block saved as NAME in the doc's working directory
  before its commands run (the commands use it by that name; the doc must name it in one).

The blocks of one doc run in order in one temporary directory holding a copy of examples/ and
a link to tests/ (the data the docs name), so ``-c examples/gateway.toml`` or
``tests/data/real/...`` work as printed and edits (``channels set``, ``tare``) touch only
copies. Long-running commands run in the background until they are up, then get SIGINT and
must exit 0: ``tactile-sim run`` is up when its port accepts a connection and stays up as the
doc's device until the doc's next ``tactile-sim run`` or its end; ``tactile-gateway run`` and
``demo`` are up when their /metrics says ``tactile_device_up ... 1``; ``tactile-gateway view``
when the page address it prints serves ``/api/playback``.

A new shell does not have the virtualenv on its PATH: a doc's commands run with the test's
virtualenv taken off PATH until the doc activates it (``. .venv/bin/activate``, which the test
checks exists and then does by putting the virtualenv's bin/ first on PATH), so a doc that
prints ``tactile-gateway`` or ``tactile-sim`` before saying how to activate fails as a user's
shell would ("command not found"). ``make demo`` needs no activation: make runs the virtualenv's
program.

What a user types is changed only by ``SUBSTITUTIONS`` and ``CONFIG_SUBSTITUTIONS`` below:
fixed ports become ephemeral loopback ports, /tmp becomes the test's directory, a 1-minute
record becomes 12 s.
"""

from __future__ import annotations

import contextlib
import os
import re
import shlex
import shutil
import signal
import socket
import subprocess
import sys
import time
import tomllib
import urllib.request
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
DOCS = [REPO / "README.md", *sorted((REPO / "docs").glob("*.md"))]
BIN = Path(sys.executable).parent
PROGRAMS = ("tactile-gateway", "tactile-sim")
COMMAND_LANGS = ("sh", "bash", "console")
#: The activation step a doc prints before its first ``tactile-gateway`` or ``tactile-sim``.
ACTIVATE = re.compile(r"^(?:\.|source) \.venv/bin/activate$")
#: How long one command or one start-up may take on a busy 2-core machine (s).
COMMAND_TIMEOUT_S = 180.0
UP_TIMEOUT_S = 60.0


@dataclass
class Ports:
    device: int
    metrics: int
    tmp: Path


#: (pattern, replacement, why) applied to each command line, in order. The replacement may
#: use {device}, {metrics} (free loopback ports) and {tmp} (the doc's working directory).
SUBSTITUTIONS: list[tuple[str, str, str]] = [
    (r"^make demo$", "{bin}/tactile-gateway demo", "the Makefile target runs this after building .venv"),
    (r"^make test$", "", "make test runs this test: not again from inside it"),
    (r"^((?:\S*/)?tactile-gateway demo)\b", r"\1 --port {metrics}", "the demo's page and metrics port, 9830"),
    (r"127\.0\.0\.1:50(20|21)\b", "127.0.0.1:{device}", "the simulator's ports"),
    (r"--port 50(20|21)\b", "--port {device}", "the simulator's ports"),
    (r"--host 192\.0\.2\.7\b", "--host 127.0.0.1 --port {device}", "a documentation address: the simulator"),
    (r"^(tactile-gateway record .*)--duration 60\b", r"\1--duration 12", "a 1-minute record: 12 s"),
    (r"(?<![\w.])/tmp/", "{tmp}/", "files in /tmp: the test's own directory"),
]
#: (pattern, replacement, why) applied to the configuration files a doc's commands read (the
#: copy of examples/ and the blocks saved with ``docs-test: file``).
CONFIG_SUBSTITUTIONS: list[tuple[str, str, str]] = [
    (r"^port = 50(20|21)\b", "port = {device}", "the simulator's ports"),
    (r'"127\.0\.0\.1:9830"', '"127.0.0.1:{metrics}"', "the metrics port"),
    (r"^port = 8765\b", "port = 0", "Foxglove's port ([foxglove]): any free one"),
]
#: A configuration without a [metrics] table serves on 127.0.0.1:9830: it gets this one first.
METRICS_TABLE = '[metrics]\naddress = "127.0.0.1:{metrics}"\n\n'

MARKER = re.compile(r"^<!--\s*docs-test:\s*(?P<kind>\S+)(?P<rest>.*?)-->\s*$")
FENCE = re.compile(r"^```(?P<lang>[\w-]*)\s*$")


@dataclass
class Block:
    doc: str
    line: int
    lang: str
    text: str
    marker: str | None = None
    marker_rest: str = ""

    @property
    def where(self) -> str:
        return f"{self.doc}:{self.line}"

    @property
    def reason(self) -> str:
        return self.marker_rest.strip().strip("()").strip()


def parse_blocks(path: Path) -> list[Block]:
    doc = str(path.relative_to(REPO))
    lines = path.read_text(encoding="utf-8").splitlines()
    blocks: list[Block] = []
    i = 0
    while i < len(lines):
        m = FENCE.match(lines[i])
        if not m:
            i += 1
            continue
        end = i + 1
        while end < len(lines) and not lines[end].startswith("```"):
            end += 1
        block = Block(doc, i + 1, m["lang"], "\n".join(lines[i + 1 : end]))
        before = next((lines[k].strip() for k in range(i - 1, -1, -1) if lines[k].strip()), "")
        marker = MARKER.match(before)
        if marker:
            block.marker, block.marker_rest = marker["kind"], marker["rest"]
        blocks.append(block)
        i = end + 1
    return blocks


ALL_BLOCKS = {str(p.relative_to(REPO)): parse_blocks(p) for p in DOCS}


def commands(block: Block) -> list[str]:
    """The command lines of a command block, as printed (prompts and comments dropped)."""
    out: list[str] = []
    pending = ""
    for raw in block.text.splitlines():
        line = raw.rstrip()
        if block.lang == "console":
            if not line.startswith("$ ") and not pending:
                continue
            line = line.removeprefix("$ ")
        if not pending and (not line.strip() or line.lstrip().startswith("#")):
            continue
        if line.endswith("\\"):
            pending += line[:-1] + " "
            continue
        out.append((pending + line).strip())
        pending = ""
    return out


def substitute(line: str, table: list[tuple[str, str, str]], ports: Ports) -> str:
    values = {
        "device": str(ports.device),
        "metrics": str(ports.metrics),
        "tmp": str(ports.tmp),
        "bin": str(BIN),
    }
    for pattern, replacement, _why in table:
        filled = re.sub(r"\{(\w+)\}", lambda m: values[m[1]], replacement)
        line = re.sub(pattern, filled, line, flags=re.MULTILINE)
    return line


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def wait_until(
    what: str, proc: subprocess.Popen[bytes], log: Callable[[], str], ok: Callable[[], bool]
) -> None:
    deadline = time.monotonic() + UP_TIMEOUT_S
    while not ok():
        if proc.poll() is not None:
            pytest.fail(f"{what} exited with {proc.returncode} before it was up:\n{log()}", pytrace=False)
        if time.monotonic() > deadline:
            pytest.fail(f"{what} was not up after {UP_TIMEOUT_S:.0f} s:\n{log()}", pytrace=False)
        # wait on the process itself between looks: an exit ends the wait at once
        with contextlib.suppress(subprocess.TimeoutExpired):
            proc.wait(timeout=0.1)


def port_open(port: int) -> bool:
    try:
        with socket.create_connection(("127.0.0.1", port), timeout=1.0):
            return True
    except OSError:
        return False


def device_up(port: int) -> bool:
    try:
        with urllib.request.urlopen(f"http://127.0.0.1:{port}/metrics", timeout=2.0) as resp:
            text = resp.read().decode()
    except OSError:
        return False
    return re.search(r"^tactile_device_up\{[^}]*\} 1(\.0)?$", text, re.MULTILINE) is not None


def view_up(log: str) -> bool:
    """``tactile-gateway view`` is up when the page it printed serves the record's frames."""
    m = re.search(r"page on (https?://\S+/) ", log)
    if m is None:
        return False
    try:
        with urllib.request.urlopen(m[1] + "api/playback", timeout=2.0) as resp:
            return resp.status == 200
    except OSError:
        return False


@dataclass
class Session:
    """One doc's working directory, ports and background processes."""

    ports: Ports
    env: dict[str, str]
    device: subprocess.Popen[bytes] | None = None
    activated: bool = False
    logs: dict[int, Path] = field(default_factory=dict)

    @property
    def cwd(self) -> Path:
        return self.ports.tmp

    def log(self, proc: subprocess.Popen[bytes]) -> str:
        return self.logs[proc.pid].read_text(errors="replace")[-4000:]

    def start(self, argv: list[str]) -> subprocess.Popen[bytes]:
        out = self.cwd / f".log-{len(self.logs)}"
        with out.open("wb") as f:
            proc = subprocess.Popen(argv, cwd=self.cwd, env=self.env, stdout=f, stderr=subprocess.STDOUT)
        self.logs[proc.pid] = out
        return proc

    def stop(self, proc: subprocess.Popen[bytes], what: str) -> None:
        if proc.poll() is None:
            proc.send_signal(signal.SIGINT)
        try:
            rc = proc.wait(timeout=COMMAND_TIMEOUT_S)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
            pytest.fail(f"{what} did not stop on SIGINT:\n{self.log(proc)}", pytrace=False)
        text = self.log(proc)
        assert rc == 0 and "Traceback" not in text, f"{what} exited {rc} on SIGINT:\n{text}"

    def kill_all(self) -> None:
        if self.device is not None and self.device.poll() is None:
            self.device.kill()
            self.device.wait()


def path_without_venv() -> str:
    """PATH as a new shell has it: without the test's virtualenv (pytest may run inside it)."""
    return os.pathsep.join(
        d for d in os.environ.get("PATH", "").split(os.pathsep) if d and Path(d).resolve() != BIN.resolve()
    )


def activate(session: Session, where: str) -> None:
    """``. .venv/bin/activate``: the script must exist where the doc's commands run."""
    script = session.cwd / ".venv" / "bin" / "activate"
    assert script.is_file(), f"{where}\n  {script} does not exist"
    session.env["PATH"] = f"{BIN}{os.pathsep}{session.env['PATH']}"
    session.activated = True


@pytest.fixture
def session(tmp_path: Path) -> Iterator[Session]:
    ports = Ports(device=free_port(), metrics=free_port(), tmp=tmp_path)
    env = {**os.environ, "PATH": path_without_venv(), "NO_COLOR": "1"}
    examples = tmp_path / "examples"
    examples.mkdir()
    for src in (REPO / "examples").iterdir():
        if src.is_file():
            (examples / src.name).write_text(substitute(src.read_text(), CONFIG_SUBSTITUTIONS, ports))
    (tmp_path / "tests").symlink_to(REPO / "tests")
    (tmp_path / ".venv").symlink_to(BIN.parent, target_is_directory=True)
    s = Session(ports, env)
    try:
        yield s
    finally:
        s.kill_all()


def save_file(session: Session, block: Block) -> Path:
    name = block.reason
    assert name and not Path(name).is_absolute() and ".." not in name, (
        f"{block.where}: bad file name {name!r}"
    )
    text = substitute(block.text + "\n", CONFIG_SUBSTITUTIONS, session.ports)
    if "[[bus]]" in text and "[metrics]" not in text:
        text = METRICS_TABLE.format(metrics=session.ports.metrics) + text
    target = session.cwd / name
    target.parent.mkdir(parents=True, exist_ok=True)
    target.write_text(text)
    return target


def run_command(session: Session, block: Block, printed: str) -> None:
    # the command without its trailing comment, then the substitutions
    line = substitute(shlex.join(shlex.split(printed, comments=True)), SUBSTITUTIONS, session.ports)
    if not line:
        return
    if ACTIVATE.match(line):
        activate(session, f"{block.where}: {printed}")
        return
    argv = shlex.split(line, comments=True)
    where = f"{block.where}: {printed}\n  ran: {shlex.join(argv)}"
    assert Path(argv[0]).name in PROGRAMS, (
        f"{where}\n  {argv[0]!r} is not one of {PROGRAMS}: mark the block skip"
    )
    found = argv[0] if Path(argv[0]).is_absolute() else shutil.which(argv[0], path=session.env["PATH"])
    assert found is not None, (
        f"{where}\n  {argv[0]}: command not found (a new shell has no virtualenv on PATH): "
        "say `. .venv/bin/activate` before the doc's first command"
    )
    argv[0] = found
    sub = argv[1] if len(argv) > 1 else ""
    if Path(argv[0]).name == "tactile-sim" and sub == "run":
        if session.device is not None:
            session.stop(session.device, "the previous tactile-sim run")
        if "--tcp" not in argv and not any(a in argv for a in ("--rtu", "--rtu-tcp", "--tls")):
            argv += ["--tcp", f"127.0.0.1:{session.ports.device}"]
        proc = session.device = session.start(argv)
        wait_until(where, proc, lambda: session.log(proc), lambda: port_open(session.ports.device))
        return
    if Path(argv[0]).name == "tactile-gateway" and sub == "view":
        proc = session.start(argv)
        try:
            wait_until(where, proc, lambda: session.log(proc), lambda: view_up(session.log(proc)))
        finally:
            session.stop(proc, where)
        return
    if Path(argv[0]).name == "tactile-gateway" and sub in ("run", "demo"):
        proc = session.start(argv)
        try:
            wait_until(where, proc, lambda: session.log(proc), lambda: device_up(session.ports.metrics))
        finally:
            session.stop(proc, where)
        return
    try:
        result = subprocess.run(
            argv,
            cwd=session.cwd,
            env=session.env,
            capture_output=True,
            timeout=COMMAND_TIMEOUT_S,
            check=False,
        )
    except subprocess.TimeoutExpired:
        pytest.fail(f"{where}\n  took longer than {COMMAND_TIMEOUT_S:.0f} s", pytrace=False)
    output = (result.stdout + result.stderr).decode(errors="replace")
    assert result.returncode == 0, f"{where}\n  exit {result.returncode}:\n{output[-4000:]}"
    assert "Traceback" not in output, f"{where}\n  printed a traceback:\n{output[-4000:]}"


def check_config(session: Session, block: Block, path: Path) -> None:
    """The test's own check of a configuration block: not a printed command, so no activation."""
    run_command(
        session,
        block,
        f"{BIN / 'tactile-gateway'} check-config -c {shlex.quote(str(path.relative_to(session.cwd)))}",
    )


def is_gateway_config(text: str) -> bool:
    try:
        return "bus" in tomllib.loads(text)
    except tomllib.TOMLDecodeError:
        return False


def problems(block: Block) -> list[str]:
    """What is wrong with a block's classification, before anything runs."""
    out: list[str] = []
    if block.marker == "skip" and not block.reason:
        out.append(f"{block.where}: a skip needs a reason: <!-- docs-test: skip (why) -->")
    elif block.marker == "fragment" and not block.reason.removeprefix("of").strip():
        out.append(f"{block.where}: say what it is a fragment of: <!-- docs-test: fragment of ... -->")
    elif block.marker == "file" and not block.reason:
        out.append(f"{block.where}: name the file: <!-- docs-test: file NAME -->")
    elif block.marker not in (None, "skip", "fragment", "file"):
        out.append(f"{block.where}: unknown docs-test marker {block.marker!r}")
    if block.marker in ("fragment", "file") and block.lang != "toml":
        out.append(f"{block.where}: {block.marker} applies to toml blocks, not {block.lang or 'plain'} ones")
    if block.lang == "toml" and block.marker is None and not is_gateway_config(block.text):
        out.append(
            f"{block.where}: a TOML block without [[bus]] is not a gateway configuration: "
            "mark it <!-- docs-test: fragment of ... (why) --> or <!-- docs-test: file NAME -->"
        )
    if block.lang in COMMAND_LANGS and block.marker is None and not commands(block):
        out.append(f"{block.where}: a command block without a command")
    return out


def first_unactivated_program(blocks: list[Block]) -> str | None:
    """Where a doc runs one of PROGRAMS before printing the activation step, or None."""
    for block in blocks:
        if block.marker in ("skip", "fragment") or block.lang not in COMMAND_LANGS:
            continue
        for line in commands(block):
            printed = shlex.join(shlex.split(line, comments=True))
            if ACTIVATE.match(printed):
                return None
            if printed.split(" ", 1)[0] in PROGRAMS:
                return f"{block.where}: {line}"
    return None


def test_every_doc_says_how_to_activate_the_virtualenv_before_its_first_program() -> None:
    late = [w for blocks in ALL_BLOCKS.values() if (w := first_unactivated_program(blocks)) is not None]
    assert not late, "printed before `. .venv/bin/activate`:\n" + "\n".join(late)


def tally() -> dict[str, list[str]]:
    counts: dict[str, list[str]] = {"run": [], "skipped": [], "fragment": [], "file": [], "not code": []}
    for blocks in ALL_BLOCKS.values():
        for b in blocks:
            if b.marker == "skip":
                counts["skipped"].append(f"{b.where} ({b.reason})")
            elif b.marker == "fragment":
                counts["fragment"].append(f"{b.where} ({b.reason})")
            elif b.marker == "file":
                counts["file"].append(f"{b.where} ({b.reason})")
            elif b.lang in (*COMMAND_LANGS, "toml"):
                counts["run"].append(b.where)
            else:
                counts["not code"].append(b.where)
    return counts


def test_every_block_is_classified_and_every_skip_has_a_reason() -> None:
    found = [p for blocks in ALL_BLOCKS.values() for b in blocks for p in problems(b)]
    assert not found, "\n".join(found)
    counts = tally()
    print({k: len(v) for k, v in counts.items()})
    for kind in ("skipped", "fragment"):
        for entry in counts[kind]:
            print(f"{kind}: {entry}")
    assert counts["run"], "no block found to run"


@pytest.mark.parametrize(
    "doc", [d for d, blocks in ALL_BLOCKS.items() if any(b.lang in (*COMMAND_LANGS, "toml") for b in blocks)]
)
def test_doc_runs_as_printed(doc: str, session: Session) -> None:
    blocks = ALL_BLOCKS[doc]
    found = [p for b in blocks for p in problems(b)]
    assert not found, "\n".join(found)
    saved = {b.reason: save_file(session, b) for b in blocks if b.marker == "file"}
    used = "\n".join(b.text for b in blocks if b.marker != "skip" and b.lang in (*COMMAND_LANGS, "toml"))
    for name in saved:
        uses = used.count(name) - sum(
            b.text.count(name) for b in blocks if b.marker == "file" and b.reason == name
        )
        assert uses > 0, f"{doc}: the file {name} is saved for the doc's commands, but no block names it"
    for block in blocks:
        if block.marker in ("skip", "fragment"):
            continue
        if block.lang in COMMAND_LANGS:
            for line in commands(block):
                run_command(session, block, line)
        elif block.lang == "toml":
            path = saved.get(block.reason) if block.marker == "file" else None
            if path is None:
                path = session.cwd / f".config-{block.line}.toml"
                path.write_text(substitute(block.text + "\n", CONFIG_SUBSTITUTIONS, session.ports))
            if is_gateway_config(path.read_text()):
                check_config(session, block, path)
    if session.device is not None:
        session.stop(session.device, f"{doc}: tactile-sim run")
