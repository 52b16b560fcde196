"""The calibration report: what was fitted, how every calibration reads held-out force and
holds, and which one is written."""

from __future__ import annotations

import math

from .calibration_range import model_force_range
from .calibration_result import OBJECTIVE_WORDS, Calibration, CalibrationModel

__all__ = ["format_report", "outside_range_words", "ranking_lines"]


def format_report(cal: Calibration) -> str:
    """Human-readable calibration report."""
    fit = cal.fit
    out = [f"channel {cal.channel} of {cal.record}: effects {', '.join(fit.effects)}"]
    out.append(f"rows: {fit.n_train} training, {fit.n_test} held out, unusable {cal.unusable}")
    lo, hi = cal.force_range_n
    low, high = cal.calibrated_range_n()
    below, above = cal.range_margin_n
    out.append(
        f"force range calibrated: {lo:.3g}-{hi:.4g} N, written as calibrated_min_n/calibrated_max_n "
        f"{low:.3g}-{high:.4g} N (widened to where the model reads the record's end loads, "
        f"bias + 3 sigma: -{below:.2g}/+{above:.2g} N) "
        f"(configured {cal.configured_range_n[0]:g}-{cal.configured_range_n[1]:g} N; "
        f"{cal.rows_outside_configured} rows outside it, none capped in the fit-quality numbers)"
        + (
            f"; the record's {cal.record_range_n[0]:.3g}-{cal.record_range_n[1]:.4g} N "
            f"+ the zero offset {cal.offset_words()}"
            if cal.offset_words()
            else ""
        )
    )
    out += outside_range_words(cal)
    out.append(
        f"fit objective: {OBJECTIVE_WORDS[fit.objective]} (requested: {cal.objective_mode}; zero offset: "
        f"{cal.offset_mode}); held-out force errors are against "
        + ("F_ref + offset" if cal.offset_words() else "F_ref")
    )
    out += [f"WARNING: {w}" for w in cal.warnings]
    out += [f"note: {n}" for n in cal.notes]
    out.append(f"measurement model: {cal.noise.describe()}")
    out.append("")
    out.append(f"{'parameter':<24} {'value':>12} {'95 % interval':>27}  note")
    for e in fit.estimates:
        interval = f"[{e.low:.4g}, {e.high:.4g}]" if e.fitted else "fixed at prior"
        out.append(f"{e.name:<24} {e.value:>12.5g} {interval:>27}  {e.note}")
    if fit.correlation.size:
        out.append("")
        out.append("strongest parameter correlations:")
        pairs = []
        n = len(fit.correlation_names)
        for i in range(n):
            for j in range(i + 1, n):
                pairs.append((abs(float(fit.correlation[i, j])), i, j))
        for value, i, j in sorted(pairs, reverse=True)[:5]:
            sign = "+" if fit.correlation[i, j] >= 0 else "-"
            out.append(f"  {fit.correlation_names[i]} ~ {fit.correlation_names[j]}: {sign}{value:.3f}")
    out.append("")
    out.append(f"held-out data ({fit.n_test} rows)             log-resistance RMS   force RMS (N)")
    if cal.fit_before is not None and cal.fit_before is not fit:
        g = cal.fit_before.gap_test
        out.append(
            f"  physical model without hysteresis {g.log_resistance_rms:>17.4f} {g.force_rms_n:>15.4f}"
        )
    out.append(
        f"  physical model (drift-corrected) {fit.gap_test.log_resistance_rms:>18.4f} "
        f"{fit.gap_test.force_rms_n:>15.4f}"
    )
    if cal.other is not None:
        g, word = cal.other.gap_test, f"  physical model, {OBJECTIVE_WORDS[cal.other.objective]} objective"
        out.append(f"{word:<35}{g.log_resistance_rms:>16.4f} {g.force_rms_n:>15.4f}")
    out.append(f"  conductance line C = m F + n     {'-':>18} {cal.rivals.line_force_rms_n:>15.4f}")
    out.append(f"  monotone lookup F(ln R)          {'-':>18} {cal.rivals.lookup_force_rms_n:>15.4f}")
    out.append(
        f"  noise floor (measurement model)  {cal.noise_floor_log:>18.4f} {cal.noise_floor_force_n:>15.4f}"
    )
    line = cal.rivals.line_curve
    out.append(f"    m = {line.slope_s_per_n:.6g} S/N, n = {line.intercept_s:.6g} S")
    out.append("")
    out += ranking_lines(cal)
    out.append(f"verdict: {cal.verdict}; written by --model auto: {cal.best}")
    if cal.starting_load_n > 0.0:
        out.append(
            f"note: the record starts loaded ({cal.starting_load_n:.4g} N): every calibration starts "
            "from the equilibrium at that load, as the gateway does"
        )
    if cal.best != "physics":
        written = cal.best in {m.value for m in CalibrationModel}
        how = f"--model {cal.best} or --model auto" if written else "--model auto"
        out.append(f"  (write it as the channel's model with {how})")
    return "\n".join(out)


def outside_range_words(cal: Calibration) -> list[str]:
    """What the channel reads outside its calibrated range (lines of the report)."""
    lo, hi = cal.calibrated_range_n()
    model_lo, model_hi = model_force_range((lo, hi))
    rival = ""
    if cal.offset_words():
        r_lo, r_hi = cal.calibrated_range_n("line")
        rival = f" (written as a line, lookup or curve: outside {r_lo:.3g}-{r_hi:.4g} N)"
    return [
        f"outside the calibrated range: below {lo:.3g} N and above {hi:.4g} N the channel reads forces "
        f"extrapolated along its curve, flagged `extrapolated`{rival}; at or below 0 N it reads no_contact",
        f"  (the physical model is written over {model_lo:.3g}-{model_hi:.4g} N, force_min_n/force_max_n: "
        f"no_contact below {model_lo:.3g} N, saturated above {model_hi:.4g} N; a line with n < 0 reads "
        "no_contact below its force_min_n, where a sensor at rest would read a phantom force)",
    ]


def ranking_lines(cal: Calibration) -> list[str]:
    """Every calibration ranked on held-out force (the table of the report), with its held-out
    hold drift in both groups; a calibration whose drift exceeds its static reference in either
    group (``Calibration.drifts_more``) is marked, and never written by ``--model auto``."""
    writable = {s.name for s in cal.writable()}
    ref_after, ref_others = cal.static_drift_reference()
    lookup_after, lookup_others = cal.static_drift_reference(dynamic=False)
    best = cal.best
    out = [
        f"ranking on held-out force ({cal.held_out_rows or cal.fit.n_test} rows, read as the gateway reads "
        "them, against F_ref);",
        "hold drift: end minus start error of each held-out hold, RMS, % of full scale, for holds right",
        f"after a higher load and the others; a drift correction may not exceed {_pct(ref_after)}, "
        f"{_pct(ref_others)} (the best static rival's or the lookup's), a static curve not the lookup's "
        f"({_pct(lookup_after)}, "
        f"{_pct(lookup_others)}):",
        f"  {'calibration':<30} {'force RMS (N)':>13} {'after higher':>12} {'others':>8} {'parameters':>10}",
    ]
    for s in cal.ranking():
        after, others = s.drift.all_pct_fs
        mark = "  <- best" if s.name == best else "" if s.name in writable else "  (holds drift more)"
        out.append(
            f"  {s.name:<30} {s.held_out_force_rms_n:>13.4f} {_pct(after):>12} {_pct(others):>8} "
            f"{s.n_parameters:>10}{mark}"
        )
    return out


def _pct(value: float) -> str:
    return "-" if not math.isfinite(value) else f"{value:.2f}"
