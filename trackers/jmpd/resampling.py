"""Systematic resampling: which particles get offspring, in linear time.

:func:`systematic_resample` turns normalised weights and one uniform into offspring
indices (compiled as :func:`.kernels.systematic_indices` when numba is there, with the
same result); :meth:`.state.ParticleState.resample` then gathers the particles.
"""

from __future__ import annotations

import numpy as np

from .backend import compiled_kernels


def effective_sample_size(weights: np.ndarray) -> float:
    """``1 / sum w_i^2`` of normalised weights ``(N,)``."""
    return 1.0 / np.dot(weights, weights)


def systematic_resample(weights: np.ndarray, u: float) -> np.ndarray:
    """Systematic resampling: indices ``(n,)`` int64 of the offspring.

    ``weights (n,)`` sum to 1; ``u`` in ``[0, 1)`` is the single uniform offset.
    Offspring ``k`` takes the first ``j`` with ``cumsum(w)[j] > (u + k) / n`` (the
    same rule as filterpy's ``systematic_resample``), so particle ``j`` has between
    ``floor(n w_j)`` and ``ceil(n w_j)`` offspring; ``n - 1`` when rounding leaves
    ``cumsum(w)[-1]`` below a position.

    Computed in linear time instead of by ``n`` binary searches: with
    ``m_j = #{k : (u + k) / n < cumsum(w)[j]}`` (the first position not below
    ``cumsum(w)[j]``), offspring ``k`` is ``#{j : m_j <= k}``. ``m_j`` is guessed as
    ``ceil(n cumsum(w)[j] - u)`` and corrected by comparing the same floating-point
    positions and sums, so the result equals ``searchsorted(cumsum(w), positions,
    side="right")`` exactly.
    """
    kernels = compiled_kernels()
    if kernels is not None:  # the same indices by one merge
        return kernels.systematic_indices(np.ascontiguousarray(weights, dtype=np.float64),
                                          float(u))
    n = weights.shape[0]
    # padded[k + 1] = positions[k] = (u + k) / n, padded[0] = -inf, padded[n + 1] = inf
    padded = np.empty(n + 2)
    padded[0], padded[-1] = -np.inf, np.inf
    positions = padded[1:-1]
    positions[:] = np.arange(n)
    positions += u
    positions /= n
    cumulative = np.cumsum(weights)
    if n == 0 or not np.isfinite(cumulative[-1]):
        idx = np.searchsorted(cumulative, positions, side="right")
        return np.minimum(idx, max(n - 1, 0), out=idx)
    guess = cumulative * n
    guess -= u
    np.ceil(guess, out=guess)
    np.clip(guess, 0.0, float(n), out=guess)
    m = guess.astype(np.int64)
    below, above = np.empty(n, dtype=bool), np.empty(n, dtype=bool)
    for _ in range(8):  # the guess is off by a rounding step at most; positions increase
        # positions[m - 1] >= cumulative: m too large; positions[m] < cumulative: too small
        np.greater_equal(np.take(padded, m), cumulative, out=below)
        m += 1
        np.less(np.take(padded, m), cumulative, out=above)
        m -= 1
        if not (below.any() or above.any()):
            break
        m -= below
        m += above
    else:  # not expected; the binary search is always right
        idx = np.searchsorted(cumulative, positions, side="right")
        return np.minimum(idx, n - 1, out=idx)
    # m <= n; offspring at m = n would be index n, clipped to n - 1 like before
    idx = np.bincount(m, minlength=n + 1)[:n]
    np.cumsum(idx, out=idx)
    np.minimum(idx, n - 1, out=idx)
    return idx
