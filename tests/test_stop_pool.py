""":func:`executors.stop_pool` (an interrupted sweep's pool): when it returns, the
workers are gone and so is the pool's manager thread, whose wake-up pipe CPython 3.11's
exit hook (``concurrent.futures.process._python_exit``) writes to unless it is closed. An
exit while that thread was still closing the pipe printed an ``OSError: [Errno 9] Bad
file descriptor`` traceback after a Ctrl-C (seen once in the interrupt test)."""

from __future__ import annotations

import concurrent.futures
import multiprocessing
import time

from mttbench.benchmarks.engine import executors


def test_the_pool_and_its_manager_thread_are_gone_when_stop_pool_returns():
    # three pools: without the wait the thread was still running after 9 of 10 stops
    for _ in range(3):
        pool = concurrent.futures.ProcessPoolExecutor(
            max_workers=2, mp_context=multiprocessing.get_context())
        futures = [pool.submit(time.sleep, 60) for _ in range(4)]
        deadline = time.monotonic() + 60
        while sum(p.is_alive() for p in (pool._processes or {}).values()) < 2:
            assert time.monotonic() < deadline, "the workers did not start"
            time.sleep(0.01)
        manager = pool._executor_manager_thread
        wakeup = pool._executor_manager_thread_wakeup
        procs = list(pool._processes.values())
        executors.stop_pool(pool)
        assert not any(p.is_alive() for p in procs)
        assert not manager.is_alive()
        assert wakeup._closed  # the exit hook skips a closed pipe
        assert all(f.done() for f in futures)
