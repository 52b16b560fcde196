"""calibrate and apply say how many rows of reference below 0 N they read as load-cell zero
noise (``ChannelRecord.zero_noise_note``)."""

from __future__ import annotations

from pathlib import Path

from click.testing import CliRunner

from gateway.cli import main

RECORD = """# time: real
time_s,force_n,resistance_ohm
0.0,-0.0002,1e7
1.0,1.0,10000
2.0,2.0,5000
3.0,3.0,3333
4.0,2.0,5000
5.0,1.0,10000
6.0,3.0,3333
7.0,2.0,5000
8.0,4.0,2500
9.0,1.0,10000
10.0,-0.0001,1e7
"""


def test_calibrate_and_apply_count_the_zero_noise_rows(tmp_path: Path) -> None:
    record = tmp_path / "bench.csv"
    record.write_text(RECORD, encoding="utf-8")
    cal = tmp_path / "cal.toml"
    words = "2 rows of reference below 0 N accepted as load-cell zero noise (down to -0.0002 N"
    out = CliRunner().invoke(
        main, ["calibrate", str(record), "--as", "tip", "--model", "lookup", "--out", str(cal)]
    )
    assert out.exit_code == 0, out.output
    assert words in out.output
    applied = tmp_path / "applied.csv"
    out = CliRunner().invoke(main, ["apply", str(cal), str(record), "--as", "0=tip", "--out", str(applied)])
    assert out.exit_code == 0, out.output
    assert words in out.output
