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

Each command is a module of its own, ``cli_<command>.py``, holding its ``cmd_*`` function and
its options (``add_parser``); what they share is in :mod:`.cli_common`. This module assembles
the parser and runs a command (:func:`main`), turning every error into its exit status.
"""

from __future__ import annotations

import argparse
import os
import shlex
import sys
from collections.abc import Sequence
from pathlib import Path

from ..engine.errors import ConfigError
from . import (
    cli_bayes,
    cli_compare,
    cli_export,
    cli_frontier,
    cli_list,
    cli_reproduce,
    cli_run,
    cli_score,
    cli_screenshot,
    cli_tune,
)
from .cli_common import check_inputs
from .executor_options import executor_scope

#: exit status after Ctrl-C (128 + SIGINT, as a shell reports it)
EXIT_INTERRUPTED = 130
#: the command modules, in the order ``mttbench --help`` lists their commands
COMMANDS = (cli_list, cli_run, cli_compare, cli_frontier, cli_tune, cli_reproduce, cli_export,
            cli_score, cli_bayes, cli_screenshot)


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
    for command in COMMANDS:
        command.add_parser(sub, fmt)
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
        check_inputs(args)
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
