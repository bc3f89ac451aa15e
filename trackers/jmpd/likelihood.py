"""This step's measurement likelihood ``log p(z_k | X_i)`` of every particle.

Grid sensor (:func:`grid_log_likelihood`): only looked-at cells that a particle
occupies contribute, ``sum_looks log l_c(T_ic)`` with ``T_ic`` the particle's number
of targets in cell ``c`` and ``l_c(T) = p(z | T) / p(z | 0)``; repeated looks at a cell
add their logs (tables from :func:`grid_log_likelihood_tables`). Superposition sensor
(:func:`superposition_log_likelihood`): ``z ~ N(mean_i H x_i, R)``, and ``z ~ N(0, R)``
for a particle with no target (the simulator's convention).

:func:`step_likelihood` wraps one step's measurement as a function of any particles
(the update evaluates it; the IP proposal uses its single-target factors).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np

from ...scenarios.model import Looks, RayleighGridSensor, Sensor
from ..cells import look_log_ratios
from .backend import compiled_kernels
from .sparse import CellIndex


def grid_log_likelihood_tables(sensor: RayleighGridSensor, look_cells: np.ndarray,
                               returns: np.ndarray, n_cells: int, t_max: int
                               ) -> tuple[CellIndex, np.ndarray]:
    """Per-look tables for :func:`grid_log_likelihood`, ``O(looks)`` (never ``O(cells)``).

    Returns ``index`` (:class:`.sparse.CellIndex` over the sorted unique looked cells:
    ``index(cells)`` is each cell's row of ``table``, ``n_u`` for an unlooked cell or
    the sentinel ``n_cells``) and ``table (n_u + 1, t_max + 1)`` with ``table[s, t] =
    sum_{looks at cell s} log l(z, t)``; its last row is zero.
    """
    ucells, LL = look_log_ratios(sensor, np.asarray(look_cells, dtype=np.int64),
                                 np.asarray(returns, bool), t_max)
    table = np.vstack([LL, np.zeros((1, t_max + 1))])  # the zero row of unlooked cells
    return CellIndex(ucells, n_cells), table


_NO_MASK = np.ones((1, 1), dtype=bool)  # the kernel's unread mask when there is none


def grid_log_likelihood(cells: np.ndarray, index: CellIndex, table: np.ndarray,
                        valid: np.ndarray | None = None,
                        key_buffer: np.ndarray | None = None,
                        path: Literal["auto", "dense", "sparse"] = "auto"
                        ) -> np.ndarray:
    """``log p(z | X_i) - log p(z | no target)`` for every particle, shape ``(N,)``.

    ``cells (N, t_max)`` (integers) are the targets' flat cells, with ``n_cells`` for an
    empty slot or a target outside the grid; ``index`` and ``table`` from
    :func:`grid_log_likelihood_tables`. If ``valid (N, t_max)`` bool is given, the
    slots where it is False are empty whatever their cell (it may then be any index
    in ``[0, n_cells]``, or beyond it, which counts as unlooked). ``key_buffer``:
    optional int32 scratch ``(t_max, N)`` for the dense path (saves allocating it).
    ``path`` forces one numpy computation (for tests). "auto": the dense path compiled
    (:func:`.kernels.grid_log_likelihood_dense`) when :func:`.backend.compiled_kernels`
    has it, else dense or sparse chosen by cost. Equation::

        log w_i = sum_{looked cells c} table[c, T_ic]

    computed without counting cells: the ``j``-th target (in slot order) found in
    cell ``c`` adds ``table[c, j] - table[c, j - 1]``, which telescopes to
    ``table[c, T_ic]`` because ``table[c, 0] = 0``. Each particle's terms are added
    in slot order, starting from 0 (both code paths below; results are identical).

    Every slot's cell is first replaced by its row ``r = index(c)`` of the table
    (``n_u`` for an unlooked cell), so the work is ``O(N t_max^2 + looks)`` whatever the
    grid's size. Slots are told apart by their rows: two looked slots share a row iff
    they share a cell, and unlooked slots (which share the row ``n_u``) add the zero
    row's entries, 0.0, whatever their rank.
    """
    c = cells.T  # (t_max, N); contiguous rows when the caller stores (t_max, N)
    v = None if valid is None else valid.T
    t_max, n = c.shape
    n_counts = table.shape[1]
    n_u = table.shape[0] - 1
    increments = np.zeros_like(table)
    increments[:, 1:] = np.diff(table, axis=1)
    inc = increments.ravel()
    rows = index(c)  # (t_max, N) int32, rows of the table
    kernels = compiled_kernels() if path == "auto" else None
    if path == "auto" and kernels is None:
        # choose on a sample of particles (the choice never changes the result); measured
        # crossover: the sparse path wins below about 5% of the slots looked at
        n_sample = min(n, 4096)  # contiguous, so cheap
        hit = rows[:, :n_sample] != n_u
        if v is not None:
            hit &= v[:, :n_sample]
        path = "dense" if 20 * int(np.count_nonzero(hit)) > hit.size else "sparse"
    if path != "sparse":
        # dense (particles gathered on looked cells): one gather per slot from the
        # table of increments with the key r * n_counts + k and k = 1 + #{j' < j: same
        # row} (0 for an empty slot: column 0 is zero); int32 keys when they fit
        key_type = np.int32 if inc.size < 2**31 else np.int64
        if key_buffer is not None and key_buffer.dtype == key_type:
            key = key_buffer
        else:
            key = np.empty((t_max, n), key_type)
        if kernels is not None and key_type is np.int32:  # the same steps, fused
            total = np.empty(n)
            kernels.grid_log_likelihood_dense(
                rows, _NO_MASK if v is None else v, v is not None, inc, n_counts, key,
                np.empty(n, dtype=np.int32), total)
            return total
        np.multiply(rows, n_counts, out=key, dtype=key_type, casting="unsafe")
        if v is not None:
            key += v
        else:
            key += 1
        # before slot j gets its rank, key[k] == key[j] (k < j) says same row and
        # same validity; going down j, the slots k < j are not ranked yet
        same = np.empty(n, dtype=bool)
        count = np.empty(n, dtype=np.uint8 if t_max < 256 else np.int64)
        for j in range(t_max - 1, 0, -1):
            count.fill(0)
            for k in range(j):
                np.equal(key[k], key[j], out=same)
                count += same
            if v is not None:
                count *= v[j]  # an empty slot keeps rank 0
            key[j] += count
        # log w = ((val[0] + val[1]) + val[2]) + ..., row by row (the order of
        # val.sum(axis=0)) so that each gathered row is added while in cache
        total = np.take(inc, key[0], mode="clip")
        row = np.empty(n)
        for j in range(1, t_max):
            total += np.take(inc, key[j], mode="clip", out=row)
        return total
    # sparse (few slots in looked cells): work on the looked slots alone, in
    # slot-major order (the order of the sums above)
    hit = rows != n_u  # (t_max, N), C order
    if v is not None:
        hit &= v
    j, i = np.divmod(np.flatnonzero(hit), n)
    rj = rows[j, i]
    rank = np.ones(j.shape[0], dtype=np.int64)
    for k in range(t_max - 1):
        same = (rows[k].take(i) == rj) & (k < j)
        if v is not None:
            same &= v[k].take(i)
        rank += same
    contrib = inc[rj * n_counts + rank]
    # an empty weighted bincount comes back as int64: force float
    return np.bincount(i, weights=contrib, minlength=n).astype(np.float64, copy=False)


def superposition_log_likelihood(X: np.ndarray, valid: np.ndarray, z: np.ndarray,
                                 H: np.ndarray, R: np.ndarray) -> np.ndarray:
    """``log N(z; mean_{valid j} H x_j, R)`` up to a constant, shape ``(N,)``.

    ``X (N, t_max, 4)``, ``valid (N, t_max)``; the mean is 0 for a particle with no
    target (the sensor then reports pure noise).
    """
    count = valid.sum(axis=1)
    hx = np.einsum("ntd,md->ntm", X, H)
    mean = (hx * valid[..., None]).sum(axis=1) / np.maximum(count, 1)[:, None]
    r = z[None, :] - mean
    return -0.5 * np.einsum("nm,nm->n", r, np.linalg.solve(R, r.T).T)


@dataclass(frozen=True)
class GridLikelihood:
    """One step's looks on the grid sensor: the tables of :func:`grid_log_likelihood`."""

    index: CellIndex
    table: np.ndarray

    def __call__(self, X: np.ndarray, valid: np.ndarray, cells: np.ndarray,
                 key_buffer: np.ndarray | None = None) -> np.ndarray:
        """``log p(z | X_i)`` up to a constant, ``(N,)``, of states ``X (4, t_max, N)``
        (component-major) with validity ``valid (t_max, N)`` and the flat cell of every
        slot ``cells (t_max, N)`` (any index in empty slots)."""
        return grid_log_likelihood(cells.T, self.index, self.table, valid.T,
                                   key_buffer=key_buffer)

    def single_target(self, cells: np.ndarray) -> np.ndarray:
        """``log l_c(1)`` summed over the looks at each cell of ``cells`` (any shape): the
        log-likelihood of a target alone (junk for an index beyond the grid)."""
        return self.table[:, 1][self.index(cells)]


