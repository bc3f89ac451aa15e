"""Compiled (numba) kernels of ``jmpd-ap``'s per-particle work, each equal bit for bit
to the numpy form it replaces (:mod:`.ap`, :mod:`.cell_proposal`, :mod:`.partitions`).

Why: a ``jmpd-ap`` step is a few dozen small operations per particle and slot (the
predictive, a window of cell masses, a sequential draw per cluster member, the
recombined positions and velocity updates, the sorting's permutation costs, the slots'
means and extents). In numpy each is a pass over ``(N, t_max, ...)`` temporaries;
here each group is one loop over the particles (docs/speed.md has the profiles).

Exactness: every kernel performs the same IEEE operations, in the same order, as its
numpy form: numpy's ``sum`` over a last axis is its pairwise summation
(:func:`..numba_exact.np_sum`, starting from 0), a sum over the particles is sequential, the
normal CDF and its inverse are scipy's own functions (``cython_special``), ``exp`` and
``log`` the C library's, as numpy's are without AVX-512 (the tests compare both forms
on whole runs and on random inputs). All random draws stay in numpy, in the same
calls and order; the kernels take them as arrays.

Importing this module imports numba; :func:`.backend.compiled_ap_kernels` imports it on
first use only. Kernels compile on first call and are cached on disk (``cache=True``);
:func:`warm_up` does that on tiny inputs so that no timed step pays for it.
"""

from __future__ import annotations

import numpy as np
from llvmlite import ir as llir
from numba import njit, types
from numba.core import cgutils
from numba.extending import intrinsic

from ..compiled import drop_stale_caches
from ..numba_exact import ndtr as _ndtr
from ..numba_exact import ndtri as _ndtri
from ..numba_exact import np_sum
from .kernels import _outside

drop_stale_caches()  # before any kernel loads: a caller's cache may hold an old callee


@intrinsic
def _prefetch(typingctx, arr, i, j):
    """A hint to the processor: fetch the cache line of ``arr[i, j, 0, ...]`` (LLVM's
    ``prefetch``, read, high locality). Changes no value; :func:`place` issues it a few
    receivers ahead, as its reads of the ancestors' rows are in random order."""
    sig = types.void(arr, i, j)

    def codegen(context, builder, signature, args):
        aryty = signature.args[0]
        ary = context.make_array(aryty)(context, builder, args[0])
        zero = context.get_constant(types.intp, 0)
        ptr = cgutils.get_item_pointer2(
            context, builder, data=ary.data, shape=cgutils.unpack_tuple(builder, ary.shape),
            strides=cgutils.unpack_tuple(builder, ary.strides), layout=aryty.layout,
            inds=[args[1], args[2]] + [zero] * (aryty.ndim - 2))
        i8p = llir.IntType(8).as_pointer()
        i32 = llir.IntType(32)
        # declare_intrinsic mangles the name for the pointer type (LLVM upgrades the
        # typed-pointer name where pointers are opaque)
        fn = builder.module.declare_intrinsic(
            "llvm.prefetch", [i8p], llir.FunctionType(llir.VoidType(), [i8p, i32, i32, i32]))
        builder.call(fn, [builder.bitcast(ptr, i8p), i32(0), i32(3), i32(1)])
        return context.get_dummy_value()
    return sig, codegen


# ------------------------------------------------------------------ predict
@njit(cache=True)
def predict(pos: np.ndarray, vel: np.ndarray, vvar: np.ndarray, tau: float, tau2: float,
            q11: np.ndarray, extent: np.ndarray, reflect: bool, rhohat: np.ndarray,
            psi: np.ndarray, sd: np.ndarray) -> None:
    """``rhohat = pos + tau vel``, ``psi = tau^2 vvar + q11``, ``sd = sqrt(psi)`` (all
    ``(N, T, 2)``; ``q11`` and ``extent`` per axis, ``tau2 = tau ** 2`` as Python
    computes it); under ``reflect`` a mean outside ``[0, L)`` is folded back
    (:func:`.state.fold`) and its velocity mean mirrored, in place in ``vel`` (numpy
    form: :meth:`.ap.JMPDAPTracker.predict` and the ``sqrt`` of its update)."""
    N, T = pos.shape[0], pos.shape[1]
    for p in range(N):
        for t in range(T):
            for a in range(2):
                r = pos[p, t, a] + tau * vel[p, t, a]
                v = tau2 * vvar[p, t, a] + q11[a]
                psi[p, t, a] = v
                sd[p, t, a] = np.sqrt(v)
                length = extent[a]
                if reflect and (r < 0.0 or r >= length):
                    r, vel[p, t, a], _ = _outside(r, vel[p, t, a], length,
                                                  np.nextafter(length, 0.0), True)
                rhohat[p, t, a] = r


@njit(cache=True)
def gather_slots(pos: np.ndarray, vel: np.ndarray, vvar: np.ndarray, valid: np.ndarray,
                 idx: np.ndarray, pos_out: np.ndarray, vel_out: np.ndarray,
                 vvar_out: np.ndarray, valid_out: np.ndarray) -> None:
    """The resampled slot arrays: ``x_out[k] = x[idx[k]]`` along the first axis for
    ``pos``, ``vel``, ``vvar`` ``(N, T, 2)`` and ``valid (N, T)`` (numpy's ``x[idx]``),
    element by element in one pass (a row assignment per array costs a view each)."""
    T = valid.shape[1]
    for k in range(idx.shape[0]):
        i = idx[k]
        for t in range(T):
            valid_out[k, t] = valid[i, t]
            for a in range(2):
                pos_out[k, t, a] = pos[i, t, a]
                vel_out[k, t, a] = vel[i, t, a]
                vvar_out[k, t, a] = vvar[i, t, a]


