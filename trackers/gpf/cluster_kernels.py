"""The GPF's clusters too large to list in full as compiled (numba) passes: the members'
beliefs (:func:`.grid._option_beliefs`), the enumeration of the combinations of largest
approximate posterior (:func:`.linear.enumerate_combinations` on a padded table), their
exact posterior, the JPDA* rule (:func:`.grid.avoid_coalescence`) and the cut
(:func:`.grid._cut_posterior`), i.e. :func:`.grid._cluster_posterior` in one call. Each
equals its numpy form bit for bit (those stay the reference, ``MTTBENCH_NO_NUMBA=1``).

Why: on ``large`` a step meets such a cluster most of the time, and its numpy form was
about 40 calls on arrays of a few hundred combinations (docs/speed.md, "The GPF's cluster
path compiled").

Exactness: a row's sum is numpy's pairwise sum (:func:`.numba_exact.np_sum`),
``bincount`` and ``ufunc.at`` add in index order from 0, ``cumsum`` from its first
element, the sorts are stable with numpy's order (NaN last). One choice of numpy's is
not a rule: ``np.argpartition`` keeps an arbitrary subset of equal bounds at the cap's
boundary. The kernel keeps the cap's set when it is unique (the ``M``-th largest bound
above the next) and otherwise says so (``exact`` False), and the caller runs the numpy
form; the order of the kept partials does not matter, since the combinations are
sorted at the end by their prior and then their ranks.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from ..compiled import drop_stale_caches
from ..numba_exact import nan_max as _nan_max
from ..numba_exact import nan_min as _nan_min
from ..numba_exact import np_sum
from ..numba_exact import search_left as _search
from ..numba_exact import unique_inverse as _unique_inverse

drop_stale_caches()  # before any kernel loads: a caller's cache may hold an old callee


@njit(cache=True, error_model="numpy")
def option_beliefs(option_probs, option_cell, LLc, iterations, damping, clip):
    """:func:`.grid._option_beliefs`: the damped fixed-point iteration, with each
    detected cell's sums over its options in (row, column) order (``bincount``'s) and each
    row's normaliser numpy's pairwise sum."""
    n, n_opt = option_probs.shape
    q = option_probs.copy()
    n_e = 0
    for i in range(n):
        for j in range(n_opt):
            n_e += option_cell[i, j] >= 0
    if n_e == 0:
        return q
    rows = np.empty(n_e, np.int64)
    cols = np.empty(n_e, np.int64)
    cell = np.empty(n_e, np.int64)
    e = 0
    for i in range(n):
        for j in range(n_opt):
            if option_cell[i, j] >= 0:
                rows[e], cols[e], cell[e] = i, j, option_cell[i, j]
                e += 1
    cells, cidx = _unique_inverse(cell)
    n_c = len(cells)
    # exp(LLc[c, T + 1] - LLc[c, T]) for T = 0, 1, 2 (the last difference repeated)
    n_d = LLc.shape[1] - 1
    steps = np.empty((n_c, 3))
    for c in range(n_c):
        for k in range(3):
            d = min(k, n_d - 1)
            steps[c, k] = np.exp(LLc[cells[c], d + 1] - LLc[cells[c], d])
    log_free = np.empty(n_e)
    odds = np.empty(n_e)
    new = np.empty((n, n_opt))
    for _ in range(iterations):
        sum_free = np.zeros(n_c)
        sum_odds = np.zeros(n_c)
        for k in range(n_e):
            b = _nan_min(q[rows[k], cols[k]], 1.0 - clip)
            log_free[k] = np.log1p(-b)
            odds[k] = b / (1.0 - b)
            sum_free[cidx[k]] += log_free[k]
            sum_odds[cidx[k]] += odds[k]
        new[:] = option_probs
        for k in range(n_e):
            c = cidx[k]
            p0 = np.exp(sum_free[c] - log_free[k])
            p1 = p0 * _nan_max(sum_odds[c] - odds[k], 0.0)
            p1 = _nan_min(p1, 1.0 - p0)
            factor = p0 * steps[c, 0] + p1 * steps[c, 1] + (1.0 - p0 - p1) * steps[c, 2]
            new[rows[k], cols[k]] *= factor
        for i in range(n):
            tot = np_sum(new[i], n_opt)
            for j in range(n_opt):
                q[i, j] = (1.0 - damping) * q[i, j] + damping * (new[i, j] / tot)
    return q


@njit(cache=True, error_model="numpy")
def _same_key(key, a, b):
    for j in range(key.shape[1]):
        if key[a, j] != key[b, j]:
            return False
    return True


@njit(cache=True, error_model="numpy")
def _better(log_post, a, b):
    """Row ``a`` precedes row ``b`` in ``np.lexsort((index, -log_post))`` (NaN last)."""
    x, y = -log_post[a], -log_post[b]
    if x != x:
        return y != y and a < b
    if y != y or x < y:
        return True
    return x == y and a < b


@njit(cache=True, error_model="numpy")
def avoid_coalescence(cluster, choice, cell, detected, log_post):
    """:func:`.grid.avoid_coalescence`: the same classes of combinations (rows of equal
    key: cluster, the choices of the members that took no detected cell, the sorted
    detected cells taken), found by a hash of each key and an exact comparison within
    equal hashes instead of numpy's sort of the keys' rows; in each class the row first
    in ``np.lexsort((index, -log_post))`` keeps its value. Only that choice reaches the
    output, so the result is numpy's exactly."""
    C, S = choice.shape
    key = np.empty((C, 1 + 2 * S), np.int64)
    taken = np.empty(S, np.int64)
    h = np.empty(C, np.uint64)
    for r in range(C):
        key[r, 0] = cluster[r]
        for j in range(S):
            took = cell[r, j] >= 0 and detected[cell[r, j]]
            key[r, 1 + j] = -1 if took else choice[r, j]
            # the taken cells sorted by insertion (a few; numba's sort call costs more)
            x = cell[r, j] if took else -1
            p = j - 1
            while p >= 0 and taken[p] > x:
                taken[p + 1] = taken[p]
                p -= 1
            taken[p + 1] = x
        for j in range(S):
            key[r, 1 + S + j] = taken[j]
        v = np.uint64(14695981039346656037)
        for j in range(1 + 2 * S):
            v = (v ^ np.uint64(key[r, j] & 0xFFFFFFFFFFFF)) * np.uint64(1099511628211)
        h[r] = v
    order = np.argsort(h, kind="mergesort")
    out = np.full(C, -np.inf)
    best = np.empty(C, np.int64)  # per class in the current run of equal hashes
    reps = np.empty(C, np.int64)
    start = 0
    while start < C:
        stop = start + 1
        while stop < C and h[order[stop]] == h[order[start]]:
            stop += 1
        n_cls = 0
        for q in range(start, stop):
            r = order[q]
            k = 0
            while k < n_cls and not _same_key(key, reps[k], r):
                k += 1
            if k == n_cls:
                reps[k], best[k] = r, r
                n_cls += 1
            elif _better(log_post, r, best[k]):
                best[k] = r
        for k in range(n_cls):
            out[best[k]] = log_post[best[k]]
        start = stop
    return out




