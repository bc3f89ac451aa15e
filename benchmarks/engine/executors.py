"""Where a sweep's runs execute: a local process pool, or a Dask cluster.

:func:`~mttbench.benchmarks.engine.sweep.run_sweep` hands an executor the runs still to do,
each with the part file it must end in, and consumes what :meth:`Executor.run` yields,
one ``(index, error)`` per run as it finishes: ``error`` is None once the part is
written, else the message of a run lost after its retries (the sweep gives it an
``error`` row that is not saved as a part, so ``--resume`` runs it again). Resume, the
summaries and the reports never see which executor ran: a run's rows depend only on
its job (:func:`~mttbench.benchmarks.engine.loop.run_job`), so both executors give the same
table bit for bit, timing and memory columns aside.

* :class:`LocalExecutor` (``--executor local``, the default): ``workers`` processes of
  this machine (``concurrent.futures``); each writes its own parts. Every run goes in a
  worker process, with one worker too. A run over its wall-time limit (``Work.timeout``,
  ``--run-timeout``) is killed and gets its error row (not retried). If a worker process
  dies (killed, out of memory, a crash in compiled code) the pool breaks and ends its
  other workers: the queued runs go to a fresh pool, and the runs that were running go
  again one at a time in a one-process pool, where a death is the run's own (so a run
  that kills its worker takes no other run down with it); a run whose own worker dies
  ``1 + retries`` times gets its error row.
* :class:`DaskExecutor` (``--executor dask``; the ``mttbench[dask]`` extra): the runs
  go to a ``dask.distributed`` cluster, an existing one (``--scheduler tcp://HOST:PORT``)
  or a ``LocalCluster`` of ``--workers`` processes with one thread each on this machine;
  each finished run's table comes back to this process (as its part file's Parquet
  bytes, encoded on the worker), which writes the part atomically. A worker that dies
  loses only the run it held (our LocalCluster gives a worker one run at a time:
  ``worker-saturation`` 1.0), and its nanny starts a new one, which our LocalCluster
  waits for however slow the start (:data:`LOST_WORKER_S`); the scheduler runs the
  lost run again elsewhere until it has been on
  ``1 + retries`` dying workers (the scheduler's
  ``allowed-failures``: set to ``retries`` on our LocalCluster; an existing cluster's
  scheduler keeps its own setting, Dask's default 3), then the run gets its error row
  (``KilledWorker``). A run that raises is retried ``retries`` times (``retries=`` of
  ``Client.submit``; :func:`~mttbench.benchmarks.engine.loop.run_job` itself turns a
  tracker's failure into rows, so this is for e.g. a worker that cannot load the job).
  A run executing on its worker for longer than its wall-time limit (``--run-timeout``,
  timed from when the scheduler first shows it executing, not from its queueing; a
  worker that stops sending heartbeats, e.g. frozen in a compiled loop that holds the
  GIL, ages the runs it holds by its silence) is cancelled and its worker restarted by
  its nanny, which ends the run: its error row, no retry. If the cluster has no worker
  able to run for ``no_worker_timeout`` seconds while runs wait
  (``--no-worker-timeout``; default the run's limit, at least 180 s: all workers killed
  and their nannies unable to restart them, or a scheduler that never gets one), every
  waiting run gets its error row and the sweep ends with its
  finished parts (:mod:`.dask_watch`).

A "job" here may be a batch of runs (:class:`~mttbench.benchmarks.engine.sweep.Batch`,
the dataset layout of docs/result_store.md): the executors treat it as one run (one
task, one file, its retries and wall-time limit), and the sweep splits a batch lost for
good into one-run tasks.

Ctrl-C (or a part that cannot be written) stops either executor: queued runs are
dropped, the local pool's running ones are ended, a Dask cluster's are released (a task
already running on an existing cluster's worker finishes there and is discarded), and
the finished parts stay.

The command line builds the executor once per command
(:func:`mttbench.benchmarks.app.executor_options.executor_scope`) and
makes it the current one (:func:`use_executor`): every ``run_sweep`` of the command
(``compare``, ``reproduce``, ``tune``'s batches) uses it, so a LocalCluster starts once.
"""

from __future__ import annotations

import contextlib
import ctypes
import hashlib
import logging
import math
import multiprocessing
import os
import signal
import sys
import threading
import time
import uuid
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from contextvars import ContextVar
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from .dask_watch import RunWatch, make_scheduler_view, no_worker_limit, no_worker_message
from .errors import ConfigError

