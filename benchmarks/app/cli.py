"""The ``mttbench`` command line: list scenarios and trackers, run sweeps, compare.

::

    mttbench scenarios                      # the shipped presets
    mttbench trackers                       # registered trackers (+ parameters) and policies
    mttbench run --scenarios default crossing --trackers kfnn jmpd:n_particles=1000 \\
                 --seeds 20 --policy raster,renyi --looks 12,24 --workers 2
    mttbench compare                        # the main job: head-to-head report
    mttbench reproduce paper [--reduced] [--check]   # the paper's figures, checked
    mttbench reproduce kreucher [--reduced] [--check]  # managed against periodic looks
    mttbench reproduce cdc2004 [--reduced] [--check]   # non-myopic against myopic, occlusion
    mttbench export default --seeds 5 --policy random --out worlds   # open world files
    mttbench score worlds --estimates est.csv --name mine   # an outside tracker's estimates
    mttbench bayes default --seeds 10       # the converged Bayes reference, stored
    mttbench frontier default --trackers gpf jmpd-ap --seeds 4   # accuracy against budget

Exit status, always with at most one line on stderr saying why (never a traceback):

* 0: every run finished (``ok`` or ``unsupported``);
* 1: a run failed (``k of n runs failed; first error: ...; see <out>/summary.csv``;
  every other run's rows are kept; a run that hangs past ``--run-timeout``, exits or
  kills its worker process is a failed run), or a file could not be written mid-sweep (disk
  full: the line names the file; nothing finished is lost);
* 2: bad input, refused before any run and before the output folder is touched: an
  unknown tracker, parameter, scenario or policy, a bad value or scenario file, a run
  that cannot fit in memory (:mod:`~mttbench.benchmarks.app.resources`), a value whose
  arithmetic would overflow in a run, an output folder that cannot be created or written,
  holds another sweep (``sweep.json``) or is in use by another process; an argparse
  error too, in one line (no usage block);
* 130: interrupted (Ctrl-C): the queued runs are dropped, finished runs kept, and the
  line gives the exact command that resumes.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import os
import re
import shlex
import sys
import textwrap
from collections.abc import Sequence
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import pandas as pd

from ... import scenarios, trackers
from ..engine import policies
from ..engine.errors import ConfigError
from ..engine.executors import describe_current
from ..engine.loop import build_jobs
from ..engine.metrics import CUTOFF_CELLS
from ..engine.specs import (
    resolve_policies,
    resolve_scenarios,
    resolve_suite,
    resolve_trackers,
    split_specs,
)
from ..engine.store import (
    LOCK_FILE,
    SWEEP_MANIFEST,
    check_sweep,
    prepare_out_dir,
    sweep_lock,
)
from . import resources
from .compare import (
    COMPARE_REFERENCES,
    COMPARE_SCENARIOS,
    COMPARE_SEEDS,
    OUTPUT_FILES,
    default_run_timeout,
    is_finished,
)
from .executor_options import add_executor_arguments, executor_scope
from .folders import EXPORT_MARK, SCORE_MARK, check_folder_kind
from .progress import run_sweep
from .summary import run_failures, write_summary
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
#: exit status after Ctrl-C (128 + SIGINT, as a shell reports it)
EXIT_INTERRUPTED = 130


def _int_list(texts: Sequence[str] | None, what: str, lo: int) -> list[int] | None:
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


def _seeds(args: argparse.Namespace, default: int) -> list[int]:
    if args.seed_list:
        return _int_list(args.seed_list, "seed", 0) or []
    n = default if args.seeds is None else args.seeds
    if not 1 <= n <= MAX_SEEDS:
        raise UsageError(f"--seeds {n} is not allowed: expected an integer from 1 to "
                         f"{MAX_SEEDS}")
    return list(range(n))


def _check_common(args: argparse.Namespace) -> None:
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
    _check_run_timeout(args)


def _check_run_timeout(args: argparse.Namespace) -> None:
    """``--run-timeout``: seconds > 0, at most :data:`MAX_TIMEOUT_S`."""
    timeout = getattr(args, "run_timeout", None)
    if timeout is not None and not (math.isfinite(timeout) and 0 < timeout <= MAX_TIMEOUT_S):
        raise UsageError(f"--run-timeout {timeout} is not allowed: expected seconds > 0 and "
                         f"<= {MAX_TIMEOUT_S:g}")


def _shown(text: str) -> str:
    return repr(text if len(text) <= 60 else text[:57] + "...")


def _check_path(option: str, text: str | None, *, folder: bool = True,
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


def _check_inputs(args: argparse.Namespace) -> None:
    """Checks shared by the commands, before anything runs: paths, empty lists, the
    scheduler's address."""
    _check_path("--out", getattr(args, "out", None))
    if args.command == "tune":
        _check_path("--tuned-dir", args.tuned_dir)
    elif args.command == "compare":
        _check_path("--tuned-dir", args.tuned_dir, must_exist=True)
    elif args.command == "reproduce":
        _check_path("--cache-dir", args.cache_dir)
        _check_path("--reference-csv", args.reference_csv, folder=False)
    texts = getattr(args, "trackers", None)
    if texts is not None and not split_specs(list(texts)):
        raise UsageError("--trackers: none given (an empty tracker spec)")
    scheduler = getattr(args, "scheduler", None)
    if scheduler is not None and not _SCHEDULER.fullmatch(scheduler):
        raise UsageError(f"--scheduler {_shown(scheduler)} is not allowed: expected the "
                         "address of a Dask scheduler, tcp://HOST:PORT")


def _scenario_names(args: argparse.Namespace) -> list[str]:
    """``--suite`` (its scenarios' names) or ``--scenarios``."""
    return resolve_suite(args.suite) if args.suite else list(args.scenarios)


def _timestamp() -> str:
    return datetime.now(UTC).strftime("%Y%m%dT%H%M%SZ")


# ------------------------------------------------------------- output folders
REPORTS = Path("reports")


def _run_finished(folder: Path) -> bool:
    return (folder / "summary.md").is_file()


def _latest_unfinished(prefix: str, finished) -> Path | None:
    """The most recent ``reports/<prefix><UTC timestamp>`` folder that is not finished."""
    try:
        folders = sorted((p for p in REPORTS.glob(prefix + "*") if p.is_dir()),
                         key=lambda p: p.name, reverse=True)
    except OSError:
        return None
    return next((p for p in folders if not finished(p)), None)


def _out_dir(args: argparse.Namespace, prefix: str, finished) -> Path:
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
    return REPORTS / f"{prefix}{_timestamp()}"


def _resume_command(args: argparse.Namespace, out_dir: Path) -> str:
    """The exact command that resumes this one: its arguments with ``--out`` and
    ``--resume`` added where missing."""
    first = Path(sys.argv[0]) if sys.argv and sys.argv[0] else Path()
    if first.name == "mttbench" and os.sep in sys.argv[0]:  # e.g. .venv/bin/mttbench
        prog = shlex.quote(sys.argv[0])
    elif first.name == "__main__.py" and first.parent.name == "mttbench":  # python -m
        prog = f"{shlex.quote(sys.executable)} -m mttbench"
    else:
        prog = "mttbench"
    words = list(args.argv[1:])
    if not args.out:
        words += ["--out", str(out_dir)]
    if not args.resume:
        words.append("--resume")
    return prog + " " + shlex.join(words)


def _failure_line(results: pd.DataFrame, out_dir: Path) -> str | None:
    """``k of n runs failed; first error: ...; see <out>/summary.csv``, or None."""
    k, n, first = run_failures(results)
    if not k:
        return None
    return f"{k} of {n} runs failed; first error: {first}; see {out_dir / 'summary.csv'}"


# ---------------------------------------------------------------------- outputs
@contextlib.contextmanager
def _folder_lock(out_dir: Path, mark: str = SWEEP_MANIFEST):
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


