"""The GPF's grid update (:func:`.grid.grid_update`) as two compiled (numba) passes,
equal bit for bit to its numpy forms :func:`.grid._pairs_and_singletons` and
:func:`.grid._moment_match` (the clusters' passes between them are
:mod:`.cluster_kernels`'), and the fold into the workspace (:func:`reflection_images`,
:func:`fold_moments`).

Why: on a small grid the update is a few hundred numpy calls on arrays of a few dozen
pairs, so its time is the interpreter's (docs/speed.md, "GPF: the update in two passes").

Exactness: each pass performs the numpy form's IEEE operations in the same order.
``bincount`` and ``ufunc.at`` add sequentially in index order from 0; ``np.unique``'s
keys are sorted by a stable sort, so that equal keys keep their index order;
``np.logaddexp`` is numpy's ``npy_logaddexp`` (:func:`_logaddexp`); the 2x2 ``einsum``
contractions of :func:`.grid.lift_to_state` are ``0 + a_0 b_0 + a_1 b_1`` (the one
exception, ``matmul`` in :func:`.grid.position_regression`, stays numpy: its regression
``B`` and residual are inputs here); ``exp``, ``log``, ``log1p`` are the C library's, as
numpy's are for doubles without AVX-512; a division by zero gives numpy's inf or NaN
(``error_model="numpy"``), not an exception. ``tests/test_gpf_kernels.py`` compares each
pass with its numpy form; ``tests/test_grid_kernels.py`` compares whole runs.
"""

from __future__ import annotations

import itertools
import math

import numpy as np
from numba import njit

from ..compiled import drop_stale_caches
from ..grid_kernels import looked_in_boxes, rect_position_moments
from ..numba_exact import find_root as _find
from ..numba_exact import nan_max as _nan_max
from ..numba_exact import nan_min as _nan_min
from ..numba_exact import ndtr as _ndtr
from ..numba_exact import np_sum
from ..numba_exact import search_left as _search
from ..numba_exact import unique_inverse as _unique_inverse
from . import cluster_kernels, step_kernels

# the GPF reaches the clusters' kernels through this module
from .cluster_kernels import (  # noqa: F401
    avoid_coalescence,
    cluster_g,
    cluster_options,
    cluster_posterior,
    option_beliefs,
)

# the GPF reaches the step's kernels through this module
from .step_kernels import (  # noqa: F401
    FLOOR,
    RESPREAD,
    above_floor,
    any_close,
    by_track_heaviest_first,
    candidates,
    cap_and_normalise,
    collapse,
    field_predict,
    field_set,
    heaviest,
    pair_distances,
)

drop_stale_caches()  # before any kernel loads: a caller's cache may hold an old callee

_LOGE2 = math.log(2.0)


@njit(cache=True, error_model="numpy")
def _logaddexp(x: float, y: float) -> float:
    """``np.logaddexp`` for doubles (numpy's ``npy_logaddexp``)."""
    if x == y:
        return x + _LOGE2
    tmp = x - y
    if tmp > 0:
        return x + np.log1p(np.exp(-tmp))
    if tmp <= 0:
        return y + np.log1p(np.exp(tmp))
    return tmp


