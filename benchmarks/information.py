"""Information-driven cell selection: the expected Renyi alpha-divergence gain of a look.

Kreucher, Kastella and Hero (Signal Processing, 2005) choose where to look by the
expected alpha-divergence between the posterior after a look and the prior before
it. We apply it per cell to the tracker's predicted count distribution ``P_c(t)``
(``(n_cells, n_counts)``, column ``t`` = probability of ``t`` targets in cell ``c``,
the last column "that many or more", evaluated at ``t`` = its column index).

One binary look at cell ``c`` returns ``z in {0, 1}`` with ``p(1|t) = p_d(t)``, the
Rayleigh model's detection probability. The posterior given ``z`` is
``P_c(t) p(z|t) / p(z)`` with ``p(z) = sum_t P_c(t) p(z|t)``, and::

    D_alpha(post || prior) = 1/(alpha-1) log sum_t post(t)^alpha prior(t)^(1-alpha)
                           = 1/(alpha-1) log( sum_t P_c(t) p(z|t)^alpha / p(z)^alpha )

    G_c = E_z[D_alpha] = sum_z p(z)/(alpha-1) log( sum_t P_c(t) p(z|t)^alpha / p(z)^alpha )

At ``alpha = 1`` the limit is the mutual information between the look and the count,
``sum_{z,t} P_c(t) p(z|t) log(p(z|t) / p(z))``. Outcomes with ``p(z) = 0`` never
happen and contribute 0; terms with ``P_c(t) p(z|t) = 0`` contribute 0 to the sums.

``n`` looks at one cell are independent given ``t``, so the posterior after an
outcome sequence depends on it only through the number of positives ``s``, which is
``Binomial(n, p_d(t))`` given ``t``; hence ``G_c(n)`` is the same closed form with the
outcome ``z`` replaced by ``s in {0..n}`` and ``p(s|t) = binom.pmf(s, n, p_d(t))``.
:func:`expected_gain` takes any such outcome table.

Deviation from the paper: the paper's gain is computed on the whole joint density;
here it is computed per cell on the marginal ``P_c`` and looks at different cells
are scored independently (the total gain of a set of looks is taken as the sum of
per-cell gains). This is what lets every tracker share one policy: each tracker
only has to provide ``P_c(t)``.
"""

from __future__ import annotations

import numpy as np
from scipy.stats import binom


def expected_gain(counts: np.ndarray, likelihood: np.ndarray, alpha: float = 0.5) -> np.ndarray:
    """Expected Renyi alpha-divergence between posterior and prior of each cell's count.

    ``G_c = sum_z p(z)/(alpha-1) log( sum_t P_c(t) p(z|t)^alpha / p(z)^alpha )``, and
    the mutual information ``sum_{z,t} P_c(t) p(z|t) log(p(z|t)/p(z))`` at ``alpha = 1``.

    Parameters
    ----------
    counts : ``(n_cells, n_counts)`` rows ``P_c(t)``, non-negative, summing to 1.
    likelihood : ``(n_outcomes, n_counts)`` table ``p(z|t)``, each column a distribution
        over outcomes (for one look ``[1 - p_d(t), p_d(t)]``), or ``(n_counts,)`` holding
        ``p(1|t)`` of a single binary look. Shared by all cells.
    alpha : order of the divergence, ``> 0``.

    Returns
    -------
    ``(n_cells,)`` float64 gains in nats. Non-negative up to rounding (not clipped),
    exactly 0 for a cell whose count is certain.
    """
    if not alpha > 0:
        raise ValueError(f"alpha must be > 0, got {alpha}")
    P = np.asarray(counts, dtype=float)
    lik = np.asarray(likelihood, dtype=float)
    if lik.ndim == 1:
        lik = np.stack([1.0 - lik, lik])
    if P.ndim != 2 or lik.ndim != 2 or lik.shape[1] != P.shape[1]:
        raise ValueError(f"counts {P.shape} and likelihood {lik.shape} do not match")
    # joint P_c(t) p(z|t): (n_cells, n_outcomes, n_counts)
    joint = P[:, None, :] * lik[None, :, :]
    pz = joint.sum(axis=2)  # (n_cells, n_outcomes)
    happens = pz > 0.0
    safe_pz = np.where(happens, pz, 1.0)
    # likelihood ratio p(z|t)/p(z): finite wherever p(z) > 0; where P_c(t) = 0 it is
    # multiplied by 0 below, and for p(z) = 0 the whole outcome is masked out
    ratio = lik[None, :, :] / safe_pz[:, :, None]
    weight = np.where(happens, pz, 0.0)
    if alpha == 1.0:
        # mutual information; 0 log 0 = 0 wherever P_c(t) p(z|t) = 0
        pos = joint > 0.0
        terms = np.where(pos, joint * np.log(np.where(pos, ratio, 1.0)), 0.0)
        return terms.sum(axis=(1, 2))
    # sum_t P_c(t) (p(z|t)/p(z))^alpha = sum_t post^alpha prior^(1-alpha)
    # (terms with P_c(t) = 0 are skipped so that 0 * inf cannot appear for alpha > 1)
    inner = np.where(P[:, None, :] > 0.0, P[:, None, :] * ratio**alpha, 0.0).sum(axis=2)
    log_inner = np.log(np.where(happens, inner, 1.0))
    return (weight * log_inner).sum(axis=1) / (alpha - 1.0)


