"""Paired comparisons of trackers on the same worlds, for docs/bayes_grid.md.

Usage: ``python docs/bayes_grid.py RESULTS.parquet REFERENCE_LABEL OTHER_LABEL...``

Per scenario and other tracker, over the seeds both ran: the paired difference of the
per-run mean OSPA (other - reference) with its 95% Student-t interval; and per step the
mean over seeds of ``est_count`` (the existence probability, for a single-target filter)
of each, with the largest absolute difference over the steps, its step, and the 95%
interval of the paired difference at that step.
"""

from __future__ import annotations

import sys

import numpy as np
import pandas as pd
from scipy import stats


def t_half(x: np.ndarray) -> float:
    """Half-width of the 95% Student-t interval of the mean of ``x``."""
    x = np.asarray(x, dtype=float)
    return float(stats.t.ppf(0.975, len(x) - 1) * x.std(ddof=1) / np.sqrt(len(x)))


def compare(df: pd.DataFrame, reference: str, other: str) -> list[str]:
    lines = []
    ok = df[(df["status"] == "ok") & (df["step"] >= 0)]
    for sc, g in ok.groupby("scenario", sort=True):
        a, b = g[g["tracker_label"] == reference], g[g["tracker_label"] == other]
        seeds = sorted(set(a["seed"]) & set(b["seed"]))
        if not seeds:
            continue
        a, b = a[a["seed"].isin(seeds)], b[b["seed"].isin(seeds)]
        run_a = a.groupby("seed")["ospa"].mean()
        run_b = b.groupby("seed")["ospa"].mean()
        d = (run_b - run_a).to_numpy()
        ea = a.pivot(index="seed", columns="step", values="est_count")
        eb = b.pivot(index="seed", columns="step", values="est_count")
        de = eb - ea
        gap = de.mean(axis=0).abs()
        k = int(gap.idxmax())
        lines.append(
            f"| {sc} | {other} - {reference} | {len(seeds)} | {run_a.mean():.3f} | "
            f"{run_b.mean():.3f} | {d.mean():+.3f} ± {t_half(d):.3f} | {gap.max():.3f} "
            f"(step {k}, ± {t_half(de[k].to_numpy()):.3f}) | {gap.mean():.3f} |")
    return lines


def main(argv: list[str]) -> int:
    if len(argv) < 3:
        print(__doc__.strip().splitlines()[2], file=sys.stderr)
        return 2
    df = pd.read_parquet(argv[0])
    print("| scenario | difference | seeds | OSPA ref | OSPA other | paired OSPA diff (95%) "
          "| max_k abs mean existence diff | mean_k |")
    print("|---|---|---|---|---|---|---|---|")
    for other in argv[2:]:
        for line in compare(df, argv[1], other):
            print(line)
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
