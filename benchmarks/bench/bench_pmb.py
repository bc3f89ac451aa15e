"""Runtime of one PMB step, and its ratio to the GPF's on ``large`` measured in one run.

* ``test_pmb_step``: the ``large`` preset (50x50 cells, 25 targets, 250 raster looks)
  and ``crossing`` (four targets meeting in the centre: the LBP's clusters); the harness
  plays ``WARM_STEPS`` untimed steps with every cell looked at (``crossing``: 44, as
  ``bench_gpf.py``, when the targets close in from neighbouring cells; at step 20 a
  fourth track's existence still wavers, OSPA 1.01 on world 0), then one step at the
  scenario's budget is timed from a copy of that state each round (conftest
  ``Warm.repeat_step``), as ``bench_trackers.py`` does for every tracker.
* ``test_pmb_against_gpf_on_large``: the speed goal, step time on ``large`` at most
  ``MAX_RATIO_TO_GPF`` times the GPF's. Both trackers are warmed up the same way; their
  timed steps alternate round by round (CPU time, ``time.process_time``, so that other
  processes' load falls on both alike), and the ratio of the fastest rounds goes into
  ``extra_info`` (``pmb_over_gpf``) and is asserted. The benchmark itself times the PMB
  step.

Every benchmark asserts the accuracy of the step it times (OSPA below ``OSPA_BOUND``).

Run: ``pytest benchmarks/bench/bench_pmb.py --benchmark-only`` (or ``--benchmark-disable``
for the accuracy and the ratio alone).
"""

from __future__ import annotations

import time

import pytest

from mttbench import scenarios
from mttbench.benchmarks.engine.policies import AllCells
from mttbench.trackers.gpf import GaussianParticleFilter
from mttbench.trackers.pmb import PMBTracker

#: untimed warm-up steps (every cell looked at); the timed step is this one
WARM_STEPS = {"large": 20, "crossing": 44}
#: rounds per benchmark (each after an untimed step)
ROUNDS = 30
#: rounds of each tracker in the paired ratio
PAIRED_ROUNDS = 15
#: OSPA (c = 2) the timed step must stay below (null scores 2)
OSPA_BOUND = 1.0
#: the speed goal: a PMB step on ``large`` costs at most this many GPF steps
MAX_RATIO_TO_GPF = 2.0


@pytest.mark.parametrize("name", ["large", "crossing"])
def test_pmb_step(benchmark, warm_up, accuracy, name):
    warm = warm_up(scenarios.get(name), PMBTracker(), WARM_STEPS[name], policy=AllCells())
    setup, step, est = warm.repeat_step()
    benchmark.extra_info.update(scenario=name, step=warm.step,
                                n_tracks=len(warm.tracker.tracks[0]),
                                n_looks=len(warm.looks.cells), warm_policy="all",
                                warm_mean_ospa=warm.warm_ospa)
    accuracy(warm.truth, est, OSPA_BOUND)
    result = benchmark.pedantic(step, setup=setup, rounds=ROUNDS, warmup_rounds=1)
    assert float(result.count) == float(est.count)


def _fastest(setup, step, rounds: int) -> float:
    best = float("inf")
    for _ in range(rounds):
        setup()
        t0 = time.process_time()
        step()
        best = min(best, time.process_time() - t0)
    return best


def test_pmb_against_gpf_on_large(benchmark, warm_up, accuracy):
    sc = scenarios.get("large")
    pmb = warm_up(sc, PMBTracker(), WARM_STEPS["large"], policy=AllCells())
    gpf = warm_up(sc, GaussianParticleFilter(), WARM_STEPS["large"], policy=AllCells())
    p_setup, p_step, p_est = pmb.repeat_step()
    g_setup, g_step, g_est = gpf.repeat_step()
    accuracy(pmb.truth, p_est, OSPA_BOUND)
    accuracy(gpf.truth, g_est, OSPA_BOUND, prefix="gpf_")
    p_best, g_best = float("inf"), float("inf")
    for _ in range(PAIRED_ROUNDS):  # alternate, so both meet the same load
        p_best = min(p_best, _fastest(p_setup, p_step, 1))
        g_best = min(g_best, _fastest(g_setup, g_step, 1))
    ratio = p_best / g_best
    benchmark.extra_info.update(scenario="large", pmb_cpu_s=p_best, gpf_cpu_s=g_best,
                                pmb_over_gpf=ratio, max_ratio=MAX_RATIO_TO_GPF)
    result = benchmark.pedantic(p_step, setup=p_setup, rounds=ROUNDS, warmup_rounds=1)
    assert float(result.count) == float(p_est.count)
    assert ratio <= MAX_RATIO_TO_GPF, (
        f"a PMB step on large costs {ratio:.2f} GPF steps (goal <= {MAX_RATIO_TO_GPF}): "
        f"{p_best * 1e3:.2f} ms against {g_best * 1e3:.2f} ms CPU")