if TYPE_CHECKING:
    from .loop import Job

#: retries of a lost run (a dead worker, or on Dask a run that raised); Dask's own default
DEFAULT_RETRIES = 3
EXECUTORS = ("local", "dask")
#: the one line shown when ``distributed`` is missing
MISSING_DASK = ("--executor dask needs the distributed package: "
                "pip install 'mttbench[dask]'")
#: a run's task key prefix on a Dask cluster (its task group, in Dask's dashboard)
TASK_PREFIX = "mttbench-run"
#: ``distributed.deploy.lost-worker-timeout`` (seconds) while our LocalCluster lives: how
#: long the cluster waits for a lost worker to register again before it closes its nanny
#: for good. Dask's default (15 s) is shorter than a restart on a loaded machine (a fresh
#: worker process imports some 600 modules: 3-4 s of CPU, over 15 s of wall time at load
#: 8 on 2 cores), so a slow restart cost the cluster that worker for the rest of the
#: command. A nanny whose restart fails closes itself, and the sweep's watch ends the
#: runs of a cluster without workers (``no_worker_timeout``): a day is "never" here.
LOST_WORKER_S = 24 * 3600.0

#: (index of the run in ``todo``, None once its part is written or the error message)
Outcome = tuple[int, str | None]


@dataclass(frozen=True)
class Work:
    """What one run is: ``rows = run_job(job, c, p)`` and its part written atomically,
    ``write(rows, part)`` where it ran (this machine), or ``encode(rows)`` (the part
    file's bytes) where it ran and ``write_bytes(part, bytes)`` where the parts are.
    :func:`~mttbench.benchmarks.engine.sweep.run_sweep` passes the harness's functions
    (module-level: they pickle by reference, and a Dask worker imports them from its own
    mttbench)."""

    run_job: Callable[[Job, float, float], Any]
    write: Callable[[Any, Path], None]
    encode: Callable[[Any, str], bytes]
    write_bytes: Callable[[Path, bytes], None]
    c: float | None = None  # None: 2 cells of each job's grid
    p: float = 2.0
    #: the wall-time limit of one run in seconds (None: none); the local pool kills a
    #: run that exceeds it, which gets its error row (not retried)
    timeout: float | None = None

    def __call__(self, job: Job, part: Path) -> None:
        self.write(self.run_job(job, self.c, self.p), part)

    def encoded(self, job: Job) -> bytes:
        return self.encode(self.run_job(job, self.c, self.p), job.key(self.c, self.p))


class Executor:
    """Runs a sweep's jobs (see the module docstring). A context manager: ``close``
    releases what it started (a Dask LocalCluster); it can run several sweeps before."""

    retries: int = DEFAULT_RETRIES

    def describe(self, n_runs: int | None = None) -> str:
        """Where ``n_runs`` runs go, for messages: ``2 worker(s)``, ``the Dask cluster at
        ...``."""
        raise NotImplementedError

    def run(self, todo: Sequence[tuple[Job, Path]], work: Work) -> Iterator[Outcome]:
        """Do ``work`` for every ``(job, part path)`` of ``todo``; yield ``(i, error)`` as
        each ends.

        Close the iterator (or let an exception through it) to stop: queued runs are
        dropped and running ones ended or released. An ``OSError`` of a part that cannot
        be written propagates."""
        raise NotImplementedError

    def close(self) -> None:
        """Release what the executor started; it is not used afterwards."""

    def __enter__(self) -> Executor:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


# ------------------------------------------------------------------ local processes
#: set in each pool worker by :func:`_init_worker`: where it says which run it starts
_STARTED: Any = None


#: how often (seconds) a pool worker checks that its parent is alive (the watchdog)
_WATCHDOG_S = 1.0


def _die_with_parent(parent: int, signal_ok: bool) -> None:
    """End this worker when its parent process ends (killed with ``SIGKILL`` or by the
    out-of-memory killer, so it could not stop its pool): on Linux the kernel sends it
    ``SIGKILL`` (``prctl(PR_SET_PDEATHSIG)``; only when the pool was made by the main
    thread, since the signal follows the thread that forked), and everywhere a daemon
    thread checks every :data:`_WATCHDOG_S` seconds that the parent pid is unchanged. A
    worker left behind would hold its run's pipe and the folder for good."""
    if signal_ok and sys.platform.startswith("linux"):
        with contextlib.suppress(Exception):
            libc = ctypes.CDLL(None, use_errno=True)
            libc.prctl(1, int(signal.SIGKILL), 0, 0, 0)  # 1: PR_SET_PDEATHSIG
    if os.getppid() != parent:  # the parent died before the signal was asked for
        os._exit(1)

    def watch() -> None:
        while os.getppid() == parent:
            time.sleep(_WATCHDOG_S)
        os._exit(1)

    threading.Thread(target=watch, name="mttbench-parent-watchdog", daemon=True).start()


