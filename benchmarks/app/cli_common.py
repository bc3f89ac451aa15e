"""What the ``mttbench`` commands share: the limits of their values, the checks made before any
run (one line each, :class:`~.usage.UsageError`), the output folder (chosen, locked, its
failure line) and the option groups several commands add."""

from __future__ import annotations

import argparse
import contextlib
import math
import os
import re
import sys
from collections.abc import Sequence
from datetime import UTC, datetime
from pathlib import Path

import pandas as pd

from ..engine.metrics import CUTOFF_CELLS
from ..engine.specs import resolve_suite, split_specs
from ..engine.store import LOCK_FILE, SWEEP_MANIFEST, sweep_lock
from .folders import check_folder_kind
from .summary import run_failures
from .usage import UsageError

# ------------------------------------------------------------------ validation
#: largest seed (and look budget): the results table stores them as int64
MAX_INT64 = 2**63 - 1
#: most seeds one sweep may ask for with --seeds (a larger sweep: several folders)
MAX_SEEDS = 1_000_000
#: c ** p of the OSPA/GOSPA metrics stays within 10 ** -E .. 10 ** E
MAX_C_POWER_P_EXP = 200
#: most trials of one tuning study
MAX_TRIALS = 100_000
#: the tuning sampler's seed is a 32-bit unsigned integer
MAX_SAMPLER_SEED = 2**32 - 1
#: a file name and a path the file systems we run on allow (bytes)
NAME_MAX, PATH_MAX = 255, 4095
#: the longest --run-timeout (seconds): a year
MAX_TIMEOUT_S = 365 * 86400.0


def int_list(texts: Sequence[str] | None, what: str, lo: int) -> list[int] | None:
    """Integers ``lo .. 2**63 - 1`` given space or comma separated, sorted without repeats;
    None when the option was not given."""
    if not texts:
        return None
    out = []
    for piece in split_specs(list(texts)):
        try:
            v = int(piece)
        except ValueError:
            raise UsageError(f"{what} {piece!r} is not an integer") from None
        if v < lo or v > MAX_INT64:
            raise UsageError(f"{what} {v} is not allowed: expected an integer >= {lo} "
                             f"and <= {MAX_INT64} (2**63 - 1)")
        out.append(v)
    if not out:
        raise UsageError(f"{what}: none given (an empty list)")
    return sorted(set(out))


def seeds_of(args: argparse.Namespace, default: int) -> list[int]:
    """``--seed-list``, or ``--seeds N`` (``default`` when absent) as ``0 .. N-1``."""
    if args.seed_list:
        return int_list(args.seed_list, "seed", 0) or []
    n = default if args.seeds is None else args.seeds
    if not 1 <= n <= MAX_SEEDS:
        raise UsageError(f"--seeds {n} is not allowed: expected an integer from 1 to "
                         f"{MAX_SEEDS}")
    return list(range(n))


def check_common(args: argparse.Namespace) -> None:
    if args.steps is not None and args.steps < 1:
        raise UsageError(f"--steps {args.steps} is not allowed: expected an integer >= 1")
    if args.workers is not None and args.workers < 1:
        raise UsageError(f"--workers {args.workers} is not allowed: expected an integer >= 1")
    if args.c is not None and not (math.isfinite(args.c) and args.c > 0):
        raise UsageError(f"--c {args.c} is not allowed: the OSPA cut-off must be a finite "
                         "number > 0")
    if not (math.isfinite(args.p) and args.p >= 1):
        raise UsageError(f"--p {args.p} is not allowed: the OSPA order must be a finite "
                         "number >= 1")
    # the metrics raise distances up to c to the power p: c ** p must stay a normal number
    # (the default c, 2 cells, checked as 2: its cell size is the scenario's)
    c = CUTOFF_CELLS if args.c is None else args.c
    if abs(args.p * math.log10(c)) > MAX_C_POWER_P_EXP:
        raise UsageError(f"--c {c} with --p {args.p} is not allowed: c ** p must stay "
                         f"within 1e-{MAX_C_POWER_P_EXP} .. 1e{MAX_C_POWER_P_EXP} (the metrics "
                         "raise distances to the power p)")
    check_run_timeout(args)


def check_run_timeout(args: argparse.Namespace) -> None:
    """``--run-timeout``: seconds > 0, at most :data:`MAX_TIMEOUT_S`."""
    timeout = getattr(args, "run_timeout", None)
    if timeout is not None and not (math.isfinite(timeout) and 0 < timeout <= MAX_TIMEOUT_S):
        raise UsageError(f"--run-timeout {timeout} is not allowed: expected seconds > 0 and "
                         f"<= {MAX_TIMEOUT_S:g}")


