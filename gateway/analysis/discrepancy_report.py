"""The discrepancy workflow's report: ``report.md`` with residual plots, written atomically."""

from __future__ import annotations

import math
from pathlib import Path

from ..atomic import atomic_write_text
from .calibration_plots import plot_fit
from .discrepancy import DiscrepancyReport, Step
from .fitting import FitData, FitResult


def _plot_residuals(data: FitData, fits: list[tuple[str, FitResult]], path: Path, real_time: bool) -> Path:
    label, fit = fits[-1]
    return plot_fit(data, fit, {label: fit.force_inverted_n}, path, real_time)


def _candidate_table(step: Step) -> list[str]:
    lines = [
        "| candidate | added parameters | penalized score (lower is better) | held-out log-R RMS | "
        "held-out force RMS, tracked state (N) |",
        "|---|---|---|---|---|",
    ]
    for c in step.candidates:
        mark = " (added)" if c.effect == step.added else ""
        lines.append(
            f"| {c.effect}{mark} | {c.added_parameters} | {c.score:.1f} | "
            f"{c.gap_test.log_resistance_rms:.4f} | {c.gap_test.force_rms_n:.4f} |"
        )
    return lines


def _unexplained_section(report: DiscrepancyReport) -> list[str]:
    """The unexplained-residual verdict, the best empirical alternative and the residual's
    structure, one table per axis."""
    u = report.unexplained
    if u is None:
        return []
    title = "An unexplained residual remains" if u.remains else "No unexplained residual"
    lines = [f"## {title}", ""]
    lines += [f"- {r}" for r in u.reasons]
    lines += [f"- possible cause: {c}" for c in u.causes]
    best = u.best_alternative
    if best is not None:
        lines.append(f"- best empirical alternative on held-out force: {best[0]} ({best[1]:.4g} N)")
    lines.append("- alternatives: " + ", ".join(f"{n} {v:.4g} N" for n, v in u.alternatives))
    lines.append(f"- structure: {u.structure.sentence()}")
    lines += [f"- not examined: {s}" for s in u.structure.skipped]
    lines.append("")
    for axis in u.structure.axes:
        lines.append(
            f"### Residual by {axis.words} (explains {100 * axis.explained_log_r:.0f} % of the log-R "
            f"residual's variance, {100 * axis.explained_force:.0f} % of the force residual's)"
        )
        lines.append("")
        lines.append("| bin | rows | log-R mean | log-R RMS | force mean (N) | force RMS (N) |")
        lines.append("|---|---|---|---|---|---|")
        for b in axis.bins:
            lines.append(
                f"| {b.label} | {b.n_rows} | {b.log_r_mean:+.4f} | {b.log_r_rms:.4f} | "
                f"{b.force_mean_n:+.4g} | {b.force_rms_n:.4g} |"
            )
        lines.append("")
    return lines


def write_report(report: DiscrepancyReport, data: FitData, out_dir: Path, real_time: bool = True) -> Path:
    """Write ``out_dir/report.md`` and its PNGs; returns the report's path."""
    out_dir.mkdir(parents=True, exist_ok=True)
    lines = [f"# Discrepancy report: {report.record} (channel {report.channel})", ""]
    j = report.as_json()
    if report.static_choice is not None:
        lines.append(f"- {report.static_choice.sentence()}")
    if report.start is not None:
        lines.append(f"- {report.start.sentence()}")
    base = ", ".join(report.baseline) or report.steps[0].label
    lines.append(f"- baseline: `{base}`; candidates: `{', '.join(report.candidates)}`")
    lines.append(
        f"- added, in order: `{', '.join(j['added']) or 'nothing'}`; final model: `{report.model_name}` "
        f"(`{', '.join(j['final']) or 'no effect'}`)"
    )
    before, after = j["gap_before"], j["gap_after"]
    lines.append(
        f"- held-out gap: log-resistance RMS {before['log_resistance_rms']} -> "
        f"{after['log_resistance_rms']}, force RMS {before['force_rms_n']} N -> {after['force_rms_n']} N"
    )
    lines.append(f"- {report.rival_summary()}")
    lines.append(f"- noise floor (held-out log-R): {report.noise_floor_log:.4g}; {report.noise_description}")
    for note in report.notes:
        lines.append(f"- note: {note}")
    lines.append("")
    for i, step in enumerate(report.steps, start=1):
        lines.append(f"## Step {i}: model `{step.label}`")
        lines.append("")
        g = step.fit_before.gap_test
        lines.append(
            f"Held-out gap: log-resistance RMS {g.log_resistance_rms:.4f}, force RMS {g.force_rms_n:.4f} N."
        )
        lines.append("")
        if step.findings:
            lines.append("Where the model and the data disagree:")
            lines += [f"- {f.sentence}" for f in step.findings]
            lines.append("")
        if step.candidates:
            lines += _candidate_table(step)
            lines.append("")
        lines.append(
            f"Decision: {'add `' + step.added + '`' if step.added else 'add nothing'}. {step.evidence}"
        )
        lines.append("")
        if step.added:
            lines.append(
                f"Tracked held-out force RMS: {step.tracked_before:.4g} -> {step.tracked_after:.4g} N."
            )
            lines.append("")
        for c, why in step.refused():
            lines.append(f"- `{c.effect}` {why}")
        if step.refused():
            lines.append("")
        fits = [("before", step.fit_before)]
        if step.added:
            fits.append(
                (f"with {step.added}", next(c.fit for c in step.candidates if c.effect == step.added))
            )
        png = _plot_residuals(data, fits, out_dir / f"step{i}_residuals.png", real_time)
        lines.append(f"![residuals, step {i}]({png.name})")
        lines.append("")
    lines += _unexplained_section(report)
    lines.append("## Fitted parameters of the final model (95 % intervals)")
    lines.append("")
    lines.append("| parameter | value | 95 % interval | note |")
    lines.append("|---|---|---|---|")
    for e in report.final_fit.estimates:
        interval = f"[{e.low:.4g}, {e.high:.4g}]" if e.fitted else "fixed"
        if e.fitted and not (math.isfinite(e.low) and math.isfinite(e.high)):
            interval = "not computed"
        lines.append(f"| {e.name} | {e.value:.5g} | {interval} | {e.note} |")
    path = out_dir / "report.md"
    atomic_write_text(path, "\n".join(lines) + "\n")
    return path