def one_blas_thread() -> None:
    """Limit this process's BLAS to one thread. A sweep runs one worker per core, so a
    worker's BLAS helper threads only compete with the other workers; and OpenBLAS's
    helpers spin after each call, CPU time that the run's timing counts (jmpd-ap at
    16,000 particles on ``default``: a third of its CPU time, docs/speed.md). The
    trackers' BLAS calls (small matmuls, a dot of the weights) give the same numbers
    with one thread (docs/speed.md, "BLAS threads in the workers")."""
    import numpy  # noqa: F401  (loads the BLAS that the limit applies to)
    from threadpoolctl import threadpool_limits

    threadpool_limits(limits=1, user_api="blas")


def _init_worker(started: Any, parent: int | None = None, signal_ok: bool = False) -> None:
    """Pool worker initializer: Ctrl-C is the main process's to handle (it stops the
    pool); runs report their start on ``started`` (which runs a dead worker held); the
    worker ends with its parent (:func:`_die_with_parent`), holds none of its folder
    locks (:func:`~.store.release_inherited_locks`) and runs BLAS on one thread
    (:func:`one_blas_thread`)."""
    global _STARTED
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    one_blas_thread()
    _STARTED = started
    from .store import release_inherited_locks

    release_inherited_locks()
    if parent is not None:
        _die_with_parent(parent, signal_ok)


def _pool_task(i: int, work: Work, job: Job, part: Path) -> int:
    if _STARTED is not None:
        _STARTED.put((i, os.getpid(), time.monotonic()))
    work(job, part)
    return i


def _read_started(started: Any, into: dict[int, tuple[int, float]]) -> None:
    """Add what the workers put on ``started`` (run -> (pid, start time))."""
    while not started.empty():
        i, pid, t0 = started.get()
        into[i] = (pid, t0)


def _drain(started: Any) -> set[int]:
    """What the workers put on ``started`` (a ``SimpleQueue``), which is then closed."""
    out: dict[int, tuple[int, float]] = {}
    _read_started(started, out)
    started.close()
    return set(out)


#: how often (seconds) the local pool looks for a run over its time limit, and the Dask
#: executor for a finished run
_POLL_S = 0.2
#: how often (seconds) the Dask executor asks its scheduler about the runs it holds
_WATCH_S = 0.5


#: how long (seconds) a worker ended with SIGTERM may take to die before SIGKILL
_TERM_GRACE_S = 5.0


def stop_pool(pool: ProcessPoolExecutor) -> None:
    """Drop the queued tasks of ``pool`` and end the running ones now (an interrupt or a
    write error; a sweep's runs, a report's figures), and wait until every worker is gone:
    ``SIGTERM``, then ``SIGKILL`` for one that is still alive after :data:`_TERM_GRACE_S`
    (a loaded machine). A worker outliving the sweep could still write a part after it
    returned, beside a resumed sweep."""
    # the worker processes, read before shutdown() forgets them (a private attribute of
    # ProcessPoolExecutor; without it the running and already queued runs would finish)
    procs = list((getattr(pool, "_processes", None) or {}).values())
    manager = getattr(pool, "_executor_manager_thread", None)  # also forgotten by shutdown()
    pool.shutdown(wait=False, cancel_futures=True)
    for proc in procs:
        with contextlib.suppress(Exception):
            proc.terminate()
    deadline = time.monotonic() + _TERM_GRACE_S
    for proc in procs:
        with contextlib.suppress(Exception):
            proc.join(timeout=max(0.0, deadline - time.monotonic()))
    for proc in procs:
        with contextlib.suppress(Exception):
            if proc.is_alive():
                proc.kill()
                proc.join(timeout=_TERM_GRACE_S)
    # the pool's manager thread closes its wake-up pipe on its way out; CPython 3.11's exit
    # hook writes to that pipe unless it is closed, so an exit while the thread is closing
    # it prints an OSError traceback (EBADF): let the thread finish first
    if manager is not None:
        with contextlib.suppress(Exception):
            manager.join(timeout=_TERM_GRACE_S)


