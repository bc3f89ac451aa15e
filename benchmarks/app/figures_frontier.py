"""The figure of ``mttbench frontier``: OSPA against CPU time per step as budgets grow.

Reads the table of :func:`~mttbench.benchmarks.app.frontier.frontier_table` (one row per
scenario, tracker and budget) and draws; it runs nothing. Built on the helpers of
:mod:`~mttbench.benchmarks.app.figures` (plain Figure objects, no pyplot).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import matplotlib as mpl
import numpy as np
import pandas as pd

from .figures import _save, _subplots

#: a marker per tracker, cycled with the colours so that 20 trackers stay apart
MARKERS = ("o", "s", "^", "D", "v", "P", "X", "*", "h", "<", ">", "p")


def tracker_styles(names: Sequence[str]) -> dict[str, tuple[tuple, str]]:
    """``{name: (colour, marker)}`` in the given order: tab20's dark shades first, then
    its light ones (20 distinct colours), and the marker cycle beside them, so no two of
    the first 20 trackers share a colour and no two neighbours a marker."""
    cmap = mpl.colormaps["tab20"]
    shades = [cmap(2 * i) for i in range(10)] + [cmap(2 * i + 1) for i in range(10)]
    return {n: (shades[i % 20], MARKERS[i % len(MARKERS)]) for i, n in enumerate(names)}


def _budget_label(value: object) -> str:
    if isinstance(value, float) and not np.isfinite(value):
        return ""
    v = float(value)  # type: ignore[arg-type]
    return f"{v:g}" if v < 1e4 else f"{v / 1e3:g}k"


def frontier_figure(table: pd.DataFrame, scenario: str, path: str | Path, *,
                    reference: Any = None,
                    order: Sequence[str] | None = None) -> Path:
    """One scenario's frontier: mean OSPA (95% interval bars) against mean CPU ms per
    step (log axis), one line per tracker through its budgets (each point labelled with
    its budget), the Pareto front across trackers as a black step line, and the
    ``reference`` (when given: a :class:`~mttbench.benchmarks.app.frontier.Reference`,
    its ``mean``, ``ci95`` and ``label``) as a horizontal line with its 95% band."""
    here = table[table["scenario"] == scenario]
    names = list(order) if order else list(dict.fromkeys(here["tracker"]))
    styles = tracker_styles(names)
    fig, axes = _subplots(1, 1, figsize=(7.5, 5.0), layout="constrained")
    ax = axes[0][0]
    for name in names:
        g = here[(here["tracker"] == name) & np.isfinite(here["ospa_mean"].astype(float))]
        if g.empty:
            continue
        g = g.sort_values("cpu_ms_mean")
        colour, marker = styles[name]
        param = g["budget_param"].iloc[0]
        ax.errorbar(g["cpu_ms_mean"], g["ospa_mean"], yerr=g["ospa_ci95"].fillna(0.0),
                    color=colour, marker=marker, ms=6, lw=1.4, capsize=3,
                    label=f"{name} ({param})" if param else f"{name} (one setting)")
        if param:
            for _, r in g.iterrows():
                ax.annotate(_budget_label(r["budget"]), (r["cpu_ms_mean"], r["ospa_mean"]),
                            textcoords="offset points", xytext=(4, 4), fontsize=7,
                            color=colour)
    front = here[here["pareto"].astype(bool)].sort_values("cpu_ms_mean")
    if len(front):
        ax.step(front["cpu_ms_mean"], front["ospa_mean"], where="post", color="black",
                lw=1.2, ls="--", alpha=0.9, label="Pareto front", zorder=3)
    if reference is not None and np.isfinite(reference.mean):
        ax.axhline(reference.mean, color="0.25", lw=1.2, ls=":",
                   label=f"{reference.label} (reference)")
        if np.isfinite(reference.ci95):
            ax.axhspan(reference.mean - reference.ci95, reference.mean + reference.ci95,
                       color="0.5", alpha=0.15, lw=0)
    ax.set_xscale("log")
    ax.set_xlabel("tracker CPU ms per step (mean over steps, then seeds)")
    ax.set_ylabel("mean OSPA (95% interval over seeds)")
    ax.set_title(f"{scenario}: accuracy against cost (lower left is better)", fontsize=10)
    ax.grid(alpha=0.3, which="both")
    fig.legend(fontsize=8, loc="outside right upper")
    return _save(fig, path)
