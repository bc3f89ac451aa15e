"""Issue 13's goal measures from a ``mttbench run`` folder (docs/jmpd-ap.md).

Usage: ``python docs/jmpd_ap_goals.py RUN_FOLDER [--from-step K] [--crossings A,B]``

Per tracker (label), over seeds: the mean OSPA from step ``K`` on, the mean |count
error| from step ``K`` on, the median tracker step time, each with a 95% t interval
over seeds (the seed is the unit); with ``--crossings``, the mean OSPA in the 20 steps
before and after each crossing step and the ratio after/before with a 95% interval
from the seeds' paired differences (delta method on the ratio of means).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import pandas as pd

from mttbench.benchmarks.app.summary import mean_ci95


def read(folder: Path) -> pd.DataFrame:
    path = folder / "results.parquet"
    if path.exists():
        return pd.read_parquet(path)
    return pd.concat([pd.read_parquet(p) for p in sorted((folder / "parts").glob("*.parquet"))])


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("folder", type=Path)
    ap.add_argument("--from-step", type=int, default=10)
    ap.add_argument("--crossings", default="")
    args = ap.parse_args(argv)
    df = read(args.folder)
    df = df[df["status"] == "ok"]
    crossings = [int(c) for c in args.crossings.split(",") if c]
    rows = []
    for (scenario, label, policy, looks), g in df.groupby(
            ["scenario", "tracker_label", "policy_label", "looks_per_step"]):
        late = g[g["step"] >= args.from_step]
        per_seed = late.groupby("seed").agg(ospa=("ospa", "mean"),
                                            count=("count_error", lambda c: c.abs().mean()))
        steps = g.groupby("seed")["tracker_wall_s"].median() * 1e3
        row = {"scenario": scenario, "tracker": label, "policy": f"{policy}@{looks}",
               "seeds": per_seed.shape[0]}
        for name, values in (("ospa", per_seed["ospa"]), ("|count err|", per_seed["count"]),
                             ("step ms (median)", steps)):
            m, h = mean_ci95(values.to_numpy())
            row[name] = f"{m:.3f} ± {h:.3f}"
        for c in crossings:
            by_seed = g.groupby("seed")
            before = by_seed.apply(lambda s, c=c: s[(s.step >= c - 20) & (s.step < c)].ospa.mean())
            after = by_seed.apply(lambda s, c=c: s[(s.step >= c) & (s.step < c + 20)].ospa.mean())
            mb, ma = before.mean(), after.mean()
            # ratio of means, interval by the delta method on the paired seeds
            d = (after - (ma / mb) * before) / mb
            _, h = mean_ci95(d.to_numpy())
            row[f"before {c}"] = f"{mb:.3f}"
            row[f"after {c}"] = f"{ma:.3f}"
            row[f"ratio {c}"] = f"{ma / mb:.2f} ± {h:.2f}"
        rows.append(row)
    out = pd.DataFrame(rows)
    print("| " + " | ".join(out.columns) + " |")
    print("|" + "---|" * len(out.columns))
    for r in out.itertuples(index=False):
        print("| " + " | ".join(str(v) for v in r) + " |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
