"""``mttbench export``: open world files (:mod:`~mttbench.benchmarks.app.export`)."""

from __future__ import annotations

import argparse
import textwrap
from pathlib import Path

from ..engine.specs import resolve_policies, resolve_scenarios
from ..engine.store import prepare_out_dir
from .cli_common import (
    MAX_SEEDS,
    REPORTS,
    add_steps_option,
    folder_lock,
    int_list,
    seeds_of,
    timestamp,
)
from .folders import EXPORT_MARK
from .usage import UsageError


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
    looks = int_list(args.looks, "--looks value", 0)
    seeds = seeds_of(args, default=10)
    export.check_size(scs, looks)
    out_dir = Path(args.out) if args.out else REPORTS / f"export-{timestamp()}"
    with folder_lock(out_dir, EXPORT_MARK):
        export.check_names(scs, policy_specs, seeds, out_dir, looks)
        prepare_out_dir(out_dir, parts=False)
        index = export.export_worlds(scs, policy_specs, seeds, out_dir, looks)
    print(f"wrote {len(index)} world(s) into {out_dir}/ ({export.WORLDS_INDEX}; per world "
          f"{', '.join(export.WORLD_FILES)}, {export.CARD}); schema: docs/world_format.md")
    return 0


def add_parser(sub: argparse._SubParsersAction, fmt: type[argparse.HelpFormatter]) -> None:
    """The ``export`` sub-command and its options."""
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
    add_steps_option(p)
    p.add_argument("--out", metavar="DIR",
                   help="output folder (default reports/export-<UTC timestamp>)")
    p.set_defaults(func=cmd_export)
