"""Information-driven cell selection: the expected Renyi alpha-divergence gain of a look.

Kreucher, Kastella and Hero (Signal Processing, 2005) choose where to look by the
expected alpha-divergence between the posterior after a look and the prior before
it. We apply it per cell to the tracker's predicted count distribution ``P_c(t)``
(``(n_cells, n_counts)``, column ``t`` = probability of ``t`` targets in cell ``c``,
the last column "that many or more", evaluated at ``t`` = its column index), given
dense or as a :class:`~mttbench.trackers.cells.CellCounts` (own rows plus one default
row: the gains are then computed once per distinct row, :func:`greedy_looks_sparse`).

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

import heapq

import numpy as np

from ...trackers.cells import CellCounts


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
    from scipy.stats import binom  # here: scipy.stats costs most commands 0.8 s to import

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
#: grids of at most this many cells (the 50x50 presets and smaller):
#: :func:`greedy_looks` turns a :class:`CellCounts` into the dense array and chooses
#: exactly as it does from that array, so those presets keep their looks
DENSE_CELLS = 2500


def greedy_looks(counts: np.ndarray | CellCounts, p_detect: np.ndarray, n_looks: int,
                 alpha: float = 0.5, repeats: bool = True,
                 rng: np.random.Generator | None = None,
                 tables: dict[int, np.ndarray] | None = None,
                 dense_cells: int = DENSE_CELLS, *, blocked: np.ndarray | None = None,
                 weights: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
    """Choose ``n_looks`` looks by expected gain; returns flat cells ``(L,)`` int64.

    ``counts`` is the dense ``(n_cells, n_counts)`` array or a :class:`CellCounts`. A
    :class:`CellCounts` on a grid of more than ``dense_cells`` cells takes
    :func:`greedy_looks_sparse` (nothing per cell of the grid, the same rule with other
    random tie-breaks); on a smaller grid it is made dense first, so the choice is the
    one described here, bit for bit.

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

    ``blocked`` (sorted flat cells) cannot be looked at: they are never chosen, and
    ``repeats=False`` takes ``min(n_looks, visible cells)`` cells. ``weights`` ``(cells
    (n,), factors (n,) > 0)`` multiplies those cells' gains (every other cell: 1), so the
    choice maximises ``w_c G_c(1)`` (``w_c (G_c(n_c + 1) - G_c(n_c))`` with repeats).
    Neither given (or both empty): the choice above, bit for bit.
    """
    tables = {} if tables is None else tables
    blocked = None if blocked is None or not len(blocked) else np.asarray(blocked, np.int64)
    if weights is not None and not len(weights[0]):
        weights = None
    if isinstance(counts, CellCounts):
        if counts.n_cells > dense_cells:
            return greedy_looks_sparse(counts, p_detect, n_looks, alpha, repeats, rng, tables,
                                       blocked=blocked, weights=weights)
        counts = counts.dense()
    pd = np.asarray(p_detect, dtype=float)

    def table(n: int) -> np.ndarray:
        if n not in tables:
            tables[n] = binomial_likelihood(pd, n)
        return tables[n]

    P = np.asarray(counts, dtype=float)
    n_cells = P.shape[0]
    perm = rng.permutation(n_cells) if rng is not None else np.arange(n_cells)
    P = P[perm]  # work in a shuffled order: the first maximum is then a random one
    first = expected_gain(P, table(1), alpha)
    n_visible = n_cells
    scale = None
    if weights is not None:  # in the shuffled order, like P
        w = np.ones(n_cells)
        w[np.asarray(weights[0], dtype=np.int64)] = np.asarray(weights[1], dtype=float)
        scale = w[perm]
        first = first * scale
    if blocked is not None:
        blind = np.zeros(n_cells, dtype=bool)
        blind[blocked] = True
        blind = blind[perm]
        n_visible = n_cells - int(blind.sum())
        first = np.where(blind, -np.inf, first)
        if n_visible == 0:
            return np.zeros(0, dtype=np.int64)
    if not repeats:
        m = min(int(n_looks), n_visible)
        order = np.argsort(-first, kind="stable")[:m]
        return np.sort(perm[order]).astype(np.int64)
    # G_c(n) for every cell and n = 0..n_pre in a few vectorised calls; a cell that
    # gets more than n_pre looks has its later gains computed one at a time
    n_pre = min(int(n_looks), _PRECOMPUTED_LOOKS) + 1
    curve = np.zeros((n_cells, n_pre + 1))
    curve[:, 1] = first
    for n in range(2, n_pre + 1):
        curve[:, n] = expected_gain(P, table(n), alpha)
        if scale is not None:
            curve[:, n] *= scale
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
               else expected_gain(P[c:c + 1], table(n + 1), alpha)[0]
               * (1.0 if scale is None else scale[c]))
        marginal[c] = nxt - gain_now[c]
    return np.sort(perm[chosen]).astype(np.int64)


def greedy_looks_sparse(counts: CellCounts, p_detect: np.ndarray, n_looks: int,
                        alpha: float = 0.5, repeats: bool = True,
                        rng: np.random.Generator | None = None,
                        tables: dict[int, np.ndarray] | None = None, *,
                        blocked: np.ndarray | None = None,
                        weights: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
    """:func:`greedy_looks` on a :class:`CellCounts` without touching every cell.

    The gains are computed once per distinct row: each own row and the one default row
    (``O(own cells)``); cells with the default row are drawn with
    :meth:`CellCounts.default_cell`, never listed. The rule is :func:`greedy_looks`'s;
    only the random tie-breaks are drawn differently (the dense path permutes all cells):

    * ``repeats=False``: the own cells of gain above the default row's by gain (ties among
      them in a random order), then, if looks remain, cells drawn uniformly without
      replacement from those tied with the default row (the default cells and the own
      cells of exactly the default gain), then the own cells below it by gain.
    * ``repeats=True``: greedy by marginal gain with a heap; every cell has a random key,
      i.i.d. uniform (the own cells' drawn up front, the default cells' drawn as the
      successive minima of the keys of the default cells not yet chosen), and exact ties
      go to the fewest looks, then the smallest key, as a random permutation would.
      Only the ``n_looks`` own cells first in (gain, key) order can be chosen, so the
      heap holds at most ``n_looks + 1`` entries.

    ``rng`` None: deterministic tie-breaks (by cell index). Cost ``O(own cells * n_counts
    + n_looks log n_looks)`` plus the binomial tables.

    ``blocked`` and ``weights`` as in :func:`greedy_looks`: their cells are made own cells
    first (their rows the default row where the tracker gave none; ``O((own + blocked +
    weighted) log)``), the blocked ones with gain ``-inf`` (never chosen), the weighted
    ones with their gains multiplied; the default row keeps weight 1.
    """
    tables = {} if tables is None else tables
    pd = np.asarray(p_detect, dtype=float)
    extra = [np.asarray(x, dtype=np.int64) for x in
             ((blocked if blocked is not None else ()),
              (weights[0] if weights is not None else ()))]
    if any(len(x) for x in extra):
        cells = np.union1d(counts.cells, np.concatenate(extra))
        counts = CellCounts(counts.n_cells, cells, counts.row_of(cells), counts.default)

    def table(n: int) -> np.ndarray:
        if n not in tables:
            tables[n] = binomial_likelihood(pd, n)
        return tables[n]

    m = len(counts.cells)
    L = int(n_looks)
    rows = np.vstack([counts.rows, counts.default[None]])  # the distinct rows: own + default
    first = expected_gain(rows, table(1), alpha)
    own_gain, g_def = first[:m], float(first[m])
    own_scale = np.ones(m)
    if weights is not None:
        at = np.searchsorted(counts.cells, np.asarray(weights[0], dtype=np.int64))
        own_scale[at] = np.asarray(weights[1], dtype=float)
        own_gain = own_gain * own_scale
    n_visible = counts.n_cells
    if blocked is not None:
        blind = np.searchsorted(counts.cells, blocked)
        own_gain = own_gain.copy()
        own_gain[blind] = -np.inf
        n_visible -= len(blocked)
        if n_visible == 0:
            return np.zeros(0, dtype=np.int64)
    if not repeats:
        return _top_cells(counts, own_gain, g_def, min(L, n_visible), rng)
    # candidate own cells: the first L in (gain descending, key ascending) order, never
    # a blocked one
    key = rng.random(m) if rng is not None else counts.cells / max(counts.n_cells, 1)
    cand = np.lexsort((key, -own_gain))[:L]
    cand = cand[np.isfinite(own_gain[cand])]
    n_pre = min(L, _PRECOMPUTED_LOOKS) + 1
    curve_rows = np.vstack([counts.rows[cand], counts.default[None]])
    curve_scale = np.append(own_scale[cand], 1.0)
    curve = np.zeros((len(cand) + 1, n_pre + 1))
    curve[:-1, 1], curve[-1, 1] = own_gain[cand], g_def
    for n in range(2, n_pre + 1):
        curve[:, n] = expected_gain(curve_rows, table(n), alpha) * curve_scale
    later: dict[tuple[int, int], float] = {}  # G(n) beyond n_pre, by (candidate, n)

    def gain(i: int, n: int) -> float:
        """``w G(n)`` of candidate ``i`` (``i = len(cand)``: the default row, shared)."""
        if n <= n_pre:
            return float(curve[i, n])
        if (i, n) not in later:
            later[i, n] = float(expected_gain(curve_rows[i:i + 1], table(n), alpha)[0]
                                * curve_scale[i])
        return later[i, n]

    # heap entries: (-marginal, looks given, key, candidate, cell); default cells that have
    # been chosen are candidates of their own (row index len(cand))
    heap = [(-curve[i, 1], 0, float(key[c]), i, int(counts.cells[c]))
            for i, c in enumerate(cand)]
    fresh = _DefaultPool(counts, rng)
    if fresh.left:
        heap.append((-g_def, 0, fresh.key, -1, -1))
    heapq.heapify(heap)
    chosen = np.empty(L, dtype=np.int64)
    for j in range(L):
        neg, n, k, i, cell = heapq.heappop(heap)
        if i == -1:  # the next fresh default cell (smallest key among those not chosen)
            cell, i = fresh.take(), len(cand)
            if fresh.left:
                heapq.heappush(heap, (-g_def, 0, fresh.key, -1, -1))
        chosen[j] = cell
        n += 1
        heapq.heappush(heap, (-(gain(i, n + 1) - gain(i, n)), n, k, i, cell))
    return np.sort(chosen)


def _top_cells(counts: CellCounts, own_gain: np.ndarray, g_def: float, L: int,
               rng: np.random.Generator | None) -> np.ndarray:
    """The ``L`` distinct cells of largest single-look gain (:func:`greedy_looks_sparse`,
    ``repeats=False``), sorted."""
    m = len(own_gain)
    perm = rng.permutation(m) if rng is not None else np.arange(m)
    order = perm[np.argsort(-own_gain[perm], kind="stable")]
    g = own_gain[order]
    # blocked own cells (gain -inf) are in none of the three
    above, tie = order[g > g_def], order[g == g_def]
    below = order[(g < g_def) & np.isfinite(g)]
    if len(above) >= L:
        return np.sort(counts.cells[above[:L]])
    need = L - len(above)
    n_tie = len(tie) + counts.n_default
    if n_tie >= need:
        pick = (rng.choice(n_tie, size=need, replace=False) if rng is not None
                else np.arange(need))
        from_own = pick < len(tie)
        tied = np.concatenate([counts.cells[tie[pick[from_own]]],
                               counts.default_cell(pick[~from_own] - len(tie))])
        rest = np.zeros(0, dtype=np.int64)
    else:  # fewer tied cells than looks left: all of them (a small grid), then the rest
        tied = np.concatenate([counts.cells[tie],
                               counts.default_cell(np.arange(counts.n_default))])
        rest = counts.cells[below[:need - n_tie]]
    return np.sort(np.concatenate([counts.cells[above], tied, rest])).astype(np.int64)


class _DefaultPool:
    """The default cells not yet chosen by :func:`greedy_looks_sparse`, with random keys.

    The keys of the ``n`` cells left are i.i.d. uniform; the smallest is drawn as
    ``x + (1 - x)(1 - V^(1/n))`` above the previous one ``x`` (``V`` uniform), and the
    cell that holds it is uniform among those left. ``rng`` None: the lowest default
    cell first, its key its index over the grid's size.
    """

    def __init__(self, counts: CellCounts, rng: np.random.Generator | None) -> None:
        self.counts, self.rng = counts, rng
        self.left = counts.n_default
        self.taken: list[int] = []  # ranks among the default cells, sorted
        self.key = 0.0
        self._draw_key()

    def _draw_key(self) -> None:
        if not self.left:
            return
        if self.rng is None:
            nxt = self.counts.default_cell(np.array([len(self.taken)]))[0]
            self.key = float(nxt) / max(self.counts.n_cells, 1)
        else:
            v = self.rng.random()
            self.key = self.key + (1.0 - self.key) * -np.expm1(np.log1p(-v) / self.left)

    def take(self) -> int:
        """The cell holding the current smallest key; draws the next key."""
        if self.rng is None:
            rank = len(self.taken)
        else:  # the k-th default cell not taken yet, uniformly
            k = int(self.rng.integers(self.left))
            taken = np.asarray(self.taken, dtype=np.int64)
            rank = k + int(np.searchsorted(taken - np.arange(len(taken)), k, side="right"))
        self.taken.insert(int(np.searchsorted(self.taken, rank)), rank)
        self.left -= 1
        self._draw_key()
        return int(self.counts.default_cell(np.array([rank]))[0])