def _sweep(args: argparse.Namespace, scs, tracker_specs, policy_specs, looks, seeds,
           out_dir: Path, workers: int, title: str) -> int:
    jobs = build_jobs(scs, tracker_specs, policy_specs, looks, seeds)
    for line in resources.check_jobs(jobs, workers):
        print(line, file=sys.stderr)
    resume = getattr(args, "resume", False)
    with _folder_lock(out_dir):
        check_sweep(out_dir, [job.key(args.c, args.p) for job in jobs], args.c, args.p, resume)
        prepare_out_dir(out_dir)
        with sweep_lock(out_dir):
            print(f"{len(jobs)} runs on {describe_current(workers, len(jobs))} -> {out_dir}",
                  file=sys.stderr)
            results = run_sweep(jobs, out_dir, workers=workers, progress=not args.no_progress,
                                resume=resume, c=args.c, p=args.p,
                                run_timeout=args.run_timeout or default_run_timeout(jobs),
                                store=getattr(args, "store", None))
            text = write_summary(_with_bayes(results, scs, policy_specs, looks, seeds, args),
                                 out_dir, title)
    print(text)
    rows = ("dataset/ (the rows, by scenario and tracker), runs.parquet"
            if (Path(out_dir) / "runs.parquet").is_file() else "results.parquet")
    print(f"wrote {out_dir}/: {rows}, summary.csv, summary.md")
    failed = _failure_line(results, out_dir)
    if failed:
        print(failed, file=sys.stderr)
        return 1
    return 0


def _with_bayes(results: pd.DataFrame, scs, policy_specs, looks, seeds,
                args: argparse.Namespace) -> pd.DataFrame:
    """The summary's table: ``results`` with the stored Bayes reference of every raster
    scenario and look budget whose seeds it covers (a line on stderr for each attached)."""
    from ..engine.specs import PolicySpec
    from . import bayes

    if not any(p.name == "raster" and not p.params for p in policy_specs or []) or \
            "step" not in results.columns:
        return results
    for m in looks or [None]:
        results, notes = bayes.attach(results, scs, seeds, PolicySpec("raster"), m, args.c,
                                      args.p)
        for line in notes:
            if "no stored" not in line:
                print(f"bayes reference: {line}", file=sys.stderr)
    return results


# --------------------------------------------------------------------- commands
def cmd_scenarios(args: argparse.Namespace) -> int:
    names = scenarios.preset_names()
    width = max(len(n) for n in names)
    for name in names:
        sc = scenarios.get(name)
        print(f"{name:<{width}}  {sc.n_steps:>4} steps  {sc.description}")
    return 0


def _print_entry(name: str, cls: type) -> None:
    """A tracker or policy: its summary, then one line per parameter with its default and
    what it accepts (the class's declaration, :mod:`mttbench.trackers.params`)."""
    from ...trackers.params import describe

    print(f"  {name:<8} {cls.summary}")
    rows = describe(cls)
    if not rows:
        print(" " * 11 + "(no parameters)")
    for key, default, allowed in rows:
        head = f"{key}={default}"
        print(textwrap.fill(allowed, width=100, initial_indent=" " * 11 + f"{head:<28} ",
                            subsequent_indent=" " * 40))


def cmd_trackers(args: argparse.Namespace) -> int:
    print("Trackers (use as NAME or NAME:key=value,key=value; a tracker from elsewhere as "
          "package.module:ClassName):")
    print("Each parameter: NAME=DEFAULT and what it accepts; bad values are refused before "
          "any run.")
    for name in trackers.available():
        _print_entry(name, trackers.get_class(name))
        missing = getattr(trackers.get_class(name), "missing_extra", None)
        if callable(missing) and missing():  # an optional extra not installed (Stone Soup)
            print(" " * 11 + f"NOT AVAILABLE: {missing()}")
    for name, why in trackers.broken_plugins().items():
        print(f"  {name:<8} NOT LOADED (entry point failed): {why}")
    print("\nCell-selection policies (--policy NAME or NAME:key=value,...):")
    for name in policies.available_policies():
        _print_entry(name, policies.get_policy_class(name))
    for name, why in policies.broken_plugins().items():
        print(f"  {name:<8} NOT LOADED (entry point failed): {why}")
    return 0


def cmd_run(args: argparse.Namespace) -> int:
    _check_common(args)
    scs = resolve_scenarios(_scenario_names(args), args.steps)
    tracker_specs = resolve_trackers(args.trackers)
    policy_specs = resolve_policies(args.policy)
    looks = _int_list(args.looks, "--looks value", 0)
    seeds = _seeds(args, default=10)
    out_dir = _out_dir(args, "run-", _run_finished)
    args.out_dir = out_dir  # for the resume line after Ctrl-C
    return _sweep(args, scs, tracker_specs, policy_specs, looks, seeds, out_dir,
                  args.workers or os.cpu_count() or 1, "mttbench run")


def cmd_compare(args: argparse.Namespace) -> int:
    """The head-to-head report (:mod:`benchmarks.app.compare`)."""
    from .compare import run_compare
    from .policy_axis import resolve as resolve_policy_axis

    _check_common(args)
    policy_specs = resolve_policy_axis(args.policies)
    seeds = _seeds(args, default=COMPARE_SEEDS)
    out_dir = _out_dir(args, "compare-", is_finished)
    args.out_dir = out_dir  # for the resume line after Ctrl-C
    with _folder_lock(out_dir):
        res = run_compare(_scenario_names(args), args.trackers, seeds, args.steps,
                          args.workers, out_dir, reference=args.reference,
                          progress=not args.no_progress, resume=args.resume, c=args.c,
                          p=args.p, argv=args.argv, tuned_dir=args.tuned_dir,
                          untuned=args.untuned, tuning_effect=args.tuning_effect,
                          run_timeout=args.run_timeout, compute_bayes=args.bayes,
                          policies=policy_specs)
    print((res.out_dir / "summary.md").read_text(encoding="utf-8"))
    man = res.manifest
    wall = f"{man['wall_time_s']:.0f} s"
    if len(man["sessions"]) > 1:
        wall += f" over {len(man['sessions'])} sessions"
    print(f"wrote {res.out_dir}/: {', '.join(OUTPUT_FILES)} ({wall})")
    failed = _failure_line(res.results, res.out_dir)
    if failed:
        print(failed, file=sys.stderr)
        return 1
    return 0


def cmd_frontier(args: argparse.Namespace) -> int:
    """Budget frontiers (:mod:`benchmarks.app.frontier`): exit 0; 1 when a run failed; 2 for
    bad input."""
    from . import frontier

    _check_common(args)
    scs = resolve_scenarios(args.scenarios, args.steps)
    curves = frontier.build_curves(resolve_trackers(args.trackers), args.points,
                                   frontier.parse_ranges(args.range))
    policy = resolve_policies(args.policy)
    looks = _int_list(args.looks, "--looks value", 0)
    if len(policy) != 1 or (looks and len(looks) > 1):
        raise UsageError("--policy and --looks: give one policy and one look budget")
    seeds = _seeds(args, default=frontier.DEFAULT_SEEDS)
    workers = args.workers or os.cpu_count() or 1
    jobs = frontier.frontier_jobs(scs, curves, policy[0], looks[0] if looks else None, seeds)
    for line in resources.check_jobs(jobs, workers):
        print(line, file=sys.stderr)
    out_dir = _out_dir(args, "frontier-", frontier.is_finished)
    args.out_dir = out_dir  # for the resume line after Ctrl-C
    settings = [f"command: `{shlex.join(args.argv)}`",
                f"seeds: {seeds[0]}..{seeds[-1]} ({len(seeds)})" if seeds == list(
                    range(seeds[0], seeds[-1] + 1)) else f"seeds: {seeds}",
                f"policy {policy[0].label}, looks per step: "
                f"{looks[0] if looks else 'the scenario default'}, OSPA c = "
                f"{'2 cells' if args.c is None else format(args.c, 'g')}, "
                f"p = {args.p:g}", f"runs: {len(jobs)} on {describe_current(workers, len(jobs))}"]
    with _folder_lock(out_dir):
        check_sweep(out_dir, [job.key(args.c, args.p) for job in jobs], args.c, args.p,
                    args.resume)
        prepare_out_dir(out_dir)
        print(f"{len(jobs)} runs on {describe_current(workers, len(jobs))} -> {out_dir}",
              file=sys.stderr)
        reference = _bayes_lines(scs, policy[0], looks[0] if looks else None, seeds, args)
        settings += [f"reference {sc}: {ref.label}" for sc, ref in reference.items()]
        res = frontier.run_frontier(jobs, curves, out_dir, settings=settings,
                                    workers=workers, progress=not args.no_progress,
                                    resume=args.resume, c=args.c, p=args.p,
                                    run_timeout=args.run_timeout, reference=reference)
    print((out_dir / frontier.REPORT_FILE).read_text(encoding="utf-8"))
    print(f"wrote {out_dir}/: {', '.join(res.files)}")
    failed = frontier.failure_line(res.results, out_dir)
    if failed:
        print(failed, file=sys.stderr)
        return 1
    return 0


