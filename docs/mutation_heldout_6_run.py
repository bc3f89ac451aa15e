"""Run the sixth held-out sample (docs/mutation_heldout_6.toml, drawn at random by
docs/mutation_heldout_6_draw.py) in a checkout with the fourth's runner
(docs/mutation_heldout_4_run.py): each mutant applied to its file in place, its listed
test files run (``pytest -x -q -p no:cacheprovider``), the file restored with ``git
checkout --``. One JSON line per mutant on stdout and appended to ``$HELDOUT6_RESULTS``
(default /tmp/heldout6_results.jsonl). Run it only in a checkout with no uncommitted
change to the mutated files.

``--check``: only check the sample against the five earlier samples and
tests/mutation/mutants.toml (each ``original`` once in its file, no shared line, unique
names), run nothing. ``--tests FILE ...`` after the names: run those test files instead
of the listed ones (a mutant the listed files miss, against the whole ``tests/`` or the
new tests).

Usage: .venv/bin/python docs/mutation_heldout_6_run.py [--check] [NAME ...] [--tests FILE ...]"""
import importlib.util
import os
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
_spec = importlib.util.spec_from_file_location("heldout4_run",
                                               ROOT / "docs" / "mutation_heldout_4_run.py")
runner = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(runner)
runner.EARLIER = [*runner.EARLIER, "docs/mutation_heldout_4.toml",
                  "docs/mutation_heldout_5.toml"]
SAMPLE = ROOT / "docs" / "mutation_heldout_6.toml"
OUT = Path(os.environ.get("HELDOUT6_RESULTS", "/tmp/heldout6_results.jsonl"))

if __name__ == "__main__":
    runner.main(SAMPLE, OUT, sys.argv[1:])