@njit(cache=True, error_model="numpy")
def pairs_and_singletons(w, m, P, uniform_cell, own, alp, U, hit, cells, returns, ll_pos,
                         ll_neg, s, nx, ny, threshold, range_sigmas, bounds, n_nodes, first,
                         nodes, weights):
    """:func:`.grid._pairs_and_singletons`; ``ll_pos``, ``ll_neg``: one look's ``log l(1)``
    for a return and for none (``LL1`` sums them per looked cell in look order). The
    clusters are the connected components by union-find, each labelled by its smallest
    track, as the numpy form's minimum-label propagation labels them. The last output is
    True when a uniform row's cell was not looked at (the caller raises)."""
    T = len(w)
    R = m.shape[0]
    n_u = len(U)
    # the looks' log l(1) per looked cell, column 1 of look_log_ratios(..., 1)
    LL1 = np.zeros((n_u, 2))
    for j in range(len(cells)):
        LL1[_search(U, cells[j]), 1] += ll_pos if returns[j] else ll_neg
    gauss = np.ones(T, np.bool_)
    n_gr = 0
    for r in range(R):
        if uniform_cell[r] < 0:
            n_gr += 1
        else:
            gauss[own[r]] = False
    gr = np.empty(n_gr, np.int64)
    lo_x = np.empty(n_gr)
    hi_x = np.empty(n_gr)
    lo_y = np.empty(n_gr)
    hi_y = np.empty(n_gr)
    i = 0
    for r in range(R):
        if uniform_cell[r] < 0:
            sx = np.sqrt(_nan_max(P[r, 0, 0], 0.0))
            sy = np.sqrt(_nan_max(P[r, 2, 2], 0.0))
            gr[i] = r
            lo_x[i] = np.floor((m[r, 0] - range_sigmas * sx) / s)
            hi_x[i] = np.floor((m[r, 0] + range_sigmas * sx) / s)
            lo_y[i] = np.floor((m[r, 2] - range_sigmas * sy) / s)
            hi_y[i] = np.floor((m[r, 2] + range_sigmas * sy) / s)
            i += 1
    box, pu0 = looked_in_boxes(lo_x, hi_x, lo_y, hi_y, U, nx, ny)
    n0 = len(box)
    mean_xy = np.empty((n0, 2))
    cov_xy = np.empty((n0, 2, 2))
    x0 = np.empty(n0)
    x1 = np.empty(n0)
    y0 = np.empty(n0)
    y1 = np.empty(n0)
    for p in range(n0):
        r = gr[box[p]]
        mean_xy[p, 0], mean_xy[p, 1] = m[r, 0], m[r, 2]
        cov_xy[p, 0, 0], cov_xy[p, 0, 1] = P[r, 0, 0], P[r, 0, 2]
        cov_xy[p, 1, 0], cov_xy[p, 1, 1] = P[r, 2, 0], P[r, 2, 2]
        c = U[pu0[p]]
        ix, iy = c % nx, c // nx
        x0[p], x1[p] = ix * s, (ix + 1) * s
        y0[p], y1[p] = iy * s, (iy + 1) * s
    mass0, m10, m20 = rect_position_moments(mean_xy, cov_xy, x0, x1, y0, y1, bounds,
                                            n_nodes, first, nodes, weights)
    n_g = 0
    for p in range(n0):
        if mass0[p] > 1e-12:
            n_g += 1
    ri_g = np.empty(n_g, np.int64)
    pu_g = np.empty(n_g, np.int64)
    mass_g = np.empty(n_g)
    p1_g = np.empty((n_g, 2))
    p2_g = np.empty((n_g, 2, 2))
    i = 0
    for p in range(n0):
        if mass0[p] > 1e-12:
            ri_g[i], pu_g[i], mass_g[i] = gr[box[p]], pu0[p], mass0[p]
            p1_g[i] = m10[p]
            p2_g[i] = m20[p]
            i += 1
    # uniform rows: one pair each, mass 1
    n_rows = n_g + R - n_gr
    row_key = np.empty(n_rows, np.int64)
    row_mass = np.empty(n_rows)
    for p in range(n_g):
        row_key[p] = own[ri_g[p]] * n_u + pu_g[p]
        row_mass[p] = alp[ri_g[p]] * mass_g[p]
    bad = False
    i = n_g
    for r in range(R):
        if uniform_cell[r] >= 0:
            pos = min(_search(U, uniform_cell[r]), n_u - 1)
            if U[pos] != uniform_cell[r]:
                bad = True  # the caller raises; pos stays a valid index meanwhile
            row_key[i] = own[r] * n_u + pos
            row_mass[i] = 1.0
            i += 1
    # (track, looked cell) pairs: np.unique(row_key, return_inverse=True), bincount
    pair_key, pair_of = _unique_inverse(row_key)
    n_p = len(pair_key)
    pi = pair_key // n_u
    pu = pair_key % n_u
    mass = np.zeros(n_p)
    for j in range(n_rows):
        mass[pair_of[j]] += row_mass[j]
    mass_in = np.zeros(T)
    for k in range(n_p):
        mass_in[pi[k]] += mass[k]
    mass_out = np.empty(T)
    logL = np.empty(T)
    log_w = np.empty(T)
    log_not_w = np.empty(T)
    for t in range(T):
        mass_out[t] = _nan_min(_nan_max(1.0 - mass_in[t], 0.0), 1.0) if gauss[t] else 0.0
        logL[t] = np.log(mass_out[t])
        log_w[t] = np.log(w[t])
        log_not_w[t] = np.log1p(-w[t])
    # each track's likelihood as if alone, log L = log(m_out + sum_c m_c l_c(1))
    log_terms = np.empty(n_p)
    for k in range(n_p):
        log_terms[k] = np.log(_nan_max(mass[k], 1e-300)) + LL1[pu[k], 1]
        logL[pi[k]] = _logaddexp(logL[pi[k]], log_terms[k])
    # significant pairs in detected cells, and the clusters they link
    lae = np.empty(T)
    for t in range(T):
        lae[t] = _logaddexp(log_w[t] + logL[t], log_not_w[t])
    signif = np.zeros(n_p, np.bool_)
    n_sig = np.zeros(n_u, np.int64)
    for k in range(n_p):
        t, u = pi[k], pu[k]
        occ = w[t] * mass[k]
        occ_alone = np.exp(log_w[t] + log_terms[k] - lae[t])
        sig = (_nan_max(occ, occ_alone) > threshold) or ((not gauss[t]) and hit[u])
        if sig and hit[u]:
            signif[k] = True
            n_sig[u] += 1
    parent = np.arange(T)
    cell_first = np.full(n_u, -1, np.int64)
    for k in range(n_p):
        if signif[k] and n_sig[pu[k]] >= 2:
            u = pu[k]
            if cell_first[u] < 0:
                cell_first[u] = pi[k]
            else:
                a, b = _find(parent, cell_first[u]), _find(parent, pi[k])
                if a < b:
                    parent[b] = a
                elif b < a:
                    parent[a] = b
    plabel = np.empty(T, np.int64)
    sizes = np.zeros(T, np.int64)
    for t in range(T):
        plabel[t] = _find(parent, t)
        sizes[plabel[t]] += 1
    in_cluster = np.empty(T, np.bool_)
    t_max = 1
    for t in range(T):
        in_cluster[t] = sizes[plabel[t]] >= 2
        t_max = max(t_max, sizes[plabel[t]])
    # singletons, closed form in log space
    w_new = w.copy()
    g_out = np.zeros(T)
    g_pair = np.zeros(n_p)
    for t in range(T):
        if not in_cluster[t]:
            logit = np.log(w[t]) + logL[t] - np.log1p(-w[t])
            w_new[t] = 1.0 if w[t] >= 1.0 else 1.0 / (1.0 + np.exp(-logit))
            g_out[t] = np.exp(-logL[t])
    for k in range(n_p):
        if not in_cluster[pi[k]]:
            g_pair[k] = np.exp(LL1[pu[k], 1] - logL[pi[k]])
    return (ri_g, pu_g, mass_g, p1_g, p2_g, pi, pu, pair_of, mass, mass_out, logL, LL1,
            plabel, in_cluster, t_max, w_new, g_out, g_pair, bad)


#: the header of :func:`grid_update_packed`'s integer output
HEADER = 10


