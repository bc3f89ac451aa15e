"""``problem_limited``: a scenario is limited by the problem when the Bayes reference
closes less than half of the floor-to-ceiling gap, ``(F - B) / (F - C) < 0.5``, the share
computed here by hand from per-seed means chosen exactly."""

from __future__ import annotations

import pytest
from test_gap_closed import frame

from mttbench.benchmarks.app import summary


@pytest.mark.parametrize("bayes_ospa", [1.7, 1.5, 1.1, 0.8])
def test_problem_limited_iff_bayes_closes_under_half_the_gap(bayes_ospa):
    floor, ceiling = [2.0, 2.0, 2.0, 2.0], [0.5, 0.55, 0.45, 0.5]
    bayes = [bayes_ospa + e for e in (0.01, -0.01, 0.02, -0.02)]
    gc = summary.gap_closed(frame({("s", "null"): floor, ("s", "truth-aided"): ceiling,
                                   ("s", "bayes"): bayes, ("s", "kfnn"): [1.2] * 4}))
    row = gc.gaps.iloc[0]
    share = (sum(floor) - sum(bayes)) / (sum(floor) - sum(ceiling))
    assert row["bayes_share_mean"] == pytest.approx(share, abs=1e-12)
    assert bool(row["problem_limited"]) == (share < summary.PROBLEM_LIMITED_SHARE)
