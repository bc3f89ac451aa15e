"""``mttbench reproduce``: the paper's, Kreucher's and the CDC 2004 figures, checked
(:mod:`~mttbench.benchmarks.app.reproduce` and its targets)."""

from __future__ import annotations

import argparse
import json
import os
import sys
import textwrap
from pathlib import Path
from typing import Any

from ..engine.specs import resolve_trackers, split_specs
from ..engine.store import prepare_out_dir
from . import resources
from .cli_common import add_run_timeout, add_workers_option, check_run_timeout, failure_line
from .executor_options import add_executor_arguments
from .usage import UsageError


def cmd_reproduce(args: argparse.Namespace) -> int:
    """Reviewer reproduction (:mod:`~mttbench.benchmarks.app.reproduce`: the paper's figures;
    :mod:`~mttbench.benchmarks.app.reproduce_kreucher`: Kreucher's managed-versus-periodic
    curve): exit 0; 1 when ``--check`` finds moved numbers or a run failed; 2 for bad
    input."""
    from . import reproduce

    if args.workers is not None and args.workers < 1:
        raise UsageError(f"--workers {args.workers} is not allowed: expected an integer >= 1")
    check_run_timeout(args)
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
    failed = failure_line(res.results, out)
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
    failed = failure_line(rep.results, out)
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


def add_parser(sub: argparse._SubParsersAction, fmt: type[argparse.HelpFormatter]) -> None:
    """The ``reproduce`` sub-command and its options."""
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
                    "(the same package versions; mttbench turns numpy's AVX-512 code off, so "
                    "x86 machines with AVX2 and with AVX-512 agree). Either exits 1 naming "
                    "every number that moved.",
        epilog=textwrap.dedent("""\
            examples:
              mttbench reproduce paper                    # full setting
              mttbench reproduce paper --reduced --check  # what CI runs
              mttbench reproduce paper --reduced --check --exact  # same versions, bit for bit
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
                   help="with --check: bit-for-bit mode for the same package versions "
                        "(every number within rtol 1e-9, intervals and snapshot included)")
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
    add_workers_option(p)
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    add_run_timeout(p, "gets an error row (the reproduction exits 1)")
    add_executor_arguments(p)
    p.set_defaults(func=cmd_reproduce)
