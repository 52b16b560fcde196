"""Figures that replay the paper from the model (matplotlib, written atomically)."""

from __future__ import annotations

import io
from pathlib import Path
from typing import Any

import numpy as np

from ..atomic import atomic_write_bytes
from ..model import SensorModel


def save_figure(fig: Any, path: Path) -> Path:
    """Save a matplotlib figure atomically, with the permission bits a CSV written beside it
    gets (``atomic_write_bytes``: a new file 0666 minus the umask, a replaced one keeps its)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=110)
    atomic_write_bytes(path, buffer.getvalue())
    return path


def plot_model_figures(model: SensorModel, out_dir: Path) -> list[Path]:
    """Fig. 5 (force vs resistance and conductance), Fig. 9b (R vs t), Fig. 10 (surface)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    single = SensorModel(model.effects, model.params.channel(0))
    written: list[Path] = []
    force = np.linspace(0.2, 5.0, 200)
    r = single.held_step(force[:, None], 0.0).total_ohm[:, 0]
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(10, 4))
    ax1.plot(force, r / 1e3)
    ax1.set(xlabel="force (N)", ylabel="resistance (kΩ)", title="Fig. 5a: force-resistance")
    ax2.plot(force, 1e6 / r)
    slope, intercept = np.polyfit(force, 1.0 / r, 1)
    ax2.plot(force, 1e6 * (slope * force + intercept), "--", label="C = m F + n")
    ax2.set(xlabel="force (N)", ylabel="conductance (µS)", title="Fig. 5b: force-conductance")
    ax2.legend()
    fig.tight_layout()
    written.append(save_figure(fig, out_dir / "fig5_force_resistance.png"))
    plt.close(fig)

    t = np.linspace(0.0, 600.0, 301)
    fig, ax = plt.subplots(figsize=(6, 4))
    for f in (0.5, 1.0, 2.0, 5.0, 8.0):
        ax.semilogy(
            t, single.held_step(np.full((t.size, 1), f), t[:, None]).total_ohm[:, 0], label=f"{f:g} N"
        )
    ax.set(xlabel="time (s)", ylabel="resistance (Ω)", title="Fig. 9b: creep at held forces")
    ax.legend()
    fig.tight_layout()
    written.append(save_figure(fig, out_dir / "fig9b_resistance_time.png"))
    plt.close(fig)

    ff, tt = np.meshgrid(np.linspace(0.5, 5.0, 40), np.linspace(0.0, 600.0, 40))
    rr = single.held_step(ff.reshape(-1, 1), tt.reshape(-1, 1)).total_ohm.reshape(ff.shape)
    fig = plt.figure(figsize=(7, 5))
    ax3 = fig.add_subplot(projection="3d")
    ax3.plot_surface(ff, tt, np.log10(rr), cmap="viridis")
    ax3.set(xlabel="force (N)", ylabel="time (s)", zlabel="log10 R (Ω)", title="Fig. 10: R(F, t)")
    fig.tight_layout()
    written.append(save_figure(fig, out_dir / "fig10_surface.png"))
    plt.close(fig)
    return written
