"""The particles' storage: component-major state buffers, validity masks and cells.

Never one Python object per particle, never an ``(N, n_cells)`` array. The states
``X (N, t_max, 4)`` (rows ``[px, vx, py, vy]``) are kept component-major, ``(4, t_max,
N)``, so that every per-step operation runs over contiguous memory; slot ``s`` of
particle ``i`` holds a target iff ``valid[s, i]`` (valid slots need not be packed
first). The functions here take those arrays; :class:`ParticleState` holds them with
the counts, weights and flat cells, and owns the buffer swaps of the predict and of the
resampling gathers.
"""

from __future__ import annotations

import math

import numpy as np

from ...scenarios.model import Grid


# --------------------------------------------------------------- boundary rule
def fold(pos: np.ndarray, vel: np.ndarray, length: float) -> tuple[np.ndarray, np.ndarray]:
    """Reflect positions into ``[0, length)``, flipping velocity on odd bounces."""
    folded = np.mod(pos, 2.0 * length)
    bounced = folded >= length
    pos = np.where(bounced, 2.0 * length - folded, folded)
    pos = np.minimum(pos, np.nextafter(length, 0.0))
    return pos, np.where(bounced, -vel, vel)


def apply_boundary(X: np.ndarray, valid: np.ndarray, width: float, height: float,
                   reflect: bool, flags: np.ndarray | None = None) -> None:
    """The model's boundary rule on every slot, in place: a position outside ``[0, L)``
    is folded back (:func:`fold`, velocity mirrored) when ``reflect``, else its slot
    dies (``valid`` cleared) and the position is parked at ``L / 2`` so that it does not
    leave again by itself.

    ``X (4, t_max, N)`` component-major (C-contiguous rows), ``valid (t_max, N)`` bool;
    ``flags`` optional bool scratch of ``valid``'s shape. The candidates come from one
    unsigned comparison of the float bits per row: for ``x >= 0`` the bits increase with
    ``x``, and a negative ``x`` has the sign bit set, so ``bits(x) >= bits(L)`` holds for
    every ``x`` outside (and also for -0.0 and NaN); the exact test then runs on the few
    candidates. :func:`.kernels.boundary_cells_counts` is the compiled form.
    """
    if flags is None:
        flags = np.empty(valid.shape, dtype=bool)
    for p_row, v_row, length in ((0, 1, width), (2, 3, height)):
        pos = X[p_row]
        np.greater_equal(pos.view(np.uint64), np.float64(length).view(np.uint64), out=flags)
        out = np.flatnonzero(flags)
        if out.size == 0:
            continue
        at = np.divmod(out, pos.shape[1])
        p = pos[at]
        keep = (p < 0.0) | (p >= length)
        if not keep.all():
            at = (at[0][keep], at[1][keep])
            p = p[keep]
        if reflect:
            pos[at], X[v_row][at] = fold(p, X[v_row][at], length)
        else:
            valid[at] = False
            pos[at] = 0.5 * length


# ----------------------------------------------------------------------- cells
def cell_dtype(grid: Grid) -> type:
    """int32 when every flat cell of ``grid`` fits (half the memory traffic of int64),
    else int64 (grids of more than ``2^31 - 1`` cells)."""
    return np.int32 if grid.n_cells <= np.iinfo(np.int32).max else np.int64


