"""The figure of ``tactile-gateway apply --plot``: forces over time against the reference.

Per channel (at most ``MAX_PLOTTED_CHANNELS``), a force panel (the reference wide and grey,
the tracked force, the static estimate dashed) and, with a reference, an error panel (force -
reference) below it, the holds of the reference shaded in both: the static estimate drifts
across a hold, the tracked force should not.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any, Final

from .apply import Applied, ChannelErrors
from .plots import save_figure

__all__ = ["MAX_PLOTTED_CHANNELS", "plot_applied"]

#: Channels drawn; a record with more draws its first ones (the title says how many).
MAX_PLOTTED_CHANNELS: Final = 6
_TRACKED, _STATIC, _REFERENCE, _HOLD = "tab:blue", "tab:orange", "0.55", "tab:green"


def _plt() -> Any:
    import matplotlib

    matplotlib.use("Agg")  # headless: no display is needed, none is opened
    import matplotlib.pyplot as plt

    return plt


def _shade_holds(ax: Any, errors: ChannelErrors | None, label: bool) -> None:
    for k, h in enumerate(errors.holds if errors is not None else ()):
        ax.axvspan(
            h.hold.start_s,
            h.hold.end_s,
            color=_HOLD,
            alpha=0.12,
            lw=0,
            label="hold" if label and k == 0 else None,
        )


def plot_applied(applied: Applied, errors: Sequence[ChannelErrors | None], path: Path) -> Path:
    """Write the figure to ``path`` (PNG, atomically) and return it."""
    plt = _plt()
    shown = list(zip(applied.channels, errors, strict=True))[:MAX_PLOTTED_CHANNELS]
    with_ref = [ch.record.force_n is not None for ch, _ in shown]
    heights = [r for has in with_ref for r in ((3.0, 1.6) if has else (3.0,))]
    fig, axes = plt.subplots(
        len(heights),
        1,
        figsize=(11, 0.9 + 1.15 * sum(heights)),
        gridspec_kw={"height_ratios": heights},
        squeeze=False,
    )
    panels = iter(axes[:, 0])
    for (ch, err), has_ref in zip(shown, with_ref, strict=True):
        rec = ch.record
        t = rec.time_s
        ax = next(panels)
        _shade_holds(ax, err, label=True)
        if rec.force_n is not None:
            ax.plot(t, rec.force_n, color=_REFERENCE, lw=3.0, alpha=0.6, label="reference")
        ax.plot(t, ch.force_tracked_n, color=_TRACKED, lw=1.0, label="tracked (drift-corrected)")
        ax.plot(t, ch.force_static_n, color=_STATIC, lw=1.0, ls="--", label="static estimate")
        title = f"{ch.name} <- [{ch.calibration_channel}], read by {ch.model}"
        if err is not None:
            s = err.overall
            title += (
                f": RMS error tracked {s.tracked_rms_n:.3g} N ({s.pct(s.tracked_rms_n):.2g} % FS), "
                f"static {s.static_rms_n:.3g} N ({s.pct(s.static_rms_n):.2g} % FS)"
            )
        ax.set_title(title, fontsize=9, loc="left")
        ax.set_ylabel("force (N)")
        low, high = ax.get_ylim()
        ax.set_ylim(low, high + 0.25 * (high - low))  # room for the legend above the curves
        ax.legend(fontsize=7, loc="upper left", ncol=4)
        ax.grid(alpha=0.3)
        if has_ref and rec.force_n is not None:
            ax.tick_params(labelbottom=False)
            ax_err = next(panels)
            ax_err.sharex(ax)
            _shade_holds(ax_err, err, label=False)
            ax_err.axhline(0.0, color="k", lw=0.6)
            ax_err.plot(t, ch.force_tracked_n - rec.force_n, color=_TRACKED, lw=1.0, label="tracked")
            ax_err.plot(t, ch.force_static_n - rec.force_n, color=_STATIC, lw=1.0, ls="--", label="static")
            ax_err.set_ylabel("error (N)")
            ax_err.grid(alpha=0.3)
            ax_err.set_xlabel("time (s)")
        else:
            ax.set_xlabel("time (s)")
    src = applied.record.path.name if applied.record.path else "record"
    more = len(applied.channels) - len(shown)
    fig.suptitle(
        f"{applied.calibration.name} applied to {src}"
        + (f" (first {len(shown)} of {len(applied.channels)} channels)" if more > 0 else ""),
        fontsize=11,
    )
    fig.tight_layout()
    save_figure(fig, path)
    plt.close(fig)
    return path
