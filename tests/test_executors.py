"""Executors (benchmarks/engine/executors.py): the local pool and a real Dask LocalCluster give the
same tables; a worker killed mid-sweep loses nothing; an interrupted Dask sweep resumes;
a run over its time limit ends, even one that freezes its worker; a cluster without
workers ends the sweep with error rows and its finished runs kept (dask_watch.py); the
command-line wiring and its one-line errors.

The trackers that kill their own worker process (:class:`KillOnce`, :class:`KillAlways`)
are named by class path (``test_executors:KillOnce``): Dask's worker processes and the
pool's import this module (``tests/`` is on their ``sys.path``). Each counts its deaths
with marker files in the folder :data:`KILL_DIR_ENV` names, and never kills the test
process itself.
"""

from __future__ import annotations

import concurrent.futures
import contextlib
import ctypes
import dataclasses
import errno
import logging
import os
import signal
import sys
import time
from pathlib import Path

import faulty_tracker
import pandas as pd
import pytest
from crashing_tracker import COUNT_LIMIT_ENV, COUNT_LOG_ENV, gate_env

from mttbench import scenarios
from mttbench.benchmarks.app.cli import main
from mttbench.benchmarks.engine import dask_watch, executors
from mttbench.benchmarks.engine import sweep as harness
from mttbench.benchmarks.engine.dask_watch import (
    NO_WORKER_FLOOR_S,
    SILENCE_FLOOR_S,
    RunWatch,
    no_worker_limit,
)
from mttbench.benchmarks.engine.errors import ConfigError
from mttbench.benchmarks.engine.executors import (
    MISSING_DASK,
    DaskExecutor,
    Executor,
    LocalExecutor,
)
from mttbench.benchmarks.engine.loop import build_jobs
from mttbench.benchmarks.engine.specs import TrackerSpec
from mttbench.benchmarks.engine.sweep import run_sweep
from mttbench.trackers.kfnn import KFNNTracker

TIMING = ["tracker_wall_s", "tracker_cpu_s", "select_wall_s", "select_cpu_s", "peak_rss_mb"]
#: environment variables: the marker folder, and the pid that must never be killed
KILL_DIR_ENV = "MTTBENCH_TEST_KILL_DIR"
KILL_SPARE_ENV = "MTTBENCH_TEST_KILL_SPARE_PID"
#: the step at which a killing tracker kills its process (mid-run)
KILL_STEP = 2
#: how long to wait for the cluster to release cancelled tasks
SETTLE_S = 30.0
#: a safety net for a sweep run beside the test: far beyond what it takes when the
#: executor works; its value decides nothing else
SWEEP_SAFETY_S = 180.0
#: Dask's lost-worker-timeout (seconds) in the tests of a worker's restart: shorter than
#: any restart (a process start and imports: over 3 s of CPU), so a cluster that kept
#: Dask's setting would lose the restarted worker every time, not only under load
QUICK_LOSS_S = 0.1


class KillOnce(KFNNTracker):
    """KF-NN that SIGKILLs its own process at step :data:`KILL_STEP` of its first
    ``deaths`` runs (counted by marker files; one run of the class per sweep); its
    numbers are KF-NN's."""

    name = "test-kill-once"
    deaths = 1

    def reset(self, model, rng):
        super().reset(model, rng)
        self._steps = 0

    def predict(self):
        super().predict()
        self._steps += 1
        folder = os.environ.get(KILL_DIR_ENV)
        if self._steps != KILL_STEP or not folder:
            return
        done = len(list(Path(folder).glob(f"{type(self).__name__}.*")))
        if done < self.deaths:
            if str(os.getpid()) == os.environ.get(KILL_SPARE_ENV):
                raise RuntimeError("a killing tracker ran in the test process")
            (Path(folder) / f"{type(self).__name__}.{done}").touch()
            os.kill(os.getpid(), signal.SIGKILL)


class KillAlways(KillOnce):
    name = "test-kill-always"
    deaths = sys.maxsize


class HoldTheGIL(faulty_tracker.Hang):
    """Hangs at step 1 inside a C call that keeps the GIL (as a compiled loop that never
    returns would): its process's other threads, a Dask worker's event loop among them,
    stop. Capped at :data:`GIL_HOLD_S`, after which the run goes on and finishes, so
    that a failing test ends."""

    name = "test-hold-the-gil"

    def fault(self):
        ctypes.PyDLL(None).sleep(ctypes.c_uint(GIL_HOLD_S))


