"""What the particles say: the count posterior, the state estimates (alignment of the
particles' targets, Kreucher's K-means over permutations) and the per-cell count
distribution ``P_c(t)`` (rows for the occupied cells only).

Estimates: the count is the posterior mode of ``T``; the states are weighted means of
the targets of the particles with ``T = mode`` after aligning each particle's targets to
a reference (the previous estimate predicted with ``F`` when it has the same count,
else the heaviest such particle), two rounds of align-then-average. Alignment minimises
the summed squared position distance: exactly over all ``T!`` permutations for
``T <= EXACT_ALIGN_MAX``, greedily (closest pair first) above.

Labels: the estimate's row ``b`` (the sorted, aligned slot) is labelled ``b``. While the
count mode is unchanged the rows are aligned to the previous estimate, so a label follows
its target; when the mode changes the reference is the heaviest particle and the rows
are re-numbered ``0..mode-1`` from it, so labels are only stable between count changes
(a re-numbering reads as identity switches in the track-level scores).
"""

from __future__ import annotations

import itertools
from typing import NamedTuple

import numpy as np

from ..base import Estimate
from ..cells import CellCounts
from .sparse import CellIndex, unique_cells

EXACT_ALIGN_MAX = 4  # enumerate all T! permutations up to this many targets


# ------------------------------------------------------------------ alignment
_PERMS: dict[int, np.ndarray] = {}


def _perms(n: int) -> np.ndarray:
    if n not in _PERMS:
        _PERMS[n] = np.array(list(itertools.permutations(range(n))), dtype=np.int64)
    return _PERMS[n]


def greedy_assignment(cost: np.ndarray) -> np.ndarray:
    """Greedy (closest pair first) assignment, vectorised over the leading axis.

    ``cost (n, a, b)`` with ``inf`` for forbidden pairs. Returns ``(n, b)`` int64:
    the row assigned to each column, ``-1`` where none is left.
    """
    cost = cost.copy()
    n, a, b = cost.shape
    out = np.full((n, b), -1, dtype=np.int64)
    rows = np.arange(n)
    for _ in range(min(a, b)):
        flat = cost.reshape(n, -1).argmin(axis=1)
        i, j = np.divmod(flat, b)
        ok = np.isfinite(cost[rows, i, j])
        out[rows[ok], j[ok]] = i[ok]
        cost[rows[ok], i[ok], :] = np.inf
        cost[rows[ok], :, j[ok]] = np.inf
    return out


def align_square(Y: np.ndarray, ref: np.ndarray) -> np.ndarray:
    """Reorder each particle's targets to match ``ref``.

    ``Y (n, R, 4)`` all valid, ``ref (R, 4)``; returns ``(n, R, 4)`` with row ``b``
    the target matched to ``ref[b]``, minimising ``sum_b |pos(Y[pi(b)]) - pos(ref_b)|^2``
    over permutations: exhaustively for ``R <= EXACT_ALIGN_MAX``, greedily above.
    """
    n, R, _ = Y.shape
    if R <= 1:
        return Y
    d = Y[:, :, None, [0, 2]] - ref[None, None, :, [0, 2]]
    cost = np.einsum("nabk,nabk->nab", d, d)  # (n, R targets, R refs)
    if R <= EXACT_ALIGN_MAX:
        perms = _perms(R)  # (P, R): perms[q, b] = target placed at ref b
        total = cost[:, perms, np.arange(R)].sum(axis=2)  # (n, P)
        order = perms[total.argmin(axis=1)]
    else:
        order = greedy_assignment(cost)
    return np.take_along_axis(Y, order[:, :, None], axis=1)


