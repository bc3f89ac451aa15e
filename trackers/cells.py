"""Per-cell helpers shared by trackers that hold Gaussian targets (KF-NN, GPF).

Two kernels build a tracker's predicted per-cell count distribution ``P_c(t)``:

* :func:`gaussian_cell_mass` -- the probability mass of each of ``K`` Gaussian
  position densities in every grid cell, ``(K, n_cells)``;
* :func:`poisson_binomial` -- per cell, the distribution of a sum of independent
  Bernoulli variables (one per target hypothesis), ``(n_cells, n_counts)`` with the
  last column holding "``n_counts - 1`` or more".

A tracker multiplies the cell masses by each target's existence probability and
passes the product to :func:`poisson_binomial`.
"""

from __future__ import annotations

import numpy as np
from scipy.special import ndtr

from ..scenarios.model import Grid, RayleighGridSensor

#: smallest standard deviation (in cells) used for a position axis; keeps the
#: standardised edges finite for a degenerate (zero-variance) Gaussian
_MIN_STD_CELLS = 1e-12


def gaussian_cell_mass(grid: Grid, means_xy: np.ndarray, cov_xy: np.ndarray) -> np.ndarray:
    """Mass of each Gaussian position density in every cell of ``grid``.

    For component ``k`` with mean ``(mx, my)`` and marginal standard deviations
    ``sx = sqrt(cov_xy[k, 0, 0])``, ``sy = sqrt(cov_xy[k, 1, 1])``, the mass in cell
    ``c = iy * nx + ix`` with edges ``[x0, x1) x [y0, y1)`` is::

        mass[k, c] = (Phi((x1 - mx)/sx) - Phi((x0 - mx)/sx))
                   * (Phi((y1 - my)/sy) - Phi((y0 - my)/sy))

    with ``Phi`` the standard normal CDF (``scipy.special.ndtr``).

    Approximation: the x-y correlation ``cov_xy[k, 0, 1]`` is ignored (the density
    is replaced by the product of its marginals). This is exact for a diagonal
    position covariance; for a correlated one the per-column and per-row sums are
    still exact when the other axis lies inside the grid, only the split between
    cells of a column (row) is approximate.

    Mass outside the workspace is not returned, so a row sums to at most 1 (less
    for a Gaussian near or beyond an edge); callers decide whether to renormalise.

    Parameters
    ----------
    grid : the grid (``nx``, ``ny``, ``cell_size``).
    means_xy : ``(K, 2)`` position means ``(px, py)`` in workspace units.
    cov_xy : ``(K, 2, 2)`` position covariances in workspace units squared.

    Returns
    -------
    ``(K, n_cells)`` float64, non-negative.
    """
    means_xy = np.asarray(means_xy, dtype=float).reshape(-1, 2)
    cov_xy = np.asarray(cov_xy, dtype=float).reshape(-1, 2, 2)
    s = grid.cell_size
    floor = _MIN_STD_CELLS * s
    sx = np.maximum(np.sqrt(np.maximum(cov_xy[:, 0, 0], 0.0)), floor)
    sy = np.maximum(np.sqrt(np.maximum(cov_xy[:, 1, 1], 0.0)), floor)
    x_edges = np.arange(grid.nx + 1) * s  # (nx+1,)
    y_edges = np.arange(grid.ny + 1) * s  # (ny+1,)
    # CDF at every edge, then differences: (K, nx) and (K, ny)
    cdf_x = ndtr((x_edges[None, :] - means_xy[:, 0:1]) / sx[:, None])
    cdf_y = ndtr((y_edges[None, :] - means_xy[:, 1:2]) / sy[:, None])
    mass_x = np.diff(cdf_x, axis=1)
    mass_y = np.diff(cdf_y, axis=1)
    # product of marginals, laid out row-major in y: c = iy * nx + ix
    # ndtr is monotone, so both factors already lie in [0, 1]
    mass = mass_y[:, :, None] * mass_x[:, None, :]  # (K, ny, nx)
    return mass.reshape(len(means_xy), grid.n_cells)


def poisson_binomial(probs: np.ndarray, n_counts: int) -> np.ndarray:
    """Per cell, the distribution of a sum of independent Bernoullis, truncated.

    ``probs[k, c]`` is the probability that target hypothesis ``k`` is present in
    cell ``c``; hypotheses are independent, and within a row the cells are mutually
    exclusive events of one hypothesis (only the per-cell marginals matter here).
    With ``D_0 = (1, 0, ..., 0)`` and one hypothesis ``p`` at a time the recurrence is::

        D_new[t] = (1 - p) D[t] + p D[t-1]          for 0 <= t < n_counts - 1
        D_new[n_counts-1] = D[n_counts-1] + p D[n_counts-2]   ("that many or more")

    Parameters
    ----------
    probs : ``(K, n_cells)`` probabilities in ``[0, 1]`` (``K`` may be 0).
    n_counts : number of count columns, ``>= 2``.

    Returns
    -------
    ``(n_cells, n_counts)`` float64; rows sum to 1.
    """
    if n_counts < 2:
        raise ValueError(f"n_counts must be >= 2, got {n_counts}")
    probs = np.clip(np.asarray(probs, dtype=float), 0.0, 1.0)
    if probs.ndim != 2:
        raise ValueError(f"probs must be (K, n_cells), got shape {probs.shape}")
    # count-major layout (n_counts, n_cells): each recurrence row is contiguous
    dist = np.zeros((n_counts, probs.shape[1]))
    dist[0] = 1.0
    for p in probs:  # K is small (tracks or components); each step is vectorised over cells
        _add_bernoulli(dist, p)
    return dist.T.copy()


