"""The calibration figure's R(F) panel counts its loading, holding and unloading rows as the
report's loading-direction table does (issue 33 §17: the counts disagreed)."""

from __future__ import annotations

import re

import numpy as np
from power_law_fsr import clean_record

from gateway.analysis.calibration_plots import _plt, draw_panels
from gateway.analysis.candidates import rank_candidates
from gateway.analysis.diagnostics import residual_structure
from gateway.analysis.discrepancy import prepare
from gateway.analysis.discrepancy_static import curve_fit


def test_the_r_of_f_legend_counts_the_rows_of_the_direction_table() -> None:
    channel, metadata = clean_record(1)
    data, _, _ = prepare(channel, metadata, None)
    fit = curve_fit(data, rank_candidates(data, kinds=("power_law",), forms=("creep",))[0], ("creep",))
    table = {
        b.label: b.n_rows
        for b in next(a for a in residual_structure(data, fit).axes if a.name == "direction").bins
    }
    plt = _plt()
    fig, axes = plt.subplots(1, 4)
    try:
        draw_panels(data, fit, {}, axes, True)
        legend = [line.get_label() for line in axes[0].get_lines()]
    finally:
        plt.close(fig)
    shown = {}
    for label in legend:
        found = re.fullmatch(r"(loading|holding|unloading) \(n=(\d+)\)", label)
        if found:
            shown[f"while {found.group(1)}"] = int(found.group(2))
    assert shown == table
    # the record loads, holds and unloads: all three are drawn, and they are distinct rows
    assert set(shown) == {"while loading", "while holding", "while unloading"}
    assert sum(shown.values()) <= int(np.count_nonzero(data.usable))
