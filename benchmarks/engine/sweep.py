"""A sweep: run jobs on an executor, and store their rows: one part per finished run and
the results table, or (a very large sweep) runs batched into a dataset and a per-run table.

Two layouts (``store``, recorded in ``sweep.json``; docs/result_store.md):

* ``parts``: ``parts/<job key>.parquet`` per run, then ``results.parquet`` (every row).
* ``dataset``: the runs go to the workers in batches (one task per batch, runs of one
  scenario and tracker, about :data:`BATCH_ROWS` rows), each written as one file
  ``dataset/scenario=<s>/tracker=<t>/batch-<hash of its keys>.parquet`` whose metadata
  lists its runs (job key, rows, status); ``dataset/manifest.json`` indexes the files and
  ``runs.parquet`` holds one row per run (the summary's input), computed file by file.
  10^6 runs of 100 steps make about 2,000 files, not 10^6. ``--resume`` works per run:
  every batch file is checked (its identity, then each listed run's rows) and only the
  runs it holds whole count; the others run again.
"""

from __future__ import annotations

import contextlib
import math
import os
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import pandas as pd

from .errors import ConfigError
from .executors import Executor, LocalExecutor, Work, current_executor
from .loop import COLUMNS, Job, _base_row, _frame, _special_row, run_job
from .store import (
    DATASET_DIR,
    RUN_KEY,
    RUNS_FILE,
    STORE_DATASET,
    STORE_ENV,  # noqa: F401 - re-exported: the variable run_sweep reads
    STORES,
    _concat,
    _parquet_bytes,
    _read_part,
    _write_bytes,
    _write_parquet,
    _write_part,
    batch_frame,
    batch_name,
    batch_path,
    check_batch,
    check_sweep,
    dataset_runs,
    frame_bytes,
    remove_stale_temp_files,
    resolve_store,
    sweep_lock,
    write_batch,
    write_batch_bytes,
    write_dataset_manifest,
    write_sweep_manifest,
)

#: ``progress(finished, total)``, called once before the first run and after each run
Progress = Callable[[int, int], None]
#: rows of one batch aimed at (``BATCH_ROWS // n_steps`` runs, at most
#: :data:`MAX_BATCH_RUNS`): about 25 MB in memory at 60 columns, 1-3 MB on disk
BATCH_ROWS = 50_000
MAX_BATCH_RUNS = 1_000


#: the environment variable of :func:`run_batch`'s checkpoint interval (seconds)
CHECKPOINT_ENV = "MTTBENCH_CHECKPOINT_S"
#: a batch task writes the runs it finished as a small batch file at least this often
#: (seconds), so a sweep killed mid-batch keeps them; 0: after every run
CHECKPOINT_S = 10.0


@dataclass(frozen=True)
class Batch:
    """Runs of one scenario and tracker that one worker task runs in turn
    (:func:`run_batch`) and one file holds; ``name`` is :func:`~.store.batch_name` of
    ``keys``. Stands for a job in the executors (:meth:`key` names its file).
    ``folder`` (the batch's partition) and ``checkpoint_s``: where and how often the task
    writes its finished runs meanwhile (None: never)."""

    jobs: tuple[Job, ...]
    keys: tuple[str, ...]
    name: str
    folder: str | None = None
    checkpoint_s: float | None = None

    def key(self, c: float | None, p: float) -> str:
        return self.name

    def __len__(self) -> int:
        return len(self.jobs)


def run_batch(batch: Batch, c: float | None = None, p: float = 2.0) -> pd.DataFrame:
    """:func:`~.loop.run_job` of each job of ``batch``, in turn, as one table
    (:func:`~.store.batch_frame`: a ``run_key`` column, the runs listed in its
    metadata). Each run's rows are those of ``run_job``: a failing run is its error
    row, and the batch goes on.

    Checkpoints: every ``batch.checkpoint_s`` seconds the runs finished since the last
    one are written into ``batch.folder`` as a batch of their own (a valid batch file,
    named by their keys), which ``--resume`` of a killed sweep keeps. The table lists
    them (``replaces``): its writer removes them once the whole batch is written
    (:func:`~.store.write_batch`). A folder that cannot be written (a remote Dask worker)
    means no checkpoints."""
    runs: list[tuple[str, pd.DataFrame]] = []
    chunk: list[tuple[str, pd.DataFrame]] = []
    written: list[str] = []
    folder = None if batch.checkpoint_s is None or batch.folder is None else Path(batch.folder)
    last = time.monotonic()
    for key, job in zip(batch.keys, batch.jobs, strict=True):
        runs.append((key, run_job(job, c, p)))
        chunk.append(runs[-1])
        if folder is None or len(runs) == len(batch) or (
                time.monotonic() - last < batch.checkpoint_s):
            continue
        name = batch_name([k for k, _ in chunk])
        try:
            _write_parquet(batch_frame(chunk, name), folder / f"batch-{name}.parquet")
        except OSError:
            folder = None
            continue
        written.append(name)
        chunk, last = [], time.monotonic()
    return batch_frame(runs, batch.name, replaces=written)


