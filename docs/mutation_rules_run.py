"""Apply a list of one-line slips (a TOML of ``[[mutant]]`` tables) one at a time to the
checkout, run each slip's listed tests, restore the file, and print caught / missed.

Each ``[[mutant]]`` has ``name``, ``file`` (a path inside the checkout), ``original`` (text
that must occur exactly once in the file), ``replacement`` and ``tests`` (a list of pytest
arguments: files or node ids); any other key (``why``, ``note``, ``equivalent``) is kept
for the reader and ignored here, except ``equivalent = "reason"``, which is only reported.

For each selected slip the runner writes the file with ``original`` replaced, runs
``nice -n 5 PYTHON -m pytest -x -q -p no:cacheprovider TESTS`` from the checkout's root
under a timeout, then restores the file with ``git checkout -- FILE`` (so a slip's file
must have no uncommitted change: the runner refuses it otherwise). A slip is *caught* when
pytest exits non-zero (a failure or an error: a slip that breaks the import counts, as it
would in any run of the suite), *missed* when it exits 0, *timeout* past the limit.

The checkout is the git top level of the current directory (``--root`` to name another),
never the folder this script lives in, so another worktree can run it on its own files.
PYTHON is the checkout's ``.venv/bin/python`` when it exists, else this interpreter.

Usage (from the checkout's root)::

    .venv/bin/python docs/mutation_rules_run.py SAMPLE.toml [NAME ...]
        [--check] [--timeout S] [--results FILE.jsonl] [--root DIR]
        [--fork PREFIX [--preload MODULES]] [--tests ARG ...]

    NAME ...        run only these slips, in this order (default: all; a name ending in
                    ``*`` is a prefix)
    --check         only check the sample (each original once in its file, unique names,
                    replacement differs, the listed test files exist); run nothing
    --tests ...     run these pytest arguments instead of each slip's own (all the rest of
                    the command line), e.g. the new tests for the misses
    --timeout S     seconds per slip (default 600)
    --results F     also append one JSON line per slip to F
    --fork PREFIX   fast mode: this process imports pytest and the heavy libraries
                    (numpy, pandas, scipy, matplotlib, optuna, and --preload) once, then
                    runs each slip's pytest in a forked child that first forgets every
                    module named PREFIX or below it (comma-separated prefixes, e.g.
                    ``mttbench.benchmarks.app``), so the child imports the mutated file
                    afresh; only for slips in files under PREFIX
    --preload MODS  with --fork: more modules to import once (comma-separated), none of
                    them importing a module under PREFIX
    --table B A     run nothing: print a Markdown table per file of the sample from two
                    results files (B: the slips against their listed tests, A: against
                    the new tests), the last row of each slip in each file counting

Prints one line per slip (``caught``/``missed``/``timeout``, seconds, the first failing
test), then a summary: ``caught N of M`` and the names missed. Exit status 0 always after a
run (a missed slip is a finding, not an error); 1 when ``--check`` finds a problem.

Each slip's cached bytecode (``__pycache__/<stem>.*.pyc``) is deleted before and after
it runs: a mutant of the same size written within the second of the original's
checkout would otherwise be served from the original's bytecode.

Other modules can ``import`` it (``importlib`` from its path) and call ``load``,
``check`` and ``run``."""
from __future__ import annotations

import argparse
import contextlib
import json
import os
import subprocess
import sys
import time
import tomllib
from pathlib import Path


def git_root(start: Path) -> Path:
    """The git top level of ``start`` (a worktree's own root)."""
    out = subprocess.run(["git", "rev-parse", "--show-toplevel"], cwd=start,
                         capture_output=True, text=True, check=True)
    return Path(out.stdout.strip())


def load(sample: Path) -> list[dict]:
    """The ``[[mutant]]`` tables of a sample TOML."""
    return tomllib.loads(Path(sample).read_text())["mutant"]


