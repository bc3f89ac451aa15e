"""Compiled (numba) kernels for the JMPD's per-slot passes, each equal bit for bit
to a numpy form in this package.

Why: a bootstrap step is ``N * t_max`` slots of a few operations each. In numpy every
operation is its own pass over ``(t_max, N)`` arrays (about 0.3 ms per pass at
``N = 1e5, t_max = 5`` on the reference machine). Three parts gain from one compiled
loop: the boundary rule, cell index and count of every slot (about 4 ms in numpy,
1.5 ms compiled), the likelihood's dense path (2.2-2.6 ms, 1.3 ms compiled: the
same passes fused, loops over particles innermost; a per-particle loop with
branches measured 4.6 ms, slower than numpy) and the systematic resampling indices
(about 2.9 ms by the linear-time numpy form, 1 ms by one merge).

Exactness: every kernel performs the same IEEE operations, in the same order, as its
numpy form (the tests compare both on random and edge inputs, and whole tracker runs
with and without the kernels), so results never depend on whether numba is present.

Importing this module imports numba, so :func:`.backend.compiled_kernels` imports it
on first use only (and not at all without numba or with ``MTTBENCH_NO_NUMBA`` set).
Kernels compile on first call and are cached on disk (``cache=True``); :func:`warm_up`
does that on tiny inputs so that no timed step pays for it.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from ..compiled import drop_stale_caches

drop_stale_caches()  # before any kernel loads: a caller's cache may hold an old callee


@njit(cache=True)
def _outside(p: float, v: float, length: float, cap: float,
             reflect: bool) -> tuple[float, float, bool]:
    """A position ``p`` outside ``[0, length)`` with velocity ``v``: ``(p, v, alive)``
    after the boundary rule. Reflect is one value of :func:`.state.fold`:
    ``np.mod(p, 2 L)`` (fmod, then the sign fix of numpy's remainder), mirrored above
    ``L`` with the velocity, capped at ``cap`` (``np.minimum``, which keeps a NaN). Die
    parks the position at ``L / 2``."""
    if not reflect:
        return 0.5 * length, v, False
    two = 2.0 * length
    folded = np.fmod(p, two)
    if folded != 0.0:
        if folded < 0.0:  # the divisor is positive: numpy adds it to a negative fmod
            folded += two
    else:
        folded = 0.0  # copysign(0, divisor)
    if folded >= length:
        p, v = two - folded, -v
    else:
        p = folded
    if p > cap:
        p = cap
    return p, v, True


@njit(cache=True)
def boundary_cells_counts(px: np.ndarray, vx: np.ndarray, py: np.ndarray, vy: np.ndarray,
                          valid: np.ndarray, width: float, height: float, cap_w: float,
                          cap_h: float, nx: int, ny: int, inv: float, unit: bool,
                          reflect: bool, cells: np.ndarray, counts: np.ndarray) -> None:
    """Boundary rule, flat cell and count of every slot in one pass.

    ``px, vx, py, vy (T, N)`` the state rows (changed in place), ``valid (T, N)`` bool
    (in place: the ``die`` rule clears it), ``cap_w = nextafter(width, 0)`` (same for
    the height), ``inv = 1 / cell_size`` (unused when ``unit``: cell size 1),
    ``reflect`` the boundary rule (else ``die``). Writes ``cells (T, N)`` (int32, or
    int64 on grids of more than ``2^31 - 1`` cells) and ``counts (N,)`` (valid slots per
    particle).

    Numpy forms: :func:`.state.apply_boundary` (a position outside ``[0, L)`` is
    folded back with its velocity mirrored, or its slot dies and the position is
    parked at ``L / 2``), :func:`.state.flat_cells` (``trunc(p / s)``, clamped to the
    grid when ``s != 1``, row-major) and the column sums of ``valid``.
    """
    T, N = valid.shape
    counts[:] = 0
    for t in range(T):
        pxt, vxt, pyt, vyt, vt, ct = px[t], vx[t], py[t], vy[t], valid[t], cells[t]
        for i in range(N):
            x = pxt[i]
            y = pyt[i]
            if not (x >= 0.0 and x < width and y >= 0.0 and y < height):
                if x < 0.0 or x >= width:  # a NaN is left alone, as in numpy
                    x, vxt[i], alive = _outside(x, vxt[i], width, cap_w, reflect)
                    pxt[i] = x
                    vt[i] = vt[i] and alive
                if y < 0.0 or y >= height:
                    y, vyt[i], alive = _outside(y, vyt[i], height, cap_h, reflect)
                    pyt[i] = y
                    vt[i] = vt[i] and alive
            if unit:
                col = np.int32(x)
                row = np.int32(y)
            else:
                col = min(np.int32(x * inv), nx - 1)
                row = min(np.int32(y * inv), ny - 1)
            ct[i] = row * nx + col  # exact: the cell fits the array's dtype
            counts[i] += vt[i]


@njit(cache=True)
def grid_log_likelihood_dense(cells: np.ndarray, valid: np.ndarray, use_valid: bool,
                              inc_cell: np.ndarray, n_counts: int, key: np.ndarray,
                              count: np.ndarray, out: np.ndarray) -> None:
    """The dense path of :func:`.likelihood.grid_log_likelihood`, its passes fused.

    ``cells (T, N)`` integers (the tracker passes each slot's row of the look table,
    :class:`.sparse.CellIndex`), ``valid (T, N)`` bool (read only when ``use_valid``;
    otherwise every slot counts as valid), ``inc_cell`` the flat increment table
    ``(rows * n_counts,)`` (indices clipped to it), ``key (T, N)`` int32 and ``count
    (N,)`` int32 scratch; writes ``out (N,)``. Same integer steps (int32 keys ``c n_counts + v``,
    ranks from the unranked keys of the earlier slots) and the same float additions
    in slot order as numpy; the loops run over particles innermost, so they vectorise.
    """
    T, N = cells.shape
    top = inc_cell.shape[0] - 1
    for j in range(T):
        cj, kj = cells[j], key[j]
        if use_valid:
            vj = valid[j]
            for i in range(N):
                kj[i] = cj[i] * n_counts + vj[i]
        else:
            for i in range(N):
                kj[i] = cj[i] * n_counts + 1
    for j in range(T - 1, 0, -1):
        kj = key[j]
        count[:] = 0
        for k in range(j):
            kk = key[k]
            for i in range(N):
                count[i] += kk[i] == kj[i]
        if use_valid:
            vj = valid[j]
            for i in range(N):
                kj[i] += count[i] * vj[i]
        else:
            for i in range(N):
                kj[i] += count[i]
    k0 = key[0]
    for i in range(N):
        out[i] = inc_cell[min(max(np.int64(k0[i]), 0), top)]
    for j in range(1, T):
        kj = key[j]
        for i in range(N):
            out[i] += inc_cell[min(max(np.int64(kj[i]), 0), top)]


@njit(cache=True)
def systematic_indices(weights: np.ndarray, u: float) -> np.ndarray:
    """``searchsorted(cumsum(weights), (u + arange(n)) / n, side="right")`` clipped to
    ``n - 1`` (:func:`.resampling.systematic_resample`), by one merge of the two sorted
    sequences (the cumulative sum is the sequential one of ``np.cumsum``). Finite
    weights only."""
    n = weights.shape[0]
    cumulative = np.empty(n)
    s = 0.0
    for j in range(n):
        s += weights[j]
        cumulative[j] = s
    positions = np.empty(n)
    for k in range(n):  # a loop of its own so that the divisions vectorise
        positions[k] = (k + u) / n
    idx = np.empty(n, dtype=np.int64)
    j = 0
    for k in range(n):
        position = positions[k]
        while j < n and cumulative[j] <= position:
            j += 1
        idx[k] = j if j < n else n - 1
    return idx


def warm_up() -> None:
    """Compile (or load from the disk cache) every kernel for the argument types the
    tracker uses, on tiny inputs. Cheap after the first time in a process."""
    if getattr(warm_up, "done", False):
        return
    rows = np.full((4, 1, 2), 0.5)
    valid = np.ones((1, 2), dtype=bool)
    for cell_type in (np.int32, np.int64):  # int64: grids of more than 2^31 - 1 cells
        boundary_cells_counts(rows[0], rows[1], rows[2], rows[3], valid, 1.0, 1.0, 0.9, 0.9,
                              1, 1, 1.0, True, True, np.zeros((1, 2), dtype=cell_type),
                              np.zeros(2, dtype=np.int64))
    out, key, count = np.empty(2), np.empty((1, 2), np.int32), np.empty(2, np.int32)
    for cells in (np.zeros((1, 2), np.int32), np.zeros((1, 2), np.int64)):
        for use_valid in (True, False):
            grid_log_likelihood_dense(cells, valid, use_valid, np.zeros(4), 2, key, count,
                                      out)
    systematic_indices(np.full(2, 0.5), 0.5)
    warm_up.done = True
