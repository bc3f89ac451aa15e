"""A sweep that survives the death of its own process (real subprocesses, real signals).

``crashing_tracker:Counted`` logs each run it starts (its worker's pid) and, past a limit,
waits for a gate file: so the test knows which run a worker holds when it kills the main
process alone. The worker must die with it (else it would hold the run's pipe and the
folder's lock for good), ``--resume`` must then finish at once with the same table as an
uninterrupted sweep, and runs finished inside a dataset batch must not run again.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pandas as pd
import pytest
from crashing_tracker import COUNT_LIMIT_ENV, COUNT_LOG_ENV, alive, gate_env

from mttbench.benchmarks.app.cli import main
from mttbench.benchmarks.engine.store import LOCK_FILE, load_results
from mttbench.benchmarks.engine.sweep import CHECKPOINT_ENV

TESTS = Path(__file__).resolve().parent
TIMING = ["tracker_wall_s", "tracker_cpu_s", "select_wall_s", "select_cpu_s", "peak_rss_mb"]
#: generous: a subprocess imports numpy, pandas, scipy and numba before its first run
START_TIMEOUT_S = 120
#: how long a worker may outlive its killed parent (the watchdog polls every second)
DIE_TIMEOUT_S = 10

pytestmark = pytest.mark.skipif(sys.platform == "win32", reason="POSIX signals and flock")


def _args(out: Path, seeds: int, store: str = "parts", executor: str = "local") -> list[str]:
    return ["run", "--scenarios", "default", "--trackers", "null", "crashing_tracker:Counted",
            "--seeds", str(seeds), "--steps", "3", "--workers", "1", "--no-progress",
            "--retries", "0", "--store", store, "--executor", executor, "--out", str(out)]


def _env(tmp: Path, limit: int) -> dict[str, str]:
    path = os.pathsep.join(p for p in (str(TESTS), os.environ.get("PYTHONPATH", "")) if p)
    return {**os.environ, "PYTHONPATH": path, COUNT_LOG_ENV: str(tmp / "log"),
            COUNT_LIMIT_ENV: str(limit), **gate_env(tmp / "gate"), CHECKPOINT_ENV: "0"}


def _log(tmp: Path) -> list[int]:
    path = tmp / "log"
    return [int(x) for x in path.read_text().split()] if path.exists() else []


def _start(args: list[str], env: dict[str, str]) -> subprocess.Popen:
    """The command in a new session: its process group (the main process's pid) holds
    every process it starts, however they are started (forked, spawned)."""
    return subprocess.Popen([sys.executable, "-m", "mttbench", *args], env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True)


def _group(pgid: int) -> list[int]:
    """The live processes of process group ``pgid`` (zombies left out)."""
    out = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if int(fields[2]) == pgid and fields[0] not in ("Z", "X"):
            out.append(int(stat.parent.name))
    return out


def _wait_for_runs(tmp: Path, n: int, proc: subprocess.Popen) -> int:
    """Wait until ``n`` runs were logged (the last one waits at the gate); its worker."""
    deadline = time.monotonic() + START_TIMEOUT_S
    while len(_log(tmp)) < n:
        assert proc.poll() is None, proc.communicate()
        assert time.monotonic() < deadline, "the sweep did not reach its gated run"
        time.sleep(0.02)
    return _log(tmp)[-1]


def _kill_main_alone(proc: subprocess.Popen, sig: int, worker: int) -> bool:
    """Send ``sig`` to the main process only; whether its worker died with it."""
    proc.send_signal(sig)
    proc.wait(timeout=START_TIMEOUT_S)  # not its pipes: a leftover worker holds them
    for pipe in (proc.stdout, proc.stderr):
        pipe.close()
    deadline = time.monotonic() + DIE_TIMEOUT_S
    while alive(worker) and time.monotonic() < deadline:
        time.sleep(0.05)
    gone = not alive(worker)
    if not gone:  # a leftover of the test's own sweep: end it, then fail
        os.kill(worker, signal.SIGKILL)
    return gone


def _table(out: Path) -> pd.DataFrame:
    df = load_results(out).drop(columns=TIMING)
    return df.sort_values(["tracker_label", "seed", "step"]).reset_index(drop=True)


@pytest.mark.parametrize("store, kills", [
    ("parts", [signal.SIGKILL]),
    ("dataset", [signal.SIGTERM, signal.SIGKILL]),
], ids=["parts-sigkill", "dataset-sigterm-then-sigkill"])
def test_killing_the_main_process_alone_ends_its_worker_and_resume_finishes(
        tmp_path, monkeypatch, capsys, store, kills):
    """Each session finishes one more ``Counted`` run, then waits on the next until its
    main process is killed; the runs it finished are kept (inside a dataset batch too,
    by its checkpoints) and never run again."""
    out = tmp_path / "out"
    seeds = len(kills) + 1
    for i, sig in enumerate(kills):
        args = _args(out, seeds, store) + (["--resume"] if i else [])
        proc = _start(args, _env(tmp_path, limit=2 * i + 1))
        worker = _wait_for_runs(tmp_path, 2 * i + 2, proc)
        assert _kill_main_alone(proc, sig, worker), "its worker outlived the main process"
    (tmp_path / "gate").touch()
    for name, value in _env(tmp_path, 0).items():
        monkeypatch.setenv(name, value)
    started = time.monotonic()
    assert main([*_args(out, seeds, store), "--resume"]) == 0, capsys.readouterr().err
    assert "in use" not in capsys.readouterr().err
    assert time.monotonic() - started < START_TIMEOUT_S
    # every session but the last ran one run again (the one it was killed in): the runs
    # finished before a kill are kept
    assert len(_log(tmp_path)) == 2 * len(kills) + 1
    whole = tmp_path / "whole"
    assert main(_args(whole, seeds, store)) == 0
    pd.testing.assert_frame_equal(_table(out), _table(whole))
    if store == "dataset":  # the checkpoints of a finished batch are gone
        assert len(list((out / "dataset").rglob("batch-*.parquet"))) <= 2 + len(kills)


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="reads /proc")
def test_killing_the_main_process_of_a_dask_sweep_leaves_no_process_and_resume_finishes(
        tmp_path, monkeypatch, capsys):
    """``--executor dask`` (a LocalCluster of one worker process): the main process is
    killed while its worker waits in a run; every process it started (the worker, the
    resource tracker) ends within seconds, the folder is free, and ``--resume`` finishes
    the table of an uninterrupted sweep. (The resume and the uninterrupted sweep run on
    the local pool, which gives the same numbers, without a second cluster's start-up;
    test_executors resumes on Dask.)"""
    pytest.importorskip("distributed", reason="distributed is not installed (mttbench[dask])")
    out = tmp_path / "out"
    proc = _start(_args(out, 2, executor="dask"), _env(tmp_path, limit=1))
    worker = _wait_for_runs(tmp_path, 2, proc)
    assert worker != proc.pid  # the run is in a worker process of the cluster
    # the main process writes the parts of the runs the cluster finished: wait for the
    # three before the gated run (null's two, Counted's first)
    deadline = time.monotonic() + START_TIMEOUT_S
    while len(list((out / "parts").glob("*.parquet"))) < 3:
        assert proc.poll() is None and time.monotonic() < deadline, "no third part"
        time.sleep(0.02)
    proc.send_signal(signal.SIGKILL)
    proc.wait(timeout=START_TIMEOUT_S)
    for pipe in (proc.stdout, proc.stderr):
        pipe.close()
    deadline = time.monotonic() + DIE_TIMEOUT_S
    while _group(proc.pid) and time.monotonic() < deadline:
        time.sleep(0.05)
    left = _group(proc.pid)
    for pid in left:  # a leftover of the test's own sweep: end it, then fail
        os.kill(pid, signal.SIGKILL)
    assert not left, f"processes outlived the killed main process: {left}"
    (tmp_path / "gate").touch()
    for name, value in _env(tmp_path, 0).items():
        monkeypatch.setenv(name, value)
    assert main([*_args(out, 2), "--resume"]) == 0, capsys.readouterr().err
    assert "in use" not in capsys.readouterr().err
    assert len(_log(tmp_path)) == 3  # the killed run again, the finished one kept
    whole = tmp_path / "whole"
    assert main(_args(whole, 2)) == 0
    pd.testing.assert_frame_equal(_table(out), _table(whole))


def test_a_folder_in_use_by_a_real_second_process_is_refused(tmp_path):
    out = tmp_path / "out"
    env = _env(tmp_path, limit=1)
    first = _start(_args(out, 2), env)
    try:
        _wait_for_runs(tmp_path, 2, first)
        second = subprocess.run([sys.executable, "-m", "mttbench", *_args(out, 2), "--resume"],
                                env=env, capture_output=True, text=True,
                                timeout=START_TIMEOUT_S)
        err = [x for x in second.stderr.splitlines() if x.strip()]
        assert second.returncode == 2, second.stderr
        assert len(err) == 1 and "in use by another mttbench process" in err[0], err
    finally:
        (tmp_path / "gate").touch()
        _, err = first.communicate(timeout=START_TIMEOUT_S)
    assert first.returncode == 0, err


#: a process that takes a folder's lock, forks a child that inherits it, and exits: the
#: child is what a worker of an older mttbench left behind (it prints its pid)
_LEAVE_AN_ORPHAN = """
import os, sys, time
from mttbench.benchmarks.engine.store import sweep_lock
with sweep_lock(sys.argv[1]):
    pid = os.fork()
    if pid == 0:
        null = os.open(os.devnull, os.O_RDWR)
        for fd in (0, 1, 2):
            os.dup2(null, fd)
        time.sleep(120)
        os._exit(0)
    print(pid, flush=True)
    os._exit(0)
"""


def test_a_stale_lock_whose_holder_is_gone_is_taken_over(tmp_path, capsys):
    out = tmp_path / "out"
    out.mkdir()
    done = subprocess.run([sys.executable, "-c", _LEAVE_AN_ORPHAN, str(out)],
                          capture_output=True, text=True, timeout=START_TIMEOUT_S)
    orphan = int(done.stdout.split()[0])
    try:
        assert alive(orphan)
        assert main(["run", "--scenarios", "default", "--trackers", "null", "--seeds", "1",
                     "--steps", "3", "--workers", "1", "--no-progress", "--out",
                     str(out)]) == 0
        err = [x for x in capsys.readouterr().err.splitlines() if LOCK_FILE in x]
        assert len(err) == 1 and "is gone; taking its lock over" in err[0], err
        assert str(out / LOCK_FILE) in err[0]
    finally:
        os.kill(orphan, signal.SIGKILL)
