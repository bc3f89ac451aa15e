"""Per-cell helpers shared by trackers that hold Gaussian targets (KF-NN, GPF).

Two kernels build a tracker's predicted per-cell count distribution ``P_c(t)``:

* :func:`gaussian_cell_mass` -- the probability mass of each of ``K`` Gaussian
  position densities in every grid cell, ``(K, n_cells)``;
* :func:`poisson_binomial` -- per cell, the distribution of a sum of independent
  Bernoulli variables (one per target hypothesis), ``(n_cells, n_counts)`` with the
  last column holding "``n_counts - 1`` or more".

A tracker multiplies the cell masses by each target's existence probability and
passes the product to :func:`poisson_binomial`.

Their sparse forms cost nothing per cell of the grid:
:func:`gaussian_cell_mass_sparse` keeps each Gaussian's masses within 6 sd of its mean,
:func:`bernoulli_cell_counts` turns such entries plus a per-cell field into
:class:`CellCounts` (``P_c(t)`` as own rows plus one default row), and :class:`CellField`
holds a per-cell value (an undetected-target intensity) as a default plus the cells that
differ. Each equals its dense counterpart bit for bit where it keeps a number.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from types import ModuleType

import numpy as np
from scipy.special import ndtr

from ..scenarios.model import Grid, RayleighGridSensor

#: smallest standard deviation (in cells) used for a position axis; keeps the
#: standardised edges finite for a degenerate (zero-variance) Gaussian
_MIN_STD_CELLS = 1e-12


def _position_sds(grid: Grid, means_xy: np.ndarray, cov_xy: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``means (K, 2)``, ``covs (K, 2, 2)`` as float arrays and the marginal sds of x and y,
    floored at ``_MIN_STD_CELLS`` cells (a degenerate Gaussian stays in its cell)."""
    means_xy = np.asarray(means_xy, dtype=float).reshape(-1, 2)
    cov_xy = np.asarray(cov_xy, dtype=float).reshape(-1, 2, 2)
    floor = _MIN_STD_CELLS * grid.cell_size
    sx = np.maximum(np.sqrt(np.maximum(cov_xy[:, 0, 0], 0.0)), floor)
    sy = np.maximum(np.sqrt(np.maximum(cov_xy[:, 1, 1], 0.0)), floor)
    return means_xy, cov_xy, sx, sy


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
    means_xy, cov_xy, sx, sy = _position_sds(grid, means_xy, cov_xy)
    s = grid.cell_size
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
    multiply their likelihoods; ``LL[:, 0] = 0``. With the compiled backend
    :func:`.grid_kernels.look_log_ratios` sums the same two rows (a look with a return and
    one without) in the same order.
    """
    kernels = _field_kernels() if _field_kernels is not None else None
    if kernels is not None:
        hit, miss = _look_ratio_rows(sensor, int(t_max))
        return kernels.look_log_ratios(np.ascontiguousarray(cells, dtype=np.int64),
                                       np.ascontiguousarray(returns, dtype=bool), hit, miss)
    U, inv = np.unique(cells, return_inverse=True)
    T = np.arange(t_max + 1)
    per_look = sensor.log_likelihood_ratio(returns[:, None], T[None, :])  # (L, t_max+1)
    LL = np.zeros((len(U), t_max + 1))
    np.add.at(LL, inv, per_look)
    return U, LL


@functools.lru_cache(maxsize=64)
def _look_ratio_rows(sensor: RayleighGridSensor, t_max: int) -> tuple[np.ndarray, np.ndarray]:
    """``log l(T)``, ``T = 0..t_max``, of a look with a return and of one without: the two
    rows :func:`look_log_ratios`' per-look table is made of (the sensor's function of
    ``T`` alone, broadcast over the looks), read-only."""
    rows = sensor.log_likelihood_ratio(np.array([[True], [False]]),
                                       np.arange(t_max + 1)[None, :])
    hit, miss = np.ascontiguousarray(rows[0]), np.ascontiguousarray(rows[1])
    hit.flags.writeable = miss.flags.writeable = False
    return hit, miss


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


# ------------------------------------------------------------- sparse P_c(t)
#: half-width, in marginal standard deviations, of the box of cells around a Gaussian's
#: mean inside which :func:`gaussian_cell_mass_sparse` keeps its cell masses: the mass
#: left out is at most ``2 * Phi(-6) = 2e-9`` per axis
BOX_SD = 6.0


def _concat_ranges(starts: np.ndarray, lengths: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``seg, values``: for each ``i``, ``lengths[i]`` entries ``seg = i`` and
    ``values = starts[i], starts[i] + 1, ...``, concatenated (``O(sum(lengths))``)."""
    starts = np.asarray(starts, dtype=np.int64)
    lengths = np.asarray(lengths, dtype=np.int64)
    seg = np.repeat(np.arange(len(lengths)), lengths)
    first = np.cumsum(lengths) - lengths
    values = np.arange(int(lengths.sum()), dtype=np.int64) - first[seg] + starts[seg]
    return seg, values