def _shown(text: str) -> str:
    return repr(text if len(text) <= 60 else text[:57] + "...")


def check_path(option: str, text: str | None, *, folder: bool = True,
                must_exist: bool = False) -> None:
    """A path option: not empty, names the file system allows, and a folder (or, with
    ``folder=False``, a regular file) where one is expected."""
    if text is None:
        return
    if not text.strip() or "\0" in text:
        raise UsageError(f"{option} {_shown(text)} is not allowed: give a path")
    raw = os.fsencode(text)
    if len(raw) > PATH_MAX or any(len(os.fsencode(part)) > NAME_MAX
                                  for part in Path(text).parts):
        raise UsageError(f"{option} {_shown(text)} is not allowed: a name longer than the "
                         f"file system allows ({NAME_MAX} bytes a name, {PATH_MAX} a path)")
    path = Path(text)
    try:
        exists = path.exists()
    except OSError as exc:
        raise UsageError(f"{option} {_shown(text)}: {exc.strerror or exc}") from None
    if folder and exists and not path.is_dir():
        raise UsageError(f"{option} {text} exists and is not a folder")
    if not folder and exists and not path.is_file():
        raise UsageError(f"{option} {text} is not a regular file")
    if must_exist and not exists:
        raise UsageError(f"{option} {text}: no such {'folder' if folder else 'file'}")


#: an existing Dask cluster's scheduler: [PROTOCOL://]HOST:PORT
_SCHEDULER = re.compile(r"([a-z][a-z0-9+.-]*://)?[A-Za-z0-9._~%\-\[\]:]+:[0-9]{1,5}/?")


def check_inputs(args: argparse.Namespace) -> None:
    """Checks shared by the commands, before anything runs: paths, empty lists, the
    scheduler's address."""
    check_path("--out", getattr(args, "out", None))
    if args.command == "tune":
        check_path("--tuned-dir", args.tuned_dir)
    elif args.command == "compare":
        check_path("--tuned-dir", args.tuned_dir, must_exist=True)
    elif args.command == "reproduce":
        check_path("--cache-dir", args.cache_dir)
        check_path("--reference-csv", args.reference_csv, folder=False)
    texts = getattr(args, "trackers", None)
    if texts is not None and not split_specs(list(texts)):
        raise UsageError("--trackers: none given (an empty tracker spec)")
    scheduler = getattr(args, "scheduler", None)
    if scheduler is not None and not _SCHEDULER.fullmatch(scheduler):
        raise UsageError(f"--scheduler {_shown(scheduler)} is not allowed: expected the "
                         "address of a Dask scheduler, tcp://HOST:PORT")


def scenario_names(args: argparse.Namespace) -> list[str]:
    """``--suite`` (its scenarios' names) or ``--scenarios``."""
    return resolve_suite(args.suite) if args.suite else list(args.scenarios)


def timestamp() -> str:
    """Now in UTC, as the default output folders are named."""
    return datetime.now(UTC).strftime("%Y%m%dT%H%M%SZ")


# ------------------------------------------------------------- output folders
REPORTS = Path("reports")


def _latest_unfinished(prefix: str, finished) -> Path | None:
    """The most recent ``reports/<prefix><UTC timestamp>`` folder that is not finished."""
    try:
        folders = sorted((p for p in REPORTS.glob(prefix + "*") if p.is_dir()),
                         key=lambda p: p.name, reverse=True)
    except OSError:
        return None
    return next((p for p in folders if not finished(p)), None)


def choose_out_dir(args: argparse.Namespace, prefix: str, finished) -> Path:
    """``--out``, or with ``--resume`` alone the most recent unfinished folder of this
    command under ``reports/`` (said on stderr), else a new timestamped folder."""
    if args.out:
        return Path(args.out)
    if args.resume:
        found = _latest_unfinished(prefix, finished)
        if found is None:
            raise UsageError(f"--resume without --out: no unfinished {REPORTS}/{prefix}* "
                             "folder to resume; name the folder with --out DIR")
        parts = found / "parts"
        n_parts = len(list(parts.glob("*.parquet"))) if parts.is_dir() else 0
        print(f"resuming {found} (the most recent unfinished {args.command}; {n_parts} "
              "runs already saved)", file=sys.stderr)
        return found
    return REPORTS / f"{prefix}{timestamp()}"


