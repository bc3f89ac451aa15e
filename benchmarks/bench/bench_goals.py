"""The speed goals between trackers (docs/speed.md), each a ratio of two trackers' steps
measured in one run.

A goal pairs a tracker with a rival on one preset, both warmed up as the benchmark files
that time them alone do (``bench_trackers.py``: every cell looked at for 20 steps;
``bench_stonesoup.py``: the scenario's raster for 60 steps, the comparison's own
protocol, which the Stone Soup peers' defaults are tuned for). Their timed steps
(``predict``, ``update``, ``estimate`` from a copy of the warm state, after one untimed
run: conftest ``Warm.repeat_step``) alternate round by round, so that other processes'
load falls on both alike, by CPU time (``time.process_time``); the ratio of the two
fastest rounds goes into ``extra_info`` (``paired_ratio``, with the goal) and into the
terminal summary. Nothing asserts it: a goal not met is a measurement, not a failure.
The benchmark itself times the first tracker's step (gated like every benchmark).

Goals (the tracker's step against the rival's):

* ``gpf-vs-ss-gmphd-large``: Stone Soup's GM-PHD step over the GPF's, at least 10.
* ``pmb-vs-gpf-default``, ``pmb-vs-gpf-large``: the pmb step over the GPF's, at most 1.5.
* ``kfnn-vs-ss-gnn-large``: Stone Soup's GNN step over KF-NN's, at least 20.

The GPF's own goal (its step on ``default`` at most a fifth of its recorded ratio to the
reference workload) is ``bench_trackers.py::test_tracker_step[gpf-small]``'s ratio.

Run: ``pytest benchmarks/bench/bench_goals.py --benchmark-only`` (or
``--benchmark-disable`` for the accuracy alone).
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import pytest

from mttbench import scenarios
from mttbench.benchmarks.engine.policies import AllCells
from mttbench.benchmarks.engine.specs import TrackerSpec


@dataclass(frozen=True)
class Goal:
    """``tracker`` against ``rival`` on ``scenario``: ``paired_ratio`` is the rival's
    fastest step over the tracker's when ``rival_over_tracker``, else the tracker's over
    the rival's; the goal is ``paired_ratio >= goal`` (rival over tracker) or ``<= goal``."""

    name: str
    tracker: str
    rival: str
    scenario: str
    every_cell: bool  # the warm-up: every cell looked at (else the raster)
    goal: float
    rival_over_tracker: bool


GOALS = [
    Goal("gpf-vs-ss-gmphd-large", "gpf", "ss-gmphd", "large", False, 10.0, True),
    Goal("pmb-vs-gpf-default", "pmb", "gpf", "default", True, 1.5, False),
    Goal("pmb-vs-gpf-large", "pmb", "gpf", "large", True, 1.5, False),
    Goal("kfnn-vs-ss-gnn-large", "kfnn", "ss-gnn", "large", False, 20.0, True),
]
#: warm-up steps: bench_trackers.py (every cell) and bench_stonesoup.py (raster)
WARM_STEPS = {True: 20, False: 60}
#: rounds of each tracker in the paired ratio (60: with 15 the fastest kfnn step on
#: `large` moved by 1.4x between processes of one tree; docs/speed.md), and of the
#: gated benchmark
PAIRED_ROUNDS, ROUNDS = 60, 15
#: OSPA (c = 2) the timed steps must stay below: bench_trackers.py's bound after the
#: every-cell warm-up, bench_stonesoup.py's after the raster (no tracker holds all 25
#: targets of large after 60 raster steps; null scores 2)
OSPA_BOUND = {True: 1.0, False: 1.8}


def _fastest(setup, step) -> float:
    setup()
    t0 = time.process_time()
    step()
    return time.process_time() - t0


@pytest.mark.parametrize("goal", GOALS, ids=[g.name for g in GOALS])
def test_goal(benchmark, warm_up, accuracy, goal_ratio, goal):
    sc = scenarios.get(goal.scenario)
    policy = AllCells() if goal.every_cell else None
    warm = {spec: warm_up(sc, TrackerSpec.parse(spec).make(), WARM_STEPS[goal.every_cell],
                          policy=policy) for spec in (goal.tracker, goal.rival)}
    steps = {spec: w.repeat_step() for spec, w in warm.items()}
    for spec, (_, _, est) in steps.items():
        accuracy(warm[spec].truth, est, OSPA_BOUND[goal.every_cell],
                 prefix="" if spec == goal.tracker else "rival_")
    setup, step, est = steps[goal.tracker]
    if not benchmark.disabled:
        best = {spec: float("inf") for spec in steps}
        for _ in range(PAIRED_ROUNDS):  # alternate, so both meet the same load
            for spec, (s, f, _) in steps.items():
                best[spec] = min(best[spec], _fastest(s, f))
        num, den = ((goal.rival, goal.tracker) if goal.rival_over_tracker
                    else (goal.tracker, goal.rival))
        ratio = best[num] / best[den]
        benchmark.extra_info.update(
            scenario=goal.scenario, tracker=goal.tracker, rival=goal.rival,
            tracker_cpu_s=best[goal.tracker], rival_cpu_s=best[goal.rival],
            paired_ratio=ratio, ratio_of=f"{num} / {den}", goal=goal.goal,
            goal_met=ratio >= goal.goal if goal.rival_over_tracker else ratio <= goal.goal)
        goal_ratio(f"{num} / {den} on {goal.scenario}", ratio,
                   (">= " if goal.rival_over_tracker else "<= ") + f"{goal.goal:g}",
                   benchmark.extra_info["goal_met"])
    result = benchmark.pedantic(step, setup=setup, rounds=ROUNDS, warmup_rounds=1)
    assert float(result.count) == float(est.count)