def select(mutants: list[dict], names: list[str]) -> list[dict]:
    """The slips named (``x*`` a prefix), in the order named (a prefix's matches in the
    sample's order); all, in the sample's order, when none named. An unknown name is an
    error (a typo would otherwise run nothing silently)."""
    if not names:
        return list(mutants)
    chosen: list[dict] = []
    for n in names:
        hit = [m for m in mutants
               if (m["name"].startswith(n[:-1]) if n.endswith("*") else m["name"] == n)]
        if not hit:
            raise SystemExit(f"no slip named {n!r} in the sample")
        chosen += [m for m in hit if m not in chosen]
    return chosen


def check(mutants: list[dict], root: Path) -> list[str]:
    """The sample's problems (empty list: none)."""
    problems = []
    names = [m.get("name", "?") for m in mutants]
    for n in sorted({n for n in names if names.count(n) > 1}):
        problems.append(f"{n}: name repeated")
    for m in mutants:
        missing = [k for k in ("name", "file", "original", "replacement", "tests")
                   if k not in m]
        if missing:
            problems.append(f"{m.get('name', '?')}: missing {', '.join(missing)}")
            continue
        path = root / m["file"]
        if not path.is_file():
            problems.append(f"{m['name']}: no file {m['file']}")
            continue
        n = path.read_text().count(m["original"])
        if n != 1:
            problems.append(f"{m['name']}: original occurs {n} times in {m['file']}")
        if m["original"] == m["replacement"]:
            problems.append(f"{m['name']}: replacement equals original")
        for t in m["tests"]:
            f = t.split("::", 1)[0]
            if not f.startswith("-") and not (root / f).exists():
                problems.append(f"{m['name']}: no test file {f}")
    return problems


def _clean(root: Path, file: str) -> bool:
    return subprocess.run(["git", "diff", "--quiet", "HEAD", "--", file],
                          cwd=root).returncode == 0


def _drop_pyc(path: Path) -> None:
    for pyc in (path.parent / "__pycache__").glob(f"{path.stem}.*.pyc"):
        pyc.unlink(missing_ok=True)


def _pytest_args(args: list[str]) -> list[str]:
    return ["-x", "-q", "-p", "no:cacheprovider", *args]


def _run_subprocess(root: Path, python: str, args: list[str], timeout: float
                    ) -> tuple[int | None, str]:
    env = {**os.environ, "PYTHONDONTWRITEBYTECODE": "1"}
    try:
        p = subprocess.run(["nice", "-n", "5", python, "-m", "pytest", *_pytest_args(args)],
                           cwd=root, env=env, capture_output=True, text=True,
                           timeout=timeout)
        return p.returncode, p.stdout + p.stderr
    except subprocess.TimeoutExpired:
        return None, "timeout"


#: module-name prefixes the forked child forgets (``--fork``); None: subprocess mode
FORK_PREFIXES: list[str] | None = None


def preload(extra: list[str]) -> None:
    """``--fork``: import pytest, the heavy libraries and ``extra`` in this process."""
    import importlib

    os.environ.setdefault("MPLBACKEND", "Agg")
    sys.dont_write_bytecode = True
    os.environ["PYTHONDONTWRITEBYTECODE"] = "1"
    for name in ["pytest", "numpy", "pandas", "scipy.stats", "matplotlib",
                 "matplotlib.figure", "pyarrow.parquet", "optuna", *extra]:
        try:
            importlib.import_module(name)
        except ImportError:
            pass


def _forget(prefixes: list[str]) -> None:
    """Remove every module named by a prefix or below it, and its parent's attribute."""
    for name in [n for n in sys.modules
                 if any(n == p or n.startswith(p + ".") for p in prefixes)]:
        del sys.modules[name]
        parent, _, child = name.rpartition(".")
        if parent in sys.modules and hasattr(sys.modules[parent], child):
            with contextlib.suppress(AttributeError):
                delattr(sys.modules[parent], child)