@njit(cache=True, error_model="numpy")
def _branch_and_bound(logs, n_pos, log_eps, max_combinations, block):
    """The loop of :func:`.linear.enumerate_combinations` on the rows' sorted log
    probabilities ``logs (n, O)``: the kept partials' ``ranks (C, n)`` and log priors
    ``(C,)`` (in no particular order), and False when the cap's set was not unique."""
    n = logs.shape[0]
    # rest[j] = sum_{k >= j} logs[k, 0], numpy's cumsum of the reversed column
    rest = np.zeros(n + 1)
    acc = 0.0
    for j in range(n - 1, -1, -1):
        acc = logs[j, 0] if j == n - 1 else acc + logs[j, 0]
        rest[j] = acc
    lp = np.zeros(1)
    ranks = np.zeros((1, n), np.int64)
    start = 0
    while start < n:
        stop, size = start + 1, n_pos[start]
        while stop < n and size * n_pos[stop] <= block:
            size *= n_pos[stop]
            stop += 1
        k = stop - start
        # every joint choice of the block (np.indices' order: the last member fastest)
        blk = np.empty((size, k), np.int64)
        blk_lp = np.empty(size)
        buf = np.empty(k)
        for r in range(size):
            rem = r
            for c in range(k - 1, -1, -1):
                blk[r, c] = rem % n_pos[start + c]
                rem //= n_pos[start + c]
            for c in range(k):
                buf[c] = logs[start + c, blk[r, c]]
            if size == 1:
                blk_lp[r] = np_sum(buf, k)
            else:
                # numpy's table is in column order (a transposed np.indices), so its
                # row sums run along the columns: in order from 0
                acc = 0.0
                for c in range(k):
                    acc += buf[c]
                blk_lp[r] = acc
        n_cand = len(lp) * size
        cand = np.empty(n_cand)
        keep = np.empty(n_cand, np.int64)
        n_keep = 0
        for p in range(len(lp)):
            for o in range(size):
                x = lp[p] + blk_lp[o]
                cand[p * size + o] = x
                if x + rest[stop] > log_eps:
                    keep[n_keep] = p * size + o
                    n_keep += 1
        keep = keep[:n_keep]
        if n_keep > max_combinations:
            # np.argpartition(-bound, M - 1)[:M]: the M largest bounds, a set when no
            # other bound equals the M-th largest
            neg = np.empty(n_keep)
            for q in range(n_keep):
                neg[q] = -(cand[keep[q]] + rest[stop])
            kth = np.partition(neg, max_combinations - 1)[max_combinations - 1]
            n_in = 0
            for q in range(n_keep):
                n_in += neg[q] <= kth
            if n_in != max_combinations:
                return ranks, lp, False
            n_in = 0
            for q in range(n_keep):
                if neg[q] <= kth:
                    keep[n_in] = keep[q]
                    n_in += 1
            keep = keep[:n_in]
        new_ranks = np.empty((len(keep), n), np.int64)
        new_lp = np.empty(len(keep))
        for q in range(len(keep)):
            parent, opt = keep[q] // size, keep[q] % size
            new_ranks[q] = ranks[parent]
            new_ranks[q, start:stop] = blk[opt]
            new_lp[q] = cand[keep[q]]
        ranks, lp = new_ranks, new_lp
        start = stop
    return ranks, lp, True