class LocalExecutor(Executor):
    """``workers`` processes of this machine (every run in a worker process)."""

    def __init__(self, workers: int = 1, retries: int = DEFAULT_RETRIES) -> None:
        self.workers = max(1, int(workers))
        self.retries = check_retries(retries)

    def describe(self, n_runs: int | None = None) -> str:
        return f"{min(self.workers, n_runs or self.workers)} worker(s)"

    def run(self, todo: Sequence[tuple[Job, Path]], work: Work) -> Iterator[Outcome]:
        # every run in a worker process, one worker included: a run that ends its
        # process (SIGKILL, out of memory, os._exit) or hangs takes no sweep with it
        if not todo:
            return
        deaths = [0] * len(todo)
        clear, suspects = list(range(len(todo))), []
        while clear or suspects:
            # the runs a broken pool was running go again one at a time, so that a
            # death is the run's own; the others (queued) in a full pool first
            alone = not clear
            batch = suspects if alone else clear
            lost: dict[int, str] = {}
            finished: set[int] = set()
            ctx = multiprocessing.get_context()
            started = ctx.SimpleQueue()
            in_main = threading.current_thread() is threading.main_thread()
            # a forkserver's workers are its children, not this process's: no watch
            parent = None if ctx.get_start_method() == "forkserver" else os.getpid()
            pool = ProcessPoolExecutor(max_workers=1 if alone else min(self.workers, len(batch)),
                                       mp_context=ctx, initializer=_init_worker,
                                       initargs=(started, parent, in_main))
            running: dict[int, tuple[int, float]] = {}  # run -> (worker pid, its start)
            timed_out: dict[int, str] = {}
            try:
                futures = {pool.submit(_pool_task, i, work, *todo[i]): i for i in batch}
                pending = set(futures)
                while pending:
                    ended, pending = wait(pending, timeout=_POLL_S,
                                          return_when=FIRST_COMPLETED)
                    for fut in sorted(ended, key=lambda f: batch.index(futures[f])):
                        i = futures[fut]
                        try:
                            fut.result()
                        except OSError:  # the part could not be written: stop the sweep
                            raise
                        except BrokenProcessPool as exc:  # a worker died: see below
                            lost[i] = _lost(exc)
                            continue
                        except Exception as exc:  # noqa: BLE001 - e.g. a job that cannot pickle
                            yield i, _lost(exc)
                            continue
                        finished.add(i)
                        yield i, None
                    if work.timeout is not None and pending:
                        _read_started(started, running)
                        now = time.monotonic()
                        for i, (pid, t0) in running.items():
                            if (i in finished or i in lost or i in timed_out
                                    or now - t0 <= work.timeout):
                                continue
                            timed_out[i] = (f"timed out: ended after {work.timeout:g} s "
                                            "of wall time (--run-timeout)")
                            with contextlib.suppress(OSError):
                                os.kill(pid, signal.SIGKILL)
            except BaseException:
                # Ctrl-C, a write error or the caller closing: drop the queued runs and end
                # the running ones instead of waiting for them
                stop_pool(pool)
                started.close()
                raise
            pool.shutdown()
            held = set(running) | _drain(started)  # the runs this pool started
            for i in sorted(timed_out):  # its own fault: its error row, no retry
                lost.pop(i, None)
                yield i, timed_out[i]
            if not lost:
                clear, suspects = ([], []) if alone else ([], suspects)
                continue
            # the runs the pool was running when it broke: started and not finished (a
            # worker that died before saying so: the first lost run, in submission order)
            held = (held - finished) & set(lost) or (
                set() if timed_out else {min(lost, key=batch.index)})
            again = []
            for i in sorted(lost):
                if alone and i in held:
                    deaths[i] += 1
                    if deaths[i] > self.retries:
                        yield i, f"{lost[i]} (its worker died {deaths[i]} time(s))"
                        continue
                again.append(i)
            if alone:
                suspects = again
            else:
                clear = [i for i in again if i not in held]
                suspects = sorted({*suspects, *(i for i in again if i in held)})


# ---------------------------------------------------------------------------- Dask
def import_distributed() -> Any:
    """The ``distributed`` module, or :class:`ConfigError` naming the extra to install."""
    try:
        import distributed
    except ImportError:
        raise ConfigError(MISSING_DASK) from None
    return distributed


