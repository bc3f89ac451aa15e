"""The mutation sample stays applicable: every mutant's text occurs exactly once in its
file and every listed test exists, so ``make mutants`` cannot rot silently. (Running the
mutants themselves takes minutes: ``make mutants``.)"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest
from run_mutants import DEFAULT_SAMPLE, REPO, SampleError, check_applicable, load_sample

#: every mutant the sample must hold, by its name in the sample
NAMED_IN_ISSUE = {"reflect-no-velocity-flip", "births-doubled", "look-ranks-reversed",
                  "survival-squared", "ip-alignment-cost-negated", "ip-alignment-cells-stale",
                  "jmpd-fold-no-velocity-flip", "quadrature-12-nodes", "pc-bernoullis-merged",
                  "gpf-birth-not-clustered"}


def _test_functions(path: Path) -> set[str]:
    tree = ast.parse(path.read_text(encoding="utf-8"))
    return {n.name for n in ast.walk(tree) if isinstance(n, ast.FunctionDef)}


def test_sample_applies_to_the_checkout_and_names_existing_tests():
    mutants = load_sample(DEFAULT_SAMPLE)
    check_applicable(mutants, REPO)  # raises with the list of stale rows
    issue = [m for m in mutants if m.sample == "issue"]
    assert len(issue) >= 21
    assert NAMED_IN_ISSUE <= {m.name for m in issue}
    assert len([m for m in mutants if m.sample == "simulator"]) >= 5
    for m in mutants:
        assert m.description and not m.known_miss, m.name
        for node in m.tests:
            file, _, name = node.partition("::")
            if name:
                assert name.split("[")[0] in _test_functions(REPO / file), (m.name, node)


def test_a_stale_mutant_is_refused(tmp_path):
    mutants = load_sample(DEFAULT_SAMPLE)
    bad = mutants[0].__class__(**{**mutants[0].__dict__, "original": "no such line"})
    with pytest.raises(SampleError, match="occurs 0 times"):
        check_applicable([bad], REPO)
    broken = tmp_path / "mutants.toml"
    broken.write_text('[[mutant]]\nname = "x"\nfile = "scenarios/simulator.py"\n')
    with pytest.raises(SampleError, match="missing keys"):
        load_sample(broken)