#: how long :class:`HoldTheGIL` holds the GIL (seconds)
GIL_HOLD_S = 150
#: --run-timeout of the hang tests on Dask: far above a null run's time on a loaded
#: machine (a run on a fresh Dask worker took over 2 s at load 18)
HANG_LIMIT_S = 8.0


def short(name: str, n_steps: int) -> scenarios.Scenario:
    return dataclasses.replace(scenarios.get(name), n_steps=n_steps)


def jobs_of(scenario: scenarios.Scenario, runs: list[tuple[str, list[int]]]) -> list:
    """The jobs of ``(tracker spec text, seeds)`` pairs on ``scenario``."""
    return [job for text, seeds in runs
            for job in build_jobs([scenario], [TrackerSpec.parse(text)], None, None, seeds)]


def strip(df: pd.DataFrame) -> pd.DataFrame:
    return df.drop(columns=TIMING).reset_index(drop=True)


def deaths(folder: Path, cls: type) -> int:
    return len(list(folder.glob(f"{cls.__name__}.*")))


@pytest.fixture
def kill_dir(tmp_path, monkeypatch):
    """The marker folder, in the environment of every process started from here on."""
    folder = tmp_path / "markers"
    folder.mkdir()
    monkeypatch.setenv(KILL_DIR_ENV, str(folder))
    monkeypatch.setenv(KILL_SPARE_ENV, str(os.getpid()))
    return folder


@pytest.fixture(scope="module")
def dask_two():
    """A LocalCluster of 2 worker processes (1 thread each), shared by the module."""
    pytest.importorskip("distributed", reason="distributed is not installed (mttbench[dask])")
    import dask

    mp = pytest.MonkeyPatch()
    # the kill tests' markers: the workers read the variables when they start (a
    # restarted worker inherits them too), so they are set before the cluster starts
    folder = Path(os.environ.get("TMPDIR", "/tmp")) / f"mttbench-kill-{os.getpid()}"
    folder.mkdir(exist_ok=True)
    mp.setenv(KILL_DIR_ENV, str(folder))
    mp.setenv(KILL_SPARE_ENV, str(os.getpid()))
    # (a worker killed by a test comes back however slow its restart: QUICK_LOSS_S)
    quick_loss = dask.config.set({"distributed.deploy.lost-worker-timeout": QUICK_LOSS_S})
    executor = DaskExecutor(workers=2)
    assert executor.client is not None  # started now, with the variables
    mp.undo()
    executor.kill_dir = folder
    yield executor
    executor.close()
    quick_loss.__exit__(None, None, None)
    for marker in folder.iterdir():
        marker.unlink()
    folder.rmdir()


def reference(jobs, folder: Path) -> pd.DataFrame:
    """The local executor's table (one worker, in this process)."""
    return run_sweep(jobs, folder, executor=LocalExecutor(1))


# ------------------------------------------------------------------ same numbers
def test_dask_sweep_equals_the_local_executor(dask_two, tmp_path):
    jobs = build_jobs([short("default", 8)], [
        TrackerSpec("null"), TrackerSpec("kfnn"), TrackerSpec("gpf"),
        TrackerSpec("crashing_tracker:Crash")], None, None, [0, 1])
    jobs += build_jobs([short("superposition", 4)], [TrackerSpec("null")], None, None, [0])
    on_dask = run_sweep(jobs, tmp_path / "dask", executor=dask_two)
    local = reference(list(reversed(jobs)), tmp_path / "local")
    pd.testing.assert_frame_equal(strip(on_dask), strip(local))
    # every run has its part, written by this process, and the tables on disk agree
    parts = sorted((tmp_path / "dask" / "parts").glob("*.parquet"))
    assert len(parts) == len(jobs)
    for part in parts:
        pd.testing.assert_frame_equal(
            strip(pd.read_parquet(part)),
            strip(pd.read_parquet(tmp_path / "local" / "parts" / part.name)))
    pd.testing.assert_frame_equal(*(strip(pd.read_parquet(tmp_path / kind / "results.parquet"))
                                    for kind in ("dask", "local")))
    # the crashing tracker's error rows are results, the same on both executors
    crash = on_dask[on_dask["tracker"] == "crashing_tracker:Crash"]
    assert (crash["status"] == "error").sum() == 2 and (on_dask["status"] != "error").sum() > 0


