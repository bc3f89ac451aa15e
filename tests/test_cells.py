"""Tests of trackers.cells against brute force enumeration and numerical integration."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from scipy import integrate, stats

from mttbench.scenarios.model import Grid
from mttbench.trackers.cells import gaussian_cell_mass, looked_in_boxes, poisson_binomial

#: one tolerance for quadrature comparisons (dblquad/quad absolute error ~1e-10)
QUAD_ATOL = 1e-8


def _brute_force_counts(probs: np.ndarray, n_counts: int) -> np.ndarray:
    """Enumerate all 2**K presence patterns per cell; truncate at n_counts - 1."""
    K, n_cells = probs.shape
    out = np.zeros((n_cells, n_counts))
    for c in range(n_cells):
        for pattern in itertools.product((0, 1), repeat=K):
            e = np.array(pattern)
            w = np.prod(np.where(e == 1, probs[:, c], 1.0 - probs[:, c]))
            out[c, min(int(e.sum()), n_counts - 1)] += w
    return out


@pytest.mark.parametrize("K", [0, 1, 2, 5])
@pytest.mark.parametrize("n_counts", [2, 4, 8])
def test_poisson_binomial_equals_enumeration(K: int, n_counts: int) -> None:
    rng = np.random.default_rng(10 * K + n_counts)
    probs = rng.uniform(0.0, 1.0, (K, 6))
    probs[:, 0] = 0.0  # a cell no hypothesis can occupy
    if K:
        probs[0, 1] = 1.0  # a certain target
    got = poisson_binomial(probs, n_counts)
    want = _brute_force_counts(probs, n_counts)
    assert got.shape == (6, n_counts)
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-14)
    np.testing.assert_allclose(got.sum(axis=1), 1.0, rtol=0, atol=1e-14)
    assert np.all(got >= 0)


def test_poisson_binomial_rejects_bad_input() -> None:
    with pytest.raises(ValueError):
        poisson_binomial(np.zeros((1, 3)), 1)
    with pytest.raises(ValueError):
        poisson_binomial(np.zeros(3), 3)


def _cell_mass_by_quadrature(grid: Grid, mean: np.ndarray, cov: np.ndarray, c: int) -> float:
    x0, x1, y0, y1 = (float(v) for v in grid.cell_bounds(np.array(c)))
    dens = stats.multivariate_normal(mean=mean, cov=cov)
    val, _ = integrate.dblquad(lambda y, x: dens.pdf([x, y]), x0, x1, y0, y1,
                               epsabs=1e-12, epsrel=1e-10)
    return val


def test_gaussian_cell_mass_diagonal_equals_quadrature() -> None:
    grid = Grid(nx=4, ny=3, cell_size=0.5)
    means = np.array([[0.9, 0.7], [0.1, 1.4]])  # the second sits near a corner
    covs = np.array([np.diag([0.04, 0.09]), np.diag([0.3, 0.02])])
    mass = gaussian_cell_mass(grid, means, covs)
    assert mass.shape == (2, grid.n_cells)
    for k in range(2):
        for c in range(grid.n_cells):
            want = _cell_mass_by_quadrature(grid, means[k], covs[k], c)
            assert mass[k, c] == pytest.approx(want, abs=QUAD_ATOL), (k, c)


def test_gaussian_cell_mass_correlated_has_exact_column_and_row_sums() -> None:
    """The product-of-marginals approximation keeps per-column/row mass exact."""
    grid = Grid(nx=8, ny=8, cell_size=1.0)
    mean = np.array([4.2, 3.7])
    cov = np.array([[0.5, 0.35], [0.35, 0.6]])  # strongly correlated, well inside the grid
    mass = gaussian_cell_mass(grid, mean[None], cov[None])[0].reshape(grid.ny, grid.nx)
    for ix in range(grid.nx):
        want, _ = integrate.quad(stats.norm(mean[0], np.sqrt(cov[0, 0])).pdf, ix, ix + 1)
        assert mass[:, ix].sum() == pytest.approx(want, abs=1e-6)  # y-tail beyond grid ~1e-7
    for iy in range(grid.ny):
        want, _ = integrate.quad(stats.norm(mean[1], np.sqrt(cov[1, 1])).pdf, iy, iy + 1)
        assert mass[iy, :].sum() == pytest.approx(want, abs=1e-6)
    # and the cell split itself is not exact: the approximation is a real approximation
    exact = _cell_mass_by_quadrature(grid, mean, cov, 3 * grid.nx + 4)
    assert abs(mass[3, 4] - exact) > 1e-3


def test_gaussian_cell_mass_degenerate_and_outside() -> None:
    grid = Grid(nx=3, ny=2, cell_size=2.0)
    means = np.array([[3.0, 1.0], [-5.0, 1.0], [5.9, 3.9]])
    covs = np.zeros((3, 2, 2))  # zero variance: all mass in the cell of the mean
    mass = gaussian_cell_mass(grid, means, covs)
    assert np.all(np.isfinite(mass))
    np.testing.assert_array_equal(mass[0], np.eye(grid.n_cells)[grid.cell_of(3.0, 1.0)])
    np.testing.assert_array_equal(mass[1], 0.0)  # outside the workspace: no mass
    np.testing.assert_array_equal(mass[2], np.eye(grid.n_cells)[grid.n_cells - 1])
    # a wide Gaussian centred on the workspace: total mass = product of 1-D masses
    wide = gaussian_cell_mass(grid, np.array([[3.0, 2.0]]), np.diag([4.0, 1.0])[None])
    want = (stats.norm(3, 2).cdf(6) - stats.norm(3, 2).cdf(0)) * (
        stats.norm(2, 1).cdf(4) - stats.norm(2, 1).cdf(0))
    assert wide.sum() == pytest.approx(want, rel=1e-12)


def test_cell_counts_rows_dense_and_default_cells_agree_with_brute_force():
    """CellCounts: row_of and default_cell against the dense array built cell by cell."""
    from mttbench.trackers.cells import CellCounts

    rng = np.random.default_rng(3)
    for _ in range(50):
        n_cells = int(rng.integers(1, 40))
        m = int(rng.integers(0, n_cells + 1))
        cells = np.sort(rng.choice(n_cells, m, replace=False))
        rows = rng.dirichlet(np.ones(4), m).reshape(m, 4)
        default = rng.dirichlet(np.ones(4))
        cc = CellCounts(n_cells, cells, rows, default)
        dense = np.array([rows[list(cells).index(c)] if c in cells else default
                          for c in range(n_cells)])
        np.testing.assert_array_equal(cc.dense(), dense)
        np.testing.assert_array_equal(cc.row_of(np.arange(n_cells)), dense)
        free = [c for c in range(n_cells) if c not in cells]
        np.testing.assert_array_equal(cc.default_cell(np.arange(len(free))), free)
    with pytest.raises(ValueError, match="sorted, unique"):
        CellCounts(5, [3, 1], np.eye(2), np.eye(2)[0])


def test_looked_in_boxes_equals_the_dense_box_test() -> None:
    """The sparse box-by-look pairs equal ``np.nonzero`` of the dense test, order included,
    for boxes small (enumerated) and large (tested against every look), partly or wholly
    off the grid, empty, infinite and NaN."""
    rng = np.random.default_rng(11)
    nx, ny = 37, 23
    for n_looks in (1, 5, 60, 400):
        looked = np.unique(rng.integers(0, nx * ny, n_looks))
        K = 50
        lo_x = np.floor(rng.uniform(-10, nx + 5, K))
        lo_y = np.floor(rng.uniform(-10, ny + 5, K))
        hi_x = lo_x + np.floor(rng.exponential(8, K)) - (rng.random(K) < 0.1) * 30
        hi_y = lo_y + np.floor(rng.exponential(8, K))
        hi_x[:3] = np.inf
        lo_y[3:5] = -np.inf
        lo_x[5] = np.nan
        hi_y[6] = np.nan
        ux, uy = looked % nx, looked // nx
        dense = ((ux[None] >= lo_x[:, None]) & (ux[None] <= hi_x[:, None])
                 & (uy[None] >= lo_y[:, None]) & (uy[None] <= hi_y[:, None]))
        ref_box, ref_i = np.nonzero(dense)
        box, i = looked_in_boxes(lo_x, hi_x, lo_y, hi_y, looked, nx, ny)
        np.testing.assert_array_equal(box, ref_box)
        np.testing.assert_array_equal(i, ref_i)