@njit(cache=True)
def held_per_particle(valid: np.ndarray) -> np.ndarray:
    """``valid.sum(axis=1)`` of ``valid (N, T)`` bool: the slots each particle holds
    (int64; numpy's reduction along a short last axis costs 15 ns an element)."""
    N, T = valid.shape
    out = np.zeros(N, np.int64)
    for p in range(N):
        n = 0
        for t in range(T):
            n += valid[p, t]
        out[p] = n
    return out


@njit(cache=True)
def _cell_of(x: float, y: float, nx: int, ny: int, cell_size: float) -> int:
    """``Grid.cell_of`` of one position: the flat cell, -1 outside the grid."""
    ix = np.floor(x / cell_size)
    iy = np.floor(y / cell_size)
    if ix >= 0 and ix < nx and iy >= 0 and iy < ny:
        return np.int64(iy * nx + ix)
    return -1


@njit(cache=True)
def slot_log_likelihood(pos: np.ndarray, valid: np.ndarray, nx: int, ny: int,
                        cell_size: float, n_cells: int, direct: bool, row_table: np.ndarray,
                        keys: np.ndarray, table: np.ndarray, out: np.ndarray) -> None:
    """``out[p] += log p(z | X_p)`` (:func:`.likelihood.grid_log_likelihood` of the
    slots' cells, an empty slot or one outside the grid at ``n_cells``): slot ``t`` adds
    ``table[r, k] - table[r, k - 1]``, ``r`` its cell's row and ``k - 1`` the earlier
    slots in that row, the terms summed in slot order (as the dense path's kernel)
    before they are added to ``out``.

    A slot in the zero row (empty, outside the grid or in a cell not looked at: the
    table's last row) adds ``0.0 - 0.0 = +0.0`` and shares its row with no looked slot,
    so it is neither looked up nor counted: the sum gains ``+ 0.0`` (which only turns a
    ``-0.0`` into ``+0.0``, as the term did)."""
    N, T = valid.shape
    n_counts = table.shape[1]
    zero_row = table.shape[0] - 1
    rows = np.empty(T, np.int64)
    for p in range(N):
        total = 0.0
        n_rows = 0  # the looked slots so far, by row
        for t in range(T):
            r = zero_row
            if valid[p, t]:
                c = _cell_of(pos[p, t, 0], pos[p, t, 1], nx, ny, cell_size)
                if c >= 0:
                    r = _row(c, direct, row_table, keys)
            if r == zero_row:
                total = total + 0.0  # at t = 0: 0.0, the term itself
                continue
            k = 1
            for q in range(n_rows):
                k += rows[q] == r
            rows[n_rows] = r
            n_rows += 1
            k = min(k, n_counts - 1)
            inc = table[r, k] - table[r, k - 1]
            total = inc if t == 0 else total + inc
        out[p] += total


@njit(cache=True)
def occupied(pos: np.ndarray, valid: np.ndarray, det: np.ndarray, nx: int, ny: int,
             cell_size: float, out: np.ndarray) -> None:
    """``out[p, d]``: particle ``p`` holds a target in cell ``det[d]`` (``det`` sorted,
    ``out (N, D)`` bool)."""
    N, T = valid.shape
    D = det.shape[0]
    for p in range(N):
        for d in range(D):
            out[p, d] = False
        for t in range(T):
            if valid[p, t]:
                c = _cell_of(pos[p, t, 0], pos[p, t, 1], nx, ny, cell_size)
                d = np.searchsorted(det, c)
                if d < D and det[d] == c:
                    out[p, d] = True


@njit(cache=True)
def birth_decisions(remaining: np.ndarray, log_keep: np.ndarray, pi_arrival: np.ndarray,
                    lam: np.ndarray, log_lam: np.ndarray, has_slot: np.ndarray,
                    occupied: np.ndarray, uniforms: np.ndarray, born: np.ndarray,
                    log_ratio: np.ndarray) -> None:
    """The birth decisions at the ``D`` detected cells, cell after cell per particle
    (the loop of :meth:`.ap.JMPDAPTracker._births`, numpy form, with its per-cell values
    given: ``log_keep = log1p(-min(share, 1 - 1e-12))``, ``pi_arrival``, ``lam`` and
    ``log(lam)``, all ``(D,)``). In place: ``remaining (N,)`` the undetected initial
    targets left, ``born (N, D)``, ``log_ratio (N,)`` (from its values). The numpy form
    computes both sides of each ``where``; a particle here computes the side it keeps."""
    N, D = born.shape
    for p in range(N):
        r = remaining[p]
        acc = log_ratio[p]
        for k in range(D):
            pi_init = -np.expm1(r * log_keep[k])
            pi = 1.0 - (1.0 - pi_init) * (1.0 - pi_arrival[k])
            z = 1.0 - pi + pi * lam[k]
            b = pi * lam[k] / z if has_slot[p, k] else 0.0
            new = uniforms[p, k] < b and not occupied[p, k]
            born[p, k] = new
            if occupied[p, k]:
                acc = acc + 0.0
            elif has_slot[p, k]:
                acc = acc + (np.log(z) - (log_lam[k] if new else 0.0))
            else:
                acc = acc + np.log1p(-pi)
            if new:
                x = r - (pi_init / pi if pi > 0.0 else 0.0)
            else:
                x = r - 0.0
            r = x if x >= 0.0 or np.isnan(x) else 0.0  # np.maximum(x, 0.0)
        remaining[p] = r
        log_ratio[p] = acc