def failure_line(results: pd.DataFrame, out_dir: Path) -> str | None:
    """``k of n runs failed; first error: ...; see <out>/summary.csv``, or None."""
    k, n, first = run_failures(results)
    if not k:
        return None
    return f"{k} of {n} runs failed; first error: {first}; see {out_dir / 'summary.csv'}"


# ---------------------------------------------------------------------- outputs
@contextlib.contextmanager
def folder_lock(out_dir: Path, mark: str = SWEEP_MANIFEST):
    """The output folder's lock (:func:`~mttbench.benchmarks.engine.store.sweep_lock`) for
    the whole command, so a second process is refused at once, and the folder checked to
    hold no other command's output (:func:`~.folders.check_folder_kind`, ``mark`` this
    command's). A folder that does not
    exist yet is created to hold the lock (no window in which two commands could both
    start in it); if the command then fails before writing anything into it (a refused
    setting), the folder is removed again."""
    folder = Path(out_dir)
    check_folder_kind(folder, mark)
    created = False
    if not folder.exists():
        try:
            folder.mkdir(parents=True)
            created = True
        except OSError:  # the command's own checks say why, in one line
            yield
            return
    try:
        with sweep_lock(folder):
            check_folder_kind(folder, mark)  # again: another command may have just ended
            yield
    except BaseException:
        if created and {p.name for p in folder.iterdir()} <= {LOCK_FILE}:
            with contextlib.suppress(OSError):
                (folder / LOCK_FILE).unlink(missing_ok=True)
                folder.rmdir()
        raise


# ----------------------------------------------------------------- option groups
SUITE_HELP = ("the scenarios of a suite instead of --scenarios: `envelope` (the operating "
              "envelope's points, docs/envelope.md), `envelope:train` or `envelope:held` (one "
              "split); each point runs at its own looks_per_step")


def add_sweep_options(p: argparse.ArgumentParser, *, seeds_default: int,
                       trackers_required: bool | None) -> None:
    """The options of every command that sweeps; ``trackers_required`` None: the command
    takes no ``--trackers`` (``bayes`` runs its own ladder)."""
    if trackers_required is not None:
        p.add_argument("--trackers", nargs="+", metavar="SPEC", required=trackers_required,
                       help="trackers as NAME or NAME:key=value,key=value (values parsed as "
                            "true/false, int, float, else string; see `mttbench trackers`)"
                            + ("" if trackers_required
                               else "; default: every registered tracker"))
    g = p.add_mutually_exclusive_group()
    g.add_argument("--seeds", type=int, metavar="N",
                   help=f"run seeds 0..N-1 (default {seeds_default}; N <= {MAX_SEEDS})")
    g.add_argument("--seed-list", nargs="+", metavar="SEED",
                   help="explicit seeds, space or comma separated")
    add_steps_option(p)
    p.add_argument("--out", metavar="DIR",
                   help="output folder (default reports/<command>-<UTC timestamp>)")
    p.add_argument("--resume", action="store_true",
                   help="skip runs already saved in DIR/parts (an interrupted sweep; damaged "
                        "parts are recomputed); without --out: the most recent unfinished "
                        "folder of this command under reports/")
    add_metric_options(p)
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    add_run_timeout(p)


def add_steps_option(p: argparse.ArgumentParser) -> None:
    """``--steps``: every scenario's length overridden."""
    p.add_argument("--steps", type=int, metavar="K",
                   help="override every scenario's n_steps (default: the scenario's)")


def add_workers_option(p: argparse.ArgumentParser) -> None:
    """``--workers``: the local pool's size (every command that runs sweeps)."""
    p.add_argument("--workers", type=int, default=None, metavar="N",
                   help="parallel worker processes (default: the number of CPUs)")


def add_run_timeout(p: argparse.ArgumentParser, then: str = "gets an error row") -> None:
    """``--run-timeout``: the wall-time limit of one run (every command that runs)."""
    p.add_argument("--run-timeout", type=float, default=None, metavar="SECONDS",
                   help=f"wall-time limit of one run: a run still going is ended and {then} "
                        "(default: 10x the slowest run's estimate, at least 60 s; at least 600 "
                        "s while the compiled kernels' disk cache is cold, as after a "
                        "plain pip install: a worker's first run compiles them)")


def add_metric_options(p: argparse.ArgumentParser) -> None:
    """``--c`` and ``--p``: the OSPA/GOSPA cut-off and order."""
    p.add_argument("--c", type=float, default=None,
                   help="OSPA/GOSPA cut-off c in world units (default 2 cells: 2 x each "
                        "scenario's cell_size)")
    p.add_argument("--p", type=float, default=2.0, help="OSPA/GOSPA order p (default 2)")
