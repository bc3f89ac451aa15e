"""Where the GPF's timed step goes, part by part, without a profiler's overhead: the
benchmarks' warm-up (``benchmarks/bench/conftest.py:warm_up``), then 300 timed steps from a
copy of the warm state, each listed kernel and step function wrapped with a clock; printed:
the fastest step and, per part, its mean over the fastest tenth of the steps (docs/speed.md,
"The GPF on `large`: the merge's distances compiled").

    python docs/gpf_step_parts.py large
"""

from __future__ import annotations

import argparse

import numpy as np
from part_clocks import PartClocks, print_parts

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
    clocks = PartClocks()
    warm = warm_up(scenarios.get(args.scenario), TrackerSpec.parse("gpf").make(), 60)
    kernels = grid_backend.compiled_gpf_kernels(wait=None)
    for name in KERNELS:
        if kernels is not None and hasattr(kernels, name):
            clocks.wrap(kernels, name, f"kernel {name}")
    for owner, names in ((grid, GRID), (tracker, TRACKER),
                         (tracker.GaussianParticleFilter, METHODS)):
        for name in names:
            clocks.wrap(owner, name, f"{owner.__name__.split('.')[-1]}.{name}")
    setup, step, _ = warm.repeat_step()
    rows = clocks.time_steps(step, args.steps, setup)
    best = rows[: max(len(rows) // 10, 1)]
    print(f"gpf on {args.scenario}: fastest step {best[0][0] * 1e3:.3f} ms CPU, mean of the "
          f"fastest tenth {np.mean([r[0] for r in best]) * 1e3:.3f} ms")
    print_parts(best)


if __name__ == "__main__":
    main()