def _run_forked(root: Path, args: list[str], timeout: float) -> tuple[int | None, str]:
    """pytest in a forked child (its own process group, output to a temporary file)."""
    import signal
    import tempfile

    with tempfile.TemporaryFile(mode="w+") as out:
        sys.stdout.flush()
        sys.stderr.flush()
        pid = os.fork()
        if pid == 0:  # the child: never returns
            code = 3
            try:
                os.setsid()
                os.nice(5)
                os.dup2(out.fileno(), 1)
                os.dup2(out.fileno(), 2)
                os.chdir(root)
                _forget(FORK_PREFIXES or [])
                import pytest
                code = int(pytest.main(_pytest_args(args)))
            except BaseException:  # noqa: BLE001 - reported through the exit status
                import traceback
                traceback.print_exc()
            finally:
                sys.stdout.flush()
                sys.stderr.flush()
                os._exit(code)
        t0 = time.time()
        while True:
            done, status = os.waitpid(pid, os.WNOHANG)
            if done:
                code = os.waitstatus_to_exitcode(status)
                break
            if time.time() - t0 > timeout:
                with contextlib.suppress(ProcessLookupError):
                    os.killpg(pid, signal.SIGKILL)
                os.waitpid(pid, 0)
                code = None
                break
            time.sleep(0.05)
        out.seek(0)
        text = out.read()
    return code, "timeout" if code is None else text


def run_one(m: dict, root: Path, python: str, timeout: float,
            tests: list[str] | None = None) -> dict:
    """Apply slip ``m``, run its tests (or ``tests``), restore the file; its result row."""
    path = root / m["file"]
    if not _clean(root, m["file"]):
        raise SystemExit(f"{m['file']} has uncommitted changes: commit or stash them first "
                         "(the runner restores it with git checkout)")
    text = path.read_text()
    if text.count(m["original"]) != 1:
        return {"name": m["name"], "status": "bad", "s": 0.0, "first": "",
                "tail": [f"original occurs {text.count(m['original'])} times"]}
    args = tests if tests is not None else list(m["tests"])
    t0 = time.time()
    try:
        path.write_text(text.replace(m["original"], m["replacement"], 1))
        _drop_pyc(path)
        if FORK_PREFIXES is not None:
            code, out = _run_forked(root, args, timeout)
        else:
            code, out = _run_subprocess(root, python, args, timeout)
    finally:
        subprocess.run(["git", "checkout", "--", m["file"]], cwd=root, check=True)
        _drop_pyc(path)
    failed = [ln.split()[1] for ln in out.splitlines()
              if ln.startswith(("FAILED ", "ERROR ")) and len(ln.split()) > 1]
    status = "timeout" if code is None else "missed" if code == 0 else "caught"
    if code == 5:       # pytest: no tests collected; not a catch
        status = "no-tests"
    return {"name": m["name"], "file": m["file"], "status": status, "code": code,
            "s": round(time.time() - t0, 1), "first": failed[0] if failed else "",
            "equivalent": m.get("equivalent", ""),
            "tail": out.strip().splitlines()[-3:]}


def run(mutants: list[dict], root: Path, python: str, timeout: float = 600,
        tests: list[str] | None = None, results: Path | None = None) -> list[dict]:
    """Run each slip in turn; print a line each and return the rows."""
    rows = []
    for m in mutants:
        row = run_one(m, root, python, timeout, tests)
        rows.append(row)
        eq = "  (marked equivalent)" if row["equivalent"] else ""
        print(f"{row['status']:8} {row['s']:6.1f}s  {row['name']}  {row['first']}{eq}",
              flush=True)
        if row["status"] in ("no-tests", "bad"):
            print("         " + " | ".join(row["tail"]), flush=True)
        if results is not None:
            with Path(results).open("a") as f:
                f.write(json.dumps(row) + "\n")
    return rows


