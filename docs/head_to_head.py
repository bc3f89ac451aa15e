"""Paired head-to-head of the tuned trackers (docs/tune.md).

    .venv/bin/python docs/head_to_head.py OUT_DIR [OUT_DIR ...]

Reads each compare folder's results.parquet; per scenario prints one markdown row: the
seeds, mean OSPA of kfnn, gpf, ss-gnn and ss-gmphd (tuned), and the paired differences
(per-seed mean OSPA) kfnn - ss-gnn, gpf - ss-gnn, gpf - ss-gmphd with their 95% t
half-widths and, in brackets, the upper bound.
"""

from __future__ import annotations

import sys

import pandas as pd
from scipy import stats

TRACKERS = ("kfnn(tuned)", "gpf(tuned)", "ss-gnn(tuned)", "ss-gmphd(tuned)")
PAIRS = (("kfnn(tuned)", "ss-gnn(tuned)"), ("gpf(tuned)", "ss-gnn(tuned)"),
         ("gpf(tuned)", "ss-gmphd(tuned)"))


def main(folders: list[str]) -> None:
    d = pd.concat([pd.read_parquet(f"{f}/results.parquet") for f in folders])
    for scenario, g in d.groupby("scenario"):
        m = g.groupby(["tracker_label", "seed"])["ospa"].mean().unstack(0)
        row = [str(scenario), str(len(m))] + [f"{m[c].mean():.3f}" for c in TRACKERS]
        for a, b in PAIRS:
            x = m[a] - m[b]
            h = stats.t.ppf(0.975, len(x) - 1) * x.std(ddof=1) / len(x) ** 0.5
            row.append(f"{x.mean():+.3f} ± {h:.3f} ({x.mean() + h:+.3f})")
        print("| " + " | ".join(row) + " |")


if __name__ == "__main__":
    main(sys.argv[1:])
