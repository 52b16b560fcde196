"""Plots a sensor engineer reads at a glance (calibration and discrepancy reports).

- R against F on log-log axes, loading and unloading coloured, with row counts;
- measured against predicted force with the +-0.1 N and +-5 % of full scale bands;
- log-resistance residuals against force with the measurement model's noise floor (+-1 sigma).

Time panels are drawn only when the record has real time (``measurement.time_is_real``).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .diagnostics import direction_bins
from .fitting import FitData, FitResult
from .plots import save_figure

FloatArray = NDArray[np.float64]

#: The colours of the loading, holding and unloading rows (``diagnostics.direction_bins``).
DIRECTION_COLOURS = ("tab:red", "tab:gray", "tab:blue")


def _plt() -> Any:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def draw_panels(
    data: FitData, fit: FitResult, predicted_force: dict[str, FloatArray], axes: Any, real_time: bool
) -> None:
    """R(F), measured vs predicted force, residuals vs force (and residual vs time with real time)."""
    ok = data.usable & np.isfinite(data.resistance_ohm)
    ax_rf, ax_ff, ax_res = axes[0], axes[1], axes[2]
    # the rows of the report's loading-direction table, counted as it counts them
    for (words, m), colour in zip(direction_bins(data, fit, real_time), DIRECTION_COLOURS, strict=True):
        n = int(np.count_nonzero(m))
        if n:
            label = words.removeprefix("while ")
            ax_rf.loglog(
                data.force_n[m], data.resistance_ohm[m], ".", ms=3, color=colour, label=f"{label} (n={n})"
            )
    order = np.argsort(data.force_n[ok])
    ax_rf.loglog(data.force_n[ok][order], fit.model_ohm[ok][order], "k-", lw=1, label="model")
    ax_rf.set(xlabel="force (N)", ylabel="resistance (ohm)", title="R against F")
    ax_rf.legend(fontsize=7)

    test = data.test
    f_ref = data.force_n[test]
    full_scale = float(np.max(data.force_n[ok])) if ok.any() else 1.0
    grid = np.linspace(0.0, full_scale, 50)
    ax_ff.plot(grid, grid, "k-", lw=0.8)
    ax_ff.fill_between(grid, grid - 0.1, grid + 0.1, color="tab:green", alpha=0.25, label="+-0.1 N")
    band = 0.05 * full_scale
    ax_ff.plot(grid, grid - band, "k:", lw=0.8)
    ax_ff.plot(grid, grid + band, "k:", lw=0.8, label=f"+-5 % FS ({band:.2g} N)")
    for name, pred in predicted_force.items():
        p = pred[test]
        good = np.isfinite(p)
        ax_ff.plot(f_ref[good], p[good], ".", ms=3, label=f"{name} (n={int(good.sum())})")
    ax_ff.set(xlabel="reference force (N)", ylabel="predicted force (N)", title="held-out rows")
    ax_ff.legend(fontsize=7)

    res = fit.log_residual
    good = ok & np.isfinite(res)
    ax_res.semilogx(
        data.force_n[good], res[good], ".", ms=2, alpha=0.5, label=f"residual (n={int(good.sum())})"
    )
    if data.sigma_log is not None:
        order = np.argsort(data.force_n[good])
        s = data.sigma_log[good][order]
        ax_res.fill_between(
            data.force_n[good][order], -s, s, color="tab:orange", alpha=0.3, label="noise floor (+-1 sigma)"
        )
    ax_res.axhline(0.0, color="k", lw=0.5)
    ax_res.set(xlabel="force (N)", ylabel="ln(R_measured / R_model)", title="residuals")
    ax_res.legend(fontsize=7)
    if real_time and len(axes) > 3:
        axes[3].plot(data.time_s[good], res[good], ".", ms=2)
        axes[3].set(xlabel="time (s)", ylabel="ln(R_measured / R_model)", title="residuals in time")


def plot_fit(
    data: FitData, fit: FitResult, predicted_force: dict[str, FloatArray], path: Path, real_time: bool
) -> Path:
    plt = _plt()
    n = 4 if real_time else 3
    fig, axes = plt.subplots(1, n, figsize=(5 * n, 4.2))
    draw_panels(data, fit, predicted_force, axes, real_time)
    fig.tight_layout()
    save_figure(fig, path)
    plt.close(fig)
    return path


def plot_calibration(cal: Any, channel: Any, out_dir: Path) -> list[Path]:
    """The calibration's figure: the physical model with the line and the lookup."""
    from .discrepancy import decimate, prepare

    small = decimate(channel)
    data, _, _ = prepare(small, {}, None)
    data = FitData(
        data.time_s,
        data.resistance_ohm,
        data.force_n,
        data.temperature_c,
        data.usable,
        data.held_out,
        cal.noise.sigma_log if cal.noise.sigma_log.size == data.time_s.size else data.sigma_log,
    )
    predicted = {
        # against F_ref: a fit with a zero offset reads F_ref + offset
        "model": cal.fit.force_inverted_n - cal.fit.force_offset_n,
        "line": cal.rivals.line_force_n,
        "lookup": cal.rivals.lookup_force_n,
    }
    real_time = not any("no real time" in n for n in cal.notes)
    path = out_dir / f"calibration_{cal.channel}.png"
    return [plot_fit(data, cal.fit, predicted, path, real_time)]