# ------------------------------------------------------------ slot summaries
@njit(cache=True)
def slot_sums(pos: np.ndarray, vel: np.ndarray, valid: np.ndarray, with_vel: bool,
              held: np.ndarray, sum_pos: np.ndarray, sum_vel: np.ndarray) -> None:
    """Per slot over the particles: ``held (T,)`` the holders, ``sum_pos``, ``sum_vel``
    ``(T, 2)`` the sums of ``pos * valid`` (``vel``: only when ``with_vel``) in
    particle order (numpy's ``(x * valid[..., None]).sum(axis=0)``)."""
    N, T = valid.shape
    held[:] = 0
    sum_pos[:] = 0.0
    sum_vel[:] = 0.0
    for p in range(N):
        for t in range(T):
            v = valid[p, t]
            f = 1.0 if v else 0.0
            sum_pos[t, 0] += pos[p, t, 0] * f
            sum_pos[t, 1] += pos[p, t, 1] * f
            if with_vel:
                sum_vel[t, 0] += vel[p, t, 0] * f
                sum_vel[t, 1] += vel[p, t, 1] * f
            if v:
                held[t] += 1


@njit(cache=True)
def max_held_sd(sd: np.ndarray, valid: np.ndarray, slots: np.ndarray) -> float:
    """``max(where(valid[:, slots], sd[:, slots], 0))`` over both axes."""
    big = 0.0
    for p in range(sd.shape[0]):
        for t in slots:
            if valid[p, t]:
                for a in range(2):
                    if sd[p, t, a] > big:
                        big = sd[p, t, a]
    return big


# ------------------------------------------------------------ the proposal
#: scipy's ``ndtr(x)`` is exactly 0 for ``x < NDTR_ZERO`` (its ``erfc(-x / sqrt 2)``
#: underflows to 0 once ``x^2 / 2`` exceeds the largest ``log`` of a double, from
#: about -37.677; the tests check it)
NDTR_ZERO = -37.7


@njit(cache=True, inline="always")
def _ndtr_lower(x: float) -> float:
    """``ndtr(x)`` for ``x <= 0``, without the call where it is exactly 0."""
    if x < NDTR_ZERO:
        return 0.0
    return _ndtr(x, 0)


@njit(cache=True, inline="always")
def _ndtr_upper(x: float, lower: float) -> float:
    """``ndtr(x)`` for ``x > 0`` given ``lower = ndtr(-x)``: scipy computes ``ndtr(x)``
    for ``x >= 1`` as ``1 - ndtr(-x)`` (``1 - erfc(x / sqrt 2) / 2``), bit for bit (the
    tests check it); below 1 it takes ``erf`` and is called."""
    if x >= 1.0:
        return 1.0 - lower
    return _ndtr(x, 0)

@njit(cache=True, inline="always")
def _row(cell: int, direct: bool, table: np.ndarray, keys: np.ndarray) -> int:
    """:class:`.sparse.CellIndex`: the row of ``cell`` (in ``[0, n_cells]``)."""
    m = keys.shape[0]
    if direct:
        return table[min(cell, table.shape[0] - 1)]
    i = np.searchsorted(keys, cell)
    if i < m and keys[i] == cell:
        return i
    return m