def _bayes_lines(scs, policy, looks, seeds, args: argparse.Namespace) -> dict:
    """The frontier's reference line per scenario: the stored Bayes reference's OSPA on
    these seeds (:mod:`benchmarks.app.bayes`), where one is stored."""
    from . import bayes, frontier
    from .summary import mean_ci95

    out = {}
    for sc in scs:
        ref = bayes.find(sc, policy, looks, seeds, args.c, args.p)
        if ref is None:
            continue
        ok = ref.rows[ref.rows["status"] == "ok"]
        mean, half = mean_ci95(ok.groupby("seed")["ospa"].mean().to_numpy(float))
        state = "converged" if ref.converged else "not converged"
        out[sc.name] = frontier.Reference(mean, half,
                                          f"bayes ({state}, N = {ref.n_particles})")
    return out


def cmd_tune(args: argparse.Namespace) -> int:
    """Tune trackers' parameters under one budget (:mod:`benchmarks.app.tune`): exit 0; 1 when
    a tracker has no finished trial; 2 for bad input."""
    from . import tune

    _check_common(args)
    if not 1 <= args.trials <= MAX_TRIALS:
        raise UsageError(f"--trials {args.trials} is not allowed: expected an integer from 1 "
                         f"to {MAX_TRIALS}")
    if args.batch_size is not None and not 1 <= args.batch_size <= MAX_TRIALS:
        raise UsageError(f"--batch-size {args.batch_size} is not allowed: expected an "
                         f"integer from 1 to {MAX_TRIALS}")
    if not 0 <= args.startup_trials <= MAX_TRIALS:
        raise UsageError(f"--startup-trials {args.startup_trials} is not allowed: expected an "
                         f"integer from 0 to {MAX_TRIALS}")
    if not 0 <= args.seed <= MAX_SAMPLER_SEED:
        raise UsageError(f"--seed {args.seed} is not allowed: expected an integer from 0 to "
                         f"{MAX_SAMPLER_SEED} (2**32 - 1)")
    if args.tuning_seeds > MAX_SEEDS or args.seed_start + args.tuning_seeds - 1 > MAX_INT64:
        raise UsageError(f"--tuning-seeds {args.tuning_seeds} from --seed-start "
                         f"{args.seed_start} is not allowed: expected at most {MAX_SEEDS} "
                         f"seeds, the last <= {MAX_INT64} (2**63 - 1)")
    if args.tuning_seeds < 1 or args.seed_start < tune.TUNING_SEED_BASE:
        raise UsageError(f"--tuning-seeds {args.tuning_seeds} from --seed-start "
                         f"{args.seed_start}: expected >= 1 seed from >= "
                         f"{tune.TUNING_SEED_BASE} (disjoint from the evaluation seeds)")
    scs = tuple(resolve_scenarios(args.scenarios, args.steps))
    specs = resolve_trackers(args.trackers)
    policy = resolve_policies(args.policy)
    if len(policy) != 1:
        raise UsageError("--policy: give one policy to tune under")
    looks = _int_list(args.looks, "--looks value", 0)
    if looks and len(looks) > 1:
        raise UsageError("--looks: give one look budget to tune under")
    workers = args.workers or os.cpu_count() or 1
    out_dir = _out_dir(args, "tune-", tune.is_finished)
    args.out_dir = out_dir  # for the resume line after Ctrl-C
    seeds = tuple(range(args.seed_start, args.seed_start + args.tuning_seeds))
    settings = []
    for spec in specs:
        batch = args.batch_size or (tune.stored_batch_size(out_dir, spec.name)
                                    if args.resume else None) or workers
        s = tune.TuneSettings(spec, scs, seeds, trials=args.trials, objective=args.objective,
                              policy=policy[0], looks=looks[0] if looks else None, c=args.c,
                              p=args.p, seed=args.seed, batch_size=batch,
                              startup_trials=args.startup_trials)
        problem = s.problem()
        if problem:
            raise UsageError(problem)
        for line in resources.check_jobs(s.jobs(s.spec({})), workers):
            print(line, file=sys.stderr)
        settings.append(s)
    with _folder_lock(out_dir):
        res = tune.run_tune(settings, out_dir, tuned_dir=args.tuned_dir, workers=workers,
                            resume=args.resume, progress=not args.no_progress,
                            argv=args.argv, run_timeout=args.run_timeout)
    status = 0
    for r in res.results:
        if r.record is None:
            print(f"{r.name}: {r.message}", file=sys.stderr)
            status = 1
            continue
        obj = r.record["objective"]
        default = obj.get("default_value")
        params = ", ".join(f"{k}={v}" for k, v in r.record["params"].items()) or "the defaults"
        print(f"{r.name}: mean {obj['metric'].upper()} {obj['value']:.4f} on the tuning seeds "
              f"(defaults: {'failed' if default is None else f'{default:.4f}'}) with {params}; "
              f"wrote {r.tuned_file}")
    print(f"wrote {res.out_dir}/: {', '.join(tune.OUTPUT_FILES)}, and per tracker "
          "study.journal, trials.csv, tuned.toml")
    return status


def cmd_reproduce(args: argparse.Namespace) -> int:
    """Reviewer reproduction (:mod:`~mttbench.benchmarks.app.reproduce`: the paper's figures;
    :mod:`~mttbench.benchmarks.app.reproduce_kreucher`: Kreucher's managed-versus-periodic
    curve): exit 0; 1 when ``--check`` finds moved numbers or a run failed; 2 for bad
    input."""
    from . import reproduce

    if args.workers is not None and args.workers < 1:
        raise UsageError(f"--workers {args.workers} is not allowed: expected an integer >= 1")
    _check_run_timeout(args)
    if args.exact and not args.check:
        raise UsageError("--exact only applies with --check")
    if args.check and args.update_reference:
        raise UsageError("--check and --update-reference: give one of them (check against "
                         "the reference, or replace it)")
    if args.target == "cdc2004":
        return _reproduce_cdc2004(args)
    if args.target == "kreucher":
        from . import reproduce_kreucher as target_module

        run = target_module.reproduce_kreucher
    else:
        target_module, run = reproduce, reproduce.reproduce_paper
    setting, out, cache, tracker_texts, specs, workers = _reproduce_inputs(args, target_module)
    ref_path = (Path(args.reference_csv) if args.reference_csv
                else reproduce.REFERENCE_DIR / f"{args.target}_{setting.name}.csv")
    if args.check and not ref_path.is_file():
        raise UsageError(f"--check: no reference {ref_path}")
    if args.check:  # read before the runs: a malformed reference is refused now
        try:
            reproduce.read_numbers(ref_path)
        except Exception as exc:  # noqa: BLE001 - pandas raises many types for a bad CSV
            first = (str(exc).strip().splitlines() or [""])[0]
            raise UsageError(f"--check: the reference {ref_path} is not a numbers CSV "
                             f"({type(exc).__name__}: {first})") from None
    for warning in resources.check_jobs(target_module.setting_jobs(setting, specs), workers):
        print(warning, file=sys.stderr)
    prepare_out_dir(out, parts=False)
    res = run(setting, out, cache, tracker_texts=tracker_texts, workers=workers,
              progress=not args.no_progress, use_cache=not args.no_cache,
              run_timeout=args.run_timeout)
    print(f"wrote {out}/ (figures, CSVs, report.md, report.html; runs "
          f"{'from the cache' if res.cached else 'computed'})")
    failed = _failure_line(res.results, out)
    if failed:
        print(failed.replace(str(out / "summary.csv"), str(out / "report.md")), file=sys.stderr)
        return 1
    versions_path = reproduce.versions_path(ref_path)
    if args.update_reference:
        written = reproduce.write_reference(res.numbers_csv, ref_path)
        print(f"reference updated: {ref_path} ({len(res.numbers)} numbers; versions in "
              f"{written.name})")
        return 0
    if not args.check:
        return 0
    check = reproduce.check_numbers(res.numbers, reproduce.read_numbers(ref_path),
                                    exact=args.exact)
    if check.passed:
        print(f"check passed: {check.n_compared} numbers agree with {ref_path} "
              f"({check.criterion})")
        return 0
    print(f"check FAILED: {check.n_moved} number(s) differ from {ref_path} beyond "
          f"{check.criterion}:", file=sys.stderr)
    limit = reproduce.MAX_REPORTED
    for line in check.lines[:limit]:
        print("  " + line, file=sys.stderr)
    if len(check.lines) > limit:
        print(f"  ... and {len(check.lines) - limit} more lines", file=sys.stderr)
    if versions_path.exists():
        changed = reproduce.changed_versions(json.loads(versions_path.read_text()))
        if changed:
            print("  note: the reference was made in another environment: " + ", ".join(changed)
                  + (" (another numpy, scipy or CPU dispatch can change the last bits, and a "
                     "particle filter's run then diverges: --check without --exact allows "
                     "for that)" if args.exact else ""), file=sys.stderr)
    return 1


