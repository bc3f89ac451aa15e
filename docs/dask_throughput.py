"""Throughput of a sweep on a Dask LocalCluster of 1 and of 2 worker processes (docs/dask.md).

Runs the same sweep (by default 200 runs: the GPF on ``default`` for 100 steps, seeds
0..199) with :class:`~mttbench.benchmarks.executors.DaskExecutor` on a LocalCluster of 1
worker, then of 2 workers, then on the local process pool of 2 workers, each into its own
folder; prints runs per second of each and the ratio 2 workers / 1 worker, and checks
that the three tables are identical (timing and memory columns aside). Each cluster is
started and its workers have imported mttbench and run one short warm-up run before the
clock starts: the figure is the sweep's, not the cluster's start.

    .venv/bin/python docs/dask_throughput.py [--runs 200] [--steps 100] [--tracker gpf]
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import sys
import tempfile
import time
from pathlib import Path

import pandas as pd

from mttbench import scenarios
from mttbench.benchmarks.executors import DaskExecutor, LocalExecutor
from mttbench.benchmarks.harness import Job, build_jobs, run_job, run_sweep
from mttbench.benchmarks.specs import TrackerSpec

TIMING = ["tracker_wall_s", "tracker_cpu_s", "select_wall_s", "select_cpu_s", "peak_rss_mb"]


def warm_up(job: Job) -> None:
    """On every worker: import and run one short job (numba's caches, imports)."""
    short = Job(dataclasses.replace(job.scenario, n_steps=2), job.tracker, job.policy,
                job.looks_per_step, job.seed)
    run_job(short)


def timed(jobs: list[Job], folder: Path, executor) -> tuple[float, pd.DataFrame]:
    t0 = time.perf_counter()
    df = run_sweep(jobs, folder, executor=executor, progress=False)
    return time.perf_counter() - t0, df


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=200)
    ap.add_argument("--steps", type=int, default=100)
    ap.add_argument("--tracker", default="gpf")
    ap.add_argument("--scenario", default="default")
    args = ap.parse_args()

    sc = dataclasses.replace(scenarios.get(args.scenario), n_steps=args.steps)
    jobs = build_jobs([sc], [TrackerSpec.parse(args.tracker)], None, None,
                      list(range(args.runs)))
    print(f"{len(jobs)} runs: {args.tracker} on {args.scenario}, {args.steps} steps; "
          f"{os.cpu_count()} CPUs; load average before {os.getloadavg()}", flush=True)
    walls: dict[str, float] = {}
    tables: dict[str, pd.DataFrame] = {}
    with tempfile.TemporaryDirectory(prefix="mttbench-dask-") as tmp:
        for n in (1, 2):
            with DaskExecutor(workers=n) as executor:
                executor.client.run(warm_up, jobs[0])
                walls[f"dask {n}"], tables[f"dask {n}"] = timed(
                    jobs, Path(tmp) / f"dask{n}", executor)
            print(f"  dask LocalCluster, {n} worker(s): {walls[f'dask {n}']:.1f} s, "
                  f"{len(jobs) / walls[f'dask {n}']:.2f} runs/s", flush=True)
        walls["local 2"], tables["local 2"] = timed(jobs, Path(tmp) / "local2",
                                                    LocalExecutor(2))
        print(f"  local pool, 2 workers: {walls['local 2']:.1f} s, "
              f"{len(jobs) / walls['local 2']:.2f} runs/s", flush=True)
    ratio = walls["dask 1"] / walls["dask 2"]
    print(f"throughput ratio, 2 workers / 1 worker: {ratio:.2f}x")
    print(f"load average after {os.getloadavg()}")
    ref = tables["dask 1"].drop(columns=TIMING)
    same = True
    for name, table in tables.items():
        other = table.drop(columns=TIMING)
        if not ref.equals(other):
            same = False
            cols = [c for c in ref.columns if not ref[c].equals(other[c])]
            rows = (ref[cols] != other[cols]).any(axis=1)
            first = ref.loc[rows, ["seed", "step"]].head(1).to_dict("records")
            print(f"  {name} differs from dask 1 in {cols} on {int(rows.sum())} rows, "
                  f"first {first}")
    print("identical results (timing and memory columns aside): " + ("yes" if same else "NO"))
    return 0 if same else 1


if __name__ == "__main__":
    sys.exit(main())
