"""One command's output per folder: the file that marks a folder as each command's.

A sweep (``run``, ``compare``, ``tune``, ``reproduce``) writes ``sweep.json``, ``score``
``score.json`` and ``export`` ``worlds.csv``; a command refuses a folder that holds another
command's mark (:func:`check_folder_kind`, one line, exit 2), so that ``score --out`` cannot
replace a sweep's summaries, ``export`` cannot write worlds into a sweep's folder and
``run`` cannot overwrite a score. Every command also holds the folder's lock
(:func:`~mttbench.benchmarks.engine.store.sweep_lock`) while it writes, so a folder in use
by a running command of any kind is refused as well.
"""

from __future__ import annotations

from pathlib import Path

from ..engine.store import SWEEP_MANIFEST
from .usage import UsageError

SCORE_MARK = "score.json"
EXPORT_MARK = "worlds.csv"
#: mark file -> whose output it is, for the message
MARKS = {SWEEP_MANIFEST: "the runs of a sweep (run, compare, tune or reproduce)",
         SCORE_MARK: "the output of `mttbench score`",
         EXPORT_MARK: "the worlds of `mttbench export`"}


def check_folder_kind(out_dir: str | Path, mine: str = SWEEP_MANIFEST) -> None:
    """:class:`UsageError` if ``out_dir`` holds another command's mark than ``mine``."""
    for mark, whose in MARKS.items():
        if mark != mine and (Path(out_dir) / mark).exists():
            raise UsageError(f"--out {out_dir} holds {whose} ({mark}); choose another "
                             "folder")
