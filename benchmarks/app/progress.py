"""The command line's progress bar over a sweep (the engine only reports counts), and the
default wall-time limit of a run for every command that sweeps."""

from __future__ import annotations

import sys
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, TextIO

import pandas as pd

from ..engine import sweep
from ..engine.loop import Job
from .resources import default_run_timeout


def run_sweep(jobs: Sequence[Job], out_dir: str | Path, *, progress: bool = True,
              **options: Any) -> pd.DataFrame:
    """:func:`~mttbench.benchmarks.engine.sweep.run_sweep` with a tqdm bar on stderr
    (``progress=False``: none); ``options`` go to it unchanged, except that a missing or
    None ``run_timeout`` becomes :func:`~.resources.default_run_timeout` of the jobs (10x
    the slowest run's estimate, at least 60 s, or 600 s while the compiled kernels' disk
    cache is cold): run, compare, tune and reproduce all end a hung run with an error row."""
    if options.get("run_timeout") is None:
        options["run_timeout"] = default_run_timeout(jobs)
    if not progress:
        return sweep.run_sweep(list(jobs), out_dir, **options)
    if not sys.stderr.isatty():  # a log file: a line per tenth, not a redraw per run
        return sweep.run_sweep(list(jobs), out_dir, progress=tenths(sys.stderr), **options)
    from tqdm.auto import tqdm

    # no monitor thread: worker processes are forked after the bar exists
    tqdm.monitor_interval = 0
    bar = tqdm(total=len(jobs), file=sys.stderr, unit="run", desc="runs")

    def show(finished: int, total: int) -> None:
        bar.n = finished
        bar.refresh()

    try:
        return sweep.run_sweep(list(jobs), out_dir, progress=show, **options)
    finally:
        bar.close()


def tenths(stream: TextIO, step: float = 0.1) -> Callable[[int, int], None]:
    """A progress callback for output that is not a terminal: one line ``runs: 40% (8/20)``
    each time the finished share passes another ``step`` (10%), and at the end; nothing
    for the runs in between."""
    shown = [-1]

    def show(finished: int, total: int) -> None:
        level = total and int(finished / total / step + 1e-9)
        if total and level > shown[0] and (level > 0 or finished == total):
            shown[0] = level
            stream.write(f"runs: {100 * finished // total}% ({finished}/{total})\n")
            stream.flush()

    return show
