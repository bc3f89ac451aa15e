"""Runtime of the harness itself, with the ``null`` tracker (whose steps cost nothing),
so that what is timed is the harness's own overhead, and KF-NN's step beside it.

* ``test_play_loop``: the 100 steps of the step loop (:func:`~mttbench.benchmarks.engine.
  loop.play`) on ``default`` (12x12 cells, 3 targets, 24 raster looks), world 0: per step
  the raster's cells, the world's looks, the eight clock reads and the step's record. The
  world's simulation and the tracker's ``reset`` (in ``play``) are each round's untimed
  setup.
* ``test_run_job``: one whole job on ``default`` (:func:`~mttbench.benchmarks.engine.loop.
  run_job`): the simulation, the loop, the metrics of every step (OSPA, GOSPA, RMSE), the
  run-level track scores and the results table. Its time over 100 is the harness's
  overhead per step (``extra_info['per_step_s']`` is filled from the fastest round).
* ``test_kfnn_step``: KF-NN's own step (``predict``, ``update``, ``estimate``) on
  ``default`` after 50 raster steps of world 0, timed on 24 raster looks, as
  ``bench_trackers.py::test_tracker_step`` times it (the conftest's ``Warm``): the
  yardstick of the goal: harness per step below KF-NN's step.

Run: ``pytest benchmarks/bench/bench_harness.py --benchmark-only``; docs/result_store.md
has the figures.
"""

from __future__ import annotations

import pytest

from mttbench import scenarios
from mttbench.benchmarks.engine.loop import Job, play, run_job
from mttbench.benchmarks.engine.specs import TrackerSpec
from mttbench.trackers.kfnn import KFNNTracker
from mttbench.trackers.null import NullTracker

ROUNDS, WARMUP_ROUNDS = 20, 2
#: rounds of KF-NN's step (each after an untimed step: conftest Warm.repeat_step)
STEP_ROUNDS = 50
WARM_STEPS = 50


@pytest.mark.parametrize("name", ["default"])
def test_play_loop(benchmark, name):
    scenario = scenarios.get(name)
    state: dict = {}

    def setup():
        state["playback"] = play(scenario, NullTracker(), 0)

    def loop():
        n = 0
        for _ in state["playback"]:
            n += 1
        return n

    benchmark.extra_info.update(scenario=name, tracker="null", steps=scenario.n_steps)
    n = benchmark.pedantic(loop, setup=setup, rounds=ROUNDS, warmup_rounds=WARMUP_ROUNDS)
    assert n == scenario.n_steps


@pytest.mark.parametrize("name", ["default"])
def test_run_job(benchmark, name):
    job = Job(scenarios.get(name), TrackerSpec("null"))
    benchmark.extra_info.update(scenario=name, tracker="null", steps=job.scenario.n_steps)
    rows = benchmark.pedantic(run_job, args=(job,), rounds=ROUNDS, warmup_rounds=WARMUP_ROUNDS)
    assert len(rows) == job.scenario.n_steps
    assert (rows["status"] == "ok").all()
    if benchmark.stats is not None:  # None with --benchmark-disable
        benchmark.extra_info["per_step_s"] = benchmark.stats.stats.min / job.scenario.n_steps


@pytest.mark.parametrize("name", ["default"])
def test_kfnn_step(benchmark, warm_up, name):
    warm = warm_up(scenarios.get(name), KFNNTracker(), WARM_STEPS)
    setup, step, est = warm.repeat_step()
    benchmark.extra_info.update(scenario=name, tracker="kfnn", step=warm.step,
                                n_looks=len(warm.looks.cells), warm_policy="raster")
    result = benchmark.pedantic(step, setup=setup, rounds=STEP_ROUNDS, warmup_rounds=1)
    # the timed step gives the same estimate as the probe (same state, same random numbers)
    assert float(result.count) == float(est.count)
