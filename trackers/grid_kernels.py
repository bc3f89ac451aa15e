"""Compiled (numba) kernels of the grid arithmetic (GPF, pmb, the cell-evidence trackers),
each equal bit for bit to the numpy form it replaces (:mod:`.gpf.grid`, :mod:`.cells`,
:mod:`.cell_evidence`).

Why: a GPF step on a small grid is a few hundred numpy calls on arrays of a few dozen
pairs, so its time is the interpreter's, not the arithmetic's (docs/speed.md has the
profiles). Each kernel here is one loop over the pairs.

Exactness: every kernel performs the numpy form's IEEE operations in the same order.
numpy's ``sum`` over a last axis is its pairwise summation from 0 (:func:`.numba_exact.np_sum`);
``einsum("nq,nq->n")`` is numpy's baseline (SSE2) sum of products, two lanes, blocks of
four vectors added from the last (:func:`_einsum_row`); the normal CDF is scipy's own C
function (``cython_special``), ``exp`` the C library's, as numpy's is for doubles
without AVX-512. ``tests/test_gpf_kernels.py`` compares both forms on random inputs and
whole runs.

Importing this module imports numba; :func:`.grid_backend.compiled_grid_kernels` imports
it on first use only, and not at all when the numpy forms are chosen
(``MTTBENCH_NO_NUMBA``, or :func:`.jmpd.backend.use_backend`). Kernels are cached on disk
(``cache=True``).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .compiled import drop_stale_caches
from .numba_exact import nan_max as _nan_max
from .numba_exact import nan_min as _nan_min
from .numba_exact import ndtr as _ndtr
from .numba_exact import np_sum
from .numba_exact import search_left as _search
from .numba_exact import unique_inverse as _unique_inverse

drop_stale_caches()  # before any kernel loads: a caller's cache may hold an old callee

_INV_SQRT_2PI = 1.0 / np.sqrt(2.0 * np.pi)


@njit(cache=True)
def _einsum_row(a: np.ndarray, b: np.ndarray, n: int) -> float:
    """``np.einsum("q,q->", a[:n], b[:n])`` as numpy's baseline build computes it: two
    lanes; blocks of 8 as four 2-vectors multiplied and added from the last; then the
    rest 2 at a time (the missing lane adds ``0 * 0``); the lanes' sum added to 0."""
    acc0 = 0.0
    acc1 = 0.0
    j = 0
    while n - j >= 8:
        for v in (6, 4, 2, 0):
            acc0 = a[j + v] * b[j + v] + acc0
            acc1 = a[j + v + 1] * b[j + v + 1] + acc1
        j += 8
    while j < n:
        acc0 = a[j] * b[j] + acc0
        acc1 = (a[j + 1] * b[j + 1] if j + 1 < n else 0.0 * 0.0) + acc1
        j += 2
    return 0.0 + (acc0 + acc1)


@njit(cache=True)
def _columns(mean_xy: np.ndarray, cov_xy: np.ndarray, x0: np.ndarray, x1: np.ndarray
             ) -> tuple[np.ndarray, np.ndarray, int]:
    """Per pair: its run (consecutive pairs of one Gaussian: the same mean and position
    covariance) and its column in the run (the run's pairs with the same ``x0, x1``,
    numbered in order of appearance); and the most columns of a run."""
    n = mean_xy.shape[0]
    run = np.empty(n, np.int64)
    col = np.empty(n, np.int64)
    cx0 = np.empty(n)
    cx1 = np.empty(n)
    n_col = 0
    most = 0
    last = -1
    r = -1
    for p in range(n):
        if not (p > 0 and mean_xy[p, 0] == mean_xy[p - 1, 0]
                and mean_xy[p, 1] == mean_xy[p - 1, 1]
                and cov_xy[p, 0, 0] == cov_xy[p - 1, 0, 0]
                and cov_xy[p, 0, 1] == cov_xy[p - 1, 0, 1]
                and cov_xy[p, 1, 1] == cov_xy[p - 1, 1, 1]):
            r += 1
            n_col = 0
            last = -1
        j = -1
        # pairs come row by row: the next column is the likeliest
        if last + 1 < n_col and cx0[last + 1] == x0[p] and cx1[last + 1] == x1[p]:
            j = last + 1
        else:
            for c in range(n_col):
                if cx0[c] == x0[p] and cx1[c] == x1[p]:
                    j = c
                    break
        if j < 0:
            j = n_col
            cx0[j], cx1[j] = x0[p], x1[p]
            n_col += 1
            most = max(most, n_col)
        run[p], col[p], last = r, j, j
    return run, col, most


