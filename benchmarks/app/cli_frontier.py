"""``mttbench frontier``: accuracy against each tracker's budget
(:mod:`~mttbench.benchmarks.app.frontier`)."""

from __future__ import annotations

import argparse
import os
import shlex
import sys
import textwrap

from ..engine.executors import describe_current
from ..engine.specs import resolve_policies, resolve_scenarios, resolve_trackers
from ..engine.store import check_sweep, prepare_out_dir
from . import resources
from .cli_common import (
    add_sweep_options,
    add_workers_option,
    check_common,
    choose_out_dir,
    folder_lock,
    int_list,
    seeds_of,
)
from .executor_options import add_executor_arguments
from .usage import UsageError


def cmd_frontier(args: argparse.Namespace) -> int:
    """Budget frontiers (:mod:`benchmarks.app.frontier`): exit 0; 1 when a run failed; 2 for
    bad input."""
    from . import frontier

    check_common(args)
    scs = resolve_scenarios(args.scenarios, args.steps)
    curves = frontier.build_curves(resolve_trackers(args.trackers), args.points,
                                   frontier.parse_ranges(args.range))
    policy = resolve_policies(args.policy)
    looks = int_list(args.looks, "--looks value", 0)
    if len(policy) != 1 or (looks and len(looks) > 1):
        raise UsageError("--policy and --looks: give one policy and one look budget")
    seeds = seeds_of(args, default=frontier.DEFAULT_SEEDS)
    workers = args.workers or os.cpu_count() or 1
    jobs = frontier.frontier_jobs(scs, curves, policy[0], looks[0] if looks else None, seeds)
    for line in resources.check_jobs(jobs, workers):
        print(line, file=sys.stderr)
    out_dir = choose_out_dir(args, "frontier-", frontier.is_finished)
    args.out_dir = out_dir  # for the resume line after Ctrl-C
    settings = [f"command: `{shlex.join(args.argv)}`",
                f"seeds: {seeds[0]}..{seeds[-1]} ({len(seeds)})" if seeds == list(
                    range(seeds[0], seeds[-1] + 1)) else f"seeds: {seeds}",
                f"policy {policy[0].label}, looks per step: "
                f"{looks[0] if looks else 'the scenario default'}, OSPA c = "
                f"{'2 cells' if args.c is None else format(args.c, 'g')}, "
                f"p = {args.p:g}", f"runs: {len(jobs)} on {describe_current(workers, len(jobs))}"]
    with folder_lock(out_dir):
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


def add_parser(sub: argparse._SubParsersAction, fmt: type[argparse.HelpFormatter]) -> None:
    """The ``frontier`` sub-command and its options."""
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
    add_sweep_options(p, seeds_default=5, trackers_required=True)
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
    add_workers_option(p)
    add_executor_arguments(p)
    p.set_defaults(func=cmd_frontier)