@njit(cache=True)
def propose(rhohat: np.ndarray, sd: np.ndarray, valid: np.ndarray, slots: np.ndarray,
            members: np.ndarray, sizes: np.ndarray, col: np.ndarray, uniforms: np.ndarray,
            nx: int, ny: int, cell_size: float, n_cells: int, wx: int, wy: int,
            reflect: bool, beta: float, direct: bool, row_table: np.ndarray,
            keys: np.ndarray, table: np.ndarray, log_z: np.ndarray, log_pi: np.ndarray,
            new_cell: np.ndarray, new_valid: np.ndarray, cdf_start: np.ndarray,
            cdf_mass: np.ndarray, cdf_upper: np.ndarray) -> None:
    """Steps 2-3 of :meth:`.ap.JMPDAPTracker._move_persistent` up to the recombination:
    every particle's proposal windows and sequential draws, cluster by cluster.

    ``slots (S,)`` the active slots (``col[t]`` the column of slot ``t``), ``members
    (C, h)`` the clusters' slots (-1 padded), ``sizes (C,)``, ``uniforms (h, N, C)``
    member ``i``'s uniforms of the clusters that have one (numpy's ``rng.random((N,
    k))`` of the live clusters, put in their columns); the look table's rows by
    ``row_table`` (``direct``) or a search of ``keys``. Writes ``log_z``, ``log_pi``
    ``(N, C)``, ``new_cell``, ``new_valid (N, S)`` and, per axis of each drawn cell,
    :func:`_truncated_normal`'s ``pa``, ``pb - pa`` and side (``cdf_start``,
    ``cdf_mass``, ``cdf_upper (N, S, 2)``; side -1: a cell outside the window's grid
    cells, whose draw computes them anew). A slot the particle does not hold is skipped
    (the numpy form computes its window and draw, and keeps neither).
    """
    N = rhohat.shape[0]
    C = members.shape[0]
    h_max = members.shape[1]
    S = slots.shape[0]
    W = wx * wy
    rows, n_counts = table.shape
    one_beta = 1.0 - beta
    # per row and count: log l(n + 1) - log l(n) and its exp (the same operations as
    # numpy's on the gathered entries)
    step_log = np.empty((rows, n_counts - 1))
    step_exp = np.empty((rows, n_counts - 1))
    for r in range(rows):
        for n in range(n_counts - 1):
            step_log[r, n] = table[r, n + 1] - table[r, n]
            step_exp[r, n] = np.exp(step_log[r, n])
    w_max = max(wx, wy)
    wi = np.empty((S, 2, w_max), np.int64)
    wm = np.empty((S, 2, w_max))
    ws = np.empty((S, 2, w_max))
    wside = np.zeros((S, 2, w_max), np.bool_)
    cdf = np.empty(w_max + 1)
    zs = np.empty(w_max + 1)
    gamma = np.empty((S, W))
    wcell = np.empty((S, W), np.int64)
    wrow = np.empty((S, W), np.int64)
    dead = np.empty(S)
    cell_nb = np.empty(W, np.int64)
    weights = np.empty(W)
    cum = np.empty(W + 1)
    placed = np.empty(h_max, np.int64)
    for p in range(N):
        # windows of the active slots the particle holds (as an ancestor), numpy's
        # axis_window per axis; a slot it does not hold draws nothing that is kept
        for j in range(S):
            t = slots[j]
            if not valid[p, t]:
                continue
            mx, my = rhohat[p, t, 0], rhohat[p, t, 1]
            in_x = in_y = 0.0
            for ax in range(2):
                # numpy's axis_window (the width form), written here rather than in a
                # helper: a call taking the scratch arrays costs reference counting
                mean, s_ = rhohat[p, t, ax], sd[p, t, ax]
                n = nx if ax == 0 else ny
                width = wx if ax == 0 else wy
                f = np.floor((mean - 4.0 * s_) / cell_size)
                top = float(max(n - width, 0))
                if f < 0.0:
                    f = 0.0
                if f > top:
                    f = top
                first = np.int64(f)
                for k in range(width + 1):
                    zs[k] = ((first + k) * cell_size - mean) / s_
                for k in range(width):
                    i = first + k
                    wi[j, ax, k] = i if i >= 0 and i < n else -1
                # the lower-tail CDF at each edge: ndtr(z) below the mean, ndtr(-z)
                # above it; a cell's side is its left edge's, so the edge where the side
                # changes needs both (above the mean, every later edge is too)
                for k in range(width + 1):
                    upper = zs[k] > 0.0
                    cdf[k] = _ndtr_lower(-zs[k]) if upper else _ndtr_lower(zs[k])
                    if k == 0:
                        continue
                    if wi[j, ax, k - 1] < 0:
                        wm[j, ax, k - 1] = 0.0
                        ws[j, ax, k - 1] = 0.0
                        continue
                    wside[j, ax, k - 1] = zs[k - 1] > 0.0
                    if zs[k - 1] > 0.0:  # above the mean: ndtr(-z_left) - ndtr(-z_right)
                        right = cdf[k]
                        wm[j, ax, k - 1] = cdf[k - 1] - right
                        ws[j, ax, k - 1] = right
                    else:  # ndtr(z_right) - ndtr(z_left)
                        right = _ndtr_upper(zs[k], cdf[k]) if upper else cdf[k]
                        wm[j, ax, k - 1] = right - cdf[k - 1]
                        ws[j, ax, k - 1] = cdf[k - 1]
                if not reflect:  # interval_mass(mean, sd, 0, n cell_size)
                    za = (0.0 - mean) / s_
                    zb = (n * cell_size - mean) / s_
                    if za > 0.0:
                        inside = _ndtr_lower(-za) - _ndtr_lower(-zb)
                    else:
                        right = _ndtr_upper(zb, _ndtr_lower(-zb)) if zb >= 1.0 \
                            else _ndtr_lower(zb)
                        inside = right - _ndtr_lower(za)
                    if ax == 0:
                        in_x = inside
                    else:
                        in_y = inside
            for a in range(wy):
                for b in range(wx):
                    k = a * wx + b
                    gamma[j, k] = wm[j, 1, a] * wm[j, 0, b]
                    if wi[j, 1, a] < 0 or wi[j, 0, b] < 0:
                        wcell[j, k] = n_cells
                    else:
                        wcell[j, k] = wi[j, 1, a] * nx + wi[j, 0, b]
                    wrow[j, k] = _row(wcell[j, k], direct, row_table, keys)
            if W < 8:  # np_sum's arithmetic, without a call taking a view
                total = -0.0
                for k in range(W):
                    total += gamma[j, k]
                total = 0.0 + total
            else:
                total = np_sum(gamma[j], W)
            if reflect:
                if total <= 0.0:  # far outside the window's reach: the nearest cell
                    near_x = min(max(np.floor(mx / cell_size), 0.0), nx - 1.0) - wi[j, 0, 0]
                    near_y = min(max(np.floor(my / cell_size), 0.0), ny - 1.0) - wi[j, 1, 0]
                    near = np.int64(min(max(near_y, 0.0), wy - 1.0) * wx
                                    + min(max(near_x, 0.0), wx - 1.0))
                    gamma[j, near] = 1.0
                    total = 1.0
                for k in range(W):
                    gamma[j, k] /= total
                m_out = 0.0
            else:
                inside = in_x * in_y
                factor = inside / total if total > 0 else 0.0
                for k in range(W):
                    gamma[j, k] *= factor
                m_out = 1.0 - inside
            dead[j] = beta + one_beta * m_out
        for c in range(C):
            log_z[p, c] = 0.0
            log_pi[p, c] = 0.0
            for i in range(sizes[c]):
                t = members[c, i]
                j = col[t]
                if not valid[p, t]:  # dies: log_z and log_pi gain 0
                    placed[i] = -1
                    new_cell[p, j] = 0
                    new_valid[p, j] = False
                    continue
                for k in range(W):
                    nb = 0
                    for q in range(i):
                        nb += placed[q] == wcell[j, k]
                    nb = min(nb, n_counts - 2)
                    cell_nb[k] = nb
                    weights[k] = one_beta * gamma[j, k] * step_exp[wrow[j, k], nb]
                d = dead[j]
                if W < 8:  # np_sum(weights, W), as above
                    sw = -0.0
                    for k in range(W):
                        sw += weights[k]
                    sw = 0.0 + sw
                else:
                    sw = np_sum(weights, W)
                z = d + sw
                cum[0] = d
                acc = 0.0
                for k in range(W):
                    acc += weights[k]
                    cum[k + 1] = d + acc
                u = uniforms[i, p, c] * z
                choice = 0
                for k in range(W + 1):
                    choice += cum[k] <= u
                choice = min(choice, W)
                alive = choice > 0
                w_idx = max(choice - 1, 0)
                cell = wcell[j, w_idx]
                log_z[p, c] += np.log(z)
                log_pi[p, c] += step_log[wrow[j, w_idx], cell_nb[w_idx]] if alive else 0.0
                placed[i] = cell if alive else -1
                new_cell[p, j] = cell
                new_valid[p, j] = alive
                a, b = w_idx // wx, w_idx % wx
                if wi[j, 0, b] >= 0 and wi[j, 1, a] >= 0:
                    cdf_start[p, j, 0], cdf_start[p, j, 1] = ws[j, 0, b], ws[j, 1, a]
                    cdf_mass[p, j, 0], cdf_mass[p, j, 1] = wm[j, 0, b], wm[j, 1, a]
                    cdf_upper[p, j, 0] = 1 if wside[j, 0, b] else 0
                    cdf_upper[p, j, 1] = 1 if wside[j, 1, a] else 0
                else:
                    cdf_upper[p, j, 0] = cdf_upper[p, j, 1] = -1


