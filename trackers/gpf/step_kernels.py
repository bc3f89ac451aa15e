"""The GPF's step around its grid update as compiled (numba) passes: the undetected
field's operations (:class:`.cells.CellField`'s ``map``, ``set``, ``at``), the looked
cells and the birth candidates, and the merge's distances (its screen and the 4x4
Cholesky forms). Each equals, bit for bit, the numpy operations of
:class:`.tracker.GaussianParticleFilter` it replaces (those stay the reference,
``MTTBENCH_NO_NUMBA=1``).

Why: on ``default`` a step is about 300 us, and these were 40-odd numpy calls of a few
microseconds each on arrays of a few dozen entries (docs/speed.md, "GPF: the step's
edges compiled").

Exactness: the field's maps are the same double operations cell by cell (numba does not
contract ``a * b + c`` into a fused multiply-add without ``fastmath``), ``np.maximum``
and ``np.minimum`` keep numpy's NaN rule (:func:`.numba_exact.nan_max`), the field's
total is numpy's pairwise sum (:func:`.numba_exact.np_sum`), and a cell whose value
equals the default rejoins it after every map, as :meth:`.CellField._rejoin` does (the
total depends on which cells are listed). ``np.unique`` of the looked cells is the
sorted distinct cells, whatever the sort.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from ..compiled import drop_stale_caches
from ..numba_exact import nan_max as _nan_max
from ..numba_exact import nan_min as _nan_min
from ..numba_exact import np_sum
from ..numba_exact import unique_inverse as _unique_inverse
from .cluster_kernels import _better

drop_stale_caches()  # before any kernel loads: a caller's cache may hold an old callee

#: field_predict's modes: the floor (a model with arrivals), the count bound's respread
#: (without), or neither (no births)
FLOOR, RESPREAD, NONE = 0, 1, 2


@njit(cache=True, error_model="numpy")
def _rejoin(default, cells, values, n):
    """Drops, in place, the first ``n`` entries equal to ``default``; the count kept."""
    k = 0
    for j in range(n):
        if not values[j] == default:
            cells[k] = cells[j]
            values[k] = values[j]
            k += 1
    return k


@njit(cache=True, error_model="numpy")
def field_predict(default, cells, values, p_s, b, mode, floor, missing, n_cells):
    """The predict's field: ``u <- 1 - (1 - p_s u)(1 - b)``, rejoin, then by ``mode``
    ``u <- max(u, floor)`` (FLOOR) or the respread of
    :meth:`.tracker.GaussianParticleFilter._respread_missing` with its ``missing``
    (RESPREAD: ``u`` scaled to ``missing`` when the total exceeds it, else scaled up
    keeping its shape, each cell at most 1/2, uniform when the total is 0), rejoin.
    Returns the new default, cells and values (new arrays)."""
    n = len(cells)
    c = cells.copy()
    v = np.empty(n)
    gb = 1.0 - b
    d = 1.0 - (1.0 - p_s * default) * gb
    for j in range(n):
        v[j] = 1.0 - (1.0 - p_s * values[j]) * gb
    n = _rejoin(d, c, v, n)
    if mode == FLOOR:
        d = _nan_max(d, floor)
        for j in range(n):
            v[j] = _nan_max(v[j], floor)
    elif mode == RESPREAD:
        total = d * (n_cells - n) + np_sum(v, n)
        if missing < total:
            f = missing / total
            d = d * f
            for j in range(n):
                v[j] = v[j] * f
        elif total > 0:
            d = _nan_min(missing * (d / total), 0.5)
            for j in range(n):
                v[j] = _nan_min(missing * (v[j] / total), 0.5)
        else:
            d = _nan_min(missing * (1.0 / n_cells), 0.5)
            n = 0
    if mode != NONE:
        n = _rejoin(d, c, v, n)
    return d, c[:n], v[:n]


@njit(cache=True, error_model="numpy")
def with_candidates(w, own, a, m, P, cand, u_cand, s, nx, vs):
    """The tracks followed by one birth candidate per cell of ``cand`` (existence
    ``u_cand``, at rest at the cell's centre, covariance ``diag(s^2/12, vs, s^2/12, vs)``):
    ``w``, ``owner``, ``alpha``, ``means``, ``covs`` and ``uniform_cell`` as
    :meth:`.tracker.GaussianParticleFilter._update_grid` builds them with numpy."""
    T, R, n_c = len(w), m.shape[0], len(cand)
    w2 = np.empty(T + n_c)
    w2[:T] = w
    w2[T:] = u_cand
    own2 = np.empty(R + n_c, np.int64)
    a2 = np.ones(R + n_c)
    ucell = np.full(R + n_c, -1, np.int64)
    m2 = np.zeros((R + n_c, 4))
    P2 = np.zeros((R + n_c, 4, 4))
    own2[:R] = own
    a2[:R] = a
    m2[:R] = m
    P2[:R] = P
    pv = s * s / 12.0
    for j in range(n_c):
        r = R + j
        own2[r] = T + j
        ucell[r] = cand[j]
        m2[r, 0] = (cand[j] % nx + 0.5) * s
        m2[r, 2] = (cand[j] // nx + 0.5) * s
        P2[r, 0, 0], P2[r, 1, 1], P2[r, 2, 2], P2[r, 3, 3] = pv, vs, pv, vs
    return w2, own2, a2, m2, P2, ucell


@njit(cache=True, error_model="numpy")
def candidates(look_cells, births, default, cells, values, w, own, a, m, P, s, nx, vs):
    """The update's front: the sorted distinct looked cells, the field ``u`` there
    (:meth:`.CellField.at`), the birth candidates (those with ``u > 0``, with births), and
    the tracks followed by one candidate per such cell (:func:`with_candidates`). Returns
    the candidates' cells and ``u``, then ``w``, ``owner``, ``alpha``, ``means``, ``covs`` and
    ``uniform_cell`` as :meth:`.tracker.GaussianParticleFilter._update_grid_numpy`
    builds them."""
    srt = np.sort(look_cells)
    looked = np.empty(len(srt), np.int64)
    n_l = 0
    for j in range(len(srt)):
        if n_l == 0 or srt[j] != looked[n_l - 1]:
            looked[n_l] = srt[j]
            n_l += 1
    cand = np.empty(n_l if births else 0, np.int64)
    u_cand = np.empty(len(cand))
    n_c = 0
    n_f = len(cells)
    if births:
        for j in range(n_l):
            u = default
            if n_f:
                i = min(np.searchsorted(cells, looked[j]), n_f - 1)
                if cells[i] == looked[j]:
                    u = values[i]
            if u > 0.0:
                cand[n_c] = looked[j]
                u_cand[n_c] = u
                n_c += 1
    w2, own2, a2, m2, P2, ucell = with_candidates(w, own, a, m, P, cand[:n_c], u_cand[:n_c],
                                                  s, nx, vs)
    return cand[:n_c], u_cand[:n_c], w2, own2, a2, m2, P2, ucell


@njit(cache=True, error_model="numpy")
def field_set(default, cells, values, set_cells, set_values, floor, apply_floor):
    """:meth:`.CellField.set` of ``set_values`` at the sorted distinct ``set_cells``, then,
    when ``apply_floor``, ``u <- max(u, floor)`` (:meth:`.CellField.map`). Returns the new
    default, cells and values."""
    n_f, n_s = len(cells), len(set_cells)
    c = np.empty(n_f + n_s, np.int64)
    v = np.empty(n_f + n_s)
    n = 0
    if n_s == 0:  # set() leaves the field as it is (no rejoin)
        c[:n_f] = cells
        v[:n_f] = values
        n = n_f
    else:
        # the kept cells and the set ones, both sorted and disjoint: a merge is the
        # stable sort of their concatenation
        i = 0
        for j in range(n_s):
            while i < n_f and cells[i] < set_cells[j]:
                c[n], v[n] = cells[i], values[i]
                n += 1
                i += 1
            if i < n_f and cells[i] == set_cells[j]:
                i += 1
            c[n], v[n] = set_cells[j], set_values[j]
            n += 1
        while i < n_f:
            c[n], v[n] = cells[i], values[i]
            n += 1
            i += 1
        n = _rejoin(default, c, v, n)
    if apply_floor:
        default = _nan_max(default, floor)
        for j in range(n):
            v[j] = _nan_max(v[j], floor)
        n = _rejoin(default, c, v, n)
    return default, c[:n], v[:n]


@njit(cache=True, error_model="numpy")
def screen_bound(m, P, i, j):
    """The merge screen's position-only lower bound of Gaussians ``i`` and ``j``:
    ``d^T S^-1 d`` over the positions, ``d = m_i - m_j``, ``S = P_i + P_j``."""
    a = P[i, 0, 0] + P[j, 0, 0]
    b = P[i, 0, 2] + P[j, 0, 2]
    c = P[i, 2, 2] + P[j, 2, 2]
    dx = m[i, 0] - m[j, 0]
    dy = m[i, 2] - m[j, 2]
    det = a * c - b * b
    return (c * dx * dx - 2.0 * b * dx * dy + a * dy * dy) / det


#: ``ln 16``, as :data:`.tracker._LN16`
_LN16 = math.log(16.0)


@njit(cache=True, error_model="numpy")
def _cholesky_forms(S, d, L, y):
    """:func:`.tracker.cholesky_forms` of one ``S (4, 4)``, ``d (4,)`` (the same operations
    in the same order), with ``L (4, 4)`` and ``y (4,)`` as scratch: ``(d^T S^-1 d,
    ln det S)``."""
    for a in range(4):
        for b in range(a + 1):
            s = S[a, b]
            for k in range(b):
                s = s - L[a, k] * L[b, k]
            L[a, b] = np.sqrt(s) if a == b else s / L[b, b]
    for a in range(4):
        s = d[a]
        for k in range(a):
            s = s - L[a, k] * y[k]
        y[a] = s / L[a, a]
    q = y[0] * y[0] + y[1] * y[1] + y[2] * y[2] + y[3] * y[3]
    logdet = 2.0 * (np.log(L[0, 0]) + np.log(L[1, 1]) + np.log(L[2, 2]) + np.log(L[3, 3]))
    return q, logdet


@njit(cache=True, error_model="numpy")
def pair_distances(m, P, threshold, bhattacharyya, groups, use_groups):
    """:func:`.tracker._pair_distances`: the pairs ``i < j`` whose position-only bound
    (:func:`screen_bound`) is not ``>= threshold`` (NaN passes), in one group when
    ``use_groups``, get the full form (:func:`_cholesky_forms`; with ``bhattacharyya``
    plus ``max(2 (ln det S - ln 16) - ln det P_i - ln det P_j, 0)`` by numpy's NaN rule),
    at ``(i, j)`` and ``(j, i)``; every other entry is ``inf``."""
    K = m.shape[0]
    d2 = np.full((K, K), np.inf)
    L = np.zeros((4, 4))
    y = np.empty(4)
    S = np.empty((4, 4))
    d = np.empty(4)
    ld = np.empty(K)
    if bhattacharyya:
        zero = np.zeros(4)
        for i in range(K):
            ld[i] = _cholesky_forms(P[i], zero, L, y)[1]
    for i in range(K):
        for j in range(i + 1, K):
            if use_groups and groups[i] != groups[j]:
                continue
            lower = screen_bound(m, P, i, j)
            if lower >= threshold:
                continue
            for a in range(4):
                d[a] = m[i, a] - m[j, a]
                for b in range(4):
                    S[a, b] = P[i, a, b] + P[j, a, b]
            full, ld_s = _cholesky_forms(S, d, L, y)
            if bhattacharyya:
                full = full + _nan_max(2.0 * (ld_s - _LN16) - ld[i] - ld[j], 0.0)
            d2[i, j] = full
            d2[j, i] = full
    return d2


@njit(cache=True, error_model="numpy")
def any_close(m, P, threshold):
    """Whether :func:`.tracker._pair_distances`' position-only screen passes any pair
    (its lower bound not ``>= threshold``; NaN passes). The bound is the same double for
    ``(i, j)`` and ``(j, i)`` (negation is exact), so the Gaussians' order does not
    matter: with no pair passing, the merge changes nothing."""
    K = m.shape[0]
    for i in range(K):
        for j in range(i + 1, K):
            lower = screen_bound(m, P, i, j)
            if not lower >= threshold:
                return True
    return False


@njit(cache=True, error_model="numpy")
def heaviest(w, n, m, P, tid):
    """The ``round_sum`` estimate's rows: ``sel = np.argsort(-w, kind="stable")[:n]``
    (numba's merge sort: stable, NaN last, numpy's order) and ``m[sel]``, ``P[sel]``,
    ``tid[sel]`` (one Gaussian per track)."""
    sel = np.argsort(-w, kind="mergesort")[:n]
    return m[sel], P[sel], tid[sel]


@njit(cache=True, error_model="numpy")
def count_bound(w, n_max):
    """:func:`.tracker.condition_on_count_bound` for ``len(w) > n_max > 0``: the prefix
    and suffix Poisson-binomial tables row by row, the suffix's cumulative sums from each
    row's first entry, and the two sums of products per track in order from 0 (numpy's
    ``einsum`` over a reversed, hence strided, operand sums in order)."""
    T = len(w)
    n = n_max + 1
    pre = np.zeros((T + 1, n))
    pre[0, 0] = 1.0
    for i in range(T):
        for j in range(n):
            pre[i + 1, j] = pre[i, j] * (1.0 - w[i])
        for j in range(1, n):
            pre[i + 1, j] += pre[i, j - 1] * w[i]
    suf = np.zeros((T + 1, n))
    suf[T, 0] = 1.0
    for i in range(T - 1, -1, -1):
        for j in range(n):
            suf[i, j] = suf[i + 1, j] * (1.0 - w[i])
        for j in range(1, n):
            suf[i, j] += suf[i + 1, j - 1] * w[i]
    out = np.empty(T)
    cum = np.empty(n)
    for i in range(T):
        cum[0] = suf[i + 1, 0]
        for j in range(1, n):
            cum[j] = cum[j - 1] + suf[i + 1, j]
        B = 0.0
        for j in range(n):
            B += pre[i, j] * cum[n - 1 - j]
        A = 0.0
        for j in range(n - 1):
            A += pre[i, j] * cum[n - 2 - j]
        den = w[i] * A + (1.0 - w[i]) * B
        out[i] = w[i] * A / den if den > 0.0 else w[i]
    return out


@njit(cache=True, error_model="numpy")
def distinct_modes(sel, score, own, m, n_tracks, min_d2):
    """:meth:`.tracker.GaussianParticleFilter._distinct_modes`: each track's rows in
    ``np.lexsort((-score, own))`` order (NaN last, ties by index), then per selected
    track its first row whose position is at least ``sqrt(min_d2)`` from every row
    chosen before (squared distances ``dx * dx + dy * dy``, their minimum NaN if any is),
    else its first row."""
    R = len(own)
    order = np.argsort(own, kind="mergesort")
    start = np.zeros(n_tracks + 1, np.int64)
    for q in range(R):
        start[own[order[q]] + 1] += 1
    for t in range(n_tracks):
        start[t + 1] += start[t]
    for t in range(n_tracks):  # within a track, by -score (an insertion sort: few rows)
        for q in range(start[t] + 1, start[t + 1]):
            x = order[q]
            p = q - 1
            while p >= start[t] and _better(score, x, order[p]):
                order[p + 1] = order[p]
                p -= 1
            order[p + 1] = x
    chosen = np.empty(len(sel), np.int64)
    for k in range(len(sel)):
        t = sel[k]
        pick = order[start[t]]
        if k > 0 and start[t + 1] - start[t] > 1:
            for q in range(start[t], start[t + 1]):
                r = order[q]
                d2 = np.nan
                for c in range(k):
                    dx = m[r, 0] - m[chosen[c], 0]
                    dy = m[r, 2] - m[chosen[c], 2]
                    v = dx * dx + dy * dy
                    d2 = v if c == 0 else _nan_min(d2, v)
                if d2 >= min_d2:
                    pick = r
                    break
        chosen[k] = pick
    return chosen


@njit(cache=True, error_model="numpy")
def _before(own, neg_a, i, j):
    """Row ``i`` precedes row ``j`` in ``np.lexsort((neg_a, own))`` (NaN last)."""
    if own[i] != own[j]:
        return own[i] < own[j]
    x, y = neg_a[i], neg_a[j]
    if x < y or (y != y and x == x):
        return True
    if x > y or (x != x and y == y):
        return False
    return i < j


@njit(cache=True, error_model="numpy")
def by_track_heaviest_first(own, a):
    """``np.lexsort((-a, own))``: a stable sort by track, then by decreasing weight (NaN
    last), then by index (the GPF's and pmb's mixture reductions)."""
    n = len(own)
    neg_a = -a
    order = np.argsort(own, kind="mergesort")
    for k in range(1, n):  # insertion sort within each track's run (a few rows)
        cur = order[k]
        q = k
        while q > 0 and own[order[q - 1]] == own[cur] and _before(own, neg_a, cur,
                                                                  order[q - 1]):
            order[q] = order[q - 1]
            q -= 1
        order[q] = cur
    return order


@njit(cache=True, error_model="numpy")
def collapse(w, m, P, owner, n):
    """:func:`.tracker.collapse`: each group's weights normalised by their sum, then its
    mean and covariance (``P + dev dev^T``) summed in row order from 0, as ``bincount``
    and ``np.add.at`` sum."""
    R = len(owner)
    tot = np.zeros(n)
    for r in range(R):
        tot[owner[r]] += w[r]
    wn = np.empty(R)
    mean = np.zeros((n, 4))
    for r in range(R):
        t = tot[owner[r]]
        wn[r] = w[r] / (t if t > 0.0 else 1.0)
        for a in range(4):
            mean[owner[r], a] += wn[r] * m[r, a]
    cov = np.zeros((n, 4, 4))
    dev = np.empty(4)
    for r in range(R):
        g = owner[r]
        for a in range(4):
            dev[a] = m[r, a] - mean[g, a]
        for a in range(4):
            for b in range(4):
                cov[g, a, b] += wn[r] * (P[r, a, b] + dev[a] * dev[b])
    return mean, cov


@njit(cache=True, error_model="numpy")
def above_floor(own, a, floor):
    """The rows a mixture reduction keeps: weight ``>= floor``, and each track's heaviest
    (:func:`by_track_heaviest_first`'s first of the track) even below it. A boolean mask."""
    n = len(a)
    keep = np.empty(n, np.bool_)
    for i in range(n):
        keep[i] = a[i] >= floor
    order = by_track_heaviest_first(own, a)
    for k in range(n):
        if k == 0 or own[order[k]] != own[order[k - 1]]:
            keep[order[k]] = True
    return keep


@njit(cache=True, error_model="numpy")
def cap_and_normalise(own, a, m, P, T, max_components):
    """The end of the GPF's and pmb's mixture reductions, on rows sorted by track and then
    by decreasing weight (:func:`by_track_heaviest_first`): a track's rows beyond
    ``max_components`` - 1 are moment-matched into one (:func:`collapse`; their weight the
    sum, in row order from 0), then the weights are normalised per track (1 where a
    track's weights sum to 0). Returns ``own``, ``a``, ``m``, ``P``."""
    n_k = len(own)
    n_rows = np.zeros(T, np.int64)
    for i in range(n_k):
        n_rows[own[i]] += 1
    rank = np.empty(n_k, np.int64)
    any_excess = False
    for i in range(n_k):
        rank[i] = i if i == 0 or own[i] != own[i - 1] else rank[i - 1]
    for i in range(n_k):
        rank[i] = i - rank[i]
        any_excess |= rank[i] >= max_components - 1 and n_rows[own[i]] > max_components
    if any_excess:
        key = np.empty(n_k, np.int64)
        for i in range(n_k):
            excess = rank[i] >= max_components - 1 and n_rows[own[i]] > max_components
            key[i] = own[i] * max_components + (max_components - 1 if excess else rank[i])
        uk, grp = _unique_inverse(key)
        wsum = np.zeros(len(uk))
        for i in range(n_k):
            wsum[grp[i]] += a[i]
        m, P = collapse(a, m, P, grp, len(uk))
        own, a = uk // max_components, wsum
    tot = np.zeros(T)
    for i in range(len(own)):
        tot[own[i]] += a[i]
    out = np.empty(len(own))
    for i in range(len(own)):
        out[i] = a[i] / tot[own[i]] if tot[own[i]] > 0.0 else 1.0
    return own, out, m, P


def warm_up() -> None:
    """Compile (or load from the disk cache) these kernels on tiny inputs of the argument
    types the GPF passes."""
    f, i = np.ones(1), np.zeros(1, np.int64)
    m, P = np.zeros((1, 4)), np.eye(4)[None]
    for mode in (FLOOR, RESPREAD, NONE):
        field_predict(0.1, i, f, 0.99, 0.01, mode, 1e-4, 0.5, 10)
    candidates(i, True, 0.1, i, f, f, i, f, m, P, 1.0, 1, 1.0)
    field_set(0.1, i, f, i, f, 1e-4, True)
    any_close(m, P, 4.0)
    for bhattacharyya in (False, True):
        pair_distances(m, P, 4.0, bhattacharyya, i, bhattacharyya)
    heaviest(f, 1, m, P, i)
    count_bound(np.full(3, 0.5), 1)
    collapse(f, m, P, i, 1)
    by_track_heaviest_first(i, f)
    above_floor(i, f, 0.02)
    cap_and_normalise(i, f, m, P, 1, 2)
    distinct_modes(i, f, i, m, 1, 1.0)