def align_slots(X: np.ndarray, valid: np.ndarray, cells: np.ndarray, reference: np.ndarray
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Permute every particle's slots so that slot ``b`` holds its target nearest
    (greedy, :func:`greedy_assignment`) to reference target ``b``; unmatched targets
    follow, then empty slots.

    ``X (4, t_max, N)`` component-major states, ``valid (t_max, N)``, ``cells (t_max,
    N)`` (any per-slot array that moves with the targets), ``reference (R, 4)``.
    Returns the permuted ``(X, valid, cells)`` as new arrays; the inputs themselves when
    ``reference`` is empty.
    """
    if len(reference) == 0:
        return X, valid, cells
    T, N = valid.shape
    R = min(len(reference), T)
    dx = X[0][:, :, None] - reference[None, None, :R, 0]  # (T, N, R)
    dy = X[2][:, :, None] - reference[None, None, :R, 2]
    cost = dx * dx + dy * dy
    cost[~valid] = np.inf
    assign = greedy_assignment(cost.transpose(1, 0, 2))  # (N, R): old slot per ref
    matched = assign >= 0
    rows = np.arange(N)
    is_matched = np.zeros((N, T), dtype=bool)  # by old slot
    is_matched[rows[:, None].repeat(R, 1)[matched], assign[matched]] = True
    # old slots not matched: leftover targets first, then empty slots (stable)
    key = np.where(is_matched, 2, np.where(valid.T, 0, 1))
    rest_old = np.argsort(key, axis=1, kind="stable")
    used_new = np.zeros((N, T), dtype=bool)
    used_new[:, :R] = matched
    free_new = np.argsort(used_new, axis=1, kind="stable")  # free positions first
    # Leftover targets exist only when every reference is matched, so the free
    # positions are then exactly R..T-1 and the leftovers come right after the
    # matched slots; the pairs beyond the free ones are overwritten below.
    perm = np.empty((N, T), dtype=np.int64)  # perm[i, new slot] = old slot
    np.put_along_axis(perm, free_new, rest_old, axis=1)
    perm[:, :R] = np.where(matched, assign, perm[:, :R])
    pT = perm.T
    return (np.take_along_axis(X, pT[None], axis=1), np.take_along_axis(valid, pT, axis=0),
            np.take_along_axis(cells, pT, axis=0))


# ------------------------------------------------------------------ estimates
class Estimation(NamedTuple):
    """The output of :func:`estimate_targets`."""

    estimate: Estimate
    #: the estimated states ``(mode, 4)`` (a copy): the next step's reference
    reference: np.ndarray
    #: ``p(T = t)``, ``t = 0..t_max``
    count_probabilities: np.ndarray
    count_mean: float


def estimate_targets(X: np.ndarray, valid: np.ndarray, counts: np.ndarray, w: np.ndarray,
                     reference: np.ndarray | None) -> Estimation:
    """Count posterior and state estimate (module docstring) of particles ``X (4, t_max,
    N)``, ``valid (t_max, N)``, ``counts (N,)``, normalised weights ``w (N,)``;
    ``reference`` the previous estimate predicted to this step (None: none yet)."""
    T = valid.shape[0]
    pT = np.bincount(counts, weights=w, minlength=T + 1)
    pT /= pT.sum()
    count_mean = float(np.dot(np.arange(T + 1), pT))
    mode = int(np.argmax(pT))
    if mode == 0:
        return Estimation(Estimate(0, np.zeros((0, 4)), np.zeros((0, 4, 4)),
                                   np.zeros(0, np.int64)),
                          np.zeros((0, 4)), pT, count_mean)
    sel = np.flatnonzero(counts == mode)
    ws = w[sel] / w[sel].sum()
    order = np.argsort(~valid[:, sel], axis=0, kind="stable")[:mode]  # (mode, n)
    Xs = X[:, :, sel]  # (4, T, n)
    Y = np.take_along_axis(Xs, order[None], axis=1).transpose(2, 1, 0)  # (n, mode, 4)
    if reference is not None and len(reference) == mode:
        ref = reference
    else:
        ref = Y[np.argmax(ws)]
    for _ in range(2):  # align, average, realign (K-means over permutations)
        Ya = align_square(Y, ref)
        ref = np.einsum("n,ntd->td", ws, Ya)
    d = Ya - ref[None]
    cov = np.einsum("n,ntd,nte->tde", ws, d, d)
    # labels: the aligned slot index (row of ``ref``)
    return Estimation(Estimate(mode, ref.astype(np.float64), cov, np.arange(mode, dtype=np.int64)),
                      ref.copy(), pT, count_mean)


# ------------------------------------------------------------------------- P_c
def _ranks(c: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For ``c (t_max, N)``: ``rank[j, i] = 1 + #{k < j : c[k, i] == c[j, i]}`` and
    ``count[j, i] = #{k : c[k, i] == c[j, i]}``, from a stable sort of each column (runs of
    equal cells): ``O(N t_max log t_max)``."""
    t_max = c.shape[0]
    order = np.argsort(c, axis=0, kind="stable")
    s = np.take_along_axis(c, order, axis=0)
    idx = np.broadcast_to(np.arange(t_max)[:, None], c.shape)
    start = np.ones(c.shape, dtype=bool)
    start[1:] = s[1:] != s[:-1]
    end = np.ones(c.shape, dtype=bool)
    end[:-1] = start[1:]
    first = np.maximum.accumulate(np.where(start, idx, 0), axis=0)
    last = np.minimum.accumulate(np.where(end, idx, t_max)[::-1], axis=0)[::-1]
    rank, count = np.empty(c.shape, dtype=np.int64), np.empty(c.shape, dtype=np.int64)
    np.put_along_axis(rank, order, idx - first + 1, axis=0)
    np.put_along_axis(count, order, last - first + 1, axis=0)
    return rank, count


def cell_count_distribution_from(cells: np.ndarray, weights: np.ndarray, n_cells: int,
                                 n_counts: int) -> CellCounts:
    """``P_c(t) = sum_i w_i [T_ic = t]`` (last column "t or more") as
    :class:`~..cells.CellCounts`: a row for every cell some particle's target occupies,
    the default row ``(1, 0, ..., 0)`` (no target) for every other cell.

    ``cells (N, t_max)`` as in :func:`grid_log_likelihood`, ``weights (N,)``
    normalised. Only occupied (particle, cell) pairs are visited: the first target
    of each cell in a particle carries the particle's count in that cell; the mass
    not accounted for goes to ``t = 0``. ``O(N t_max log t_max)`` (the in-particle
    counts) plus :func:`.sparse.unique_cells`; nothing per cell of the grid. ``dense()`` equals the
    ``(n_cells, n_counts)`` array of the former dense computation bit for bit: each
    occupied cell's bins receive the same weights in the same order.
    """
    c = cells.T
    rank, n_in = _ranks(c)
    first = rank == 1
    keep = first & (c < n_cells)
    slot, particle = np.nonzero(keep)
    held = c[slot, particle]
    occupied = unique_cells(held, n_cells)
    row = CellIndex(occupied, n_cells)(held)
    key = row.astype(np.int64) * n_counts + np.minimum(n_in[slot, particle], n_counts - 1)
    P = np.bincount(key, weights=weights[particle], minlength=len(occupied) * n_counts)
    P = P.reshape(len(occupied), n_counts).astype(np.float64, copy=False)  # int when empty
    P[:, 0] = np.maximum(1.0 - P[:, 1:].sum(axis=1), 0.0)
    P /= P.sum(axis=1, keepdims=True)
    return CellCounts(n_cells, occupied, P, np.eye(n_counts)[0])
