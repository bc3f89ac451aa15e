"""The figure of ``mttbench reproduce kreucher``: OSPA against looks per step.

Reads the curve table of :func:`~mttbench.benchmarks.app.reproduce_kreucher.curve_table`
(one row per scenario, tracker, policy and looks) and draws; it runs nothing. Built on
the helpers of :mod:`~mttbench.benchmarks.app.figures` (plain Figure objects, no pyplot).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
from matplotlib.lines import Line2D
from matplotlib.ticker import NullFormatter

from .figures import _save, _subplots, tracker_colors

#: markers of the managed scans at their budget, in the order they appear
MANAGED_MARKERS = ("*", "D", "s", "^", "v")


def managed_vs_periodic(curve: pd.DataFrame, path: str | Path, n_cells: int | None = None
                        ) -> Path:
    """One panel per scenario (SNR): each tracker's raster curve (OSPA against looks per
    step, log axis; median solid, mean dashed) in its colour, and each managed scan as a
    horizontal line at its median (solid) and mean (dashed) with a marker at its budget.
    A dotted vertical line marks ``n_cells`` (beyond it the raster revisits cells)."""
    scs = list(dict.fromkeys(curve.sort_values("snr")["scenario"])) if len(curve) else []
    n = max(len(scs), 1)
    fig, axes = _subplots(1, n, figsize=(5.2 * n, 4.2), layout="constrained", sharey=True)
    colors = tracker_colors(sorted(set(curve["tracker"]))) if len(curve) else {}
    managed = sorted(set(curve.loc[curve["kind"] == "managed", "policy"])) if len(curve) else []
    marker = {p: MANAGED_MARKERS[i % len(MANAGED_MARKERS)] for i, p in enumerate(managed)}
    looks_ticks = sorted(set(curve["looks"])) if len(curve) else []
    for ax, sc in zip(axes[0], scs, strict=False):
        g = curve[curve["scenario"] == sc]
        for tracker, t in g.groupby("tracker", sort=True):
            col = colors[tracker]
            r = t[t["kind"] == "periodic"].sort_values("looks")
            ax.plot(r["looks"], r["ospa_median"], "-o", color=col, ms=4, lw=1.6)
            ax.plot(r["looks"], r["ospa_mean"], "--o", color=col, ms=3, lw=1.2, mfc="none")
            for m in t[t["kind"] == "managed"].itertuples():
                ax.axhline(m.ospa_median, color=col, lw=0.9, ls="-", alpha=0.6)
                ax.axhline(m.ospa_mean, color=col, lw=0.9, ls="--", alpha=0.6)
                ax.plot([m.looks], [m.ospa_median], marker[m.policy], color=col, ms=10,
                        mec="black", mew=0.5)
                ax.plot([m.looks], [m.ospa_mean], marker[m.policy], color=col, ms=8,
                        mfc="none")
        if n_cells is not None:
            ax.axvline(n_cells, color="0.5", lw=0.8, ls=":")
            ax.annotate("revisits →", (n_cells, 1.0), xycoords=("data", "axes fraction"),
                        xytext=(3, -12), textcoords="offset points", fontsize=8, color="0.4")
        ax.set_xscale("log")
        ax.set_xticks(looks_ticks)
        ax.set_xticklabels([str(v) for v in looks_ticks])
        ax.xaxis.set_minor_formatter(NullFormatter())
        snr = g["snr"].iloc[0]
        ax.set_title(f"{sc} (snr {snr:g})" if np.isfinite(snr) else sc, fontsize=10)
        ax.set_xlabel("looks per step")
        ax.grid(alpha=0.3, which="both")
    axes[0][0].set_ylabel("OSPA (cells), steps after burn-in")
    handles = [Line2D([], [], color=colors[t], lw=2, label=t) for t in colors]
    handles += [Line2D([], [], color="black", lw=1.6, ls="-", label="median over seeds"),
                Line2D([], [], color="black", lw=1.2, ls="--", label="mean over seeds"),
                Line2D([], [], color="black", marker="o", ls="", label="raster (periodic)")]
    handles += [Line2D([], [], color="black", marker=marker[p], ls="", ms=9,
                       label=f"{p} (managed; line: its level)") for p in managed]
    if handles:
        fig.legend(handles=handles, loc="outside lower center", fontsize=8,
                   ncol=min(len(handles), 4))
    try:
        return _save(fig, path)
    finally:
        fig.clear()