def test_a_worker_killed_mid_sweep_loses_nothing_on_dask(dask_two, tmp_path):
    folder = dask_two.kill_dir
    before = set(dask_two.client.nthreads())
    jobs = jobs_of(short("default", 10), [("test_executors:KillOnce", [0]),
                                          ("kfnn", [0, 1, 2]), ("null", [0, 1])])
    on_dask = run_sweep(jobs, tmp_path / "dask", executor=dask_two)
    assert deaths(folder, KillOnce) == 1  # one worker died mid-run ...
    assert (on_dask["status"] == "ok").all()  # ... and every run finished
    assert len(list((tmp_path / "dask" / "parts").glob("*.parquet"))) == len(jobs)
    # the retried runs' numbers (KillOnce is KF-NN) are the local executor's
    local = reference(jobs, tmp_path / "local")  # the markers exist: nothing dies here
    pd.testing.assert_frame_equal(strip(on_dask), strip(local))
    # the nanny restarted the worker, which ignores Ctrl-C like the others (the preload)
    # and runs without the profiler (the cluster's configuration)
    # (a restart took 45 s at load 18: the wait is a safety net, not a requirement)
    dask_two.client.wait_for_workers(2, timeout=SWEEP_SAFETY_S)
    after = set(dask_two.client.nthreads())
    assert len(after) == 2 and after != before
    handlers = dask_two.client.run(lambda: signal.getsignal(signal.SIGINT))
    assert set(handlers.values()) == {signal.SIG_IGN}
    profiling = dask_two.client.run(
        lambda: __import__("dask").config.get("distributed.worker.profile.enabled"))
    assert set(profiling.values()) == {False}


def test_a_run_that_kills_every_retry_gets_its_error_row_on_dask(kill_dir, tmp_path):
    """The kfnn runs wait for the nanny to restart the killed worker. Dask's own
    lost-worker-timeout is set far below any restart here: the executor's cluster must
    not close a nanny whose restart is slower (it would be left without workers)."""
    pytest.importorskip("distributed", reason="distributed is not installed (mttbench[dask])")
    import dask

    jobs = jobs_of(short("default", 6), [("test_executors:KillOnce", [0]), ("kfnn", [0, 1])])
    # no retry: KillOnce's one death is its run's last chance (kfnn runs are untouched)
    with (dask.config.set({"distributed.deploy.lost-worker-timeout": QUICK_LOSS_S}),
          DaskExecutor(workers=1, retries=0) as executor):
        first = run_sweep(jobs, tmp_path / "out", executor=executor)
        failed = first[first["status"] == "error"]
        assert len(failed) == 1 and failed["tracker"].iloc[0] == "test_executors:KillOnce"
        assert failed["step"].iloc[0] == -1 and "KilledWorker" in failed["error"].iloc[0]
        assert (first[first["tracker"] == "kfnn"]["status"] == "ok").all()
        assert len(list((tmp_path / "out" / "parts").glob("*.parquet"))) == len(jobs) - 1
        # the failed run has no part: --resume runs it again (its worker lives now)
        again = run_sweep(jobs, tmp_path / "out", executor=executor,
                          resume=True)
    assert deaths(kill_dir, KillOnce) == 1 and (again["status"] == "ok").all()
    pd.testing.assert_frame_equal(strip(again), strip(reference(jobs, tmp_path / "local")))


class Interrupting(Executor):
    """Passes ``inner``'s outcomes on and raises KeyboardInterrupt at the ``at``-th (as a
    Ctrl-C in the sweep's loop would)."""

    def __init__(self, inner: Executor, at: int) -> None:
        self.inner, self.at = inner, at

    def run(self, todo, work):
        with contextlib.closing(self.inner.run(todo, work)) as outcomes:
            for n, outcome in enumerate(outcomes):
                if n == self.at:
                    raise KeyboardInterrupt
                yield outcome


def assert_timed_out(out: pd.DataFrame, tracker: str) -> None:
    """``tracker``'s one run ended at its wall-time limit: an error row that says so."""
    rows = out[out["tracker"] == tracker]
    assert len(rows) == 1 and rows["status"].iloc[0] == "error", list(rows["error"])
    assert "timed out" in rows["error"].iloc[0] and "--run-timeout" in rows["error"].iloc[0]