def _reproduce_inputs(args: argparse.Namespace, module: Any) -> tuple:
    """What every reproduction reads from the command line: ``module``'s setting (full or
    ``--reduced``), the output and cache folders, the ``--trackers`` texts (checked), the
    registered trackers' specs and the worker count."""
    from . import reproduce

    setting = module.SETTINGS["reduced" if args.reduced else "full"]
    out = Path(args.out) if args.out else Path("reports") / args.target
    cache = Path(args.cache_dir) if args.cache_dir else Path(".cache") / "reproduce"
    tracker_texts = tuple(split_specs(args.trackers)) if args.trackers else None
    if tracker_texts:
        resolve_trackers(tracker_texts)
    specs, _ = reproduce.available_trackers(tracker_texts or setting.trackers)
    return setting, out, cache, tracker_texts, specs, args.workers or os.cpu_count() or 1


def _reproduce_cdc2004(args: argparse.Namespace) -> int:
    """``reproduce cdc2004`` (:mod:`~mttbench.benchmarks.app.reproduce_cdc2004`): its
    ``--check`` is its own (structure, and not worse than myopic beyond noise), with no
    reference CSV."""
    from . import reproduce_cdc2004 as cdc

    for flag in ("update_reference", "exact", "reference_csv"):
        if getattr(args, flag):
            raise UsageError(f"--{flag.replace('_', '-')} does not apply to cdc2004: it has no "
                             "reference CSV (--check runs its own checks)")
    setting, out, cache, tracker_texts, specs, workers = _reproduce_inputs(args, cdc)
    for warning in resources.check_jobs(cdc.setting_jobs(setting, specs), workers):
        print(warning, file=sys.stderr)
    prepare_out_dir(out, parts=False)
    rep = cdc.reproduce_cdc2004(setting, out, cache, tracker_texts=tracker_texts,
                                workers=workers, progress=not args.no_progress,
                                use_cache=not args.no_cache, run_timeout=args.run_timeout)
    print(f"wrote {out}/ (policies.csv, paired.csv, runs.csv, report.md, report.html; runs "
          f"{'from the cache' if rep.cached else 'computed'})")
    for line in cdc.verdict_lines(rep.paired, setting):
        print(line.replace("`", ""))
    failed = _failure_line(rep.results, out)
    if failed:
        print(failed.replace(str(out / "summary.csv"), str(out / "report.md")), file=sys.stderr)
        return 1
    if not args.check:
        return 0
    result = cdc.check(setting, rep.specs, rep.results)
    if result.passed:
        print(f"check passed: {result.n_conditions} conditions (every run, every seed, no "
              "look at a blind cell, visibility in force, not worse than myopic beyond noise)")
        return 0
    print(f"check FAILED: {len(result.lines)} of {result.n_conditions} conditions:",
          file=sys.stderr)
    for line in result.lines:
        print("  " + line, file=sys.stderr)
    return 1


def cmd_export(args: argparse.Namespace) -> int:
    """Write open world files (:mod:`~mttbench.benchmarks.app.export`): exit 0; 2 for bad
    input, a closed-loop policy or a scenario without cells, refused before any file."""
    from . import export

    if args.steps is not None and args.steps < 1:
        raise UsageError(f"--steps {args.steps} is not allowed: expected an integer >= 1")
    scs = resolve_scenarios(args.scenarios, args.steps)
    policy_specs = resolve_policies(args.policy)
    for sc in scs:
        export.check_exportable(sc, policy_specs)
    looks = _int_list(args.looks, "--looks value", 0)
    seeds = _seeds(args, default=10)
    export.check_size(scs, looks)
    out_dir = Path(args.out) if args.out else REPORTS / f"export-{_timestamp()}"
    with _folder_lock(out_dir, EXPORT_MARK):
        export.check_names(scs, policy_specs, seeds, out_dir, looks)
        prepare_out_dir(out_dir, parts=False)
        index = export.export_worlds(scs, policy_specs, seeds, out_dir, looks)
    print(f"wrote {len(index)} world(s) into {out_dir}/ ({export.WORLDS_INDEX}; per world "
          f"{', '.join(export.WORLD_FILES)}, {export.CARD}); schema: docs/world_format.md")
    return 0


def cmd_score(args: argparse.Namespace) -> int:
    """Score an outside tracker's estimates (:mod:`~mttbench.benchmarks.app.score`): exit 0;
    2 for a bad world, estimates file or option, refused before anything is written."""
    from . import score

    _check_common(args)
    _check_path("WORLD_DIR", args.world_dir, must_exist=True)
    _check_path("--beside", args.beside, must_exist=True)
    out_dir = Path(args.out) if args.out else REPORTS / f"score-{_timestamp()}"
    check_folder_kind(out_dir, SCORE_MARK)
    if (out_dir / "results.parquet").exists() and not (out_dir / SCORE_MARK).exists():
        raise UsageError(f"--out {out_dir} holds the results of another command; choose "
                         "another folder")
    with _folder_lock(out_dir, SCORE_MARK):
        res = score.run_score(args.world_dir, args.estimates, args.name, out_dir, c=args.c,
                              p=args.p, beside=args.beside)
    print((out_dir / "summary.md").read_text(encoding="utf-8"))
    print(f"wrote {out_dir}/: {', '.join(res.files)}")
    return 0


def _provenance(argv: Sequence[str]) -> dict:
    """Commit, package versions and the command, for a stored result."""
    from .compare import git_commit, package_versions

    return {"git": git_commit(), "versions": package_versions(), "command": list(argv)}