@njit(cache=True, error_model="numpy")
def grid_update_packed(w, m, P, uniform_cell, own, alp, cells, returns, ll_pos, ll_neg, s,
                       nx, ny, threshold, range_sigmas, bounds, n_nodes, first, nodes,
                       weights, B, resid, split_share):
    """:func:`pairs_and_singletons` and, when no cluster holds two tracks, :func:`
    moment_match`, with the looked cells and detected ones found here, everything
    returned in one integer and one float array (numba boxes each returned array at a
    cost of microseconds; :func:`.grid.grid_update` unpacks them). ``ints[:HEADER]``:
    ``n_g, n_p, n_rows, T, n_u, t_max, bad, done, rows out``; ``done``: the update is
    complete (ints: owner; floats: means, covs, alpha, clipped ``w``), else ints hold
    ``ri_g, pu_g, pi, pu, pair_of, plabel, in_cluster, hit`` and floats ``mass_g, p1_g,
    p2_g, mass, mass_out, logL, LL1, w_new, g_out, g_pair`` (flattened, in that order)."""
    U = np.unique(cells)
    n_u = len(U)
    hit = np.zeros(n_u, np.bool_)
    for j in range(len(cells)):
        if returns[j]:
            hit[_search(U, cells[j])] = True
    (ri_g, pu_g, mass_g, p1_g, p2_g, pi, pu, pair_of, mass, mass_out, logL, LL1, plabel,
     in_cluster, t_max, w_new, g_out, g_pair, bad) = pairs_and_singletons(
        w, m, P, uniform_cell, own, alp, U, hit, cells, returns, ll_pos, ll_neg, s, nx, ny,
        threshold, range_sigmas, bounds, n_nodes, first, nodes, weights)
    T = len(w)
    n_g, n_p, n_rows = len(ri_g), len(pi), len(pair_of)
    head = np.array([n_g, n_p, n_rows, T, n_u, t_max, int(bad), 0, 0, 0], np.int64)
    if not bad and t_max <= 1:
        gauss_row = uniform_cell < 0
        means, covs, alpha, out_own = moment_match(
            ri_g, pu_g, mass_g, p1_g, p2_g, pair_of, g_pair, g_out, w_new, own, alp,
            gauss_row, hit, m, P, B, resid, T, split_share)
        n_out = len(out_own)
        head[7], head[8] = 1, n_out
        ints = np.empty(HEADER + n_out, np.int64)
        ints[:HEADER] = head
        ints[HEADER:] = out_own
        floats = np.empty(21 * n_out + T)
        floats[:4 * n_out] = means.ravel()
        floats[4 * n_out:20 * n_out] = covs.ravel()
        floats[20 * n_out:21 * n_out] = alpha
        for t in range(T):
            floats[21 * n_out + t] = _nan_min(_nan_max(w_new[t], 0.0), 1.0)
        return ints, floats
    ints = np.empty(HEADER + 2 * n_g + 2 * n_p + n_rows + 2 * T + n_u, np.int64)
    ints[:HEADER] = head
    o = HEADER
    for part in (ri_g, pu_g, pi, pu, pair_of, plabel):
        ints[o:o + len(part)] = part
        o += len(part)
    for t in range(T):
        ints[o + t] = in_cluster[t]
    o += T
    for u in range(n_u):
        ints[o + u] = hit[u]
    floats = np.empty(7 * n_g + 2 * n_p + 5 * T + 2 * n_u)
    o = 0
    for part in (mass_g, p1_g.ravel(), p2_g.ravel(), mass, mass_out, logL, LL1.ravel(),
                 w_new, g_out, g_pair):
        floats[o:o + len(part)] = part
        o += len(part)
    return ints, floats


def unpack_front(ints: np.ndarray, floats: np.ndarray) -> tuple:
    """:func:`grid_update_packed`'s output when it stopped before the moment match: the
    tuple of :func:`.grid._pairs_and_singletons` (views), then ``hit``."""
    n_g, n_p, n_rows, T, n_u, t_max, bad = ints[:7].tolist()
    # Python ints: slicing by them costs a fraction of slicing by numpy's
    cuts = list(itertools.accumulate((n_g, n_g, n_p, n_p, n_rows, T, T, n_u), initial=HEADER))
    ri_g, pu_g, pi, pu, pair_of, plabel, in_cluster, hit = (
        ints[a:b] for a, b in zip(cuts[:-1], cuts[1:], strict=True))
    cuts = list(itertools.accumulate((n_g, 2 * n_g, 4 * n_g, n_p, T, T, 2 * n_u, T, T, n_p),
                                     initial=0))
    (mass_g, p1_g, p2_g, mass, mass_out, logL, LL1, w_new, g_out, g_pair) = (
        floats[a:b] for a, b in zip(cuts[:-1], cuts[1:], strict=True))
    return (ri_g, pu_g, mass_g, p1_g.reshape(n_g, 2), p2_g.reshape(n_g, 2, 2), pi, pu,
            pair_of, mass, mass_out, logL, LL1.reshape(n_u, 2), plabel,
            in_cluster.astype(bool), t_max, w_new, g_out, g_pair, bool(bad)), hit.astype(bool)


