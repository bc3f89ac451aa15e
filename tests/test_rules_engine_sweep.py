"""Rules of the sweep (benchmarks/engine/sweep.py) on the batched dataset, with an
executor that runs every task in this process (or loses the ones a test says): batches
group by tracker name, a batch task's time limit is the run limit times its runs,
progress counts runs, a lost batch of several runs goes again one run per task, and a
lost run's row is the error row at step -1."""

from __future__ import annotations

import dataclasses

import pytest

from mttbench.benchmarks.engine import sweep
from mttbench.benchmarks.engine.executors import Executor
from mttbench.benchmarks.engine.loop import Job
from mttbench.benchmarks.engine.specs import TrackerSpec
from mttbench.scenarios import get as get_scenario


class InProcess(Executor):
    """Runs each task here, in order; a task of more than ``lose_above`` runs is lost."""

    def __init__(self, lose_above: int | None = None) -> None:
        self.lose_above = lose_above
        self.timeouts: list[float | None] = []
        self.sizes: list[int] = []

    def describe(self, n_runs=None):
        return "this process"

    def run(self, todo, work):
        self.timeouts.append(work.timeout)
        for i, (job, part) in enumerate(todo):
            self.sizes.append(len(job) if hasattr(job, "__len__") else 1)
            if self.lose_above is not None and len(job) > self.lose_above:
                yield i, "worker failed: lost"
                continue
            work(job, part)
            yield i, None


@pytest.fixture
def jobs():
    sc = dataclasses.replace(get_scenario("single-clean"), n_steps=3)
    return [Job(sc, TrackerSpec("null"), seed=s) for s in range(3)]


def test_batches_group_by_tracker_name_whatever_the_parameters(tmp_path):
    sc = dataclasses.replace(get_scenario("single-clean"), n_steps=3)
    specs = [TrackerSpec("renyi-x", {}), TrackerSpec("renyi-x", {"a": 1})]
    js = [Job(sc, s, seed=0) for s in specs]
    keys = ["a" * 24, "b" * 24]
    batches = sweep.make_batches(js, keys, tmp_path, runs_per_batch=10)
    assert len(batches) == 1 and batches[0][0].keys == tuple(keys)
    assert batches[0][1].parent.name == "tracker=renyi-x"


def test_a_dataset_sweep_limits_a_task_by_its_runs_and_counts_progress_in_runs(jobs,
                                                                              tmp_path):
    ex, seen = InProcess(), []
    runs = sweep.run_sweep(jobs, tmp_path, executor=ex, store="dataset", run_timeout=2.0,
                           runs_per_batch=3, progress=lambda f, t: seen.append((f, t)))
    assert ex.sizes == [3] and ex.timeouts == [6.0]  # one task of 3 runs: 3 x 2 s
    assert seen == [(0, 3), (3, 3)]
    assert runs["status"].tolist() == ["ok"] * 3


def test_a_lost_batch_of_two_runs_goes_again_one_run_per_task(jobs, tmp_path):
    ex = InProcess(lose_above=1)
    runs = sweep.run_sweep(jobs[:2], tmp_path, executor=ex, store="dataset",
                           runs_per_batch=2)
    assert ex.sizes == [2, 1, 1]
    assert sorted(runs["seed"].tolist()) == [0, 1] and set(runs["status"]) == {"ok"}


def test_a_run_lost_for_good_gets_the_error_row_at_step_minus_one(jobs):
    row = sweep._lost_job_frame(jobs[0], "worker failed: gone", None, 2.0)
    assert len(row) == 1
    assert (row["step"].iloc[0], row["status"].iloc[0], row["error"].iloc[0]) == (
        -1, "error", "worker failed: gone")
    assert row["ospa_c"].iloc[0] == 2.0  # two cells of 1


def test_a_dataset_run_lost_for_good_is_in_the_runs_table_as_an_error(jobs, tmp_path):
    runs = sweep.run_sweep(jobs[:1], tmp_path, executor=InProcess(lose_above=0),
                           store="dataset", runs_per_batch=1)
    assert runs["status"].tolist() == ["error"]
    assert runs["error"].tolist() == ["worker failed: lost"]


def test_a_resumed_part_holding_another_runs_rows_is_run_again(jobs, tmp_path, capsys):
    ex = InProcess()
    sweep.run_sweep(jobs[:2], tmp_path, executor=ex)
    parts = [tmp_path / "parts" / f"{j.key(None, 2.0)}.parquet" for j in jobs[:2]]
    parts[0].write_bytes(parts[1].read_bytes())  # job 0's part now holds job 1's rows
    ex.sizes.clear()
    df = sweep.run_sweep(jobs[:2], tmp_path, executor=ex, resume=True)
    assert len(ex.sizes) == 1  # job 0 only, run again
    assert sorted(set(zip(df["seed"], df["step"], strict=True))) == [
        (s, k) for s in (0, 1) for k in range(3)]
    assert "1 damaged part file(s) will be recomputed" in capsys.readouterr().err
