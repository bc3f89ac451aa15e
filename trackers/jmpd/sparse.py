"""Per-cell tables whose cost follows the cells they hold, never the grid's size.

The JMPD trackers keep per-step tables keyed by flat cells (this step's looked cells,
the cells the particles occupy) and per-run values that start equal in every cell and
change only where the sensor looked (``jmpd-ap``'s undetected targets). A dense array
over the grid would cost ``O(cells)`` per step however few cells are involved; here:

* :class:`CellIndex` -- the position of flat cells among sorted unique ``keys``
  (``len(keys)`` for any other cell): one gather from a direct table on grids of at
  most :data:`DIRECT_MAX` cells (the table is then cheaper than hashing), else a
  multiplicative hash of ``O(keys)`` buckets (verified against the keys; the few
  queries whose bucket holds several keys are resolved by a binary search). Either
  way ``O(queries + keys)`` time and ``O(keys)`` memory beyond the answer.
* :func:`unique_cells` -- the sorted unique cells of an array of flat cells, without a
  sort of the whole array: a direct occupancy count on small grids, else the hash
  buckets' representatives (only the cells that share a bucket with another are
  sorted).
* :class:`CellTable` -- named per-cell columns: one default value per column for every
  cell, and the sorted cells that have values of their own.

Which path runs never changes a result: every query gets the same integer.
"""

from __future__ import annotations

import numpy as np

#: grids of at most this many cells (plus the sentinel ``n_cells``) use a direct table
#: (``O(cells)``, bounded by this constant; 256 KB of int32)
DIRECT_MAX = 1 << 16
#: buckets per key of the hash (a key shares its bucket with probability about 6%)
_BUCKETS_PER_KEY = 16
_GOLDEN = np.uint64(0x9E3779B97F4A7C15)  # 2^64 / golden ratio (Fibonacci hashing)


def _bucket(cells: np.ndarray, bits: int) -> np.ndarray:
    """``(cells * golden mod 2^64) >> (64 - bits)`` as intp (any integer dtype; negative
    values wrap, they only need a bucket)."""
    h = np.asarray(cells).astype(np.uint64)
    h *= _GOLDEN
    h >>= np.uint64(64 - bits)
    return h.astype(np.intp)


class CellIndex:
    """Rows of flat cells in a table keyed by ``keys (m,)`` (sorted, unique, in ``[0,
    n_cells)``): ``index(cells)`` is, element by element, ``i`` where ``keys[i] ==
    cell`` and ``m`` (the missing row) elsewhere, int32 of ``cells``' shape.

    Cells in ``[0, n_cells]`` and above are answered exactly on both paths (the
    direct table clips anything above ``n_cells`` onto its sentinel entry); negative
    values are junk (the direct table clips them onto cell 0). ``direct`` forces the
    path (None: direct when ``n_cells + 1 <= DIRECT_MAX``; tests force both).
    """

    __slots__ = ("keys", "n_cells", "missing", "direct", "_table", "_bits", "_crowded",
                 "_keys_ext")

    def __init__(self, keys: np.ndarray, n_cells: int, direct: bool | None = None) -> None:
        keys = np.asarray(keys, dtype=np.int64).reshape(-1)
        m = len(keys)
        self.keys, self.n_cells, self.missing = keys, int(n_cells), m
        self.direct = self.n_cells + 1 <= DIRECT_MAX if direct is None else bool(direct)
        if self.direct:
            table = np.full(self.n_cells + 1, m, dtype=np.int32)
            table[keys] = np.arange(m, dtype=np.int32)
            self._table = table
            return
        bits = max(int(np.ceil(np.log2(max(_BUCKETS_PER_KEY * m, 2)))), 4)
        b = _bucket(keys, bits)
        table = np.full(1 << bits, m, dtype=np.int32)
        table[b[::-1]] = np.arange(m, dtype=np.int32)[::-1]  # the first key of a bucket
        crowded = np.bincount(b, minlength=1 << bits) > 1
        self._table, self._bits = table, bits
        self._crowded = crowded if crowded.any() else None
        # keys plus the missing row's entry: a query equal to it is missing either way
        self._keys_ext = np.append(keys, np.int64(-1))

    def direct_table(self) -> np.ndarray | None:
        """The direct path's table ``(n_cells + 1,)`` int32 (``index(c) = table[min(c,
        n_cells)]`` for ``c >= 0``), None on the hashed path."""
        return self._table if self.direct else None

    def __call__(self, cells: np.ndarray) -> np.ndarray:
        cells = np.asarray(cells)
        if self.direct:
            return np.take(self._table, cells, mode="clip")
        b = _bucket(cells, self._bits)
        rows = np.take(self._table, b)
        found = np.take(self._keys_ext, rows) == cells
        rows[~found] = self.missing
        if self._crowded is not None:
            # a bucket of several keys holds only the first: search the keys instead
            at = np.flatnonzero(np.take(self._crowded, b))
            if at.size:
                q = cells.reshape(-1)[at]
                i = np.minimum(np.searchsorted(self.keys, q), max(self.missing - 1, 0))
                hit = self.keys[i] == q
                rows.reshape(-1)[at] = np.where(hit, i, self.missing)
        return rows


