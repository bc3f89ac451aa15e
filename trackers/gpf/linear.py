"""GPF kernels for the paper's superposition sensor, and the combination enumeration.

Two pieces of the Gaussian particle filter (paper Section IV and its appendix):

* :func:`enumerate_combinations` -- the paper's combinations ``E``: every joint choice of
  one option per particle (for the linear sensor the options are "present" / "absent";
  the grid update adds "in looked cell c" / "elsewhere") whose prior probability exceeds
  ``epsilon`` (at most ``max_combinations``, the most probable), found by a vectorised
  branch and bound so that 2^K choices are never listed, together with the probability
  mass the threshold and the cap drop.
* :func:`superposition_update` -- the update of ``K`` weighted Gaussians by one
  measurement ``z = (1/n) sum_{i present} H x_i + w``, ``w ~ N(0, R)``.

Superposition update, for one combination ``E`` with ``n = |E| >= 1`` present particles
(the appendix's gain, with the sensor's ``H`` in place of the paper's identity)::

    S_E   = R + (1/n^2) sum_{i in E} H Sigma_i H^T                 (m, m)
    zhat  = (1/n) sum_{i in E} H mu_i                               (m,)
    K_j   = (1/n) Sigma_j H^T S_E^-1                                (4, m)   for j in E
    mu_j' = mu_j + K_j (z - zhat)
    Sigma_j' = Sigma_j - (1/n) K_j H Sigma_j                       (Joseph form in code)
    log w_E = sum_i log(w_i^e_i (1 - w_i)^(1 - e_i)) + log N(z; zhat, S_E)

The main text's per-particle form (measurement matrix ``H/n``, ``z`` shifted by the other
present particles' predicted means, noise ``R + (1/n^2) sum_{i != j} H Sigma_i H^T``) gives
the same innovation covariance ``S_E`` and hence the same gain. Both are the *marginal* of
the exact joint update of the stacked state ``[x_i]_{i in E}`` with ``H_joint = [H/n, ...]``,
so the per-combination moments are exact (tests/test_gpf_linear.py checks this against the
stacked update). The paper's printed covariance update has ``1/n`` where ``1/n^2`` belongs
inside the inverse and ``1/n`` (not ``1/n^2``) in front; we use the derivation's result above.
The paper's combination weight has typos (``||Sigma^-1||`` and no ``1/2`` in the exponent);
we use the Gaussian density.

Choices where the paper is silent (documented in the tracker too):

* Empty combination (``n = 0``): the simulator's sensor then reports pure noise, so its
  likelihood is ``N(z; 0, R)``.
* Folding the groups ``G_c`` back into one particle set: particle ``j``'s posterior
  existence is ``w_j' = sum_{E: e_j = 1} p(E | z)`` (exact marginal), and its Gaussian is the
  moment match of the mixture ``sum_{E: e_j=1} p(E|z) N(mu_j^E, Sigma_j^E) / w_j'``. This
  drops the correlation between particles that the joint update creates (the price of
  keeping one Gaussian per particle) and is exact for the first two moments of each
  particle's marginal.
* Combinations cut by ``epsilon`` (and by ``max_combinations``) are dropped and the kept
  ones renormalised; the dropped prior mass is returned.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

_LOG_2PI = math.log(2.0 * math.pi)


# ----------------------------------------------------------------- combinations
@dataclass(frozen=True)
class Combinations:
    """Joint option choices with prior probability above a threshold.

    ``choice (C, K)`` int: option index chosen by each of the ``K`` particles in each of
    the ``C`` combinations (indices into the caller's option lists), listed in decreasing
    prior probability. ``log_prior (C,)``: log prior probability of each combination.
    ``dropped (float)``: ``1 - sum(exp(log_prior))``, the prior mass cut by the threshold
    and the cap (the option probabilities of each particle must sum to 1).
    """

    choice: np.ndarray
    log_prior: np.ndarray
    dropped: float


#: largest number of joint choices of one block of particles expanded at once (see below)
_BLOCK = 64


def enumerate_combinations(option_probs: list[np.ndarray] | np.ndarray, epsilon: float,
                           max_combinations: int) -> Combinations:
    """All joint choices whose prior ``prod_k option_probs[k][choice_k]`` exceeds ``epsilon``.

    ``option_probs[k]`` is a 1-D array of the (non-negative, summing to 1) probabilities of
    particle ``k``'s options (or one ``(K, n_options)`` array padded with zeros). Particles are
    independent a priori, so a combination's prior is the product; options of probability 0 are
    never chosen. At most ``max_combinations`` are kept: the most probable ones.

    Branch and bound, vectorised over partial choices: the particles are taken in blocks
    (consecutive particles whose joint option count is at most 64, listed in full); after
    fixing the options of the particles up to a block, a partial choice's prior times the
    largest option probability of every remaining particle is the largest prior any
    completion can reach. A partial is dropped when that bound is ``<= epsilon`` (no
    completion can pass), and only the ``max_combinations`` partials with the largest bounds
    are carried on (each has a completion that reaches its bound, so a dropped partial
    cannot hold one of the ``max_combinations`` most probable combinations; ties are broken
    arbitrarily). The result is exactly the set the threshold and the cap define, listed in
    decreasing prior (if no combination exceeds ``epsilon``, the ``max_combinations`` most
    probable ones instead, so that a posterior always exists); the work is about ``C * 64``
    per block, independent of ``2^K``.
    """
    n = len(option_probs)
    if n == 0:
        return Combinations(np.zeros((1, 0), dtype=np.int64), np.zeros(1), 0.0)
    # pad to (n, n_opt_max), sort each row by decreasing probability (zeros last)
    if isinstance(option_probs, np.ndarray) and option_probs.ndim == 2:
        pad = np.asarray(option_probs, dtype=float)  # already padded with zeros
    else:
        lens = np.array([len(p) for p in option_probs])
        flat = np.concatenate([np.asarray(p, dtype=float).ravel() for p in option_probs])
        row = np.repeat(np.arange(n), lens)
        col = np.arange(len(flat)) - np.repeat(np.cumsum(lens) - lens, lens)
        pad = np.zeros((n, int(lens.max())))
        pad[row, col] = flat
    orders = np.argsort(-pad, axis=1, kind="stable")
    srt = np.take_along_axis(pad, orders, axis=1)
    n_pos = np.maximum((srt > 0.0).sum(axis=1), 1)
    with np.errstate(divide="ignore"):
        logs = np.log(srt)
    log_eps = math.log(epsilon) if epsilon > 0 else -math.inf
    best = logs[:, 0]
    rest = np.concatenate([np.cumsum(best[::-1])[::-1], [0.0]])  # rest[j] = sum_{k>=j} best
    lp = np.zeros(1)
    ranks = np.zeros((1, n), dtype=np.int64)
    start = 0
    while start < n:
        stop, size = start + 1, int(n_pos[start])
        while stop < n and size * int(n_pos[stop]) <= _BLOCK:
            size *= int(n_pos[stop])
            stop += 1
        # every joint choice of the block's particles: ranks (size, stop - start), log priors
        blk = np.indices(tuple(n_pos[start:stop])).reshape(stop - start, -1).T
        blk_lp = logs[np.arange(start, stop)[None, :], blk].sum(axis=1)
        cand = (lp[:, None] + blk_lp[None, :]).ravel()
        bound = cand + rest[stop]
        keep = np.nonzero(bound > log_eps)[0]
        if len(keep) > max_combinations:
            keep = keep[np.argpartition(-bound[keep], max_combinations - 1)[:max_combinations]]
        parent, opt = np.divmod(keep, len(blk_lp))
        ranks = ranks[parent]
        ranks[:, start:stop] = blk[opt]
        lp = cand[keep]
        start = stop
    if len(lp) == 0 and log_eps > -math.inf:
        # nothing passes epsilon (many particles, none nearly certain): keep the cap's worth
        return enumerate_combinations(option_probs, 0.0, max_combinations)
    # decreasing prior; ties in the order of the ranks (as a best-first search lists them)
    order = np.lexsort(tuple(ranks[:, j] for j in range(n - 1, -1, -1)) + (-lp,))
    ranks, lp = ranks[order], lp[order]
    choice = orders[np.arange(n)[None, :], ranks]
    dropped = max(0.0, 1.0 - float(np.exp(lp).sum()))
    return Combinations(choice, lp, dropped)


def log_normalise(log_w: np.ndarray) -> np.ndarray:
    """``exp(log_w - logsumexp(log_w))``: normalised weights without underflow."""
    top = np.max(log_w)
    w = np.exp(log_w - top)
    return w / w.sum()


# ----------------------------------------------------------- superposition update
@dataclass(frozen=True)
class SuperpositionResult:
    """Posterior of a superposition update.

    ``weights (K,)``, ``means (K, 4)``, ``covs (K, 4, 4)``: the folded particle set.
    ``present (C, K)`` bool and ``comb_weights (C,)`` (normalised ``p(E | z)``): the
    combinations kept. ``comb_means (C, K, 4)`` / ``comb_covs (C, K, 4, 4)``: each present
    particle's Gaussian given the combination (the prior where absent).
    ``dropped``: prior mass of the combinations cut by ``epsilon`` / the cap.
    """

    weights: np.ndarray
    means: np.ndarray
    covs: np.ndarray
    present: np.ndarray
    comb_weights: np.ndarray
    comb_means: np.ndarray
    comb_covs: np.ndarray
    dropped: float


def superposition_update(w: np.ndarray, m: np.ndarray, P: np.ndarray, z: np.ndarray,
                         H: np.ndarray, R: np.ndarray, epsilon: float = 0.0,
                         max_combinations: int = 4096) -> SuperpositionResult:
    """Update particles ``w (K,)``, ``m (K, 4)``, ``P (K, 4, 4)`` with ``z (m,)``.

    ``H (m, 4)``, ``R (m, m)``. Equations in the module docstring. Vectorised over
    combinations and particles (arrays ``(C, K, ...)``); ``C`` is at most
    ``max_combinations``.
    """
    w = np.clip(np.asarray(w, dtype=float), 0.0, 1.0)
    d = m.shape[1]
    r = H.shape[0]
    combs = enumerate_combinations([np.array([1.0 - wi, wi]) for wi in w], epsilon,
                                   max_combinations)
    E = combs.choice.astype(bool)  # (C, K): option 1 = present
    n = E.sum(axis=1)  # (C,)
    n_safe = np.maximum(n, 1).astype(float)
    Hm = m @ H.T  # (K, r)
    HPHt = H @ P @ H.T  # (K, r, r)
    # S_E = R + (1/n^2) sum_i e_i H P_i H^T ; zhat = (1/n) sum_i e_i H mu_i
    S = R + np.einsum("ck,kab->cab", E, HPHt) / n_safe[:, None, None] ** 2
    zhat = (E.astype(float) @ Hm) / n_safe[:, None]
    y = z[None, :] - zhat  # (C, r)
    L = np.linalg.cholesky(S)
    alpha = np.linalg.solve(L, y[..., None])[..., 0]
    log_det = 2.0 * np.log(np.diagonal(L, axis1=-2, axis2=-1)).sum(axis=-1)
    log_lik = -0.5 * (np.einsum("ca,ca->c", alpha, alpha) + log_det + r * _LOG_2PI)
    log_post = combs.log_prior + log_lik
    pc = log_normalise(log_post)  # (C,)

    # per (combination, particle) gain K_cj = (1/n) P_j H^T S_c^-1   -> (C, K, d, r)
    PHt = P @ H.T  # (K, d, r)
    S_inv = np.linalg.inv(S)
    gain = np.einsum("kdr,crs->ckds", PHt, S_inv) / n_safe[:, None, None, None]
    cm = m[None] + np.einsum("ckdr,cr->ckd", gain, y)
    # Joseph form with the effective measurement matrix H/n and the noise the others
    # make, R_j = S - (1/n^2) H P_j H^T: A P A^T + K R_j K^T, A = I - K H / n
    A = np.eye(d) - gain @ H / n_safe[:, None, None, None]
    Rj = S[:, None] - HPHt[None] / n_safe[:, None, None, None] ** 2
    Gt = np.swapaxes(gain, -1, -2)
    cP = A @ P[None] @ np.swapaxes(A, -1, -2) + gain @ Rj @ Gt
    cP = 0.5 * (cP + np.swapaxes(cP, -1, -2))
    # absent particles keep their prior in the per-combination arrays
    cm = np.where(E[..., None], cm, m[None])
    cP = np.where(E[..., None, None], cP, P[None])

    # fold: w_j' = sum_{E: e_j=1} p(E|z); moments = moment match over those E
    q = pc[:, None] * E  # (C, K)
    w_post = q.sum(axis=0)
    safe = np.where(w_post > 0.0, w_post, 1.0)
    mean = np.einsum("ck,ckd->kd", q, cm) / safe[:, None]
    dev = cm - mean[None]
    cov = (np.einsum("ck,ckab->kab", q, cP)
           + np.einsum("ck,cka,ckb->kab", q, dev, dev)) / safe[:, None, None]
    # a particle present in no kept combination keeps its prior moments
    gone = w_post <= 0.0
    mean[gone], cov[gone] = m[gone], P[gone]
    cov = 0.5 * (cov + np.swapaxes(cov, -1, -2))
    return SuperpositionResult(np.clip(w_post, 0.0, 1.0), mean, cov, E, pc, cm, cP,
                               combs.dropped)
