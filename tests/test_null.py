"""The ``null`` baseline: no target anywhere, in its estimate and in its prediction."""

from __future__ import annotations

import numpy as np

from mttbench.scenarios.model import BirthDeath, Dynamics, Grid, Looks, TrackingModel
from mttbench.trackers import make


def test_null_predicts_no_target_in_any_cell_and_reports_none():
    """Its count is 0, so its predicted per-cell count distribution puts probability 1 on
    "no target" in every cell, before and after looks (expected count 0 everywhere)."""
    grid = Grid(5, 4)
    model = TrackingModel(grid, Dynamics(wna_intensity=0.01),
                          BirthDeath(n_random_initial=3, birth_rate=0.5))
    tracker = make("null")
    tracker.reset(model, np.random.default_rng(0))
    for _ in range(2):
        tracker.predict()
        dense = tracker.cell_count_distribution().dense()
        assert dense.shape[0] == grid.n_cells
        want = np.zeros_like(dense)
        want[:, 0] = 1.0
        np.testing.assert_array_equal(dense, want)
        assert float((dense @ np.arange(dense.shape[1])).sum()) == 0.0
        tracker.update(Looks(np.arange(grid.n_cells), np.ones(grid.n_cells, bool)))
        est = tracker.estimate()
        assert est.count == 0 and len(est.states) == 0
