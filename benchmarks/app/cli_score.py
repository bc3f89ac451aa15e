"""``mttbench score``: an outside tracker's estimates scored
(:mod:`~mttbench.benchmarks.app.score`)."""

from __future__ import annotations

import argparse
import textwrap
from pathlib import Path

from .cli_common import (
    REPORTS,
    add_metric_options,
    check_common,
    check_path,
    folder_lock,
    timestamp,
)
from .folders import SCORE_MARK, check_folder_kind
from .usage import UsageError


def cmd_score(args: argparse.Namespace) -> int:
    """Score an outside tracker's estimates (:mod:`~mttbench.benchmarks.app.score`): exit 0;
    2 for a bad world, estimates file or option, refused before anything is written."""
    from . import score

    check_common(args)
    check_path("WORLD_DIR", args.world_dir, must_exist=True)
    check_path("--beside", args.beside, must_exist=True)
    out_dir = Path(args.out) if args.out else REPORTS / f"score-{timestamp()}"
    check_folder_kind(out_dir, SCORE_MARK)
    if (out_dir / "results.parquet").exists() and not (out_dir / SCORE_MARK).exists():
        raise UsageError(f"--out {out_dir} holds the results of another command; choose "
                         "another folder")
    with folder_lock(out_dir, SCORE_MARK):
        res = score.run_score(args.world_dir, args.estimates, args.name, out_dir, c=args.c,
                              p=args.p, beside=args.beside)
    print((out_dir / "summary.md").read_text(encoding="utf-8"))
    print(f"wrote {out_dir}/: {', '.join(res.files)}")
    return 0


def add_parser(sub: argparse._SubParsersAction, fmt: type[argparse.HelpFormatter]) -> None:
    """The ``score`` sub-command and its options."""
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
    add_metric_options(p)
    p.set_defaults(func=cmd_score, steps=None, workers=None)
