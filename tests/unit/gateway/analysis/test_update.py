"""``calibrate --update``: only the sensitivity (gain, offset) of a curve calibration moves."""

from __future__ import annotations

import dataclasses
import math
import tomllib
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from gateway.analysis.records import ChannelRecord
from gateway.analysis.update import (
    PhysicsChannel,
    UpdateError,
    load_channels,
    rewrite_sensitivity,
    update_from_loads,
    update_from_record,
)
from gateway.cli import main
from gateway.model.curves import CurveChannel, Drift, PowerLawCurve

K_S, N = 1e-4, 1.0  # G = k F: R = 1 / (k F), F = 1 / (k R)

CAL = """# a calibration file
[meta]
record = "bench.csv"

[channel."pad"]
r0_ohm = 17000.0

[curve."pad"]  # written by hand
kind = "power_law"
coefficient_s = 0.0001
exponent = 1.0
gain = 1.0
offset_n = 0.0
creep_fraction = 0.1
creep_tau_s = 10.0
force_min_n = 0.5
force_max_n = 20.0
"""


def test_one_known_load_fits_the_gain_by_hand() -> None:
    # the sensor now conducts 1.6 x: at 4 N it reads R = 1 / (1.6 k 4) = 1562.5 ohm; the stored
    # curve reads 6.4 N there; the gain that reads 4 N is 1 / 1.6 = 0.625 (x = curve(R / gain))
    channel = CurveChannel(PowerLawCurve(K_S, N))
    up = update_from_loads("pad", channel, [(4.0, 1.0 / (1.6 * K_S * 4.0))])
    assert up.after.gain == pytest.approx(0.625, rel=1e-6)
    assert up.after.offset_n == 0.0  # one load: the offset is kept
    assert up.rms_before_n == pytest.approx(2.4, rel=1e-9) and up.rms_after_n < 1e-6


def test_two_known_loads_fit_gain_and_offset_by_hand() -> None:
    # R = 2 / (k (F - 0.3)): curve(R / g) = g (F - 0.3) / 2, so x = F needs g = 2 and offset 0.3 N
    channel = CurveChannel(PowerLawCurve(K_S, N))
    loads = [(f, 2.0 / (K_S * (f - 0.3))) for f in (2.0, 8.0)]
    up = update_from_loads("pad", channel, loads)
    assert up.after.gain == pytest.approx(2.0, rel=1e-6)
    assert up.after.offset_n == pytest.approx(0.3, abs=1e-6)
    assert up.after.curve == channel.curve and up.after.drift == channel.drift


def test_a_short_record_fits_the_gain_with_the_dynamics_kept() -> None:
    # a held step of 5 N with creep a = 0.1, tau = 10 s, on a sensor conducting 1.25 x: the
    # apparent force x = F (1 + a (1 - e^(-t/tau))) (previous force held over each interval)
    drift = Drift(creep_fraction=0.1, creep_tau_s=10.0)
    channel = CurveChannel(PowerLawCurve(K_S, N), drift)
    t = np.arange(0.0, 60.0, 0.5)
    f = np.where(t >= 1.0, 5.0, 0.0)
    z, x = 0.0, []
    for k in range(t.size):
        held = f[k - 1] if k else 0.0
        e = math.exp(-(t[k] - t[k - 1]) / 10.0) if k else 1.0
        z = e * z + (1 - e) * 0.1 * held
        x.append(f[k] + z)
    x_arr = np.asarray(x)
    r = np.where(x_arr > 0, 1.0 / (1.25 * K_S * np.maximum(x_arr, 1e-300)), np.inf)
    rec = ChannelRecord("0", t, r, f, None, np.arange(t.size, dtype=np.int64))
    up = update_from_record("pad", channel, rec)
    assert up.after.gain == pytest.approx(0.8, rel=1e-5)
    assert up.rms_after_n < 1e-5 < up.rms_before_n
    assert up.after.drift == drift


