"""Every tracker of a report has a colour and a marker of its own in every figure."""

from __future__ import annotations

import itertools

import numpy as np
import pandas as pd
from matplotlib.colors import to_rgba

from mttbench.benchmarks.app import figures
from mttbench.trackers import base

#: a report of every shipped tracker plus two settings of one (make compare's 12 labels)
LABELS = sorted([*base.available(), "jmpd(n_particles=1000)", "gpf(epsilon=0.001)"])


def test_styles_are_unique():
    """No two labels share colour and marker; up to 12 labels none shares either."""
    styles = figures.tracker_styles(LABELS)
    pairs = [(to_rgba(c), m) for c, m in styles.values()]
    assert len(set(pairs)) == len(LABELS)
    first12 = list(styles.values())[:12]
    assert len({to_rgba(c) for c, _ in first12}) == len(first12)
    assert len({m for _, m in first12}) == len(first12)
    many = figures.tracker_styles([f"t{i:02d}" for i in range(60)])
    assert len({(to_rgba(c), m) for c, m in many.values()}) == 60


def _drawn(monkeypatch, draw) -> dict[str, tuple]:
    """(colour, marker) of each legend entry of the figure ``draw`` saves."""
    saved = {}
    monkeypatch.setattr(figures, "_save", lambda fig, path: saved.setdefault("fig", fig))
    draw()
    fig = saved["fig"]
    out = {}
    for ax in fig.axes:
        for h, lab in zip(*ax.get_legend_handles_labels(), strict=True):
            line = h[0] if isinstance(h, tuple) else getattr(h, "lines", [h])[0]
            out[lab] = (to_rgba(line.get_color()), line.get_marker())
    return out


def test_figures_draw_each_tracker_apart(monkeypatch):
    """The accuracy-against-runtime and metric-over-time figures of 12 trackers: 12
    legend entries, no two with the same colour and marker."""
    rows = [{"scenario": "default", "tracker_label": lab, "n_seeds": 3,
             "tracker_wall_s_mean": 1e-3 * (i + 1), "tracker_wall_s_ci95": 1e-4,
             "ospa_mean": 1.0 + 0.01 * i, "ospa_ci95": 0.05}
            for i, lab in enumerate(LABELS)]
    drawn = _drawn(monkeypatch, lambda: figures.accuracy_vs_runtime(pd.DataFrame(rows), "x"))
    results = pd.DataFrame([{"scenario": "default", "tracker_label": lab, "seed": s,
                             "step": k, "status": "ok", "ospa": float(np.sin(i + k + s))}
                            for i, lab in enumerate(LABELS) for s in range(2)
                            for k in range(10)])
    over_time = _drawn(monkeypatch,
                       lambda: figures.metric_over_time(results, "ospa", "x"))
    for styles in (drawn, over_time):
        assert len(styles) == len(LABELS)
        for (a, sa), (b, sb) in itertools.combinations(styles.items(), 2):
            assert sa != sb, (a, b)