@njit(cache=True, error_model="numpy")
def _ranks_before(ranks, a, b):
    for j in range(ranks.shape[1]):
        if ranks[a, j] != ranks[b, j]:
            return ranks[a, j] < ranks[b, j]
    return False


@njit(cache=True, error_model="numpy")
def enumerate_choices(option_probs, epsilon, max_combinations, block):
    """:func:`.linear.enumerate_combinations` of a padded ``(n, O)`` table: the choices
    ``(C, n)`` in its order (decreasing prior, ties by the ranks), its ``dropped``, and
    whether the result is numpy's (False: the cap's set was not unique; module
    docstring)."""
    n, n_opt = option_probs.shape
    if n == 0:
        return np.zeros((1, 0), np.int64), 0.0, True
    orders = np.empty((n, n_opt), np.int64)
    logs = np.empty((n, n_opt))
    n_pos = np.empty(n, np.int64)
    neg = np.empty(n_opt)
    for i in range(n):
        for j in range(n_opt):
            neg[j] = -option_probs[i, j]
        o = np.argsort(neg, kind="mergesort")
        cnt = 0
        for j in range(n_opt):
            v = option_probs[i, o[j]]
            orders[i, j] = o[j]
            cnt += v > 0.0
            logs[i, j] = np.log(v)
        n_pos[i] = max(cnt, 1)
    log_eps = math.log(epsilon) if epsilon > 0 else -math.inf
    ranks, lp, exact = _branch_and_bound(logs, n_pos, log_eps, max_combinations, block)
    if exact and len(lp) == 0 and log_eps > -math.inf:
        # nothing passes epsilon: the cap's worth of the most probable
        ranks, lp, exact = _branch_and_bound(logs, n_pos, -math.inf, max_combinations, block)
    C = len(lp)
    if not exact:
        return np.zeros((0, n), np.int64), 0.0, False
    # np.lexsort((ranks[:, n - 1], ..., ranks[:, 0], -lp)): stable by -lp, equal -lp by
    # the ranks (distinct rows, so a total order)
    neg_lp = np.empty(C)
    for c in range(C):
        neg_lp[c] = -lp[c]
    order = np.argsort(neg_lp, kind="mergesort")
    s = 0
    while s < C:
        e = s + 1
        while e < C and neg_lp[order[e]] == neg_lp[order[s]]:
            e += 1
        for q in range(s + 1, e):  # insertion sort of the run by the ranks
            x = order[q]
            p = q - 1
            while p >= s and _ranks_before(ranks, x, order[p]):
                order[p + 1] = order[p]
                p -= 1
            order[p + 1] = x
        s = e
    choice = np.empty((C, n), np.int64)
    ex = np.empty(C)
    for c in range(C):
        r = order[c]
        for j in range(n):
            choice[c, j] = orders[j, ranks[r, j]]
        ex[c] = np.exp(lp[r])
    left = 1.0 - np_sum(ex, C)
    return choice, (left if left > 0.0 else 0.0), True  # Python's max(0.0, left)


