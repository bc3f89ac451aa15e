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
    remove_stale_temp_files,
)

#: ``progress(finished, total)``, called once before the first run and after each run
Progress = Callable[[int, int], None]


def run_sweep(jobs: list[Job], out_dir: str | Path, workers: int = 1,
              progress: Progress | None = None, resume: bool = False, c: float = 2.0,
              p: float = 2.0, executor: Executor | None = None) -> pd.DataFrame:
    """Run ``jobs`` and write ``out_dir/results.parquet``; returns the table.

    Every finished job is written at once to ``out_dir/parts/<job hash>.parquet``,
    so an interrupted sweep keeps what it finished; with ``resume=True`` the jobs
    whose part exists are not run again. The jobs run on ``executor``
    (:mod:`~mttbench.benchmarks.engine.executors`); None means the current one
    (:func:`~mttbench.benchmarks.engine.executors.use_executor`, set by the command line), else
    a local pool of ``workers`` processes (``workers <= 1``: in this process). The
    results do not depend on the executor or the number of workers (timings aside). A
    run lost with its worker process is run again (``retries`` of the executor); one lost
    every time gets an error row that is not saved as a part, so ``--resume`` runs it
    again; finished parts are kept. ``progress(finished, total)``, if given, is called
    before the first run and after each (the command line draws its bar with it).

    On resume a part that cannot be read (damaged, empty, not a part) is reported in
    one line on stderr and recomputed. Temp files left by a killed earlier sweep are
    removed at the start. Ctrl-C (``KeyboardInterrupt``) drops the queued runs, ends the
    running ones and propagates; finished parts stay. A part that cannot be written
    (disk full, read-only) raises ``OSError`` naming the file, and stops the sweep.
    """
    out_dir = Path(out_dir)
    parts_dir = out_dir / "parts"
    parts_dir.mkdir(parents=True, exist_ok=True)
    remove_stale_temp_files(out_dir)
    remove_stale_temp_files(parts_dir)
    paths = [parts_dir / f"{job.key(c, p)}.parquet" for job in jobs]
    done: dict[Path, pd.DataFrame] = {}
    damaged: list[str] = []
    if resume:
        for path in dict.fromkeys(paths):
            if path.exists():
                try:
                    done[path] = _read_part(path)
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
        work = Work(run_job, _write_parquet, _parquet_bytes, _write_bytes, c, p)
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
              else pd.read_parquet(path) for path in paths]
    df = _concat(frames) if frames else pd.DataFrame(columns=COLUMNS)
    _write_parquet(df, out_dir / "results.parquet")
    return df


def _lost_job_frame(job: Job, message: str, c: float, p: float) -> pd.DataFrame:
    """The one error row of a job lost with its worker process (not saved as a part)."""
    row = _special_row(_base_row(job, c, p), -1, "error", message, math.nan)
    return _frame([{**row, "peak_rss_mb": math.nan}])
