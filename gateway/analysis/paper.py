"""Replaying the paper's experiments (Fig. 5, 6b, 9, 10) on records of the simulated array.

The analysis follows the paper: each creep test (2, 4, 6, 8 N held) is fitted with eq. 17
(a step held from t = 0) for constant E0, E1 and mu1 at that force; lines are then fitted
to the coefficients against force (eq. 19, Fig. 6b). The force-resistance and
force-conductance curves (Fig. 5) come from a staircase, with the conductance line
C = m F + n of eq. 18. R0 and the contact coefficient are taken as known (the paper
measured its material separately); everything else comes from the record.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import least_squares

from ..atomic import atomic_write_text
from ..model import SensorModel, SensorParams
from ..model.static_curves import LineCurve
from .plots import save_figure
from .records import ChannelRecord

FloatArray = NDArray[np.float64]
CREEP_FORCES_N = (2.0, 4.0, 6.0, 8.0)
PAPER_EFFECTS = ("tunneling", "contact", "creep")


@dataclass(frozen=True)
class HoldFit:
    """Eq. 17 fitted to one creep test: constant E0, E1, mu1 at that force."""

    force_n: float
    e0_pa: float
    e1_pa: float
    mu1_pa_s: float
    log_rms: float
    time_s: FloatArray
    resistance_ohm: FloatArray
    #: standard errors of ln E0, ln E1, ln mu1 (relative errors) from the fit's Jacobian
    rel_sigma: tuple[float, float, float] = (math.nan, math.nan, math.nan)


@dataclass(frozen=True)
class LinearLaw:
    """value(F) = intercept + slope * F (the paper's eq. 19 form)."""

    intercept: float
    slope: float

    def __call__(self, force_n: FloatArray | float) -> FloatArray:
        return np.asarray(self.intercept + self.slope * np.asarray(force_n))


@dataclass(frozen=True)
class PaperResult:
    holds: tuple[HoldFit, ...]
    e0: LinearLaw
    e1: LinearLaw
    mu1: LinearLaw
    line: LineCurve
    staircase_force_n: FloatArray
    staircase_resistance_ohm: FloatArray
    fitted: SensorParams
    true: SensorParams


def _holds(channel: ChannelRecord, level_n: float) -> tuple[FloatArray, FloatArray, float]:
    """Time since the first sample, resistance, and the sampling gap before the hold.

    The step happened somewhere between the last sample before the hold and its first
    sample; that gap bounds the unknown onset. Leading samples of the hold that read open
    were taken before the step (their reference force was read after it: the two blocks are
    separate Modbus requests), so the hold starts at its first finite reading.
    """
    assert channel.force_n is not None
    at = np.abs(channel.force_n - level_n) < 1e-6
    idx = np.flatnonzero(at)
    if idx.size < 10:
        raise ValueError(f"the record has no hold at {level_n:g} N")
    breaks = np.flatnonzero(np.diff(idx) > 1)
    first = idx[: breaks[0] + 1] if breaks.size else idx
    if first[0] == 0:
        raise ValueError(
            f"the record starts inside the {level_n:g} N hold: the load step's time is unknown "
            "(start recording before the first load)"
        )
    # a reading taken across the step (reference already at the level, resistance still
    # open) belongs before the step: the step happened after it
    lead = int(np.argmax(np.isfinite(channel.resistance_ohm[first])))
    first = first[lead:]
    t = channel.time_s[first]
    r = channel.resistance_ohm[first]
    gap = float(t[0] - channel.time_s[first[0] - 1]) if first[0] > 0 else 0.0
    ok = np.isfinite(r)
    return t[ok] - t[0], r[ok], gap


def fit_hold(channel: ChannelRecord, level_n: float, known: SensorParams) -> HoldFit:
    """Fit constant E0, E1, mu1 at one force to its creep test with eq. 17.

    The load step's exact time is unknown between two samples, so the onset is a fourth
    parameter bounded by that sampling gap.
    """
    t, r, gap = _holds(channel, level_n)
    base = replace(known, e0_slope_pa_per_n=0.0, e1_slope_pa_per_n=0.0, mu1_slope_pa_s_per_n=0.0)

    def model_r(x: FloatArray) -> FloatArray:
        p = replace(
            base,
            e0_pa=known.e0_pa * math.exp(x[0]),
            e1_pa=known.e1_pa * math.exp(x[1]),
            mu1_pa_s=known.mu1_pa_s * math.exp(x[2]),
        )
        return SensorModel(PAPER_EFFECTS, p).held_step(np.full(t.size, level_n), t + x[3]).total_ohm

    def residual(x: FloatArray) -> FloatArray:
        return np.asarray(np.log(r) - np.log(model_r(x)))

    lower = np.array([-5.0, -5.0, -5.0, 0.0])
    upper = np.array([5.0, 5.0, 5.0, max(gap, 1e-9)])
    fit = least_squares(residual, np.array([0.0, 0.0, 0.0, gap / 2]), bounds=(lower, upper), x_scale="jac")
    sd = _hold_sigma(residual, fit.x, fit.fun, gap)
    return HoldFit(
        force_n=level_n,
        e0_pa=known.e0_pa * math.exp(fit.x[0]),
        e1_pa=known.e1_pa * math.exp(fit.x[1]),
        mu1_pa_s=known.mu1_pa_s * math.exp(fit.x[2]),
        log_rms=float(np.sqrt(np.mean(fit.fun**2))),
        time_s=t + fit.x[3],
        resistance_ohm=r,
        rel_sigma=(float(sd[0]), float(sd[1]), float(sd[2])),
    )


def _hold_sigma(
    residual: Callable[[FloatArray], FloatArray], x: FloatArray, fun: FloatArray, gap: float
) -> FloatArray:
    """Standard errors of ln E0, ln E1, ln mu1: the noise's (Jacobian at the fit, onset held)
    and the onset's, which the data barely pin down inside the sampling gap: the moduli refitted
    with the onset at either end of the gap, their spread taken as uniform (range / sqrt 12)."""
    n = fun.size
    dof = max(n - 4, 1)
    s2 = float(fun @ fun) / dof
    jac = np.empty((n, 3))
    for i in range(3):
        up, down = x.copy(), x.copy()
        up[i] += 1e-5
        down[i] -= 1e-5
        jac[:, i] = (residual(up) - residual(down)) / 2e-5
    noise_var = np.diag(np.linalg.pinv(jac.T @ jac)) * s2
    ends = []
    for onset in (0.0, max(gap, 1e-9)):

        def at_onset(y: FloatArray, onset: float = onset) -> FloatArray:
            return residual(np.array([y[0], y[1], y[2], onset]))

        box = (np.full(3, -5.0), np.full(3, 5.0))
        ends.append(least_squares(at_onset, x[:3], bounds=box, x_scale="jac").x)
    onset_var = ((ends[1] - ends[0]) / math.sqrt(12.0)) ** 2
    return np.asarray(np.sqrt(np.clip(noise_var, 0.0, None) + onset_var))


def _line(x: FloatArray, y: FloatArray) -> LinearLaw:
    slope, intercept = np.polyfit(x, y, 1)
    return LinearLaw(float(intercept), float(slope))


def staircase_points(channel: ChannelRecord, settle_s: float = 2.0) -> tuple[FloatArray, FloatArray]:
    """(force, resistance) early in each loaded step of a staircase (median over 2 s)."""
    assert channel.force_n is not None
    f, t, r = channel.force_n, channel.time_s, channel.resistance_ohm
    starts = np.flatnonzero(np.diff(f, prepend=-1.0) != 0.0)
    forces, resist = [], []
    for s in starts:
        if f[s] <= 0.0:
            continue
        window = (t >= t[s]) & (t <= t[s] + settle_s) & (f == f[s]) & np.isfinite(r)
        if np.count_nonzero(window) >= 1:
            forces.append(float(f[s]))
            resist.append(float(np.median(r[window])))
    return np.array(forces), np.array(resist)


def analyze(creep: ChannelRecord, staircase: ChannelRecord, true: SensorParams) -> PaperResult:
    """Fit the creep tests and the staircase; R0 and the contact coefficient are known."""
    holds = tuple(fit_hold(creep, level, true) for level in CREEP_FORCES_N)
    forces = np.array([h.force_n for h in holds])
    e0 = _line(forces, np.array([h.e0_pa for h in holds]))
    e1 = _line(forces, np.array([h.e1_pa for h in holds]))
    mu1 = _line(forces, np.array([h.mu1_pa_s for h in holds]))
    sf, sr = staircase_points(staircase)
    fitted = replace(
        true,
        e0_pa=e0.intercept,
        e0_slope_pa_per_n=max(e0.slope, 0.0),
        e1_pa=e1.intercept,
        e1_slope_pa_per_n=max(e1.slope, 0.0),
        mu1_pa_s=mu1.intercept,
        mu1_slope_pa_s_per_n=max(mu1.slope, 0.0),
    )
    return PaperResult(holds, e0, e1, mu1, LineCurve.fit_conductance(sf, sr), sf, sr, fitted, true)


def write_outputs(result: PaperResult, out_dir: Path, source: str) -> list[Path]:
    """PNGs of Fig. 5, 6b, 9, 10 and ``summary.md`` with fitted and true numbers."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out_dir.mkdir(parents=True, exist_ok=True)
    written: list[Path] = []
    fitted_model = SensorModel(PAPER_EFFECTS, result.fitted)

    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(10, 4))
    ax1.plot(result.staircase_force_n, result.staircase_resistance_ohm / 1e3, "o", label="measured")
    grid = np.linspace(0.3, max(5.0, float(result.staircase_force_n.max(initial=5.0))), 100)
    ax1.plot(grid, fitted_model.held_step(grid, 0.0).total_ohm / 1e3, "-", label="model")
    ax1.set(xlabel="force (N)", ylabel="resistance (kΩ)", title="Fig. 5a")
    ax1.legend()
    ax2.plot(result.staircase_force_n, 1e6 / result.staircase_resistance_ohm, "o", label="measured")
    ax2.plot(grid, 1e6 * result.line.conductance(grid), "--", label="C = m F + n")
    ax2.set(xlabel="force (N)", ylabel="conductance (µS)", title="Fig. 5b")
    ax2.legend()
    fig.tight_layout()
    written.append(save_figure(fig, out_dir / "fig5_force_resistance_conductance.png"))
    plt.close(fig)

    forces = np.array([h.force_n for h in result.holds])
    fig, axes = plt.subplots(1, 3, figsize=(13, 4))
    for ax, name, law, values, true_law in (
        (
            axes[0],
            "E0 (MPa)",
            result.e0,
            [h.e0_pa for h in result.holds],
            LinearLaw(result.true.e0_pa, result.true.e0_slope_pa_per_n),
        ),
        (
            axes[1],
            "E1 (MPa)",
            result.e1,
            [h.e1_pa for h in result.holds],
            LinearLaw(result.true.e1_pa, result.true.e1_slope_pa_per_n),
        ),
        (
            axes[2],
            "mu1 (GPa s)",
            result.mu1,
            [h.mu1_pa_s for h in result.holds],
            LinearLaw(result.true.mu1_pa_s, result.true.mu1_slope_pa_s_per_n),
        ),
    ):
        scale = 1e9 if "GPa" in name else 1e6
        ax.plot(forces, np.array(values) / scale, "o", label="fitted per force")
        fgrid = np.linspace(0.0, 9.0, 10)
        ax.plot(fgrid, law(fgrid) / scale, "-", label="least-squares line")
        ax.plot(fgrid, true_law(fgrid) / scale, ":", label="simulator truth")
        ax.set(xlabel="force (N)", ylabel=name)
        ax.legend(fontsize=8)
    fig.suptitle("Fig. 6b: viscoelastic coefficients from the creep tests")
    fig.tight_layout()
    written.append(save_figure(fig, out_dir / "fig6b_viscoelastic_coefficients.png"))
    plt.close(fig)

    fig, ax = plt.subplots(figsize=(7, 5))
    for h in result.holds:
        ax.semilogy(h.time_s, h.resistance_ohm, ".", ms=2, label=f"measured {h.force_n:g} N")
        model_r = fitted_model.held_step(np.full(h.time_s.size, h.force_n), h.time_s).total_ohm
        ax.semilogy(h.time_s, model_r, "k-", lw=1)
    ax.set(
        xlabel="time since the load step (s)",
        ylabel="resistance (Ω)",
        title="Fig. 9b: model (lines) vs record",
    )
    ax.legend(fontsize=8)
    fig.tight_layout()
    written.append(save_figure(fig, out_dir / "fig9b_creep_model_vs_record.png"))
    plt.close(fig)

    ff, tt = np.meshgrid(np.linspace(0.5, 8.0, 40), np.linspace(0.0, 600.0, 40))
    rr = fitted_model.held_step(ff.ravel(), tt.ravel()).total_ohm.reshape(ff.shape)
    fig = plt.figure(figsize=(7, 5))
    ax3 = fig.add_subplot(projection="3d")
    ax3.plot_surface(ff, tt, np.log10(rr), cmap="viridis")
    ax3.set(xlabel="force (N)", ylabel="time (s)", zlabel="log10 R (Ω)", title="Fig. 10")
    fig.tight_layout()
    written.append(save_figure(fig, out_dir / "fig10_surface.png"))
    plt.close(fig)

    t = result.true
    lines = [
        "# The paper's experiments, replayed on the simulated array",
        "",
        f"Records: {source}. R0 = {t.r0_ohm:.4g} ohm and rho2 = {t.rho2_ohm_m:.4g} ohm m are taken as known;",
        "E0, E1 and mu1 are fitted per creep test with eq. 17 and then as lines in force (eq. 19);",
        "sigma: each one's standard error from the fit (how well the record's sampling and noise",
        "pin it down).",
        "",
        "## Per-force coefficients (Fig. 6b)",
        "",
        "| force (N) | E0 fitted (MPa) | E0 true | E1 fitted (MPa) | E1 true | mu1 fitted (GPa s) | mu1 true "
        "| log-R RMS | E0 sigma (%) | E1 sigma (%) | mu1 sigma (%) |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for h in result.holds:
        f = h.force_n
        lines.append(
            f"| {f:g} | {h.e0_pa / 1e6:.3f} | {(t.e0_pa + t.e0_slope_pa_per_n * f) / 1e6:.3f} | "
            f"{h.e1_pa / 1e6:.2f} | {(t.e1_pa + t.e1_slope_pa_per_n * f) / 1e6:.2f} | "
            f"{h.mu1_pa_s / 1e9:.2f} | {(t.mu1_pa_s + t.mu1_slope_pa_s_per_n * f) / 1e9:.2f} | "
            f"{h.log_rms:.4f} | {100 * h.rel_sigma[0]:.2f} | {100 * h.rel_sigma[1]:.2f} | "
            f"{100 * h.rel_sigma[2]:.2f} |"
        )
    laws = (
        ("E0 (Pa)", result.e0, t.e0_pa, t.e0_slope_pa_per_n),
        ("E1 (Pa)", result.e1, t.e1_pa, t.e1_slope_pa_per_n),
        ("mu1 (Pa s)", result.mu1, t.mu1_pa_s, t.mu1_slope_pa_s_per_n),
    )
    line_error = np.abs(result.line.force(result.staircase_resistance_ohm) - result.staircase_force_n)
    lines += [
        "",
        "## Lines in force (eq. 19)",
        "",
        "| coefficient | fitted intercept | fitted slope (per N) | true intercept | true slope (per N) |",
        "|---|---|---|---|---|",
        *[
            f"| {name} | {law.intercept:.4g} | {law.slope:.4g} | {true_i:.4g} | {true_s:.4g} |"
            for name, law, true_i, true_s in laws
        ],
        "",
        "## Conductance calibration (eq. 18, Fig. 5b)",
        "",
        f"C = m F + n with m = {result.line.slope_s_per_n:.5g} S/N and n = {result.line.intercept_s:.5g} S; "
        f"worst force error of the line on the staircase: {float(line_error.max(initial=0.0)):.3f} N.",
        "",
        *[f"![{p.stem}]({p.name})" for p in written],
    ]
    summary = out_dir / "summary.md"
    atomic_write_text(summary, "\n".join(lines) + "\n")
    written.append(summary)
    return written
