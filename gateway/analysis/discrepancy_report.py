"""The discrepancy workflow's report: ``report.md`` with residual plots, written atomically."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..atomic import atomic_write_text
from .discrepancy import DiscrepancyReport, Step, residual_axes
from .fitting import FitData, FitResult
from .plots import save_figure


def _plot_residuals(data: FitData, fits: list[tuple[str, FitResult]], path: Path) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    axes_data = residual_axes(data)
    fig, axes = plt.subplots(1, 3, figsize=(14, 4), sharey=True)
    for label, fit in fits:
        res = fit.log_residual
        ok = data.usable & np.isfinite(res)
        axes[0].semilogx(axes_data["force"][ok], res[ok], ".", ms=2, alpha=0.4, label=label)
        since = np.maximum(axes_data["time_since_change"][ok], 0.1)
        axes[1].semilogx(since, res[ok], ".", ms=2, alpha=0.4, label=label)
        d = axes_data["direction"][ok]
        means = [float(np.mean(res[ok][d == v])) if np.any(d == v) else np.nan for v in (-1.0, 0.0, 1.0)]
        axes[2].plot(["unloading", "hold/rest", "loading"], means, "o-", label=label)
    axes[0].set(xlabel="force (N)", ylabel="ln(R_measured / R_model)", title="by force")
    axes[1].set(xlabel="time since the last load change (s)", title="by time")
    axes[2].set(xlabel="load direction", title="mean by direction")
    for ax in axes:
        ax.axhline(0.0, color="k", lw=0.5)
    axes[0].legend(markerscale=4)
    fig.tight_layout()
    save_figure(fig, path)
    plt.close(fig)
    return path


def _candidate_table(step: Step) -> list[str]:
    lines = [
        "| candidate | added parameters | score | held-out log-R RMS | held-out force RMS (N) |",
        "|---|---|---|---|---|",
    ]
    for c in step.candidates:
        mark = " (added)" if c.effect == step.added else ""
        lines.append(
            f"| {c.effect}{mark} | {c.added_parameters} | {c.score:.1f} | "
            f"{c.gap_test.log_resistance_rms:.4f} | {c.gap_test.force_rms_n:.4f} |"
        )
    return lines


def write_report(report: DiscrepancyReport, data: FitData, out_dir: Path) -> Path:
    """Write ``out_dir/report.md`` and its PNGs; returns the report's path."""
    out_dir.mkdir(parents=True, exist_ok=True)
    lines = [f"# Discrepancy report: {report.record} (channel {report.channel})", ""]
    j = report.as_json()
    lines.append(f"- baseline: `{', '.join(report.baseline)}`; candidates: `{', '.join(report.candidates)}`")
    lines.append(
        f"- added, in order: `{', '.join(j['added']) or 'nothing'}`; final model: `{', '.join(j['final'])}`"
    )
    before, after = j["gap_before"], j["gap_after"]
    lines.append(
        f"- held-out gap: log-resistance RMS {before['log_resistance_rms']} -> "
        f"{after['log_resistance_rms']}, force RMS {before['force_rms_n']} N -> {after['force_rms_n']} N"
    )
    for note in report.notes:
        lines.append(f"- note: {note}")
    lines.append("")
    for i, step in enumerate(report.steps, start=1):
        lines.append(f"## Step {i}: model `{', '.join(step.effects_before)}`")
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
        fits = [("before", step.fit_before)]
        if step.added:
            fits.append(
                (f"with {step.added}", next(c.fit for c in step.candidates if c.effect == step.added))
            )
        png = _plot_residuals(data, fits, out_dir / f"step{i}_residuals.png")
        lines.append(f"![residuals, step {i}]({png.name})")
        lines.append("")
    lines.append("## Fitted parameters of the final model (95 % intervals)")
    lines.append("")
    lines.append("| parameter | value | 95 % interval | note |")
    lines.append("|---|---|---|---|")
    for e in report.final_fit.estimates:
        interval = f"[{e.low:.4g}, {e.high:.4g}]" if e.fitted else "fixed"
        lines.append(f"| {e.name} | {e.value:.5g} | {interval} | {e.note} |")
    path = out_dir / "report.md"
    atomic_write_text(path, "\n".join(lines) + "\n")
    return path
