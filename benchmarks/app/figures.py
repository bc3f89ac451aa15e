"""Figures: one small function per figure; each reads tables and draws (runs cached apart).

Every function takes tidy data (the results table, a summary, or the frames of a
:class:`benchmarks.engine.snapshot.Trace`), writes one PNG to ``path`` and returns it. No
function runs a tracker. Figures are built as :class:`matplotlib.figure.Figure` objects,
never through pyplot, so drawing neither switches the process's backend nor leaves
figures open.

Confidence bands are 95% Student-t intervals over seeds at each step::

    mean_k +- t_{0.975, n-1} * sd_k / sqrt(n)      (sd with ddof = 1, n seeds)
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import matplotlib as mpl
import numpy as np
import pandas as pd
from matplotlib.axes import Axes
from matplotlib.figure import Figure
from matplotlib.layout_engine import ConstrainedLayoutEngine
from matplotlib.lines import Line2D
from matplotlib.patches import Ellipse, Rectangle
from scipy import stats

from . import summary as _summary

#: chi-square(2) 95% quantile: a 2-D Gaussian puts 95% of its mass inside this ellipse
ELLIPSE_CHI2 = float(stats.chi2.ppf(0.95, 2))
DPI = 110


#: tab20's strong colours first, then their light partners: 20 colours
_COLOR_ORDER = (*range(0, 20, 2), *range(1, 20, 2))
#: 12 markers (coprime with nothing above 60 trackers: colour and marker together repeat
#: only after lcm(20, 12) = 60 labels)
MARKERS = ("o", "s", "^", "D", "v", "P", "X", "<", ">", "h", "*", "p")


def tracker_styles(labels: list[str]) -> dict[str, tuple[tuple, str]]:
    """A fixed ``(colour, marker)`` per tracker label, in sorted order: up to 12 labels
    each has a colour and a marker of its own; up to 60, no two share both."""
    cmap = mpl.colormaps["tab20"]
    return {lab: (cmap(_COLOR_ORDER[i % 20]), MARKERS[i % len(MARKERS)])
            for i, lab in enumerate(sorted(set(labels)))}


def tracker_colors(labels: list[str]) -> dict[str, tuple]:
    """The colour of :func:`tracker_styles` per tracker label."""
    return {lab: style[0] for lab, style in tracker_styles(labels).items()}


def step_stats(results: pd.DataFrame, metric: str,
               by: tuple[str, ...] = ("scenario", "tracker_label")) -> pd.DataFrame:
    """Per ``by`` and step: ``mean``, ``ci95`` (t half-width over seeds) and ``n`` of ``metric``.

    Only ``status == "ok"`` rows with a finite value count.
    """
    ok = results[(results["status"] == "ok") & np.isfinite(results[metric].astype(float))]
    g = ok.groupby([*by, "step"], sort=True)[metric]
    out = g.agg(mean="mean", sd="std", n="count").reset_index()  # sd: ddof 1
    t = stats.t.ppf(0.975, np.maximum(out["n"] - 1, 1))
    out["ci95"] = np.where(out["n"] > 1, t * out["sd"] / np.sqrt(out["n"]), np.nan)
    return out.drop(columns="sd")


def _save(fig: Figure, path: str | Path) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    # a constrained layout keeps every artist inside the figure already; "tight" would
    # draw the figure a second time to measure it (a fifth of a report's drawing time)
    constrained = isinstance(fig.get_layout_engine(), ConstrainedLayoutEngine)
    fig.savefig(path, dpi=DPI, bbox_inches=None if constrained else "tight")
    return path


def _subplots(rows: int, cols: int, **kwargs: Any) -> tuple[Figure, np.ndarray]:
    """``(figure, axes (rows, cols))`` without pyplot (a plain Figure renders with Agg)."""
    fig = Figure(figsize=kwargs.pop("figsize", None), layout=kwargs.pop("layout", None))
    return fig, fig.subplots(rows, cols, squeeze=False, **kwargs)


def _grid_of_axes(n: int, width: float = 4.2, height: float = 3.2):
    cols = min(n, 2) if n > 1 else 1
    rows = math.ceil(n / cols)
    fig, axes = _subplots(rows, cols, figsize=(width * cols, height * rows),
                          layout="constrained")
    for ax in axes.flat[n:]:
        ax.set_visible(False)
    return fig, list(axes.flat[:n])


def _legend_below(fig: Figure, axes: list[Axes]) -> None:
    """One legend for all panels, below them (``loc="best"`` is slow with many artists)."""
    seen: dict[str, Any] = {}
    for ax in axes:
        for h, lab in zip(*ax.get_legend_handles_labels(), strict=True):
            seen.setdefault(lab, h)
    if seen:
        fig.legend(list(seen.values()), list(seen), loc="outside lower center", fontsize=8,
                   ncol=min(len(seen), 4))


def metric_over_time(results: pd.DataFrame, metric: str, path: str | Path,
                     ylabel: str | None = None, title: str | None = None) -> Path:
    """``metric`` against step, one panel per scenario, one line per tracker:
    mean over seeds with a shaded 95% band. ``title`` (default ``ylabel``) heads the
    figure. Trackers without a finite value (e.g. a track score of a tracker without
    labels) draw no line."""
    st = step_stats(results, metric)
    scen = sorted(st["scenario"].unique())
    styles = tracker_styles(list(results["tracker_label"].unique()))
    truth, _ = _summary.truth_labels(results)
    fig, axes = _grid_of_axes(max(len(scen), 1))
    for ax, sc in zip(axes, scen, strict=False):
        for lab, g in st[st["scenario"] == sc].groupby("tracker_label", sort=True):
            c, marker = styles[lab]
            ax.plot(g["step"], g["mean"], color=c, lw=1.4, label=_summary.mark_truth(lab, truth),
                    ls=_line_style(lab), marker=marker, ms=4,
                    markevery=max(1, len(g) // 8))
            lo, hi = g["mean"] - g["ci95"].fillna(0), g["mean"] + g["ci95"].fillna(0)
            ax.fill_between(g["step"], lo, hi, color=c, alpha=0.2, lw=0)
        ax.set_title(sc)
        ax.set_xlabel("step")
        ax.set_ylabel(ylabel or metric)
        ax.grid(alpha=0.3)
    _legend_below(fig, axes)
    fig.suptitle(f"{title or ylabel or metric}: mean over seeds, shaded 95% interval",
                 fontsize=10)
    return _save(fig, path)


def _line_style(label: str) -> str:
    """Dashed for the floor (``null``), dotted for the ceiling (``truth-aided``)."""
    name = _summary.tracker_name(label)
    return {_summary.FLOOR_TRACKER: "--", _summary.CEILING_TRACKER: ":"}.get(name, "-")


def runtime_per_step(runs: pd.DataFrame, path: str | Path) -> Path:
    """Per-run median tracker time per step (ms, log scale): one dot per run, grouped
    by tracker, one panel per scenario; a bar marks the mean over runs."""
    ok = runs[runs["status"] == "ok"]
    scen = sorted(ok["scenario"].unique())
    labels = sorted(runs["tracker_label"].unique())
    styles = tracker_styles(labels)
    fig, axes = _grid_of_axes(max(len(scen), 1))
    for ax, sc in zip(axes, scen, strict=False):
        g = ok[ok["scenario"] == sc]
        drawn = False
        for i, lab in enumerate(labels):
            ms = g.loc[g["tracker_label"] == lab, "tracker_wall_s"].to_numpy(float) * 1e3
            ms = ms[ms > 0]  # NaN: a time not known (a tracker scored outside)
            if ms.size == 0:
                continue
            jitter = np.linspace(-0.15, 0.15, ms.size) if ms.size > 1 else np.zeros(1)
            ax.scatter(i + jitter, ms, s=12, color=styles[lab][0], marker=styles[lab][1],
                       alpha=0.7)
            ax.hlines(ms.mean(), i - 0.3, i + 0.3, color="k", lw=1.5)
            drawn = True
        ax.set_xticks(range(len(labels)), labels, rotation=30, ha="right", fontsize=7)
        if drawn:  # a log axis without a positive value cannot be drawn
            ax.set_yscale("log")
        ax.set_ylabel("ms per step")
        ax.set_title(sc)
        ax.grid(alpha=0.3, axis="y")
    fig.suptitle("tracker time per step (median per run; bar = mean over runs)", fontsize=10)
    return _save(fig, path)


def accuracy_vs_runtime(summary: pd.DataFrame, path: str | Path,
                        metric: str = "ospa") -> Path:
    """Mean ``metric`` against mean ms/step, one point per tracker label (tracker and
    parameter setting) with 95% error bars on both axes, one panel per scenario. The
    floor (``null``) and the ceiling (``truth-aided``, which uses the truth) are also
    drawn as horizontal dashed and dotted lines at their ``metric`` (the first policy
    and look budget of a panel when there are several)."""
    ok = summary[summary["n_seeds"] > 0]
    scen = sorted(ok["scenario"].unique())
    styles = tracker_styles(list(summary["tracker_label"].unique()))
    colors = {lab: style[0] for lab, style in styles.items()}
    truth, _ = _summary.truth_labels(summary)
    fig, axes = _grid_of_axes(max(len(scen), 1))
    for ax, sc in zip(axes, scen, strict=False):
        here = ok[ok["scenario"] == sc]
        levels: set[str] = set()
        for _, r in here.iterrows():
            x, xe = r["tracker_wall_s_mean"] * 1e3, r["tracker_wall_s_ci95"] * 1e3
            y, ye = r[f"{metric}_mean"], r[f"{metric}_ci95"]
            lab = r["tracker_label"]
            ax.errorbar(x, y, xerr=None if np.isnan(xe) else xe,
                        yerr=None if np.isnan(ye) else ye, fmt=styles[lab][1], ms=6, capsize=2,
                        color=colors[lab], label=_summary.mark_truth(lab, truth))
            ls = _line_style(lab)
            if ls != "-" and np.isfinite(y) and lab not in levels:
                levels.add(lab)  # one line per floor or ceiling and panel
                ax.axhline(y, color=colors[lab], ls=ls, lw=1.0, alpha=0.8)
        ax.set_xscale("log")
        ax.set_xlabel("ms per step")
        ax.set_ylabel(f"mean {metric}")
        ax.set_title(sc)
        ax.grid(alpha=0.3)
    _legend_below(fig, axes)
    fig.suptitle("accuracy against runtime (lower-left is better), 95% intervals", fontsize=10)
    return _save(fig, path)


def gap_closed_shares(shares: pd.DataFrame, path: str | Path, column: str = "share",
                      style_labels: list[str] | None = None) -> Path:
    """Each contestant's (and the Bayes reference's) share of the gap closed, ``<column>_mean``
    with its 95% interval ``<column>_ci95``, one column of markers per scenario x policy x
    looks (a :class:`~.summary.GapClosed`'s ``shares``; floor and ceiling, 0 and 1 by
    definition, are the dashed lines). ``style_labels``: the labels the report's other
    figures style (so a tracker keeps its colour and marker), default those drawn."""
    sh = shares[~shares["role"].isin(("floor", "ceiling"))]
    keys = sh[_summary.GAP_GROUP].drop_duplicates().sort_values(_summary.GAP_GROUP)
    groups = [tuple(k) for k in keys.itertuples(index=False)]
    labels = sorted(sh["tracker_label"].astype(str).unique())
    styles = tracker_styles(sorted(set(labels) | set(style_labels or [])))
    fig, axes = _subplots(1, 1, figsize=(max(5.0, 1.1 * len(groups) + 2.5), 4.2),
                          layout="constrained")
    ax = axes[0, 0]
    width = 0.8 / max(len(labels), 1)
    for j, lab in enumerate(labels):
        mine = sh[sh["tracker_label"].astype(str) == lab]
        xs, ys, es = [], [], []
        for i, g in enumerate(groups):
            r = mine[np.logical_and.reduce([mine[k] == v for k, v in
                                            zip(_summary.GAP_GROUP, g, strict=True)])]
            if len(r) and np.isfinite(r[f"{column}_mean"].iloc[0]):
                xs.append(i - 0.4 + width * (j + 0.5))
                ys.append(r[f"{column}_mean"].iloc[0])
                es.append(r[f"{column}_ci95"].iloc[0])
        if xs:
            color, marker = styles[lab]
            ax.errorbar(xs, ys, yerr=np.nan_to_num(np.array(es, float)), fmt=marker, ms=6,
                        capsize=2, color=color, label=lab)
    ax.axhline(0.0, color="0.4", ls="--", lw=1.0)
    ax.axhline(1.0, color="0.4", ls=":", lw=1.0)
    ax.set_xticks(range(len(groups)))
    ax.set_xticklabels([str(g[0]) if len(keys["policy_label"].unique()) == 1
                        and len(keys["looks_per_step"].unique()) == 1
                        else f"{g[0]}\n{g[1]}, {g[2]}" for g in groups],
                       rotation=30, ha="right", fontsize=8)
    ax.set_ylabel("share of the gap closed" if column == "share"
                  else "share of the achievable gap")
    ax.grid(alpha=0.3, axis="y")
    _legend_below(fig, [ax])
    fig.suptitle("share of the gap closed: 0 = the floor (null), 1 = the ceiling "
                 "(truth-aided); 95% intervals", fontsize=10)
    return _save(fig, path)


def _cov_ellipse(px: float, py: float, cxx: float, cxy: float, cyy: float, **kw) -> Ellipse:
    """The 95% ellipse of N([px, py], [[cxx, cxy], [cxy, cyy]])."""
    vals, vecs = np.linalg.eigh(np.array([[cxx, cxy], [cxy, cyy]]))
    vals = np.clip(vals, 0.0, None)
    angle = math.degrees(math.atan2(vecs[1, 1], vecs[0, 1]))
    w, h = 2 * np.sqrt(ELLIPSE_CHI2 * vals[1]), 2 * np.sqrt(ELLIPSE_CHI2 * vals[0])
    return Ellipse((px, py), w, h, angle=angle, fill=False, **kw)


def draw_snapshot(ax: Axes, frames: dict[str, pd.DataFrame], step: int, nx: int, ny: int,
                  cell_size: float = 1.0, title: str = "", show_estimates: bool = True) -> None:
    """One step of a trace on ``ax``: grid, looked-at cells (light grey), positive
    returns (magenta squares), true targets (blue dots), estimates (black crosses) with
    95% covariance ellipses. ``frames`` as :meth:`Trace.frames`."""
    looks = frames["looks"][frames["looks"]["step"] == step]
    truth = frames["truth"][frames["truth"]["step"] == step]
    est = frames["estimates"][frames["estimates"]["step"] == step]
    for (ix, iy), g in looks.groupby(["ix", "iy"]):
        pos = bool(g["positive"].any())
        ax.add_patch(Rectangle((ix * cell_size, iy * cell_size), cell_size, cell_size,
                               facecolor="magenta" if pos else "0.85",
                               alpha=0.75 if pos else 0.6, lw=0))
    for i in range(nx + 1):
        ax.axvline(i * cell_size, color="0.7", lw=0.5)
    for j in range(ny + 1):
        ax.axhline(j * cell_size, color="0.7", lw=0.5)
    ax.plot(truth["px"], truth["py"], "o", color="blue", ms=6, label="true target")
    if show_estimates and len(est):
        ax.plot(est["px"], est["py"], "x", color="black", ms=7, mew=1.5, label="estimate")
        for _, r in est.iterrows():
            if np.isfinite(r["cov_xx"]):
                ax.add_patch(_cov_ellipse(r["px"], r["py"], r["cov_xx"], r["cov_xy"],
                                          r["cov_yy"], color="black", lw=0.9))
    ax.set_xlim(0, nx * cell_size)
    ax.set_ylim(0, ny * cell_size)
    ax.set_aspect("equal")
    if "counts" in frames:
        c = frames["counts"].loc[frames["counts"]["step"] == step, "count"]
        count = float(c.iloc[0]) if len(c) else float("nan")
    else:
        count = float(est["count"].iloc[0]) if len(est) else float("nan")
    extra = f"  true {len(truth)}, est. count {count:.2f}" if show_estimates else ""
    ax.set_title((title + f"  step {step}" + extra).strip(), fontsize=8)
    ax.tick_params(labelsize=7)


def snapshot(frames: dict[str, pd.DataFrame], path: str | Path, steps: list[int], nx: int,
             ny: int, cell_size: float = 1.0, title: str = "") -> Path:
    """Snapshot panels of a traced run at ``steps`` (see :func:`draw_snapshot`)."""
    fig, axes = _subplots(1, len(steps), figsize=(3.6 * len(steps), 3.9))
    for ax, k in zip(axes.flat, steps, strict=True):
        draw_snapshot(ax, frames, k, nx, ny, cell_size)
    handles = [
        Rectangle((0, 0), 1, 1, color="0.85", label="looked at, no return"),
        Rectangle((0, 0), 1, 1, color="magenta", alpha=0.75, label="positive return"),
        Line2D([], [], ls="", marker="o", color="blue", label="true target"),
        Line2D([], [], ls="", marker="x", color="black", label="estimate, 95% ellipse"),
    ]
    fig.legend(handles=handles, loc="lower center", ncol=4, fontsize=8,
               bbox_to_anchor=(0.5, -0.02))
    if title:
        fig.suptitle(title, fontsize=10)
    fig.tight_layout(rect=(0, 0.06, 1, 1))
    return _save(fig, path)


def paper_error_curves(curves: pd.DataFrame, path: str | Path, highlight: str = "gpf") -> Path:
    """The paper's "Simulation Result" figure: state error and count error against step.

    ``curves`` has columns ``tracker_label, step, state_error, count_error`` (means over
    seeds; optional ``state_error_ci95``/``count_error_ci95`` for bands). The
    ``highlight`` tracker is drawn as in the paper (state error black, count error red);
    the others are overlaid in thin coloured lines.
    """
    fig, axes = _subplots(1, 2, figsize=(9.5, 4.0), layout="constrained")
    axes = axes[0]
    labels = sorted(curves["tracker_label"].unique())
    styles = tracker_styles(labels)
    for ax, col, main in ((axes[0], "state_error", "black"), (axes[1], "count_error", "red")):
        for lab in labels:
            g = curves[curves["tracker_label"] == lab].sort_values("step")
            hl = lab == highlight or lab.startswith(highlight + "(")
            c = main if hl else styles[lab][0]
            ax.plot(g["step"], g[col], color=c, lw=2.2 if hl else 1.0,
                    alpha=1.0 if hl else 0.8, label=lab, marker=None if hl else styles[lab][1],
                    ms=3, markevery=max(1, len(g) // 8))
            if f"{col}_ci95" in g:
                half = g[f"{col}_ci95"].fillna(0)
                ax.fill_between(g["step"], g[col] - half, g[col] + half, color=c,
                                alpha=0.15 if hl else 0.08, lw=0)
        ax.set_xlabel("time step k")
        ax.grid(alpha=0.3)
    axes[0].set_ylabel("state error (OSPA, c = 2, p = 2)")
    axes[1].set_ylabel("target number error |N_est - N|")
    _legend_below(fig, [axes[0]])
    fig.suptitle("estimation error over time (mean over seeds, 95% band)", fontsize=10)
    return _save(fig, path)