#: the installed packages whose files :func:`source_digest` reads, with their patterns
SOURCE_PACKAGES = {
    "mttbench": "*.py", "mttbench.trackers": "*.py", "mttbench.trackers.jmpd": "*.py",
    "mttbench.scenarios": "*.py", "mttbench.scenarios.presets": "*.toml",
    "mttbench.benchmarks": "*.py",
}


def source_digest() -> str:
    """SHA-256 over the installed mttbench's version and sources (a Dask worker must run
    the same); the same for a checkout and a plain install of it."""
    import importlib

    import mttbench

    h = hashlib.sha256(mttbench.__version__.encode())
    for name, pattern in SOURCE_PACKAGES.items():
        package = importlib.import_module(name)
        for path in sorted(Path(next(iter(package.__path__))).glob(pattern)):
            h.update(f"{name}/{path.name}".encode())
            h.update(path.read_bytes())
    return h.hexdigest()[:16]


@contextlib.contextmanager
def _sigint_ignored() -> Iterator[None]:
    """Ignore Ctrl-C meanwhile (in the main thread only: elsewhere nothing changes)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)


def dask_setup(worker: Any) -> None:
    """Preload of our LocalCluster's worker processes: Ctrl-C is the client's to handle,
    and the modules every run needs (pandas, pyarrow, numba: some 600) are imported
    before the worker takes a run. Else a fresh worker's first run pays for them in its
    wall time, and numba's initialisation, holding the GIL, silences the worker's
    heartbeats for seconds on a loaded machine (the run limit reads them). BLAS runs on
    one thread, as in the local pool's workers (:func:`one_blas_thread`)."""
    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGINT, signal.SIG_IGN)
    one_blas_thread()
    import importlib

    # by name: a warm-up of what a run imports, not a dependency of this module (the sweep
    # imports the executors)
    for name in ("loop", "sweep"):
        importlib.import_module(f"{__package__}.{name}")


def _worker_identity() -> tuple[str, str]:
    """Run on each Dask worker: its mttbench version and :func:`source_digest`."""
    import mttbench

    return mttbench.__version__, source_digest()


