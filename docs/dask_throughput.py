"""Throughput of a sweep on a Dask LocalCluster of 1 and of 2 worker processes (docs/dask.md).

Runs the same sweep (by default 200 runs: the GPF on ``default`` for 100 steps, seeds
0..199) with :class:`~mttbench.benchmarks.engine.executors.DaskExecutor` on a LocalCluster of 1
worker, on one of 2 workers, and on the local process pool of 2 workers, each time into a
fresh folder, ``--repeat`` times in turn; prints every wall time, the best of each
(the repetition least disturbed by other processes on a shared machine), runs per second
and the ratio 2 workers / 1 worker of the best times, and checks that all the tables are
identical (timing and memory columns aside). Both clusters are started and their workers
have imported mttbench and run one short warm-up run before any clock starts: the figure
is the sweep's, not the cluster's start.

    .venv/bin/python docs/dask_throughput.py [--runs 200] [--steps 100] [--tracker gpf]
                                             [--repeat 3]
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
from mttbench.benchmarks.engine.executors import DaskExecutor, LocalExecutor
from mttbench.benchmarks.engine.loop import Job, build_jobs, run_job
from mttbench.benchmarks.engine.specs import TrackerSpec
from mttbench.benchmarks.engine.sweep import run_sweep

TIMING = ["tracker_wall_s", "tracker_cpu_s", "select_wall_s", "select_cpu_s", "peak_rss_mb"]


def warm_up(job: Job) -> None:
    """On every worker: import and run one short job (numba's caches, imports)."""
    short = Job(dataclasses.replace(job.scenario, n_steps=2), job.tracker, job.policy,
                job.looks_per_step, job.seed)
    run_job(short)


def timed(jobs: list[Job], folder: Path, executor) -> tuple[float, pd.DataFrame]:
    t0 = time.perf_counter()
    df = run_sweep(jobs, folder, executor=executor)
    return time.perf_counter() - t0, df


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=200)
    ap.add_argument("--steps", type=int, default=100)
    ap.add_argument("--tracker", default="gpf")
    ap.add_argument("--scenario", default="default")
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()

    sc = dataclasses.replace(scenarios.get(args.scenario), n_steps=args.steps)
    jobs = build_jobs([sc], [TrackerSpec.parse(args.tracker)], None, None,
                      list(range(args.runs)))
    print(f"{len(jobs)} runs: {args.tracker} on {args.scenario}, {args.steps} steps, "
          f"{args.repeat} repetition(s); {os.cpu_count()} CPUs; load average before "
          f"{os.getloadavg()}", flush=True)
    walls: dict[str, list[float]] = {"dask 1": [], "dask 2": [], "local 2": []}
    tables: list[pd.DataFrame] = []
    with (tempfile.TemporaryDirectory(prefix="mttbench-dask-") as tmp,
          DaskExecutor(workers=1) as one, DaskExecutor(workers=2) as two):
        executors = {"dask 1": one, "dask 2": two, "local 2": LocalExecutor(2)}
        for executor in (one, two):
            executor.client.run(warm_up, jobs[0])
        for r in range(args.repeat):
            for name, executor in executors.items():
                wall, table = timed(jobs, Path(tmp) / f"{name}-{r}".replace(" ", ""),
                                    executor)
                walls[name].append(wall)
                tables.append(table.drop(columns=TIMING))
                print(f"  {name:8s} repetition {r}: {wall:.1f} s, {len(jobs) / wall:.2f} "
                      f"runs/s; load average {os.getloadavg()[0]:.2f}", flush=True)
    for name, w in walls.items():
        print(f"best {name}: {min(w):.1f} s, {len(jobs) / min(w):.2f} runs/s "
              f"(all: {', '.join(f'{x:.1f}' for x in w)} s)")
    print(f"throughput ratio, 2 workers / 1 worker (best times): "
          f"{min(walls['dask 1']) / min(walls['dask 2']):.2f}x")
    print(f"load average after {os.getloadavg()}")
    same = True
    for table in tables[1:]:
        if not tables[0].equals(table):
            same = False
            cols = [c for c in table.columns if not tables[0][c].equals(table[c])]
            print(f"  a table differs from the first in {cols}")
    print("identical results (timing and memory columns aside): " + ("yes" if same else "NO"))
    return 0 if same else 1


if __name__ == "__main__":
    sys.exit(main())