@njit(cache=True, error_model="numpy")
def cluster_posterior(option_probs, option_cell, LLc, detected, epsilon, max_combinations,
                      block, iterations, damping, clip):
    """:func:`.grid._cluster_posterior`: ``post (n, O)``, the dropped mass, and whether
    the enumeration was numpy's (False: run the numpy form; module docstring)."""
    n, n_opt = option_probs.shape
    beliefs = option_beliefs(option_probs, option_cell, LLc, iterations, damping, clip)
    ch, comb_dropped, exact = enumerate_choices(beliefs, 0.0, max_combinations, block)
    post = np.zeros((n, n_opt))
    if not exact:
        return post, 0.0, False
    C = ch.shape[0]
    # each combination's log prior and its cells, then sum_c LLc[c, T_c] over the cells
    # any combination holds (sorted; count 0 included, as the numpy form's table)
    cell_of = np.empty((C, n), np.int64)
    log_post = np.empty(C)
    buf = np.empty(max(n, 1))
    n_held = 0
    for c in range(C):
        for j in range(n):
            buf[j] = np.log(option_probs[j, ch[c, j]])
            cell_of[c, j] = option_cell[j, ch[c, j]]
            n_held += cell_of[c, j] >= 0
        log_post[c] = np_sum(buf, n)
    held = np.empty(n_held, np.int64)
    q = 0
    for c in range(C):
        for j in range(n):
            if cell_of[c, j] >= 0:
                held[q] = cell_of[c, j]
                q += 1
    loc_cells, loc_idx = _unique_inverse(held)
    n_loc = len(loc_cells)
    counts = np.zeros(n_loc, np.int64)
    terms = np.empty(max(n_loc, 1))
    q = 0
    for c in range(C):
        counts[:] = 0
        for j in range(n):
            if cell_of[c, j] >= 0:
                counts[loc_idx[q]] += 1
                q += 1
        for k in range(n_loc):
            terms[k] = LLc[loc_cells[k], counts[k]]
        log_post[c] = log_post[c] + np_sum(terms, n_loc)
    log_post = avoid_coalescence(np.zeros(C, np.int64), ch, cell_of, detected, log_post)
    # _cut_posterior with one group
    top = -np.inf
    for c in range(C):
        top = _nan_max(top, log_post[c])
    e = np.empty(C)
    tot = 0.0
    for c in range(C):
        e[c] = np.exp(log_post[c] - top)
        tot += e[c]
    pc = np.empty(C)
    n_kept = 0
    for c in range(C):
        pc[c] = e[c] / tot
        n_kept += pc[c] > epsilon
    cut_vals = np.empty(C)
    n_cut = 0
    tot = 0.0
    for c in range(C):
        if n_kept > 0 and not pc[c] > epsilon:
            cut_vals[n_cut] = pc[c]
            n_cut += 1
            pc[c] = 0.0
        tot += pc[c]
    cut = np_sum(cut_vals, n_cut)
    for c in range(C):
        pc[c] = pc[c] / tot
    # post[j, o] = sum of p(C | z) over the combinations with choice_j = o
    for c in range(C):
        for j in range(n):
            post[j, ch[c, j]] += pc[c]
    return post, comb_dropped + cut, True


