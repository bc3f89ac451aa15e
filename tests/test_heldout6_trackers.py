"""Tracker behaviours no earlier test reached: the truth-aided reference's P_c(t) for a
target whose filter has left the grid, and the PMB's Poisson intensity at one cell."""

from __future__ import annotations

import numpy as np
import pytest

from mttbench.scenarios.model import BirthDeath, Dynamics, Grid, RayleighGridSensor, TrackingModel
from mttbench.trackers.truth_aided import TruthAidedTracker


@pytest.mark.parametrize("state, cell_xy", [
    ((5.5, 30.0, 4.5, 0.0), (9, 4)),     # beyond the right wall: its row's last cell
    ((2.5, 0.0, 6.5, -40.0), (2, 0)),    # below the bottom wall
    ((3.5, -25.0, 8.5, 25.0), (0, 9)),   # past a corner
])
def test_a_target_whose_filter_left_the_grid_is_certain_in_the_nearest_cell(state, cell_xy):
    """With walls where targets die, a filter predicted far past a wall puts no mass on
    any cell; its target is then counted, with probability 1, in the cell nearest its
    mean (the documented fallback), and a second target inside the grid keeps its own
    mass. The reference: that cell found by clipping the mean to the grid by hand, and
    the inside target's cell probabilities summing to one."""
    grid = Grid(10, 10)
    inside = (4.5, 0.0, 4.5, 0.0)
    model = TrackingModel(grid, Dynamics(wna_intensity=1e-4),
                          BirthDeath(initial_states=(state, inside), boundary="die"),
                          RayleighGridSensor())
    tr = TruthAidedTracker()
    tr.reset(model, np.random.default_rng(0))
    tr.observe_truth(np.array([state, inside]), np.array([0, 1]))
    tr.predict()
    dense = tr.cell_count_distribution().dense()
    present = 1.0 - dense[:, 0]  # P(at least one target) per cell
    far = cell_xy[1] * grid.nx + cell_xy[0]
    assert present[far] == pytest.approx(1.0, abs=1e-12)
    near = 4 * grid.nx + 4  # the inside target's own cell and its neighbours
    assert 0.9 < present[near] <= 1.0
    # the expected count over the grid: the two targets, each once
    counts = dense @ np.arange(dense.shape[1])
    assert counts.sum() == pytest.approx(2.0, abs=1e-6)


def test_the_pmb_intensity_grows_by_what_is_added_even_at_a_single_cell():
    """``lambda_c += amount`` at the given cells (repeats summed): the reference is a
    dense array updated by ``np.add.at``, for one cell, one cell twice, several cells
    and none; and a Bernoulli recycled from a Gaussian inside one cell adds its ``r``
    there (its other cells' masses are negligible)."""
    from mttbench.trackers.cells import CellField
    from mttbench.trackers.pmb.ppp import add_intensity, recycle

    field, ref = CellField(12, 0.05), np.full(12, 0.05)
    for cells, amounts in (([7], [0.3]), ([2, 2], [0.1, 0.25]), ([0, 11, 5], [1.0, 0.5, 2.0]),
                           ([], [])):
        add_intensity(field, np.array(cells, dtype=np.int64), np.array(amounts, float))
        np.add.at(ref, np.array(cells, dtype=np.int64), np.array(amounts, float))
        np.testing.assert_allclose(field.dense(), ref, rtol=1e-15, atol=0)
    grid = Grid(4, 3)
    field = CellField(grid.n_cells, 0.0)
    m = np.array([[2.5, 0.0, 1.5, 0.0]])
    P = np.diag([1e-4, 1e-4, 1e-4, 1e-4])[None]
    recycle(field, grid, np.array([0.4]), m, P)
    want = np.zeros(grid.n_cells)
    want[1 * grid.nx + 2] = 0.4
    np.testing.assert_allclose(field.dense(), want, atol=1e-9)