class DaskExecutor(Executor):
    """Runs on a Dask cluster: ``scheduler`` an address (``tcp://HOST:PORT``), or
    ``client`` a ``distributed.Client`` of the caller's (kept open by :meth:`close`,
    e.g. of a dask-jobqueue or dask-kubernetes cluster), or neither: a ``LocalCluster``
    of ``workers`` processes (default: the number of CPUs) with one thread each, started
    at the first sweep and ended by :meth:`close`. ``connect_timeout`` (seconds) None
    means Dask's ``distributed.comm.timeouts.connect``. ``no_worker_timeout`` (seconds):
    how long the cluster may have no worker while runs wait before they get their
    error rows; None: the run's wall-time limit, at least
    :data:`~.dask_watch.NO_WORKER_FLOOR_S`.

    An existing cluster's workers are checked at connection: each must import the same
    mttbench (version and :func:`source_digest`), else :class:`ConfigError`.
    """

    def __init__(self, scheduler: str | None = None, workers: int | None = None,
                 retries: int = DEFAULT_RETRIES, client: Any = None,
                 connect_timeout: float | None = None,
                 no_worker_timeout: float | None = None) -> None:
        import_distributed()
        if scheduler and workers:
            raise ConfigError("--workers starts a LocalCluster and --scheduler names an "
                             "existing cluster: give one of them")
        if workers is not None and int(workers) < 1:
            raise ConfigError(f"--workers {workers} is not allowed: expected an integer >= 1")
        self.scheduler = scheduler
        self.workers = None if scheduler or client is not None else int(
            workers or os.cpu_count() or 1)
        self.retries = check_retries(retries)
        self.connect_timeout = connect_timeout
        self.no_worker_timeout = check_no_worker_timeout(no_worker_timeout)
        self._client = client
        self._own_client = client is None
        self._checked = False
        self._cluster: Any = None
        self._lost_worker: Any = None  # the dask.config.set to undo at close()

    def describe(self, n_runs: int | None = None) -> str:
        if self.workers is not None:
            return f"a Dask LocalCluster of {self.workers} worker(s)"
        if self.scheduler:
            return f"the Dask cluster at {self.scheduler}"
        return f"the Dask cluster at {self._client.scheduler.address}"

    @property
    def client(self) -> Any:
        """The ``distributed.Client`` (connecting, or starting the LocalCluster, once)."""
        if self._client is None:
            self._client = self._start()
        elif not self._checked:  # the caller's client
            self._check_workers(self._client)
            self._checked = True
        return self._client

    def _start(self) -> Any:
        import dask

        distributed = import_distributed()
        if self.workers is not None:
            # one run per worker thread at a time (no run waits on a worker behind
            # another, so a dying worker takes no queued run with it); no memory limit
            # of the nanny (the local pool has none; resources.check_jobs checks first);
            # no statistical profiler in the workers (it samples the running run's stack
            # every 10 ms for a dashboard we do not start: measured 3-9% of a gpf run).
            # Ctrl-C is this process's to handle (it closes the cluster): the worker
            # processes ignore it, from their start (the disposition is inherited) and
            # after a restart (the preload, dask_setup below)
            # (the workers' setting goes through the nannies' config, which a restarted
            # worker gets too; a dask.config.set here would reach only the first ones)
            # the cluster reads lost-worker-timeout whenever a worker goes (a nanny's
            # restart), so it is set until close() rather than around the start
            self._lost_worker = dask.config.set(
                {"distributed.deploy.lost-worker-timeout": LOST_WORKER_S})
            with (dask.config.set({"distributed.scheduler.worker-saturation": 1.0}),
                  _sigint_ignored()):
                self._cluster = distributed.LocalCluster(
                    n_workers=self.workers, threads_per_worker=1, processes=True,
                    dashboard_address=None, memory_limit=0, silence_logs=logging.CRITICAL,
                    # no dashboard, and its HTTP server on a free port (not 8787)
                    scheduler_kwargs={"allowed_failures": self.retries,
                                      "dashboard_address": "127.0.0.1:0"},
                    config={"distributed.worker.profile.enabled": False},
                    preload=[__name__])
            self._checked = True  # workers of this installation
            return distributed.Client(self._cluster, set_as_default=False)
        try:
            timeout = {} if self.connect_timeout is None else {"timeout": self.connect_timeout}
            client = distributed.Client(self.scheduler, set_as_default=False, **timeout)
        except Exception as exc:  # noqa: BLE001 - OSError, TimeoutError, ValueError
            raise ConfigError(f"cannot reach the Dask scheduler at {self.scheduler}: "
                             f"{_one_line(exc)}") from None
        try:
            self._check_workers(client)
        except BaseException:
            client.close()
            raise
        self._checked = True
        return client

    def _check_workers(self, client: Any) -> None:
        mine = _worker_identity()
        try:
            theirs = client.run(_worker_identity)
        except Exception as exc:  # noqa: BLE001 - e.g. ModuleNotFoundError on a worker
            raise ConfigError(f"the workers of {self.describe()} cannot run mttbench "
                             f"({type(exc).__name__}: {_one_line(exc)}): install mttbench "
                             f"{mine[0]} on every worker") from None
        for worker, ident in sorted(theirs.items()):
            if tuple(ident) != mine:
                raise ConfigError(
                    f"Dask worker {worker} runs mttbench {ident[0]} (sources {ident[1]}), "
                    f"this process {mine[0]} (sources {mine[1]}): install the same mttbench "
                    "on every worker, or the numbers could differ")

    def run(self, todo: Sequence[tuple[Job, Path]], work: Work) -> Iterator[Outcome]:
        if not todo:
            return
        distributed = import_distributed()
        client = self.client
        token = uuid.uuid4().hex
        keys = [f"{TASK_PREFIX}-{token}-{i}" for i in range(len(todo))]
        # the part's bytes come back (Parquet, encoded on the worker: about half the size
        # of the pickled table, and the encoding's CPU time off this process)
        futures = client.map(work.encoded, [job for job, _ in todo], key=keys, pure=False,
                             retries=self.retries)
        index = {fut.key: i for i, fut in enumerate(futures)}
        # the runs over their wall-time limit and a cluster without workers, as the
        # scheduler sees them (dask_watch); checked every _WATCH_S seconds
        watch = RunWatch(work.timeout, no_worker_limit(self.no_worker_timeout, work.timeout))
        view = make_scheduler_view()
        next_watch = time.monotonic() + _WATCH_S
        timed_out: set[str] = set()
        pending = set(futures)
        ready = distributed.as_completed(futures, loop=client.loop)
        try:
            while pending:
                ended = ready.next_batch(block=False) if ready.has_ready() else []
                if not ended:
                    time.sleep(_POLL_S)
                pending -= set(ended)
                for fut in sorted(ended, key=lambda f: index[f.key]):
                    i = index[fut.key]
                    if fut.key in timed_out:
                        continue
                    try:
                        data = fut.result()
                    except Exception as exc:  # noqa: BLE001 - KilledWorker after the retries
                        fut.release()
                        yield i, _lost(exc)
                        continue
                    fut.release()
                    work.write_bytes(todo[i][1], data)  # an OSError stops the sweep
                    yield i, None
                if pending and time.monotonic() >= next_watch:
                    yield from self._watch(client, view, f"{TASK_PREFIX}-{token}-", watch,
                                           pending, index, timed_out)
                    next_watch = time.monotonic() + _WATCH_S
        finally:
            waiting = [fut for fut in futures if not fut.done()]
            if waiting:
                with contextlib.suppress(Exception):
                    client.cancel(waiting)

    @staticmethod
    def _watch(client: Any, view: Callable, prefix: str, watch: RunWatch, pending: set,
               index: dict, timed_out: set) -> Iterator[Outcome]:
        """One look at the scheduler (:class:`~.dask_watch.RunWatch`): a run over its limit
        is cancelled and its worker restarted (its nanny ends the run); if the cluster
        has had no worker for too long, every pending run ends. Yields their error rows
        and drops them from ``pending``."""
        try:
            seen = client.run_on_scheduler(view, prefix)
        except Exception:  # noqa: BLE001 - a scheduler that cannot say now: look again later
            return
        mine = {fut.key: fut for fut in pending}
        overdue, empty = watch.check(seen, mine, time.monotonic())
        for key, _, _ in overdue:
            timed_out.add(key)
            pending.discard(mine[key])
            with contextlib.suppress(Exception):
                client.cancel([mine[key]])
        for worker in sorted({worker for _, worker, _ in overdue}):
            with contextlib.suppress(Exception):  # a worker without a nanny stays
                client.restart_workers([worker], raise_for_error=False)
        for key, _, message in overdue:
            yield index[key], message
        if empty:
            message = no_worker_message(watch.no_worker_s)
            for fut in sorted(pending, key=lambda f: index[f.key]):
                yield index[fut.key], message
            pending.clear()

    def close(self) -> None:
        client, cluster = self._client, self._cluster
        self._client = self._cluster = None
        if client is not None and self._own_client:
            with contextlib.suppress(Exception):
                client.close()
        if cluster is not None:
            with contextlib.suppress(Exception):
                cluster.close()
        if self._lost_worker is not None:
            self._lost_worker.__exit__(None, None, None)
            self._lost_worker = None


