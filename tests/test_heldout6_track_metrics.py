"""The dense layout of a run's per-step positions and ids (``track_metrics.as_dense``):
a step whose ids and positions differ in number is refused, naming the step, even when
the run's totals agree (so no later shape check could notice)."""

from __future__ import annotations

import numpy as np
import pytest

from mttbench.benchmarks.engine.track_metrics import as_dense


def test_a_step_with_more_positions_than_ids_is_refused_though_the_totals_agree():
    points = [np.array([[0.0, 0.0], [1.0, 1.0]]), np.array([[2.0, 2.0]])]
    ids = [np.array([7]), np.array([7, 8])]  # 3 positions and 3 ids in all
    with pytest.raises(ValueError, match=r"^step 0: 2 positions but 1 ids$"):
        as_dense(points, ids)
    ids = [np.array([7, 8]), np.array([9, 8])]  # each step agrees: laid out by id
    pos, present = as_dense([points[0], np.array([[2.0, 2.0], [3.0, 3.0]])], ids)
    want = np.full((2, 3, 2), np.nan)
    want[0, 0], want[0, 1], want[1, 2], want[1, 1] = [0, 0], [1, 1], [2, 2], [3, 3]
    np.testing.assert_array_equal(pos, want)
    np.testing.assert_array_equal(present, ~np.isnan(want[..., 0]))
