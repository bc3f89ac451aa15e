"""Track-level (run-level) scores: how well a tracker keeps each target's identity.

The per-step metrics of :mod:`~mttbench.benchmarks.engine.metrics` compare two sets of
positions and ignore identity: a tracker that swaps two targets at a crossing, or breaks
one track into five, scores as well as one that follows each target through. These pure
functions score a whole run, given per step ``k = 0..T-1``::

    truth[k]      (n_k, 2)  true positions          truth_ids[k]  (n_k,) int  target ids
    estimate[k]   (m_k, 2)  estimated positions     labels[k]     (m_k,) int  track labels

A *trajectory* is everything with one id (truth) or one label (estimate): its position at
the steps where it is present. Ids and labels need not be contiguous in time. Distances
are Euclidean; ``c`` is the cut-off and ``p`` the order. The scores take the run as
:func:`dense_pair` gives it too (``dense=``), so that several scores of one run convert
it once.

* :func:`trajectory_gospa` -- Garcia-Fernandez, Rahmathullah & Svensson, "A metric on the
  space of finite sets of trajectories for evaluation of multi-target tracking
  algorithms", IEEE TSP 68, 2020: the linear-programming metric with ``alpha = 2`` and
  switching cost ``gamma``, solved with HiGHS (``scipy.optimize.linprog``); the integer
  program is solved when the relaxation is not integral, so the value is the metric
  with integer assignments.
* :func:`ospa2` -- Beard, Vo & Vo, "A solution for large-scale multi-object tracking",
  IEEE TSP 68, 2020 (OSPA(2)): OSPA between the sets of tracks in a sliding window, with
  the time-averaged OSPA of two tracks as base distance; averaged over the run's windows.
* :func:`clear_mot` -- CLEAR-MOT correspondences (Bernardin & Stiefelhagen, "Evaluating
  multiple object tracking performance: the CLEAR MOT metrics", EURASIP JIVP 2008) with
  a gating distance: identity switches (in total and per step), fragmentations, mostly
  tracked / mostly lost.
* :func:`crossings` -- where the truth alone makes identity hard: the steps at which two
  true targets are closer than a stated distance, and the steps within a window of them
  (to count the switches around the crossings).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy import sparse
from scipy.optimize import linear_sum_assignment, linprog
from scipy.sparse.csgraph import connected_components
from scipy.spatial.distance import cdist

__all__ = [
    "ClearMOT",
    "Crossings",
    "OSPA2",
    "TrajectoryGOSPA",
    "as_dense",
    "dense_pair",
    "clear_mot",
    "crossings",
    "ospa2",
    "trajectory_gospa",
]


def _positions(points: np.ndarray) -> np.ndarray:
    arr = np.asarray(points, dtype=np.float64)
    if arr.size == 0:
        return arr.reshape(0, 2)
    if arr.ndim != 2 or arr.shape[1] != 2:
        raise ValueError(f"positions must have shape (k, 2), got {arr.shape}")
    return arr


def as_dense(points: Sequence[np.ndarray], ids: Sequence[np.ndarray]
             ) -> tuple[np.ndarray, np.ndarray]:
    """Per-step positions and ids -> ``(positions (T, N, 2), present (T, N))`` over the
    ``N`` distinct ids of the run (sorted); absent entries are NaN / False. Raises
    ``ValueError`` when ids and positions disagree in length or an id repeats in a step."""
    if len(points) != len(ids):
        raise ValueError(f"{len(points)} steps of positions but {len(ids)} of ids")
    T = len(points)
    if T == 0:
        return np.zeros((0, 0, 2)), np.zeros((0, 0), dtype=bool)
    pts = [_positions(x) for x in points]
    idv = [np.asarray(i, dtype=np.int64).reshape(-1) for i in ids]
    sizes = np.array([len(i) for i in idv])
    bad = np.nonzero(sizes != np.array([len(x) for x in pts]))[0]
    if len(bad):
        raise ValueError(f"step {bad[0]}: {len(pts[bad[0]])} positions but {sizes[bad[0]]} ids")
    step = np.repeat(np.arange(T), sizes)
    all_ids = np.concatenate(idv)
    universe, col = np.unique(all_ids, return_inverse=True)
    key = step * max(len(universe), 1) + col.reshape(-1)
    if len(np.unique(key)) != len(key):
        raise ValueError("an id repeats within a step")
    pos = np.full((T, len(universe), 2), np.nan)
    present = np.zeros((T, len(universe)), dtype=bool)
    pos[step, col] = np.concatenate(pts)
    present[step, col] = True
    return pos, present


def _check(c: float, p: float) -> None:
    if not (np.isfinite(c) and c > 0):
        raise ValueError(f"cut-off c must be positive and finite, got {c}")
    if not (np.isfinite(p) and p >= 1):
        raise ValueError(f"order p must be >= 1 and finite, got {p}")


# --------------------------------------------------------------- trajectory GOSPA
@dataclass(frozen=True)
class TrajectoryGOSPA:
    """Trajectory GOSPA (alpha = 2) and its parts.

    ``total`` is in position units; ``localisation``, ``missed``, ``false`` and
    ``switch`` are costs in the p-th-power domain summed over the run, so that
    ``localisation + missed + false + switch == total ** p``. ``switches`` is the number
    of switches (a change between two tracks counts 1, a change between a track and
    none 1/2), ``switch == gamma ** p * switches``. ``solver`` says how the optimal
    assignments were found: ``"none"`` (no pair is ever within ``c``), ``"dp"`` (dynamic
    programming over the steps, a unique optimum), ``"lp"`` (HiGHS, the relaxation
    integral) or ``"milp"`` (HiGHS, the integer program).
    """

    total: float
    localisation: float
    missed: float
    false: float
    switch: float
    switches: float
    solver: str


def dense_pair(truth, truth_ids, estimate, labels):
    """:func:`as_dense` of the truth and of the estimates, which must have as many steps:
    ``(X, ax, Y, ay)`` (the scores below take it as ``dense=`` when a caller has it)."""
    X, ax = as_dense(truth, truth_ids)
    Y, ay = as_dense(estimate, labels)
    if len(X) != len(Y):
        raise ValueError(f"{len(X)} steps of truth but {len(Y)} of estimates")
    return X, ax, Y, ay


def trajectory_gospa(truth: Sequence[np.ndarray], truth_ids: Sequence[np.ndarray],
                     estimate: Sequence[np.ndarray], labels: Sequence[np.ndarray],
                     c: float = 2.0, p: float = 2.0, gamma: float = 2.0, *,
                     dense: tuple | None = None) -> TrajectoryGOSPA:
    """Trajectory metric of Garcia-Fernandez, Rahmathullah & Svensson (2020), alpha = 2.

    With truth trajectories ``i = 1..nx``, estimated trajectories ``j = 1..ny`` and, per
    step ``k``, an assignment matrix ``W^k`` of size ``(nx + 1) x (ny + 1)`` (the last
    row and column: "not assigned") with unit row sums over ``i <= nx``, unit column sums
    over ``j <= ny``, ``W^k[nx+1, ny+1] = 0`` and ``W^k >= 0``::

        d(X, Y) = ( min_W  sum_k  sum_{i,j} D^k[i,j] W^k[i,j]
                    + gamma**p / 2 * sum_{k<T} sum_{i<=nx, j<=ny} |W^k[i,j] - W^{k+1}[i,j]|
                  ) ** (1/p)

        D^k[i,j] = min(d(x_i^k, y_j^k), c) ** p   both present at k
                 = c**p / 2                        exactly one present (or a dummy
                                                   against a present one)
                 = 0                               neither present

    An integer ``W`` gives the metric (switching a truth between two tracks costs
    ``gamma**p``, between a track and none ``gamma**p / 2``); its relaxation is the LP
    metric. The value returned is the metric with integer assignments.

    The program is reduced without changing its value: a pair ``(i, j)`` that is never
    present together within distance ``< c`` can be left unassigned throughout
    (assigning it costs exactly what leaving both unassigned costs, and switch costs can
    only fall), so only the other pairs ``q`` get variables ``w^k_q`` (one per step),
    with the coefficient ``D^k[i,j] - D^k[i,ny+1] - D^k[nx+1,j]`` relative to leaving
    both unassigned (``d**p - c**p`` when both are present, else 0).

    It is then solved in one of two exact ways:

    1. **Dynamic programming** (:func:`_tgospa_dp`). The pairs fall into connected
       components (two pairs are joined when they share a truth or a track); the
       program is a sum of independent programs, one per component, whose state at step
       ``k`` is a matching ``s`` of the component's pairs. With ``a_k(s) = sum_{q in s}
       coef^k_q`` and ``h(s, s') = gamma**p / 2 * |s xor s'|`` the forward and backward
       recursions::

           F_0(s) = a_0(s),      F_k(s) = min_s' [F_{k-1}(s') + h(s', s)] + a_k(s)
           B_{T-1}(s) = 0,       B_k(s) = min_s' [h(s, s') + a_{k+1}(s') + B_{k+1}(s')]

       give the optimum ``min_s F_{T-1}(s)`` over integer assignments, and ``F_k(s) +
       B_k(s)`` is the best total through state ``s`` at step ``k``. The parts below
       read ``W`` only where a pair is present together within ``c`` (elsewhere its
       coefficient is 0, so two optimal ``W`` that agree there have the same cost and
       hence the same number of switches). So when, at every step, every state whose
       total is within ``1e-6 * max(c**p, gamma**p)`` of the optimum agrees there with
       the best state, every optimal ``W`` (the integer program's included) gives the
       same parts, and the best states are taken. (Many optima differ only where this
       does not matter: a truth passed from one track to the next can switch at any
       step between them.) A component with more than :data:`_DP_MAX_STATES` matchings
       is not tried.
    2. **HiGHS** (:func:`_tgospa_highs`), when some component is not settled so: the
       whole reduced program as an LP (``scipy.optimize.linprog``), the "unassigned"
       entries eliminated through the row and column sums and ``|.|`` linearised with one
       ``e^k_q >= +-(w^k_q - w^{k+1}_q)`` each; if its optimum is not integral the
       integer program (same LP, ``W`` integer) is solved.

    Parts (from the optimal integer ``W``): ``localisation`` sums ``d**p`` over the
    assigned pairs present together within ``d < c``; every other present truth (or
    estimate) at a step costs ``c**p / 2`` in ``missed`` (``false``); ``switch`` is
    ``gamma**p / 2 * sum |W^k - W^{k+1}|``.
    """
    _check(c, p)
    if not (np.isfinite(gamma) and gamma > 0):
        raise ValueError(f"switching cost gamma must be positive and finite, got {gamma}")
    X, ax, Y, ay = dense or dense_pair(truth, truth_ids, estimate, labels)
    T = len(X)
    half = c**p / 2
    const = half * (ax.sum() + ay.sum())
    if T == 0 or X.shape[1] == 0 or Y.shape[1] == 0:
        return TrajectoryGOSPA(float(const) ** (1 / p), 0.0, half * float(ax.sum()),
                               half * float(ay.sum()), 0.0, 0.0, "none")
    # distances (T, nx, ny); NaN where either is absent
    d = np.sqrt(((X[:, :, None, :] - Y[:, None, :, :]) ** 2).sum(-1))
    both = ax[:, :, None] & ay[:, None, :]
    close = both & (d < c)
    qi, qj = np.nonzero(close.any(axis=0))
    Q = len(qi)
    if Q == 0:
        return TrajectoryGOSPA(float(const) ** (1 / p), 0.0, half * float(ax.sum()),
                               half * float(ay.sum()), 0.0, 0.0, "none")
    # coefficient of w^k_q relative to leaving i and j unassigned at k
    dq = d[:, qi, qj]
    bq = both[:, qi, qj]
    coef = np.where(bq, np.minimum(np.nan_to_num(dq, nan=c), c) ** p - 2 * half, 0.0)
    W = _tgospa_dp(coef, bq & (dq < c), qi, qj, gamma**p / 2, 1e-6 * max(c**p, gamma**p))
    solver = "dp"
    if W is None:
        W, solver = _tgospa_highs(coef, qi, qj, X.shape[1], Y.shape[1], gamma**p / 2)
    hit = W & bq & (dq < c)
    loc = float(np.sum(dq[hit] ** p))
    n_hit = int(hit.sum())
    missed = half * (float(ax.sum()) - n_hit)
    false = half * (float(ay.sum()) - n_hit)
    switches = float(np.abs(np.diff(W.astype(float), axis=0)).sum()) / 2
    switch = gamma**p * switches
    return TrajectoryGOSPA((loc + missed + false + switch) ** (1 / p), loc, missed, false,
                           switch, switches, solver)


#: the most matchings a component may have for :func:`_tgospa_dp` (its recursions cost
#: ``S**2`` per step; beyond this HiGHS is faster)
_DP_MAX_STATES = 100


def _component_matchings(qi: np.ndarray, qj: np.ndarray, limit: int) -> np.ndarray | None:
    """``(S, len(qi))`` bool: every matching of the pairs ``(qi[q], qj[q])`` (no truth and
    no track twice), the empty one first; None if there are more than ``limit``."""
    _, ti = np.unique(qi, return_inverse=True)
    _, tj = np.unique(qj, return_inverse=True)
    chosen = np.zeros((1, len(qi)), dtype=bool)
    used_i = np.zeros((1, ti.max() + 1), dtype=bool)
    used_j = np.zeros((1, tj.max() + 1), dtype=bool)
    for q in range(len(qi)):  # each matching so far, with pair q added where it fits
        fits = ~used_i[:, ti[q]] & ~used_j[:, tj[q]]
        if len(chosen) + np.count_nonzero(fits) > limit:
            return None
        add = chosen[fits]
        add[:, q] = True
        ui, uj = used_i[fits], used_j[fits]
        ui[:, ti[q]] = True
        uj[:, tj[q]] = True
        chosen = np.concatenate([chosen, add])
        used_i, used_j = np.concatenate([used_i, ui]), np.concatenate([used_j, uj])
    return chosen


def _tgospa_dp(coef: np.ndarray, read: np.ndarray, qi: np.ndarray, qj: np.ndarray,
               g: float, tol: float) -> np.ndarray | None:
    """An optimal integer assignment ``W (T, Q)`` bool of the reduced program of
    :func:`trajectory_gospa` by dynamic programming per component of pairs, or None when
    a component has more than :data:`_DP_MAX_STATES` matchings or the optimal ``W`` are
    not all equal where ``read (T, Q)`` is True (some state within ``tol`` of the
    optimum differs there from the best one). ``coef (T, Q)``: the pairs'
    coefficients; ``g = gamma**p / 2`` per unit change of one ``w_q``.

    Components with the same number ``S`` of matchings go through the recursions
    together: ``cost (T, C, S)`` and ``h (C, S, S)``, one numpy step per time step.
    """
    T, Q = coef.shape
    n_truth = int(qi.max()) + 1
    _, comp = connected_components(
        sparse.csr_matrix((np.ones(Q), (qi, n_truth + qj)),
                          shape=(n_truth + int(qj.max()) + 1,) * 2), directed=False)
    comp = comp[qi]
    groups: dict[int, list[tuple[np.ndarray, np.ndarray]]] = {}
    for label in np.unique(comp):
        members = np.nonzero(comp == label)[0]
        states = _component_matchings(qi[members], qj[members], _DP_MAX_STATES)
        if states is None:
            return None
        groups.setdefault(len(states), []).append((members, states))
    W = np.zeros((T, Q), dtype=bool)
    for comps in groups.values():
        # the group's components padded to its widest one (absent pairs: never chosen)
        C, S = len(comps), len(comps[0][1])
        width = max(len(members) for members, _ in comps)
        cols = np.zeros((C, width), dtype=np.int64)
        real = np.zeros((C, width), dtype=bool)
        M = np.zeros((C, S, width), dtype=bool)
        for a, (members, states) in enumerate(comps):
            cols[a, :len(members)] = members
            real[a, :len(members)] = True
            M[a, :, :len(members)] = states
        Mf = M.astype(np.float64)
        cost = np.einsum("tcn,csn->tcs", coef[:, cols] * real, Mf)  # a_k(s)
        h = g * np.abs(Mf[:, :, None, :] - Mf[:, None, :, :]).sum(-1)  # (C, S, S)
        best, near = _viterbi(cost, h, tol)
        chosen = M[np.arange(C)[None, :], best]  # (T, C, width)
        # a near-optimal state that differs from the best one where the parts read W
        watched = read[:, cols] & real  # (T, C, width)
        differs = ((M[None] != chosen[:, :, None, :]) & watched[:, :, None, :]).any(-1)
        if np.any(near & differs):
            return None
        for a, (members, _) in enumerate(comps):
            W[:, members] = chosen[:, a, :len(members)]
    return W


def _viterbi(cost: np.ndarray, h: np.ndarray, tol: float) -> tuple[np.ndarray, np.ndarray]:
    """Min-sum paths of ``C`` independent chains: ``cost (T, C, S)`` per step and state,
    ``h (C, S, S)`` per transition ``s -> s'``. Returns the states of one optimal path per
    chain ``(T, C)`` int (traced back from the forward totals) and ``(T, C, S)`` bool:
    the states through which some path is within ``tol`` of the optimum."""
    T = len(cost)
    F = np.empty_like(cost)
    B = np.zeros_like(cost)
    F[0] = cost[0]
    for k in range(1, T):
        F[k] = (F[k - 1][:, :, None] + h).min(axis=1) + cost[k]
    for k in range(T - 2, -1, -1):
        B[k] = (h + (cost[k + 1] + B[k + 1])[:, None, :]).min(axis=2)
    V = F + B
    # back along one optimal path (per-step minima of V may mix several optimal paths)
    best = np.empty((T, cost.shape[1]), dtype=np.int64)
    chain = np.arange(cost.shape[1])
    best[-1] = F[-1].argmin(axis=1)
    for k in range(T - 2, -1, -1):
        best[k] = (F[k] + h[chain, :, best[k + 1]]).argmin(axis=1)
    return best, V <= V.min(axis=2, keepdims=True) + tol


def _tgospa_highs(coef: np.ndarray, qi: np.ndarray, qj: np.ndarray, nx: int, ny: int,
                  g: float) -> tuple[np.ndarray, str]:
    """The optimal integer assignment ``W (T, Q)`` bool of the reduced program of
    :func:`trajectory_gospa` with HiGHS: the LP, then the integer program if the LP's
    optimum is not integral. Returns ``(W, "lp" or "milp")``."""
    T, Q = coef.shape
    nw, ne = T * Q, (T - 1) * Q
    cost = np.concatenate([coef.ravel(), np.full(ne, g)])
    # at most one track per truth and one truth per track, per step
    rows_i = np.repeat(np.arange(T)[:, None] * nx, Q, 1) + qi[None, :]
    rows_j = np.repeat(np.arange(T)[:, None] * ny, Q, 1) + qj[None, :]
    var = np.arange(nw)
    A_i = sparse.csr_matrix((np.ones(nw), (rows_i.ravel(), var)), shape=(T * nx, nw + ne))
    A_j = sparse.csr_matrix((np.ones(nw), (rows_j.ravel(), var)), shape=(T * ny, nw + ne))
    # +-(w^k - w^{k+1}) - e^k <= 0
    r = np.arange(ne)
    e_col = nw + r
    blocks = []
    for sign in (1.0, -1.0):
        blocks.append(sparse.csr_matrix(
            (np.concatenate([np.full(ne, sign), np.full(ne, -sign), np.full(ne, -1.0)]),
             (np.tile(r, 3), np.concatenate([r, r + Q, e_col]))), shape=(ne, nw + ne)))
    A = sparse.vstack([A_i, A_j, *blocks], format="csr")
    b = np.concatenate([np.ones(A_i.shape[0] + A_j.shape[0]), np.zeros(2 * ne)])
    bounds = np.column_stack([np.zeros(nw + ne), np.r_[np.ones(nw), np.full(ne, np.inf)]])
    res = linprog(cost, A_ub=A, b_ub=b, bounds=bounds, method="highs-ds")
    if res.status != 0:
        raise RuntimeError(f"trajectory GOSPA: HiGHS failed ({res.message})")
    w = res.x[:nw]
    solver = "lp"
    if not np.all(np.abs(w - np.round(w)) <= 1e-7):
        res = linprog(cost, A_ub=A, b_ub=b, bounds=bounds, method="highs",
                      integrality=np.concatenate([np.ones(nw), np.zeros(ne)]))
        if res.status != 0:
            raise RuntimeError(f"trajectory GOSPA: HiGHS failed ({res.message})")
        w = res.x[:nw]
        solver = "milp"
    return np.round(w).reshape(T, Q).astype(bool), solver


# ------------------------------------------------------------------------ OSPA(2)
@dataclass(frozen=True)
class OSPA2:
    """OSPA(2) averaged over the run's windows (position units; ``total ** p ==
    localisation ** p + cardinality ** p`` per window) and the per-window values."""

    total: float
    localisation: float
    cardinality: float
    per_step: np.ndarray


def ospa2(truth: Sequence[np.ndarray], truth_ids: Sequence[np.ndarray],
          estimate: Sequence[np.ndarray], labels: Sequence[np.ndarray],
          c: float = 2.0, p: float = 2.0, window: int | None = 10, *,
          dense: tuple | None = None) -> OSPA2:
    """OSPA(2) of Beard, Vo & Vo (2020), over sliding windows.

    For the window ``K = {k - window + 1, ..., k}`` (clipped at 0; ``window=None`` means
    the whole run up to ``k``) and two tracks ``x``, ``y`` with steps of presence
    ``D_x``, ``D_y`` inside ``K``, the base distance is the time-averaged OSPA between
    the two single-point sets::

        d_c(x, y) = sum_{t in D_x | D_y} d_O(x(t), y(t)) / |D_x | D_y|   (0 if empty)
        d_O       = min(||x(t) - y(t)||, c)   both present at t
                  = c                          exactly one present

    and OSPA(2) is OSPA of order ``p`` and cut-off ``c`` between the sets of the ``m``
    truths and ``n`` tracks present in ``K`` (``m <= n`` without loss of generality)::

        OSPA2(k) = ( (min_pi sum_{i<=m} d_c(X_i, Y_pi(i)) ** p + c**p (n - m)) / n ) ** (1/p)
        loc(k)   = ( min_pi sum d_c ** p / n ) ** (1/p),  card(k) = ( c**p (n - m) / n ) ** (1/p)

    (0 when both sets are empty). The run's score is the mean over ``k`` of OSPA2(k)
    (and of its parts); ``per_step`` holds OSPA2(k).
    """
    _check(c, p)
    X, ax, Y, ay = dense or dense_pair(truth, truth_ids, estimate, labels)
    T = len(X)
    if T == 0:
        return OSPA2(0.0, 0.0, 0.0, np.zeros(0))
    if window is not None and int(window) < 1:
        raise ValueError(f"the OSPA(2) window must be >= 1 step, got {window}")
    w = T if window is None else int(window)
    d = np.sqrt(((X[:, :, None, :] - Y[:, None, :, :]) ** 2).sum(-1))
    both = ax[:, :, None] & ay[:, None, :]
    either = ax[:, :, None] | ay[:, None, :]
    step_cost = np.where(both, np.minimum(np.nan_to_num(d, nan=c), c),
                         np.where(either, c, 0.0))
    zero = np.zeros((1, *step_cost.shape[1:]))
    csum = np.concatenate([zero, np.cumsum(step_cost, axis=0)])
    nsum = np.concatenate([zero, np.cumsum(either, axis=0)])
    psx = np.concatenate([np.zeros((1, X.shape[1])), np.cumsum(ax, axis=0)])
    psy = np.concatenate([np.zeros((1, Y.shape[1])), np.cumsum(ay, axis=0)])
    tot, loc, card = np.zeros(T), np.zeros(T), np.zeros(T)
    for k in range(T):
        lo = 0 if window is None else max(0, k - w + 1)
        ix = np.nonzero(psx[k + 1] - psx[lo] > 0)[0]
        iy = np.nonzero(psy[k + 1] - psy[lo] > 0)[0]
        m, n = len(ix), len(iy)
        if max(m, n) == 0:
            continue
        if min(m, n) == 0:
            tot[k] = card[k] = c
            continue
        cs = (csum[k + 1] - csum[lo])[ix[:, None], iy]
        ns = (nsum[k + 1] - nsum[lo])[ix[:, None], iy]
        base = np.minimum(cs / ns, c) ** p
        r, s = linear_sum_assignment(base)
        big = max(m, n)
        lp = float(base[r, s].sum()) / big
        cp = c**p * (big - min(m, n)) / big
        tot[k], loc[k], card[k] = (lp + cp) ** (1 / p), lp ** (1 / p), cp ** (1 / p)
    return OSPA2(float(tot.mean()), float(loc.mean()), float(card.mean()), tot)


# ---------------------------------------------------------------------- CLEAR-MOT
@dataclass(frozen=True)
class ClearMOT:
    """CLEAR-MOT identity scores of one run.

    ``id_switches`` and ``fragmentations`` are counts over the run; ``mostly_tracked``
    and ``mostly_lost`` are the FRACTIONS of the run's truths (0 with no truth) covered
    on at least ``mt`` (resp. at most ``ml``) of their lifetime; ``coverage`` is per
    truth (sorted ids), the share of its steps with a correspondence; ``switch_steps``
    ``(T,)`` int counts the switches at each step (``switch_steps.sum() ==
    id_switches``).
    """

    id_switches: int
    fragmentations: int
    mostly_tracked: float
    mostly_lost: float
    coverage: np.ndarray
    switch_steps: np.ndarray


def clear_mot(truth: Sequence[np.ndarray], truth_ids: Sequence[np.ndarray],
              estimate: Sequence[np.ndarray], labels: Sequence[np.ndarray],
              gate: float = 1.0, mt: float = 0.8, ml: float = 0.2, *,
              dense: tuple | None = None) -> ClearMOT:
    """Correspondences per step as in Bernardin & Stiefelhagen (2008), with the gate
    ``||x - y|| < gate``:

    1. a truth keeps the track it was last matched with (at any earlier step) if that
       track is present and within the gate (closest pairs first; a track serves one
       truth);
    2. the remaining truths and tracks are matched by an optimal assignment on the
       distances, pairs outside the gate excluded.

    Scores:

    * ``id_switches``: a truth matched with a track other than the one it was last
      matched with (at any earlier step) counts one switch, at the step of the new
      match (``switch_steps[k]``); so a clean swap at a crossing counts one per truth;
    * ``fragmentations``: per truth, the number of times its correspondence resumes
      after an interruption within its lifetime (tracked segments - 1); a truth
      followed by k tracks with gaps between them counts k - 1;
    * ``mostly_tracked`` / ``mostly_lost``: a truth matched on ``>= mt`` (``<= ml``)
      of the steps it is present.
    """
    if not (np.isfinite(gate) and gate > 0):
        raise ValueError(f"the CLEAR-MOT gate must be positive and finite, got {gate}")
    X, ax, Y, ay = dense or dense_pair(truth, truth_ids, estimate, labels)
    T, nx = ax.shape
    last = np.full(nx, -1)
    tracked = np.zeros((T, nx), dtype=bool)
    switch_steps = np.zeros(T, dtype=np.int64)
    for k in range(T):
        ti = np.nonzero(ax[k])[0]
        tj = np.nonzero(ay[k])[0] if Y.shape[1] else np.zeros(0, int)
        if len(ti) == 0 or len(tj) == 0:
            continue
        dist = cdist(X[k, ti], Y[k, tj])
        match: dict[int, int] = {}
        used: set[int] = set()
        keep = [(dist[a, b], a, b) for a, i in enumerate(ti) if last[i] >= 0
                for b in np.nonzero(tj == last[i])[0] if dist[a, b] < gate]
        for _, a, b in sorted(keep):
            if b not in used and a not in match:
                match[a] = b
                used.add(b)
        ra = [a for a in range(len(ti)) if a not in match]
        rb = [b for b in range(len(tj)) if b not in used]
        if ra and rb:
            sub = dist[np.ix_(ra, rb)]
            big = gate * 10 + 1.0
            r, s = linear_sum_assignment(np.where(sub < gate, sub, big))
            for a, b in zip(r, s, strict=True):
                if sub[a, b] < gate:
                    match[ra[a]] = rb[b]
        for a, b in match.items():
            i, j = ti[a], tj[b]
            if last[i] >= 0 and last[i] != j:
                switch_steps[k] += 1
            last[i] = j
            tracked[k, i] = True
    frags = 0
    cover = np.zeros(nx)
    for i in range(nx):
        life = np.nonzero(ax[:, i])[0]
        seq = tracked[life, i]
        cover[i] = seq.mean() if len(seq) else 0.0
        starts = int(seq[0]) + int(np.sum(seq[1:] & ~seq[:-1])) if len(seq) else 0
        frags += max(starts - 1, 0)
    return ClearMOT(int(switch_steps.sum()), frags,
                    float(np.mean(cover >= mt)) if nx else 0.0,
                    float(np.mean(cover <= ml)) if nx else 0.0, cover, switch_steps)


# ---------------------------------------------------------------------- crossings
@dataclass(frozen=True)
class Crossings:
    """The truth's close encounters in one run, per step ``k = 0..T-1``.

    ``close (T,)`` int: pairs of true targets present together at ``k`` closer than the
    distance; ``starts (T,)`` int: encounters that begin at ``k`` (an encounter is one
    pair's maximal run of consecutive close steps; ``starts.sum()`` counts the run's
    crossings); ``near (T,)`` bool: ``k`` is within ``window`` steps of a close step.
    """

    close: np.ndarray
    starts: np.ndarray
    near: np.ndarray


def crossings(truth: Sequence[np.ndarray], truth_ids: Sequence[np.ndarray],
              distance: float = 2.0, window: int = 5) -> Crossings:
    """Close encounters of the true targets (positions and ids as the other scores)::

        close[k] = #{ i < j : both present at k, ||x_i(k) - x_j(k)|| < distance }
        near[k]  = any(close[t] > 0 for |t - k| <= window)

    With ``distance`` the CLEAR-MOT gate, a close step is one where a track inside the
    gate of one target is inside the gate of another, so an identity switch is possible
    by geometry alone; the switches at the ``near`` steps are the ones "around the
    crossings". ``window`` (steps, >= 0) widens each close step on both sides, since a
    tracker often swaps a few steps after the targets part. A pair that stays close for
    many steps (targets moving together) is one encounter.
    """
    if not (np.isfinite(distance) and distance > 0):
        raise ValueError(f"the crossing distance must be positive and finite, got {distance}")
    if int(window) != window or window < 0:
        raise ValueError(f"the crossing window must be an integer >= 0 steps, got {window}")
    X, ax = as_dense(truth, truth_ids)
    T, n = ax.shape
    if T == 0 or n < 2:
        zero = np.zeros(T, dtype=np.int64)
        return Crossings(zero, zero.copy(), np.zeros(T, dtype=bool))
    i, j = np.triu_indices(n, 1)
    both = ax[:, i] & ax[:, j]
    d = np.sqrt(((X[:, i] - X[:, j]) ** 2).sum(-1))  # NaN where either is absent
    pair_close = both & (np.nan_to_num(d, nan=np.inf) < distance)  # (T, pairs)
    began = pair_close & ~np.vstack([np.zeros((1, len(i)), bool), pair_close[:-1]])
    close = pair_close.sum(axis=1).astype(np.int64)
    w = int(window)
    hits = np.convolve((close > 0).astype(np.int64), np.ones(2 * w + 1, np.int64))[w:w + T]
    return Crossings(close, began.sum(axis=1).astype(np.int64), hits > 0)