def test_rewrite_changes_only_gain_and_offset(tmp_path: Path) -> None:
    new = CurveChannel(PowerLawCurve(K_S, N)).with_sensitivity(0.625, -0.25)
    text = rewrite_sensitivity(CAL, {"pad": new})
    changed = [(a, b) for a, b in zip(CAL.splitlines(), text.splitlines(), strict=True) if a != b]
    assert changed == [("gain = 1.0", "gain = 0.625"), ("offset_n = 0.0", "offset_n = -0.25")]
    data = tomllib.loads(text)
    assert data["curve"]["pad"]["gain"] == 0.625 and data["channel"]["pad"]["r0_ohm"] == 17000.0
    # absent keys are added to the table
    bare = CAL.replace("gain = 1.0\n", "").replace("offset_n = 0.0\n", "")
    assert tomllib.loads(rewrite_sensitivity(bare, {"pad": new}))["curve"]["pad"]["offset_n"] == -0.25


def test_errors_are_messages(tmp_path: Path) -> None:
    nothing = tmp_path / "meta.toml"
    nothing.write_text('[meta]\nrecord = "bench.csv"\n', encoding="utf-8")
    with pytest.raises(UpdateError, match="no calibrated channel"):
        load_channels(nothing)
    with pytest.raises(UpdateError, match="force > 0 N"):
        update_from_loads("pad", CurveChannel(PowerLawCurve(K_S, N)), [(0.0, 1000.0)])


def test_cli_update_from_known_loads_and_from_a_record(tmp_path: Path) -> None:
    cal = tmp_path / "cal.toml"
    cal.write_text(CAL, encoding="utf-8")
    runner = CliRunner()
    r_at_4 = 1.0 / (1.6 * K_S * 4.0)
    out = runner.invoke(
        main, ["calibrate", "--update", str(cal), "--channel", "pad", "--known", f"4={r_at_4}"]
    )
    assert out.exit_code == 0, out.output
    assert "gain 1 -> 0.625" in out.output and f"wrote {cal}" in out.output
    assert tomllib.loads(cal.read_text(encoding="utf-8"))["curve"]["pad"]["gain"] == pytest.approx(0.625)
    # a calibration file with a [curve] table may be replaced by calibrate --out
    rec = tmp_path / "rec.csv"
    rows = ["time_s,resistance_ohm,force_n"] + [f"{i * 0.5},{1.0 / (K_S * 2.0)},2.0" for i in range(20)]
    rec.write_text("\n".join(rows) + "\n", encoding="utf-8")
    out = runner.invoke(main, ["calibrate", "--update", str(cal), str(rec), "--as", "pad", "--json"])
    assert out.exit_code == 0, out.output
    assert '"updates"' in out.output
    bad = runner.invoke(main, ["calibrate", "--update", str(cal)])
    assert (
        bad.exit_code == 2 and "either RECORD.csv or --known" in bad.output and "Traceback" not in bad.output
    )


def test_every_kind_of_calibration_loads_for_an_update(tmp_path: Path) -> None:
    """A [curve], a [line], a [lookup] table and a physical model's [channel] table alone."""
    path = tmp_path / "cal.toml"
    path.write_text(
        CAL + '[channel."tip"]\nr0_ohm = 20000.0\n[line."line"]\nslope_s_per_n = 2e-5\n'
        "intercept_s = 1e-6\nforce_min_n = 0.1\nforce_max_n = 10.0\n"
        '[lookup."lut"]\nresistance_ohm = [1e3, 1e4, 1e5]\nforce_n = [8.0, 2.0, 0.5]\n',
        encoding="utf-8",
    )
    channels = load_channels(path)
    assert isinstance(channels["tip"], PhysicsChannel) and channels["tip"].params.r0_ohm == 20000.0
    kinds = {name: getattr(ch, "table_kind", "physics") for name, ch in channels.items()}
    assert kinds == {"pad": "curve", "tip": "physics", "line": "line", "lut": "lookup"}


