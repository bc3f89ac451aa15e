"""The command line's progress bar over a sweep (the engine only reports counts)."""

from __future__ import annotations

import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import pandas as pd

from ..engine import sweep
from ..engine.loop import Job


def run_sweep(jobs: Sequence[Job], out_dir: str | Path, *, progress: bool = True,
              **options: Any) -> pd.DataFrame:
    """:func:`~mttbench.benchmarks.engine.sweep.run_sweep` with a tqdm bar on stderr
    (``progress=False``: none); ``options`` go to it unchanged."""
    if not progress:
        return sweep.run_sweep(list(jobs), out_dir, **options)
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
