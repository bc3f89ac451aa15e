"""The oracle's target cells at the grid's edges: cell 0 and the last cell are cells like
any other (only ``-1``, outside the grid, and indices past the grid are ignored), checked
against the definition on every edge case with as many looks as target cells."""

from __future__ import annotations

import numpy as np
import pytest

from mttbench import scenarios
from mttbench.benchmarks.engine.policies import make_policy

MODEL = scenarios.get("default").model
N = MODEL.grid.n_cells


@pytest.mark.parametrize("truth", [[0], [N - 1], [0, N - 1], [0, 0, -1, N], [-1, 0, 7, N - 1]])
def test_the_oracle_looks_at_every_target_cell_of_the_grid_edges(truth):
    inside = sorted({c for c in truth if 0 <= c < N})  # the definition
    for looks in (len(inside), len(inside) + 3):
        pol = make_policy("oracle")
        pol.reset(MODEL, looks, np.random.default_rng(5))
        cells = pol.select(0, truth_cells=np.array(truth, dtype=np.int64))
        assert len(cells) == len(set(cells.tolist())) == looks
        assert set(inside) <= set(cells.tolist())
        assert cells.min() >= 0 and cells.max() < N


def test_sparse_distinct_looks_on_a_grid_with_few_default_cells_equal_the_dense_choice():
    """``repeats=False`` with more looks than the cells above or tied with the default
    row: the sparse pick takes those, then the best of the rest, ``n_looks`` distinct
    cells in all; the dense kernel (every cell's gain, top ``n_looks``) is the reference.
    Gains are distinct here except for the default cells, so the sets must be equal."""
    from mttbench.benchmarks.engine.information import (
        expected_gain,
        greedy_looks,
        greedy_looks_sparse,
    )
    from mttbench.trackers.cells import CellCounts

    rng = np.random.default_rng(11)
    n_cells, n_counts = 20, 3
    own = np.sort(rng.choice(n_cells, size=17, replace=False))
    rows = rng.dirichlet(np.full(n_counts, 0.7), size=len(own))
    counts = CellCounts(n_cells, own, rows, np.array([0.8, 0.15, 0.05]))
    pd_ = MODEL.sensor.detection_probability(np.arange(n_counts))
    gains = expected_gain(counts.dense(), pd_, 0.5)
    default_gain = gains[np.setdiff1d(np.arange(n_cells), own)][0]
    assert (gains[own] > default_gain).sum() < 12 < (gains[own] != default_gain).sum()
    for looks in (12, 16, 19):
        got = greedy_looks_sparse(counts, pd_, looks, 0.5, repeats=False,
                                  rng=np.random.default_rng(1))
        want = greedy_looks(counts.dense(), pd_, looks, 0.5, repeats=False,
                            rng=np.random.default_rng(1))
        assert len(got) == len(set(got.tolist())) == looks
        assert sorted(got.tolist()) == sorted(want.tolist())