def test_a_hung_run_gets_its_error_row_on_dask(dask_two, tmp_path):
    """--run-timeout on Dask: a run on its worker for longer than the limit is cancelled
    and its worker restarted; it gets its error row (no retry), the others finish, and the
    cluster has its workers again for the next sweep. On the module's cluster (two
    workers, as the cluster of its own that it started before: that start was most of
    the test's time); the restart is one more of that cluster's, as the kill test's."""
    jobs = jobs_of(short("default", 6), [("faulty_tracker:Hang", [0]), ("null", [0, 1])])
    # the limit: far above what a null run takes on a loaded machine (a hang exceeds any
    # limit), so that it decides nothing for them
    out = run_sweep(jobs, tmp_path / "out", executor=dask_two, run_timeout=HANG_LIMIT_S)
    assert_timed_out(out, "faulty_tracker:Hang")
    assert (out[out["tracker"] == "null"]["status"] == "ok").all(), list(out["error"])
    # the restarted worker imports everything again on its first run: the limit here
    # only needs to let the cluster show it has its workers back
    again = run_sweep(jobs[1:], tmp_path / "again", executor=dask_two, run_timeout=60.0)
    assert (again["status"] == "ok").all()


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="libc's sleep through ctypes")
def test_a_run_that_freezes_its_worker_is_ended_at_its_time_limit_on_dask(tmp_path,
                                                                          monkeypatch):
    """A run holding the GIL freezes its Dask worker (no heartbeat, no answer to a call):
    its limit still holds (the scheduler's view, dask_watch.py), it gets its error row,
    and the other runs finish on the restarted worker. One worker and three runs: the
    scheduler gives the worker one run at a time, so no other run waits on it. The
    silence floor (20 s, for a fresh worker's imports on a loaded machine) lowered to the
    run limit: this cluster's worker imports before it takes a run (dask_setup), and the
    wait is what the test would otherwise spend most of its time on."""
    pytest.importorskip("distributed", reason="distributed is not installed (mttbench[dask])")
    monkeypatch.setattr(dask_watch, "SILENCE_FLOOR_S", HANG_LIMIT_S)
    jobs = jobs_of(short("default", 6), [("test_executors:HoldTheGIL", [0]), ("null", [0, 1])])
    with DaskExecutor(workers=1) as executor:
        out = run_sweep(jobs, tmp_path / "out", executor=executor, run_timeout=HANG_LIMIT_S)
    # (a call that ended by itself would let the run finish: status ok)
    assert_timed_out(out, "test_executors:HoldTheGIL")
    # ended by the worker's silence: a frozen worker never reports the run executing
    assert "sent no heartbeat" in out.loc[out["status"] == "error", "error"].iloc[0]
    assert (out[out["tracker"] == "null"]["status"] == "ok").all()


# ------------------------------------------------------- a cluster without workers
def _counted_env(folder: Path, limit: int) -> dict[str, str]:
    """crashing_tracker:Counted's variables: its log, and after ``limit`` runs the gate
    (never opened here: the run waits there until its worker is killed)."""
    return {COUNT_LOG_ENV: str(folder / "log"), COUNT_LIMIT_ENV: str(limit),
            **gate_env(folder / "gate")}


def _logged(folder: Path) -> list[int]:
    log = folder / "log"
    return [int(x) for x in log.read_text().split()] if log.exists() else []


def _wait_until(condition, what: str, sweep: concurrent.futures.Future) -> None:
    deadline = time.monotonic() + SWEEP_SAFETY_S  # a safety net: see SWEEP_SAFETY_S
    while not condition():
        if sweep.done():
            sweep.result()  # its error, if it failed
            raise AssertionError(f"the sweep ended before {what}")
        assert time.monotonic() < deadline, f"no {what}"
        time.sleep(0.02)


