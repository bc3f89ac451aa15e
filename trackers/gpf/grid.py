"""GPF kernels for the Rayleigh grid sensor (this project's reading of the paper).

The grid likelihood is piecewise constant in a target's position: a look at cell ``c``
only cares whether the target is in ``c``. So a particle ``{w, N(mu, Sigma)}`` has, per
looked cell ``c``, a prior mass ``m_c = P(position in c)`` and the moments of the Gaussian
truncated to ``c``; everything outside the looked cells is one more bin "elsewhere" with
mass ``m_out = 1 - sum_c m_c`` and likelihood ratio 1.

Single particle (no other particle shares its looked cells), with
``l_c = prod_{looks at c} p(z | 1) / p(z | 0)``::

    L     = m_out + sum_c m_c l_c
    w'    = w L / (w L + 1 - w)                        (exact Bernoulli update)
    p(x | exists, z) = N(x; mu, Sigma) g(x) / L,  g = l_c in cell c, 1 elsewhere

and the posterior Gaussian is the moment match of that density (law of total covariance over
the bins). Clusters of particles that share a looked cell that returned a detection (each
with occupancy probability above ``interaction_threshold``, prior ``w m_c`` or posterior
as if alone ``w m_c l_c / (w L + 1 - w)``: a particle updated apart credits the
detection to itself alone, and at ``l_c(1) = p_d / p_f = 2.7e4`` a tail of ``3e-6`` in
a neighbour's detected cell moved 16% of it there, docs/gpf.md section 14; connected components
of the particle -- cell graph, so the cost grows with the cluster sizes, never with
``2^K``) are updated by enumerating combinations: every particle of the cluster picks one
option -- absent (prior ``1 - w``), elsewhere (``w m_out``), "missed" (below) or detected
cell ``c`` (``w m_c``) -- the paper's ``E`` refined by the cell, which the grid needs
because ``p_d(T)`` depends on the in-cell count ``T``. The combination likelihood is
``prod_c l_c(T_c)``; combinations with posterior probability ``<= epsilon`` (or beyond
``max_combinations``) are dropped and the rest renormalised, and the dropped mass is
reported. Particle ``i``'s posterior is then ``w_i' = P(i present | z)`` and, given
presence, bin ``b`` with probability ``pi_b``, i.e. density ratio ``g_b = pi_b / m_b``.

Truncated moments: the position density is written ``p(px) p(py | px)`` (exact for any
covariance); the ``py`` integral over ``[y0, y1)`` is closed form and the ``px`` integral is
Gauss-Legendre over the cell's x-range clipped to ``mu_x +- 7 sigma_x``, 8 to 24 nodes by
the integrand's difficulty (:func:`rect_position_moments`; as accurate as 24 nodes
everywhere: mass error ~1e-11 for ``sigma_x >= 0.1`` cell; below that, with a wide,
strongly correlated ``py``, up to 2e-5 for ``sigma_x >= 0.08`` and 2e-3 at
``sigma_x = 0.056``; docs/gpf.md). Velocities follow from the linear regression on position,
``v = m_v + B (p - m_p) + e``, ``B = S_vp S_pp^-1``, ``e ~ N(0, S_vv - B S_pv)`` independent
of ``p``; the moment match is linear in the cells' position moments, so a row's cells are
summed first and lifted to the full state once (:func:`lift_to_state`).

Missed cells (a deviation from the paper): members of a cluster interact only through
looked cells that returned a detection, and each member's looked cells without a
detection are one option "missed" with likelihood ``sum_c m_c l_c(1)``, as if no two
targets shared such a cell (``l(1)^2`` for ``l(2)``: 0.25 against 0.305 at ``p_d = 0.5``,
``snr = 10``). Every option is tilted by its own likelihood, ``q_o ~ p_o l_o(1)``, and the
combinations are weighed by the coupling ``LL[c, T] - T LL[c, 1]`` of the detected cells.
The cut ``epsilon`` acts on the combinations' normalised posterior (a deviation from the
paper, which cuts on the prior): a broad particle's options are not each below
``epsilon``, so the combinations in which two broad particles both explain detections
survive the cut (docs/gpf.md section 9); and the combinations with a member absent,
which the tilt alone makes look improbable whenever another member explains the same
detection (``l(1) = 2.7e4`` at ``p_f = 2.2e-5``), survive where their posterior is
above ``epsilon`` (cut on the tilted prior they went, and every member's weight became
exactly 1: docs/gpf.md section 13). Small clusters list every combination; a larger one
lists the ``max_combinations`` of largest approximate posterior (the product of each
member's belief, its tilted options weighed by the coupling expected from the others,
:func:`_option_beliefs`) before the cut; ranked by the tilted prior the list filled with
combinations of several members in one detected cell and left the likely ones out
(docs/gpf.md section 14).

JPDA* (:func:`avoid_coalescence`, Blom and Bloem 2000): of the combinations that differ
only by which members took which detected cells, only the most probable is kept, so that
two tracks that could swap their detections do not both move to the blend of them.

Components (the tracker's ``max_components > 1``): a track may carry a mixture of Gaussian
rows (``owner``, ``alpha``); its mass in a cell is the mixture's, the combinatorics run on
tracks, and each row is moment matched under its track's ``g``. With ``split_share``, the
part of a row in a detected cell whose posterior share of the track reaches ``split_share``
becomes a component of its own (the row's Gaussian truncated to the cell), so a track that
may have made a far detection keeps that mode instead of a broad blend.

"Uniform" particles (the tracker's birth candidates) have all their mass in one cell and
are treated as uniform there: they take part in the likelihood like any particle, and
their posterior given existence is unchanged (it stays uniform on the cell). In a cell that
returned a detection they always join the cluster of the particles that occupy it; in a
cell without a detection only by the usual occupancy threshold.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np
from scipy.special import ndtr

from ...scenarios.model import Grid, RayleighGridSensor
from .. import kalman
from ..cells import look_log_ratios
from ..grid_backend import compiled_gpf_kernels, compiled_grid_kernels, looked_in_boxes
from .linear import _BLOCK, enumerate_combinations

_RANGE_SIGMAS = 7.0
_INV_SQRT_2PI = 1.0 / np.sqrt(2.0 * np.pi)
#: Gauss-Legendre orders by difficulty ``D`` (see :func:`rect_position_moments`): the
#: first order whose bound exceeds ``D``; the last (24) for everything harder
_GL_ORDERS = ((1.0, 8), (2.0, 12), (4.0, 16), (6.0, 20), (math.inf, 24))
_GL_RULES = {q: np.polynomial.legendre.leggauss(q) for _, q in _GL_ORDERS}


_GL_TABLE: dict[tuple[int, int], tuple[np.ndarray, ...]] = {}


def _gl_table() -> tuple[np.ndarray, ...]:
    """``_GL_ORDERS`` and ``_GL_RULES`` as the kernel's arrays: difficulty bounds, nodes
    per rule, each rule's first node, then all nodes and all weights."""
    key = (id(_GL_ORDERS), id(_GL_RULES))
    if key not in _GL_TABLE:
        rules = [_GL_RULES[q] for _, q in _GL_ORDERS]
        counts = np.array([len(r[0]) for r in rules], dtype=np.int64)
        _GL_TABLE.clear()
        _GL_TABLE[key] = (np.array([b for b, _ in _GL_ORDERS], dtype=float), counts,
                          np.cumsum(counts) - counts,
                          np.concatenate([r[0] for r in rules]),
                          np.concatenate([r[1] for r in rules]))
    return _GL_TABLE[key]


def _phi(t: np.ndarray) -> np.ndarray:
    return _INV_SQRT_2PI * np.exp(-0.5 * t * t)


