"""``mttbench compare``: the head-to-head report (:mod:`~mttbench.benchmarks.app.compare`)."""

from __future__ import annotations

import argparse
import sys
import textwrap

from .cli_common import (
    SUITE_HELP,
    add_sweep_options,
    add_workers_option,
    check_common,
    choose_out_dir,
    failure_line,
    folder_lock,
    scenario_names,
    seeds_of,
)
from .compare import COMPARE_REFERENCES, COMPARE_SCENARIOS, COMPARE_SEEDS, OUTPUT_FILES, is_finished
from .executor_options import add_executor_arguments


def cmd_compare(args: argparse.Namespace) -> int:
    """The head-to-head report (:mod:`benchmarks.app.compare`)."""
    from .compare import run_compare
    from .policy_axis import resolve as resolve_policy_axis

    check_common(args)
    policy_specs = resolve_policy_axis(args.policies)
    seeds = seeds_of(args, default=COMPARE_SEEDS)
    out_dir = choose_out_dir(args, "compare-", is_finished)
    args.out_dir = out_dir  # for the resume line after Ctrl-C
    with folder_lock(out_dir):
        res = run_compare(scenario_names(args), args.trackers, seeds, args.steps,
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
    failed = failure_line(res.results, res.out_dir)
    if failed:
        print(failed, file=sys.stderr)
        return 1
    return 0


def add_parser(sub: argparse._SubParsersAction, fmt: type[argparse.HelpFormatter]) -> None:
    """The ``compare`` sub-command and its options."""
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
    add_sweep_options(p, seeds_default=COMPARE_SEEDS, trackers_required=False)
    add_workers_option(p)
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