@njit(cache=True)
def _truncated_normal(mean: float, sd: float, lo: float, hi: float, u: float) -> float:
    """:func:`.cell_proposal.truncated_normal` for one draw."""
    za = (lo - mean) / sd
    zb = (hi - mean) / sd
    upper = za > 0.0
    a = -zb if upper else za
    b = -za if upper else zb
    pa, pb = _ndtr(a, 0), _ndtr(b, 0)
    # pb - pa > 0 exactly when pb > pa (float subtraction of unequal numbers is not 0)
    return _draw_in_cell(mean, sd, lo, hi, u, pa, pb - pa, upper)


@njit(cache=True)
def _draw_in_cell(mean: float, sd: float, lo: float, hi: float, u: float, pa: float,
                  mass: float, upper: bool) -> float:
    """:func:`_truncated_normal` given its ``pa`` and ``pb - pa`` (from the window)."""
    z = _ndtri(pa + u * mass, 0)
    if upper:
        z = -z
    x = mean + sd * z
    if not (mass > 0.0) or not np.isfinite(x):  # pb > pa
        x = lo + u * (hi - lo)
    top = np.nextafter(hi, lo)
    if x < lo:
        x = lo
    if x > top:
        x = top
    return x


#: how many receivers ahead :func:`place` prefetches the ancestors' rows (3-6 measured
#: alike at 16,000 particles; docs/speed.md)
AHEAD = 4


