"""Run the third held-out sample (docs/mutation_heldout_3.toml) in a checkout: apply each
mutant to its file in place, run its listed test files (``pytest -x -q -p no:cacheprovider``,
one process, ``nice -n 5``), restore the file with ``git checkout --``. One JSON line per
mutant on stdout and appended to ``$HELDOUT3_RESULTS`` (default
/tmp/heldout3_results.jsonl). In place rather than in an installed copy (as
tests/mutation/run_mutants.py does) so the compiled kernels' warm disk cache is used: on a
loaded 2-core machine the copy's cold compile and its baseline took more than 10 minutes.
Run it only in a checkout with no uncommitted change to the mutated files.

The loop is the fourth runner's (`mutation_heldout_4_run.run`).

Usage: .venv/bin/python docs/mutation_heldout_3_run.py [NAME ...]"""
import os
import sys
import tomllib
from pathlib import Path

from mutation_heldout_4_run import ROOT, run

SAMPLE = ROOT / "docs" / "mutation_heldout_3.toml"
OUT = Path(os.environ.get("HELDOUT3_RESULTS", "/tmp/heldout3_results.jsonl"))

if __name__ == "__main__":
    run(tomllib.loads(SAMPLE.read_text())["mutant"], set(sys.argv[1:]), OUT)