def _add_bernoulli(dist: np.ndarray, p: np.ndarray) -> None:
    """One recurrence step in place: ``dist (n_counts, m)``, Bernoulli probabilities ``p (m,)``."""
    into_last = dist[-2] * p  # the last column keeps its mass whatever p does
    # rows 1..n-2: the right-hand side uses the old rows, evaluated before assignment
    dist[1:-1] = dist[1:-1] * (1.0 - p) + dist[:-2] * p
    dist[0] *= 1.0 - p
    dist[-1] += into_last


def look_log_ratios(sensor: RayleighGridSensor, cells: np.ndarray, returns: np.ndarray,
                    t_max: int) -> tuple[np.ndarray, np.ndarray]:
    """Looked cells ``U (n_u,)`` (sorted, unique) and ``LL (n_u, t_max + 1)``.

    ``LL[u, T] = sum_{looks at U[u]} log p(z | T) / p(z | 0)``: several looks at one cell
    multiply their likelihoods; ``LL[:, 0] = 0``.
    """
    U, inv = np.unique(cells, return_inverse=True)
    T = np.arange(t_max + 1)
    per_look = sensor.log_likelihood_ratio(returns[:, None], T[None, :])  # (L, t_max+1)
    LL = np.zeros((len(U), t_max + 1))
    np.add.at(LL, inv, per_look)
    return U, LL


class CellCounts:
    """``P_c(t)`` for every cell of a grid, stored in ``O(cells with their own row)``.

    ``cells (m,)`` sorted, unique flat cell indices with rows ``rows (m, n_counts)``; every
    other cell has the row ``default (n_counts,)`` (for example the undetected-target field
    where no track has mass). Each row is a distribution over counts ``0..n_counts-1`` (the
    last column "that many or more"). ``dense()`` builds the ``(n_cells, n_counts)`` array
    (``O(cells)``: small grids, tests). A tracker's ``cell_count_distribution`` may return
    this or the dense array (:func:`as_cell_counts` turns either into this).
    """

    __slots__ = ("n_cells", "cells", "rows", "default")

    def __init__(self, n_cells: int, cells: np.ndarray, rows: np.ndarray,
                 default: np.ndarray) -> None:
        cells = np.asarray(cells, dtype=np.int64).reshape(-1)
        rows = np.asarray(rows, dtype=float)
        default = np.asarray(default, dtype=float).reshape(-1)
        if rows.ndim != 2 or rows.shape != (len(cells), len(default)) or len(default) < 2:
            raise ValueError(f"CellCounts: rows {rows.shape} must be (len(cells) = "
                             f"{len(cells)}, n_counts = {len(default)} >= 2)")
        if len(cells) and (np.any(np.diff(cells) <= 0) or cells[0] < 0
                           or cells[-1] >= n_cells):
            raise ValueError(f"CellCounts: cells must be sorted, unique and in [0, {n_cells})")
        self.n_cells, self.cells, self.rows, self.default = int(n_cells), cells, rows, default

    @property
    def n_counts(self) -> int:
        return len(self.default)

    @property
    def n_default(self) -> int:
        """How many cells have the default row."""
        return self.n_cells - len(self.cells)

    def row_of(self, cells: np.ndarray) -> np.ndarray:
        """The rows of the given flat cells, ``(len(cells), n_counts)``."""
        cells = np.asarray(cells, dtype=np.int64).reshape(-1)
        i = np.searchsorted(self.cells, cells)
        own = i < len(self.cells)
        own[own] = self.cells[i[own]] == cells[own]
        out = np.repeat(self.default[None], len(cells), axis=0)
        out[own] = self.rows[i[own]]
        return out

    def default_cell(self, k: np.ndarray) -> np.ndarray:
        """The ``k``-th cells (0-based, ascending) among those with the default row:
        ``k + (number of own cells at or below the answer)``, by a search over ``cells``."""
        k = np.asarray(k, dtype=np.int64)
        # own cells below position j: cells[j] - j cells with the default row come before it
        gaps = self.cells - np.arange(len(self.cells))
        return k + np.searchsorted(gaps, k, side="right")

    def dense(self) -> np.ndarray:
        """``(n_cells, n_counts)``: every cell's row (``O(cells)``)."""
        out = np.repeat(self.default[None], self.n_cells, axis=0)
        out[self.cells] = self.rows
        return out

    @staticmethod
    def from_dense(P: np.ndarray) -> CellCounts:
        """Every cell its own row (``default`` the first row, unused)."""
        P = np.asarray(P, dtype=float)
        return CellCounts(len(P), np.arange(len(P)), P, P[0] if len(P) else np.eye(2)[0])


def as_cell_counts(P: CellCounts | np.ndarray) -> CellCounts:
    """A tracker's ``cell_count_distribution()`` output as :class:`CellCounts`."""
    return P if isinstance(P, CellCounts) else CellCounts.from_dense(P)