@njit(cache=True, error_model="numpy")
def cluster_options(w, mass, mass_out, pi, pu, mem, LL, hit):
    """The options of the clusters' members ``mem`` (grouped by cluster), as
    :func:`.grid.grid_update` builds them and :func:`.grid._aggregate_misses` pools and
    tilts them: ``q (M, O + 1)``, their cells, the coupling ``LLc``, each member's
    ``sum_c m_c l_c(1)`` over its missed cells, its number of options of positive
    probability (at least 1), and the ``rows``, ``cols`` and track pairs ``pidx`` of the
    members' looked cells. Sums as numpy's: the missed mass in pair order from 0, each
    row's normaliser pairwise (:func:`.numba_exact.np_sum`)."""
    M = len(mem)
    first = np.empty(M, np.int64)
    cnt = np.empty(M, np.int64)
    most = 0
    for i in range(M):
        first[i] = _search(pi, mem[i])
        cnt[i] = _search(pi, mem[i] + 1) - first[i]
        most = max(most, cnt[i])
    n_opt = 2 + most
    n_e = 0
    for i in range(M):
        n_e += cnt[i]
    rows = np.empty(n_e, np.int64)
    cols = np.empty(n_e, np.int64)
    pidx = np.empty(n_e, np.int64)
    q = np.zeros((M, n_opt + 1))
    out_cell = np.full((M, n_opt + 1), -1, np.int64)
    miss_lik = np.empty(M)
    n_pos = np.empty(M, np.int64)
    e = 0
    for i in range(M):
        wm = w[mem[i]]
        q[i, 0] = 1.0 - wm
        q[i, 1] = wm * mass_out[mem[i]]
        miss_w = 0.0
        for k in range(cnt[i]):
            rows[e], cols[e], pidx[e] = i, 2 + k, first[i] + k
            c = pu[pidx[e]]
            pl = wm * mass[pidx[e]] * np.exp(LL[c, 1])
            if hit[c]:
                q[i, 2 + k] = pl
                out_cell[i, 2 + k] = c
            else:
                miss_w += pl
            e += 1
        q[i, n_opt] = miss_w
        wm2 = 1.0 - q[i, 0]
        miss_lik[i] = miss_w / wm2 if wm2 > 0.0 else 0.0
        tot = np_sum(q[i], n_opt + 1)
        n = 0
        for j in range(n_opt + 1):
            q[i, j] = q[i, j] / tot
            n += q[i, j] > 0.0
        n_pos[i] = max(n, 1)
    LLc = np.empty(LL.shape)
    for c in range(LL.shape[0]):
        for t in range(LL.shape[1]):
            LLc[c, t] = LL[c, t] - t * LL[c, 1]
    return q, out_cell, LLc, miss_lik, n_pos, rows, cols, pidx


@njit(cache=True, error_model="numpy")
def cluster_g(post, mem, rows, cols, pidx, mass, mass_out, pu, hit, LL, miss_lik, w_new,
              g_out, g_pair):
    """From the members' option posteriors ``post``, as :func:`.grid.grid_update` does in
    place: ``w_new`` (presence), and where present ``g_out`` and ``g_pair`` (posterior over
    prior mass given presence; in a missed cell the missed option's share by
    ``m_c l_c(1)``)."""
    M = len(mem)
    present = np.empty(M)
    for i in range(M):
        present[i] = 1.0 - post[i, 0]
        w_new[mem[i]] = present[i]
        if present[i] > 0.0:
            mo = mass_out[mem[i]]
            g_out[mem[i]] = post[i, 1] / present[i] / mo if mo > 0.0 else 0.0
    last = post.shape[1] - 1
    for e in range(len(rows)):
        i = rows[e]
        if not present[i] > 0.0:
            continue
        c = pu[pidx[e]]
        if not hit[c]:
            g_pair[pidx[e]] = post[i, last] / present[i] * np.exp(LL[c, 1]) / miss_lik[i]
        else:
            mp = mass[pidx[e]]
            g_pair[pidx[e]] = post[i, cols[e]] / present[i] / mp if mp > 0.0 else 0.0


def warm_up() -> None:
    """Compile (or load from the disk cache) these kernels on tiny inputs of the argument
    types the GPF passes."""
    probs = np.full((2, 3), 1.0 / 3.0)
    cell = np.array([[-1, -1, 0], [-1, -1, 0]])
    avoid_coalescence(np.zeros(1, np.int64), np.zeros((1, 2), np.int64),
                      np.zeros((1, 2), np.int64), np.ones(1, np.bool_), np.zeros(1))
    option_beliefs(probs, cell, np.zeros((1, 3)), 20, 0.5, 1e-12)
    enumerate_choices(probs, 1e-3, 4, 64)
    cluster_posterior(probs, cell, np.zeros((1, 3)), np.ones(1, np.bool_), 1e-3, 4, 64, 20,
                      0.5, 1e-12)
    f, i, b = np.full(2, 0.5), np.zeros(2, np.int64), np.ones(1, np.bool_)
    LL = np.zeros((1, 3))
    q, out_cell, LLc, miss_lik, n_pos, rows, cols, pidx = cluster_options(
        f, f, f, i, i, np.arange(2), LL, b)
    cluster_g(q, np.arange(2), rows, cols, pidx, f, f, i, b, LL, miss_lik, f.copy(), f.copy(),
              f.copy())