def _axis_boxes(mean: np.ndarray, sd: np.ndarray, n: int, s: float, n_sd: float
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per Gaussian, the first cell of its box on one axis, the box's width in cells (0 when
    the box misses the grid) and the masses of its cells concatenated (:func:`gaussian_cell_mass`'s
    arithmetic on the box's edges only)."""
    with np.errstate(invalid="ignore", over="ignore"):
        lo = np.floor((mean - n_sd * sd) / s)
        hi = np.floor((mean + n_sd * sd) / s)
    hit = (hi >= 0) & (lo <= n - 1)
    i0 = np.clip(np.nan_to_num(lo, nan=0.0), 0, n - 1).astype(np.int64)
    i1 = np.clip(np.nan_to_num(hi, nan=-1.0), 0, n - 1).astype(np.int64)
    width = np.where(hit, i1 - i0 + 1, 0)
    seg, edge = _concat_ranges(i0, np.where(hit, width + 1, 0))
    # the same expression as the dense kernel: edge index times the cell size, standardised
    cdf = ndtr((edge * s - mean[seg]) / sd[seg])
    # differences within a box; the last edge of each box starts no cell
    last = np.cumsum(np.where(hit, width + 1, 0)) - 1
    keep = np.ones(len(cdf), dtype=bool)
    keep[last[hit]] = False
    mass = (cdf[1:] - cdf[:-1])[keep[:-1]] if len(cdf) else np.zeros(0)
    return i0, width, mass


def looked_in_boxes(ix_lo: np.ndarray, ix_hi: np.ndarray, iy_lo: np.ndarray,
                    iy_hi: np.ndarray, looked: np.ndarray, nx: int, ny: int
                    ) -> tuple[np.ndarray, np.ndarray]:
    """The looked cells inside each box: pairs ``(box, i)`` with ``looked[i]`` (sorted
    unique flat cells) in ``[ix_lo, ix_hi] x [iy_lo, iy_hi]`` (inclusive cell indices,
    floats allowed, any range; NaN bounds hold nothing). Boxes ascend, and ``i`` within a
    box, as ``np.nonzero`` of the dense box-by-look test orders them. A box holding at most
    ``len(looked)`` cells enumerates its cells, a larger one tests every look: time and
    memory ``O(sum over boxes of min(box cells, looks))``, never boxes x looks."""
    n_u, K = len(looked), len(ix_lo)
    empty = np.zeros(0, dtype=np.int64)
    if n_u == 0 or K == 0:
        return empty, empty
    with np.errstate(invalid="ignore"):
        hit = (ix_hi >= 0) & (ix_lo <= nx - 1) & (iy_hi >= 0) & (iy_lo <= ny - 1)
    hit &= (ix_hi >= ix_lo) & (iy_hi >= iy_lo)
    x0 = np.clip(np.nan_to_num(ix_lo, nan=0.0), 0, nx - 1).astype(np.int64)
    x1 = np.clip(np.nan_to_num(ix_hi, nan=0.0), 0, nx - 1).astype(np.int64)
    y0 = np.clip(np.nan_to_num(iy_lo, nan=0.0), 0, ny - 1).astype(np.int64)
    y1 = np.clip(np.nan_to_num(iy_hi, nan=0.0), 0, ny - 1).astype(np.int64)
    w = np.where(hit, x1 - x0 + 1, 0)
    area = w * np.where(hit, y1 - y0 + 1, 0)
    small = area <= n_u
    seg, t = _concat_ranges(np.zeros(K, dtype=np.int64), np.where(small, area, 0))
    ws = np.maximum(w[seg], 1)
    cells = (y0[seg] + t // ws) * nx + x0[seg] + t % ws
    pos = np.minimum(np.searchsorted(looked, cells), n_u - 1)
    inside = looked[pos] == cells
    big = np.nonzero(~small)[0]
    ux, uy = looked % nx, looked // nx
    near = ((ux[None] >= x0[big, None]) & (ux[None] <= x1[big, None])
            & (uy[None] >= y0[big, None]) & (uy[None] <= y1[big, None]))
    b, i_big = np.nonzero(near)
    box = np.concatenate([seg[inside], big[b]])
    i = np.concatenate([pos[inside], i_big])
    order = np.argsort(box, kind="stable")
    return box[order], i[order]


def gaussian_cell_mass_sparse(grid: Grid, means_xy: np.ndarray, cov_xy: np.ndarray,
                              n_sd: float = BOX_SD
                              ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`gaussian_cell_mass` restricted to a box of ``+- n_sd`` marginal standard
    deviations around each mean (clipped to the grid), in ``O(cells in the boxes)``.

    Returns ``comp (nnz,)``, ``cells (nnz,)`` (int64) and ``mass (nnz,)`` float64: the
    entries of component ``k`` are contiguous, ``k`` ascending, and within one component
    the cells ascend. Each entry is bit for bit the dense kernel's value (the same
    expression on the same edges); cells outside the box are left out, which drops at
    most ``2 Phi(-n_sd)`` of mass per axis (``4e-9`` in all at ``n_sd = 6``). A Gaussian
    whose box misses the grid has no entries.
    """
    means_xy, cov_xy, sx, sy = _position_sds(grid, means_xy, cov_xy)
    s = grid.cell_size
    ix0, wx, mass_x = _axis_boxes(means_xy[:, 0], sx, grid.nx, s, n_sd)
    iy0, wy, mass_y = _axis_boxes(means_xy[:, 1], sy, grid.ny, s, n_sd)
    size = wx * wy
    comp, t = _concat_ranges(np.zeros(len(size), dtype=np.int64), size)
    w = wx[comp]
    ly, lx = t // np.maximum(w, 1), t % np.maximum(w, 1)
    off_x = np.cumsum(wx) - wx
    off_y = np.cumsum(wy) - wy
    mass = mass_y[off_y[comp] + ly] * mass_x[off_x[comp] + lx]
    cells = (iy0[comp] + ly) * grid.nx + ix0[comp] + lx
    return comp, cells, mass


def bernoulli_cell_counts(n_cells: int, n_counts: int, cells: np.ndarray, probs: np.ndarray,
                          last_default: float = 0.0, last_cells: np.ndarray | None = None,
                          last_probs: np.ndarray | None = None) -> CellCounts:
    """:func:`poisson_binomial` of sparse Bernoullis, as :class:`CellCounts`.

    Entry ``i`` is a Bernoulli of probability ``probs[i]`` in cell ``cells[i]`` (a cell
    may have many; they are applied in the order given). Then every cell gets one more
    Bernoulli, of probability ``last_default`` except at the sorted unique
    ``last_cells`` (``last_probs``): a field such as "at least one untracked target".
    The cells with entries or their own ``last`` value get their own rows; every other
    cell the default row, one Bernoulli ``last_default``. ``O((entries + last_cells)
    n_counts)`` plus a sort of the entries.

    Every row equals, bit for bit, :func:`poisson_binomial`'s row of the dense
    ``(K + 1, n_cells)`` array holding the same Bernoullis in the same order and zeros
    elsewhere (a zero probability leaves the recurrence's row unchanged exactly).
    """
    if n_counts < 2:
        raise ValueError(f"n_counts must be >= 2, got {n_counts}")
    cells = np.asarray(cells, dtype=np.int64).reshape(-1)
    probs = np.clip(np.asarray(probs, dtype=float).reshape(-1), 0.0, 1.0)
    last_cells = (np.zeros(0, dtype=np.int64) if last_cells is None
                  else np.asarray(last_cells, dtype=np.int64).reshape(-1))
    last_probs = (np.zeros(0) if last_probs is None
                  else np.clip(np.asarray(last_probs, dtype=float).reshape(-1), 0.0, 1.0))
    p_default = float(np.clip(last_default, 0.0, 1.0))
    order = np.argsort(cells, kind="stable")  # by cell, the given order within a cell
    c_sorted, p_sorted = cells[order], probs[order]
    own = np.union1d(c_sorted, last_cells)
    dist = np.zeros((n_counts, len(own)))
    dist[0] = 1.0
    if len(c_sorted):
        col = np.searchsorted(own, c_sorted)
        rank = np.arange(len(c_sorted)) - np.searchsorted(c_sorted, c_sorted, side="left")
        by_rank = np.argsort(rank, kind="stable")
        bounds = np.concatenate([[0], np.cumsum(np.bincount(rank))])
        for r in range(len(bounds) - 1):  # the r-th Bernoulli of every cell that has one
            sel = by_rank[bounds[r]:bounds[r + 1]]
            idx = col[sel]
            sub = dist[:, idx]
            _add_bernoulli(sub, p_sorted[sel])
            dist[:, idx] = sub
    p_last = np.full(len(own), p_default)
    if len(last_cells):
        p_last[np.searchsorted(own, last_cells)] = last_probs
    _add_bernoulli(dist, p_last)
    default = np.zeros((n_counts, 1))
    default[0] = 1.0
    _add_bernoulli(default, np.array([p_default]))
    return CellCounts(n_cells, own, dist.T.copy(), default[:, 0])


#: where :class:`CellField` finds the compiled kernels (a function returning their module
#: or None): :func:`use_field_kernels`; None until then (the numpy form)
_field_kernels: Callable[[], ModuleType | None] | None = None


def use_field_kernels(provider: Callable[[], ModuleType | None] | None) -> None:
    """Have :class:`CellField` merge with ``provider()``'s :func:`.grid_kernels.field_apply`
    whenever it returns the kernels (the same numbers as the numpy form).
    :mod:`.grid_backend` registers its ``compiled_grid_kernels`` when it is imported: it
    imports this module, so this one cannot import it."""
    global _field_kernels
    _field_kernels = provider


class CellField:
    """A value per cell (for example an undetected-target intensity) stored as one
    ``default`` shared by every cell plus the sorted ``cells`` whose ``values`` differ.

    Updates apply the same floating-point operations as the dense ``(n_cells,)`` array
    would, cell by cell, so :meth:`dense` equals that array bit for bit; a cell whose
    value becomes exactly the default again rejoins it. Memory and time
    ``O(cells with their own value)``: the cells touched so far (looked at), never the grid.
    """

    __slots__ = ("n_cells", "default", "cells", "values")

    def __init__(self, n_cells: int, default: float) -> None:
        self.n_cells = int(n_cells)
        self.default = float(default)
        self.cells = np.zeros(0, dtype=np.int64)
        self.values = np.zeros(0)

    def copy(self) -> CellField:
        """An independent copy (its own arrays)."""
        out = CellField(self.n_cells, self.default)
        out.cells, out.values = self.cells.copy(), self.values.copy()
        return out

    def affine(self, a: float, b: float) -> None:
        """``x <- a x + b`` in every cell (with the compiled backend in one pass,
        :func:`.grid_kernels.field_affine`: the same numbers)."""
        kernels = _field_kernels() if _field_kernels is not None else None
        if kernels is not None:
            self.default, self.cells, self.values = kernels.field_affine(
                float(self.default), self.cells, self.values, float(a), float(b))
            return
        self.default = a * self.default + b
        self.values = a * self.values + b
        self._rejoin()

    def multiply(self, cells: np.ndarray, factors: np.ndarray) -> None:
        """``x_c <- x_c * factor_c`` at the sorted unique ``cells``."""
        self._apply(np.multiply, cells, factors)

    def add(self, cells: np.ndarray, amounts: np.ndarray) -> None:
        """``x_c <- x_c + amount_c`` at the sorted unique ``cells``."""
        self._apply(np.add, cells, amounts)

    def _apply(self, op, cells: np.ndarray, operands: np.ndarray) -> None:
        """``x_c <- op(x_c, operand_c)`` at the sorted unique ``cells``: the cells that had
        the default are first inserted (sorted, with the default value: a memory move).
        With the compiled backend :func:`.grid_kernels.field_apply` merges them in one
        pass (the same numbers)."""
        cells = np.asarray(cells, dtype=np.int64).reshape(-1)
        if not len(cells):
            return
        kernels = _field_kernels() if _field_kernels is not None else None
        if kernels is not None:
            operands = np.ascontiguousarray(operands, dtype=float).reshape(-1)
            if len(operands) != len(cells):
                raise ValueError(f"{len(operands)} operands for {len(cells)} cells")
            self.cells, self.values = kernels.field_apply(
                self.default, self.cells, self.values, np.ascontiguousarray(cells), operands,
                op is np.add)
            return
        i = np.searchsorted(self.cells, cells)
        new = cells[(i == len(self.cells)) | (self.cells[np.minimum(i, len(self.cells) - 1)]
                                              != cells)] if len(self.cells) else cells
        if len(new):
            at = np.searchsorted(self.cells, new)
            self.cells = np.insert(self.cells, at, new)
            self.values = np.insert(self.values, at, self.default)
            i = np.searchsorted(self.cells, cells)
        self.values[i] = op(self.values[i], np.asarray(operands, dtype=float).reshape(-1))
        self._rejoin()

    def at(self, cells: np.ndarray) -> np.ndarray:
        """The values at ``cells`` (any order, repeats allowed)."""
        cells = np.asarray(cells, dtype=np.int64).reshape(-1)
        out = np.full(len(cells), self.default)
        if len(self.cells):
            i = np.minimum(np.searchsorted(self.cells, cells), len(self.cells) - 1)
            own = self.cells[i] == cells
            out[own] = self.values[i[own]]
        return out

    def dense(self) -> np.ndarray:
        """``(n_cells,)``: every cell's value (``O(cells)``: small grids, tests)."""
        out = np.full(self.n_cells, self.default)
        out[self.cells] = self.values
        return out

    def map(self, f) -> None:
        """``x <- f(x)`` in every cell, for an element-wise numpy function ``f`` (the same
        arithmetic as on the dense array)."""
        self.default = float(f(np.array([self.default]))[0])
        self.values = np.asarray(f(self.values), dtype=float)
        self._rejoin()

    def set(self, cells: np.ndarray, values: np.ndarray) -> None:
        """``x_c <- value_c`` at the unique ``cells`` (any order)."""
        cells = np.asarray(cells, dtype=np.int64).reshape(-1)
        if not len(cells):
            return
        values = np.broadcast_to(np.asarray(values, dtype=float), cells.shape)
        keep = ~np.isin(self.cells, cells, assume_unique=True)
        all_cells = np.concatenate([self.cells[keep], cells])
        order = np.argsort(all_cells, kind="stable")
        self.cells = all_cells[order]
        self.values = np.concatenate([self.values[keep], values])[order]
        self._rejoin()

    def total(self) -> float:
        """The sum over every cell."""
        return self.default * (self.n_cells - len(self.cells)) + float(self.values.sum())

    def _rejoin(self) -> None:
        same = self.values == self.default
        if np.any(same):
            self.cells, self.values = self.cells[~same], self.values[~same]


def untracked_probabilities(field: CellField) -> tuple[float, np.ndarray, np.ndarray]:
    """``P(at least one target) = 1 - exp(-lambda)`` of a Poisson intensity ``field``: the
    default cells' value, the own cells and theirs (:func:`bernoulli_cell_counts`'s
    ``last_*`` arguments), in one array operation as on the dense field."""
    p = -np.expm1(-np.concatenate([[field.default], field.values]))
    return float(p[0]), field.cells, p[1:]