@njit(cache=True)
def place(anc: np.ndarray, order: np.ndarray, prefetch: bool, cluster_of: np.ndarray,
          slots: np.ndarray, new_cell: np.ndarray, new_valid: np.ndarray,
          cdf_start: np.ndarray, cdf_mass: np.ndarray, cdf_upper: np.ndarray,
          rhohat: np.ndarray, sd: np.ndarray, psi: np.ndarray, uniforms: np.ndarray, nx: int,
          cell_size: float, tau: float, q12: np.ndarray, q22: np.ndarray,
          vel_src: np.ndarray, vvar_src: np.ndarray, others: np.ndarray, pos: np.ndarray,
          vel: np.ndarray, vvar: np.ndarray, valid: np.ndarray) -> None:
    """The end of :meth:`.ap.JMPDAPTracker._move_persistent`: receiver ``p`` takes slot
    ``slots[j]``'s cell from ancestor ``anc[p, cluster_of[j]]``, draws its position in
    the cell from the ancestor's predictive truncated to it (``uniforms (N, S, 2)``;
    the CDF values :func:`propose` kept for the drawn cell) and updates the velocity
    posterior (read from ``vel_src``, ``vvar_src``, the states before the step; written
    to ``vel``, ``vvar``, ``pos``, ``valid``; the slots ``others`` in no cluster keep
    the receiver's own velocity mean and variance, copied). A slot left empty gets a uniform
    position in cell 0 (the numpy form draws the ancestor's predictive truncated to
    cell 0): no computation reads an empty slot's position or velocity mean (every one
    masks them by ``valid``, or multiplies them by 0, which a finite value survives),
    and every slot that becomes valid gets all of its values anew.

    The receivers go in ``order (N,)``: any order gives the same values (a receiver
    reads the ancestors' rows and its own uniforms, and writes its own rows). With one
    cluster the caller orders them by ancestor, so that the ancestors' rows are read in
    memory order; with more it passes the particles' order and ``prefetch``: the
    ancestors' rows of the receiver ``AHEAD`` places on are asked for early (the first
    and last slot of each cluster), as they are read at random (docs/speed.md)."""
    N, S = new_cell.shape
    for q in range(N):
        p = order[q]
        if prefetch and q + AHEAD < N:
            r = order[q + AHEAD]
            for j in range(S):
                if j == 0 or j == S - 1 or cluster_of[j] != cluster_of[j - 1]:
                    a, t = anc[r, cluster_of[j]], slots[j]
                    _prefetch(rhohat, a, t)
                    _prefetch(sd, a, t)
                    _prefetch(psi, a, t)
                    _prefetch(vel_src, a, t)
                    _prefetch(vvar_src, a, t)
                    _prefetch(cdf_start, a, j)
                    _prefetch(cdf_mass, a, j)
                    _prefetch(cdf_upper, a, j)
                    _prefetch(new_cell, a, j)
                    _prefetch(new_valid, a, j)
        for j in range(S):
            a = anc[p, cluster_of[j]]
            t = slots[j]
            alive = new_valid[a, j]
            cell = new_cell[a, j] if alive else 0
            for ax in range(2):
                k = cell % nx if ax == 0 else cell // nx  # cell_bounds
                lo, hi = k * cell_size, (k + 1) * cell_size
                mu, s = rhohat[a, t, ax], sd[a, t, ax]
                if not alive:  # an empty slot's values are never read
                    x = lo + uniforms[p, j, ax] * (hi - lo)
                elif cdf_upper[a, j, ax] >= 0:
                    x = _draw_in_cell(mu, s, lo, hi, uniforms[p, j, ax], cdf_start[a, j, ax],
                                      cdf_mass[a, j, ax], cdf_upper[a, j, ax] == 1)
                else:
                    x = _truncated_normal(mu, s, lo, hi, uniforms[p, j, ax])
                vv = vvar_src[a, t, ax]
                cross = tau * vv + q12[ax]
                gain = cross / psi[a, t, ax]
                pos[p, t, ax] = x
                vel[p, t, ax] = vel_src[a, t, ax] + gain * (x - mu)
                vvar[p, t, ax] = vv + q22[ax] - cross * gain
            valid[p, t] = alive
    # the slots in no cluster, in a pass of their own (interleaved with the loop above,
    # a 64,000-particle step of three one-slot clusters took 1.5x as long)
    for p in range(N):
        for t in others:
            for ax in range(2):
                vel[p, t, ax] = vel_src[p, t, ax]
                vvar[p, t, ax] = vvar_src[p, t, ax]


@njit(cache=True)
def recombined_log_pi(log_pi: np.ndarray, anc: np.ndarray, out: np.ndarray) -> None:
    """``out = -log_pi[anc, arange(C)].sum(axis=1)``: per receiver, minus the sum over
    the clusters of its ancestors' proposal log-probabilities (``log_pi``, ``anc (N,
    C)``), as numpy sums a row (:func:`..numba_exact.np_sum`)."""
    N, C = anc.shape
    row = np.empty(C)
    for p in range(N):
        if C < 8:  # np_sum's arithmetic, without a call taking a view
            total = -0.0
            for c in range(C):
                total += log_pi[anc[p, c], c]
            total = 0.0 + total
        else:
            for c in range(C):
                row[c] = log_pi[anc[p, c], c]
            total = np_sum(row, C)
        out[p] = -total