def flat_cells(px: np.ndarray, py: np.ndarray, grid: Grid, out: np.ndarray | None = None,
               col: np.ndarray | None = None, tmp: np.ndarray | None = None) -> np.ndarray:
    """Flat cells ``floor(py / s) nx + floor(px / s)`` (``s`` the cell size) of positions
    inside the workspace, of their shape and dtype :func:`cell_dtype` (int32 unless the
    grid has more cells); ``out``, ``col`` (that dtype) and ``tmp`` (float64) are
    optional buffers of that shape.

    Computed as ``trunc(py * (1 / s)) nx + trunc(px * (1 / s))``; the positions are
    inside, so the truncating cast is the floor. With ``s = 1`` the products are skipped
    (``x * 1.0 == x`` exactly); otherwise the indices are clamped to the grid, because a
    position one ulp below the edge can round up to ``nx`` (``ny``) in the product.
    :func:`.kernels.boundary_cells_counts` is the compiled form.
    """
    if out is None:
        out = np.empty(px.shape, dtype=cell_dtype(grid))
    if col is None:
        col = np.empty(px.shape, dtype=out.dtype)
    if grid.cell_size == 1.0:
        np.copyto(out, py, casting="unsafe")
        np.copyto(col, px, casting="unsafe")
    else:
        inv = 1.0 / grid.cell_size
        if tmp is None:
            tmp = np.empty(px.shape)
        np.multiply(py, inv, out=tmp)
        np.copyto(out, tmp, casting="unsafe")
        np.minimum(out, grid.ny - 1, out=out)
        np.multiply(px, inv, out=tmp)
        np.copyto(col, tmp, casting="unsafe")
        np.minimum(col, grid.nx - 1, out=col)
    out *= grid.nx
    out += col
    return out


# ------------------------------------------------------------------- gathers
def gather_mask(valid: np.ndarray, idx: np.ndarray, out: np.ndarray) -> None:
    """``out[:, k] = valid[:, idx[k]]`` for ``valid, out (t_max, N)`` bool, ``idx`` in
    range: up to 8 slots go as the bits of one byte per particle (one gather of N bytes
    instead of ``t_max N``)."""
    T = valid.shape[0]
    if T > 8:
        np.take(valid, idx, axis=1, out=out, mode="clip")
        return
    bits = valid[0].view(np.uint8).copy()
    tmp = np.empty_like(bits)
    for t in range(1, T):
        np.left_shift(valid[t].view(np.uint8), t, out=tmp)
        bits |= tmp
    bits = np.take(bits, idx, mode="clip")
    for t in range(T):
        np.right_shift(bits, t, out=tmp)
        np.bitwise_and(tmp, 1, out=out[t].view(np.uint8))