def test_a_line_table_is_updated_into_a_curve_table_of_that_line(tmp_path: Path) -> None:
    """The sensor conducts 1.25 x: a known load of 3 N reads R = 1 / (1.25 (m 3 + n)); gain 0.8
    reads it; the [line] table becomes a [curve] line with gain 0.8, the rest kept."""
    text = (
        '# mine\n[line."tip"]\nslope_s_per_n = 2e-5\nintercept_s = 1e-6\n'
        "force_min_n = 0.1\nforce_max_n = 10.0\n"
    )
    path = tmp_path / "line.toml"
    path.write_text(text, encoding="utf-8")
    line = load_channels(path)["tip"]
    assert not isinstance(line, PhysicsChannel)
    up = update_from_loads("tip", line, [(3.0, 1.0 / (1.25 * (2e-5 * 3.0 + 1e-6)))])
    assert up.after.gain == pytest.approx(0.8, rel=1e-6)
    new = rewrite_sensitivity(text, {"tip": up.after})
    data = tomllib.loads(new)
    assert "line" not in data and data["curve"]["tip"]["kind"] == "line"
    assert data["curve"]["tip"]["gain"] == pytest.approx(0.8, rel=1e-6)
    assert new.startswith("# mine")
    out = tmp_path / "updated.toml"
    out.write_text(new, encoding="utf-8")
    assert load_channels(out)["tip"] == dataclasses.replace(up.after, table_kind="curve")


def test_a_physical_model_is_updated_by_a_gain_on_its_resistances(tmp_path: Path) -> None:
    """A sensor that now reads every resistance half of what the stored model says: the gain
    is 2 (the model reads R x 2 as it read R), and every resistance parameter is halved."""
    from gateway.model import SensorModel, SensorParams

    params = SensorParams()
    channel = PhysicsChannel(params, ("tunneling", "contact"))
    model = SensorModel(("tunneling", "contact"), [params])
    loads = [(f, 0.5 * float(model.resistance(np.array([f]))[0])) for f in (1.0, 4.0)]
    up = update_from_loads("tip", channel, loads)
    assert isinstance(up.after, PhysicsChannel)
    assert up.after.gain == pytest.approx(2.0, rel=1e-4) and up.rms_after_n < 1e-3 < up.rms_before_n
    scaled = up.after.scaled_params()
    assert scaled["r0_ohm"] == pytest.approx(params.r0_ohm / 2.0, rel=1e-4)
    assert scaled["rho2_ohm_m"] == pytest.approx(params.rho2_ohm_m / 2.0, rel=1e-4)


def test_the_rest_of_the_run_is_the_transfer_test() -> None:
    """Update from the first 30 s of a 60 s record; the rest is scored with the state carried
    over, in % of the whole run's full scale, beside a lookup re-fitted on the head."""
    channel = CurveChannel(PowerLawCurve(K_S, N))
    t = np.arange(0.0, 60.0, 0.5)
    f = 1.0 + 4.0 * (np.sin(t / 3.0) ** 2)
    r = 1.0 / (1.25 * K_S * f)
    rec = ChannelRecord("0", t, r, f, None, np.arange(t.size, dtype=np.int64))
    up = update_from_record("pad", channel, rec, first_s=30.0)
    assert up.transfer is not None
    assert up.transfer.rows == int(np.count_nonzero(t >= 30.0))
    assert up.transfer.full_scale_n == pytest.approx(float(f.max()))
    assert up.transfer.rms_after_n < 1e-5 < up.transfer.rms_before_n
    assert up.transfer.pct(up.transfer.rms_before_n) == pytest.approx(
        100.0 * float(np.sqrt(np.mean((1.25 * f - f)[t >= 30.0] ** 2))) / float(f.max()), rel=1e-6
    )
    assert "the rest of the run" in up.describe()