@dataclass(frozen=True)
class SuperpositionLikelihood:
    """One step's measurement ``z`` of the superposition sensor ``(H, R)``."""

    z: np.ndarray
    H: np.ndarray
    R: np.ndarray

    def __call__(self, X: np.ndarray, valid: np.ndarray, cells: np.ndarray | None = None,
                 key_buffer: np.ndarray | None = None) -> np.ndarray:
        """As :meth:`GridLikelihood.__call__` (``cells`` and ``key_buffer`` unused)."""
        return superposition_log_likelihood(X.transpose(2, 1, 0), valid.T, self.z, self.H,
                                            self.R)


def step_likelihood(sensor: Sensor, looks: Looks, n_cells: int, t_max: int
                    ) -> GridLikelihood | SuperpositionLikelihood | None:
    """The likelihood of one step's ``looks``; None when they hold no measurement (no
    look on the grid, no ``z`` on the superposition sensor)."""
    if isinstance(sensor, RayleighGridSensor):
        if len(looks) == 0:
            return None
        return GridLikelihood(*grid_log_likelihood_tables(sensor, looks.cells, looks.returns,
                                                          n_cells, t_max))
    if looks.z is None:
        return None
    return SuperpositionLikelihood(np.asarray(looks.z), sensor.H, sensor.R)
