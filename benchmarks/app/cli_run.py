"""``mttbench run``: one sweep of scenario x tracker x policy x looks x seed, summarised."""

from __future__ import annotations

import argparse
import os
import sys
import textwrap
from pathlib import Path

import pandas as pd

from ..engine.executors import describe_current
from ..engine.loop import build_jobs
from ..engine.specs import resolve_policies, resolve_scenarios, resolve_trackers
from ..engine.store import check_sweep, prepare_out_dir, sweep_lock
from . import policy_axis, resources
from .cli_common import (
    SUITE_HELP,
    add_sweep_options,
    add_workers_option,
    check_common,
    choose_out_dir,
    failure_line,
    folder_lock,
    int_list,
    scenario_names,
    seeds_of,
)
from .compare import default_run_timeout
from .executor_options import add_executor_arguments
from .progress import run_sweep
from .summary import write_summary


def _run_finished(folder: Path) -> bool:
    return (folder / "summary.md").is_file()


def _sweep(args: argparse.Namespace, scs, tracker_specs, policy_specs, looks, seeds,
           out_dir: Path, workers: int, title: str) -> int:
    jobs = build_jobs(scs, tracker_specs, policy_specs, looks, seeds)
    for line in resources.check_jobs(jobs, workers):
        print(line, file=sys.stderr)
    resume = getattr(args, "resume", False)
    with folder_lock(out_dir):
        check_sweep(out_dir, [job.key(args.c, args.p) for job in jobs], args.c, args.p, resume)
        prepare_out_dir(out_dir)
        with sweep_lock(out_dir):
            print(f"{len(jobs)} runs on {describe_current(workers, len(jobs))} -> {out_dir}",
                  file=sys.stderr)
            results = run_sweep(jobs, out_dir, workers=workers, progress=not args.no_progress,
                                resume=resume, c=args.c, p=args.p,
                                run_timeout=args.run_timeout or default_run_timeout(jobs),
                                store=getattr(args, "store", None))
            table = _with_bayes(results, scs, policy_specs, looks, seeds, args)
            text = write_summary(table, out_dir, title,
                                 sections=_policy_sections(table, policy_specs))
    print(text)
    rows = ("dataset/ (the rows, by scenario and tracker), runs.parquet"
            if (Path(out_dir) / "runs.parquet").is_file() else "results.parquet")
    print(f"wrote {out_dir}/: {rows}, summary.csv, summary.md")
    failed = failure_line(results, out_dir)
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


def _policy_sections(results: pd.DataFrame, policy_specs) -> list[str]:
    """The tracker x policy section of ``compare`` (:mod:`.policy_axis`: the table, the
    paired ``policy - first`` differences, the best pair) where a scenario and look budget
    ran under two policies or more, the policies in the order given; none otherwise."""
    axis = policy_axis.policy_axis(results, order=[spec.label for spec in policy_specs])
    text = policy_axis.markdown(axis)
    return [text] if text else []


def cmd_run(args: argparse.Namespace) -> int:
    check_common(args)
    scs = resolve_scenarios(scenario_names(args), args.steps)
    tracker_specs = resolve_trackers(args.trackers)
    policy_specs = resolve_policies(args.policy)
    looks = int_list(args.looks, "--looks value", 0)
    seeds = seeds_of(args, default=10)
    out_dir = choose_out_dir(args, "run-", _run_finished)
    args.out_dir = out_dir  # for the resume line after Ctrl-C
    return _sweep(args, scs, tracker_specs, policy_specs, looks, seeds, out_dir,
                  args.workers or os.cpu_count() or 1, "mttbench run")


def add_parser(sub: argparse._SubParsersAction, fmt: type[argparse.HelpFormatter]) -> None:
    """The ``run`` sub-command and its options."""
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
    add_sweep_options(p, seeds_default=10, trackers_required=True)
    p.add_argument("--policy", "--policies", nargs="+", default=["raster"], metavar="SPEC",
                   help="cell-selection policies, comma or space separated "
                        "(default raster; see `mttbench trackers`); with two or more, "
                        "summary.md adds the tracker x policy table of `compare` (paired "
                        "differences against the first given, the best pair)")
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
    add_workers_option(p)
    add_executor_arguments(p)
    p.set_defaults(func=cmd_run)
