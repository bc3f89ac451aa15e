"""The GPF's (track, looked cell) pairs at its timed step on a scenario and the compiled
quadrature's time on them (docs/speed.md, "The pairs' quadrature shares a column's nodes
and edges"): the benchmarks' warm-up (60 raster steps) and one step with the numpy forms,
every call of ``gpf.grid.rect_position_moments`` captured; per call its pairs, Gaussians
and the pairs whose lower edge is the upper edge of their column's pair before them; then
the fastest of 200 calls of the compiled kernel on the largest call's pairs. Run it in
another tree with that tree's Python for the time before a change:

    python docs/rect_moments_timing.py large
"""

from __future__ import annotations

import sys
import time

import numpy as np

from mttbench import scenarios
from mttbench.benchmarks.bench.conftest import warm_up
from mttbench.benchmarks.engine.specs import TrackerSpec
from mttbench.trackers import grid_kernels
from mttbench.trackers.gpf import grid
from mttbench.trackers.jmpd import use_backend


def main() -> None:
    name = sys.argv[1] if len(sys.argv) > 1 else "large"
    calls = []
    numpy_form = grid.rect_position_moments

    def captured(*args):
        calls.append([np.ascontiguousarray(a, dtype=float) for a in args])
        return numpy_form(*args)

    grid.rect_position_moments = captured
    with use_backend("numpy"):
        warm = warm_up(scenarios.get(name), TrackerSpec.parse("gpf").make(), 60)
        setup, step, _ = warm.repeat_step()
        setup()
        calls.clear()
        step()
    grid.rect_position_moments = numpy_form
    columns = getattr(grid_kernels, "_columns", None)  # None in a tree before the sharing
    for args in calls:
        if columns is None:
            print(f"{len(args[0])} pairs")
            continue
        run, col, _ = columns(*args[:4])
        above: dict = {}
        shared = 0
        for p in range(len(run)):
            shared += above.get((run[p], col[p])) == args[4][p]
            above[(run[p], col[p])] = args[5][p]
        print(f"{len(run)} pairs, {run[-1] + 1 if len(run) else 0} runs of one Gaussian, "
              f"{shared} lower edges shared")
    args = max(calls, key=lambda a: len(a[0]))
    table = grid._gl_table()
    grid_kernels.rect_position_moments(*args, *table)
    best = float("inf")
    for _ in range(200):
        t0 = time.perf_counter()
        grid_kernels.rect_position_moments(*args, *table)
        best = min(best, time.perf_counter() - t0)
    print(f"compiled rect_position_moments on {len(args[0])} pairs: {best * 1e3:.3f} ms")


if __name__ == "__main__":
    main()
