"""Where ``jmpd-ap``'s step goes, part by part: the per-particle benchmark's warm-up (28
raster steps of world 0 from the tracker's prior, ``benchmarks/bench/bench_jmpd_ap.py``),
then the next steps of the same world, each listed kernel and method wrapped with a CPU
clock (no copies between steps, as in the harness); printed: the fastest step and, per
part, its mean over the fastest half of the steps (docs/speed.md, "jmpd-ap, fourth
round").

    python docs/jmpd_ap_step_parts.py default 4000
    python docs/jmpd_ap_step_parts.py default 64000 --steps 8 --init-fraction 1.0

BLAS runs on one thread (as in the benchmarks): with more, a BLAS call's CPU time
includes its helper threads' busy-waiting.
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # before numpy loads

import argparse  # noqa: E402

import numpy as np  # noqa: E402
from part_clocks import PartClocks, print_parts  # noqa: E402

from mttbench.benchmarks.bench.conftest import warm_up  # noqa: E402
from mttbench.benchmarks.engine.specs import resolve_scenarios  # noqa: E402
from mttbench.trackers.jmpd import JMPDAPTracker, ap, backend  # noqa: E402

KERNELS = ["propose", "place", "slot_log_likelihood", "gather_slots", "predict",
           "slot_sums", "sort_cluster", "max_held_sd", "held_per_particle",
           "birth_decisions", "recombined_log_pi", "occupied", "cluster_slots"]
METHODS = ["predict", "update", "estimate", "_move_persistent_compiled", "_births", "_clusters",
           "_undetected_misses", "_slot_means", "_sort_compiled", "_remaining"]
FUNCTIONS = ["grid_log_likelihood_tables", "systematic_resample", "cluster_slots",
             "coupled_slots", "merge_slots"]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("scenario", nargs="?", default="default")
    parser.add_argument("n_particles", nargs="?", type=int, default=4000)
    parser.add_argument("--steps", type=int, default=10)
    parser.add_argument("--warm", type=int, default=28)
    parser.add_argument("--init-fraction", type=float, default=None)
    args = parser.parse_args()
    clocks = PartClocks()
    params = {} if args.init_fraction is None else {"init_fraction": args.init_fraction}
    scenario = resolve_scenarios([args.scenario])[0]
    warm = warm_up(scenario, JMPDAPTracker(n_particles=args.n_particles, **params), args.warm)
    kernels = backend.compiled_ap_kernels()
    # (names an older tree lacks are skipped, so that two trees can be compared)
    for owner, names, prefix in ((kernels, KERNELS, "kernel "), (ap.JMPDAPTracker, METHODS,
                                                               "ap."), (ap, FUNCTIONS, "ap.")):
        for name in names:
            if hasattr(owner, name):
                clocks.wrap(owner, name, prefix + name)
    step, _ = warm.advance(args.steps)
    best = clocks.time_steps(step, args.steps)[: max(args.steps // 2, 1)]
    mean = float(np.mean([r[0] for r in best]))
    print(f"jmpd-ap, {args.n_particles} particles, on {args.scenario}: fastest step "
          f"{best[0][0] * 1e3:.3f} ms CPU, mean of the fastest half {mean * 1e3:.3f} ms "
          f"= {mean / args.n_particles * 1e6:.3f} us per particle")
    print_parts(best)


if __name__ == "__main__":
    main()