def make_batches(jobs: Sequence[Job], keys: Sequence[str], out_dir: Path,
                 runs_per_batch: int | None = None,
                 checkpoint_s: float | None = None) -> list[tuple[Batch, Path]]:
    """The jobs grouped by (scenario, tracker name), in order, cut into batches of
    ``runs_per_batch`` (default ``BATCH_ROWS // n_steps`` within ``[1,
    MAX_BATCH_RUNS]``), each with its file (:func:`~.store.batch_path`) and checkpoint
    interval (:func:`run_batch`)."""
    groups: dict[tuple[str, str], list[tuple[Job, str]]] = {}
    for job, key in zip(jobs, keys, strict=True):
        groups.setdefault((job.scenario.name, job.tracker.name), []).append((job, key))
    out = []
    for (scenario, tracker), members in groups.items():
        size = runs_per_batch or max(1, min(
            MAX_BATCH_RUNS, BATCH_ROWS // max(1, members[0][0].scenario.n_steps)))
        for start in range(0, len(members), size):
            chunk = members[start:start + size]
            ks = tuple(k for _, k in chunk)
            name = batch_name(ks)
            path = batch_path(out_dir, scenario, tracker, name)
            out.append((Batch(tuple(j for j, _ in chunk), ks, name, str(path.parent),
                              checkpoint_s), path))
    return out


def run_sweep(jobs: list[Job], out_dir: str | Path, workers: int = 1,
              progress: Progress | None = None, resume: bool = False, c: float | None = None,
              p: float = 2.0, executor: Executor | None = None,
              extend: bool = False, run_timeout: float | None = None,
              store: str | None = None, runs_per_batch: int | None = None) -> pd.DataFrame:
    """Run ``jobs`` and write ``out_dir/results.parquet``; returns the table.

    ``store``: the results' layout (module docstring), ``"parts"`` or ``"dataset"``;
    None: :func:`~.store.resolve_store` (the environment's ``MTTBENCH_STORE``, ignored
    by an ``extend`` sweep; else the folder's sweep's; else ``parts``). A dataset sweep
    writes ``runs.parquet`` instead of ``results.parquet`` and returns the per-run
    table (:func:`~.store.runs_of`, what the summaries take; :func:`~.store.load_results`
    loads the rows); ``runs_per_batch`` overrides the batch size. Everything below holds
    for both, per run: a lost batch's runs go again one per task, so a run that kills or
    hangs its worker gets its own error row; the wall-time limit of a batch task is
    ``run_timeout`` times its runs.

    Every finished job is written at once to ``out_dir/parts/<job hash>.parquet``,
    so an interrupted sweep keeps what it finished; with ``resume=True`` the jobs
    whose part exists are not run again. The jobs run on ``executor``
    (:mod:`~mttbench.benchmarks.engine.executors`); None means the current one
    (:func:`~mttbench.benchmarks.engine.executors.use_executor`, set by the command line), else
    a local pool of ``workers`` processes (every run in a worker process; a run over
    ``run_timeout`` seconds of wall time is killed and gets an error row). The
    results do not depend on the executor or the number of workers (timings aside). A
    run lost with its worker process is run again (``retries`` of the executor); one lost
    every time gets an error row that is not saved as a part, so ``--resume`` runs it
    again; finished parts are kept. ``progress(finished, total)``, if given, is called
    before the first run and after each (the command line draws its bar with it).

    The folder is one sweep's: ``sweep.json`` (its job keys, ``c``, ``p``) is written
    before the runs, and a folder holding another sweep's, or this sweep's without
    ``resume``, is refused (:class:`ConfigError`, :func:`~.store.check_sweep`);
    ``extend=True`` is a sweep that grows (tune's batches, each with ``resume=True``).
    The folder's lock (:func:`~.store.sweep_lock`) is held meanwhile: a second process
    is refused. Every part carries its job key, row count and status
    (:func:`~.store.part_identity`); on resume a part that cannot be read (damaged,
    empty, not a part) or is not its job's whole rows (another run's, cut short) is
    reported in one line on stderr and recomputed. Temp files left by a killed earlier sweep are
    removed at the start. Ctrl-C (``KeyboardInterrupt``) drops the queued runs, ends the
    running ones and propagates; finished parts stay. A part that cannot be written
    (disk full, read-only) raises ``OSError`` naming the file, and stops the sweep.
    """
    out_dir = Path(out_dir)
    if store is not None and store not in STORES:
        raise ConfigError(f"store {store!r} is not one of {', '.join(STORES)}")
    out_dir.mkdir(parents=True, exist_ok=True)
    with sweep_lock(out_dir):
        keys = [job.key(c, p) for job in jobs]
        store = resolve_store(out_dir, store, extend)
        manifest = check_sweep(out_dir, keys, c, p, resume, extend, store)
        write_sweep_manifest(out_dir, manifest)
        if store == STORE_DATASET:
            return _run_dataset_sweep(jobs, keys, out_dir, workers, progress, resume, c, p,
                                      executor, run_timeout, runs_per_batch)
        return _run_sweep(jobs, keys, out_dir, workers, progress, resume, c, p, executor,
                          run_timeout)


def _run_sweep(jobs: list[Job], keys: list[str], out_dir: Path, workers: int,
               progress: Progress | None, resume: bool, c: float, p: float,
               executor: Executor | None, run_timeout: float | None) -> pd.DataFrame:
    parts_dir = out_dir / "parts"
    parts_dir.mkdir(parents=True, exist_ok=True)
    remove_stale_temp_files(out_dir)
    remove_stale_temp_files(parts_dir)
    paths = [parts_dir / f"{key}.parquet" for key in keys]
    done: dict[Path, pd.DataFrame] = {}
    damaged: list[str] = []
    if resume:
        for path, job in dict(zip(paths, jobs, strict=True)).items():
            if path.exists():
                try:
                    done[path] = _read_part(path, path.stem, job.scenario.n_steps)
                except ValueError as exc:
                    damaged.append(f"{path}: {exc}")
    if damaged:
        print(f"{len(damaged)} damaged part file(s) will be recomputed (first: {damaged[0]})",
              file=sys.stderr)
    todo = [(job, path) for job, path in zip(jobs, paths, strict=True) if path not in done]
    lost: dict[Path, pd.DataFrame] = {}
    if executor is None:
        executor = current_executor() or LocalExecutor(workers)

    finished = len(jobs) - len(todo)
    if progress is not None:
        progress(finished, len(jobs))
    try:
        work = Work(run_job, _write_part, _parquet_bytes, _write_bytes, c, p, run_timeout)
        with contextlib.closing(executor.run(todo, work)) as outcomes:
            for i, error in outcomes:
                job, path = todo[i]
                if error is not None:
                    lost[path] = _lost_job_frame(job, error, c, p)
                else:
                    # read while the workers run the rest: the table is ready at the end
                    # (one that cannot be read here is read, and refused, below)
                    with contextlib.suppress(ValueError):
                        done[path] = _read_part(path)
                finished += 1
                if progress is not None:
                    progress(finished, len(jobs))
    except BaseException:
        # Ctrl-C or a write error: the executor dropped the queued runs and ended the
        # running ones; the finished parts stay for --resume
        remove_stale_temp_files(parts_dir)  # what the ended workers were writing
        raise

    frames = [lost[path] if path in lost else done[path] if path in done
              else _read_part(path) for path in paths]
    df = _concat(frames) if frames else pd.DataFrame(columns=COLUMNS)
    _write_parquet(df, out_dir / "results.parquet")
    return df


def _lost_job_frame(job: Job, message: str, c: float, p: float) -> pd.DataFrame:
    """The one error row of a job lost with its worker process (not saved as a part)."""
    row = _special_row(_base_row(job, c, p), -1, "error", message, math.nan)
    return _frame([{**row, "peak_rss_mb": math.nan}])


def checkpoint_interval() -> float:
    """:data:`CHECKPOINT_S`, or the environment's :data:`CHECKPOINT_ENV` (seconds, >= 0);
    :class:`ConfigError` for another value."""
    text = os.environ.get(CHECKPOINT_ENV, "").strip()
    if not text:
        return CHECKPOINT_S
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not math.isfinite(value) or value < 0:
        raise ConfigError(f"{CHECKPOINT_ENV}={text!r} is not allowed: expected seconds >= 0")
    return value


def _dataset_folders(root: Path) -> list[Path]:
    return [root, *(d for d in root.rglob("*") if d.is_dir())] if root.is_dir() else []


def _run_dataset_sweep(jobs: list[Job], keys: list[str], out_dir: Path, workers: int,
                       progress: Progress | None, resume: bool, c: float, p: float,
                       executor: Executor | None, run_timeout: float | None,
                       runs_per_batch: int | None) -> pd.DataFrame:
    """:func:`run_sweep` into the batched dataset (the module docstring)."""
    root = out_dir / DATASET_DIR
    root.mkdir(parents=True, exist_ok=True)
    remove_stale_temp_files(out_dir)
    for folder in _dataset_folders(root):
        remove_stale_temp_files(folder)
    by_key = dict(zip(keys, jobs, strict=True))

    def n_steps(key: str) -> int | None:
        job = by_key.get(key)
        return None if job is None else job.scenario.n_steps

    held: set[str] = set()
    files: dict[Path, tuple[list[str], int]] = {}  # file -> (its runs taken, runs listed)
    damaged: list[str] = []
    if resume:
        for path in sorted(root.rglob("batch-*.parquet")):
            try:
                good, listed, problem = check_batch(path, n_steps)
            except ValueError as exc:
                damaged.append(f"{path}: {exc}")
                continue
            if problem:
                damaged.append(f"{path}: {problem}")
            fresh = [k for k in good if k not in held]  # a run held twice: the first file
            held.update(fresh)
            if fresh:
                files[path] = (fresh, listed)
    if damaged:
        print(f"{len(damaged)} damaged batch file(s): their runs that are not whole will be "
              f"recomputed (first: {damaged[0]})", file=sys.stderr)
    todo = [(job, key) for job, key in zip(jobs, keys, strict=True) if key not in held]
    checkpoint_s = checkpoint_interval()
    pending = make_batches([j for j, _ in todo], [k for _, k in todo], out_dir,
                           runs_per_batch, checkpoint_s)
    lost: list[pd.DataFrame] = []
    if executor is None:
        executor = current_executor() or LocalExecutor(workers)
    finished = len(jobs) - len(todo)
    if progress is not None:
        progress(finished, len(jobs))
    try:
        while pending:
            for _, path in pending:
                path.parent.mkdir(parents=True, exist_ok=True)
            longest = max(len(batch) for batch, _ in pending)
            work = Work(run_batch, write_batch, frame_bytes, write_batch_bytes, c, p,
                        None if run_timeout is None else run_timeout * longest)
            again: list[tuple[Batch, Path]] = []
            with contextlib.closing(executor.run(pending, work)) as outcomes:
                for i, error in outcomes:
                    batch, path = pending[i]
                    if error is None:
                        files[path] = (list(batch.keys), len(batch))
                        finished += len(batch)
                    elif len(batch) > 1:  # its runs again, one per task: whose fault?
                        again.extend(make_batches(batch.jobs, batch.keys, out_dir, 1,
                                                  checkpoint_s))
                        continue
                    else:
                        lost.append(_lost_job_frame(batch.jobs[0], error, c, p).assign(
                            **{RUN_KEY: batch.keys[0]}))
                        finished += 1
                    if progress is not None:
                        progress(finished, len(jobs))
            pending = again
    except BaseException:
        for folder in _dataset_folders(root):  # what the ended workers were writing
            remove_stale_temp_files(folder)
        raise
    write_dataset_manifest(out_dir, [(path, ks, n) for path, (ks, n) in files.items()])
    runs = dataset_runs(out_dir, lost)
    _write_parquet(runs, out_dir / RUNS_FILE)
    return runs
