"""Where one tracker's timed step goes: the benchmarks' warm-up (the scenario's raster for
``--warm`` steps, ``benchmarks/bench/conftest.py:warm_up``), then the fastest of 15 timed
steps (CPU time, ``predict`` + ``update`` + ``estimate`` from a copy of the warm state) and
a cProfile of 30 more (docs/speed.md, "Where the step goes").

    python docs/profile_step.py gpf large
    python docs/profile_step.py jmpd-ap:n_particles=16000 default --sort tottime
"""

from __future__ import annotations

import argparse
import cProfile
import pstats
import time

from mttbench.benchmarks.bench.conftest import warm_up
from mttbench.benchmarks.engine.specs import TrackerSpec, resolve_scenarios


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("tracker")
    ap.add_argument("scenario")
    ap.add_argument("--warm", type=int, default=60, help="warm-up steps (default 60)")
    ap.add_argument("--sort", default="cumulative", help="pstats order (default cumulative)")
    ap.add_argument("--lines", type=int, default=40, help="profile lines shown (default 40)")
    args = ap.parse_args()
    warm = warm_up(resolve_scenarios([args.scenario])[0], TrackerSpec.parse(args.tracker).make(),
                   args.warm)
    setup, step, est = warm.repeat_step()
    best = float("inf")
    for _ in range(15):
        setup()
        t0 = time.process_time()
        step()
        best = min(best, time.process_time() - t0)
    print(f"{args.tracker} on {args.scenario}: fastest step {best * 1e3:.2f} ms CPU, "
          f"estimated count {float(est.count):.2f}")
    prof = cProfile.Profile()
    for _ in range(30):
        setup()
        prof.enable()
        step()
        prof.disable()
    pstats.Stats(prof).sort_stats(args.sort).print_stats(args.lines)


if __name__ == "__main__":
    main()
