"""Marginal association probabilities by loopy belief propagation (Williams and Lau 2014).

The association problem of one step, between ``T`` tracks (Bernoullis) and ``J``
measurements (here: the looked cells that returned a detection), written as in
J. L. Williams and R. A. Lau, "Approximate evaluation of marginal association
probabilities with belief propagation", IEEE TAES 50(4), 2014 (arXiv:1209.6299):

* track ``i`` picks ``a_i`` in ``{0} u {j : edge (i, j)}`` with weight ``w_i0`` (not the
  source of any measurement: absent, or present and undetected) or ``w_ij`` (the source
  of ``j``);
* measurement ``j`` picks ``b_j`` in ``{0} u {i : edge (i, j)}`` with weight ``beta_j`` for
  ``b_j = 0`` (a false alarm or a target of the undetected Poisson process) and 1 for a
  track;
* the two must agree (``a_i = j`` iff ``b_j = i``), so a measurement has at most one
  track and a track at most one measurement. The joint law is
  ``P(a) ~ prod_i w_{i a_i} prod_{j unused} beta_j``.

The sum-product messages on the bipartite graph, one per edge ``e = (i, j)``
(Williams and Lau's message passing, in the normalised form ``w_i0``, ``beta_j``)::

    mu_{i->j} = w_ij / (w_i0 + sum_{j' != j} w_ij' nu_{j'->i})
    nu_{j->i} = 1 / (beta_j + sum_{i' != i} mu_{i'->j})

iterated from ``nu = 1 / beta`` until the largest relative change of ``nu`` is below
``tol``; the marginals are ``P(a_i = j) ~ w_ij nu_{j->i}``, ``P(a_i = 0) ~ w_i0`` and
``P(b_j = 0) ~ beta_j``, ``P(b_j = i) ~ mu_{i->j}``. On a tree-structured graph (no cycle)
the fixed point is exact; on a loopy one it is the Bethe approximation, and the
iteration converges (Williams and Lau prove it for this graph).

Clusters: the connected components of the edges are independent problems; the messages
of every cluster are iterated together as arrays over the edges (one ``bincount`` per
half-step), and a cluster whose messages have converged is left alone
(:func:`edge_clusters`). The "sum over the others" of each message is the node's total
minus the edge's own term (the vectorised form; Williams and Lau's implementation does
the same), which loses relative precision only when one term carries nearly all of a
total, at which point the message it feeds is dominated by that term anyway. The
difference is floored at the term every "others" sum contains (``w_i0`` for a track,
``beta_j`` for a measurement): where the subtraction cancels to nothing or below (a
detection whose likelihood ratio is ``1e30`` after many positive repeats of one cell),
the floor is the exact lower bound of the sum, not a division by a rounding residue.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

#: largest relative change of any message at which the iteration stops
LBP_TOL = 1e-12
#: at most this many iterations (a loopy cluster that has not converged by then keeps
#: its last messages; ``converged`` says so)
LBP_MAX_ITER = 500


@dataclass(frozen=True)
class Marginals:
    """Association marginals: ``p_missed (T,)`` = ``P(a_i = 0)``, ``p_edge (E,)`` =
    ``P(a_i = j)`` per edge, ``p_unused (J,)`` = ``P(b_j = 0)``; ``iterations`` run and
    whether every cluster ``converged``; ``cluster (E,)`` the cluster of each edge."""

    p_missed: np.ndarray
    p_edge: np.ndarray
    p_unused: np.ndarray
    iterations: int
    converged: bool
    cluster: np.ndarray


def edge_clusters(ei: np.ndarray, ej: np.ndarray, n_tracks: int, n_meas: int) -> np.ndarray:
    """The connected component of each edge ``(ei[e], ej[e])`` of the bipartite graph of
    ``n_tracks`` tracks and ``n_meas`` measurements (``scipy.sparse.csgraph``), ``(E,)``."""
    if len(ei) == 0:
        return np.zeros(0, dtype=np.int64)
    n = n_tracks + n_meas
    adj = coo_matrix((np.ones(len(ei)), (ei, n_tracks + ej)), shape=(n, n))
    _, label = connected_components(adj, directed=False)
    return label[ei].astype(np.int64)


def association_marginals(w_missed: np.ndarray, ei: np.ndarray, ej: np.ndarray,
                          w_edge: np.ndarray, beta: np.ndarray, *, tol: float = LBP_TOL,
                          max_iter: int = LBP_MAX_ITER) -> Marginals:
    """Marginal association probabilities by loopy belief propagation (module docstring).

    ``w_missed (T,)`` > 0: each track's weight of ``a_i = 0``; edges ``ei (E,)``,
    ``ej (E,)`` (track, measurement; each pair at most once) with weights
    ``w_edge (E,)`` >= 0; ``beta (J,)`` > 0: each measurement's weight of ``b_j = 0``.
    Returns :class:`Marginals`; a track without edges has ``p_missed = 1``, a measurement
    without edges ``p_unused = 1``.
    """
    w0 = np.asarray(w_missed, dtype=float)
    w = np.asarray(w_edge, dtype=float)
    beta = np.asarray(beta, dtype=float)
    ei = np.asarray(ei, dtype=np.int64)
    ej = np.asarray(ej, dtype=np.int64)
    T, J, E = len(w0), len(beta), len(w)
    cluster = edge_clusters(ei, ej, T, J)
    if E == 0:
        return Marginals(np.ones(T), np.zeros(0), np.ones(J), 0, True, cluster)
    n_clusters = int(cluster.max()) + 1
    nu = 1.0 / beta[ej]  # nu_{j->i}, started as if no other track claimed j
    active = np.ones(E, dtype=bool)
    it, converged = 0, False
    mu = np.zeros(E)
    for it in range(1, max_iter + 1):  # noqa: B007 - the count is reported
        # mu_{i->j} = w_ij / (w_i0 + sum_{j' != j} w_ij' nu_{j'->i})
        s_track = w0 + np.bincount(ei, weights=w * nu, minlength=T)
        mu = w / np.maximum(s_track[ei] - w * nu, w0[ei])
        # nu_{j->i} = 1 / (beta_j + sum_{i' != i} mu_{i'->j})
        s_meas = beta + np.bincount(ej, weights=mu, minlength=J)
        new_nu = 1.0 / np.maximum(s_meas[ej] - mu, beta[ej])
        change = np.abs(new_nu - nu) / np.maximum(new_nu, 1e-300)
        nu = np.where(active, new_nu, nu)
        worst = np.zeros(n_clusters)
        np.maximum.at(worst, cluster, np.where(active, change, 0.0))
        active = worst[cluster] > tol
        if not active.any():
            converged = True
            break
    # marginals from the final messages (mu recomputed from the final nu)
    s_track = w0 + np.bincount(ei, weights=w * nu, minlength=T)
    p_edge = w * nu / s_track[ei]
    p_missed = w0 / s_track
    mu = w / np.maximum(s_track[ei] - w * nu, w0[ei])
    s_meas = beta + np.bincount(ej, weights=mu, minlength=J)
    p_unused = beta / s_meas
    return Marginals(p_missed, p_edge, p_unused, it, converged, cluster)
