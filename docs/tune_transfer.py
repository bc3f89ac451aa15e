"""Does a tuned file transfer? Tuned against default settings on the held-apart points.

Reads the ``results.parquet`` of a compare run with both settings::

    mttbench compare --suite envelope:held --tuning-effect --tuned-dir DIR --seeds 10 \\
        --trackers kfnn gpf ... --out OUT
    .venv/bin/python docs/tune_transfer.py OUT/results.parquet [--metric ospa]

and prints, per tracker run both ways (labels ``name`` and ``name(tuned...)``), the paired
difference tuned - default of each run's mean over its steps: per held point (mean and
95% t half-width over seeds) and over the points together (per seed, the mean over the
points, then the paired interval over seeds). The rule the project ships by: a tuned file
is kept only where the overall upper bound is below 0.
"""

from __future__ import annotations

import argparse

import numpy as np
import pandas as pd
from scipy import stats


def _ci(d: np.ndarray) -> tuple[float, float]:
    d = d[~np.isnan(d)]
    if len(d) < 2:
        return float(np.mean(d)) if len(d) else float("nan"), float("nan")
    return float(d.mean()), float(stats.t.ppf(0.975, len(d) - 1) * d.std(ddof=1)
                                  / np.sqrt(len(d)))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("results")
    ap.add_argument("--metric", default="ospa")
    args = ap.parse_args()
    df = pd.read_parquet(args.results)
    ok = df[df["status"] == "ok"]
    runs = ok.groupby(["scenario", "tracker", "tracker_label", "seed"])[args.metric].mean()
    runs = runs.reset_index()
    for name, g in runs.groupby("tracker"):
        labels = sorted(set(g["tracker_label"]))
        tuned = [lab for lab in labels if lab.startswith(f"{name}(tuned")]
        # the default setting's label: the tuned one without its mark
        default = (tuned[0].replace("(tuned,", "(").replace("(tuned)", "")
                   if tuned else None)
        if not tuned or default not in labels:
            continue
        wide = g.pivot_table(index=["scenario", "seed"], columns="tracker_label",
                             values=args.metric)
        diff = (wide[tuned[0]] - wide[default]).rename("d").reset_index()
        print(f"\n{tuned[0]} - {default} ({args.metric}, paired by seed)")
        print("| point | seeds | tuned - default |")
        print("|---|---:|---:|")
        for sc, h in diff.groupby("scenario"):
            m, half = _ci(h["d"].to_numpy(float))
            print(f"| `{sc}` | {len(h)} | {m:+.3f} ± {half:.3f} |")
        per_seed = diff.groupby("seed")["d"].mean().to_numpy(float)
        m, half = _ci(per_seed)
        verdict = "ships (upper bound < 0)" if m + half < 0 else "defaults ship"
        print(f"| all held points | {len(per_seed)} | {m:+.3f} ± {half:.3f} (upper "
              f"{m + half:+.3f}): {verdict} |")


if __name__ == "__main__":
    main()