@njit(cache=True)
def rect_position_moments(mean_xy: np.ndarray, cov_xy: np.ndarray, x0: np.ndarray,
                          x1: np.ndarray, y0: np.ndarray, y1: np.ndarray,
                          bounds: np.ndarray, n_nodes: np.ndarray, first: np.ndarray,
                          nodes: np.ndarray, weights: np.ndarray
                          ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`.gpf.grid.rect_position_moments` (and its ``_gl_moments``), one pass per
    pair. The Gauss-Legendre rules: ``bounds (G,)`` difficulty bounds, rule ``g`` with
    ``n_nodes[g]`` nodes at ``nodes[first[g]:]``, ``weights`` alike.

    A wide Gaussian meets many looked cells, row after row: the pairs of one Gaussian in
    one column (:func:`_columns`) share its nodes and node weights, and a pair whose
    lower edge ``y0`` is the upper edge ``y1`` of the column's pair before it shares that
    edge's normal CDF and density. Shared values are the values the pair would compute
    (the same operations on the same operands; equal edges of opposite signed zeros give
    at most a zero of the other sign), so the numbers do not change. NaN is never equal,
    so a pair with a NaN edge or moment computes everything afresh."""
    n = mean_xy.shape[0]
    mass = np.empty(n)
    m1 = np.empty((n, 2))
    m2 = np.empty((n, 2, 2))
    q_max = n_nodes.max()
    wq = np.empty(q_max)
    i0 = np.empty(q_max)
    ey = np.empty(q_max)
    eyy = np.empty(q_max)
    wi = np.empty(q_max)
    wu = np.empty(q_max)
    wuu = np.empty(q_max)
    run, col, most = _columns(mean_xy, cov_xy, x0, x1)
    # per column of the current run: its rule, nodes, node weights, and the last pair's
    # upper edge (y1, then per node be, ndtr(be), phi(be))
    c_run = np.full(most, -1, np.int64)
    c_q = np.empty(most, np.int64)
    c_y1 = np.empty(most)
    c_u = np.empty((most, q_max))
    c_w = np.empty((most, q_max))
    c_be = np.empty((most, q_max))
    c_nb = np.empty((most, q_max))
    c_pb = np.empty((most, q_max))
    G = len(bounds)
    for p in range(n):
        mx, my = mean_xy[p, 0], mean_xy[p, 1]
        a = _nan_max(cov_xy[p, 0, 0], 1e-300)
        c = cov_xy[p, 0, 1]
        sx = np.sqrt(a)
        k = c / a
        s = np.sqrt(_nan_max(cov_xy[p, 1, 1] - c * k, 1e-24))
        j = col[p]
        if c_run[j] != run[p]:  # the column's first pair in this run: its nodes
            lo = _nan_max(x0[p] - mx, -7.0 * sx)
            hi = _nan_min(x1[p] - mx, 7.0 * sx)
            half = 0.5 * _nan_max(hi - lo, 0.0)
            difficulty = 2.0 * half * _nan_max(1.0 / sx, np.abs(k) / s)
            g = 0  # np.searchsorted(bounds, difficulty, side="right")
            while g < G and bounds[g] <= difficulty:
                g += 1
            if g == G:
                g = G - 1
            Q, f = n_nodes[g], first[g]
            mid = lo + half
            hs = half / sx
            for q in range(Q):
                uq = mid + half * nodes[f + q]
                t = uq / sx
                c_u[j, q] = uq
                c_w[j, q] = weights[f + q] * hs * (_INV_SQRT_2PI * np.exp(-0.5 * t * t))
            c_run[j], c_q[j] = run[p], Q
            c_y1[j] = np.nan  # no edge yet
        Q = c_q[j]
        shared = y0[p] == c_y1[j]
        dy0 = y0[p] - my
        dy1 = y1[p] - my
        for q in range(Q):
            uq, wqq = c_u[j, q], c_w[j, q]
            ku = k * uq
            if shared:
                al, nal, pa = c_be[j, q], c_nb[j, q], c_pb[j, q]
            else:
                al = (dy0 - ku) / s
                nal = _ndtr(al, 0)
                pa = _INV_SQRT_2PI * np.exp(-0.5 * al * al)
            be = (dy1 - ku) / s
            nbe = _ndtr(be, 0)
            pb = _INV_SQRT_2PI * np.exp(-0.5 * be * be)
            c_be[j, q], c_nb[j, q], c_pb[j, q] = be, nbe, pb
            i0q = nbe - nal
            j1 = pa - pb
            j2 = i0q + al * pa - be * pb
            eyq = ku * i0q + s * j1
            wq[q], i0[q], ey[q] = wqq, i0q, eyq
            eyy[q] = ku * eyq + s * (ku * j1 + s * j2)
            wi[q] = wqq * i0q
            wu[q] = wqq * uq
            wuu[q] = wu[q] * uq
        c_y1[j] = y1[p]
        m2[p, 0, 0] = _einsum_row(wuu, i0, Q)
        m2[p, 0, 1] = m2[p, 1, 0] = _einsum_row(wu, ey, Q)
        m2[p, 1, 1] = _einsum_row(wq, eyy, Q)
        m1[p, 0] = _einsum_row(wu, i0, Q)
        m1[p, 1] = _einsum_row(wq, ey, Q)
        mass[p] = np_sum(wi, Q)
    return mass, m1, m2


@njit(cache=True)
def looked_in_boxes(ix_lo: np.ndarray, ix_hi: np.ndarray, iy_lo: np.ndarray,
                    iy_hi: np.ndarray, looked: np.ndarray, nx: int, ny: int
                    ) -> tuple[np.ndarray, np.ndarray]:
    """:func:`.cells.looked_in_boxes`: per box in order, the looked cells inside it in
    ascending order (a box of at most ``len(looked)`` cells enumerates its cells by rows
    and finds each by binary search; a larger one tests every look)."""
    n_u, K = len(looked), len(ix_lo)
    # the clipped box of each box that meets the grid (x0 = -1: none)
    edges = np.full((K, 4), -1, np.int64)
    bound = 0  # at most min(box cells, looks) pairs per box
    for b in range(K):
        lo_x, hi_x, lo_y, hi_y = ix_lo[b], ix_hi[b], iy_lo[b], iy_hi[b]
        if not (hi_x >= 0 and lo_x <= nx - 1 and hi_y >= 0 and lo_y <= ny - 1
                and hi_x >= lo_x and hi_y >= lo_y):
            continue
        edges[b, 0] = int(min(max(lo_x, 0.0), nx - 1))
        edges[b, 1] = int(min(max(hi_x, 0.0), nx - 1))
        edges[b, 2] = int(min(max(lo_y, 0.0), ny - 1))
        edges[b, 3] = int(min(max(hi_y, 0.0), ny - 1))
        bound += min((edges[b, 1] - edges[b, 0] + 1) * (edges[b, 3] - edges[b, 2] + 1), n_u)
    box = np.empty(bound, np.int64)
    idx = np.empty(bound, np.int64)
    n = 0
    for b in range(K):
        x0, x1, y0, y1 = edges[b, 0], edges[b, 1], edges[b, 2], edges[b, 3]
        if x0 < 0 or n_u == 0:
            continue
        if (x1 - x0 + 1) * (y1 - y0 + 1) <= n_u:
            for y in range(y0, y1 + 1):
                for x in range(x0, x1 + 1):
                    c = y * nx + x
                    pos = _search(looked, c)
                    if pos < n_u and looked[pos] == c:
                        box[n] = b
                        idx[n] = pos
                        n += 1
        else:
            for i in range(n_u):
                ux, uy = looked[i] % nx, looked[i] // nx
                if x0 <= ux <= x1 and y0 <= uy <= y1:
                    box[n] = b
                    idx[n] = i
                    n += 1
    return box[:n], idx[:n]


@njit(cache=True)
def cell_evidence(s: float, nx: int, ny: int, mean_xy: np.ndarray, cov_xy: np.ndarray,
                  box_sd: float, looked: np.ndarray, log_r: np.ndarray,
                  det_cells: np.ndarray, rows: np.ndarray,
                  hit_cells: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:func:`.cell_evidence.cell_evidence`: its standard deviations (floored at ``1e-12
    s``) and negative cells (``looked`` not in the sorted ``det_cells``), then per track
    ``log1p(sum_c m_kc expm1(log r_c))`` and ``min(1, sum_c m_kc)`` over the negative
    looked cells in its box, then its associated detection's cell, each sum sequential
    in that order (``bincount``'s)."""
    K = len(mean_xy)
    mx, my = mean_xy[:, 0].copy(), mean_xy[:, 1].copy()
    sx, sy = np.empty(K), np.empty(K)
    for k in range(K):
        sx[k] = _nan_max(np.sqrt(_nan_max(cov_xy[k, 0, 0], 0.0)), 1e-12 * s)
        sy[k] = _nan_max(np.sqrt(_nan_max(cov_xy[k, 1, 1], 0.0)), 1e-12 * s)
    n_neg = 0
    negative = np.empty(len(looked), np.int64)
    for j in range(len(looked)):  # a binary search of the sorted det_cells per looked cell
        d = _search(det_cells, looked[j])
        if d == len(det_cells) or det_cells[d] != looked[j]:
            negative[n_neg] = looked[j]
            n_neg += 1
    negative = negative[:n_neg]
    lo_x = np.floor((mx - box_sd * sx) / s)
    hi_x = np.floor((mx + box_sd * sx) / s)
    lo_y = np.floor((my - box_sd * sy) / s)
    hi_y = np.floor((my + box_sd * sy) / s)
    box, i = looked_in_boxes(lo_x, hi_x, lo_y, hi_y, negative, nx, ny)
    total = np.zeros(K)
    tested = np.zeros(K)
    n_pairs = len(box) + len(rows)
    if n_pairs == 0:
        return total, tested
    # each box's normal CDF at its cell edges, once: a looked cell's mass is a difference
    # of two neighbours (the same arguments, so the same numbers, as per cell)
    x0 = np.zeros(K, np.int64)
    y0 = np.zeros(K, np.int64)
    at_x = np.zeros(K + 1, np.int64)
    at_y = np.zeros(K + 1, np.int64)
    for k in range(K):  # the box's cells on each axis (as looked_in_boxes clips them)
        x0[k], wx = _axis_box(mx[k], sx[k], nx, s, box_sd)
        y0[k], wy = _axis_box(my[k], sy[k], ny, s, box_sd)
        at_x[k + 1] = at_x[k] + (wx + 1 if wx else 0)  # w cells, w + 1 edges
        at_y[k + 1] = at_y[k] + (wy + 1 if wy else 0)
    cdf_x = np.empty(at_x[K])
    cdf_y = np.empty(at_y[K])
    for k in range(K):
        for j in range(at_x[k + 1] - at_x[k]):
            cdf_x[at_x[k] + j] = _ndtr(((x0[k] + j) * s - mx[k]) / sx[k], 0)
        for j in range(at_y[k + 1] - at_y[k]):
            cdf_y[at_y[k] + j] = _ndtr(((y0[k] + j) * s - my[k]) / sy[k], 0)
    for p in range(n_pairs):
        if p < len(box):
            k, c = box[p], negative[i[p]]
            ix, iy = c % nx - x0[k] + at_x[k], c // nx - y0[k] + at_y[k]
            mass = (cdf_x[ix + 1] - cdf_x[ix]) * (cdf_y[iy + 1] - cdf_y[iy])
        else:  # the detection's cell: maybe outside the box
            k, c = rows[p - len(box)], hit_cells[p - len(box)]
            ix, iy = c % nx, c // nx
            mass = ((_ndtr(((ix + 1) * s - mx[k]) / sx[k], 0)
                     - _ndtr((ix * s - mx[k]) / sx[k], 0))
                    * (_ndtr(((iy + 1) * s - my[k]) / sy[k], 0)
                       - _ndtr((iy * s - my[k]) / sy[k], 0)))
        total[k] += mass * np.expm1(log_r[_search(looked, c)])
        tested[k] += mass
    for k in range(K):
        total[k] = np.log1p(_nan_max(total[k], -1.0 + 1e-300))
        tested[k] = _nan_min(tested[k], 1.0)
    return total, tested


@njit(cache=True)
def _axis_box(mean: float, sd: float, n: int, s: float, n_sd: float) -> tuple[int, int]:
    """One Gaussian's box on one axis as :func:`.cells._axis_boxes` computes it: its
    first cell and its width (0 when it misses the grid)."""
    lo = np.floor((mean - n_sd * sd) / s)
    hi = np.floor((mean + n_sd * sd) / s)
    if not (hi >= 0 and lo <= n - 1):
        return 0, 0
    i0 = int(min(max(lo, 0.0), n - 1))
    return i0, int(min(max(hi, 0.0), n - 1)) - i0 + 1


@njit(cache=True)
def recycled_intensity(s: float, nx: int, ny: int, mean_xy: np.ndarray, cov_xy: np.ndarray,
                       sd_floor: float, n_sd: float, r: np.ndarray
                       ) -> tuple[np.ndarray, np.ndarray]:
    """``r_k m_kc`` over the Gaussians' boxes as :func:`.pmb.ppp.recycle` computes them
    from :func:`.cells.gaussian_cell_mass_sparse` (each cell's mass the product of its
    axes' normal CDF differences): the cells and amounts, Gaussian by Gaussian, each box
    by rows."""
    K = mean_xy.shape[0]
    boxes = np.zeros((K, 4), np.int64)  # ix0, wx, iy0, wy
    sds = np.empty((K, 2))
    total = 0
    for k in range(K):
        for a in range(2):
            sds[k, a] = _nan_max(np.sqrt(_nan_max(cov_xy[k, a, a], 0.0)), sd_floor)
        boxes[k, 0], boxes[k, 1] = _axis_box(mean_xy[k, 0], sds[k, 0], nx, s, n_sd)
        boxes[k, 2], boxes[k, 3] = _axis_box(mean_xy[k, 1], sds[k, 1], ny, s, n_sd)
        total += boxes[k, 1] * boxes[k, 3]
    cells = np.empty(total, np.int64)
    amounts = np.empty(total)
    mass_x = np.empty(nx)
    mass_y = np.empty(ny)
    e = 0
    for k in range(K):
        for a in range(2):  # the box's cell masses on each axis: differences of the CDF
            i0, w = boxes[k, 2 * a], boxes[k, 2 * a + 1]
            out = mass_x if a == 0 else mass_y
            m, sd = mean_xy[k, a], sds[k, a]
            prev = _ndtr((i0 * s - m) / sd, 0)
            for j in range(w):
                cdf = _ndtr(((i0 + j + 1) * s - m) / sd, 0)
                out[j] = cdf - prev
                prev = cdf
        for ly in range(boxes[k, 3]):
            for lx in range(boxes[k, 1]):
                cells[e] = (boxes[k, 2] + ly) * nx + boxes[k, 0] + lx
                amounts[e] = r[k] * (mass_y[ly] * mass_x[lx])
                e += 1
    return cells, amounts


@njit(cache=True)
def recycle_into_field(f_default: float, f_cells: np.ndarray, f_values: np.ndarray, s: float,
                       nx: int, ny: int, m: np.ndarray, P: np.ndarray, sd_floor: float,
                       n_sd: float, r: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:func:`.pmb.ppp.recycle` in one call: the states' position marginals (``m (K,
    4)``, ``P (K, 4, 4)``), :func:`recycled_intensity`, :func:`cell_sums` and
    :func:`field_apply`'s sum; the field's new ``cells`` and ``values``."""
    K = m.shape[0]
    mean_xy = np.empty((K, 2))
    cov_xy = np.empty((K, 2, 2))
    for k in range(K):
        for a in range(2):
            mean_xy[k, a] = m[k, 2 * a]
            for b in range(2):
                cov_xy[k, a, b] = P[k, 2 * a, 2 * b]
    cells, amounts = recycled_intensity(s, nx, ny, mean_xy, cov_xy, sd_floor, n_sd, r)
    uniq, sums = cell_sums(cells, amounts)
    return field_apply(f_default, f_cells, f_values, uniq, sums, True)


@njit(cache=True)
def cell_sums(cells: np.ndarray, amounts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The sorted unique ``cells`` and each one's sum of ``amounts``, as
    :func:`.pmb.ppp.add_intensity` computes them (``np.unique``, then ``np.bincount``'s
    weighted sums: from 0, in the order given). Cells already strictly increasing (one
    Gaussian's box, by rows) need no sort."""
    n = len(cells)
    increasing = True
    for j in range(1, n):
        if cells[j] <= cells[j - 1]:
            increasing = False
            break
    if increasing:
        sums = np.empty(n)
        for j in range(n):
            sums[j] = 0.0 + amounts[j]
        return cells.copy(), sums
    uniq, inv = _unique_inverse(cells)
    sums = np.zeros(len(uniq))
    for j in range(n):
        sums[inv[j]] += amounts[j]
    return uniq, sums