@njit(cache=True, error_model="numpy")
def _lift(B, resid, r, mass, a0, a1, b00, b01, b11, M1, M2, o):
    """:func:`.grid.lift_to_state` of one row: position moments ``mass``, ``(a0, a1)``,
    ``[[b00, b01], [b01, b11]]`` of row ``r``'s Gaussian into ``M1[o]``, ``M2[o]``."""
    m1 = (a0, a1)
    m2 = ((b00, b01), (b01, b11))
    for i in range(2):
        M1[o, 2 * i] = m1[i]
        M1[o, 2 * i + 1] = (0.0 + B[r, i, 0] * m1[0]) + B[r, i, 1] * m1[1]
    pv = np.empty((2, 2))
    for i in range(2):
        for k in range(2):
            pv[i, k] = (0.0 + m2[i][0] * B[r, k, 0]) + m2[i][1] * B[r, k, 1]
    for i in range(2):
        for k in range(2):
            M2[o, 2 * i, 2 * k] = m2[i][k]
            M2[o, 2 * i, 2 * k + 1] = pv[i, k]
            M2[o, 2 * i + 1, 2 * k] = pv[k, i]
            M2[o, 2 * i + 1, 2 * k + 1] = (((0.0 + B[r, i, 0] * pv[0, k])
                                            + B[r, i, 1] * pv[1, k]) + mass * resid[r, i, k])


@njit(cache=True, error_model="numpy")
def state_moments(means, covs, owner, x0, x1, y0, y1, B, resid, bounds, n_nodes, first,
                  nodes, weights):
    """:func:`.grid.rect_state_moments` after its regression (``B``, ``resid`` of
    ``covs``): the rectangles' position moments and each lifted to the full state."""
    n = len(owner)
    mean_xy = np.empty((n, 2))
    cov_xy = np.empty((n, 2, 2))
    for p in range(n):
        r = owner[p]
        mean_xy[p, 0], mean_xy[p, 1] = means[r, 0], means[r, 2]
        cov_xy[p, 0, 0], cov_xy[p, 0, 1] = covs[r, 0, 0], covs[r, 0, 2]
        cov_xy[p, 1, 0], cov_xy[p, 1, 1] = covs[r, 2, 0], covs[r, 2, 2]
    mass, m1, m2 = rect_position_moments(mean_xy, cov_xy, x0, x1, y0, y1, bounds, n_nodes,
                                         first, nodes, weights)
    M1 = np.empty((n, 4))
    M2 = np.empty((n, 4, 4))
    for p in range(n):
        _lift(B, resid, owner[p], mass[p], m1[p, 0], m1[p, 1], m2[p, 0, 0], m2[p, 0, 1],
              m2[p, 1, 1], M1, M2, p)
    return mass, M1, M2


@njit(cache=True, error_model="numpy")
def moment_match(ri_g, pu_g, mass_g, p1_g, p2_g, pair_of, g_pair, g_out, w_new, own, alp,
                 gauss_row, hit, m, P, B, resid, T, split_share):
    """:func:`.grid._moment_match`: the rows' sums over their pairs in pair order, the
    lift to the full state, the split components appended after the kept rows."""
    R = m.shape[0]
    n_gp = len(ri_g)
    g_rp = np.empty(n_gp)
    live = np.empty(n_gp, np.bool_)
    coef = np.empty(n_gp)
    go_r = np.empty(R)
    for r in range(R):
        go_r[r] = g_out[own[r]]
    acc = np.zeros(R)
    for p in range(n_gp):
        r = ri_g[p]
        live[p] = w_new[own[r]] > 0.0
        g_rp[p] = g_pair[pair_of[p]] if live[p] else 0.0
        coef[p] = g_rp[p] - go_r[r]
        acc[r] += coef[p] * mass_g[p]
    Z_full = go_r + acc
    split = np.zeros(n_gp, np.bool_)
    any_split = False
    if split_share > 0.0:
        full_alpha = np.empty(R)
        tot = np.zeros(T)
        for r in range(R):
            full_alpha[r] = alp[r] * (Z_full[r] if gauss_row[r] else 1.0)
            tot[own[r]] += full_alpha[r]
        for p in range(n_gp):
            r = ri_g[p]
            part = alp[r] * g_rp[p] * mass_g[p]
            share = part / _nan_max(tot[own[r]], 1e-300)
            split[p] = (hit[pu_g[p]] and share >= split_share and live[p]
                        and part < (1.0 - split_share) * full_alpha[r])
            any_split |= split[p]
    # the rest of each row: sums over its pairs of coef * (mass, m1, m2), lifted once
    sums = np.zeros((6, R))
    for p in range(n_gp):
        r = ri_g[p]
        c = coef[p] - g_rp[p] if split[p] else coef[p]
        sums[0, r] += c * mass_g[p]
        sums[1, r] += c * p1_g[p, 0]
        sums[2, r] += c * p1_g[p, 1]
        sums[3, r] += c * p2_g[p, 0, 0]
        sums[4, r] += c * p2_g[p, 0, 1]
        sums[5, r] += c * p2_g[p, 1, 1]
    Z = go_r + sums[0] if any_split else Z_full
    d = np.empty((R, 4))
    S2 = np.empty((R, 4, 4))
    means = m.copy()
    covs = P.copy()
    new_alpha = np.empty(R)
    upd = np.empty(R, np.bool_)
    dd = np.empty(4)
    for r in range(R):
        _lift(B, resid, r, Z[r] - go_r[r], sums[1, r], sums[2, r], sums[3, r], sums[4, r],
              sums[5, r], d, S2, r)
        for i in range(4):
            for j in range(4):
                S2[r, i, j] = S2[r, i, j] + go_r[r] * P[r, i, j]
        new_alpha[r] = alp[r] * (Z[r] if gauss_row[r] else 1.0)
        upd[r] = gauss_row[r] and w_new[own[r]] > 0.0 and Z[r] > 0.0
        if upd[r]:
            for i in range(4):
                dd[i] = d[r, i] / Z[r]
                means[r, i] = m[r, i] + dd[i]
            for i in range(4):
                for j in range(4):
                    cij = S2[r, i, j] / Z[r] - dd[i] * dd[j]
                    cji = S2[r, j, i] / Z[r] - dd[j] * dd[i]
                    covs[r, i, j] = 0.5 * (cij + cji)
    if not any_split:
        out_own = own.copy()
        prior_alpha = alp
    else:
        # a split row's remainder is dropped when negligible or its moments degenerate
        was_split = np.zeros(R, np.bool_)
        n_s = 0
        for p in range(n_gp):
            if split[p]:
                was_split[ri_g[p]] = True
                n_s += 1
        rest_ok = np.empty(R, np.bool_)
        n_rest = 0
        for r in range(R):
            sane = covs[r, 0, 0] > 0.0 and covs[r, 2, 2] > 0.0
            rest_ok[r] = (not was_split[r]) or (upd[r] and Z[r] > 1e-6 * Z_full[r] and sane)
            n_rest += rest_ok[r]
        n_out = n_rest + n_s
        out_m = np.empty((n_out, 4))
        out_P = np.empty((n_out, 4, 4))
        out_alpha = np.empty(n_out)
        out_own = np.empty(n_out, np.int64)
        prior_alpha = np.empty(n_out)
        o = 0
        for r in range(R):
            if rest_ok[r]:
                out_m[o] = means[r]
                out_P[o] = covs[r]
                out_alpha[o] = new_alpha[r]
                out_own[o] = own[r]
                prior_alpha[o] = alp[r]
                o += 1
        M1 = np.empty((1, 4))
        M2 = np.empty((1, 4, 4))
        sd = np.empty(4)
        for p in range(n_gp):
            if not split[p]:
                continue
            r, sm = ri_g[p], mass_g[p]
            _lift(B, resid, r, sm, p1_g[p, 0], p1_g[p, 1], p2_g[p, 0, 0], p2_g[p, 0, 1],
                  p2_g[p, 1, 1], M1, M2, 0)
            for i in range(4):
                sd[i] = M1[0, i] / sm
                out_m[o, i] = m[r, i] + sd[i]
            for i in range(4):
                for j in range(4):
                    cij = M2[0, i, j] / sm - sd[i] * sd[j]
                    cji = M2[0, j, i] / sm - sd[j] * sd[i]
                    out_P[o, i, j] = 0.5 * (cij + cji)
            out_alpha[o] = alp[r] * g_rp[p] * sm
            out_own[o] = own[r]
            prior_alpha[o] = alp[r] * 0.0
            o += 1
        means, covs, new_alpha = out_m, out_P, out_alpha
    # renormalise the mixture weights within each track (a track with no posterior mass
    # keeps its prior weights)
    tot = np.zeros(T)
    for o in range(len(out_own)):
        tot[out_own[o]] += new_alpha[o]
    alpha = np.empty(len(out_own))
    for o in range(len(out_own)):
        t = tot[out_own[o]]
        alpha[o] = new_alpha[o] / t if t > 0.0 else prior_alpha[o]
    return means, covs, alpha, out_own