def rect_position_moments(mean_xy: np.ndarray, cov_xy: np.ndarray, x0: np.ndarray,
                          x1: np.ndarray, y0: np.ndarray, y1: np.ndarray
                          ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Zeroth, first and second centred moments of ``N(mean, cov)`` on rectangles.

    For ``N`` pairs: ``mean_xy (N, 2)``, ``cov_xy (N, 2, 2)``, edges ``(N,)`` each. Returns
    ``mass (N,) = int_rect N``, ``m1 (N, 2) = int_rect (p - mean) N`` and
    ``m2 (N, 2, 2) = int_rect (p - mean)(p - mean)^T N``. With ``u = px - mx``,
    ``k = cxy / cxx``, ``s^2 = cyy - cxy^2 / cxx`` and ``py - my = k u + s t``, the inner
    integrals over ``t in [alpha, beta]`` are ``Phi(beta) - Phi(alpha)``,
    ``phi(alpha) - phi(beta)`` and ``Phi(beta) - Phi(alpha) + alpha phi(alpha) - beta phi(beta)``
    (first three moments of the standard normal); the outer one is Gauss-Legendre over the
    x-range ``[lo, hi]`` clipped to ``+- 7 sigma_x``. Its order follows the integrand's
    difficulty ``D = max(L / sigma_x, |k| L / s)``, ``L = hi - lo`` (the range in the outer
    Gaussian's sds and the inner bounds' travel in ``t``): 8 nodes for ``D < 1``, 12, 16, 20
    below 2, 4, 6, else 24 (each within ~1e-13 of a 96-node rule on its range; docs/gpf.md
    section 10). A broad Gaussian on a cell, the common case, takes 8. With the compiled
    backend (:mod:`.grid_backend`) :func:`.grid_kernels.rect_position_moments` computes
    the same numbers, bit for bit.
    """
    kernels = compiled_grid_kernels()
    if kernels is not None:
        return kernels.rect_position_moments(
            np.ascontiguousarray(mean_xy, dtype=float), np.ascontiguousarray(cov_xy, dtype=float),
            *(np.ascontiguousarray(e, dtype=float) for e in (x0, x1, y0, y1)), *_gl_table())
    mx, my = mean_xy[:, 0], mean_xy[:, 1]
    a = np.maximum(cov_xy[:, 0, 0], 1e-300)
    c = cov_xy[:, 0, 1]
    sx = np.sqrt(a)
    k = c / a
    s = np.sqrt(np.maximum(cov_xy[:, 1, 1] - c * k, 1e-24))
    lo = np.maximum(x0 - mx, -_RANGE_SIGMAS * sx)
    hi = np.minimum(x1 - mx, _RANGE_SIGMAS * sx)
    half = 0.5 * np.maximum(hi - lo, 0.0)
    n = len(mx)
    mass, m1, m2 = np.empty(n), np.empty((n, 2)), np.empty((n, 2, 2))
    difficulty = 2.0 * half * np.maximum(1.0 / sx, np.abs(k) / s)
    order = np.searchsorted(np.array([b for b, _ in _GL_ORDERS]), difficulty, side="right")
    for i in np.unique(order):
        sel = np.nonzero(order == i)[0]
        nodes, weights = _GL_RULES[_GL_ORDERS[i][1]]
        mass[sel], m1[sel], m2[sel] = _gl_moments(
            nodes, weights, mx[sel], my[sel], sx[sel], k[sel], s[sel], lo[sel], half[sel],
            y0[sel], y1[sel])
    return mass, m1, m2


def _gl_moments(nodes: np.ndarray, weights: np.ndarray, mx: np.ndarray, my: np.ndarray,
                sx: np.ndarray, k: np.ndarray, s: np.ndarray, lo: np.ndarray,
                half: np.ndarray, y0: np.ndarray, y1: np.ndarray
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`rect_position_moments` with one Gauss-Legendre rule for every pair."""
    u = (lo + half)[:, None] + half[:, None] * nodes[None, :]  # (N, Q)
    wq = weights[None, :] * (half / sx)[:, None] * _phi(u / sx[:, None])
    ku = k[:, None] * u
    sc = s[:, None]
    al = ((y0 - my)[:, None] - ku) / sc  # finite (s >= 1e-12): phi and ndtr saturate
    be = ((y1 - my)[:, None] - ku) / sc
    i0 = ndtr(be) - ndtr(al)
    pa, pb = _phi(al), _phi(be)
    j1 = pa - pb
    j2 = i0 + al * pa - be * pb
    ey = ku * i0 + sc * j1  # int (py - my) over the y-range
    eyy = ku * ey + sc * (ku * j1 + sc * j2)
    wi = wq * i0
    wu = wq * u
    m2 = np.empty((len(mx), 2, 2))
    m2[:, 0, 0] = np.einsum("nq,nq->n", wu * u, i0)
    m2[:, 0, 1] = m2[:, 1, 0] = np.einsum("nq,nq->n", wu, ey)
    m2[:, 1, 1] = np.einsum("nq,nq->n", wq, eyy)
    m1 = np.stack([np.einsum("nq,nq->n", wu, i0), np.einsum("nq,nq->n", wq, ey)], axis=-1)
    return wi.sum(axis=1), m1, m2


def sorted_runs(key: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``np.unique(key, return_inverse=True, return_counts=True)`` of a non-decreasing int
    array ``key``: its distinct values, the run each entry is in, each run's length (the
    same arrays in a quarter of ``np.unique``'s time, which sorts again)."""
    n = len(key)
    new = np.empty(n, dtype=bool)
    new[:1] = True
    np.not_equal(key[1:], key[:-1], out=new[1:])
    starts = new.nonzero()[0]
    counts = np.empty(len(starts), dtype=np.int64)
    np.subtract(starts[1:], starts[:-1], out=counts[:-1])
    counts[-1:] = n - starts[-1:]
    return key[starts], np.arange(len(starts)).repeat(counts), counts


def position_regression(covs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per Gaussian ``covs (K, 4, 4)``: the regression of velocity on position,
    ``v - m_v = B (p - m_p) + e``: ``B = S_vp S_pp^-1 (K, 2, 2)`` (closed-form 2x2 inverse)
    and the residual covariance ``S_vv - B S_pv (K, 2, 2)``."""
    Svp = covs[:, 1::2, 0::2]  # positions are state entries 0, 2; velocities 1, 3
    kernels = compiled_gpf_kernels()
    inv = (kalman.inverse(covs[:, 0::2, 0::2]) if kernels is None
           else kernels.position_inverse(np.ascontiguousarray(covs, dtype=float)))
    B = Svp @ inv
    return B, covs[:, 1::2, 1::2] - B @ np.swapaxes(Svp, -1, -2)


def lift_to_state(B: np.ndarray, resid: np.ndarray, mass: np.ndarray, m1: np.ndarray,
                  m2: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Full-state moments ``M1 (N, 4)``, ``M2 (N, 4, 4)`` from position moments ``mass (N,)``,
    ``m1 (N, 2)``, ``m2 (N, 2, 2)`` of a Gaussian with regression ``B``, ``resid`` (rows
    aligned): ``M1_v = B m1``, ``M2_pv = m2 B^T``, ``M2_vv = B m2 B^T + mass resid``. Linear
    in ``(mass, m1, m2)``, so sums of pairs of one Gaussian may be lifted once."""
    Bt = np.swapaxes(B, -1, -2)
    M1 = np.empty((len(mass), 4))
    M1[:, 0::2] = m1
    M1[:, 1::2] = np.einsum("nij,nj->ni", B, m1)
    M2 = np.empty((len(mass), 4, 4))
    pv = np.einsum("nij,njk->nik", m2, Bt)
    M2[:, 0::2, 0::2] = m2
    M2[:, 0::2, 1::2] = pv
    M2[:, 1::2, 0::2] = np.swapaxes(pv, -1, -2)
    M2[:, 1::2, 1::2] = np.einsum("nij,njk->nik", B, pv) + mass[:, None, None] * resid
    return M1, M2


def rect_state_moments(means: np.ndarray, covs: np.ndarray, x0: np.ndarray, x1: np.ndarray,
                       y0: np.ndarray, y1: np.ndarray, owner: np.ndarray | None = None
                       ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Like :func:`rect_position_moments` for full states ``means (K, 4)``, ``covs (K, 4, 4)``.

    ``owner (N,)``: the Gaussian (row of ``means``) of each of the ``N`` rectangles (default:
    rectangle ``k`` belongs to Gaussian ``k``, ``N = K``). Returns ``mass (N,)``, ``M1 (N, 4)``
    and ``M2 (N, 4, 4)`` (centred on the owner's mean), with the velocity parts from the
    regression on position (:func:`position_regression`, :func:`lift_to_state`).
    """
    if owner is None:
        owner = np.arange(len(means))
    B, resid = position_regression(covs)
    kernels = compiled_gpf_kernels()
    if kernels is not None:
        return kernels.state_moments(
            np.ascontiguousarray(means, dtype=float), np.ascontiguousarray(covs, dtype=float),
            np.ascontiguousarray(owner, dtype=np.int64),
            *(np.ascontiguousarray(e, dtype=float) for e in (x0, x1, y0, y1)), B, resid,
            *_gl_table())
    mass, m1, m2 = rect_position_moments(means[owner][:, 0::2], covs[owner][:, 0::2, 0::2],
                                         x0, x1, y0, y1)
    M1, M2 = lift_to_state(B[owner], resid[owner], mass, m1, m2)
    return mass, M1, M2


@dataclass(frozen=True)
class GridUpdateResult:
    """Posterior of a grid update: ``weights (T,)`` per track, ``means (R, 4)``,
    ``covs (R, 4, 4)`` per Gaussian row;
    ``dropped``: total prior mass cut by the combination threshold (summed over clusters);
    ``n_clusters``: number of multi-particle clusters enumerated;
    ``max_cluster``: size of the largest one (0 if none)."""

    weights: np.ndarray
    means: np.ndarray
    covs: np.ndarray
    dropped: float
    n_clusters: int
    max_cluster: int
    #: mixture weight and track of each row of ``means`` (one row per track unless
    #: components were given or split off)
    alpha: np.ndarray | None = None
    owner: np.ndarray | None = None


def _components(part: np.ndarray, cell: np.ndarray, K: int) -> np.ndarray:
    """Connected components of the bipartite graph particle -- looked cell.

    ``part (E,)`` particle index and ``cell (E,)`` looked-cell index of each edge. Returns a
    label ``(K,)`` per particle (equal labels = same component; a particle without edges is
    alone). Minimum-label propagation over the few edges (a cell joins to its smallest
    particle, a particle to its smallest cell's label) until nothing changes; the loop runs
    about the component diameter times, and no sparse matrix is built.
    """
    label = np.arange(K)
    if len(part) == 0:
        return label
    cells, cidx = np.unique(cell, return_inverse=True)
    while True:
        cell_lab = np.full(len(cells), K)
        np.minimum.at(cell_lab, cidx, label[part])
        new = label.copy()
        np.minimum.at(new, part, cell_lab[cidx])
        new = new[new]  # pointer jumping: follow a label to its own label
        if np.array_equal(new, label):
            return label
        label = new


#: clusters with at most this many joint option choices are listed in full, all together
_FULL_LISTING = 4096


def avoid_coalescence(cluster: np.ndarray, choice: np.ndarray, cell: np.ndarray,
                      detected: np.ndarray, log_post: np.ndarray) -> np.ndarray:
    """Blom and Bloem's JPDA* rule: of the combinations that differ only by which members
    took which detected cells (the same members take detected cells, the same multiset of
    detected cells is taken, every other member makes the same choice), keep only the most
    probable (the first on ties). ``cluster (C,)``, ``choice (C, S)`` and ``cell (C, S)``
    (members padded with ``-2``; cell ``-1``: none), ``detected (n_u,)``, ``log_post (C,)``;
    returns ``log_post`` with the others at ``-inf``. Without it the members of a cluster
    whose detections could be swapped all move to the same blend of them (coalescence)."""
    kernels = compiled_gpf_kernels()
    if kernels is not None:
        return kernels.avoid_coalescence(
            np.ascontiguousarray(cluster, dtype=np.int64),
            np.ascontiguousarray(choice, dtype=np.int64),
            np.ascontiguousarray(cell, dtype=np.int64),
            np.ascontiguousarray(detected, dtype=bool),
            np.ascontiguousarray(log_post, dtype=float))
    took = cell >= 0
    took[took] = detected[cell[took]]
    marker = np.where(took, -1, choice)
    taken = np.sort(np.where(took, cell, -1), axis=1)
    key = np.column_stack([cluster, marker, taken])
    _, cls = np.unique(key, axis=0, return_inverse=True)
    cls = cls.reshape(-1)
    order = np.lexsort((np.arange(len(cls)), -log_post, cls))
    first = np.ones(len(order), dtype=bool)
    first[1:] = cls[order[1:]] != cls[order[:-1]]
    out = np.full(len(log_post), -np.inf)
    out[order[first]] = log_post[order[first]]
    return out


def _cut_posterior(log_post: np.ndarray, group: np.ndarray, n_groups: int,
                   epsilon: float) -> tuple[np.ndarray, float]:
    """Per group, the normalised posterior ``p_C ~ exp(log_post)`` of its combinations with
    those of posterior ``<= epsilon`` dropped and the rest renormalised (a group whose
    combinations are all at or below ``epsilon`` keeps them all). Returns ``p (C,)`` and the
    posterior mass dropped, summed over the groups."""
    top = np.full(n_groups, -np.inf)
    np.maximum.at(top, group, log_post)
    e = np.exp(log_post - top[group])
    pc = e / np.bincount(group, weights=e, minlength=n_groups)[group]
    keep = pc > epsilon
    kept_any = np.bincount(group, weights=keep, minlength=n_groups) > 0
    keep |= ~kept_any[group]
    dropped = float(pc[~keep].sum())
    pc = np.where(keep, pc, 0.0)
    return pc / np.bincount(group, weights=pc, minlength=n_groups)[group], dropped


def _cluster_posterior(option_probs: np.ndarray, option_cell: np.ndarray, LL: np.ndarray,
                       epsilon: float, max_combinations: int,
                       detected: np.ndarray) -> tuple[np.ndarray, float]:
    """One cluster too large to list in full: the ``max_combinations`` combinations of
    largest approximate posterior -- the product of the members' :func:`_option_beliefs`,
    which weigh each detected-cell option by the coupling it meets from the others -- by
    :func:`enumerate_combinations`, then their exact posterior (tilted prior times the
    coupling), the JPDA* rule and the cut on the posterior (:func:`_cut_posterior`).
    Ranked by the tilted prior alone, as before, the list filled with combinations in
    which several members take one detected cell (each option tilted by ``l(1)`` as if
    alone), whose posterior is ``l(2) / l(1)^2 ~ 5e-5`` of the rest at ``p_f = 2.2e-5``,
    and the cut kept those (docs/gpf.md section 14). ``option_probs``, ``option_cell`` are
    ``(n, O)`` (cell ``-1`` = not in a looked cell); returns ``post (n, O)``, the posterior
    probability of each member's options, and the dropped mass (the listed combinations'
    posterior at or below ``epsilon``, plus the approximate posterior beyond the cap).
    ``detected (n_u,)``: the detected looked cells, for :func:`avoid_coalescence`.
    With the compiled backend :func:`.cluster_kernels.cluster_posterior` computes the
    same numbers in one call (this form where its enumeration's cap meets a tie)."""
    kernels = compiled_gpf_kernels()
    if kernels is not None:
        post, dropped, exact = kernels.cluster_posterior(
            np.ascontiguousarray(option_probs, dtype=float),
            np.ascontiguousarray(option_cell, dtype=np.int64),
            np.ascontiguousarray(LL, dtype=float), np.ascontiguousarray(detected, dtype=bool),
            float(epsilon), int(max_combinations), _BLOCK, _BELIEF_ITERATIONS,
            _BELIEF_DAMPING, _BELIEF_CLIP)
        if exact:
            return post, dropped
    n, n_opt = option_probs.shape
    combs = enumerate_combinations(_option_beliefs(option_probs, option_cell, LL), 0.0,
                                   max_combinations)
    ch = combs.choice  # (C, n)
    with np.errstate(divide="ignore"):
        log_prior = np.log(option_probs)[np.arange(n)[None, :], ch].sum(axis=1)
    cell_of = option_cell[np.arange(n)[None, :], ch]
    # counts per looked cell in each combination, then sum_c LL[c, T_c]
    loc_cells, loc_idx = np.unique(cell_of[cell_of >= 0], return_inverse=True)
    counts = np.zeros((ch.shape[0], len(loc_cells)), dtype=np.int64)
    np.add.at(counts, (np.nonzero(cell_of >= 0)[0], loc_idx), 1)
    loglik = LL[loc_cells[None, :], counts].sum(axis=1)
    log_post = avoid_coalescence(np.zeros(len(ch), dtype=np.int64), ch, cell_of, detected,
                                 log_prior + loglik)
    pc, cut = _cut_posterior(log_post, np.zeros(len(ch), dtype=np.int64), 1, epsilon)
    # post[j, o] = sum over combinations with choice_j = o of p(C | z)
    post = np.bincount((np.arange(n)[None, :] * n_opt + ch).ravel(),
                       weights=np.repeat(pc, n), minlength=n * n_opt).reshape(n, n_opt)
    return post, combs.dropped + cut


#: fixed-point iterations of :func:`_option_beliefs` and the share of the new value in each
_BELIEF_ITERATIONS = 20
_BELIEF_DAMPING = 0.5
#: a member's option probability is held below 1 by this much in the leave-one-out counts
_BELIEF_CLIP = 1e-12


def _option_beliefs(option_probs: np.ndarray, option_cell: np.ndarray, LLc: np.ndarray
                    ) -> np.ndarray:
    """Approximate posterior option probabilities of one cluster's members (``(n, O)``,
    rows summing to 1), to rank its combinations.

    The joint posterior is ``prod_j q_j(o_j) exp(sum_c LLc[c, T_c])`` (``q`` the tilted
    option probabilities, ``LLc`` the coupling, :func:`_aggregate_misses`). Member ``i``'s
    option at detected cell ``c`` is weighed by the coupling's expected increment given
    the others, ``b_i(c) ~ q_i(c) E[exp(LLc[c, T_-i + 1] - LLc[c, T_-i])]``, ``T_-i`` the
    number of other members at ``c`` under the current beliefs, independent Bernoullis
    (``P(T_-i = 0) = prod_{j != i} (1 - b_j)``, ``P(T_-i = 1) = P(T_-i = 0) sum_{j != i}
    b_j / (1 - b_j)``,
    the rest counted at ``T_-i = 2``); a damped fixed-point iteration from ``q``
    (loopy belief propagation's form on this factor graph, not its exact messages)."""
    kernels = compiled_gpf_kernels()
    if kernels is not None:
        return kernels.option_beliefs(
            np.ascontiguousarray(option_probs, dtype=float),
            np.ascontiguousarray(option_cell, dtype=np.int64),
            np.ascontiguousarray(LLc, dtype=float), _BELIEF_ITERATIONS, _BELIEF_DAMPING,
            _BELIEF_CLIP)
    n, n_opt = option_probs.shape
    rows, cols = np.nonzero(option_cell >= 0)
    q = option_probs.copy()
    if len(rows) == 0:
        return q
    cells, cidx = np.unique(option_cell[rows, cols], return_inverse=True)
    steps = np.exp(np.diff(LLc[cells], axis=1))  # exp(LLc[c, T + 1] - LLc[c, T])
    steps = np.concatenate([steps, steps[:, -1:], steps[:, -1:]], axis=1)[:, :3]
    n_c = len(cells)
    for _ in range(_BELIEF_ITERATIONS):
        b = np.minimum(q[rows, cols], 1.0 - _BELIEF_CLIP)
        log_free = np.log1p(-b)
        odds = b / (1.0 - b)
        p0 = np.exp(np.bincount(cidx, weights=log_free, minlength=n_c)[cidx] - log_free)
        p1 = p0 * np.maximum(np.bincount(cidx, weights=odds, minlength=n_c)[cidx] - odds, 0.0)
        p1 = np.minimum(p1, 1.0 - p0)
        factor = (p0 * steps[cidx, 0] + p1 * steps[cidx, 1]
                  + (1.0 - p0 - p1) * steps[cidx, 2])
        new = option_probs.copy()
        new[rows, cols] *= factor
        new /= new.sum(axis=1, keepdims=True)
        q = (1.0 - _BELIEF_DAMPING) * q + _BELIEF_DAMPING * new
    return q


def _small_clusters_posterior(option_probs: np.ndarray, option_cell: np.ndarray,
                              cl: np.ndarray, n_pos: np.ndarray, LL: np.ndarray,
                              epsilon: float, detected: np.ndarray
                              ) -> tuple[np.ndarray, float]:
    """Several clusters at once, each listing all its joint choices (few: the cap never binds).

    ``option_probs``, ``option_cell (M, O)`` for the members of all the clusters, grouped by
    cluster (``cl (M,)`` non-decreasing), ``n_pos (M,)`` options of positive probability.
    Combination ``r`` of a cluster picks, for member ``j``, its positive option number
    ``(r // stride_j) % n_pos_j`` (mixed radix, ``stride_j`` = product of ``n_pos`` of the
    later members). :func:`avoid_coalescence` applies with ``detected (n_u,)`` the detected
    cells, then combinations with posterior ``<= epsilon`` are dropped
    (:func:`_cut_posterior`). Returns ``post (M, O)`` and the total dropped posterior mass.
    """
    M, n_opt = option_probs.shape
    # positive options first, in their original order
    pos_opt = np.argsort(option_probs <= 0.0, axis=1, kind="stable")
    stride = np.empty(M, dtype=np.int64)
    cl_l, np_l = cl.tolist(), n_pos.tolist()
    size = {}
    acc = 1
    for r in range(M - 1, -1, -1):  # suffix products within each cluster (integers)
        if r == M - 1 or cl_l[r + 1] != cl_l[r]:
            acc = 1
        stride[r] = acc
        acc *= np_l[r]
        size[cl_l[r]] = acc
    _, cidx = np.unique(cl, return_inverse=True)  # clusters numbered 0..G-1
    n_comb = np.array([size[c] for c in dict.fromkeys(cl_l)], dtype=np.int64)  # (G,)
    comb_start = np.cumsum(n_comb) - n_comb
    comb_cl = np.repeat(np.arange(len(n_comb)), n_comb)
    # one entry per (combination, member of its cluster)
    per_member = n_comb[cidx]
    member = np.repeat(np.arange(M), per_member)
    r_local = np.arange(len(member)) - np.repeat(np.cumsum(per_member) - per_member, per_member)
    comb = comb_start[cidx[member]] + r_local
    opt = pos_opt[member, (r_local // stride[member]) % n_pos[member]]
    with np.errstate(divide="ignore"):
        lp = np.bincount(comb, weights=np.log(option_probs[member, opt]),
                         minlength=len(comb_cl))
    # sum_c LL[c, T_c]: count each looked cell's occupants per combination
    n_u = LL.shape[0]
    cell = option_cell[member, opt]
    hit = (cell >= 0) & np.isfinite(lp)[comb]
    key, t_count = np.unique(comb[hit] * n_u + cell[hit], return_counts=True)
    loglik = np.bincount(key // n_u, weights=LL[key % n_u, t_count], minlength=len(comb_cl))
    log_post = lp + loglik
    # JPDA*: each combination's members in a row, (n_comb, largest cluster), padded with -2
    rank = member - np.searchsorted(cidx, cidx[member])  # the member's place in its cluster
    width = int(rank.max()) + 1
    choice = np.full((len(comb_cl), width), -2)
    cells = np.full((len(comb_cl), width), -2)
    choice[comb, rank] = opt
    cells[comb, rank] = cell
    log_post = avoid_coalescence(comb_cl, choice, cells, detected, log_post)
    pc, dropped = _cut_posterior(log_post, comb_cl, len(n_comb), epsilon)
    post = np.bincount(member * n_opt + opt, weights=pc[comb],
                       minlength=M * n_opt).reshape(M, n_opt)
    return post, dropped


def _aggregate_misses(option_probs: np.ndarray, option_cell: np.ndarray, rows: np.ndarray,
                      cols: np.ndarray, LL: np.ndarray, hit: np.ndarray
                      ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Cluster options with the looked cells that returned nothing pooled into one option,
    and every option tilted by its own likelihood (module docstring, "missed cells").

    In: ``option_probs``, ``option_cell (M, O)`` as in :func:`grid_update` (absent,
    elsewhere, then the member's looked cells at ``(rows, cols)``), ``LL (n_u, T + 1)``,
    ``hit (n_u,)``. Out, ``(M, O + 1)``: the same columns, missed cells emptied, and a last
    column "missed", with probabilities ``q_o = p_o l_o / sum_o' p_o' l_o'`` (``l`` = 1
    for absent and elsewhere, ``sum_c m_c l_c(1) / sum_c m_c`` for missed, ``l_c(1)`` for a
    detected cell); their cells (``-1`` but for detected cells); the coupling
    ``LLc[c, T] = LL[c, T] - T LL[c, 1]`` (0 for ``T <= 1``); and each member's
    ``sum_c m_c l_c(1)`` over its missed cells (``m_c`` given existence). The joint
    posterior is unchanged, up to a constant, wherever no two members share a missed cell.
    """
    M, n_opt = option_probs.shape
    cell = option_cell[rows, cols]
    p = option_probs[rows, cols]
    l1 = np.exp(LL[cell, 1])
    missed = ~hit[cell]
    wm = 1.0 - option_probs[:, 0]
    miss_w = np.bincount(rows[missed], weights=p[missed] * l1[missed], minlength=M)
    q = np.zeros((M, n_opt + 1))
    q[:, :2] = option_probs[:, :2]
    q[rows[~missed], cols[~missed]] = p[~missed] * l1[~missed]
    q[:, -1] = miss_w
    q /= q.sum(axis=1, keepdims=True)
    out_cell = np.full((M, n_opt + 1), -1)
    out_cell[rows[~missed], cols[~missed]] = cell[~missed]
    with np.errstate(divide="ignore", invalid="ignore"):
        miss_lik = np.where(wm > 0.0, miss_w / wm, 0.0)
    LLc = LL - np.arange(LL.shape[1])[None, :] * LL[:, [1]]
    return q, out_cell, LLc, miss_lik


def grid_update(w: np.ndarray, m: np.ndarray, P: np.ndarray, uniform_cell: np.ndarray,
                cells: np.ndarray, returns: np.ndarray, grid: Grid,
                sensor: RayleighGridSensor, epsilon: float = 1e-3,
                max_combinations: int = 512, interaction_threshold: float = 1e-3,
                range_sigmas: float = 6.0, owner: np.ndarray | None = None,
                alpha: np.ndarray | None = None, split_share: float = 0.0
                ) -> GridUpdateResult:
    """Update tracks ``w (T,)`` with Gaussian rows ``m (R, 4)``, ``P (R, 4, 4)`` by the looks
    of one step.

    ``owner (R,)``: the track of each row, ``alpha (R,)`` its mixture weight within the track
    (default: one row per track, weight 1). ``uniform_cell (R,)`` int: ``-1`` for a Gaussian
    row, else the (looked) cell on which the row is uniform (such a row is alone in its
    track). ``cells (L,)``, ``returns (L,)``: the looks. A Gaussian row is paired with the
    looked cells within ``range_sigmas`` marginal standard deviations of its mean (mass
    beyond is below 1e-8 at 6); a track's mass in a cell is ``sum_r alpha_r m_rc``.
    Equations in the module docstring (clusters through detected cells, the "missed
    cells" option, JPDA* by :func:`avoid_coalescence`); ``split_share > 0``: each
    row's part in a detected cell whose posterior share of its track is at least
    ``split_share`` becomes a component of its own (the Gaussian truncated to the cell),
    the rest of the row stays one moment-matched component.

    With the compiled backend (:mod:`.grid_backend`) the pairs, the singletons and the
    moment match run as :mod:`.update_kernels`' passes, and the clusters' options, the
    large clusters' posteriors and the members' ``g`` as :mod:`.cluster_kernels`', with
    the same numbers bit for bit; the small clusters' full listing stays numpy.
    """
    T = len(w)
    R = len(m)
    w = np.asarray(w, dtype=float).clip(0.0, 1.0)  # np.clip's ufunc, without its wrapper
    own = np.arange(R) if owner is None else np.asarray(owner, dtype=np.int64)
    alp = np.ones(R) if alpha is None else np.asarray(alpha, dtype=float)
    if T == 0 or len(cells) == 0:
        return GridUpdateResult(w.copy(), m.copy(), P.copy(), 0.0, 0, 0, alp.copy(),
                                own.copy())
    kernels = compiled_gpf_kernels()
    if kernels is None:
        U = np.unique(cells)
        hit = np.zeros(len(U), dtype=bool)
        hit[np.searchsorted(U, cells[returns])] = True
        pairs = _pairs_and_singletons(w, m, P, uniform_cell, own, alp, U, hit, cells, returns,
                                      grid, sensor, interaction_threshold, range_sigmas)
    else:
        # one pass, and a second for the moment match when no cluster holds two tracks
        B, resid = position_regression(P)
        ll_pos, ll_neg = _one_target_ratios(sensor)
        ints, floats = kernels.grid_update_packed(
            w, np.ascontiguousarray(m, dtype=float), np.ascontiguousarray(P, dtype=float),
            np.ascontiguousarray(uniform_cell, dtype=np.int64), np.ascontiguousarray(own),
            np.ascontiguousarray(alp),
            np.ascontiguousarray(cells, dtype=np.int64), np.ascontiguousarray(returns, dtype=bool),
            ll_pos, ll_neg, float(grid.cell_size), grid.nx, grid.ny,
            float(interaction_threshold), float(range_sigmas), *_gl_table(), B, resid,
            float(split_share))
        if ints[6]:
            raise ValueError("a uniform particle must sit in a looked cell")
        if ints[7]:
            n = int(ints[8])
            return GridUpdateResult(floats[21 * n:], floats[:4 * n].reshape(n, 4),
                                    floats[4 * n:20 * n].reshape(n, 4, 4), 0.0, 0, 0,
                                    floats[20 * n:21 * n], ints[kernels.HEADER:])
        pairs, hit = kernels.unpack_front(ints, floats)
    (ri_g, pu_g, mass_g, p1_g, p2_g, pi, pu, pair_of, mass, mass_out, logL, LL1, plabel,
     in_cluster, t_max, w_new, g_out, g_pair, bad_uniform) = pairs
    if bad_uniform:
        raise ValueError("a uniform particle must sit in a looked cell")
    K = T
    # the same table as LL1 when no cluster holds two tracks (the same call)
    LL = LL1 if t_max <= 1 else look_log_ratios(sensor, cells, returns, t_max)[1]

    # ---- multi-particle clusters: enumerate combinations
    dropped = 0.0
    n_clusters, max_cluster = 0, 0
    mem = np.nonzero(in_cluster)[0]
    if len(mem):
        mem = mem[np.argsort(plabel[mem], kind="stable")]  # grouped by cluster
        _, cl, csize = sorted_runs(plabel[mem])
        n_clusters, max_cluster = len(csize), int(csize.max())
        M = len(mem)
        if kernels is not None:
            (option_probs, option_cell, LLc, miss_lik, n_pos, rows, cols,
             pidx) = kernels.cluster_options(w, mass, mass_out, pi, pu, mem,
                                             np.ascontiguousarray(LL), hit)
        else:
            # options per member, padded to (M, 2 + most pairs): absent, elsewhere, its cells
            pair_start = np.searchsorted(pi, np.arange(K + 1))
            first, cnt = pair_start[mem], pair_start[mem + 1] - pair_start[mem]
            n_opt = 2 + int(cnt.max())
            rows = np.repeat(np.arange(M), cnt)
            cols = 2 + np.arange(len(rows)) - np.repeat(np.cumsum(cnt) - cnt, cnt)
            pidx = first[rows] + cols - 2  # the member's pairs, in pair order
            wm = w[mem]
            option_probs = np.zeros((M, n_opt))
            option_probs[:, 0] = 1.0 - wm
            option_probs[:, 1] = wm * mass_out[mem]
            option_probs[rows, cols] = wm[rows] * mass[pidx]
            option_cell = np.full((M, n_opt), -1)
            option_cell[rows, cols] = pu[pidx]
            option_probs, option_cell, LLc, miss_lik = _aggregate_misses(
                option_probs, option_cell, rows, cols, LL, hit)
            n_pos = np.maximum((option_probs > 0.0).sum(axis=1), 1)
        n_opt = option_probs.shape[1]
        # clusters with few joint choices (at most the cap) are listed in full, all at once
        log_size = np.bincount(cl, weights=np.log(n_pos))
        small = log_size <= math.log(min(max_combinations, _FULL_LISTING)) + 1e-9
        post = np.zeros((M, n_opt))
        cstart = np.cumsum(csize) - csize
        for c in np.nonzero(~small)[0]:
            sl = slice(cstart[c], cstart[c] + csize[c])
            post[sl], d = _cluster_posterior(option_probs[sl], option_cell[sl], LLc, epsilon,
                                             max_combinations, hit)
            dropped += d
        sm = np.nonzero(small[cl])[0]
        if len(sm):
            post[sm], d = _small_clusters_posterior(option_probs[sm], option_cell[sm], cl[sm],
                                                    n_pos[sm], LLc, epsilon, hit)
            dropped += d
        if kernels is not None:
            kernels.cluster_g(post, mem, rows, cols, pidx, mass, mass_out, pu, hit,
                              np.ascontiguousarray(LL), miss_lik, w_new, g_out, g_pair)
        else:
            _cluster_g(post, mem, rows, cols, pidx, mass, mass_out, pu, hit, LL, miss_lik,
                       w_new, g_out, g_pair)

    # ---- moment match each Gaussian row: density prior * g, g piecewise constant (its
    # track's g per cell)
    gauss_row = uniform_cell < 0
    if kernels is None:
        B, resid = position_regression(P)
        means, covs, new_alpha, out_own = _moment_match(
            ri_g, pu_g, mass_g, p1_g, p2_g, pair_of, g_pair, g_out, w_new, own, alp,
            gauss_row, hit, m, P, B, resid, T, split_share)
    else:
        means, covs, new_alpha, out_own = kernels.moment_match(
            ri_g, pu_g, mass_g, p1_g, p2_g, pair_of, g_pair, g_out, w_new, own, alp,
            gauss_row, hit, np.ascontiguousarray(m, dtype=float),
            np.ascontiguousarray(P, dtype=float), B, resid, T, float(split_share))
    return GridUpdateResult(np.clip(w_new, 0.0, 1.0), means, covs, dropped, n_clusters,
                            max_cluster, new_alpha, out_own)


def _cluster_g(post: np.ndarray, mem: np.ndarray, rows: np.ndarray, cols: np.ndarray,
               pidx: np.ndarray, mass: np.ndarray, mass_out: np.ndarray, pu: np.ndarray,
               hit: np.ndarray, LL: np.ndarray, miss_lik: np.ndarray, w_new: np.ndarray,
               g_out: np.ndarray, g_pair: np.ndarray) -> None:
    """The clusters' members' presence ``w_new`` and, where present, their ``g_out`` and
    ``g_pair`` from the option posteriors ``post`` (in place; numpy form of
    :func:`.cluster_kernels.cluster_g`)."""
    present = 1.0 - post[:, 0]
    w_new[mem] = present
    ok = present > 0.0
    # the prior mass of each option's bin, given existence
    bin_mass = np.zeros(post.shape)
    bin_mass[:, 1] = mass_out[mem]
    bin_mass[rows, cols] = mass[pidx]
    with np.errstate(divide="ignore", invalid="ignore"):
        g = np.where(bin_mass > 0.0, post / present[:, None] / bin_mass, 0.0)
        # inside the missed bin the posterior over its cells is m_c l_c(1) / sum
        missed = ~hit[pu[pidx]]
        gm = post[rows, -1] / present[rows] * np.exp(LL[pu[pidx], 1]) / miss_lik[rows]
        g[rows[missed], cols[missed]] = gm[missed]
    g[~ok] = 0.0
    g_out[mem] = np.where(ok, g[:, 1], g_out[mem])
    g_pair[pidx] = np.where(ok[rows], g[rows, cols], g_pair[pidx])


@functools.lru_cache(maxsize=64)
def _one_target_ratios(sensor: RayleighGridSensor) -> tuple[float, float]:
    """``log l(1)`` of one look with a return and without, as :func:`.cells.look_log_ratios`
    computes them (the sensor is immutable)."""
    ll_pos, ll_neg = sensor.log_likelihood_ratio(np.array([True, False]), np.ones(2))
    return float(ll_pos), float(ll_neg)


def _pairs_and_singletons(w: np.ndarray, m: np.ndarray, P: np.ndarray, uniform_cell: np.ndarray,
                          own: np.ndarray, alp: np.ndarray, U: np.ndarray, hit: np.ndarray,
                          cells: np.ndarray, returns: np.ndarray, grid: Grid,
                          sensor: RayleighGridSensor, interaction_threshold: float,
                          range_sigmas: float) -> tuple:
    """The first part of :func:`grid_update` (numpy form; the compiled one is
    :func:`.update_kernels.pairs_and_singletons`, equal bit for bit): the (row, looked
    cell) pairs and their position moments, the (track, looked cell) pairs and masses,
    each track's likelihood as if alone, the clusters, and the singletons' closed form.
    ``U`` the sorted looked cells, ``hit (n_u,)`` those that returned a detection."""
    T = K = len(w)
    s = grid.cell_size
    n_u = len(U)
    gauss_row = uniform_cell < 0
    gauss = np.ones(T, dtype=bool)
    gauss[own[~gauss_row]] = False

    # ---- (row, looked cell) pairs
    sx = np.sqrt(np.maximum(P[:, 0, 0], 0.0))
    sy = np.sqrt(np.maximum(P[:, 2, 2], 0.0))
    gr = np.nonzero(gauss_row)[0]  # a uniform row pairs with its own cell only (below)
    box, pu_g = looked_in_boxes(
        np.floor((m[gr, 0] - range_sigmas * sx[gr]) / s),
        np.floor((m[gr, 0] + range_sigmas * sx[gr]) / s),
        np.floor((m[gr, 2] - range_sigmas * sy[gr]) / s),
        np.floor((m[gr, 2] + range_sigmas * sy[gr]) / s), U, grid.nx, grid.ny)
    ri_g = gr[box]
    x0, x1, y0, y1 = grid.cell_bounds(U[pu_g])
    # position moments per pair; the velocity parts are lifted per row after summing
    # (lift_to_state is linear), and per pair only for the components split off
    mass_g, p1_g, p2_g = rect_position_moments(
        m[ri_g][:, 0::2], P[ri_g][:, 0::2, 0::2], x0.astype(float), x1.astype(float),
        y0.astype(float), y1.astype(float))
    keep = mass_g > 1e-12
    ri_g, pu_g, mass_g, p1_g, p2_g = ri_g[keep], pu_g[keep], mass_g[keep], p1_g[keep], p2_g[keep]
    # uniform rows: one pair, mass 1 (their moments are never used)
    ri_u = np.nonzero(~gauss_row)[0]
    pu_u = np.searchsorted(U, uniform_cell[ri_u])
    if np.any(U[np.minimum(pu_u, n_u - 1)] != uniform_cell[ri_u]):
        raise ValueError("a uniform particle must sit in a looked cell")
    # ---- (track, looked cell) pairs: the track's mass sum_r alpha_r m_rc
    row_pi = np.concatenate([own[ri_g], own[ri_u]])
    row_pu = np.concatenate([pu_g, pu_u])
    row_mass = np.concatenate([alp[ri_g] * mass_g, np.ones(len(ri_u))])
    key, pair_of = np.unique(row_pi * n_u + row_pu, return_inverse=True)
    pair_of = pair_of.reshape(-1)
    pi, pu = key // n_u, key % n_u  # sorted by track, then cell
    mass = np.bincount(pair_of, weights=row_mass, minlength=len(key))
    mass_in = np.bincount(pi, weights=mass, minlength=K)
    mass_out = np.clip(1.0 - mass_in, 0.0, 1.0)
    mass_out[~gauss] = 0.0

    # ---- each track's likelihood as if alone, L = m_out + sum_c m_c l_c(1) (log, given
    # existence): the singletons' update, and the significance of a pair below
    _, LL1 = look_log_ratios(sensor, cells, returns, 1)
    log_terms = np.log(np.maximum(mass, 1e-300)) + LL1[pu, 1]  # per pair, log m_c l_c(1)
    with np.errstate(divide="ignore"):
        logL = np.log(mass_out)
        log_w, log_not_w = np.log(w), np.log1p(-w)
    np.logaddexp.at(logL, pi, log_terms)

    # ---- clusters: particles linked through a looked cell both occupy significantly
    # (prior w m_c, or posterior as if alone w m_c l_c / (w L + 1 - w): a track updated
    # apart credits a detection to itself alone, so at l_c(1) = p_d / p_f = 2.7e4 a tail
    # of 3e-6 in a neighbour's detected cell took 16% of it; docs/gpf.md section 14)
    occ = w[pi] * mass
    with np.errstate(invalid="ignore"):  # a track with no mass at all: nan, not linked
        occ_alone = np.exp(log_w[pi] + log_terms - np.logaddexp(log_w + logL, log_not_w)[pi])
    # a uniform particle (birth candidate) always links in a cell that returned a detection,
    # so that a return an existing particle explains is not also credited to a new target
    signif = ((np.maximum(occ, occ_alone) > interaction_threshold)
              | (~gauss[pi] & hit[pu]))
    signif &= hit[pu]  # members interact only through cells that returned a detection
    n_sig = np.bincount(pu[signif], minlength=n_u)
    link = signif & (n_sig[pu] >= 2)
    plabel = _components(pi[link], pu[link], K)
    sizes = np.bincount(plabel)
    in_cluster = sizes[plabel] >= 2
    t_max = int(sizes[plabel].max()) if K else 1

    # ---- per pair: g (posterior/prior density ratio given existence); per particle g_out
    g_pair = np.zeros(len(pi))
    g_out = np.zeros(K)
    w_new = w.copy()
    # singletons, closed form in log space
    single = ~in_cluster
    sp = single[pi]
    s_idx = np.nonzero(single)[0]
    with np.errstate(divide="ignore"):
        logit = np.log(w[s_idx]) + logL[s_idx] - np.log1p(-w[s_idx])
    w_new[s_idx] = np.where(w[s_idx] >= 1.0, 1.0, 1.0 / (1.0 + np.exp(-logit)))
    g_out[s_idx] = np.exp(-logL[s_idx])
    g_pair[sp] = np.exp(LL1[pu[sp], 1] - logL[pi[sp]])

    return (ri_g, pu_g, mass_g, p1_g, p2_g, pi, pu, pair_of, mass, mass_out, logL, LL1, plabel,
            in_cluster, t_max, w_new, g_out, g_pair, False)


def _moment_match(ri_g: np.ndarray, pu_g: np.ndarray, mass_g: np.ndarray, p1_g: np.ndarray,
                  p2_g: np.ndarray, pair_of: np.ndarray, g_pair: np.ndarray, g_out: np.ndarray,
                  w_new: np.ndarray, own: np.ndarray, alp: np.ndarray, gauss_row: np.ndarray,
                  hit: np.ndarray, m: np.ndarray, P: np.ndarray, B: np.ndarray,
                  resid: np.ndarray, T: int, split_share: float
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The last part of :func:`grid_update` (numpy form; the compiled one is
    :func:`.update_kernels.moment_match`, equal bit for bit): each Gaussian row moment
    matched under its track's ``g`` (row ``r``'s posterior mass within its track is
    ``alpha_r Z_r``), the split components, the renormalised mixture weights. ``B``,
    ``resid``: :func:`position_regression` of ``P``. Returns means, covs, alpha, owner."""
    R = len(m)
    n_gp = len(ri_g)
    gi = pair_of[:n_gp]  # the track pair of each Gaussian row pair
    live = w_new[own[ri_g]] > 0.0
    g_rp = np.where(live, g_pair[gi], 0.0)
    go_r = g_out[own]
    coef = g_rp - go_r[ri_g]  # (g_c - g_out) per row pair
    Z_full = go_r + np.bincount(ri_g, weights=coef * mass_g, minlength=R)
    split = np.zeros(n_gp, dtype=bool)
    if split_share > 0.0:
        # a detected cell's part of a row, if heavy enough, leaves as its own component
        full_alpha = alp * np.where(gauss_row, Z_full, 1.0)
        tot = np.bincount(own, weights=full_alpha, minlength=T)
        share = alp[ri_g] * g_rp * mass_g / np.maximum(tot[own[ri_g]], 1e-300)
        split = hit[pu_g] & (share >= split_share) & live
        # ... unless it is (nearly) all of the row: then the row is that component anyway
        split &= alp[ri_g] * g_rp * mass_g < (1.0 - split_share) * full_alpha[ri_g]
    # the rest of each row: sums over its pairs of coef * (mass, m1, m2), lifted once
    c_rest = np.where(split, coef - g_rp, coef)
    Z = go_r + np.bincount(ri_g, weights=c_rest * mass_g, minlength=R) if np.any(split) else Z_full
    sums = [np.bincount(ri_g, weights=c_rest * v, minlength=R)
            for v in (p1_g[:, 0], p1_g[:, 1], p2_g[:, 0, 0], p2_g[:, 0, 1], p2_g[:, 1, 1])]
    d1 = np.stack(sums[:2], axis=-1)
    d2 = np.stack([np.stack(sums[2:4], axis=-1), np.stack(sums[3:], axis=-1)], axis=-2)
    d, S2 = lift_to_state(B, resid, Z - go_r, d1, d2)
    S2 += go_r[:, None, None] * P
    new_alpha = alp * np.where(gauss_row, Z, 1.0)
    means, covs = m.copy(), P.copy()
    upd = gauss_row & (w_new[own] > 0.0) & (Z > 0.0)
    Zs = Z[upd]
    dd = d[upd] / Zs[:, None]
    means[upd] = m[upd] + dd
    cv = S2[upd] / Zs[:, None, None] - dd[:, :, None] * dd[:, None, :]
    covs[upd] = 0.5 * (cv + np.swapaxes(cv, -1, -2))
    out_own = own
    if np.any(split):
        # a split row's remainder is dropped when negligible or its moments degenerate
        was_split = np.zeros(R, dtype=bool)
        was_split[ri_g[split]] = True
        sane = (covs[:, 0, 0] > 0.0) & (covs[:, 2, 2] > 0.0)
        rest_ok = ~was_split | (upd & (Z > 1e-6 * Z_full) & sane)
        srow = ri_g[split]
        sm = mass_g[split]
        M1_s, M2_s = lift_to_state(B[srow], resid[srow], sm, p1_g[split], p2_g[split])
        sd = M1_s / sm[:, None]
        sc = M2_s / sm[:, None, None] - sd[:, :, None] * sd[:, None, :]
        means = np.concatenate([means[rest_ok], m[srow] + sd])
        covs = np.concatenate([covs[rest_ok], 0.5 * (sc + np.swapaxes(sc, -1, -2))])
        new_alpha = np.concatenate([new_alpha[rest_ok], alp[srow] * g_rp[split] * sm])
        out_own = np.concatenate([own[rest_ok], own[srow]])
    # renormalise the mixture weights within each track (a track with no posterior mass
    # keeps its prior weights)
    tot = np.bincount(out_own, weights=new_alpha, minlength=T)
    prior_alpha = (np.concatenate([alp[rest_ok], alp[ri_g[split]] * 0.0])
                   if np.any(split) else alp)
    good = tot[out_own] > 0.0
    new_alpha = np.where(good, new_alpha / np.where(good, tot[out_own], 1.0), prior_alpha)
    return means, covs, new_alpha, out_own


# ------------------------------------------------- Gaussians known to exist (reference)
#: looked cells farther than this many marginal sds from a target's mean are ignored
RANGE_SIGMAS = 6.0
#: a reflection image with less mass than this in the workspace is ignored
IMAGE_MASS_FLOOR = 1e-9
#: a posterior normaliser below this keeps the prior (mean projected into the workspace)
_TINY = 1e-300


def _axis_images(mean: np.ndarray, sd: np.ndarray, length: float
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Reflection images of one axis for ``K`` Gaussians: ``sign (K, 6)`` (+1 translated,
    -1 mirrored), ``shift (K, 6)`` (image position = ``sign * p + shift``) and ``mass
    (K, 6)``, each image's mass inside ``[0, length)`` (marginal normal CDF). Column 1 is
    the Gaussian itself."""
    n = np.array([-1.0, 0.0, 1.0])
    sign = np.concatenate([np.ones(3), -np.ones(3)])
    shift = 2.0 * length * np.concatenate([n, n])
    mu = sign[None, :] * mean[:, None] + shift[None, :]  # (K, 6)
    sd = np.maximum(sd, 1e-300)[:, None]
    mass = ndtr((length - mu) / sd) - ndtr(-mu / sd)
    K = len(mean)
    return np.broadcast_to(sign, (K, 6)), np.broadcast_to(shift, (K, 6)), mass


def reflection_images(m: np.ndarray, P: np.ndarray, grid: Grid
                      ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The Gaussians whose sum, restricted to the workspace, is the density of the
    state folded into it by reflection (the simulator's boundary rule).

    Per axis the images of ``N(m, P)`` are ``p + 2nL`` and ``2nL - p`` (that velocity
    negated on a mirror), ``n`` in ``{-1, 0, 1}``; an image is kept when its mass inside
    ``W`` (product of its axes' masses, the x-y correlation ignored) exceeds
    :data:`IMAGE_MASS_FLOOR`, and the Gaussian itself always. ``m (K, 4)``,
    ``P (K, 4, 4)``. Returns ``owner (J,)`` (the target of each image, non-decreasing),
    ``means (J, 4)`` and ``covs (J, 4, 4)``; a target far from the walls has exactly one
    image, itself.
    """
    width, height = grid.extent
    sgx, shx, mx = _axis_images(m[:, 0], np.sqrt(np.maximum(P[:, 0, 0], 0.0)), width)
    sgy, shy, my = _axis_images(m[:, 2], np.sqrt(np.maximum(P[:, 2, 2], 0.0)), height)
    keep = mx[:, :, None] * my[:, None, :] > IMAGE_MASS_FLOOR  # (K, 6, 6)
    keep[:, 1, 1] = True
    owner, ix, iy = np.nonzero(keep)
    sign = np.stack([sgx[owner, ix], sgx[owner, ix], sgy[owner, iy], sgy[owner, iy]], axis=1)
    shift = np.zeros((len(owner), 4))
    shift[:, 0], shift[:, 2] = shx[owner, ix], shy[owner, iy]
    means = sign * m[owner] + shift
    covs = sign[:, :, None] * P[owner] * sign[:, None, :]
    return owner, means, covs


#: how the prior is held to the workspace: folded into it, truncated to it, or not at all
WORKSPACE_RULES = ("reflect", "truncate", "none")


def known_existence_update(m: np.ndarray, P: np.ndarray, cells: np.ndarray,
                           returns: np.ndarray, grid: Grid,
                           sensor: RayleighGridSensor | None,
                           own_cells: np.ndarray | None = None, workspace: str = "truncate",
                           range_sigmas: float = RANGE_SIGMAS
                           ) -> tuple[np.ndarray, np.ndarray]:
    """Grid update of ``K`` independent targets that are known to exist.

    ``m (K, 4)``, ``P (K, 4, 4)``: the predicted Gaussians (rows ``[px, vx, py, vy]``,
    workspace units). ``cells (L,)``, ``returns (L,)``: the looks of the step (repeats
    allowed: they multiply; ``sensor`` may be None when there is none). ``own_cells
    (K,)``: each target's true cell (-1: none); given, target ``k`` sees a positive look
    as positive only at ``own_cells[k]`` and as a miss anywhere else (the detections of
    other targets and false alarms attributed by the truth); None, every target sees
    every return as it is. ``workspace``: ``"reflect"``, the prior is ``N(m, P)`` folded
    into the workspace ``W`` (the sum of :func:`reflection_images` on ``W``);
    ``"truncate"``, ``N(m, P)`` restricted to ``W``; ``"none"``, ``N(m, P)`` as it is.
    Each target's posterior, prior times ``g`` (``Lambda_c`` in looked cell ``c``, 1
    elsewhere), is moment-matched to one Gaussian (equations in the module docstring).
    Returns the posterior means ``(K, 4)`` and covariances ``(K, 4, 4)`` (new arrays).
    """
    if workspace not in WORKSPACE_RULES:
        raise ValueError(f"workspace must be one of {WORKSPACE_RULES}, got {workspace!r}")
    m = np.asarray(m, dtype=float).reshape(-1, 4)
    P = np.asarray(P, dtype=float).reshape(-1, 4, 4)
    K = len(m)
    cells = np.asarray(cells, dtype=np.int64).reshape(-1)
    returns = np.asarray(returns, dtype=bool).reshape(-1)
    if K == 0:
        return m.copy(), P.copy()
    s = grid.cell_size
    width, height = grid.extent
    # the prior's components: the images of each target (reflect) or the target itself
    if workspace == "reflect":
        owner, cm, cP = reflection_images(m, P, grid)
    else:
        owner, cm, cP = np.arange(K), m, P
    J = len(owner)
    sx = np.sqrt(np.maximum(cP[:, 0, 0], 0.0))
    sy = np.sqrt(np.maximum(cP[:, 2, 2], 0.0))

    # ---- the workspace term per component: mass, M1, M2 of N on W (exactly 1, 0, P
    # when W holds its 6-sigma box, or without a workspace rule)
    mass_w = np.ones(J)
    M1_w = np.zeros((J, 4))
    M2_w = cP.copy()
    if workspace != "none":
        edge = ((cm[:, 0] - range_sigmas * sx < 0) | (cm[:, 0] + range_sigmas * sx > width)
                | (cm[:, 2] - range_sigmas * sy < 0) | (cm[:, 2] + range_sigmas * sy > height))
        e = np.nonzero(edge)[0]
        if len(e):
            zeros, ones = np.zeros(len(e)), np.ones(len(e))
            mass_w[e], M1_w[e], M2_w[e] = rect_state_moments(
                cm[e], cP[e], zeros, width * ones, zeros, height * ones)

    # ---- (component, looked cell) pairs within range, log Lambda of each pair
    if len(cells):
        U, inv = np.unique(cells, return_inverse=True)
        n_pos = np.bincount(inv, weights=returns, minlength=len(U))
        n_all = np.bincount(inv, minlength=len(U)).astype(float)
        # log Lambda of one positive and of one negative look, one target in the cell
        ll_pos, ll_neg = sensor.log_likelihood_ratio(np.array([True, False]), np.ones(2))
        pj, pu = looked_in_boxes(np.floor((cm[:, 0] - range_sigmas * sx) / s),
                                 np.floor((cm[:, 0] + range_sigmas * sx) / s),
                                 np.floor((cm[:, 2] - range_sigmas * sy) / s),
                                 np.floor((cm[:, 2] + range_sigmas * sy) / s), U,
                                 grid.nx, grid.ny)
        seen_pos = n_pos[pu]
        if own_cells is not None:  # a positive look elsewhere than its own cell is a miss
            own = np.asarray(own_cells, dtype=np.int64).reshape(-1)
            seen_pos = np.where(U[pu] == own[owner[pj]], seen_pos, 0.0)
        log_lam = seen_pos * ll_pos + (n_all[pu] - seen_pos) * ll_neg  # per pair
    else:
        log_lam = np.zeros(0)
        pj = pu = np.zeros(0, dtype=np.int64)

    # scale: every weight of a target divided by exp(top), top = max(0, its largest
    # log Lambda), so that many positive repeats cannot overflow
    top = np.zeros(K)
    if len(pj):
        np.maximum.at(top, owner[pj], log_lam)
    base = np.exp(-top)[owner]  # (J,) weight of the workspace term (Lambda = 1)
    Zc = base * mass_w  # per component: weight, and moments centred on its mean
    S1 = base[:, None] * M1_w
    S2 = base[:, None, None] * M2_w
    if len(pj):
        x0, x1, y0, y1 = grid.cell_bounds(U[pu])
        mass_c, M1_c, M2_c = rect_state_moments(cm, cP, x0.astype(float), x1.astype(float),
                                                y0.astype(float), y1.astype(float), owner=pj)
        coef = np.exp(log_lam - top[owner[pj]]) - base[pj]  # (Lambda_c - 1) / exp(top)
        np.add.at(Zc, pj, coef * mass_c)
        np.add.at(S1, pj, coef[:, None] * M1_c)
        np.add.at(S2, pj, coef[:, None, None] * M2_c)

    # ---- per target: the moments of the sum of its components
    Z = np.bincount(owner, weights=Zc, minlength=K)
    raw1 = np.zeros((K, 4))
    np.add.at(raw1, owner, Zc[:, None] * cm + S1)
    ok = Z > _TINY * np.exp(-top)
    mean = np.where(ok[:, None], raw1 / np.where(ok, Z, 1.0)[:, None], m)
    delta = cm - mean[owner]  # component mean minus the target's posterior mean
    second = (S2 + S1[:, :, None] * delta[:, None, :] + delta[:, :, None] * S1[:, None, :]
              + Zc[:, None, None] * delta[:, :, None] * delta[:, None, :])
    S = np.zeros((K, 4, 4))
    np.add.at(S, owner, second)
    means, covs = m.copy(), P.copy()
    means[ok] = mean[ok]
    cv = S[ok] / Z[ok, None, None]
    covs[ok] = 0.5 * (cv + np.swapaxes(cv, -1, -2))
    if not np.all(ok) and workspace != "none":
        # no mass left in W at all (a mean far outside with a tiny covariance): keep the
        # prior, its position projected onto the workspace
        bad = ~ok
        means[bad, 0] = np.clip(m[bad, 0], 0.0, np.nextafter(width, 0.0))
        means[bad, 2] = np.clip(m[bad, 2], 0.0, np.nextafter(height, 0.0))
    return means, covs


def fold_into_workspace(m: np.ndarray, P: np.ndarray, grid: Grid
                        ) -> tuple[np.ndarray, np.ndarray]:
    """Mean ``(K, 4)`` and covariance ``(K, 4, 4)`` of ``N(m, P)`` folded into the
    workspace by reflection (:func:`known_existence_update` without looks): the mass
    beyond a wall mirrored back, position and that axis's velocity, as the truth
    reflects. Used by the GPF's predict and the truth-aided reference. A Gaussian whose
    ``RANGE_SIGMAS`` box lies inside the workspace is returned as it is (its images' masses
    are below :data:`IMAGE_MASS_FLOOR`, so the fold would only symmetrise ``P``). With the
    compiled backend :func:`.update_kernels.reflection_images` and
    :func:`.update_kernels.fold_moments` compute the same numbers."""
    m = np.asarray(m, dtype=float).reshape(-1, 4)
    P = np.asarray(P, dtype=float).reshape(-1, 4, 4)
    width, height = grid.extent
    kernels = compiled_gpf_kernels()
    if kernels is not None:
        edge = kernels.near_walls(np.ascontiguousarray(m), np.ascontiguousarray(P), RANGE_SIGMAS,
                                  float(width), float(height))
    else:
        sx = RANGE_SIGMAS * np.sqrt(np.maximum(P[:, 0, 0], 0.0))
        sy = RANGE_SIGMAS * np.sqrt(np.maximum(P[:, 2, 2], 0.0))
        edge = np.nonzero((m[:, 0] - sx < 0) | (m[:, 0] + sx > width)
                          | (m[:, 2] - sy < 0) | (m[:, 2] + sy > height))[0]
    means, covs = m.copy(), P.copy()
    if len(edge) and kernels is not None:
        # the same numbers in two passes around the images' regression (numpy's matmul)
        me, Pe = m[edge], P[edge]
        owner, cm, cP, reach = kernels.reflection_images(me, Pe, float(width), float(height),
                                                         IMAGE_MASS_FLOOR, RANGE_SIGMAS)
        B, resid = position_regression(cP[reach])
        means[edge], covs[edge] = kernels.fold_moments(
            me, Pe, owner, cm, cP, reach, B, resid, float(width), float(height),
            float(np.nextafter(width, 0.0)), float(np.nextafter(height, 0.0)), _TINY,
            *_gl_table())
    elif len(edge):
        means[edge], covs[edge] = known_existence_update(
            m[edge], P[edge], np.zeros(0, np.int64), np.zeros(0, bool), grid, None,
            workspace="reflect")
    return means, covs