# ------------------------------------------------------------------ partitions
@njit(cache=True)
def cluster_slots(centres: np.ndarray, active: np.ndarray, gamma: float,
                  coupled: np.ndarray, members: np.ndarray, sizes: np.ndarray) -> int:
    """:func:`.partitions.cluster_slots`: the connected components of the active slots
    linked by ``|centre_i - centre_j| < gamma`` (numpy's ``norm``: the square root of
    ``dx^2 + dy^2``) or ``coupled[i, j]`` (an empty ``(0, 0)`` array: no coupling), each
    labelled by its smallest slot (the union keeps the smaller root, as the numpy form).
    Writes the clusters' slots, ascending, cluster after cluster by their first slot,
    into ``members (T,)`` and their sizes into ``sizes (T,)``; returns how many."""
    T = active.shape[0]
    parent = np.arange(T)
    use_coupled = coupled.shape[0] > 0
    for i in range(T):
        if not active[i]:
            continue
        for j in range(i + 1, T):
            if not active[j]:
                continue
            dx = centres[i, 0] - centres[j, 0]
            dy = centres[i, 1] - centres[j, 1]
            if np.sqrt(dx * dx + dy * dy) < gamma or (use_coupled and coupled[i, j]):
                ri, rj = i, j
                while parent[ri] != ri:
                    ri = parent[ri]
                while parent[rj] != rj:
                    rj = parent[rj]
                if ri != rj:
                    parent[max(ri, rj)] = min(ri, rj)
    n, k = 0, 0
    for r in range(T):
        if not active[r] or parent[r] != r:
            continue
        size = 0
        for t in range(r, T):
            if not active[t]:
                continue
            root = t
            while parent[root] != root:
                root = parent[root]
            if root == r:
                members[k] = t
                k += 1
                size += 1
        sizes[n] = size
        n += 1
    return n


# ------------------------------------------------------------------ sorting
@njit(cache=True)
def _least_permutation(D: np.ndarray, h: int, best: np.ndarray, path: np.ndarray,
                       used: np.ndarray, nxt: np.ndarray, partial: np.ndarray) -> None:
    """The first permutation ``perm`` (lexicographic order, as ``itertools``) of least
    ``sum_j D[j, perm_j]``, summed from 0 in ``j`` order, into ``best (h,)``.

    Depth-first over the permutations in that order: a prefix's partial sum is shared by
    all its completions (the same additions in the same order as the full sums), and a
    prefix whose partial sum is already at least the least complete sum so far is
    skipped: ``D >= 0`` and ``fl(a + b) >= a`` for ``b >= 0``, so none of its
    completions is strictly less, and the first least is the one a full scan finds.
    ``path``, ``used``, ``nxt``, ``partial``: scratch of ``h``, ``h``, ``h + 1``, ``h +
    1``."""
    best_cost = np.inf
    for k in range(h):
        used[k] = False
    d = 0
    nxt[0] = 0
    partial[0] = 0.0
    while d >= 0:
        if d == h:  # a complete permutation
            if partial[h] < best_cost:
                best_cost = partial[h]
                for j in range(h):
                    best[j] = path[j]
            d -= 1
            used[path[d]] = False
            continue
        k = nxt[d]
        while k < h and used[k]:
            k += 1
        if k == h:  # every choice at depth d tried
            d -= 1
            if d >= 0:
                used[path[d]] = False
            continue
        nxt[d] = k + 1
        c = partial[d] + D[d, k]
        if c >= best_cost:
            continue
        path[d] = k
        used[k] = True
        partial[d + 1] = c
        d += 1
        nxt[d] = 0


@njit(cache=True)
def sort_cluster(pos: np.ndarray, vel: np.ndarray, vvar: np.ndarray, valid: np.ndarray,
                 slots: np.ndarray, means: np.ndarray, held: np.ndarray,
                 new_held: np.ndarray, new_sums: np.ndarray) -> int:
    """One K-means sweep of :func:`.partitions.sort_slots` over one cluster ``slots
    (h,)``: every particle takes the permutation of ``range(h)`` of least ``sum_j valid
    |pos[slots[perm_j]] - means_j|^2`` (terms of slots held nowhere, ``held (h,)``,
    count 0; the first least in ``itertools`` order, as ``argmin`` over
    :func:`.partitions.permutations`: the identity when no other permutation can be
    strictly less, else :func:`_least_permutation`), applied in place to
    all four arrays. Also the cluster's holders ``new_held (h,)`` and position sums
    ``new_sums (h, 2)`` after the sweep (:func:`slot_sums`' numbers, summed in particle
    order). Returns the particles moved."""
    N = pos.shape[0]
    h = slots.shape[0]
    D = np.empty((h, h))
    best = np.empty(h, np.int64)
    path = np.empty(h, np.int64)
    used = np.empty(h, np.bool_)
    nxt = np.empty(h + 1, np.int64)
    partial = np.empty(h + 1)
    src = np.empty(h, np.int64)
    tp = np.empty((h, 2))
    tv = np.empty((h, 2))
    tw = np.empty((h, 2))
    tb = np.empty(h, np.bool_)
    new_held[:] = 0
    new_sums[:] = 0.0
    moved = 0
    for p in range(N):
        for j in range(h):
            for k in range(h):
                t = slots[k]
                if held[j] > 0 and valid[p, t]:
                    dx = pos[p, t, 0] - means[j, 0]
                    dy = pos[p, t, 1] - means[j, 1]
                    D[j, k] = dx * dx + dy * dy
                else:
                    D[j, k] = 0.0
        # the identity is the first permutation, and a least one (so the answer) when
        # every valid slot k costs at least the identity's sum in every other row r: a
        # permutation other than the identity either only exchanges invalid slots (the
        # same terms, an equal sum) or puts a valid k in a row r != k, and a sum of terms
        # >= 0 is at least each term (fl is monotone), so no sum is strictly less. Most
        # particles pass; the others take the search.
        cost = 0.0
        for j in range(h):
            cost += D[j, j]
        identity = True
        for k in range(h):
            if valid[p, slots[k]]:
                for r in range(h):
                    if r != k and D[r, k] < cost:
                        identity = False
        if not identity:
            _least_permutation(D, h, best, path, used, nxt, partial)
            identity = True
            for j in range(h):
                identity = identity and best[j] == j
        if not identity:
            moved += 1
            for j in range(h):
                src[j] = slots[best[j]]
            for j in range(h):
                s = src[j]
                tp[j, 0], tp[j, 1] = pos[p, s, 0], pos[p, s, 1]
                tv[j, 0], tv[j, 1] = vel[p, s, 0], vel[p, s, 1]
                tw[j, 0], tw[j, 1] = vvar[p, s, 0], vvar[p, s, 1]
                tb[j] = valid[p, s]
            for j in range(h):
                t = slots[j]
                pos[p, t, 0], pos[p, t, 1] = tp[j, 0], tp[j, 1]
                vel[p, t, 0], vel[p, t, 1] = tv[j, 0], tv[j, 1]
                vvar[p, t, 0], vvar[p, t, 1] = tw[j, 0], tw[j, 1]
                valid[p, t] = tb[j]
        for j in range(h):  # slot_sums' terms for this particle, in particle order
            t = slots[j]
            f = 1.0 if valid[p, t] else 0.0
            new_sums[j, 0] += pos[p, t, 0] * f
            new_sums[j, 1] += pos[p, t, 1] * f
            if valid[p, t]:
                new_held[j] += 1
    return moved