@njit(cache=True, error_model="numpy")
def keep_promoted(weights, owner, alpha, means, covs, T, cand, cells, returns, prune):
    """After the update with birth candidates (tracks ``T..``): a candidate whose cell
    returned a detection and whose weight exceeds ``prune`` becomes a track; returns that
    mask, the candidates' new field values (0 where promoted, else their weight) and the
    kept tracks' ``w``, rows' ``owner`` (renumbered), ``alpha``, ``means``, ``covs``."""
    n_c = len(cand)
    det = np.sort(cells[returns])
    keep_track = np.ones(T + n_c, np.bool_)
    promote = np.zeros(n_c, np.bool_)
    u_new = np.empty(n_c)
    for j in range(n_c):
        wc = weights[T + j]
        pos = _search(det, cand[j])
        promote[j] = pos < len(det) and det[pos] == cand[j] and wc > prune
        u_new[j] = 0.0 if promote[j] else wc
        keep_track[T + j] = promote[j]
    new_index = np.cumsum(keep_track) - 1
    n_t = 0
    for t in range(T + n_c):
        n_t += keep_track[t]
    w = np.empty(n_t)
    for t in range(T + n_c):
        if keep_track[t]:
            w[new_index[t]] = weights[t]
    n_r = 0
    for r in range(len(owner)):
        n_r += keep_track[owner[r]]
    own = np.empty(n_r, np.int64)
    a = np.empty(n_r)
    m = np.empty((n_r, 4))
    P = np.empty((n_r, 4, 4))
    o = 0
    for r in range(len(owner)):
        if keep_track[owner[r]]:
            own[o] = new_index[owner[r]]
            a[o] = alpha[r]
            m[o] = means[r]
            P[o] = covs[r]
            o += 1
    return promote, u_new, w, own, a, m, P


@njit(cache=True, error_model="numpy")
def keep_and_prune(weights, owner, alpha, means, covs, T, cand, cells, returns, prune, tid,
                   next_tid, default, f_cells, f_values, floor, apply_floor):
    """The update's tail in one pass: :func:`keep_promoted`, the promoted candidates' new
    track ids (``next_tid`` on), the field's :func:`.step_kernels.field_set` of the
    candidates' values (then the floor when ``apply_floor``), and :func:`prune_tracks`.
    Returns the number of new tracks, the field's default, cells and values, and the
    pruned tracks' ``w``, ``owner``, ``alpha``, ``means``, ``covs`` and ids."""
    promote, u_new, w, own, a, m, P = keep_promoted(weights, owner, alpha, means, covs, T,
                                                    cand, cells, returns, prune)
    n_new = 0
    for j in range(len(promote)):
        n_new += promote[j]
    n_t = len(tid)
    tid2 = np.empty(n_t + n_new, np.int64)
    tid2[:n_t] = tid
    for j in range(n_new):
        tid2[n_t + j] = next_tid + j
    d, fc, fv = field_set(default, f_cells, f_values, cand, u_new, floor, apply_floor)
    w2, own2, a2, m2, P2, tid3 = prune_tracks(w, own, a, m, P, tid2, prune)
    return n_new, d, fc, fv, w2, own2, a2, m2, P2, tid3


