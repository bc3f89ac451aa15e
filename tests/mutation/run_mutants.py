"""Run the mutation sample: does the test suite catch one-line changes to the code?

Usage (``make mutants`` runs the first line)::

    .venv/bin/python tests/mutation/run_mutants.py
    .venv/bin/python tests/mutation/run_mutants.py --only reflect-no-velocity-flip births-doubled
    .venv/bin/python tests/mutation/run_mutants.py --list

What it does, without touching the checkout:

1. copies the checkout's sources to a temporary folder and installs them there,
   non-editably, with ``pip install --no-deps --no-compile --target <tmp>/site`` (the same
   plain install ``tests/test_packaging.py`` builds);
2. checks that every mutant's ``original`` text occurs exactly once in its file, both in
   the checkout and in the installed copy (a stale sample is refused, not run);
3. runs the union of the listed tests against the unmutated copy and refuses to report
   anything unless every one of them passes;
4. for each mutant: replaces ``original`` by ``replacement`` in the installed file
   (``trackers/x.py`` is ``<site>/mttbench/trackers/x.py``, and so on), runs
   ``pytest -x -q -p no:cacheprovider <the mutant's tests>`` from an empty folder with
   ``PYTHONPATH=<site>`` (the checkout's tests, the installed code), restores the file;
5. prints one row per mutant (caught / missed / timeout, with the first failing test) and
   ``caught k of n`` per sample and overall.

A mutant is *caught* when its tests fail (or run past ``--timeout``). Exit status: 0 when
every mutant is caught (or missed and marked ``known_miss`` in the sample, with the
reason), 1 when a mutant is missed unexpectedly, 2 when the sample or the baseline is
broken. Bytecode is neither read nor written (``PYTHONDONTWRITEBYTECODE``, install with
``--no-compile``), so a mutant written in the same second as its original is never
shadowed by a stale ``.pyc``; numba's on-disk cache lives in the temporary folder.
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
import time
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
HERE = Path(__file__).resolve().parent
DEFAULT_SAMPLE = HERE / "mutants.toml"
#: checkout folder -> installed package folder (pyproject.toml's package-dir)
LAYOUT = {"trackers": "mttbench/trackers", "scenarios": "mttbench/scenarios",
          "benchmarks": "mttbench/benchmarks", "mttbench": "mttbench"}
#: top-level entries a build does not need (as in tests/test_packaging.py)
NOT_COPIED = {".git", ".venv", "build", "dist", "tests", "docs", ".cache", ".hypothesis",
              ".pytest_cache", ".ruff_cache", ".benchmarks"}


@dataclass(frozen=True)
class Mutant:
    """One line of the sample (see mutants.toml for the fields)."""

    name: str
    file: str
    original: str
    replacement: str
    description: str
    tests: tuple[str, ...]
    sample: str
    known_miss: str = ""

    def installed_path(self, site: Path) -> Path:
        top, _, rest = self.file.partition("/")
        if top not in LAYOUT or not rest:
            raise SampleError(f"{self.name}: file {self.file!r} is not in {sorted(LAYOUT)}")
        return site / LAYOUT[top] / rest


@dataclass
class Outcome:
    mutant: Mutant
    status: str  # caught | missed | timeout
    seconds: float
    #: the first failing test (caught), or why it counts as caught without one
    detail: str = field(default="")
    #: the end of pytest's output
    log: str = field(default="")


class SampleError(Exception):
    """The sample or the baseline is broken: nothing is reported."""


# ------------------------------------------------------------------ the sample
def load_sample(path: Path) -> list[Mutant]:
    """Mutants of ``path`` (TOML, ``[[mutant]]`` tables), checked for shape and unique names."""
    data = tomllib.loads(path.read_text(encoding="utf-8"))
    keys = {"name", "file", "original", "replacement", "description", "tests", "sample",
            "known_miss"}
    out = []
    for i, row in enumerate(data.get("mutant", [])):
        unknown = set(row) - keys
        missing = {"name", "file", "original", "replacement", "description", "tests",
                   "sample"} - set(row)
        if unknown or missing:
            raise SampleError(f"mutant #{i}: unknown keys {sorted(unknown)}, "
                              f"missing keys {sorted(missing)}")
        if not row["tests"]:
            raise SampleError(f"mutant {row['name']}: no tests listed")
        if row["original"] == row["replacement"]:
            raise SampleError(f"mutant {row['name']}: the replacement changes nothing")
        out.append(Mutant(name=row["name"], file=row["file"], original=row["original"],
                          replacement=row["replacement"], description=row["description"],
                          tests=tuple(row["tests"]), sample=row["sample"],
                          known_miss=row.get("known_miss", "")))
    names = [m.name for m in out]
    if len(set(names)) != len(names):
        raise SampleError("mutant names must be unique")
    return out


def check_applicable(mutants: list[Mutant], root: Path, installed: Path | None = None) -> None:
    """Every ``original`` occurs exactly once in its file (checkout and installed copy),
    and every listed test file exists."""
    problems = []
    for m in mutants:
        for where in filter(None, (root / m.file, installed and m.installed_path(installed))):
            if not where.is_file():
                problems.append(f"{m.name}: no file {where}")
                continue
            n = where.read_text(encoding="utf-8").count(m.original)
            if n != 1:
                problems.append(f"{m.name}: the original text occurs {n} times in {where}")
        for t in m.tests:
            if not (root / t.split("::")[0]).is_file():
                problems.append(f"{m.name}: no test file {t.split('::')[0]}")
    if problems:
        raise SampleError("the sample does not apply to this checkout:\n  "
                          + "\n  ".join(problems))


# ------------------------------------------------------------- install and run
def _ignore(folder: str, names: list[str]) -> set[str]:
    here = Path(folder)
    skip = {n for n in names if n == "__pycache__" or n.endswith(".egg-info")}
    if here == REPO:
        skip |= NOT_COPIED & set(names)
    elif here == REPO / "reports":
        skip |= {n for n in names if n not in ("reference", "README.md")}
    return skip


def install_copy(work: Path) -> Path:
    """Copy the checkout to ``work/src`` and install it into ``work/site``; returns the site."""
    src, site = work / "src", work / "site"
    shutil.copytree(REPO, src, ignore=_ignore)
    proc = subprocess.run(
        [sys.executable, "-m", "pip", "install", "--no-deps", "--no-input", "--no-compile",
         "--disable-pip-version-check", "--quiet", "--target", str(site), str(src)],
        cwd=work, capture_output=True, text=True, check=False)
    if proc.returncode:
        raise SampleError(f"pip install of the copy failed:\n{proc.stdout}\n{proc.stderr}")
    shutil.rmtree(src)
    for cache in site.rglob("__pycache__"):
        shutil.rmtree(cache)
    return site


def _env(site: Path, work: Path) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if not k.startswith(("PYTHON", "NUMBA"))}
    env.update(PYTHONPATH=str(site), PYTHONNOUSERSITE="1", PYTHONDONTWRITEBYTECODE="1",
               NUMBA_CACHE_DIR=str(work / "numba-cache"), PYTHONHASHSEED="0")
    return env


def check_import_location(site: Path, work: Path) -> None:
    """The tests must import the installed copy, not the editable checkout."""
    code = ("import mttbench.scenarios.simulator as s, mttbench.trackers.gpf as g; "
            "print(s.__file__); print(g.__file__)")
    proc = subprocess.run([sys.executable, "-c", code], cwd=work / "run",
                          env=_env(site, work), capture_output=True, text=True, check=False)
    files = proc.stdout.split()
    if proc.returncode or len(files) != 2 or not all(
            Path(f).resolve().is_relative_to(site.resolve()) for f in files):
        raise SampleError(f"the tests would not import the installed copy: {proc.stdout}"
                          f"{proc.stderr}")


def run_tests(tests: list[str], site: Path, work: Path, timeout: float
              ) -> tuple[int | None, str]:
    """``pytest -x`` on ``tests`` (checkout paths) against the installed copy; returns the
    exit code (None on timeout) and the tail of the output."""
    pytest = Path(sys.executable).with_name("pytest")
    args = [str(pytest), "-x", "-q", "-p", "no:cacheprovider", "--no-header",
            *[str(REPO / t) for t in tests]]
    try:
        proc = subprocess.run(args, cwd=work / "run", env=_env(site, work),
                              capture_output=True, text=True, timeout=timeout, check=False)
    except subprocess.TimeoutExpired:
        return None, f"timed out after {timeout:.0f} s"
    lines = (proc.stdout + proc.stderr).strip().splitlines()
    summary = [ln for ln in lines if ln.startswith(("FAILED ", "ERROR "))]
    return proc.returncode, "\n".join(summary + lines[-15:])


def run_mutant(m: Mutant, site: Path, work: Path, timeout: float) -> Outcome:
    target = m.installed_path(site)
    original = target.read_text(encoding="utf-8")
    t0 = time.perf_counter()
    try:
        target.write_text(original.replace(m.original, m.replacement, 1), encoding="utf-8")
        code, tail = run_tests(list(m.tests), site, work, timeout)
    finally:
        target.write_text(original, encoding="utf-8")
    seconds = time.perf_counter() - t0
    if code is None:
        return Outcome(m, "timeout", seconds, tail, tail)
    if code == 0:
        return Outcome(m, "missed", seconds, "", tail)
    failed = [ln.split()[1] for ln in tail.splitlines() if ln.startswith(("FAILED ", "ERROR "))]
    if code != 1 or not failed:  # 2: interrupted or collection error, 3: internal, 4: usage
        return Outcome(m, "caught", seconds, f"pytest exit {code}, not a test failure", tail)
    path, _, name = failed[0].partition("::")
    return Outcome(m, "caught", seconds, f"{Path(path).name}::{name}", tail)


# ---------------------------------------------------------------------- report
def report(outcomes: list[Outcome]) -> str:
    rows = [("mutant", "sample", "file", "result", "s", "first failing test")]
    for o in outcomes:
        result = o.status + (" (known)" if o.status == "missed" and o.mutant.known_miss else "")
        rows.append((o.mutant.name, o.mutant.sample, o.mutant.file, result,
                     f"{o.seconds:.1f}", o.detail if o.status == "caught" else ""))
    widths = [max(len(r[i]) for r in rows) for i in range(5)]
    lines = []
    for j, r in enumerate(rows):
        lines.append("  ".join(r[i].ljust(widths[i]) for i in range(5)) + "  " + r[5])
        if j == 0:
            lines.append("  ".join("-" * w for w in widths) + "  " + "-" * 18)
    lines.append("")
    samples = list(dict.fromkeys(o.mutant.sample for o in outcomes))
    for s in samples:
        part = [o for o in outcomes if o.mutant.sample == s]
        k = sum(o.status != "missed" for o in part)
        lines.append(f"sample {s!r}: caught {k} of {len(part)}")
    k = sum(o.status != "missed" for o in outcomes)
    lines.append(f"caught {k} of {len(outcomes)}")
    for o in outcomes:
        if o.status == "missed":
            why = f" (known: {o.mutant.known_miss})" if o.mutant.known_miss else ""
            lines.append(f"missed {o.mutant.name}{why}: {', '.join(o.mutant.tests)}")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--sample", type=Path, default=DEFAULT_SAMPLE, help="the mutants (TOML)")
    ap.add_argument("--only", nargs="+", metavar="NAME", help="run only these mutants")
    ap.add_argument("--list", action="store_true", help="list the mutants and exit")
    ap.add_argument("-v", "--verbose", action="store_true",
                    help="print the end of pytest's output for every mutant")
    ap.add_argument("--timeout", type=float, default=600.0,
                    help="seconds per mutant before it counts as caught (default 600)")
    ap.add_argument("--keep", action="store_true", help="keep the temporary folder")
    args = ap.parse_args(argv)
    try:
        mutants = load_sample(args.sample)
        if args.only:
            unknown = set(args.only) - {m.name for m in mutants}
            if unknown:
                raise SampleError(f"unknown mutants: {sorted(unknown)}")
            mutants = [m for m in mutants if m.name in args.only]
        if args.list:
            for m in mutants:
                print(f"{m.name:<36} {m.sample:<10} {m.file:<34} {m.description}")
            return 0
        check_applicable(mutants, REPO)
        work = Path(tempfile.mkdtemp(prefix="mttbench-mutants-"))
        try:
            (work / "run").mkdir()
            t0 = time.perf_counter()
            site = install_copy(work)
            check_applicable(mutants, REPO, site)
            check_import_location(site, work)
            print(f"installed a copy into {site} ({time.perf_counter() - t0:.0f} s)",
                  flush=True)
            every_test = list(dict.fromkeys(t for m in mutants for t in m.tests))
            t0 = time.perf_counter()
            code, tail = run_tests(every_test, site, work, args.timeout * 2)
            if code != 0:
                raise SampleError(f"the listed tests do not all pass on the unmutated code "
                                  f"(exit {code}); nothing to report:\n{tail}")
            print(f"baseline: the {len(every_test)} listed tests pass unmutated "
                  f"({time.perf_counter() - t0:.0f} s)", flush=True)
            outcomes = []
            for i, m in enumerate(mutants, 1):
                o = run_mutant(m, site, work, args.timeout)
                print(f"[{i}/{len(mutants)}] {m.name}: {o.status} ({o.seconds:.1f} s)",
                      flush=True)
                if args.verbose:
                    print("    " + o.log.replace("\n", "\n    "), flush=True)
                outcomes.append(o)
        finally:
            if args.keep:
                print(f"kept {work}")
            else:
                shutil.rmtree(work, ignore_errors=True)
    except SampleError as exc:
        print(f"run_mutants: {exc}", file=sys.stderr)
        return 2
    print()
    print(report(outcomes))
    unexpected = [o for o in outcomes if o.status == "missed" and not o.mutant.known_miss]
    return 1 if unexpected else 0


if __name__ == "__main__":
    sys.exit(main())