def cmd_bayes(args: argparse.Namespace) -> int:
    """The converged Bayes reference of each scenario (:mod:`benchmarks.app.bayes`),
    computed on a particle-count ladder and stored: exit 0 (converged or not: the table
    says which), 1 when a run failed, 2 for bad input."""
    from . import bayes

    _check_common(args)
    if bool(args.scenarios) == bool(args.suite):
        raise UsageError("name the scenarios (SCENARIO ...) or --suite, one of the two")
    ladder = bayes.Ladder(n_start=args.n_start, factor=args.factor, n_max=args.n_max,
                          tolerance=args.tolerance, run_limit_s=args.run_limit,
                          gap_share=args.gap_share, confirm=args.confirm)
    scs = resolve_scenarios(_scenario_names(args), args.steps)
    pols = resolve_policies(args.policy)
    if len(pols) != 1:
        raise UsageError("--policy: one policy per reference (run the command once per "
                         "policy)")
    policy = pols[0]
    looks = _int_list(args.looks, "--looks value", 1)
    if looks is not None and len(looks) > 1:
        raise UsageError("--looks: one look budget per reference (run the command once per "
                         "budget)")
    seeds = _seeds(args, default=bayes.DEFAULT_SEEDS)
    store = Path(args.store) if args.store else bayes.default_write_store()
    out_dir = _out_dir(args, "bayes-", lambda f: (f / "ladder.md").is_file())
    args.out_dir = out_dir  # for the resume line after Ctrl-C
    workers = args.workers or os.cpu_count() or 1
    with _folder_lock(out_dir):
        refs = bayes.run_command(scs, seeds, ladder, policy, None if looks is None else looks[0],
                                 out_dir, store, workers=workers,
                                 progress=not args.no_progress, resume=args.resume, c=args.c,
                                 p=args.p, run_timeout=args.run_timeout,
                                 provenance=_provenance(args.argv))
    failed = [name for name, ref in refs.items() if "failed" in ref.provenance.get("reason", "")]
    if failed:
        print(f"runs failed on {', '.join(failed)}; see {out_dir / 'ladder.md'}",
              file=sys.stderr)
        return 1
    return 0


def cmd_screenshot(args: argparse.Namespace) -> int:
    """Open a report folder's ``report.html`` in headless chromium; write ``screenshot.png``."""
    from .report import screenshot

    folder = Path(args.report_dir)
    if not (folder / "report.html").is_file():
        raise UsageError(f"{folder} holds no report.html")
    try:
        png = screenshot(folder / "report.html", folder / "screenshot.png")
    except (FileNotFoundError, RuntimeError) as exc:
        raise UsageError(str(exc).splitlines()[0]) from None
    print(png)
    return 0


# ----------------------------------------------------------------------- parser
SUITE_HELP = ("the scenarios of a suite instead of --scenarios: `envelope` (the operating "
              "envelope's points, docs/envelope.md), `envelope:train` or `envelope:held` (one "
              "split); each point runs at its own looks_per_step")