def summary(rows: list[dict]) -> str:
    caught = [r for r in rows if r["status"] == "caught"]
    missed = [r for r in rows if r["status"] == "missed"]
    other = [r for r in rows if r["status"] not in ("caught", "missed")]
    lines = [f"caught {len(caught)} of {len(rows)}; missed {len(missed)}"
             + (f"; other {len(other)}" if other else "")]
    if missed:
        lines.append("missed: " + " ".join(r["name"] for r in missed))
    if other:
        lines.append("other: " + " ".join(f"{r['name']}({r['status']})" for r in other))
    return "\n".join(lines)


def _last_rows(path: Path) -> dict[str, dict]:
    rows: dict[str, dict] = {}
    if Path(path).is_file():
        for line in Path(path).read_text().splitlines():
            if line.strip():
                r = json.loads(line)
                rows[r["name"]] = r
    return rows


def table(mutants: list[dict], before: Path, after: Path) -> str:
    """Markdown: per file the counts (equivalent slips apart: neither before nor after
    counts them), then per file each slip's result before and after."""
    b, a = _last_rows(before), _last_rows(after)
    out, totals = [], []
    files = list(dict.fromkeys(m["file"] for m in mutants))
    for f in files:
        ms = [m for m in mutants if m["file"] == f]
        out += ["", f"#### `{f}`", "", "| slip | before (listed tests) | after (new tests) |",
                "|---|---|---|"]
        for m in ms:
            rb = b.get(m["name"], {}).get("status", "not run")
            ra = a.get(m["name"], {}).get("status", "not run")
            eq = " (equivalent)" if m.get("equivalent") else ""
            out.append(f"| {m['name']}{eq} | {rb} | {ra} |")
        real = [m for m in ms if not m.get("equivalent")]
        run_b = [m for m in real if m["name"] in b]
        totals.append((f, len(ms), sum(b[m["name"]]["status"] == "caught" for m in run_b),
                       len(run_b), sum(a.get(m["name"], {}).get("status") == "caught"
                                       for m in real), len(ms) - len(real)))
    head = ["| file | slips | caught before (of those run) | caught after | equivalent |",
            "|---|---:|---:|---:|---:|"]
    head += [f"| `{f}` | {n} | {cb} of {rb} | {ca} | {eq} |" for f, n, cb, rb, ca, eq in totals]
    n = sum(x[1] for x in totals)
    head.append(f"| all | {n} | {sum(x[2] for x in totals)} of {sum(x[3] for x in totals)} | "
                f"{sum(x[4] for x in totals)} | {sum(x[5] for x in totals)} |")
    return "\n".join(head + out)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("sample", type=Path)
    ap.add_argument("names", nargs="*")
    ap.add_argument("--check", action="store_true")
    ap.add_argument("--timeout", type=float, default=600)
    ap.add_argument("--results", type=Path)
    ap.add_argument("--root", type=Path)
    ap.add_argument("--fork", metavar="PREFIX")
    ap.add_argument("--preload", default="")
    ap.add_argument("--table", nargs=2, type=Path, metavar=("BEFORE", "AFTER"))
    ap.add_argument("--tests", nargs=argparse.REMAINDER)
    a = ap.parse_args(argv)
    root = git_root(a.root or Path.cwd())
    sample = a.sample if a.sample.is_absolute() else Path.cwd() / a.sample
    mutants = load(sample)
    if a.table:
        print(table(mutants, *a.table))
        return 0
    if a.check:
        problems = check(mutants, root)
        print("\n".join(problems) or f"{len(mutants)} slips: no problem")
        return 1 if problems else 0
    chosen = select(mutants, a.names)
    if a.fork:
        global FORK_PREFIXES
        FORK_PREFIXES = [p for p in a.fork.split(",") if p]
        os.chdir(root)
        sys.path.insert(0, str(root / "tests"))
        preload([m for m in a.preload.split(",") if m])
    venv = root / ".venv" / "bin" / "python"
    python = str(venv) if venv.exists() else sys.executable
    rows = run(chosen, root, python, a.timeout, a.tests, a.results)
    print(summary(rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
