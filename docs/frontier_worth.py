"""What one tracker setting is worth in another tracker's budget, from a frontier.csv.

    python docs/frontier_worth.py reports/frontier-default/frontier.csv \\
        --setting gpf --against jmpd-ap jmpd

For each scenario: the OSPA of ``--setting`` (a tracker of the table at its best budget, or
``tracker=BUDGET``), then for each ``--against`` tracker the budget at which its curve
reaches that OSPA (mean OSPA interpolated linearly in log budget between the two budgets
that bracket it), the CPU ms per step there (interpolated the same way) and the ratio to
the setting's CPU ms. A curve that never comes down to the OSPA is reported as "not
reached" with its best; one already below it at its smallest budget as "<= smallest".
With ``--results`` (the frontier's results.parquet), also the paired difference of each
budget of the ``--against`` trackers minus the setting, per run OSPA on the same seeds, with
its 95% t interval: how sure the comparison is (the worlds are shared).
"""

from __future__ import annotations

import argparse
import math

import numpy as np
import pandas as pd

from mttbench.benchmarks.app.frontier import per_run
from mttbench.benchmarks.app.summary import mean_ci95


def crossing(budget: np.ndarray, ospa: np.ndarray, cpu: np.ndarray, target: float
             ) -> tuple[str, float, float]:
    """``(how, budget, cpu)`` where the curve (sorted by budget) first reaches ``target``."""
    order = np.argsort(budget)
    b, y, c = budget[order], ospa[order], cpu[order]
    if y[0] <= target:
        return "<=", float(b[0]), float(c[0])
    for i in range(1, len(b)):
        if y[i] <= target:
            t = (y[i - 1] - target) / (y[i - 1] - y[i])
            lb = math.log(b[i - 1]) + t * (math.log(b[i]) - math.log(b[i - 1]))
            lc = math.log(c[i - 1]) + t * (math.log(c[i]) - math.log(c[i - 1]))
            return "=", math.exp(lb), math.exp(lc)
    return "not reached", float(b[np.argmin(y)]), float(c[np.argmin(y)])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("csv", nargs="+")
    ap.add_argument("--setting", default="gpf")
    ap.add_argument("--against", nargs="+", default=["jmpd-ap", "jmpd"])
    ap.add_argument("--results", nargs="+", default=[])
    args = ap.parse_args()
    table = pd.concat([pd.read_csv(p) for p in args.csv], ignore_index=True)
    runs = (per_run(pd.concat([pd.read_parquet(p) for p in args.results]))
            if args.results else None)
    name, _, fixed = args.setting.partition("=")
    for sc, g in table.groupby("scenario", sort=False):
        mine = g[g["tracker"] == name]
        row = (mine.loc[mine["ospa_mean"].idxmin()] if not fixed
               else mine[mine["budget"] == float(fixed)].iloc[0])
        target, cpu0 = float(row["ospa_mean"]), float(row["cpu_ms_mean"])
        print(f"{sc}: {name} at {row['budget_param']}={row['budget']:g}: OSPA {target:.3f} "
              f"± {row['ospa_ci95']:.3f}, {cpu0:.3g} ms/step")
        for other in args.against:
            o = g[g["tracker"] == other].dropna(subset=["ospa_mean"])
            if o.empty:
                continue
            if o["budget"].isna().all():  # a tracker without a budget: one point
                r = o.iloc[0]
                print(f"  {other} (one setting): OSPA {r['ospa_mean']:.3f}, "
                      f"{r['cpu_ms_mean']:.3g} ms/step, {r['cpu_ms_mean'] / cpu0:.1f}x the CPU")
                continue
            how, b, c = crossing(o["budget"].to_numpy(float), o["ospa_mean"].to_numpy(float),
                                 o["cpu_ms_mean"].to_numpy(float), target)
            n = o["budget_param"].iloc[0]
            what = {"=": f"reaches it at {n} = {b:.0f}",
                    "<=": f"is below it already at {n} = {b:.0f}",
                    "not reached": f"does not reach it (best at {n} = {b:.0f}: OSPA "
                                   f"{o['ospa_mean'].min():.3f})"}[how]
            print(f"  {other} {what}: {c:.3g} ms/step, {c / cpu0:.1f}x the CPU")
            if runs is None:
                continue
            ok = runs[runs["ok"] & (runs["scenario"] == sc)].set_index("seed")
            ref = ok[ok["tracker_label"] == row["tracker_label"]]["ospa"]
            for _, r in o.iterrows():
                mine = ok[ok["tracker_label"] == r["tracker_label"]]["ospa"]
                seeds = mine.index.intersection(ref.index)
                m, h = mean_ci95((mine.loc[seeds] - ref.loc[seeds]).to_numpy(float))
                print(f"    {r['tracker_label']} minus the setting: {m:+.3f} ± {h:.3f} "
                      f"({len(seeds)} seeds)")


if __name__ == "__main__":
    main()
