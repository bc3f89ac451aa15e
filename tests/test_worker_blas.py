"""A sweep's workers run BLAS on one thread, on the local pool and on a Dask cluster's
workers (one worker per core: helper threads would only compete with the other workers)."""

import json
import os
import subprocess
import sys
from pathlib import Path

from threadpoolctl import threadpool_info

from mttbench.benchmarks.engine.executors import LocalExecutor, Work


def _blas_threads() -> list[int]:
    return [lib["num_threads"] for lib in threadpool_info() if lib["user_api"] == "blas"]


def _threads_as_rows(job, c, p) -> list[int]:
    return _blas_threads()


def _record(rows, part: Path) -> None:
    part.write_text(json.dumps(rows))


WORK = Work(run_job=_threads_as_rows, write=_record, encode=None, write_bytes=None)


def test_local_pool_workers_run_blas_on_one_thread(tmp_path):
    parts = [tmp_path / f"{i}.json" for i in range(2)]
    outcomes = list(LocalExecutor(2).run([(None, part) for part in parts], WORK))
    assert [error for _, error in outcomes] == [None, None]
    for part in parts:
        threads = json.loads(part.read_text())
        assert threads and set(threads) == {1}, threads


def test_the_dask_preload_limits_blas_to_one_thread():
    # in a fresh process (the preload also ignores Ctrl-C, which this one must not)
    code = ("import json; from mttbench.benchmarks.engine.executors import dask_setup; "
            "from threadpoolctl import threadpool_info; dask_setup(None); "
            "print(json.dumps([lib['num_threads'] for lib in threadpool_info() "
            "if lib['user_api'] == 'blas']))")
    env = {k: v for k, v in os.environ.items() if not k.endswith("_NUM_THREADS")}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         env=env, timeout=120, check=True)
    threads = json.loads(out.stdout.splitlines()[-1])
    assert threads and set(threads) == {1}, threads
