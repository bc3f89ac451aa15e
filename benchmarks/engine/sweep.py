"""A sweep: run jobs on an executor, one part per finished run, and the results table."""

from __future__ import annotations

import contextlib
import math
import sys
from collections.abc import Callable
from pathlib import Path

import pandas as pd

from .executors import Executor, LocalExecutor, Work, current_executor
from .loop import COLUMNS, Job, _base_row, _frame, _special_row, run_job
from .store import (
    _concat,
    _parquet_bytes,
    _read_part,
    _write_bytes,
    _write_parquet,
    _write_part,
    check_sweep,
    remove_stale_temp_files,
    sweep_lock,
    write_sweep_manifest,
)

#: ``progress(finished, total)``, called once before the first run and after each run
Progress = Callable[[int, int], None]


def run_sweep(jobs: list[Job], out_dir: str | Path, workers: int = 1,
              progress: Progress | None = None, resume: bool = False, c: float = 2.0,
              p: float = 2.0, executor: Executor | None = None,
              extend: bool = False, run_timeout: float | None = None) -> pd.DataFrame:
    """Run ``jobs`` and write ``out_dir/results.parquet``; returns the table.

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
    out_dir.mkdir(parents=True, exist_ok=True)
    with sweep_lock(out_dir):
        keys = [job.key(c, p) for job in jobs]
        manifest = check_sweep(out_dir, keys, c, p, resume, extend)
        write_sweep_manifest(out_dir, manifest)
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
                if error is not None:
                    job, path = todo[i]
                    lost[path] = _lost_job_frame(job, error, c, p)
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
