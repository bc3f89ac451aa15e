"""Per-seed run means of every rung of a `mttbench bayes` ladder folder, as the CSVs in
docs/ (`docs/bayes_<scenario>_ladder_<seeds>.csv`: seed, OSPA at each particle count).

    .venv/bin/python docs/bayes_ladder_csv.py LADDER_FOLDER OUT.csv

Reads every run of the folder's ``parts/`` (all rungs, all seeds run there), takes each
run's mean OSPA over its steps with ``summary.per_run`` (the ladder's own statistic) and
writes one row per seed, one column per particle count (empty where a seed lacks a rung).
"""

from __future__ import annotations

import sys
from pathlib import Path

import pandas as pd

from mttbench.benchmarks.app import summary


def main(argv: list[str]) -> int:
    folder, out = Path(argv[0]), Path(argv[1])
    parts = sorted((folder / "parts").glob("*.parquet"))
    if not parts:
        raise SystemExit(f"{folder}/parts holds no runs")
    runs = summary.per_run(pd.concat([pd.read_parquet(p) for p in parts], ignore_index=True))
    bad = runs[runs["status"] != "ok"]
    if len(bad):
        raise SystemExit(f"{len(bad)} run(s) not ok, first: {bad['error'].iloc[0]}")
    runs["n"] = runs["tracker_label"].str.extract(r"n_particles=(\d+)")[0].astype(int)
    wide = runs.pivot(index="seed", columns="n", values="ospa").sort_index()
    wide.columns = [f"ospa_n{n}" for n in wide.columns]
    wide.round(6).to_csv(out)
    print(f"{out}: {len(wide)} seeds, runs per rung {wide.count().to_dict()}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
