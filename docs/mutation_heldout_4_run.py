"""Run the fourth held-out sample (docs/mutation_heldout_4.toml) in a checkout, as the
third's runner does (docs/mutation_heldout_3_run.py): apply each mutant to its file in
place, run its listed test files (``pytest -x -q -p no:cacheprovider``, one process,
``nice -n 5``), restore the file with ``git checkout --``. One JSON line per mutant on
stdout and appended to ``$HELDOUT4_RESULTS`` (default /tmp/heldout4_results.jsonl).
Run it only in a checkout with no uncommitted change to the mutated files.

``--check``: only check the sample (each ``original`` once in its file, no line shared
with an earlier sample's ``original`` in the same file, unique names), run nothing.

Usage: .venv/bin/python docs/mutation_heldout_4_run.py [--check] [NAME ...]"""
import json
import os
import subprocess
import sys
import time
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SAMPLE = ROOT / "docs" / "mutation_heldout_4.toml"
EARLIER = ["tests/mutation/mutants.toml", "docs/mutation_heldout.toml",
           "docs/mutation_heldout_2.toml", "docs/mutation_heldout_3.toml"]
OUT = Path(os.environ.get("HELDOUT4_RESULTS", "/tmp/heldout4_results.jsonl"))
TIMEOUT = 600


def _lines(text: str) -> set[str]:
    return {ln.strip() for ln in text.splitlines() if ln.strip()}


def check(mutants: list[dict]) -> list[str]:
    """The sample's problems (empty: none)."""
    earlier = [m for f in EARLIER for m in tomllib.loads((ROOT / f).read_text())["mutant"]]
    problems = []
    if len({m["name"] for m in mutants}) != len(mutants):
        problems.append("repeated names")
    for m in mutants:
        n = (ROOT / m["file"]).read_text().count(m["original"])
        if n != 1:
            problems.append(f"{m['name']}: original occurs {n} times in {m['file']}")
        if m["original"] == m["replacement"]:
            problems.append(f"{m['name']}: replacement equals original")
        shared = [e["name"] for e in earlier if e["file"] == m["file"]
                  and _lines(e["original"]) & _lines(m["original"])]
        if shared:
            problems.append(f"{m['name']}: a line of {shared[0]}")
    return problems


def run(mutants: list[dict], only: set[str], out_file: Path = OUT) -> None:
    """Apply, test and restore each mutant of ``mutants`` (those named in ``only``, or
    all); one JSON line each on stdout and appended to ``out_file``."""
    env = {**os.environ, "PYTHONDONTWRITEBYTECODE": "1"}
    for m in mutants:
        if only and m["name"] not in only:
            continue
        path = ROOT / m["file"]
        text = path.read_text()
        assert text.count(m["original"]) == 1, m["name"]
        t0 = time.time()
        try:
            path.write_text(text.replace(m["original"], m["replacement"], 1))
            try:
                p = subprocess.run(["nice", "-n", "5", str(ROOT / ".venv/bin/python"), "-m",
                                    "pytest", "-x", "-q", "-p", "no:cacheprovider",
                                    *m["tests"]],
                                   cwd=ROOT, env=env, capture_output=True, text=True,
                                   timeout=TIMEOUT)
                code, out = p.returncode, p.stdout + p.stderr
            except subprocess.TimeoutExpired:
                code, out = None, "timeout"
        finally:
            subprocess.run(["git", "checkout", "--", m["file"]], cwd=ROOT, check=True)
        failed = [ln.split()[1] for ln in out.splitlines()
                  if ln.startswith(("FAILED ", "ERROR "))]
        status = "timeout" if code is None else "missed" if code == 0 else "caught"
        row = {"name": m["name"], "status": status, "code": code,
               "s": round(time.time() - t0, 1), "first": failed[0] if failed else "",
               "tail": out.strip().splitlines()[-3:]}
        print(json.dumps(row), flush=True)
        with out_file.open("a") as f:
            f.write(json.dumps(row) + "\n")


def main(sample: Path, out_file: Path, args: list[str]) -> None:
    """The command line of this runner and of the later samples' (theirs pass their own
    sample and results file): ``--check``, or the NAMEs to run (all when none), with
    ``--tests FILE ...`` after them in place of each mutant's listed files."""
    mutants = tomllib.loads(sample.read_text())["mutant"]
    if args[:1] == ["--check"]:
        problems = check(mutants)
        print("\n".join(problems) or f"{len(mutants)} mutants: no problem")
        sys.exit(1 if problems else 0)
    if "--tests" in args:
        i = args.index("--tests")
        args, tests = args[:i], args[i + 1:]
        mutants = [{**m, "tests": tests} for m in mutants]
    run(mutants, set(args), out_file)


if __name__ == "__main__":
    main(SAMPLE, OUT, sys.argv[1:])