def test_a_dask_cluster_that_lost_its_workers_ends_the_sweep_and_resume_finishes(
        tmp_path, monkeypatch):
    """The worker of a one-worker cluster is killed mid-run and its nanny does not
    restart it (as when the restart fails on a loaded machine): the sweep ends after the
    no-worker limit, the runs still waiting get error rows that say why, the finished
    runs keep their parts (the rows of an uninterrupted local-pool sweep), and --resume
    runs only the missing ones."""
    distributed = pytest.importorskip("distributed",
                                      reason="distributed is not installed (mttbench[dask])")
    for name, value in _counted_env(tmp_path, limit=2).items():
        monkeypatch.setenv(name, value)  # before the workers start: they inherit them
    jobs = jobs_of(short("default", 3), [("crashing_tracker:Counted", [0, 1, 2, 3])])
    out = tmp_path / "out"
    with contextlib.ExitStack() as stack:
        cluster = stack.enter_context(distributed.LocalCluster(
            n_workers=1, threads_per_worker=1, processes=True, dashboard_address=None,
            silence_logs=logging.CRITICAL))
        client = stack.enter_context(distributed.Client(cluster, set_as_default=False))
        executor = DaskExecutor(client=client, no_worker_timeout=1.0)
        pool = stack.enter_context(concurrent.futures.ThreadPoolExecutor(1))
        sweep = pool.submit(run_sweep, jobs, out, executor=executor)
        # two runs finish (one at a time: four runs on one thread), the third waits at
        # the gate; then its worker dies and its nanny lets it go
        _wait_until(lambda: len(_logged(tmp_path)) == 3
                    and len(list((out / "parts").glob("*.parquet"))) == 2,
                    "third run waiting after two finished", sweep)
        (nanny,) = cluster.workers.values()
        nanny.close_gracefully()  # the nanny does not restart the worker it loses
        os.kill(_logged(tmp_path)[-1], signal.SIGKILL)
        first = sweep.result(timeout=SWEEP_SAFETY_S)
        assert client.nthreads() == {}
    done = {p: p.stat().st_mtime_ns for p in (out / "parts").glob("*.parquet")}
    assert len(done) == 2
    ok = first[first["status"] == "ok"]
    failed = first[first["status"] == "error"]
    assert ok["seed"].nunique() == 2 and len(failed) == 2 and (failed["step"] == -1).all()
    assert set(ok["seed"]) | set(failed["seed"]) == {0, 1, 2, 3}
    assert failed["error"].str.contains(
        "the Dask cluster had no worker for 1 s (--no-worker-timeout); --resume",
        regex=False).all(), list(failed["error"])
    # the finished runs' rows are those of an uninterrupted local-pool sweep of them
    monkeypatch.setenv(COUNT_LIMIT_ENV, "0")  # from here on no run waits at the gate
    finished = [job for job in jobs if job.seed in set(ok["seed"])]
    pd.testing.assert_frame_equal(strip(ok), strip(reference(finished, tmp_path / "ref")))
    # --resume runs the two missing runs only, and the table is the uninterrupted one
    logged = len(_logged(tmp_path))
    again = run_sweep(jobs, out, executor=LocalExecutor(1), resume=True)
    assert len(_logged(tmp_path)) == logged + 2
    assert {p: p.stat().st_mtime_ns for p in done} == done
    pd.testing.assert_frame_equal(strip(again), strip(reference(jobs, tmp_path / "whole")))


def test_a_scheduler_without_workers_ends_the_run_command_then_resume_finishes(
        tmp_path, capsys):
    """``mttbench run --executor dask --scheduler ...`` on a scheduler that has no worker:
    exit status 1 and every run an error row after --no-worker-timeout, with the resume
    advice; once a worker joins, the printed --resume finishes the sweep on it."""
    distributed = pytest.importorskip("distributed",
                                      reason="distributed is not installed (mttbench[dask])")
    args = ["run", "--scenarios", "default", "--trackers", "null", "kfnn", "--seeds", "2",
            "--steps", "4", "--no-progress", "--out", str(tmp_path / "dask"), "--executor",
            "dask", "--no-worker-timeout", "0.5"]
    with (distributed.LocalCluster(n_workers=0, threads_per_worker=1, processes=True,
                                   dashboard_address=None,
                                   silence_logs=logging.CRITICAL) as cluster,
          distributed.Client(cluster, set_as_default=False) as client):
        address = ["--scheduler", cluster.scheduler_address]
        assert main([*args, *address]) == 1
        err = [x for x in capsys.readouterr().err.splitlines() if x.strip()]
        assert err[-1].startswith("4 of 4 runs failed; first error: "), err
        assert ("the Dask cluster had no worker for 0.5 s (--no-worker-timeout); --resume "
                "runs this run again") in err[-1], err
        table = pd.read_parquet(tmp_path / "dask" / "results.parquet")
        assert len(table) == 4 and (table["status"] == "error").all()
        assert not list((tmp_path / "dask" / "parts").glob("*.parquet"))
        cluster.scale(1)
        client.wait_for_workers(1, timeout=SWEEP_SAFETY_S)  # a safety net
        assert main([*args, *address, "--resume"]) == 0, capsys.readouterr().err
    assert main([*args[:-6], "--out", str(tmp_path / "local"), "--workers", "1"]) == 0
    pd.testing.assert_frame_equal(
        strip(pd.read_parquet(tmp_path / "dask" / "results.parquet")),
        strip(pd.read_parquet(tmp_path / "local" / "results.parquet")))