# ------------------------------------------------------------------ the current one
_CURRENT: ContextVar[Executor | None] = ContextVar("mttbench_executor", default=None)


def current_executor() -> Executor | None:
    """The executor set by :func:`use_executor`, or None (``run_sweep``'s local pool)."""
    return _CURRENT.get()


def describe_current(workers: int, n_runs: int | None = None) -> str:
    """Where a sweep of ``n_runs`` runs goes: the current executor, else ``workers``
    local processes (for the command line's messages)."""
    return (current_executor() or LocalExecutor(workers)).describe(n_runs)


@contextlib.contextmanager
def use_executor(executor: Executor) -> Iterator[Executor]:
    """Make ``executor`` the one ``run_sweep`` uses when given none; close it at the end."""
    token = _CURRENT.set(executor)
    try:
        yield executor
    finally:
        _CURRENT.reset(token)
        executor.close()


def check_no_worker_timeout(seconds: float | None) -> float | None:
    """``--no-worker-timeout``: None, or seconds > 0 (finite)."""
    if seconds is None:
        return None
    value = float(seconds)
    if not (math.isfinite(value) and value > 0):
        raise ConfigError(f"--no-worker-timeout {seconds} is not allowed: expected seconds > 0")
    return value


def check_retries(retries: int) -> int:
    if int(retries) < 0:
        raise ConfigError(f"--retries {retries} is not allowed: expected an integer >= 0")
    return int(retries)




def _one_line(exc: BaseException) -> str:
    return " ".join(str(exc).split())


def _lost(exc: BaseException) -> str:
    """The error text of a lost run (its row's ``error``)."""
    return f"worker failed: {type(exc).__name__}: {_one_line(exc)}"
