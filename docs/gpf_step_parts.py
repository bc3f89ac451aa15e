"""Where the GPF's timed step goes, part by part, without a profiler's overhead: the
benchmarks' warm-up (``benchmarks/bench/conftest.py:warm_up``), then 300 timed steps from a
copy of the warm state, each listed kernel and step function wrapped with a clock; printed:
the fastest step and, per part, its mean over the fastest tenth of the steps (docs/speed.md,
"The GPF on `large`: the merge's distances compiled").

    python docs/gpf_step_parts.py large
"""

from __future__ import annotations

import argparse
import collections
import functools
import time

import numpy as np

from mttbench import scenarios
from mttbench.benchmarks.bench.conftest import warm_up
from mttbench.benchmarks.engine.specs import TrackerSpec
from mttbench.trackers import grid_backend
from mttbench.trackers.gpf import grid, tracker

KERNELS = ["grid_update_packed", "cluster_posterior", "fold_moments", "moment_match",
           "keep_and_prune", "candidates", "unpack_front", "cluster_options", "cluster_g",
           "greedy_merge", "rows_by_track", "prune_tracks", "any_close", "near_walls",
           "field_predict"]
GRID = ["_cluster_posterior", "position_regression", "look_log_ratios", "fold_into_workspace"]
TRACKER = ["merge_groups", "_pair_distances", "collapse", "condition_on_count_bound"]
METHODS = ["predict", "update", "estimate", "_merge_and_prune", "_reduce_components",
           "_update_grid"]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scenario", nargs="?", default="large")
    ap.add_argument("--steps", type=int, default=300)
    args = ap.parse_args()
    spent: collections.Counter = collections.Counter()

    def wrap(owner, name, label):
        f = getattr(owner, name)

        @functools.wraps(f)
        def timed(*a, **k):
            t0 = time.process_time()
            try:
                return f(*a, **k)
            finally:
                spent[label] += time.process_time() - t0
        setattr(owner, name, timed)

    warm = warm_up(scenarios.get(args.scenario), TrackerSpec.parse("gpf").make(), 60)
    kernels = grid_backend.compiled_gpf_kernels(wait=None)
    for name in KERNELS:
        if kernels is not None and hasattr(kernels, name):
            wrap(kernels, name, f"kernel {name}")
    for owner, names in ((grid, GRID), (tracker, TRACKER),
                         (tracker.GaussianParticleFilter, METHODS)):
        for name in names:
            wrap(owner, name, f"{owner.__name__.split('.')[-1]}.{name}")
    setup, step, _ = warm.repeat_step()
    rows = []
    for _ in range(args.steps):
        setup()
        spent.clear()
        t0 = time.process_time()
        step()
        rows.append((time.process_time() - t0, dict(spent)))
    rows.sort(key=lambda r: r[0])
    best = rows[: max(len(rows) // 10, 1)]
    print(f"gpf on {args.scenario}: fastest step {best[0][0] * 1e3:.3f} ms CPU, mean of the "
          f"fastest tenth {np.mean([r[0] for r in best]) * 1e3:.3f} ms")
    parts = {k: np.mean([r[1].get(k, 0.0) for r in best]) for r in best for k in r[1]}
    for label, t in sorted(parts.items(), key=lambda kv: -kv[1]):
        print(f"{t * 1e3:8.3f} ms  {label}")


if __name__ == "__main__":
    main()