@njit(cache=True, error_model="numpy")
def greedy_merge(w, m, P, close, threshold, bounded, sum_tol):
    """:func:`.tracker.merge_groups` after its sort by decreasing weight and its
    distances ``close``: the groups, greedily from the heaviest (``bounded``: members by
    increasing distance while the sum stays ``<= 1 + sum_tol``), each group's weight
    (``min(1, sum)``, numpy's pairwise sum in index order), and its ``w``-weighted moment
    match (sequential sums in index order, as ``np.add.at``). Returns the weights, the
    label of each input and the merged means and covariances."""
    K = len(w)
    label = np.full(K, -1, np.int64)
    out_w = np.empty(K)
    n_g = 0
    buf = np.empty(K)
    for i in range(K):
        if label[i] >= 0:
            continue
        g = n_g
        n_g += 1
        label[i] = g
        lonely = True
        for j in range(K):
            if close[i, j] < threshold:
                lonely = False
        if lonely:
            out_w[g] = 1.0 if 1.0 < w[i] else w[i]  # Python's min(w, 1.0)
            continue
        grp = np.empty(K, np.int64)
        n = 0
        for j in range(K):
            if close[i, j] < threshold and label[j] < 0:
                grp[n] = j
                n += 1
        if bounded:
            tot = w[i]
            order = np.argsort(close[i, grp[:n]], kind="mergesort")
            for q in range(n):
                j = grp[order[q]]
                if tot + w[j] <= 1.0 + sum_tol:
                    label[j] = g
                    tot += w[j]
            out_w[g] = 1.0 if 1.0 < tot else tot  # Python's min(tot, 1.0)
        else:
            for q in range(n):
                label[grp[q]] = g
            nb = 0
            for j in range(K):
                if label[j] == g:
                    buf[nb] = w[j]
                    nb += 1
            tot = np_sum(buf, nb)
            out_w[g] = tot if tot < 1.0 else 1.0  # Python's min(1.0, tot)
    mean = np.zeros((n_g, 4))
    cov = np.zeros((n_g, 4, 4))
    if n_g == K:
        return out_w[:n_g], label, mean, cov
    tot_w = np.zeros(n_g)
    head = np.full(n_g, -1, np.int64)
    for j in range(K):
        tot_w[label[j]] += w[j]
        if head[label[j]] < 0:
            head[label[j]] = j
    wn = np.empty(K)
    for j in range(K):
        g = label[j]
        if tot_w[g] > 0.0:
            wn[j] = w[j] / tot_w[g]
        else:
            wn[j] = 1.0 if j == head[g] else 0.0
        for x in range(4):
            mean[g, x] += wn[j] * m[j, x]
    for j in range(K):
        g = label[j]
        for x in range(4):
            dx = m[j, x] - mean[g, x]
            for y in range(4):
                cov[g, x, y] += wn[j] * (P[j, x, y] + dx * (m[j, y] - mean[g, y]))
    return out_w[:n_g], label, mean, cov


@njit(cache=True, error_model="numpy")
def prune_tracks(w, own, a, m, P, tid, threshold):
    """The tracks with ``w >= threshold`` (NaN goes), their rows, owners renumbered."""
    T, R = len(w), len(own)
    idx = np.empty(T, np.int64)
    n_t = 0
    for t in range(T):
        idx[t] = n_t
        n_t += w[t] >= threshold
    w2 = np.empty(n_t)
    tid2 = np.empty(n_t, np.int64)
    for t in range(T):
        if w[t] >= threshold:
            w2[idx[t]], tid2[idx[t]] = w[t], tid[t]
    n_r = 0
    for r in range(R):
        n_r += w[own[r]] >= threshold
    own2 = np.empty(n_r, np.int64)
    a2 = np.empty(n_r)
    m2 = np.empty((n_r, 4))
    P2 = np.empty((n_r, 4, 4))
    o = 0
    for r in range(R):
        if w[own[r]] >= threshold:
            own2[o], a2[o] = idx[own[r]], a[r]
            m2[o] = m[r]
            P2[o] = P[r]
            o += 1
    return w2, own2, a2, m2, P2, tid2


@njit(cache=True, error_model="numpy")
def reduce_components(own, a, m, P, T, max_components, threshold, floor, sum_tol):
    """:meth:`.tracker.GaussianParticleFilter._reduce_components` for ``max_components >
    1``: each track keeps its rows of weight ``>= floor`` and its heaviest; with
    ``threshold > 0`` a track's rows merge by :func:`.tracker.merge_groups`' capped rule on
    Bhattacharyya distances (:func:`.step_kernels.pair_distances`, :func:`greedy_merge`);
    beyond ``max_components`` a track's lightest rows are moment-matched into one
    (:func:`.step_kernels.cap_and_normalise`, shared with pmb); the weights are normalised
    per track. The same operations in the same order as the numpy form (``bincount`` sums
    in index order from 0). Returns ``own``, ``a``, ``m``, ``P``."""
    idx = np.nonzero(above_floor(own, a, floor))[0]
    own, a, m, P = own[idx], a[idx], m[idx], P[idx]
    K = len(a)
    if threshold > 0 and K > 1:
        o = np.argsort(-a, kind="mergesort")
        w_s, m_s, P_s, g_s = a[o], m[o], P[o], own[o]
        close = pair_distances(m_s, P_s, threshold, True, g_s, True)
        out_w, label, mean, cov = greedy_merge(w_s, m_s, P_s, close, threshold, False,
                                               sum_tol)
        merged_own = np.empty(len(out_w), np.int64)
        for q in range(K):
            merged_own[label[q]] = g_s[q]  # a group's members share their track
        if len(out_w) == K:
            own, a, m, P = merged_own, out_w, m_s, P_s
        else:
            own, a, m, P = merged_own, out_w, mean, cov
    order = by_track_heaviest_first(own, a)
    return cap_and_normalise(own[order], a[order], m[order], P[order], T, max_components)