class ParticleState:
    """The ``N`` particles of one run, component-major, with their bookkeeping.

    Fields: ``X (4, t_max, N)`` the states; ``valid (t_max, N)`` bool; ``counts (N,)``
    int64 targets per particle; ``logw``, ``w (N,)`` normalised log-weights and their
    exponentials (kept in step); ``raw_cells (t_max, N)`` the flat cell of every
    slot, valid or not (None: stale after a resampling until the next predict; empty
    slots hold positions inside the workspace too, so their cells are in range).

    ``X`` lives in one of two buffers ``(8, t_max, N)``: rows 0-3 states, rows 4-7 the
    step's standard normals, so that ``x <- F x + L e`` is one ``(4, 8) @ (8, t_max N)``
    product into the other buffer; a resampling also gathers into the other buffer, then
    the two swap (no fresh arrays per step). ``cells_buf``, ``col_buf``, ``key_buf``
    (:func:`cell_dtype`; the keys int32), ``flags`` (bool) and ``tmp`` (float64), all
    ``(t_max, N)``, are scratch. ``raw_cells`` are :func:`cell_dtype` (int32 unless the
    grid has more than ``2^31 - 1`` cells).
    """

    def __init__(self, n: int, t_max: int, grid: Grid) -> None:
        T, N = t_max, n
        self.n, self.t_max, self.grid = n, t_max, grid
        self.width, self.height = grid.extent
        self.bufs = (np.empty((8, T, N)), np.empty((8, T, N)))
        self.X = self.bufs[0][:4]
        self.valid = np.zeros((T, N), dtype=bool)
        self.valid_spare = np.empty((T, N), dtype=bool)
        # int32 cells when they fit (half the memory traffic of int64), int32 keys
        self.cells_buf = np.empty((T, N), dtype=cell_dtype(grid))
        self.col_buf = np.empty((T, N), dtype=cell_dtype(grid))
        self.key_buf = np.empty((T, N), dtype=np.int32)
        self.flags = np.empty((T, N), dtype=bool)
        self.tmp = np.empty((T, N))
        self.counts = np.zeros(N, dtype=np.int64)
        self.logw = np.full(N, -math.log(N))
        self.w = np.full(N, 1.0 / N)
        self.raw_cells: np.ndarray | None = None

    # ------------------------------------------------------------- buffers
    def other_buffer(self) -> np.ndarray:
        """The buffer not holding the states (the target of the next predict/gather)."""
        a, b = self.bufs
        if self.X.base is not a:
            if self.X.base is not b:  # replaced by a realignment: copy it home
                a[:4] = self.X
                self.X = a[:4]
                return b
            return a
        return b

    def propagate(self, FL: np.ndarray, rng: np.random.Generator) -> None:
        """``x <- F x + L e`` for every slot as one matrix product.

        ``e`` are ``4 t_max N`` standard normals from one ``standard_normal`` call, in
        rows 4-7 of the buffer holding ``x``; ``FL = [F | L] (4, 8)`` times that buffer
        seen as ``(8, t_max N)`` goes into the other buffer's state rows.
        """
        out = self.other_buffer()
        src = self.X.base
        T, N = self.t_max, self.n
        rng.standard_normal(out=src[4:])
        np.matmul(FL, src.reshape(8, T * N), out=out[:4].reshape(4, T * N))
        self.X = out[:4]

    # --------------------------------------------------------- cells, counts
    def apply_boundary(self, reflect: bool) -> None:
        """:func:`apply_boundary` on the states (numpy form)."""
        apply_boundary(self.X, self.valid, self.width, self.height, reflect, self.flags)

    def boundary_cells_counts(self, kernels, reflect: bool) -> np.ndarray:
        """The boundary rule, ``raw_cells`` and the counts in one compiled pass
        (:func:`.kernels.boundary_cells_counts`); returns the counts ``(N,)``."""
        X, grid = self.X, self.grid
        width, height = self.width, self.height
        counts = np.empty(self.n, dtype=np.int64)
        kernels.boundary_cells_counts(
            X[0], X[1], X[2], X[3], self.valid, width, height, np.nextafter(width, 0.0),
            np.nextafter(height, 0.0), grid.nx, grid.ny, 1.0 / grid.cell_size,
            grid.cell_size == 1.0, reflect, self.cells_buf, counts)
        self.raw_cells = self.cells_buf
        return counts

    def update_cells(self) -> None:
        """``raw_cells`` from the positions (:func:`flat_cells`, numpy form)."""
        X = self.X
        self.raw_cells = flat_cells(X[0], X[2], self.grid, out=self.cells_buf,
                                    col=self.col_buf, tmp=self.tmp)

    def count_targets(self) -> np.ndarray:
        """``valid.sum(axis=0)`` as row additions (a strided reduction is several times
        slower)."""
        valid = self.valid
        counts = valid[0].astype(np.int64)
        for row in valid[1:]:
            counts += row
        return counts

    def slot_cells(self) -> np.ndarray:
        """The flat cell of every slot ``(t_max, N)`` (:func:`cell_dtype`): ``raw_cells``,
        or computed from the positions by the same rule when stale."""
        if self.raw_cells is not None:
            return self.raw_cells
        return flat_cells(self.X[0], self.X[2], self.grid)

    def cells(self) -> np.ndarray:
        """Flat cells ``(t_max, N)`` int64 with ``n_cells`` for empty slots (a new array)."""
        return np.where(self.valid, self.slot_cells(), self.grid.n_cells).astype(np.int64)

    # ----------------------------------------------------------- resampling
    def resample(self, idx: np.ndarray) -> None:
        """Keep particles ``idx (N,)`` (in range) with equal weights: one gather per array
        into the spare buffer, then swap."""
        # np.take keeps C order (fancy indexing on the last axis would not) and
        # mode="clip" stops it from buffering the output
        X, V = self.other_buffer()[:4], self.valid_spare
        np.take(self.X, idx, axis=2, out=X, mode="clip")
        gather_mask(self.valid, idx, V)
        self.X = X
        self.valid_spare, self.valid = self.valid, V
        self.raw_cells = None  # stale until the next predict recomputes it
        self.counts = self.counts[idx]
        self.logw.fill(-math.log(self.n))
        self.w.fill(1.0 / self.n)