def test_the_watch_ages_runs_and_counts_the_time_without_workers():
    """dask_watch.RunWatch on made-up views of the scheduler (worker, seconds executing
    at its last heartbeat or None, seconds since that heartbeat)."""
    watch = RunWatch(run_timeout=5.0, no_worker_s=3.0)
    a, b = "mttbench-run-t-0", "mttbench-run-t-1"
    # a executing on w1 from t=0; b held by w2 (queued there, or frozen before a report)
    assert watch.check((2, {a: ("w1", 0.1, 0.2), b: ("w2", None, 0.3)}), {a, b}, 0.0) == (
        [], False)
    assert watch.check((2, {a: ("w1", 4.0, 0.2), b: ("w2", None, 4.0)}), {a, b}, 4.9)[0] == []
    over, _ = watch.check((2, {a: ("w1", 5.0, 0.2), b: ("w2", None, 5.2)}), {a, b}, 5.1)
    assert [(key, worker) for key, worker, _ in over] == [(a, "w1")]
    assert "ended after 5 s of wall time (--run-timeout)" in over[0][2]
    # a worker silent since before it reported b: over once past the silence floor too
    quiet = {b: ("w2", None, SILENCE_FLOOR_S + 0.5)}
    assert watch.check((2, quiet), {b}, SILENCE_FLOOR_S - 0.1)[0] == []
    over, _ = watch.check((2, quiet), {b}, SILENCE_FLOOR_S + 0.2)
    assert [key for key, _, _ in over] == [b] and "sent no heartbeat" in over[0][2]
    # a run moved to another worker (its first died) counts from its new start there
    moved = RunWatch(run_timeout=5.0, no_worker_s=3.0)
    moved.check((2, {a: ("w1", 1.0, 0.1)}), {a}, 0.0)
    moved.check((1, {}), {a}, 4.0)  # back in the scheduler's queue
    moved.check((1, {a: ("w2", 0.5, 0.1)}), {a}, 4.5)
    assert moved.check((1, {a: ("w2", 6.0, 0.1)}), {a}, 9.4)[0] == []
    assert moved.check((1, {a: ("w2", 6.0, 0.1)}), {a}, 9.6)[0] != []
    # no worker: the runs end after no_worker_s without one, counted from the first view
    # without; a worker seen meanwhile starts the count again
    empty = RunWatch(run_timeout=None, no_worker_s=3.0)
    assert empty.check((0, {}), {a}, 10.0) == ([], False)
    assert empty.check((1, {}), {a}, 12.0) == ([], False)
    assert empty.check((0, {}), {a}, 12.5) == ([], False)
    assert empty.check((0, {}), {a}, 15.4) == ([], False)
    assert empty.check((0, {}), {a}, 15.5) == ([], True)
    assert empty.check((0, {}), set(), 20.0) == ([], False)  # nothing waits: nothing ends
    # the default limit: the run's limit, at least the floor
    assert no_worker_limit(None, None) == NO_WORKER_FLOOR_S
    assert no_worker_limit(None, 3 * NO_WORKER_FLOOR_S) == 3 * NO_WORKER_FLOOR_S
    assert no_worker_limit(2.5, 3 * NO_WORKER_FLOOR_S) == 2.5


def test_an_interrupted_dask_sweep_resumes(dask_two, tmp_path):
    jobs = build_jobs([short("default", 30)], [TrackerSpec("kfnn"), TrackerSpec("null")],
                      None, None, [0, 1, 2, 3])
    out = tmp_path / "out"
    with pytest.raises(KeyboardInterrupt):
        run_sweep(jobs, out, executor=Interrupting(dask_two, at=2))
    # three runs came back (the third's part is written before it is handed on), the
    # rest were cancelled: the scheduler forgets them
    done = {p: p.stat().st_mtime_ns for p in (out / "parts").glob("*.parquet")}
    assert len(done) == 3 and not list(out.rglob("*.tmp"))
    deadline = time.monotonic() + SETTLE_S
    while _our_tasks(dask_two) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert not _our_tasks(dask_two)
    again = run_sweep(jobs, out, executor=dask_two, resume=True)
    assert {p: p.stat().st_mtime_ns for p in done} == done  # not recomputed
    assert len(list((out / "parts").glob("*.parquet"))) == len(jobs)
    pd.testing.assert_frame_equal(strip(again), strip(reference(jobs, tmp_path / "local")))