@njit(cache=True, error_model="numpy")
def rows_by_track(own, a, m, P):
    """The rows in a stable order of their track."""
    order = np.argsort(own, kind="mergesort")
    return own[order], a[order], m[order], P[order]


@njit(cache=True, error_model="numpy")
def position_inverse(P):
    """:func:`.kalman.inverse` of each position block ``P[:, 0::2, 0::2]`` (closed form)."""
    R = P.shape[0]
    out = np.empty((R, 2, 2))
    for r in range(R):
        a, b, c, d = P[r, 0, 0], P[r, 0, 2], P[r, 2, 0], P[r, 2, 2]
        det = a * d - b * c
        out[r, 0, 0], out[r, 0, 1] = d / det, -b / det
        out[r, 1, 0], out[r, 1, 1] = -c / det, a / det
    return out


@njit(cache=True, error_model="numpy")
def near_walls(m, P, range_sigmas, width, height):
    """The rows whose ``range_sigmas`` box reaches beyond the workspace
    (:func:`.grid.fold_into_workspace`'s test)."""
    R = m.shape[0]
    out = np.empty(R, np.int64)
    n = 0
    for r in range(R):
        sx = range_sigmas * np.sqrt(_nan_max(P[r, 0, 0], 0.0))
        sy = range_sigmas * np.sqrt(_nan_max(P[r, 2, 2], 0.0))
        if (m[r, 0] - sx < 0 or m[r, 0] + sx > width or m[r, 2] - sy < 0
                or m[r, 2] + sy > height):
            out[n] = r
            n += 1
    return out[:n]


@njit(cache=True, error_model="numpy")
def _axis_mass(mean, sd, length, shift_unit, ix):
    """Image ``ix`` of one axis (:func:`.grid._axis_images`): its sign, shift and mass
    inside ``[0, length)``."""
    sign = 1.0 if ix < 3 else -1.0
    shift = shift_unit * (ix % 3 - 1.0)
    mu = sign * mean + shift
    return sign, shift, _ndtr((length - mu) / sd, 0) - _ndtr(-mu / sd, 0)


@njit(cache=True, error_model="numpy")
def reflection_images(m, P, width, height, mass_floor, range_sigmas):
    """:func:`.grid.reflection_images` (images ``owner``, ``means``, ``covs`` in its
    order: by Gaussian, then x image, then y image) and the images whose
    ``range_sigmas`` box reaches beyond the workspace (``known_existence_update``'s
    ``edge``)."""
    K = m.shape[0]
    keep = np.zeros((K, 6, 6), np.bool_)
    sgn = np.empty((K, 2, 6))
    shf = np.empty((K, 2, 6))
    J = 0
    for k in range(K):
        mass = np.empty((2, 6))
        for a, (col, length) in enumerate(((0, width), (2, height))):
            sd = _nan_max(np.sqrt(_nan_max(P[k, col, col], 0.0)), 1e-300)
            for ix in range(6):
                sgn[k, a, ix], shf[k, a, ix], mass[a, ix] = _axis_mass(
                    m[k, col], sd, length, 2.0 * length, ix)
        for ix in range(6):
            for iy in range(6):
                keep[k, ix, iy] = mass[0, ix] * mass[1, iy] > mass_floor or (ix == 1 and iy == 1)
                J += keep[k, ix, iy]
    owner = np.empty(J, np.int64)
    cm = np.empty((J, 4))
    cP = np.empty((J, 4, 4))
    edge = np.empty(J, np.int64)
    sg = np.empty(4)
    j, n_e = 0, 0
    for k in range(K):
        for ix in range(6):
            for iy in range(6):
                if not keep[k, ix, iy]:
                    continue
                owner[j] = k
                sg[0] = sg[1] = sgn[k, 0, ix]
                sg[2] = sg[3] = sgn[k, 1, iy]
                cm[j, 0] = sg[0] * m[k, 0] + shf[k, 0, ix]
                cm[j, 1] = sg[1] * m[k, 1] + 0.0
                cm[j, 2] = sg[2] * m[k, 2] + shf[k, 1, iy]
                cm[j, 3] = sg[3] * m[k, 3] + 0.0
                for a in range(4):
                    for b in range(4):
                        cP[j, a, b] = sg[a] * P[k, a, b] * sg[b]
                sx = np.sqrt(_nan_max(cP[j, 0, 0], 0.0))
                sy = np.sqrt(_nan_max(cP[j, 2, 2], 0.0))
                if (cm[j, 0] - range_sigmas * sx < 0 or cm[j, 0] + range_sigmas * sx > width
                        or cm[j, 2] - range_sigmas * sy < 0
                        or cm[j, 2] + range_sigmas * sy > height):
                    edge[n_e] = j
                    n_e += 1
                j += 1
    return owner, cm, cP, edge[:n_e]


