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
* ``test_step_metrics_of_run``: the built-in per-step metrics (OSPA, GOSPA, RMSE, counts)
  of a whole finished run at once (:func:`~mttbench.benchmarks.engine.metrics.
  builtin_run_columns`, as ``run_job`` computes them), on KF-NN's 100 steps of
  ``default``, world 0.
* ``test_track_scores_of_run``: the run-level track scores and their per-step series of
  the same run (:func:`~mttbench.benchmarks.engine.metrics.run_level_metrics` and
  :func:`~mttbench.benchmarks.engine.track_series.series_values`: trajectory GOSPA,
  OSPA(2), CLEAR-MOT, crossings), on a fresh ``RunData`` each round (no cached parts).

Run: ``pytest benchmarks/bench/bench_harness.py --benchmark-only``; docs/result_store.md
has the figures.
"""

from __future__ import annotations

import pytest

from mttbench import scenarios
from mttbench.benchmarks.engine.loop import Job, play, run_job
from mttbench.benchmarks.engine.metrics import RunData, builtin_run_columns, run_level_metrics
from mttbench.benchmarks.engine.specs import TrackerSpec
from mttbench.benchmarks.engine.track_series import series_values
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


@pytest.fixture(scope="module")
def kfnn_run():
    """KF-NN's 100 steps of ``default``, world 0: per step the true positions and ids,
    the estimated positions, labels and count."""
    steps = [(rec.truth[:, [0, 2]], rec.truth_ids, rec.estimate.states[:, [0, 2]],
              rec.estimate.labels, float(rec.estimate.count))
             for rec in play(scenarios.get("default"), KFNNTracker(), 0)]
    return [list(column) for column in zip(*steps, strict=True)]


def test_step_metrics_of_run(benchmark, kfnn_run):
    truth, _, estimate, _, counts = kfnn_run
    benchmark.extra_info.update(scenario="default", tracker="kfnn", steps=len(truth))
    cols = benchmark.pedantic(builtin_run_columns, args=(truth, estimate, counts),
                              rounds=ROUNDS, warmup_rounds=WARMUP_ROUNDS)
    assert len(cols["ospa"]) == len(truth)


def test_track_scores_of_run(benchmark, kfnn_run):
    truth, ids, estimate, labels, _ = kfnn_run

    def scores():
        run = RunData(truth, ids, estimate, labels, c=2.0, p=2.0)
        return run_level_metrics(run), series_values(run)

    benchmark.extra_info.update(scenario="default", tracker="kfnn", steps=len(truth))
    values, series = benchmark.pedantic(scores, rounds=ROUNDS, warmup_rounds=WARMUP_ROUNDS)
    assert values["tgospa"] > 0 and len(series["ospa2_window"]) == len(truth)
