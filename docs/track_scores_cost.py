"""Cost of the track-level scores in the default ``mttbench compare`` (docs/track_scores.md).

Runs every job of ``mttbench compare --seeds 2`` (the default scenarios and trackers, the
tuned files as compare applies them) one after the other in this process, and times,
inside each ``run_job``, the run-level track scores (``run_level_metrics``: trajectory
GOSPA, OSPA(2), CLEAR-MOT) and the per-step series (``series_values``) apart from the
rest of the run. One run measures all three, so machine load affects them alike::

    .venv/bin/python docs/track_scores_cost.py [--seeds 2]

Prints the totals and the ratios ``with / without`` (track scores, series).
"""

from __future__ import annotations

import argparse
import time
from collections import defaultdict

from mttbench.benchmarks.app import compare, tuned
from mttbench.benchmarks.engine import loop, track_series
from mttbench.benchmarks.engine.specs import PolicySpec, resolve_scenarios, resolve_trackers


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, default=2)
    args = ap.parse_args()
    seeds = list(range(args.seeds))
    scs = resolve_scenarios(list(compare.COMPARE_SCENARIOS), None)
    plan = tuned.plan_tuning(resolve_trackers(compare.default_tracker_texts()), None, seeds)
    jobs = loop.build_jobs(scs, plan.specs, [PolicySpec("raster")], None, seeds)

    spent = defaultdict(float)

    def timed(name, fn):
        def wrapper(*a, **k):
            t0 = time.perf_counter()
            try:
                return fn(*a, **k)
            finally:
                spent[name] += time.perf_counter() - t0
        return wrapper

    # the series are computed once per run (then read from the run's cache), inside
    # run_level_metrics (their run means) or series_values, whichever asks first
    loop.run_level_metrics = timed("track", loop.run_level_metrics)
    loop.series_values = timed("track", loop.series_values)
    track_series.RunSeries.values = timed("series", track_series.RunSeries.values)
    per_tracker = defaultdict(lambda: [0.0, 0.0])
    total = 0.0
    for job in jobs:
        before = spent["track"]
        t0 = time.perf_counter()
        loop.run_job(job)
        dt = time.perf_counter() - t0
        total += dt
        per_tracker[job.tracker.label][0] += dt
        per_tracker[job.tracker.label][1] += spent["track"] - before
    track, series = spent["track"], spent["series"]  # series: part of track
    bare = total - track
    print(f"{len(jobs)} runs, seeds {seeds}")
    print(f"run_job total {total:.2f} s; track scores {track:.2f} s, of which the "
          f"per-step series {series:.2f} s; the rest {bare:.2f} s")
    print(f"with series / without series: {total / (total - series):.4f}")
    print(f"with all track scores / without any: {total / bare:.4f}")
    for label, (t, s) in sorted(per_tracker.items()):
        print(f"  {label:28s} {t:7.2f} s, track scores {s:6.2f} s ({100 * s / t:5.1f}%)")


if __name__ == "__main__":
    main()