def _add_sweep_options(p: argparse.ArgumentParser, *, seeds_default: int,
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
    p.add_argument("--steps", type=int, metavar="K",
                   help="override every scenario's n_steps (default: the scenario's)")
    p.add_argument("--out", metavar="DIR",
                   help="output folder (default reports/<command>-<UTC timestamp>)")
    p.add_argument("--resume", action="store_true",
                   help="skip runs already saved in DIR/parts (an interrupted sweep; damaged "
                        "parts are recomputed); without --out: the most recent unfinished "
                        "folder of this command under reports/")
    _add_metric_options(p)
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    _add_run_timeout(p)


def _add_run_timeout(p: argparse.ArgumentParser, then: str = "gets an error row") -> None:
    """``--run-timeout``: the wall-time limit of one run (every command that runs)."""
    p.add_argument("--run-timeout", type=float, default=None, metavar="SECONDS",
                   help=f"wall-time limit of one run: a run still going is ended and {then} "
                        "(default: 10x the slowest run's estimate, at least 60 s)")


def _add_metric_options(p: argparse.ArgumentParser) -> None:
    """``--c`` and ``--p``: the OSPA/GOSPA cut-off and order."""
    p.add_argument("--c", type=float, default=None,
                   help="OSPA/GOSPA cut-off c in world units (default 2 cells: 2 x each "
                        "scenario's cell_size)")
    p.add_argument("--p", type=float, default=2.0, help="OSPA/GOSPA order p (default 2)")


class _Parser(argparse.ArgumentParser):
    """An argument parser whose errors are one line (no usage block): ``PROG: error:
    MESSAGE (see PROG --help)``, exit status 2. Sub-command parsers are of this class too."""

    def error(self, message: str) -> None:  # type: ignore[override]
        self.exit(2, f"{self.prog}: error: {' '.join(message.split())} "
                     f"(see `{self.prog} --help`)\n")


def build_parser() -> argparse.ArgumentParser:
    fmt = argparse.RawDescriptionHelpFormatter
    parser = _Parser(
        prog="mttbench", formatter_class=fmt,
        description="Benchmarks of multi-target trackers with an unknown number of targets.",
        epilog="Run `mttbench COMMAND --help` for the options of a command.")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")

    p = sub.add_parser("scenarios", help="list the scenario presets",
                       description="List the shipped scenario presets with their descriptions. "
                                   "Any command also accepts a path to a scenario .toml file.")
    p.set_defaults(func=cmd_scenarios)

    p = sub.add_parser("trackers", help="list trackers (with parameters) and policies",
                       description="List the registered trackers with their parameters and "
                                   "defaults, and the cell-selection policies.")
    p.set_defaults(func=cmd_trackers)

    p = sub.add_parser(
        "run", help="run a sweep and summarise it", formatter_class=fmt,
        description="Run every scenario x tracker x policy x looks x seed and write "
                    "results.parquet (one row per step), summary.csv and summary.md into "
                    "--out; print the summary (means over seeds ± 95% t half-widths).",
        epilog=textwrap.dedent("""\
            examples:
              mttbench run --scenarios default --trackers null kfnn --seeds 20
              mttbench run --scenarios default crossing my.toml \\
                  --trackers kfnn jmpd:n_particles=1000 --policy raster,renyi \\
                  --looks 12,24 --workers 2 --out reports/mine
              mttbench run ... --out reports/mine --resume   # finish an interrupted sweep

            The superposition scenario has no cells: --policy and --looks do not apply
            to it (one run per tracker x seed)."""))
    g = p.add_mutually_exclusive_group(required=True)
    g.add_argument("--scenarios", nargs="+", metavar="SCENARIO",
                   help="preset names (see `mttbench scenarios`), envelope points (env-...) "
                        "or paths to .toml files")
    g.add_argument("--suite", metavar="SUITE", help=SUITE_HELP)
    _add_sweep_options(p, seeds_default=10, trackers_required=True)
    p.add_argument("--policy", nargs="+", default=["raster"], metavar="SPEC",
                   help="cell-selection policies, comma or space separated "
                        "(default raster; see `mttbench trackers`)")
    p.add_argument("--store", choices=("parts", "dataset"), default=None,
                   help="how the rows are kept: parts (one Parquet file per run, then "
                        "results.parquet; the default) or dataset (one file per worker "
                        "batch, partitioned by scenario and tracker, plus runs.parquet: "
                        "for studies of 10^4 runs and more, docs/result_store.md); "
                        "default: the folder's own on --resume, else $MTTBENCH_STORE, "
                        "else parts")
    p.add_argument("--looks", nargs="+", metavar="M",
                   help="looks per step, comma or space separated "
                        "(default: each scenario's looks_per_step)")
    p.add_argument("--workers", type=int, default=None, metavar="N",
                   help="parallel worker processes (default: the number of CPUs)")
    add_executor_arguments(p)
    p.set_defaults(func=cmd_run)

    p = sub.add_parser(
        "compare", help="head-to-head report of every tracker on the standard scenarios",
        formatter_class=fmt,
        description="The main job. Every registered tracker (including the `null` baseline; "
                    "JMPD at 1000 and 250 particles) on the scenarios "
                    f"{', '.join(COMPARE_SCENARIOS)}, raster policy at each scenario's look "
                    f"budget (--policies: every tracker under each policy), {COMPARE_SEEDS} "
                    "seeds, in parallel processes. Writes "
                    "results.parquet, summary.csv/.md, report.md, a self-contained "
                    "report.html, figures/ and manifest.json into --out (default "
                    "reports/compare-<UTC timestamp>). Defaults take about 1.5 minutes on 2 "
                    "cores (longer on a busy machine).",
        epilog=textwrap.dedent("""\
            examples:
              mttbench compare
              mttbench compare --seeds 30 --steps 200 --workers 8
              mttbench compare --trackers kfnn gpf jmpd:n_particles=4000 --scenarios crossing \\
                  --reference gpf
              mttbench compare --policies raster renyi --trackers null truth-aided gpf pmb"""))
    g = p.add_mutually_exclusive_group()
    g.add_argument("--scenarios", nargs="+", default=list(COMPARE_SCENARIOS),
                   metavar="SCENARIO", help="override the scenarios")
    g.add_argument("--suite", metavar="SUITE", help=SUITE_HELP)
    _add_sweep_options(p, seeds_default=COMPARE_SEEDS, trackers_required=False)
    p.add_argument("--workers", type=int, default=None, metavar="N",
                   help="parallel worker processes (default: the number of CPUs)")
    p.add_argument("--policies", "--policy", nargs="+", default=["raster"], metavar="SPEC",
                   help="cell-selection policies, comma or space separated (default "
                        "raster): every tracker runs under each on the same worlds; the "
                        "report adds a tracker x policy table with the paired differences "
                        "against the first and the best pair per scenario (see `mttbench "
                        "trackers`)")
    p.add_argument("--reference", default=None, metavar="TRACKER",
                   help="tracker (name or label) that paired differences subtract "
                        f"(default: the first of {', '.join(COMPARE_REFERENCES)} that runs, "
                        "else the first tracker that does not use the truth)")
    g = p.add_mutually_exclusive_group()
    g.add_argument("--untuned", action="store_true",
                   help="run every tracker's defaults, not its tuned parameters")
    g.add_argument("--tuning-effect", action="store_true",
                   help="run each tuned tracker's defaults beside it and report tuned minus "
                        "default (paired by seed)")
    p.add_argument("--tuned-dir", metavar="DIR",
                   help="tuned parameter files (default: the package's tuned/; a tracker "
                        "with DIR/<name>.toml runs its parameters, labelled name(tuned))")
    p.add_argument("--bayes", action="store_true",
                   help="compute the converged Bayes reference of every scenario that has "
                        "none stored for these seeds (`mttbench bayes` with its defaults, "
                        "into DIR/bayes/; minutes to hours: docs/bayes.md); without it the "
                        "stored references are shown where they exist")
    add_executor_arguments(p)
    p.set_defaults(func=cmd_compare)

    p = sub.add_parser(
        "frontier", help="accuracy against cost as each tracker's budget grows (particles, "
                         "components, tracks)", formatter_class=fmt,
        description="For each tracker, sweep its main budget parameter (its declared "
                    "Tracker.budget: particles, Gaussians per track, tracks) on a log grid of "
                    "--points values within the declared range, every setting on the same "
                    "seeds (common random numbers), as one sweep (local pool or --executor "
                    "dask, --resume, a progress bar). Writes results.parquet, frontier.csv "
                    "(per scenario x tracker x budget: OSPA, CPU ms per step and count error, "
                    "means over seeds with 95% intervals; the Pareto front), cheapest.csv, "
                    "frontier.md and frontier-<scenario>.png into --out (default "
                    "reports/frontier-<UTC timestamp>). A tracker with no budget knob (kfnn, "
                    "ss-gnn) is one point.",
        epilog=textwrap.dedent("""\
            examples:
              mttbench frontier default --trackers gpf jmpd-ap pmb --seeds 4 --workers 1
              mttbench frontier default env-pf-0.1 --trackers jmpd-ap --range jmpd-ap=250:4000
              mttbench frontier default --trackers gpf --range gpf.max_combinations=4:512
              mttbench frontier default --trackers gpf --out reports/f --resume  # after Ctrl-C

            Budget ranges (`mttbench trackers` lists the parameters): gpf max_components 1-8,
            jmpd and jmpd-ap n_particles 100-16000, pmb max_components 1-8, ss-gmphd
            max_components 3-300, ss-jpda max_tracks 5-120."""))
    p.add_argument("scenarios", nargs="+", metavar="SCENARIO",
                   help="preset names, envelope points (env-...) or paths to .toml files")
    _add_sweep_options(p, seeds_default=5, trackers_required=True)
    p.add_argument("--points", type=int, default=5, metavar="K",
                   help="budgets per tracker, log-spaced over the range, ends included "
                        "(default 5; integer budgets are rounded and repeats dropped)")
    p.add_argument("--range", nargs="+", metavar="NAME[.PARAM]=LOW:HIGH",
                   help="sweep within LOW..HIGH instead of the declared range (which it must "
                        "lie within); .PARAM sweeps another declared budget parameter than "
                        "the main one")
    p.add_argument("--policy", nargs="+", default=["raster"], metavar="SPEC",
                   help="the one cell-selection policy (default raster)")
    p.add_argument("--looks", nargs="+", metavar="M",
                   help="one look budget per step (default: each scenario's looks_per_step)")
    p.add_argument("--workers", type=int, default=None, metavar="N",
                   help="parallel worker processes (default: the number of CPUs)")
    add_executor_arguments(p)
    p.set_defaults(func=cmd_frontier)

    from . import tune as _tune  # its defaults (optuna is imported only when tuning)

    p = sub.add_parser(
        "tune", help="tune trackers' parameters, the same budget for each, on held-apart seeds",
        formatter_class=fmt,
        description="\n\n".join(textwrap.fill(" ".join(para.split()), 88) for para in (
            "Tune each tracker's declared search space (its parameters' search=Search(...), "
            "listed in the tuned file) with optuna's seeded TPE sampler, minimising the mean "
            "of the --objective metric (default OSPA; one of "
            f"{', '.join(_tune.objective_names())}): each run's per-step values averaged over its "
            "steps, then over the tuning seeds, then over the scenarios.",
            "Budget, the same for every tracker and stated in the output: --trials parameter "
            "settings x --tuning-seeds seeds x the scenarios, each run --steps long (the "
            "scenario's own by default) under the raster policy at the scenario's look "
            "budget (--policy/--looks), plus those runs once more for the defaults, so the "
            f"output shows what tuning gained. Default: {_tune.TUNE_TRIALS} trials x "
            f"{_tune.TUNE_SEEDS} seeds x {len(_tune.TUNE_SCENARIOS)} scenarios of 100 steps "
            f"= {_tune.TUNE_TRIALS * _tune.TUNE_SEEDS * len(_tune.TUNE_SCENARIOS)} runs per "
            f"tracker (+ {_tune.TUNE_SEEDS * len(_tune.TUNE_SCENARIOS)} for the defaults), "
            "about 20 minutes for kfnn, gpf, jmpd-ap:n_particles=250, ss-gnn and ss-gmphd "
            "together on a quiet 2-core machine (docs/tune.md).",
            f"Tuning seeds start at {_tune.TUNING_SEED_BASE:,}; evaluation seeds (--seeds N: "
            "0..N-1) never reach them. Trials go in batches of --batch-size (default: the "
            "workers) over the same executor as `run`; every run is saved at once, and "
            "--resume continues an interrupted study with the trials an uninterrupted one "
            "would have drawn. Writes tuned/<tracker>.toml (the best parameters and their "
            "provenance; `mttbench compare` runs them) and the study into --out (default "
            "reports/tune-<UTC timestamp>).")),
        epilog=textwrap.dedent("""\
            examples:
              mttbench tune kfnn --trials 8 --tuning-seeds 2 --scenarios default --steps 50
              mttbench tune kfnn gpf jmpd-ap:n_particles=250 ss-gnn ss-gmphd  # default budget
              mttbench tune kfnn --out reports/tune-kfnn --resume  # after an interrupt

            Parameters given with a tracker (jmpd-ap:n_particles=250) are held fixed and
            not searched. A failed run fails its trial (kept in trials.csv); the study
            goes on."""))
    p.add_argument("trackers", nargs="+", metavar="TRACKER",
                   help="trackers to tune, as NAME or NAME:key=value (held fixed)")
    p.add_argument("--trials", type=int, default=_tune.TUNE_TRIALS, metavar="N",
                   help=f"parameter settings tried per tracker (default {_tune.TUNE_TRIALS})")
    p.add_argument("--tuning-seeds", type=int, default=_tune.TUNE_SEEDS, metavar="N",
                   help=f"seeds per scenario and setting (default {_tune.TUNE_SEEDS})")
    p.add_argument("--seed-start", type=int, default=_tune.TUNING_SEED_BASE, metavar="S",
                   help=f"first tuning seed (default and least {_tune.TUNING_SEED_BASE:,})")
    p.add_argument("--scenarios", nargs="+", metavar="SCENARIO",
                   default=list(_tune.TUNE_SCENARIOS),
                   help="scenarios the objective averages (default: "
                        f"{' '.join(_tune.TUNE_SCENARIOS)})")
    p.add_argument("--steps", type=int, metavar="K",
                   help="override every scenario's n_steps (default: the scenario's)")
    p.add_argument("--objective", choices=_tune.objective_names(), default="ospa",
                   help="metric minimised (default ospa): a registered metric declared "
                        "objective=True (mttbench.benchmarks.engine.metrics)")
    p.add_argument("--policy", nargs="+", default=["raster"], metavar="SPEC",
                   help="the cell-selection policy to tune under (default raster)")
    p.add_argument("--looks", nargs="+", metavar="M",
                   help="looks per step (default: each scenario's looks_per_step)")
    p.add_argument("--seed", type=int, default=0,
                   help="seed of the TPE sampler (default 0)")
    p.add_argument("--startup-trials", type=int, default=_tune.STARTUP_TRIALS, metavar="N",
                   help="random trials before TPE models the results (default "
                        f"{_tune.STARTUP_TRIALS})")
    p.add_argument("--batch-size", type=int, default=None, metavar="B",
                   help="trials asked together and run in parallel (default: the workers; a "
                        "resumed study keeps its own)")
    p.add_argument("--workers", type=int, default=None, metavar="N",
                   help="parallel worker processes (default: the number of CPUs)")
    p.add_argument("--tuned-dir", metavar="DIR",
                   help="where tuned/<tracker>.toml goes (default: the checkout's tuned/; "
                        "from an installed package ./tuned)")
    p.add_argument("--out", metavar="DIR",
                   help="study folder (default reports/tune-<UTC timestamp>)")
    p.add_argument("--resume", action="store_true",
                   help="continue the studies in DIR (runs already saved are read back); "
                        "without --out: the most recent unfinished reports/tune-* folder")
    _add_metric_options(p)
    p.add_argument("--no-progress", action="store_true", help="no progress lines")
    _add_run_timeout(p, "fails its trial")
    add_executor_arguments(p)
    p.set_defaults(func=cmd_tune)

    p = sub.add_parser(
        "reproduce", help="regenerate the paper's figures (or Kreucher's managed-versus-periodic "
                          "curve) and check them against the reference",
        formatter_class=fmt,
        description="paper: regenerate the paper's two result figures (snapshot on the 12x12 "
                    "grid; state and count error over time) for the GPF with the other "
                    "trackers overlaid, from pinned seeds, into --out (default reports/paper), "
                    "with the numbers behind each figure as CSV. kreucher: Kreucher's "
                    "managed-versus-periodic result on the `kreucher` preset at snr 2 and 10 "
                    "(renyi at 24 looks against raster at 24-312 looks, the raster looks that "
                    "match the managed scan, for the literature-strength JMPD and the GPF) "
                    "into reports/kreucher (module mttbench.benchmarks.app.reproduce_kreucher). "
                    "cdc2004: the non-myopic `lookahead` policy against the myopic `renyi` "
                    "on the `occlusion` preset, paired over seeds, against Kreucher, Hero, "
                    "Kastella and Chang (CDC 2004) into reports/cdc2004 (module "
                    "mttbench.benchmarks.app.reproduce_cdc2004; its --check is its own: "
                    "structure, and not worse than myopic beyond noise). "
                    "Runs are cached by their "
                    "configuration, code, package versions, platform and numpy CPU dispatch "
                    "(.cache/reproduce); figures only plot. --check compares the curves "
                    "with the checked-in reference within their Monte Carlo error, so it "
                    "holds on any CPU; --check --exact compares every number bit for bit "
                    "(same machine). Either exits 1 naming every number that moved.",
        epilog=textwrap.dedent("""\
            examples:
              mttbench reproduce paper                    # full setting
              mttbench reproduce paper --reduced --check  # what CI runs
              mttbench reproduce paper --reduced --check --exact  # same machine, bit for bit
              mttbench reproduce paper --reduced --update-reference  # after a change
              mttbench reproduce kreucher --reduced --check  # managed against periodic
              mttbench reproduce cdc2004 --reduced --check   # non-myopic under occlusion"""))
    p.add_argument("target", choices=["paper", "kreucher", "cdc2004"],
                   help="what to reproduce: the paper's figures, Kreucher's "
                        "managed-versus-periodic curve, or the non-myopic policy against "
                        "the myopic one under occlusion (Kreucher et al., CDC 2004)")
    p.add_argument("--reduced", action="store_true",
                   help="the reduced setting (fewer seeds and steps; what CI checks)")
    p.add_argument("--check", action="store_true",
                   help="compare the numbers with the reference CSV within their Monte Carlo "
                        "error (holds on any CPU): each curve's mean |now - ref| / (95%% band "
                        "+ floor) over its steps <= 1 and every step <= 4; truth and seed "
                        "counts exact; exit 1 naming every number that moved")
    p.add_argument("--exact", action="store_true",
                   help="with --check: bit-for-bit mode for the same machine (every number "
                        "within rtol 1e-9, intervals and snapshot included)")
    p.add_argument("--update-reference", action="store_true",
                   help="write the numbers as the new reference with its versions file "
                        "(after a deliberate change of a tracker or of the setting; commit "
                        "both)")
    p.add_argument("--reference-csv", metavar="CSV",
                   help="reference to check against (default "
                        "reports/reference/<target>_<setting>.csv)")
    p.add_argument("--trackers", nargs="+", metavar="SPEC",
                   help="trackers to overlay (default: the reproduction's pinned list, "
                        "those registered)")
    p.add_argument("--out", metavar="DIR",
                   help="output folder (default reports/<target>: reports/paper, "
                        "reports/kreucher)")
    p.add_argument("--cache-dir", metavar="DIR", help="run cache (default .cache/reproduce)")
    p.add_argument("--no-cache", action="store_true",
                   help="recompute, neither reading nor writing the cache")
    p.add_argument("--workers", type=int, default=None, metavar="N",
                   help="parallel worker processes (default: the number of CPUs)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    _add_run_timeout(p, "gets an error row (the reproduction exits 1)")
    add_executor_arguments(p)
    p.set_defaults(func=cmd_reproduce)

    p = sub.add_parser(
        "export", help="write open world files (truth, every look, a model card) for a "
                       "tracker that runs elsewhere",
        formatter_class=fmt,
        description="For each world (scenario x policy x looks x seed), drawn by the same "
                    "step loop as `run` (the same seeds give the same truth and looks), write "
                    "the truth, every look with its 0/1 return (zeros included), Stone Soup "
                    "CSV files and a model card (JSON: model, policy, seed, versions, sha256 "
                    "of each file) as Parquet and CSV into --out/<world>/ (default "
                    "reports/export-<UTC timestamp>). Open-loop policies only (all, random, "
                    "raster): a closed-loop policy's looks depend on the tracker's own "
                    "estimates. Columns: docs/world_format.md.",
        epilog=textwrap.dedent("""\
            examples:
              mttbench export default --seeds 5 --policy random --out worlds
              mttbench export births my.toml --seed-list 7,8 --policy raster --looks 12,24"""))
    p.add_argument("scenarios", nargs="+", metavar="SCENARIO",
                   help="preset names, envelope points (env-...) or paths to .toml files")
    g = p.add_mutually_exclusive_group()
    g.add_argument("--seeds", type=int, metavar="N",
                   help=f"worlds of seeds 0..N-1 (default 10; N <= {MAX_SEEDS})")
    g.add_argument("--seed-list", nargs="+", metavar="SEED",
                   help="explicit seeds, space or comma separated")
    p.add_argument("--policy", nargs="+", default=["raster"], metavar="SPEC",
                   help="open-loop policies, comma or space separated (default raster)")
    p.add_argument("--looks", nargs="+", metavar="M",
                   help="looks per step (default: each scenario's looks_per_step)")
    p.add_argument("--steps", type=int, metavar="K",
                   help="override every scenario's n_steps (default: the scenario's)")
    p.add_argument("--out", metavar="DIR",
                   help="output folder (default reports/export-<UTC timestamp>)")
    p.set_defaults(func=cmd_export)

    p = sub.add_parser(
        "score", help="score an outside tracker's estimates on exported worlds",
        formatter_class=fmt,
        description="Read an outside tracker's estimates (CSV or Parquet; columns step, x, y, "
                    "optional label and count) on the worlds of WORLD_DIR (one world, or an "
                    "export folder: then FILE is relative to each world's folder) and write "
                    "the same per-step rows, summaries and track scores as an in-process "
                    "tracker, under the tracker name outside:NAME, into --out (default "
                    "reports/score-<UTC timestamp>). --beside DIR adds the runs of a `run` or "
                    "`compare` folder on the same worlds (left unchanged) and writes the "
                    "report of both. A bad estimates file: exit 2 and one line. Format: "
                    "docs/world_format.md.",
        epilog=textwrap.dedent("""\
            examples:
              mttbench score worlds/default__seed0__random__m24 --estimates est.csv --name mine
              mttbench score worlds --estimates estimates.csv --name mine \\
                  --beside reports/inside --out reports/mine"""))
    p.add_argument("world_dir", metavar="WORLD_DIR",
                   help="a world folder, or an export folder (its worlds.csv)")
    p.add_argument("--estimates", required=True, metavar="FILE",
                   help="the estimates (.csv or .parquet); with an export folder, the file's "
                        "path inside each world's folder")
    p.add_argument("--name", metavar="NAME",
                   help="the outside tracker's name (default: the estimates file's stem); its "
                        "rows are labelled outside:NAME")
    p.add_argument("--out", metavar="DIR",
                   help="output folder (default reports/score-<UTC timestamp>)")
    p.add_argument("--beside", metavar="DIR",
                   help="a folder written by `mttbench run` or `compare` on the same worlds: "
                        "its rows join the summary and a report (report.md, report.html)")
    _add_metric_options(p)
    p.set_defaults(func=cmd_score, steps=None, workers=None)

    p = sub.add_parser(
        "bayes", help="compute and store the converged Bayes reference of scenarios",
        formatter_class=fmt,
        description="\n\n".join(textwrap.fill(" ".join(para.split()), 88) for para in (
            "The model's Bayes filter, approximated by jmpd-ap on a ladder of particle "
            "counts (--n-start, x --factor, up to --n-max) on the same worlds, until two "
            "consecutive counts' paired OSPA difference has a 95% interval within "
            "+-TOLERANCE (converged), or until the next count's runs would exceed "
            "--run-limit CPU seconds each (not converged: the largest count is an estimate, "
            "never a bound). docs/bayes.md.",
            "Every count's runs are a sweep in --out (default reports/bayes-<UTC "
            "timestamp>): progress, --resume, --executor dask as for `run`. The reference "
            "(the converged count's rows and its provenance: scenario hash, seeds, ladder, "
            "each count's OSPA and cost, commit) is written to --store (default: the "
            "checkout's reports/reference/bayes/, from an installed package ./bayes), where "
            "`mttbench compare` finds it and adds the `bayes` row and each tracker's share "
            "of the achievable gap.")),
        epilog=textwrap.dedent("""\
            examples:
              mttbench bayes default crossing births kreucher --seeds 10
              mttbench bayes --suite envelope --seeds 8 --n-max 16000 --workers 2
              mttbench bayes my.toml --seeds 10 --store refs --out reports/bayes-mine"""))
    p.add_argument("scenarios", nargs="*", metavar="SCENARIO", default=[],
                   help="preset names, envelope points (env-...) or paths to .toml files")
    p.add_argument("--suite", metavar="SUITE", help=SUITE_HELP)
    _add_sweep_options(p, seeds_default=10, trackers_required=None)
    p.add_argument("--policy", nargs="+", default=["raster"], metavar="SPEC",
                   help="the cell-selection policy (default raster: the same looks as every "
                        "tracker's)")
    p.add_argument("--looks", nargs="+", metavar="M",
                   help="looks per step (default: the scenario's looks_per_step)")
    p.add_argument("--n-start", type=int, default=1000, metavar="N",
                   help="the first particle count (default 1000)")
    p.add_argument("--factor", type=int, default=4, metavar="F",
                   help="each rung has F times the particles of the last (default 4)")
    p.add_argument("--n-max", type=int, default=64000, metavar="N",
                   help="the largest particle count (default 64000)")
    p.add_argument("--tolerance", type=float, default=0.02, metavar="D",
                   help="converged when the paired OSPA difference's 95%% interval lies "
                        "within +-D (default 0.02)")
    p.add_argument("--gap-share", type=float, default=0.05, metavar="S",
                   help="or within S of the achievable gap (null OSPA minus the higher "
                        "count's), whichever is wider (default 0.05; 0: --tolerance alone)")
    p.add_argument("--confirm", type=int, default=2, metavar="K",
                   help="converged when the last K steps (N -> 4N) each lie within it "
                        "(default 2; 1 to 3)")
    p.add_argument("--run-limit", type=float, default=600.0, metavar="SECONDS",
                   help="skip a rung whose runs would take more CPU seconds each (4x the "
                        "last rung's, measured; default 600)")
    p.add_argument("--store", metavar="DIR",
                   help="where the references go (default: the checkout's "
                        "reports/reference/bayes/; from an installed package ./bayes)")
    p.add_argument("--workers", type=int, default=None, metavar="N",
                   help="parallel worker processes (default: the number of CPUs)")
    add_executor_arguments(p)
    p.set_defaults(func=cmd_bayes)

    p = sub.add_parser(
        "screenshot", help="check a report in a real browser (headless chromium)",
        description="Open REPORT_DIR/report.html in headless chromium (Debian: apt-get "
                    "install chromium), with networking off, and write "
                    "REPORT_DIR/screenshot.png.")
    p.add_argument("report_dir", metavar="REPORT_DIR", help="a folder written by compare")
    p.set_defaults(func=cmd_screenshot)
    return parser


def _os_error_text(exc: OSError) -> str:
    what = exc.strerror or str(exc)
    return f"{exc.filename}: {what}" if exc.filename else what


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point; returns the exit status (0 ok, 1 a run or a write failed, 2 bad input,
    130 interrupted; see the module docstring)."""
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:  # --help (0) or an argparse error (2)
        return exc.code if isinstance(exc.code, int) else 2
    args.argv = ["mttbench", *(sys.argv[1:] if argv is None else argv)]
    if args.command is None:
        parser.print_help()
        return 2
    who = f"mttbench {args.command}"
    try:
        _check_inputs(args)
        with executor_scope(args):  # --executor: every sweep of the command runs there
            return args.func(args)
    except ConfigError as exc:  # the engine's, and UsageError, its subclass
        print(f"{who}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        out_dir = getattr(args, "out_dir", None)
        if out_dir is not None and (Path(out_dir) / "parts").is_dir():
            print(f"{who}: interrupted; finished runs are kept in {out_dir}/parts; resume "
                  f"with: {_resume_command(args, Path(out_dir))}", file=sys.stderr)
        else:
            print(f"{who}: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    except BrokenPipeError:  # output piped into `head` and the like: not an error
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0
    except OSError as exc:  # disk full, a folder removed mid-sweep, ...
        out_dir = getattr(args, "out_dir", None)
        kept = (f"; finished runs are kept in {out_dir}/parts (--resume)"
                if out_dir is not None and (Path(out_dir) / "parts").is_dir() else "")
        print(f"{who}: error: {_os_error_text(exc)}{kept}", file=sys.stderr)
        return 1
    except MemoryError:
        print(f"{who}: error: out of memory (the estimate of mttbench.benchmarks.app.resources "
              "was too low: run fewer --workers or a smaller scenario)", file=sys.stderr)
        return 1