@njit(cache=True)
def looked_log_ratios(cells: np.ndarray, returns: np.ndarray, log_pos: float,
                      log_neg: float, max_log: float
                      ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """:func:`.cell_evidence.looked_log_ratios`: the looked cells (sorted), the looks at
    each, the positive cells and ``min(k_c log_pos + (n_c - k_c) log_neg, max_log)``."""
    uniq, inv = _unique_inverse(cells)
    n_looks = np.zeros(len(uniq), np.int64)
    positive = np.zeros(len(uniq), np.int64)
    for j in range(len(cells)):
        n_looks[inv[j]] += 1
        if returns[j]:
            positive[inv[j]] += 1
    n_det = 0
    for c in range(len(uniq)):
        if positive[c] > 0:
            n_det += 1
    det_cells = np.empty(n_det, np.int64)
    log_r = np.empty(len(uniq))
    d = 0
    for c in range(len(uniq)):
        if positive[c] > 0:
            det_cells[d] = uniq[c]
            d += 1
        log_r[c] = _nan_min(positive[c] * log_pos + (n_looks[c] - positive[c]) * log_neg,
                            max_log)
    return uniq, n_looks, det_cells, log_r


@njit(cache=True)
def look_log_ratios(cells: np.ndarray, returns: np.ndarray, hit: np.ndarray,
                    miss: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:func:`.cells.look_log_ratios` given its two rows ``hit``, ``miss`` (``log l(T)`` of
    a look with a return and without): the sorted looked cells and each one's looks' rows
    summed from 0 in look order, as ``np.add.at`` adds."""
    uniq, inv = _unique_inverse(cells)
    n_t = len(hit)
    LL = np.zeros((len(uniq), n_t))
    for j in range(len(cells)):
        row = hit if returns[j] else miss
        for t in range(n_t):
            LL[inv[j], t] += row[t]
    return uniq, LL


@njit(cache=True, error_model="numpy")
def field_apply(f_default, f_cells, f_values, cells, operands, add):
    """:meth:`.cells.CellField.multiply` (``add`` False) or ``add`` at the sorted unique
    ``cells``: the new ``cells`` and ``values`` (a cell whose value becomes the default
    rejoins it; nothing changes when ``cells`` is empty)."""
    if len(cells) == 0:
        return f_cells, f_values
    n_f, n_c = len(f_cells), len(cells)
    out_c = np.empty(n_f + n_c, np.int64)
    out_v = np.empty(n_f + n_c)
    i = k = n = 0
    while i < n_f or k < n_c:
        if k == n_c or (i < n_f and f_cells[i] < cells[k]):
            c, v = f_cells[i], f_values[i]
            i += 1
        else:
            c = cells[k]
            v = f_default
            if i < n_f and f_cells[i] == c:
                v = f_values[i]
                i += 1
            v = v + operands[k] if add else v * operands[k]
            k += 1
        if not v == f_default:
            out_c[n], out_v[n] = c, v
            n += 1
    return out_c[:n], out_v[:n]


@njit(cache=True, error_model="numpy")
def field_affine(f_default, f_cells, f_values, a, b):
    """:meth:`.cells.CellField.affine`: ``x <- a x + b`` in every cell (two roundings, as
    numpy's ``a * values + b``), a cell whose value becomes the default rejoining it.
    Returns the new default, cells and values (new arrays)."""
    d = a * f_default + b
    n = len(f_cells)
    out_c = np.empty(n, np.int64)
    out_v = np.empty(n)
    k = 0
    for j in range(n):
        v = a * f_values[j] + b
        if not v == d:
            out_c[k], out_v[k] = f_cells[j], v
            k += 1
    return d, out_c[:k], out_v[:k]


def warm_up() -> None:
    """Compile (or load from the disk cache) every kernel on tiny inputs, for the argument
    types the callers pass, so that a tracker's ``reset`` pays for it and no timed step
    does. Cheap after the first time in a process."""
    if getattr(warm_up, "done", False):
        return
    f, i = np.zeros(1), np.zeros(1, np.int64)
    cov = np.ones((1, 2, 2))
    rect_position_moments(np.zeros((1, 2)), cov, f, f + 1.0, f, f + 1.0, np.array([np.inf]),
                          np.array([2], np.int64), i, np.zeros(2), np.ones(2))
    looked_in_boxes(f, f, f, f, i, 1, 1)
    cell_evidence(1.0, 1, 1, np.zeros((1, 2)), np.ones((1, 2, 2)), 6.0, i, f, i, i, i)
    cell_sums(i, f)
    recycle_into_field(0.0, i, f, 1.0, 1, 1, np.zeros((1, 4)), np.ones((1, 4, 4)), 1e-12, 6.0, f)
    field_apply(0.0, i, f, i, f, True)
    field_affine(0.0, i, f, 1.0, 0.0)
    looked_log_ratios(i, np.zeros(1, np.bool_), 1.0, -1.0, 700.0)
    ro = np.zeros(1)
    ro.flags.writeable = False  # cells' rows are read-only
    look_log_ratios(i, np.zeros(1, np.bool_), ro, ro)
    warm_up.done = True
