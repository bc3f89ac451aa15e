"""The GPF without per-cell arrays: its P_c(t) and field against the dense forms.

References: ``gaussian_cell_mass`` over every cell and ``poisson_binomial`` of every
track and the dense field (the computation the GPF made before it stored the field
sparsely), and a dense field updated with numpy on every cell.
"""

from __future__ import annotations

import tracemalloc

import numpy as np

from mttbench import trackers
from mttbench.scenarios.model import (
    BirthDeath,
    Dynamics,
    Grid,
    Looks,
    RayleighGridSensor,
    TrackingModel,
)
from mttbench.trackers import kalman
from mttbench.trackers.cells import CellField, gaussian_cell_mass, poisson_binomial


def _model(grid, n0=3, birth_rate=0.0):
    return TrackingModel(grid, Dynamics(wna_intensity=1e-3),
                         BirthDeath(n_random_initial=n0, birth_rate=birth_rate,
                                    survival_probability=0.99 if birth_rate else 1.0,
                                    birth_velocity_std=0.1),
                         RayleighGridSensor(p_d=0.5, snr=10.0, looks_per_step=20))


def test_cell_field_maps_and_sets_like_a_dense_array():
    rng = np.random.default_rng(2)
    f, dense = CellField(50, 0.02), np.full(50, 0.02)
    for _ in range(30):
        cells = rng.choice(50, int(rng.integers(0, 8)), replace=False)
        vals = rng.uniform(0.0, 0.1, len(cells))
        f.set(cells, vals)
        dense[cells] = vals
        f.map(lambda u: 1.0 - (1.0 - 0.99 * u) * (1.0 - 1e-3))
        dense = 1.0 - (1.0 - 0.99 * dense) * (1.0 - 1e-3)
        f.map(lambda u: np.maximum(u, 0.015))
        dense = np.maximum(dense, 0.015)
        np.testing.assert_array_equal(f.dense(), dense)
        np.testing.assert_array_equal(f.at(np.arange(50)), dense)
        assert f.total() == np.float64(dense.sum()) or abs(f.total() - dense.sum()) < 1e-15
    assert len(f.cells) < 50  # cells equal to the common value again are dropped


def test_sparse_count_distribution_equals_the_dense_computation():
    """Tracks with several components and a field changed in some cells, on a 30 x 30
    grid: the stored rows are the dense Poisson-binomial (tracks in order, then the
    field) up to the Gaussians' mass beyond 6 sd (< 1e-9), and every other cell has the
    field's common row."""
    grid = Grid(30, 30, 1.0)
    t = trackers.make("gpf", n_counts=4)
    t.reset(_model(grid), np.random.default_rng(0))
    m = np.array([[5.2, 0, 5.1, 0], [6.0, 0, 5.5, 0], [20.3, 0, 12.7, 0], [3.1, 0, 25.9, 0]])
    P = np.stack([np.diag([a * a, 0.01, b * b, 0.01])
                  for a, b in ((0.4, 0.3), (1.2, 0.9), (0.6, 0.6), (2.5, 1.0))])
    t._set(np.array([0.9, 0.7, 0.4]), np.array([0, 0, 1, 2]), np.array([0.6, 0.4, 1.0, 1.0]),
           m, P)
    t._u.set([3, 17, 400, 899], [0.05, 0.0, 0.2, 0.01])
    got = t.cell_count_distribution()
    mass = gaussian_cell_mass(grid, *kalman.position_marginal(m, P))
    per_track = np.zeros((3, grid.n_cells))
    np.add.at(per_track, np.array([0, 0, 1, 2]), np.array([0.6, 0.4, 1.0, 1.0])[:, None] * mass)
    probs = np.vstack([np.array([0.9, 0.7, 0.4])[:, None] * per_track, t._u.dense()[None]])
    want = poisson_binomial(probs, 4)
    np.testing.assert_allclose(got.dense(), want, atol=1e-9, rtol=0)
    assert len(got.cells) < grid.n_cells / 2
    np.testing.assert_allclose(got.default, want[np.setdiff1d(np.arange(900), got.cells)[0]],
                               atol=1e-9, rtol=0)


def test_a_huge_grid_costs_what_a_small_one_costs():
    """1e5 x 1e5 cells (1e10): reset, ten predict / update / P_c steps with 30 looks near
    three tracks allocate a few MB at most (tracemalloc peak), as on a 50 x 50 grid."""
    def peak(n):
        grid = Grid(n, n, 1.0)
        t = trackers.make("gpf")
        tracemalloc.start()
        t.reset(_model(grid, birth_rate=0.05), np.random.default_rng(0))
        t.set_particles([0.9, 0.8, 0.7], np.array([[10.5, 0.1, 10.5, 0], [20.5, 0, 12.5, 0.1],
                                                   [30.5, 0, 30.5, 0]]),
                        np.stack([np.diag([0.1, 0.01, 0.1, 0.01])] * 3))
        rng = np.random.default_rng(1)
        for _ in range(10):
            t.predict()
            pc = t.cell_count_distribution()
            cells = (rng.integers(5, 35, 30) * n + rng.integers(5, 35, 30)).astype(np.int64)
            t.update(Looks(cells, rng.uniform(size=30) < 0.2))
            t.estimate()
        size = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()
        assert pc.n_cells == n * n and len(pc.cells) < 5000
        return size

    small, huge = peak(50), peak(100_000)
    assert huge < 2 * small + 1_000_000, (small, huge)
