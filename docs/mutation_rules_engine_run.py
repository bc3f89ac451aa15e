"""Run the engine's rule slips (docs/mutation_rules_engine.toml) in a checkout with the
fourth held-out sample's runner (docs/mutation_heldout_4_run.py): each slip applied to
its file in place, its listed tests run (``pytest -x -q -p no:cacheprovider``), the file
restored with ``git checkout --``. One JSON line per slip on stdout and appended to
``$RULES_ENGINE_RESULTS`` (default /tmp/rules_engine_results.jsonl). Run it only in a
checkout with no uncommitted change to the mutated files.

``--check``: only check the sample against the six held-out samples and
tests/mutation/mutants.toml (each ``original`` once in its file, no shared line, unique
names), run nothing. ``--tests FILE ...`` after the names: run those tests instead of
the listed ones (e.g. the new tests/test_rules_*.py files).

Usage: .venv/bin/python docs/mutation_rules_engine_run.py [--check] [NAME ...] [--tests FILE ...]"""
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
                  "docs/mutation_heldout_5.toml", "docs/mutation_heldout_6.toml"]
SAMPLE = ROOT / "docs" / "mutation_rules_engine.toml"
OUT = Path(os.environ.get("RULES_ENGINE_RESULTS", "/tmp/rules_engine_results.jsonl"))

if __name__ == "__main__":
    runner.main(SAMPLE, OUT, sys.argv[1:])
