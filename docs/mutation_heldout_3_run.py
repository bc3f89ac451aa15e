"""Run the third held-out sample (docs/mutation_heldout_3.toml) in a checkout: apply each
mutant to its file in place, run its listed test files (``pytest -x -q -p no:cacheprovider``,
one process, ``nice -n 5``), restore the file with ``git checkout --``. One JSON line per
mutant on stdout and appended to ``$HELDOUT3_RESULTS`` (default
/tmp/heldout3_results.jsonl). In place rather than in an installed copy (as
tests/mutation/run_mutants.py does) so the compiled kernels' warm disk cache is used: on a
loaded 2-core machine the copy's cold compile and its baseline took more than 10 minutes.
Run it only in a checkout with no uncommitted change to the mutated files.

Usage: .venv/bin/python docs/mutation_heldout_3_run.py [NAME ...]"""
import json
import os
import subprocess
import sys
import time
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SAMPLE = ROOT / "docs" / "mutation_heldout_3.toml"
OUT = Path(os.environ.get("HELDOUT3_RESULTS", "/tmp/heldout3_results.jsonl"))
TIMEOUT = 600

mutants = tomllib.loads(SAMPLE.read_text())["mutant"]
only = set(sys.argv[1:])
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
            p = subprocess.run(["nice", "-n", "5", str(ROOT / ".venv/bin/python"), "-m", "pytest",
                                "-x", "-q", "-p", "no:cacheprovider", *m["tests"]],
                               cwd=ROOT, env=env, capture_output=True, text=True,
                               timeout=TIMEOUT)
            code, out = p.returncode, p.stdout + p.stderr
        except subprocess.TimeoutExpired:
            code, out = None, "timeout"
    finally:
        subprocess.run(["git", "checkout", "--", m["file"]], cwd=ROOT, check=True)
    failed = [ln.split()[1] for ln in out.splitlines() if ln.startswith(("FAILED ", "ERROR "))]
    status = ("timeout" if code is None else "missed" if code == 0 else "caught")
    row = {"name": m["name"], "status": status, "code": code, "s": round(time.time() - t0, 1),
           "first": failed[0] if failed else "", "tail": out.strip().splitlines()[-3:]}
    print(json.dumps(row), flush=True)
    with OUT.open("a") as f:
        f.write(json.dumps(row) + "\n")
