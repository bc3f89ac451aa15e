"""The sweep's bookkeeping around its executor, in process: what a lost batch becomes, the
wall-time limit a batch task gets, where a resumed sweep's progress starts and the
checkpoint interval's environment variable.

The executor here runs each task in this process and loses the tasks it is told to
(an error instead of a file), so each rule is checked against the jobs' own keys and
batch sizes, not against another sweep's output.
"""

from __future__ import annotations

import pytest
from test_result_store import _jobs  # the runs on default, cut short

from mttbench.benchmarks.engine.errors import ConfigError
from mttbench.benchmarks.engine.executors import Executor
from mttbench.benchmarks.engine.sweep import CHECKPOINT_ENV, checkpoint_interval, run_sweep

N_STEPS = 3


class InProcess(Executor):
    """Runs every task here, in order; a task whose first job's tracker is in ``lose``
    is lost (its error, no file), as a task whose worker died for good. Records each
    round's wall-time limit and task sizes."""

    def __init__(self, lose: tuple[str, ...] = ()) -> None:
        self.lose = set(lose)
        self.rounds: list[tuple[float | None, list[int]]] = []

    def describe(self, n_runs=None) -> str:
        return "this process"

    def run(self, todo, work):
        self.rounds.append((work.timeout, [len(getattr(job, "jobs", [job]))
                                           for job, _ in todo]))
        for i, (job, path) in enumerate(todo):
            first = job.jobs[0] if hasattr(job, "jobs") else job
            if first.tracker.name in self.lose:
                yield i, "worker failed: lost for the test"
                continue
            work(job, path)
            yield i, None


@pytest.mark.parametrize("size", [2, 3])
def test_every_run_of_a_batch_lost_for_good_gets_its_own_error_row(tmp_path, size):
    """A lost batch of two or more runs goes again one run per task; lost again, each run
    has one error row: the per-run table holds every job once."""
    jobs = _jobs(("null", "kfnn"), range(size), N_STEPS)
    ex = InProcess(lose=("kfnn",))
    runs = run_sweep(jobs, tmp_path / "o", store="dataset", runs_per_batch=size, executor=ex)
    assert len(runs) == len(jobs)
    got = {(r.tracker, r.seed): r.status for r in runs.itertuples()}
    want = {(j.tracker.name, j.seed): "error" if j.tracker.name == "kfnn" else "ok"
            for j in jobs}
    assert got == want
    # the second round: the lost batch's runs one per task
    assert ex.rounds[1][1] == [1] * size


def test_a_batch_tasks_time_limit_is_the_run_limit_times_its_longest_batch(tmp_path):
    """Batches of 3 and 1 runs (4 jobs, 3 per batch) share one limit: 3 x run_timeout, so
    the longer batch is not ended early."""
    ex = InProcess()
    jobs = _jobs(("null",), range(4), N_STEPS)
    run_sweep(jobs, tmp_path / "o", store="dataset", runs_per_batch=3,
              executor=ex, run_timeout=7.0)
    assert ex.rounds == [(21.0, [3, 1])]


@pytest.mark.parametrize("store", ["parts", "dataset"])
def test_a_resumed_sweeps_progress_starts_at_the_runs_it_keeps(tmp_path, store):
    jobs = _jobs(("null",), range(4), N_STEPS)
    out = tmp_path / "o"
    run_sweep(jobs, out, store=store, runs_per_batch=1, executor=InProcess())
    files = sorted((out / ("parts" if store == "parts" else "dataset")).rglob("*.parquet"))
    assert len(files) == 4
    for f in files[:3]:
        f.unlink()
    calls: list[tuple[int, int]] = []
    run_sweep(jobs, out, store=store, runs_per_batch=1, executor=InProcess(), resume=True,
              progress=lambda done, total: calls.append((done, total)))
    assert calls == [(1, 4), (2, 4), (3, 4), (4, 4)]


def test_the_checkpoint_interval_reads_seconds_from_the_environment(monkeypatch):
    """Unset or blank: the default; 0 (after every run) and positive seconds as given;
    negative, infinite or not a number: refused in one line."""
    from mttbench.benchmarks.engine.sweep import CHECKPOINT_S

    monkeypatch.delenv(CHECKPOINT_ENV, raising=False)
    assert checkpoint_interval() == CHECKPOINT_S
    for text, value in [(" ", CHECKPOINT_S), ("0", 0.0), ("2.5", 2.5)]:
        monkeypatch.setenv(CHECKPOINT_ENV, text)
        assert checkpoint_interval() == value
    for text in ["-1", "inf", "nan", "soon"]:
        monkeypatch.setenv(CHECKPOINT_ENV, text)
        with pytest.raises(ConfigError, match=CHECKPOINT_ENV):
            checkpoint_interval()
