"""``mttbench tune``: the tuning study (:mod:`~mttbench.benchmarks.app.tune`)."""

from __future__ import annotations

import argparse
import os
import sys
import textwrap

from ..engine.specs import resolve_policies, resolve_scenarios, resolve_trackers
from . import resources
from .cli_common import (
    MAX_INT64,
    MAX_SAMPLER_SEED,
    MAX_SEEDS,
    MAX_TRIALS,
    add_metric_options,
    add_run_timeout,
    add_steps_option,
    add_workers_option,
    check_common,
    choose_out_dir,
    folder_lock,
    int_list,
)
from .executor_options import add_executor_arguments
from .usage import UsageError


def cmd_tune(args: argparse.Namespace) -> int:
    """Tune trackers' parameters under one budget (:mod:`benchmarks.app.tune`): exit 0; 1 when
    a tracker has no finished trial; 2 for bad input."""
    from . import tune

    check_common(args)
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
    looks = int_list(args.looks, "--looks value", 0)
    if looks and len(looks) > 1:
        raise UsageError("--looks: give one look budget to tune under")
    workers = args.workers or os.cpu_count() or 1
    out_dir = choose_out_dir(args, "tune-", tune.is_finished)
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
    with folder_lock(out_dir):
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


def add_parser(sub: argparse._SubParsersAction, fmt: type[argparse.HelpFormatter]) -> None:
    """The ``tune`` sub-command and its options."""
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
    add_steps_option(p)
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
    add_workers_option(p)
    p.add_argument("--tuned-dir", metavar="DIR",
                   help="where tuned/<tracker>.toml goes (default: the checkout's tuned/; "
                        "from an installed package ./tuned)")
    p.add_argument("--out", metavar="DIR",
                   help="study folder (default reports/tune-<UTC timestamp>)")
    p.add_argument("--resume", action="store_true",
                   help="continue the studies in DIR (runs already saved are read back); "
                        "without --out: the most recent unfinished reports/tune-* folder")
    add_metric_options(p)
    p.add_argument("--no-progress", action="store_true", help="no progress lines")
    add_run_timeout(p, "fails its trial")
    add_executor_arguments(p)
    p.set_defaults(func=cmd_tune)