def warm_up() -> None:
    """Compile (or load from the disk cache) every kernel on tiny inputs, for the
    argument types the tracker uses. Cheap after the first time in a process."""
    if getattr(warm_up, "done", False):
        return
    N, T = 2, 2
    pos = np.full((N, T, 2), 0.5)
    valid = np.ones((N, T), dtype=bool)
    rh, ps = np.empty_like(pos), np.empty_like(pos)
    predict(pos, pos.copy(), np.ones_like(pos), 1.0, 1.0, np.full(2, 0.1), np.ones(2), True, rh, ps,
            np.empty_like(pos))
    gather_slots(pos, pos, pos, valid, np.zeros(N, np.int64), np.empty_like(pos),
                 np.empty_like(pos), np.empty_like(pos), np.empty_like(valid))
    held_per_particle(valid)
    recombined_log_pi(np.zeros((N, 1)), np.zeros((N, 1), np.int64), np.empty(N))
    for links in (np.ones((T, T), np.bool_), np.zeros((0, 0), np.bool_)):
        cluster_slots(pos[0], valid[0], 1.0, links, np.empty(T, np.int64),
                      np.empty(T, np.int64))
    held, sums = np.empty(T, np.int64), np.empty((T, 2))
    slot_sums(pos, pos, valid, True, held, sums, sums.copy())
    slots = np.arange(T, dtype=np.int64)
    max_held_sd(ps, valid, slots)
    members = slots[None, :].copy()
    sizes = np.array([T], dtype=np.int64)
    log_z, log_pi = np.empty((N, 1)), np.empty((N, 1))
    cell, alive = np.empty((N, T), np.int64), np.empty((N, T), bool)
    table = np.zeros((2, T + 1))
    starts, masses = np.empty((N, T, 2)), np.empty((N, T, 2))
    sides = np.empty((N, T, 2), np.int8)
    for direct in (True, False):
        for reflect in (True, False):
            propose(rh, ps, valid, slots, members, sizes, slots, np.full((T, N, 1), 0.5),
                    1, 1, 1.0, 1, 1, 1, reflect, 0.1, direct, np.zeros(2, np.int32),
                    np.zeros(1, np.int64), table, log_z, log_pi, cell, alive, starts,
                    masses, sides)
    place(np.zeros((N, 1), np.int64), np.arange(N, dtype=np.int64), True,
          np.zeros(T, np.int64), slots, cell, alive, starts,
          masses, sides, rh, ps, ps,
          np.full((N, T, 2), 0.5), 1, 1.0, 1.0, np.zeros(2), np.zeros(2), pos.copy(),
          pos.copy(), np.zeros(0, np.int64), pos.copy(), pos.copy(), pos.copy(), valid.copy())
    sort_cluster(pos.copy(), pos.copy(), pos.copy(), valid.copy(), slots, np.zeros((T, 2)),
                 held, held.copy(), sums.copy())
    for direct in (True, False):
        slot_log_likelihood(pos, valid, 1, 1, 1.0, 1, direct, np.zeros(2, np.int32),
                            np.zeros(1, np.int64), table, np.zeros(N))
    occupied(pos, valid, np.zeros(1, np.int64), 1, 1, 1.0, np.empty((N, 1), bool))
    one = np.full(1, 0.5)
    birth_decisions(np.ones(N), one, one, one, one, valid[:, :1].copy(), valid[:, :1].copy(),
                    np.full((N, 1), 0.5), np.empty((N, 1), bool), np.zeros(N))
    warm_up.done = True
