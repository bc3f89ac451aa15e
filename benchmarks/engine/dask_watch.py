"""What the Dask executor watches while a sweep's runs wait: each run's wall time on its
worker (the ``--run-timeout`` limit) and whether the cluster still has a worker (the
``--no-worker-timeout`` limit).

Both are read from the scheduler, never from the workers: a worker whose run holds the
GIL (a compiled loop that never returns) cannot answer a call, and a cluster whose
workers are all gone (killed, and their nannies unable to restart them; or a scheduler
that never gets one) has nobody to ask. The scheduler knows, for each worker, the runs
it holds, which of them its last heartbeat reported executing, and when that heartbeat
came.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import Any

#: the shortest time (seconds) a cluster may have no worker while runs wait, whatever
#: the run limit: a worker restarted on a loaded machine starts a process and imports
#: numpy, pandas and mttbench before it registers again (seen: 45 s at load 18 on 2
#: cores, docs/dask.md)
NO_WORKER_FLOOR_S = 180.0

#: one run as the scheduler sees it: (its worker's address, seconds it had been
#: executing at the worker's last heartbeat or None if not reported executing then,
#: seconds since that heartbeat)
RunView = tuple[str, float | None, float]


def no_worker_limit(given: float | None, run_timeout: float | None) -> float:
    """How long (seconds) the cluster may have no worker while runs wait: ``given``,
    else the run's wall-time limit, at least :data:`NO_WORKER_FLOOR_S`."""
    if given is not None:
        return float(given)
    return max(NO_WORKER_FLOOR_S, run_timeout or 0.0)


def no_worker_message(limit: float) -> str:
    """The error row of a run that was pending when the watch gave up on the cluster."""
    return (f"the Dask cluster had no worker for {limit:g} s (--no-worker-timeout); "
            "--resume runs this run again")


def make_scheduler_view() -> Callable[[str, Any], tuple[int, dict[str, RunView]]]:
    """The function that ``client.run_on_scheduler(view, prefix)`` runs on the scheduler
    (which passes itself as ``dask_scheduler``):
    ``(workers able to run, {key: RunView})`` for the tasks whose key starts with
    ``prefix`` that a worker holds.

    Made inside this function so that cloudpickle sends its code rather than its name:
    the scheduler of an existing cluster need not have mttbench installed."""

    def view(prefix: str, dask_scheduler: Any) -> tuple[int, dict[str, RunView]]:
        import time

        now = time.time()  # the scheduler's clock, as its heartbeat times
        running = 0
        runs: dict[str, RunView] = {}
        for ws in list(dask_scheduler.workers.values()):
            # a worker closing or paused takes no run
            running += getattr(ws.status, "name", "") == "running"
            silent = max(0.0, now - ws.last_seen)
            executing = {str(ts.key): float(s) for ts, s in dict(ws.executing).items()}
            for ts in list(ws.processing):
                key = str(ts.key)
                if key.startswith(prefix):
                    runs[key] = (ws.address, executing.get(key), silent)
        return running, runs

    return view


#: a worker that has sent no heartbeat for this long (seconds) is frozen, not slow: a
#: worker sends one every 0.5-1 s (every few seconds on a cluster of hundreds); a fresh
#: worker's first run importing numba on a loaded machine silenced it for over 10 s
#: (our LocalCluster's workers import it before their first run: dask_setup)
SILENCE_FLOOR_S = 20.0


@dataclass
class RunWatch:
    """The state of one sweep's watch. :meth:`check` takes the scheduler's view at client
    time ``now`` (``time.monotonic()``) and says which runs are over their limit and
    whether the cluster has had no worker for too long.

    A run's time counts from the first view that shows it executing on its worker (as
    the worker's last heartbeat said). A run held by a worker that stopped sending
    heartbeats before reporting it (frozen in the run, e.g. a compiled loop holding
    the GIL) counts the worker's silence, from when the run was first seen on it, and
    is over its limit once that exceeds both the limit and :data:`SILENCE_FLOOR_S`."""

    run_timeout: float | None
    no_worker_s: float
    #: run -> (its worker, client time it was first seen held by it)
    _held: dict[str, tuple[str, float]] = field(default_factory=dict)
    #: run -> (its worker, client time it was first seen executing there)
    _executing: dict[str, tuple[str, float]] = field(default_factory=dict)
    #: client time of the first view without a worker (None: the last view had one)
    _empty_since: float | None = None

    def check(self, view: tuple[int, dict[str, RunView]], pending: Iterable[str],
              now: float) -> tuple[list[tuple[str, str, str]], bool]:
        """For the runs ``pending``: ``(the runs over the time limit as (key, worker,
        error message), whether the cluster has had no worker able to run for
        no_worker_s seconds)``."""
        workers, runs = view
        pending = set(pending)
        held = pending & set(runs)
        for key in set(self._held) - held:  # finished, or back in the scheduler's queue
            del self._held[key]
            self._executing.pop(key, None)
        overdue = []
        for key in sorted(held):
            worker, executing_s, silent_s = runs[key]
            if self._held.get(key, ("",))[0] != worker:  # first seen there (or again)
                self._held[key] = (worker, now)
                self._executing.pop(key, None)
            if executing_s is not None and key not in self._executing:
                self._executing[key] = (worker, now)
            message = self._over(key, silent_s, now)
            if message:
                overdue.append((key, worker, message))
        if workers:
            self._empty_since = None
            return overdue, False
        if self._empty_since is None:
            self._empty_since = now
        return overdue, bool(pending) and now - self._empty_since >= self.no_worker_s

    def _over(self, key: str, silent_s: float, now: float) -> str | None:
        """The error message of ``key`` if it is over its limit, else None."""
        limit = self.run_timeout
        if limit is None:
            return None
        if key in self._executing:
            if now - self._executing[key][1] > limit:
                return f"timed out: ended after {limit:g} s of wall time (--run-timeout)"
            return None
        silent = min(silent_s, now - self._held[key][1])
        if silent > max(limit, SILENCE_FLOOR_S):
            # a worker may hold a run queued behind another (Dask gives a worker more
            # runs than threads in small sweeps and by default): this one may not have run
            return (f"timed out: its Dask worker sent no heartbeat for {silent:.0f} s while "
                    "holding this run (--run-timeout); --resume runs it again")
        return None
