"""``mttbench bayes``: the converged Bayes reference, stored
(:mod:`~mttbench.benchmarks.app.bayes`)."""

from __future__ import annotations

import argparse
import os
import sys
import textwrap
from collections.abc import Sequence
from pathlib import Path

from ..engine.specs import resolve_policies, resolve_scenarios
from .cli_common import (
    SUITE_HELP,
    add_sweep_options,
    add_workers_option,
    check_common,
    choose_out_dir,
    folder_lock,
    int_list,
    scenario_names,
    seeds_of,
)
from .executor_options import add_executor_arguments
from .usage import UsageError


def _provenance(argv: Sequence[str]) -> dict:
    """Commit, package versions and the command, for a stored result."""
    from .compare import git_commit, package_versions

    return {"git": git_commit(), "versions": package_versions(), "command": list(argv)}


def cmd_bayes(args: argparse.Namespace) -> int:
    """The converged Bayes reference of each scenario (:mod:`benchmarks.app.bayes`),
    computed on a particle-count ladder and stored: exit 0 (converged or not: the table
    says which), 1 when a run failed, 2 for bad input."""
    from . import bayes

    check_common(args)
    if bool(args.scenarios) == bool(args.suite):
        raise UsageError("name the scenarios (SCENARIO ...) or --suite, one of the two")
    ladder = bayes.Ladder(n_start=args.n_start, factor=args.factor, n_max=args.n_max,
                          tolerance=args.tolerance, run_limit_s=args.run_limit,
                          gap_share=args.gap_share, confirm=args.confirm)
    scs = resolve_scenarios(scenario_names(args), args.steps)
    pols = resolve_policies(args.policy)
    if len(pols) != 1:
        raise UsageError("--policy: one policy per reference (run the command once per "
                         "policy)")
    policy = pols[0]
    looks = int_list(args.looks, "--looks value", 1)
    if looks is not None and len(looks) > 1:
        raise UsageError("--looks: one look budget per reference (run the command once per "
                         "budget)")
    seeds = seeds_of(args, default=bayes.DEFAULT_SEEDS)
    store = Path(args.store) if args.store else bayes.default_write_store()
    out_dir = choose_out_dir(args, "bayes-", lambda f: (f / "ladder.md").is_file())
    args.out_dir = out_dir  # for the resume line after Ctrl-C
    workers = args.workers or os.cpu_count() or 1
    with folder_lock(out_dir):
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


def add_parser(sub: argparse._SubParsersAction, fmt: type[argparse.HelpFormatter]) -> None:
    """The ``bayes`` sub-command and its options."""
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
    add_sweep_options(p, seeds_default=10, trackers_required=None)
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
    add_workers_option(p)
    add_executor_arguments(p)
    p.set_defaults(func=cmd_bayes)