@njit(cache=True, error_model="numpy")
def fold_moments(m, P, owner, cm, cP, edge, B, resid, width, height, x_top, y_top, tiny,
                 bounds, n_nodes, first, nodes, weights):
    """:func:`.grid.known_existence_update` without looks, ``workspace="reflect"``, after
    its images (:func:`reflection_images`) and the regression of the wall-reaching ones
    (``B``, ``resid``): each image's mass and moments in the workspace (1, 0 and its
    covariance away from the walls), summed per Gaussian in image order and moment
    matched; a Gaussian with no mass left keeps its prior, the position clipped to
    ``[0, x_top]``, ``[0, y_top]`` (the largest doubles below the width and height)."""
    K, J = m.shape[0], len(owner)
    n_e = len(edge)
    em = np.empty((n_e, 4))
    eP = np.empty((n_e, 4, 4))
    for q in range(n_e):
        em[q] = cm[edge[q]]
        eP[q] = cP[edge[q]]
    zeros = np.zeros(n_e)
    mass_e, M1_e, M2_e = state_moments(em, eP, np.arange(n_e), zeros, np.full(n_e, width),
                                       zeros, np.full(n_e, height), B, resid, bounds,
                                       n_nodes, first, nodes, weights)
    Zc = np.ones(J)
    S1 = np.zeros((J, 4))
    S2 = cP.copy()
    for q in range(n_e):
        Zc[edge[q]] = mass_e[q]
        S1[edge[q]] = M1_e[q]
        S2[edge[q]] = M2_e[q]
    # (the numpy form's weights exp(-top) are exactly 1 without looks)
    Z = np.zeros(K)
    raw1 = np.zeros((K, 4))
    for j in range(J):
        Z[owner[j]] += Zc[j]
        for a in range(4):
            raw1[owner[j], a] += Zc[j] * cm[j, a] + S1[j, a]
    mean = np.empty((K, 4))
    for k in range(K):
        for a in range(4):
            mean[k, a] = raw1[k, a] / Z[k] if Z[k] > tiny else m[k, a]
    S = np.zeros((K, 4, 4))
    delta = np.empty(4)
    for j in range(J):
        k = owner[j]
        for a in range(4):
            delta[a] = cm[j, a] - mean[k, a]
        for a in range(4):
            for b in range(4):
                S[k, a, b] += (((S2[j, a, b] + S1[j, a] * delta[b]) + delta[a] * S1[j, b])
                               + Zc[j] * delta[a] * delta[b])
    means, covs = m.copy(), P.copy()
    for k in range(K):
        if Z[k] > tiny:
            means[k] = mean[k]
            for a in range(4):
                for b in range(4):
                    covs[k, a, b] = 0.5 * (S[k, a, b] / Z[k] + S[k, b, a] / Z[k])
        else:
            # np.clip: np.maximum then np.minimum (NaN stays, -0.0 at 0.0 stays -0.0)
            means[k, 0] = _nan_min(_nan_max(m[k, 0], 0.0), x_top)
            means[k, 2] = _nan_min(_nan_max(m[k, 2], 0.0), y_top)
    return means, covs


def warm_up() -> None:
    """Compile (or load from the disk cache) every kernel the GPF calls, on tiny inputs of
    the argument types it passes (about 50 s of CPU the first time after an edit, 0.2 s
    from the cache; docs/speed.md). Cheap after the first time in a process."""
    if getattr(warm_up, "done", False):
        return
    # the kernels these call first (with a caller's cache older than its callee's, a
    # callee first loaded inside its caller returned arrays without their dtype)
    step_kernels.warm_up()
    cluster_kernels.warm_up()
    f, i, b = np.ones(1), np.zeros(1, np.int64), np.zeros(1, np.bool_)
    m, P = np.zeros((1, 4)), np.eye(4)[None]
    # pairs_and_singletons is compiled into grid_update_packed (alone: tests only);
    # moment_match alone serves the updates with clusters
    moment_match(i, i, f, np.zeros((1, 2)), np.zeros((1, 2, 2)), i, f, f, f, i, f, b | True, b,
                 m, P, np.zeros((1, 2, 2)), np.zeros((1, 2, 2)), 1, 0.1)
    grid_update_packed(0.5 * f, m, P, i - 1, i, f, i, b, 0.5, -0.1, 1.0, 1, 1, 1e-3, 6.0,
                       np.array([np.inf]), np.array([2], np.int64), i, np.zeros(2), np.ones(2),
                       np.zeros((1, 2, 2)), np.zeros((1, 2, 2)), 0.1)
    w2, own2, a2, m2, P2, ucell = step_kernels.with_candidates(f, i, f, m, P, i, f, 1.0, 1, 1.0)
    keep_promoted(w2, own2, a2, m2, P2, 1, i, i, b, 1e-3)
    keep_and_prune(w2, own2, a2, m2, P2, 1, i, i, b, 1e-3, i, 1, 0.1, i, f, 1e-4, True)
    for bounded in (False, True):
        greedy_merge(w2, m2, P2, np.zeros((2, 2)), 4.0, bounded, 1e-9)
    position_inverse(P2)
    prune_tracks(w2, own2, a2, m2, P2, own2, 1e-3)
    rows_by_track(own2, a2, m2, P2)
    for threshold in (0.0, 4.0):
        reduce_components(own2, a2, m2, P2, 2, 2, threshold, 0.02, 1e-9)
    near_walls(m2, P2, 6.0, 1.0, 1.0)
    owner, cm, cP, edge = reflection_images(m2, P2, 1.0, 1.0, 1e-9, 6.0)
    fold_moments(m2, P2, owner, cm, cP, edge, np.zeros((len(edge), 2, 2)),
                 np.zeros((len(edge), 2, 2)), 1.0, 1.0, 0.99, 0.99, 1e-300,
                 np.array([np.inf]), np.array([2], np.int64), i, np.zeros(2), np.ones(2))
    state_moments(m2, P2, i, f, f + 1.0, f, f + 1.0, np.zeros((2, 2, 2)), np.zeros((2, 2, 2)),
                  np.array([np.inf]), np.array([2], np.int64), i, np.zeros(2), np.ones(2))
    warm_up.done = True