def test_a_part_that_cannot_be_written_stops_a_dask_sweep(dask_two, tmp_path, monkeypatch):
    jobs = build_jobs([short("default", 20)], [TrackerSpec("kfnn")], None, None, range(6))
    written = []

    def full_after_two(path, data):
        if len(written) == 2:
            raise OSError(errno.ENOSPC, "No space left on device", str(path))
        written.append(path)
        real(path, data)

    real = harness._write_bytes
    monkeypatch.setattr(harness, "_write_bytes", full_after_two)
    with pytest.raises(OSError, match="No space left"):
        run_sweep(jobs, tmp_path / "out", executor=dask_two)
    assert sorted((tmp_path / "out" / "parts").glob("*.parquet")) == sorted(written)
    deadline = time.monotonic() + SETTLE_S
    while _our_tasks(dask_two) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert not _our_tasks(dask_two)  # the rest were cancelled


def _our_tasks(executor: DaskExecutor) -> list[str]:
    return executor.client.run_on_scheduler(
        lambda dask_scheduler: [str(k) for k in dask_scheduler.tasks
                                if str(k).startswith(executors.TASK_PREFIX)])


# ------------------------------------------------------------------- local pool
def test_the_local_pool_retries_a_run_whose_worker_died(kill_dir, tmp_path, monkeypatch):
    jobs = jobs_of(short("default", 8), [("test_executors:KillOnce", [0]),
                                         ("test_executors:KillAlways", [0]),
                                         ("kfnn", [0, 1, 2])])
    # retries=1: KillOnce dies once and finishes on its retry; KillAlways dies on its
    # retry too and gets its error row
    out = run_sweep(jobs, tmp_path / "pool", executor=LocalExecutor(2, retries=1))
    assert deaths(kill_dir, KillOnce) == 1 and deaths(kill_dir, KillAlways) >= 2
    failed = out[out["status"] == "error"]
    assert list(failed["tracker"]) == ["test_executors:KillAlways"]
    assert failed["step"].iloc[0] == -1 and "BrokenProcessPool" in failed["error"].iloc[0]
    assert "died 2 time(s)" in failed["error"].iloc[0]
    # every other run finished (those lost with a broken pool went again, uncharged) and
    # has its part; the failed one has none
    assert (out[out["status"] != "error"]["status"] == "ok").all()
    assert out.groupby(["tracker", "seed"]).ngroups == len(jobs)
    parts = tmp_path / "pool" / "parts"
    done = {p: p.stat().st_mtime_ns for p in parts.glob("*.parquet")}
    assert len(done) == len(jobs) - 1
    # --resume runs only it again; without the marker folder it lives: the serial table
    monkeypatch.delenv(KILL_DIR_ENV)
    again = run_sweep(jobs, tmp_path / "pool", executor=LocalExecutor(2),
                      resume=True)
    assert {p: p.stat().st_mtime_ns for p in done} == done
    pd.testing.assert_frame_equal(strip(again), strip(reference(jobs, tmp_path / "local")))


# ------------------------------------------------------------------ command line
def test_run_on_an_existing_scheduler(dask_two, tmp_path, capsys):
    address = dask_two.client.scheduler.address
    dask_two.client.get_task_stream()  # the scheduler records tasks from here on
    t0 = time.time()
    args = ["run", "--scenarios", "default", "--trackers", "null", "kfnn", "--seeds", "2",
            "--steps", "5", "--no-progress", "--out"]
    assert main([*args, str(tmp_path / "dask"), "--executor", "dask",
                 "--scheduler", address]) == 0
    err = capsys.readouterr().err
    assert f"4 runs on the Dask cluster at {address} -> {tmp_path / 'dask'}" in err
    # the runs went to the cluster's workers
    stream = dask_two.client.get_task_stream(start=t0)
    assert sum(str(t["key"]).startswith(executors.TASK_PREFIX) for t in stream) == 4
    assert main([*args, str(tmp_path / "local"), "--workers", "1"]) == 0
    pd.testing.assert_frame_equal(
        strip(pd.read_parquet(tmp_path / "dask" / "results.parquet")),
        strip(pd.read_parquet(tmp_path / "local" / "results.parquet")))


