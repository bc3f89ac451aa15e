"""compare's default reference when neither pmb nor kfnn runs: the first tracker, in the
order given, that does not use the truth (the documented rule, applied by hand to lists
where that tracker is neither first nor last)."""

from __future__ import annotations

import pytest

from mttbench.benchmarks.app import compare
from mttbench.benchmarks.engine.specs import TrackerSpec


@pytest.mark.parametrize("names, want", [
    (["truth-aided", "null", "gpf", "jmpd"], "null"),
    (["gpf", "truth-aided", "null"], "gpf"),
    (["truth-aided", "jmpd", "ss-gnn", "null"], "jmpd"),
])
def test_without_a_listed_reference_the_first_fair_tracker_is_the_reference(names, want):
    specs = [TrackerSpec(n) for n in names]
    assert not {"pmb", "kfnn"} & set(names)
    assert compare.default_reference(specs) == want
    # and it is a label of the list, kept when the list is reversed (the first again)
    fair = [n for n in reversed(names) if n != "truth-aided"]
    assert compare.default_reference(list(reversed(specs))) == fair[0]
