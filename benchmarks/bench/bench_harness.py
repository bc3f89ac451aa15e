"""Runtime of the harness itself, with the ``null`` tracker (whose steps cost nothing),
so that what is timed is the harness's own overhead.

* ``test_play_loop``: the 100 steps of the step loop (:func:`~mttbench.benchmarks.engine.
  loop.play`) on ``default`` (12x12 cells, 3 targets, 24 raster looks), world 0: per step
  the raster's cells, the world's looks, the eight clock reads and the step's record. The
  world's simulation and the tracker's ``reset`` (in ``play``) are each round's untimed
  setup.
* ``test_run_job``: one whole job on ``default`` (:func:`~mttbench.benchmarks.engine.loop.
  run_job`): the simulation, the loop, the metrics of every step (OSPA, GOSPA, RMSE)
  and the results table. About 8 ms and 20 ms on the development machine.

Run: ``pytest benchmarks/bench/bench_harness.py --benchmark-only``.
"""

from __future__ import annotations

import pytest

from mttbench import scenarios
from mttbench.benchmarks.engine.loop import Job, play, run_job
from mttbench.benchmarks.engine.specs import TrackerSpec
from mttbench.trackers.null import NullTracker

ROUNDS, WARMUP_ROUNDS = 20, 2


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
