"""Compiled (numba) helpers that reproduce numpy's and scipy's arithmetic exactly, shared
by the kernels of :mod:`.grid_kernels` and :mod:`.jmpd.ap_kernels`.

* :func:`np_sum`: ``a[:n].sum()`` as numpy computes it, 0 plus its pairwise summation
  (blocks of at most 128 with 8 accumulators, :func:`_block`; larger arrays as the halves
  of numpy's recursion, :func:`_pairwise`).
* :data:`ndtr`, :data:`ndtri`: scipy's own C normal CDF and its inverse for doubles
  (``cython_special``), as external symbols so that the kernels calling them cache on
  disk (a ctypes pointer cannot); called as ``ndtr(x, 0)``.

Importing this module imports numba (the kernels' modules import it on first use only).
"""

from __future__ import annotations

import llvmlite.binding
import numpy as np
from numba import njit, types
from numba.extending import get_cython_function_address

from .compiled import drop_stale_caches

drop_stale_caches()  # before any kernel loads: a caller's cache may hold an old callee


def scipy_function(symbol: str, name: str) -> types.ExternalFunction:
    """scipy's C function ``name`` of ``cython_special`` (``double (double, int
    skip_dispatch)``) as an external symbol, so that the kernels calling it can be
    cached on disk (a ctypes pointer cannot). ImportError when scipy exports it with
    another signature (the numpy forms then run)."""
    from scipy.special import cython_special
    capsule = cython_special.__pyx_capi__.get(name)
    if capsule is None or '"double (double, int' not in repr(capsule):
        raise ImportError(f"scipy.special.cython_special.{name} is not double (double, int)")
    llvmlite.binding.add_symbol(symbol, get_cython_function_address(
        "scipy.special.cython_special", name))
    return types.ExternalFunction(symbol, types.float64(types.float64, types.intc))


#: scipy.special.ndtr and ndtri for doubles (the ufuncs' own C functions)
ndtr = scipy_function("mttbench_scipy_ndtr", "__pyx_fuse_1ndtr")
ndtri = scipy_function("mttbench_scipy_ndtri", "ndtri")


@njit(cache=True)
def _block(a: np.ndarray, lo: int, n: int) -> float:
    """numpy's pairwise sum of ``a[lo:lo + n]`` for ``n <= 128`` (8 accumulators)."""
    if n < 8:
        res = -0.0
        for i in range(n):
            res += a[lo + i]
        return res
    r0, r1, r2, r3 = a[lo], a[lo + 1], a[lo + 2], a[lo + 3]
    r4, r5, r6, r7 = a[lo + 4], a[lo + 5], a[lo + 6], a[lo + 7]
    m = n - n % 8
    for i in range(lo + 8, lo + m, 8):
        r0 += a[i]
        r1 += a[i + 1]
        r2 += a[i + 2]
        r3 += a[i + 3]
        r4 += a[i + 4]
        r5 += a[i + 5]
        r6 += a[i + 6]
        r7 += a[i + 7]
    res = ((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7))
    for i in range(lo + m, lo + n):
        res += a[i]
    return res


@njit(cache=True)
def _pairwise(a: np.ndarray, lo: int, n: int) -> float:
    """numpy's pairwise sum of ``a[lo:lo + n]``: blocks of at most 128 (:func:`_block`)
    added as the halves of numpy's recursion (``n / 2`` rounded down to a multiple of
    8), here by an explicit stack (numba cannot cache a recursive function)."""
    if n <= 128:
        return _block(a, lo, n)
    seg_lo = np.empty(64, np.int64)
    seg_n = np.empty(64, np.int64)
    stage = np.zeros(64, np.int64)
    values = np.empty(64)
    sp, vp = 0, 0
    seg_lo[0], seg_n[0] = lo, n
    while sp >= 0:
        sl, sn = seg_lo[sp], seg_n[sp]
        if sn <= 128:
            values[vp] = _block(a, sl, sn)
            vp += 1
            sp -= 1
            continue
        n2 = sn // 2
        n2 -= n2 % 8
        if stage[sp] == 0:  # the left half first
            stage[sp] = 1
            sp += 1
            seg_lo[sp], seg_n[sp], stage[sp] = sl, n2, 0
        elif stage[sp] == 1:  # then the right half
            stage[sp] = 2
            sp += 1
            seg_lo[sp], seg_n[sp], stage[sp] = sl + n2, sn - n2, 0
        else:  # both done: left + right
            values[vp - 2] = values[vp - 2] + values[vp - 1]
            vp -= 1
            sp -= 1
    return values[0]


@njit(cache=True)
def np_sum(a: np.ndarray, n: int) -> float:
    """``a[:n].sum()`` as numpy computes it (0 plus the pairwise sum)."""
    return 0.0 + _pairwise(a, 0, n)


# --------------------------------------------- small exact forms the kernels share
@njit(cache=True, inline="always")
def nan_max(a: float, b: float) -> float:
    """``np.maximum`` of two doubles (a NaN wins; on a tie the first)."""
    if a != a:
        return a
    if b != b:
        return b
    return a if a >= b else b


@njit(cache=True, inline="always")
def nan_min(a: float, b: float) -> float:
    """``np.minimum`` of two doubles (a NaN wins; on a tie the first)."""
    if a != a:
        return a
    if b != b:
        return b
    return a if a <= b else b


@njit(cache=True)
def search_left(a: np.ndarray, v: int) -> int:
    """``np.searchsorted(a, v)`` (side left) on a sorted int array."""
    lo, hi = 0, len(a)
    while lo < hi:
        mid = (lo + hi) // 2
        if a[mid] < v:
            lo = mid + 1
        else:
            hi = mid
    return lo


@njit(cache=True)
def find_root(parent: np.ndarray, i: int) -> int:
    """The root of ``i`` in a union-find forest, halving the path on the way."""
    while parent[i] != i:
        parent[i] = parent[parent[i]]
        i = parent[i]
    return i


@njit(cache=True)
def unique_inverse(key: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``np.unique(key, return_inverse=True)`` of an int array."""
    n = len(key)
    order = np.argsort(key)  # any order among equal keys gives the same two arrays
    inv = np.empty(n, np.int64)
    n_k = 0
    for j in range(n):
        if j == 0 or key[order[j]] != key[order[j - 1]]:
            n_k += 1
        inv[order[j]] = n_k - 1
    uniq = np.empty(n_k, np.int64)
    for j in range(n):
        uniq[inv[j]] = key[j]
    return uniq, inv
