"""pmb's step in compiled (numba) passes, each equal bit for bit to its numpy form: the
cell ratios (:func:`.update.cell_ratios`), the update (:func:`.update.pmb_update`, its
loopy belief propagation :func:`.lbp.association_marginals` included), the mixture bound
(:func:`.tracker.reduce_rows`) and the tracker's whole measurement step around them
(:func:`step_update`: the PPP's intensity at the detections, its miss factor, the new
Bernoullis).

Why: on a small grid pmb's update is a few hundred numpy calls on arrays of a few dozen
pairs, so its time is the interpreter's (docs/speed.md, the pmb section).

Exactness: each pass performs its numpy form's IEEE operations in the same order.
``bincount`` and ``ufunc.at`` add sequentially in index order from 0; ``np.unique``'s
keys come from a stable sort; ``np.lexsort((-a, own))`` is a stable sort by track, then
by decreasing weight (NaN last); ``np.maximum`` and ``np.minimum`` return a NaN operand
(the first when both are), else the second when the two compare equal (``-0.0`` and
``0.0``), and ``np.clip`` keeps a NaN and ``-0.0`` (:func:`_maximum`, :func:`_minimum`,
:func:`_clip`, checked on these values by ``tests/test_pmb_kernels.py``); ``exp`` is the
C library's, as numpy's is for doubles without AVX-512; the rectangles' moments are the
GPF's kernel (:func:`.gpf.update_kernels.state_moments`) after the position regression,
whose 2x2 ``matmul`` stays numpy (the caller's ``B``, ``resid``); a division by zero
gives numpy's inf or NaN (``error_model="numpy"``). The clusters of the association
graph are scipy's connected components, labelled as scipy labels them (in the order of
each component's smallest node, tracks before measurements), found by union-find.
``tests/test_pmb_kernels.py`` compares each pass with its numpy form byte for byte and
whole runs with and without the kernels.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from ..compiled import drop_stale_caches
from ..gpf import step_kernels
from ..gpf.step_kernels import above_floor, cap_and_normalise
from ..gpf.step_kernels import by_track_heaviest_first as _by_track_heaviest_first
from ..gpf.step_kernels import collapse as _collapse
from ..gpf.update_kernels import state_moments
from ..grid_kernels import field_apply, looked_in_boxes
from ..numba_exact import find_root as _find
from ..numba_exact import search_left as _search
from ..numba_exact import unique_inverse as _unique_inverse

drop_stale_caches()  # before any kernel loads: a caller's cache may hold an old callee


@njit(cache=True, error_model="numpy")
def _maximum(a: float, b: float) -> float:
    """``np.maximum(a, b)`` for doubles: a NaN operand (the first if both), else ``b``
    when the two compare equal."""
    if a != a:
        return a
    if b != b:
        return b
    return a if a > b else b


@njit(cache=True, error_model="numpy")
def _minimum(a: float, b: float) -> float:
    """``np.minimum(a, b)`` for doubles (NaN and ties as :func:`_maximum`)."""
    if a != a:
        return a
    if b != b:
        return b
    return a if a < b else b


@njit(cache=True, error_model="numpy")
def _clip(x: float, lo: float, hi: float) -> float:
    """``np.clip(x, lo, hi)`` for a double: a NaN and a bound's equal (``-0.0`` at 0)
    stay."""
    if x != x:
        return x
    if x < lo:
        return lo
    if x > hi:
        return hi
    return x


# ----------------------------------------------------------------------- cell ratios
@njit(cache=True, error_model="numpy")
def cell_ratios(cells, returns, ll_pos, ll_neg, ll_miss, max_log):
    """:func:`.update.cell_ratios`: ``U (n_u,)`` and ``(L, M, S) (3, n_u)``, ``positive
    (n_u,)``. ``ll_pos``, ``ll_neg``: one look's ``log l(1)`` with and without a return
    (summed per cell in look order, ``np.add.at``'s), ``ll_miss`` the same without a
    return as the numpy form computes it for the miss factor."""
    U = np.unique(cells)
    n_u = len(U)
    LL1 = np.zeros(n_u)
    n = np.zeros(n_u)
    k = np.zeros(n_u)
    for j in range(len(cells)):
        u = _search(U, cells[j])
        LL1[u] += ll_pos if returns[j] else ll_neg
        n[u] += 1.0
        k[u] += 1.0 if returns[j] else 0.0
    out = np.empty((3, n_u))
    positive = np.empty(n_u, np.bool_)
    for u in range(n_u):
        L = np.exp(_minimum(LL1[u], max_log))
        M = np.exp(_minimum(n[u] * ll_miss, max_log))
        positive[u] = k[u] > 0
        out[0, u] = L
        out[1, u] = M if positive[u] else L
        out[2, u] = _maximum(L - M, 0.0) if positive[u] else 0.0
    return U, out, positive


# ------------------------------------------------------ association marginals (LBP)
@njit(cache=True, error_model="numpy")
def edge_clusters(ei, ej, n_tracks, n_meas):
    """:func:`.lbp.edge_clusters`: each edge's connected component, labelled as scipy's
    ``connected_components`` labels the nodes (in the order of each component's smallest
    node; tracks are nodes ``0..T-1``, measurements ``T..``)."""
    E = len(ei)
    if E == 0:
        return np.zeros(0, np.int64)
    n = n_tracks + n_meas
    parent = np.arange(n)
    for e in range(E):
        a, b = _find(parent, ei[e]), _find(parent, n_tracks + ej[e])
        if a < b:
            parent[b] = a
        elif b < a:
            parent[a] = b
    label = np.empty(n, np.int64)
    n_lab = 0
    for v in range(n):
        root = _find(parent, v)
        if root == v:
            label[v] = n_lab
            n_lab += 1
        else:
            label[v] = label[root]  # the root is the smaller node, labelled before
    out = np.empty(E, np.int64)
    for e in range(E):
        out[e] = label[ei[e]]
    return out


@njit(cache=True, error_model="numpy")
def association_marginals(w0, ei, ej, w, beta, tol, max_iter):
    """:func:`.lbp.association_marginals`: the same messages, iterated over every edge
    (a converged cluster's messages kept) with each node's sum in edge order
    (``bincount``'s). Returns ``p_missed (T,)``, ``p_edge (E,)``, ``p_unused (J,)``,
    ``iterations``, ``converged``, ``cluster (E,)``."""
    T, J, E = len(w0), len(beta), len(w)
    cluster = edge_clusters(ei, ej, T, J)
    if E == 0:
        return np.ones(T), np.zeros(0), np.ones(J), 0, True, cluster
    n_clusters = 0
    for e in range(E):
        n_clusters = max(n_clusters, cluster[e] + 1)
    nu = np.empty(E)
    for e in range(E):
        nu[e] = 1.0 / beta[ej[e]]
    active = np.ones(E, np.bool_)
    mu = np.zeros(E)
    s_track = np.empty(T)
    s_meas = np.empty(J)
    worst = np.empty(n_clusters)
    it, converged = 0, False
    for step in range(1, max_iter + 1):
        it = step
        # mu_{i->j} = w_ij / (w_i0 + sum_{j' != j} w_ij' nu_{j'->i})
        s_track[:] = 0.0
        for e in range(E):
            s_track[ei[e]] += w[e] * nu[e]
        for t in range(T):
            s_track[t] = w0[t] + s_track[t]
        for e in range(E):
            mu[e] = w[e] / _maximum(s_track[ei[e]] - w[e] * nu[e], w0[ei[e]])
        # nu_{j->i} = 1 / (beta_j + sum_{i' != i} mu_{i'->j})
        s_meas[:] = 0.0
        for e in range(E):
            s_meas[ej[e]] += mu[e]
        for j in range(J):
            s_meas[j] = beta[j] + s_meas[j]
        worst[:] = 0.0
        for e in range(E):
            new_nu = 1.0 / _maximum(s_meas[ej[e]] - mu[e], beta[ej[e]])
            change = np.abs(new_nu - nu[e]) / _maximum(new_nu, 1e-300)
            if active[e]:
                nu[e] = new_nu
            worst[cluster[e]] = _maximum(worst[cluster[e]], change if active[e] else 0.0)
        any_active = False
        for e in range(E):
            active[e] = worst[cluster[e]] > tol
            any_active |= active[e]
        if not any_active:
            converged = True
            break
    # marginals from the final messages (mu recomputed from the final nu)
    s_track[:] = 0.0
    for e in range(E):
        s_track[ei[e]] += w[e] * nu[e]
    p_missed = np.empty(T)
    for t in range(T):
        s_track[t] = w0[t] + s_track[t]
        p_missed[t] = w0[t] / s_track[t]
    p_edge = np.empty(E)
    s_meas[:] = 0.0
    for e in range(E):
        p_edge[e] = w[e] * nu[e] / s_track[ei[e]]
        mu[e] = w[e] / _maximum(s_track[ei[e]] - w[e] * nu[e], w0[ei[e]])
        s_meas[ej[e]] += mu[e]
    p_unused = np.empty(J)
    for j in range(J):
        p_unused[j] = beta[j] / (beta[j] + s_meas[j])
    return p_missed, p_edge, p_unused, it, converged, cluster


# --------------------------------------------------------------------------- update
@njit(cache=True, error_model="numpy")
def pmb_update(r, own, alpha, m, P, B, resid, U, L, M, S, positive, lam_meas, s, nx, ny,
               range_sigmas, tol, max_iter, bounds, n_nodes, first, nodes, weights):
    """:func:`.update.pmb_update` after its position regression (``B``, ``resid`` of
    ``P``), on the cell ratios ``U``, ``L``, ``M``, ``S``, ``positive``. Returns the
    :class:`.update.PMBUpdate`'s arrays: ``r_post``, ``out_own``, ``alpha_post``,
    ``means``, ``covs``, ``hyp``, ``meas_cells``, ``r_new``, the marginals' ``p_missed``,
    ``p_edge``, ``p_unused``, ``iterations``, ``converged``, ``cluster``, and
    ``n_pairs``."""
    T, R, n_u = len(r), m.shape[0], len(U)
    J = 0
    for u in range(n_u):
        J += positive[u]
    meas = np.empty(J, np.int64)
    jmap = np.full(n_u, -1, np.int64)
    j = 0
    for u in range(n_u):
        if positive[u]:
            meas[j], jmap[u] = u, j
            j += 1
    # (row, looked cell) pairs within range, each row's Gaussian on each cell
    if R and n_u:
        lo_x = np.empty(R)
        hi_x = np.empty(R)
        lo_y = np.empty(R)
        hi_y = np.empty(R)
        for q in range(R):
            sx = np.sqrt(_maximum(P[q, 0, 0], 0.0))
            sy = np.sqrt(_maximum(P[q, 2, 2], 0.0))
            lo_x[q] = np.floor((m[q, 0] - range_sigmas * sx) / s)
            hi_x[q] = np.floor((m[q, 0] + range_sigmas * sx) / s)
            lo_y[q] = np.floor((m[q, 2] - range_sigmas * sy) / s)
            hi_y[q] = np.floor((m[q, 2] + range_sigmas * sy) / s)
        pr, pu = looked_in_boxes(lo_x, hi_x, lo_y, hi_y, U, nx, ny)
    else:
        pr = np.zeros(0, np.int64)
        pu = np.zeros(0, np.int64)
    n_p = len(pr)
    x0 = np.empty(n_p)
    x1 = np.empty(n_p)
    y0 = np.empty(n_p)
    y1 = np.empty(n_p)
    for p in range(n_p):
        c = U[pu[p]]
        ix, iy = c % nx, c // nx
        x0[p], x1[p] = ix * s, (ix + 1) * s
        y0[p], y1[p] = iy * s, (iy + 1) * s
    if n_p:
        mass, M1, M2 = state_moments(m, P, pr, x0, x1, y0, y1, B, resid, bounds, n_nodes,
                                     first, nodes, weights)
        for p in range(n_p):
            mass[p] = _clip(mass[p], 0.0, 1.0)
    else:
        mass, M1, M2 = np.zeros(0), np.zeros((0, 4)), np.zeros((0, 4, 4))
    # per (track, looked cell): the track's mass m_tc = sum_r alpha_r m_rc
    key = np.empty(n_p, np.int64)
    for p in range(n_p):
        key[p] = own[pr[p]] * n_u + pu[p]
    tkey, pair_tc = _unique_inverse(key)
    n_tc = len(tkey)
    m_tc = np.zeros(n_tc)
    for p in range(n_p):
        m_tc[pair_tc[p]] += alpha[pr[p]] * mass[p]
    nd = max(n_u, 1)
    t_of = np.empty(n_tc, np.int64)
    u_of = np.empty(n_tc, np.int64)
    in_t = np.zeros(T)
    miss_t = np.zeros(T)
    for k in range(n_tc):
        t_of[k], u_of[k] = tkey[k] // nd, tkey[k] % nd
        in_t[t_of[k]] += m_tc[k]
    for k in range(n_tc):
        miss_t[t_of[k]] += m_tc[k] * M[u_of[k]]
    # association weights and marginals over (track, measured cell) edges
    w0 = np.empty(T)
    for t in range(T):
        Q = _maximum(1.0 - in_t[t], 0.0) + miss_t[t]
        w0[t] = _maximum(1.0 - r[t] + r[t] * Q, 1e-300)
    edge_of = np.full(n_tc, -1, np.int64)
    E = 0
    for k in range(n_tc):
        if positive[u_of[k]] and m_tc[k] > 0.0:
            edge_of[k] = E
            E += 1
    ei = np.empty(E, np.int64)
    ej = np.empty(E, np.int64)
    w_edge = np.empty(E)
    for k in range(n_tc):
        e = edge_of[k]
        if e >= 0:
            ei[e], ej[e] = t_of[k], jmap[u_of[k]]
            w_edge[e] = r[t_of[k]] * m_tc[k] * S[u_of[k]]
    nu_new = np.empty(J)
    beta = np.empty(J)
    for j in range(J):
        nu_new[j] = lam_meas[j] * S[meas[j]]
        beta[j] = 1.0 + nu_new[j]
    p_missed, p_edge, p_unused, iterations, converged, cluster = association_marginals(
        w0, ei, ej, w_edge, beta, tol, max_iter)
    # "source of nothing": every row times g_0 (M_c in looked cells, 1 elsewhere)
    acc = np.zeros(R)
    S1 = np.zeros((R, 4))
    S2 = P.copy()
    for p in range(n_p):
        q = pr[p]
        coef = M[pu[p]] - 1.0
        acc[q] += coef * mass[p]
        for a in range(4):
            S1[q, a] += coef * M1[p, a]
        for a in range(4):
            for b in range(4):
                S2[q, a, b] += coef * M2[p, a, b]
    # "source of measured cell j": the pairs of an edge with mass
    n_src = 0
    for p in range(n_p):
        n_src += edge_of[pair_tc[p]] >= 0 and mass[p] > 0.0
    n_out = R + n_src
    out_own = np.empty(n_out, np.int64)
    w_all = np.empty(n_out)
    means = np.empty((n_out, 4))
    covs = np.empty((n_out, 4, 4))
    hyp = np.empty(n_out, np.int64)
    d = np.empty(4)
    c = np.empty((4, 4))
    for q in range(R):
        Z0 = 1.0 + acc[q]
        ok = Z0 > 1e-300
        t = own[q]
        out_own[q] = t
        hyp[q] = -1
        w_all[q] = p_missed[t] * r[t] / w0[t] * alpha[q] * Z0
        for a in range(4):
            d[a] = S1[q, a] / (Z0 if ok else 1.0) if ok else 0.0
            means[q, a] = m[q, a] + d[a]
        for a in range(4):
            for b in range(4):
                c[a, b] = (S2[q, a, b] / (Z0 if ok else 1.0) if ok else P[q, a, b]) - d[a] * d[b]
        for a in range(4):
            for b in range(4):
                covs[q, a, b] = 0.5 * (c[a, b] + c[b, a])
    o = R
    for p in range(n_p):
        e = edge_of[pair_tc[p]]
        if not (e >= 0 and mass[p] > 0.0):
            continue
        q = pr[p]
        out_own[o] = own[q]
        hyp[o] = jmap[pu[p]]
        w_all[o] = p_edge[e] * alpha[q] * mass[p] / m_tc[pair_tc[p]]
        for a in range(4):
            d[a] = M1[p, a] / mass[p]
            means[o, a] = m[q, a] + d[a]
        for a in range(4):
            for b in range(4):
                c[a, b] = M2[p, a, b] / mass[p] - d[a] * d[b]
        for a in range(4):
            for b in range(4):
                covs[o, a, b] = 0.5 * (c[a, b] + c[b, a])
        o += 1
    # the posterior rows' track existence and weights within it
    tot = np.zeros(T)
    for o in range(n_out):
        tot[out_own[o]] += w_all[o]
    r_post = np.empty(T)
    for t in range(T):
        r_post[t] = _clip(tot[t], 0.0, 1.0)
    alpha_post = np.empty(n_out)
    for o in range(n_out):
        t = out_own[o]
        if tot[t] > 0.0:
            alpha_post[o] = w_all[o] / tot[t]
        else:
            alpha_post[o] = alpha[o] if o < R else 0.0
    r_new = np.empty(J)
    meas_cells = np.empty(J, np.int64)
    for j in range(J):
        r_new[j] = p_unused[j] * nu_new[j] / beta[j]
        meas_cells[j] = U[meas[j]]
    return (r_post, out_own, alpha_post, means, covs, hyp, meas_cells, r_new, p_missed,
            p_edge, p_unused, iterations, converged, cluster, n_p)


# ------------------------------------------------------------------ mixture bound
@njit(cache=True, error_model="numpy")
def reduce_rows(own, a, m, P, hyp, T, max_components, floor):
    """:func:`.tracker.reduce_rows` (``floor``: its ``COMPONENT_FLOOR``): the rows of one
    track truncated to the same cell merged, the floor, the lightest beyond
    ``max_components`` merged, the weights renormalised. Returns ``own``, ``a``, ``m``,
    ``P``, sorted by track."""
    R = len(own)
    n_h = 1
    if R:
        n_h = hyp.max() + 2
    key = np.empty(R, np.int64)
    for i in range(R):
        key[i] = own[i] * n_h + hyp[i] + 1 if hyp[i] >= 0 else -1 - i
    _, grp = _unique_inverse(key)
    n_g = 0
    for i in range(R):
        n_g = max(n_g, grp[i] + 1)
    g_own = np.zeros(n_g, np.int64)
    g_a = np.zeros(n_g)
    for i in range(R):
        g_own[grp[i]] = own[i]
        g_a[grp[i]] += a[i]
    if n_g < R:
        m, P = _collapse(a, m, P, grp, n_g)
    else:  # nothing to merge: the rows in the groups' order
        m2 = np.empty((n_g, 4))
        P2 = np.empty((n_g, 4, 4))
        for i in range(R):
            m2[grp[i]] = m[i]
            P2[grp[i]] = P[i]
        m, P = m2, P2
    own, a = g_own, g_a
    # the floor, each track keeping its heaviest row
    keep = above_floor(own, a, floor)
    # then sorted by track, heaviest first
    n_k = 0
    for i in range(n_g):
        n_k += keep[i]
    idx = np.empty(n_k, np.int64)
    n_k = 0
    for i in range(n_g):
        if keep[i]:
            idx[n_k] = i
            n_k += 1
    order = _by_track_heaviest_first(own[idx], a[idx])
    own, a, m, P = own[idx[order]], a[idx[order]], m[idx[order]], P[idx[order]]
    return cap_and_normalise(own, a, m, P, T, max_components)


# ------------------------------------------------------- the PPP (a CellField's arrays)
@njit(cache=True, error_model="numpy")
def field_at(f_default, f_cells, f_values, cells):
    """:meth:`.cells.CellField.at`: the field's values at ``cells``."""
    out = np.full(len(cells), f_default)
    n_f = len(f_cells)
    if n_f:
        for i in range(len(cells)):
            k = min(_search(f_cells, cells[i]), n_f - 1)
            if f_cells[k] == cells[i]:
                out[i] = f_values[k]
    return out


# ------------------------------------------------------------ the tracker's update
#: :func:`step_update`'s integer header: sizes and flags
HEADER = 12


@njit(cache=True, error_model="numpy")
def step_update(r, own, alpha, m, P, tid, next_tid, B, resid, cells, returns, ll_pos,
                ll_neg, ll_miss, max_log, f_default, f_cells, f_values, s, nx, ny,
                range_sigmas, tol, max_iter, max_components, floor, recycle_threshold,
                max_tracks, P_new, bounds, n_nodes, first, nodes, weights):
    """:meth:`.tracker.PMBTracker.update` up to its merge and recycling: the cell ratios,
    the PPP at the detections, :func:`pmb_update`, the PPP's miss factor, :func:`
    reduce_rows`, the new Bernoullis (kept, or their existence added to the PPP), all
    returned in one integer and one float array (numba boxes each returned array at a
    cost of microseconds; :func:`.tracker.unpack_step` reads them). ``ints[:HEADER]``:
    ``T', R', rows out of the update, J, E, n_f, iterations, converged, n_pairs, next
    tid, recycle`` (``recycle``: some track is below ``recycle_threshold`` or there are
    more than ``max_tracks``)."""
    U, LMS, positive = cell_ratios(cells, returns, ll_pos, ll_neg, ll_miss, max_log)
    n_u = len(U)
    J = 0
    for u in range(n_u):
        J += positive[u]
    meas = np.empty(J, np.int64)
    j = 0
    for u in range(n_u):
        if positive[u]:
            meas[j] = U[u]
            j += 1
    lam_meas = field_at(f_default, f_cells, f_values, meas)
    (r_post, out_own, alpha_post, means, covs, hyp, meas_cells, r_new, p_missed, p_edge,
     p_unused, iterations, converged, cluster, n_pairs) = pmb_update(
        r, own, alpha, m, P, B, resid, U, LMS[0], LMS[1], LMS[2], positive, lam_meas, s,
        nx, ny, range_sigmas, tol, max_iter, bounds, n_nodes, first, nodes, weights)
    # the PPP's targets missed by the looks
    f_cells, f_values = field_apply(f_default, f_cells, f_values, U, LMS[1], False)
    T = len(r)
    own2, a2, m2, P2 = reduce_rows(out_own, alpha_post, means, covs, hyp, T,
                                   max_components, floor)
    # new Bernoullis: kept above the recycling threshold, else back into the PPP
    n_new = 0
    for j in range(J):
        n_new += r_new[j] >= recycle_threshold
    weak_cells = np.empty(J - n_new, np.int64)
    weak_r = np.empty(J - n_new)
    k = 0
    for j in range(J):
        if not r_new[j] >= recycle_threshold:
            weak_cells[k], weak_r[k] = meas_cells[j], 0.0 + r_new[j]  # bincount's sum
            k += 1
    f_cells, f_values = field_apply(f_default, f_cells, f_values, weak_cells, weak_r, True)
    # the new state: the tracks' rows (reduced), then one row per new Bernoulli
    R1, T2 = len(own2), T + n_new
    r2 = np.empty(T2)
    r2[:T] = r_post
    own3 = np.empty(R1 + n_new, np.int64)
    own3[:R1] = own2
    a3 = np.ones(R1 + n_new)
    a3[:R1] = a2
    m3 = np.zeros((R1 + n_new, 4))
    m3[:R1] = m2
    P3 = np.empty((R1 + n_new, 4, 4))
    P3[:R1] = P2
    tid2 = np.empty(T2, np.int64)
    tid2[:T] = tid
    k = 0
    for j in range(J):
        if r_new[j] >= recycle_threshold:
            c = meas_cells[j]
            r2[T + k] = r_new[j]
            own3[R1 + k] = T + k
            m3[R1 + k, 0] = (c % nx + 0.5) * s
            m3[R1 + k, 2] = (c // nx + 0.5) * s
            P3[R1 + k] = P_new
            tid2[T + k] = next_tid + k
            k += 1
    n_strong = 0
    recycle = False
    for t in range(T2):
        recycle |= r2[t] < recycle_threshold
        n_strong += not r2[t] < recycle_threshold
    recycle |= n_strong > max_tracks
    R2, n_f, n_out, E = R1 + n_new, len(f_cells), len(out_own), len(p_edge)
    ints = np.empty(HEADER + R2 + T2 + n_f + 2 * n_out + J + E, np.int64)
    ints[:HEADER] = np.array([T2, R2, n_out, J, E, n_f, iterations, converged, n_pairs,
                              next_tid + n_new, recycle, 0], np.int64)
    o = HEADER
    for part in (own3, tid2, f_cells, out_own, hyp, meas_cells, cluster):
        ints[o:o + len(part)] = part
        o += len(part)
    floats = np.empty(T2 + 21 * R2 + n_f + 2 * T + 21 * n_out + 2 * J + E)
    o = 0
    for part in (r2, a3, m3.ravel(), P3.ravel(), f_values, r_post, alpha_post,
                 means.ravel(), covs.ravel(), r_new, p_missed, p_edge, p_unused):
        floats[o:o + len(part)] = part
        o += len(part)
    return ints, floats


def warm_up() -> None:
    """Compile (or load from the disk cache) every kernel pmb calls, on tiny inputs of
    the argument types it passes (docs/speed.md has the time). Cheap after the first time
    in a process."""
    if getattr(warm_up, "done", False):
        return
    step_kernels.warm_up()  # the GPF's kernels these call first (as the GPF's warm_up does)
    f, i, b = np.ones(1), np.zeros(1, np.int64), np.ones(1, np.bool_)
    m, P = np.zeros((1, 4)) + 0.5, np.eye(4)[None]
    zero22 = np.zeros((1, 2, 2))
    gl = (np.array([np.inf]), np.array([2], np.int64), i, np.zeros(2), np.ones(2))
    step_update(0.5 * f, i, f, m, P, i, 1, zero22, zero22, i, b, 0.5, -0.1, -0.1, 700.0,
                0.01, i, f, 1.0, 1, 1, 6.0, 1e-12, 500, 4, 0.02, 0.01, 200, np.eye(4), *gl)
    estimate_rows(f, i, f, m, P, i, 1)
    warm_up.done = True


# ------------------------------------------------------------------------- estimate
@njit(cache=True, error_model="numpy")
def estimate_rows(r, own, a, m, P, tid, n):
    """:meth:`.tracker.PMBTracker.estimate`'s selection for ``round_sum``: the ``n``
    tracks of largest existence (``np.argsort(-r, kind="stable")``: ties by index; no
    NaN, whose sum the caller cannot round), ascending, each by its heaviest row
    (``np.lexsort((-a, own))``'s first of the track). Returns the rows' means ``(n, 4)``
    then covariances ``(n, 4, 4)``, flattened in one array, and the tracks' labels."""
    sel = np.argsort(-r, kind="mergesort")[:n]
    sel.sort()
    rows = _by_track_heaviest_first(own, a)
    out = np.empty(20 * n)
    labels = np.empty(n, np.int64)
    for k in range(n):
        t = sel[k]
        lo, hi = 0, len(rows)  # np.searchsorted(own[rows], t)
        while lo < hi:
            mid = (lo + hi) // 2
            if own[rows[mid]] < t:
                lo = mid + 1
            else:
                hi = mid
        if lo == len(rows):
            raise IndexError("a track without a Gaussian row")
        q = rows[lo]
        out[4 * k:4 * k + 4] = m[q]
        out[4 * n + 16 * k:4 * n + 16 * k + 16] = P[q].ravel()
        labels[k] = tid[t]
    return out, labels