@pytest.mark.parametrize("how", ["scheduler", "client"])
def test_workers_with_other_sources_are_refused(dask_two, monkeypatch, how):
    monkeypatch.setattr(executors, "source_digest", lambda: "0123456789abcdef")
    executor = (DaskExecutor(scheduler=dask_two.client.scheduler.address) if how == "scheduler"
                else DaskExecutor(client=dask_two.client))
    with pytest.raises(ConfigError, match=r"runs mttbench .* this process .*0123456789abcdef"):
        executor.client  # noqa: B018 - connecting checks the workers
    executor.close()
    assert dask_two.client.status == "running"  # a caller's client is the caller's to close


def test_a_callers_client_runs_the_sweep(dask_two, tmp_path):
    jobs = build_jobs([short("crossing", 6)], [TrackerSpec("kfnn")], None, None, [0, 1, 2])
    with DaskExecutor(client=dask_two.client) as executor:
        assert executor.describe() == f"the Dask cluster at {dask_two.client.scheduler.address}"
        on_dask = run_sweep(jobs, tmp_path / "dask", executor=executor)
    assert dask_two.client.status == "running"
    pd.testing.assert_frame_equal(strip(on_dask), strip(reference(jobs, tmp_path / "local")))


def test_an_unreachable_scheduler_is_one_line():
    pytest.importorskip("distributed", reason="distributed is not installed (mttbench[dask])")
    import socket

    with socket.socket() as sock:  # a port where nothing listens
        sock.bind(("127.0.0.1", 0))
        port = sock.getsockname()[1]
    executor = DaskExecutor(scheduler=f"tcp://127.0.0.1:{port}", connect_timeout=0.5)
    with pytest.raises(ConfigError, match=f"cannot reach the Dask scheduler at tcp://127.0.0.1:"
                                         f"{port}: ") as info:
        executor.client  # noqa: B018
    assert "\n" not in str(info.value)


def test_missing_distributed_is_one_line(monkeypatch, tmp_path, capsys):
    monkeypatch.setitem(sys.modules, "distributed", None)  # import distributed fails
    with pytest.raises(ConfigError, match="pip install 'mttbench\\[dask\\]'"):
        DaskExecutor(workers=2)
    out = tmp_path / "never"
    assert main(["run", "--scenarios", "default", "--trackers", "null", "--out", str(out),
                 "--executor", "dask"]) == 2
    err = capsys.readouterr().err
    assert err == f"mttbench run: error: {MISSING_DASK}\n" and not out.exists()


@pytest.mark.parametrize("extra, message", [
    (["--scheduler", "tcp://127.0.0.1:8786"], "--scheduler needs --executor dask"),
    (["--retries", "-1"], "--retries -1 is not allowed"),
    (["--executor", "dask", "--scheduler", "tcp://127.0.0.1:8786", "--workers", "2"],
     "give one of them"),
    (["--no-worker-timeout", "30"], "--no-worker-timeout needs --executor dask"),
    (["--executor", "dask", "--no-worker-timeout", "0"], "--no-worker-timeout 0.0 is not allowed"),
    (["--executor", "dask", "--no-worker-timeout", "nan"],
     "--no-worker-timeout nan is not allowed"),
])
def test_bad_executor_options_are_refused(extra, message, tmp_path, capsys):
    if "dask" in extra:
        pytest.importorskip("distributed", reason="distributed is not installed")
    out = tmp_path / "never"
    assert main(["run", "--scenarios", "default", "--trackers", "null", "--out", str(out),
                 *extra]) == 2
    err = capsys.readouterr().err
    assert message in err and len(err.splitlines()) == 1 and not out.exists()


def test_every_sweep_command_takes_the_executor_options():
    import argparse

    from mttbench.benchmarks.app.cli import build_parser

    parser = build_parser()
    (commands,) = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    # export and score draw or score worlds in the calling process: not sweeps
    sweeps = set(commands.choices) - {"scenarios", "trackers", "screenshot", "export", "score"}
    assert {"run", "compare", "reproduce"} <= sweeps
    for name in sorted(sweeps):
        options = {o for a in commands.choices[name]._actions for o in a.option_strings}
        assert {"--executor", "--scheduler", "--retries", "--workers",
                "--no-worker-timeout"} <= options, name
    args = parser.parse_args(["compare", "--executor", "dask", "--scheduler", "tcp://h:1",
                              "--retries", "5"])
    assert (args.executor, args.scheduler, args.retries) == ("dask", "tcp://h:1", 5)