def binomial_likelihood(p_detect: np.ndarray, n_looks: int) -> np.ndarray:
    """``p(s|t) = binom.pmf(s, n, p_d(t))``: ``(n_looks + 1, n_counts)`` for ``s = 0..n``.

    ``p_detect`` is ``(n_counts,)``, ``p_d(t)`` at each count column ``t``.
    """
    s = np.arange(n_looks + 1)[:, None]
    return binom.pmf(s, n_looks, np.asarray(p_detect, dtype=float)[None, :])


def gain_of_looks(counts: np.ndarray, p_detect: np.ndarray, n_looks: int,
                  alpha: float = 0.5) -> np.ndarray:
    """``G_c(n)``: expected gain of ``n`` independent looks at each cell, ``(n_cells,)``.

    ``G_c(0) = 0``. ``counts`` is ``(n_cells, n_counts)``, ``p_detect`` ``(n_counts,)``.
    """
    counts = np.asarray(counts, dtype=float)
    if n_looks == 0:
        return np.zeros(counts.shape[0])
    return expected_gain(counts, binomial_likelihood(p_detect, n_looks), alpha)


#: looks per cell whose gains :func:`greedy_looks` computes for all cells at once
_PRECOMPUTED_LOOKS = 3


def greedy_looks(counts: np.ndarray, p_detect: np.ndarray, n_looks: int, alpha: float = 0.5,
                 repeats: bool = True, rng: np.random.Generator | None = None,
                 tables: dict[int, np.ndarray] | None = None) -> np.ndarray:
    """Choose ``n_looks`` looks by expected gain; returns flat cells ``(L,)`` int64.

    ``repeats=False``: the ``min(n_looks, n_cells)`` distinct cells of largest ``G_c(1)``.

    ``repeats=True``: greedy over marginal gains. With ``n_c`` looks already given to
    cell ``c``, the next look goes to ``argmax_c G_c(n_c + 1) - G_c(n_c)``. ``G_c(n)`` is
    computed for all cells up to a few looks at once, beyond that only for the chosen
    cell, so a step costs ``O(n_looks * n_cells)`` for the argmaxes plus
    ``O(n_looks^2 * n_counts)`` for the binomial tables.

    Exact ties (for example a flat prior) go to the cell with the fewest looks so far,
    then uniformly at random with ``rng`` (lowest index first if ``rng`` is None), so a
    flat prior does not always look at the first cells of the grid, and an all-zero
    gain (every count certain) spreads the looks over distinct cells. ``tables``
    optionally caches the binomial tables ``p(s|t)`` by ``n`` across calls with the
    same ``p_detect``.
    """
    tables = {} if tables is None else tables

    def table(n: int) -> np.ndarray:
        if n not in tables:
            tables[n] = binomial_likelihood(pd, n)
        return tables[n]

    P = np.asarray(counts, dtype=float)
    pd = np.asarray(p_detect, dtype=float)
    n_cells = P.shape[0]
    perm = rng.permutation(n_cells) if rng is not None else np.arange(n_cells)
    P = P[perm]  # work in a shuffled order: the first maximum is then a random one
    first = expected_gain(P, table(1), alpha)
    if not repeats:
        m = min(int(n_looks), n_cells)
        order = np.argsort(-first, kind="stable")[:m]
        return np.sort(perm[order]).astype(np.int64)
    # G_c(n) for every cell and n = 0..n_pre in a few vectorised calls; a cell that
    # gets more than n_pre looks has its later gains computed one at a time
    n_pre = min(int(n_looks), _PRECOMPUTED_LOOKS) + 1
    curve = np.zeros((n_cells, n_pre + 1))
    curve[:, 1] = first
    for n in range(2, n_pre + 1):
        curve[:, n] = expected_gain(P, table(n), alpha)
    n_given = np.zeros(n_cells, dtype=np.int64)
    gain_now = np.zeros(n_cells)  # G_c(n_c)
    marginal = first.copy()  # G_c(n_c + 1) - G_c(n_c)
    chosen = np.empty(int(n_looks), dtype=np.int64)
    for j in range(int(n_looks)):
        # among cells of equal (largest) marginal gain, the one with fewest looks so far:
        # with a flat or certain prediction the looks spread out instead of piling up
        best = marginal == marginal.max()
        c = int(np.argmin(np.where(best, n_given, np.iinfo(np.int64).max)))
        chosen[j] = c
        n = int(n_given[c]) + 1
        n_given[c] = n
        gain_now[c] = curve[c, n] if n <= n_pre else gain_now[c] + marginal[c]
        nxt = (curve[c, n + 1] if n + 1 <= n_pre
               else expected_gain(P[c:c + 1], table(n + 1), alpha)[0])
        marginal[c] = nxt - gain_now[c]
    return np.sort(perm[chosen]).astype(np.int64)