def unique_cells(cells: np.ndarray, n_cells: int, direct: bool | None = None) -> np.ndarray:
    """The sorted unique values of ``cells`` (flat cells in ``[0, n_cells)``, any shape),
    int64. ``direct`` as in :class:`CellIndex`: an occupancy count over the grid, or the
    representatives of hash buckets (each bucket's first cell; the cells that differ from
    their bucket's representative, few, are deduplicated by a sort), then a sort of the
    distinct cells only."""
    cells = np.asarray(cells).reshape(-1)
    if direct is None:
        direct = n_cells + 1 <= DIRECT_MAX
    if direct:
        return np.flatnonzero(np.bincount(cells, minlength=n_cells)).astype(np.int64)
    if cells.size == 0:
        return np.zeros(0, dtype=np.int64)
    bits = max(int(np.ceil(np.log2(max(2 * cells.size, 2)))), 4)
    b = _bucket(cells, bits)
    first = np.full(1 << bits, -1, dtype=np.intp)
    first[b[::-1]] = np.arange(cells.size)[::-1]
    reps = cells[first[first >= 0]]
    other = cells != cells[first[b]]
    # distinct buckets hold distinct cells, and a cell unlike its bucket's representative
    # is unlike every representative
    out = np.concatenate([reps, np.unique(cells[other])]).astype(np.int64)
    out.sort()
    return out


class CellTable:
    """Per-cell columns over ``n_cells`` cells: ``defaults[name]`` in every cell but
    ``cells (m,)`` (sorted, unique), whose values are ``columns[name] (m,)``.

    Reading costs a binary search per queried cell; :meth:`set` merges new cells into the
    sorted arrays (``O(m)`` copying, done once per step for that step's cells).
    """

    __slots__ = ("n_cells", "defaults", "cells", "columns")

    def __init__(self, n_cells: int, **defaults: tuple[float | int, type]) -> None:
        """``defaults``: ``name=(value, dtype)`` per column."""
        self.n_cells = int(n_cells)
        self.defaults = {k: np.asarray(v, dtype=t)[()] for k, (v, t) in defaults.items()}
        self.cells = np.zeros(0, dtype=np.int64)
        self.columns = {k: np.zeros(0, dtype=t) for k, (_, t) in defaults.items()}

    @property
    def n_default(self) -> int:
        """How many cells have the default values."""
        return self.n_cells - len(self.cells)

    def _where(self, cells: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        i = np.searchsorted(self.cells, cells)
        own = i < len(self.cells)
        own[own] = self.cells[i[own]] == cells[own]
        return i, own

    def get(self, name: str, cells: np.ndarray) -> np.ndarray:
        """Column ``name`` at ``cells`` (any shape)."""
        cells = np.asarray(cells, dtype=np.int64)
        i, own = self._where(cells)
        out = np.full(cells.shape, self.defaults[name])
        out[own] = self.columns[name][i[own]]
        return out

    def set(self, cells: np.ndarray, **values: np.ndarray) -> None:
        """Give ``cells`` (sorted, unique) the ``values`` of every column (all named)."""
        cells = np.asarray(cells, dtype=np.int64).reshape(-1)
        if set(values) != set(self.columns):
            raise ValueError(f"set needs every column {sorted(self.columns)}")
        i, own = self._where(cells)
        for name, v in values.items():
            self.columns[name][i[own]] = np.broadcast_to(v, cells.shape)[own]
        new = ~own
        if new.any():
            at = i[new]
            self.cells = np.insert(self.cells, at, cells[new])
            for name, v in values.items():
                self.columns[name] = np.insert(self.columns[name], at,
                                               np.broadcast_to(v, cells.shape)[new])

    def dense(self, name: str) -> np.ndarray:
        """Column ``name`` over every cell, ``(n_cells,)`` (``O(cells)``: tests)."""
        out = np.full(self.n_cells, self.defaults[name])
        out[self.cells] = self.columns[name]
        return out
