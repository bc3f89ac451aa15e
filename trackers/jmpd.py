"""JMPD: the joint multitarget probability density particle filter.

Kreucher, Kastella and Hero, "Multitarget tracking using the joint multitarget
probability density", IEEE TAES 41(4), 2005. Each particle ``i`` holds a target
count ``T_i <= t_max`` and ``T_i`` target states ``[px, vx, py, vy]``, so the
count is part of the state and no measurement-to-target association is needed.

Storage (never one Python object per particle, never an ``(N, n_cells)`` array):

* states ``X`` of shape ``(N, t_max, 4)``. It is kept internally as a
  component-major buffer ``(4, t_max, N)`` so that every per-step operation runs
  over contiguous memory; :attr:`JMPDTracker.states` is the ``(N, t_max, 4)`` view.
* a validity mask ``(N, t_max)`` (slot ``s`` of particle ``i`` holds a target iff
  the mask is set; valid slots need not be packed first, which lets the
  independent-partition proposal keep slot ``s`` aligned with estimated target
  ``s``), counts ``T_i`` ``(N,)`` and normalised log-weights ``(N,)``.

Speed: the step is numpy over whole arrays; three per-slot passes (boundary rule +
cell + count, the likelihood's dense path, the systematic resampling indices) run as
numba kernels when numba is installed (:mod:`trackers.kernels`,
:func:`compiled_kernels`). Each kernel repeats its numpy form's floating-point
operations in the same order, so the numbers are the same with or without numba.

Bootstrap step (the kinematic prior as proposal), in the simulator's order:

1. death: every target dies with ``death_probability`` (default ``1 - p_s`` of the
   model, at least ``DEFAULT_DEATH_PROBABILITY``);
2. dynamics ``x <- F x + L e``, ``e ~ N(0, I)``, ``L L^T = Q`` (one draw of
   ``N * t_max * 4`` normal variates), then the model's boundary rule (reflect, or
   die when leaving the workspace);
3. birth: with probability ``1 - exp(-birth_rate)`` a particle with ``T_i < t_max``
   gains one target, uniform in the workspace with velocity
   ``N(0, birth_velocity_std^2)`` per axis (at most one birth per particle per
   step; ``birth_rate`` defaults to the model's rate, at least
   ``DEFAULT_BIRTH_RATE``). The floors keep the filter able to find targets and
   drop ghosts when the model says the count never changes; pass 0 to switch
   them off.
4. weight: ``log w_i += log p(z | X_i)``. Grid sensor (DESIGN.md): only looked-at
   cells that the particle occupies contribute, ``sum_looks log l_c(T_ic)`` with
   ``T_ic`` the particle's number of targets in cell ``c`` and
   ``l_c(T) = p(z | T) / p(z | 0)``; repeated looks at a cell add their logs.
   Superposition sensor: ``z ~ N(mean_i H x_i, R)``, and ``z ~ N(0, R)`` for a
   particle with no target (the simulator's convention).
5. normalise with ``logsumexp``; systematic resampling when the effective sample
   size ``1 / sum w_i^2`` drops below ``resample_threshold * N``.

Independent-partition proposal (``proposal="ip"``, Kreucher et al. Table III):
after the kinematic proposal the slots of every particle are aligned to the last
estimate (greedy nearest assignment); then for every slot ``p`` separately, the
particles that hold slot ``p`` (the pool) exchange their slot-``p`` targets by
systematic resampling with probabilities ``b_j ∝ w_j l_p(x_{p,j})``, where
``l_p`` is the likelihood of that target alone (``prod_looks l_c(1)`` over looks at
its cell). The bias of this proposal is corrected in the weight::

    w_i <- w_i * p(z | X_i) * prod_{valid p} c_p / l_p(x_{p,i}),
    c_p = sum_pool w_j l_p(x_{p,j}) / sum_pool w_j.

This is exact importance sampling for the factorised prior ``prod_p pi_p`` that
the method assumes (the pools' weighted marginals). The receivers of each slot
are a random permutation of the pool so that slots are drawn independently.
Deviations: only the slots aligned to an estimated target are partitions; new or
unmatched targets keep the kinematic proposal, because a free slot would otherwise
be pulled onto the strongest detection of another target (Kreucher's coupled
partitions case), which inflates the count. On the superposition sensor the
measurement couples all targets, so there is no single-target partition
likelihood; ``ip`` then weighs like the bootstrap. The IP proposal is exact only
for the factorised prior: coupled targets get approximate joint statistics.

Estimates: the count is the posterior mode of ``T`` (:attr:`count_mean` and
:attr:`count_probabilities` hold the mean and the distribution). The states are
weighted means of the partitions of the particles with ``T = mode``, after
aligning each particle's targets to a reference (the previous estimate predicted
with ``F`` when it has the same count, else the heaviest such particle), two
rounds of align-then-average (Kreucher's K-means over permutations). Alignment
minimises the summed squared position distance: exactly over all ``T!``
permutations for ``T <= 4``, greedily (closest pair first) above.

Measured limit of the bootstrap proposal (looks at all 144 cells every step,
OSPA c = 2, p = 2, mean over 100 steps): ``crossing`` 1.49 / 1.33 / 1.29 and
``default`` 1.46 / 1.30 / 0.78 at N = 2e3 / 1e4 / 1e5 (4, 4 and 2 seeds). Even with
every particle started on the true targets and the count known (no births or
deaths) it loses targets: ``default`` OSPA 0.11 over steps 0-9, 0.4-1.0 over 10-29
and 1.0-1.5 afterwards with 3 targets (1 target: 0.34 throughout), N = 2000; 0.83
overall at N = 2e4. The joint weight selects on every target at once, so each
target's own particle diversity collapses to a few lineages; with q = 5e-4 (1e-5
on ``crossing``) the velocity noise cannot restore it, and a lineage with the
wrong velocity leaves the true cell and the target becomes a ghost. Lower death
or birth floors (0, 1e-3; 5e-3) and other resampling thresholds (0.02-1) do not
help (measured); the independent-partition proposal does (``default`` 0.82 at
N = 2000).

Resample-move (opt-in, ``move_steps > 0``, bootstrap proposal only; Gilks and
Berzuini 2001). The bootstrap step is a deterministic map of auxiliary draws:
``X_k = g(X_{k-1}, u)`` with ``u`` the deaths, the noises ``e ~ N(0, I)`` of every
slot, the births and their states. After weighting and resampling, the particles
are equally weighted draws (approximately) of the joint

    pi(X_{k-1}, u) ∝ p(X_{k-1} | Z_{k-1}) p(u) p(z_k | g(X_{k-1}, u)).

Each MH sweep changes only the noises ``e`` of the slots that survived the
predict (not this step's births, not empty slots), keeping the parent
``X_{k-1}`` (stored: the buffer the move read holds ``x_{k-1}`` and ``e``; it is
gathered with the states at resampling) and the other draws. Its target is
``pi``'s conditional of ``e`` given the rest, ``∝ N(e; 0, I) p(z_k | X(e))`` with
``X(e) = b(F x_{k-1} + L e)`` (``b`` the boundary rule). The proposal
``e' = e + move_scale * eps``, ``eps ~ N(0, I)``, for every movable slot of a
particle at once, is symmetric; it moves the pre-boundary state by
``N(0, move_scale^2 Q)``, and the acceptance probability is

    min(1, p(z_k | X') N(e'; 0, I) / (p(z_k | X) N(e; 0, I))),

the brief's ``N(x; F x_{k-1}, Q)`` ratio written for the noise (the same when no
target crosses the boundary; written on ``e`` it is also exact for reflected
targets, whose density in ``x`` is a folded Gaussian). With the ``die`` boundary a
proposal that takes a movable target outside is rejected: the kernel then targets
``pi`` conditioned on which slots are alive, a pattern it never changes, and a
kernel that keeps every such conditional invariant keeps ``pi`` invariant.
Invariance of the conditional implies invariance of ``pi`` (a Metropolis-within-
Gibbs step), hence of its marginal ``p(X_k | Z_k)``; draws of a distribution moved
by a kernel that leaves it invariant are still draws of it, so the weights stay
equal (``1 / N``) and only the states change. One uniform per particle decides;
the likelihood of all proposals is one call of :func:`grid_log_likelihood` (or the
superposition likelihood). The IP proposal exchanges slots between particles and
does not keep each slot's parent, so the move is refused there.

What it can and cannot do: the kernel draws each copy of a resampled particle
afresh from ``p(x_k | x_{k-1}, z_k)``, whose spread is at most one step of
process noise ``Q``; copies that share a parent stay within that spread. It
restores the diversity one resampling removes at the current step, not the
diversity lost over earlier steps (that would need moves of ``x_{k-1}`` and
earlier, e.g. over a window of stored noises and looks). Measured (N = 2000, 100
steps, 20 seeds, paired by seed against the plain bootstrap, mean ± 95% t
half-width): OSPA differences with ``move_steps = 1 / 2`` are -0.02 ± 0.06 /
-0.03 ± 0.05 (``default``, looks at all cells), +0.02 ± 0.06 / +0.03 ± 0.05
(``default``, raster 24), -0.01 ± 0.04 / -0.01 ± 0.04 (``crossing``, all), +0.01 ±
0.04 / +0.01 ± 0.04 (``crossing``, raster 24); count errors likewise within noise
(all |diff| <= 0.16 with intervals of ±0.1-0.24 spanning 0). The IP proposal on the
same seeds: -0.54 ± 0.11, -0.20 ± 0.04, -0.16 ± 0.04, -0.18 ± 0.05. About 15-19% of
the proposals are accepted (all cells looked at); a sweep costs about one more
bootstrap step. So the move is kept opt-in: exact, but no measurable gain here.

Prior before step 0: ``T_i ~ Poisson(initial_count_mean)`` clipped to ``t_max``
(or exactly ``initial_count`` if given), positions uniform over the workspace,
velocities ``N(0, birth_velocity_std^2)`` per axis.
"""

from __future__ import annotations

import itertools
import math
import os
from types import ModuleType
from typing import Literal

import numpy as np
from scipy.special import logsumexp

from ..scenarios.model import Looks, RayleighGridSensor, TrackingModel
from .base import Estimate, Tracker, register
from .cells import look_log_ratios

DEFAULT_BIRTH_RATE = 0.02  # per particle and step, used when the model has no births
DEFAULT_DEATH_PROBABILITY = 0.01  # per target and step, used when the model has p_s = 1
EXACT_ALIGN_MAX = 4  # enumerate all T! permutations up to this many targets


_KERNELS: ModuleType | None | bool = False  # False: not looked up yet


def compiled_kernels() -> ModuleType | None:
    """:mod:`trackers.kernels` (numba), imported on first use; None when numba is not
    installed or ``MTTBENCH_NO_NUMBA`` is set (not ``0``). Results are the same either
    way: every kernel equals its numpy form bit for bit."""
    global _KERNELS
    if _KERNELS is False:
        if os.environ.get("MTTBENCH_NO_NUMBA", "") not in ("", "0"):
            _KERNELS = None
        else:
            try:
                from . import kernels
            except ImportError:
                _KERNELS = None
            else:
                _KERNELS = kernels
    return _KERNELS


# --------------------------------------------------------------------- kernels
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


def bernoulli_indices(rng: np.random.Generator, n: int, p: float) -> np.ndarray:
    """Sorted indices ``k < n`` of independent Bernoulli(``p``) successes.

    Drawn by geometric gaps between successes, so the cost is ``O(n p)`` draws
    instead of ``n`` uniforms (deaths and births are rare).
    """
    if n <= 0 or p <= 0.0:
        return np.zeros(0, dtype=np.int64)
    if p >= 1.0:
        return np.arange(n, dtype=np.int64)
    mean = n * p
    chunk = int(mean + 6.0 * math.sqrt(mean) + 16)
    pos = np.cumsum(rng.geometric(p, size=chunk)) - 1
    while pos[-1] < n:
        more = np.cumsum(rng.geometric(p, size=chunk)) + pos[-1]
        pos = np.concatenate([pos, more])
    return pos[pos < n]


def grid_log_likelihood_tables(sensor: RayleighGridSensor, look_cells: np.ndarray,
                               returns: np.ndarray, n_cells: int, t_max: int
                               ) -> tuple[np.ndarray, np.ndarray]:
    """Per-look tables for :func:`grid_log_likelihood`.

    Returns ``slot_of_cell (n_cells + 1,) int64`` (looked slot of each cell; the
    unlooked cells and the sentinel ``n_cells`` map to the zero row ``n_u``) and
    ``table (n_u + 1, t_max + 1)`` with ``table[s, t] = sum_{looks at cell s}
    log l(z, t)``; its last row is zero.
    """
    ucells, LL = look_log_ratios(sensor, np.asarray(look_cells, dtype=np.int64),
                                 np.asarray(returns, bool), t_max)
    n_u = ucells.shape[0]
    table = np.vstack([LL, np.zeros((1, t_max + 1))])  # the zero row of unlooked cells
    slot_of_cell = np.full(n_cells + 1, n_u, dtype=np.int64)
    slot_of_cell[ucells] = np.arange(n_u)
    return slot_of_cell, table


_NO_MASK = np.ones((1, 1), dtype=bool)  # the kernel's unread mask when there is none


def _ranks(c: np.ndarray) -> np.ndarray:
    """``rank[j, i] = 1 + #{k < j : c[k, i] == c[j, i]}`` for ``c (t_max, N)``."""
    t_max = c.shape[0]
    rank = np.ones(c.shape, dtype=np.int64)
    for j in range(1, t_max):
        for k in range(j):
            rank[j] += c[k] == c[j]
    return rank


def grid_log_likelihood(cells: np.ndarray, slot_of_cell: np.ndarray, table: np.ndarray,
                        valid: np.ndarray | None = None,
                        key_buffer: np.ndarray | None = None,
                        path: Literal["auto", "compiled", "dense", "sparse"] = "auto"
                        ) -> np.ndarray:
    """``log p(z | X_i) - log p(z | no target)`` for every particle, shape ``(N,)``.

    ``cells (N, t_max)`` (integers) are the targets' flat cells, with ``n_cells`` for an
    empty slot or a target outside the grid; tables from
    :func:`grid_log_likelihood_tables`. If ``valid (N, t_max)`` bool is given, the
    slots where it is False are empty whatever their cell (it may then be any index
    in ``[0, n_cells]``, or beyond it, which counts as unlooked). ``key_buffer``:
    optional int32 scratch ``(t_max, N)`` for the dense path (saves allocating it).
    ``path`` forces one computation (for tests). "auto": the dense path compiled
    (:func:`trackers.kernels.grid_log_likelihood_dense`) when :func:`compiled_kernels`
    has it, else dense or sparse chosen by cost.
    Equation (DESIGN.md)::

        log w_i = sum_{looked cells c} table[c, T_ic]

    computed without counting cells: the ``j``-th target (in slot order) found in
    cell ``c`` adds ``table[c, j] - table[c, j - 1]``, which telescopes to
    ``table[c, T_ic]`` because ``table[c, 0] = 0``. Each particle's terms are added
    in slot order, starting from 0 (both code paths below; results are identical).
    """
    c = cells.T  # (t_max, N); contiguous rows when the caller stores (t_max, N)
    v = None if valid is None else valid.T
    t_max, n = c.shape
    n_counts = table.shape[1]
    n_u = table.shape[0] - 1
    increments = np.zeros_like(table)
    increments[:, 1:] = np.diff(table, axis=1)
    looked = (slot_of_cell != n_u).view(np.uint8)
    kernels = compiled_kernels() if path in ("auto", "compiled") else None
    if path == "compiled" and kernels is None:
        raise RuntimeError("path='compiled' needs numba (trackers.kernels)")
    if path == "auto" and kernels is None:
        # choose on a sample of particles (the choice never changes the result); measured
        # crossover: the sparse path wins below about 5% of the slots looked at
        n_sample = min(n, 4096)  # contiguous, so cheap
        hit = np.take(looked, c[:, :n_sample], mode="clip")
        if v is not None:
            hit &= v[:, :n_sample].view(np.uint8)
        path = "dense" if 20 * int(np.count_nonzero(hit)) > hit.size else "sparse"
    if path != "sparse":
        # dense (particles gathered on looked cells): one gather per slot from the
        # per-cell table inc_cell[c, r] = increments[slot_of_cell[c], r], with the
        # key c * n_counts + r and r = 1 + #{k < j: same cell} (0 for an empty slot:
        # column 0 is zero); cells >= n_cells land in the zero sentinel row or are
        # clipped onto its last entry
        inc_cell = increments[slot_of_cell].ravel()
        # int32 keys when they fit (half the traffic of the rank compares)
        key_type = np.int32 if inc_cell.size < 2**30 else np.int64
        if key_buffer is not None and key_buffer.dtype == key_type:
            key = key_buffer
        else:
            key = np.empty((t_max, n), key_type)
        if kernels is not None and key_type is np.int32:  # the same steps, fused
            total = np.empty(n)
            kernels.grid_log_likelihood_dense(
                c, _NO_MASK if v is None else v, v is not None, inc_cell, n_counts, key,
                np.empty(n, dtype=np.int32), total)
            return total
        np.multiply(c, n_counts, out=key, dtype=key_type, casting="unsafe")
        if v is not None:
            key += v
        else:
            key += 1
        # before slot j gets its rank, key[k] == key[j] (k < j) says same cell and
        # same validity; going down j, the slots k < j are not ranked yet
        same = np.empty(n, dtype=bool)
        count = np.empty(n, dtype=np.uint8 if t_max < 256 else np.int64)
        for j in range(t_max - 1, 0, -1):
            count.fill(0)
            for k in range(j):
                np.equal(key[k], key[j], out=same)
                count += same
            if v is not None:
                count *= v[j]  # an empty slot keeps rank 0
            key[j] += count
        # log w = ((val[0] + val[1]) + val[2]) + ..., row by row (the order of
        # val.sum(axis=0)) so that each gathered row is added while in cache
        total = np.take(inc_cell, key[0], mode="clip")
        row = np.empty(n)
        for j in range(1, t_max):
            total += np.take(inc_cell, key[j], mode="clip", out=row)
        return total
    # sparse (few slots in looked cells): work on the looked slots alone, in
    # slot-major order (the order of the sums above)
    hit = np.take(looked, c, mode="clip")  # (t_max, N) uint8, C order
    if v is not None:
        hit &= v.view(np.uint8)
    j, i = np.divmod(np.flatnonzero(hit), n)
    cj = c[j, i]
    rank = np.ones(j.shape[0], dtype=np.int64)
    for k in range(t_max - 1):
        same = (c[k].take(i) == cj) & (k < j)
        if v is not None:
            same &= v[k].take(i)
        rank += same
    contrib = increments.ravel()[slot_of_cell[cj] * n_counts + rank]
    # an empty weighted bincount comes back as int64: force float
    return np.bincount(i, weights=contrib, minlength=n).astype(np.float64, copy=False)


def superposition_log_likelihood(X: np.ndarray, valid: np.ndarray, z: np.ndarray,
                                 H: np.ndarray, R: np.ndarray) -> np.ndarray:
    """``log N(z; mean_{valid j} H x_j, R)`` up to a constant, shape ``(N,)``.

    ``X (N, t_max, 4)``, ``valid (N, t_max)``; the mean is 0 for a particle with no
    target (the sensor then reports pure noise).
    """
    count = valid.sum(axis=1)
    hx = np.einsum("ntd,md->ntm", X, H)
    mean = (hx * valid[..., None]).sum(axis=1) / np.maximum(count, 1)[:, None]
    r = z[None, :] - mean
    return -0.5 * np.einsum("nm,nm->n", r, np.linalg.solve(R, r.T).T)


def cell_count_distribution_from(cells: np.ndarray, weights: np.ndarray, n_cells: int,
                                 n_counts: int) -> np.ndarray:
    """``P_c(t) = sum_i w_i [T_ic = t]`` (last column "t or more"), ``(n_cells, n_counts)``.

    ``cells (N, t_max)`` as in :func:`grid_log_likelihood`, ``weights (N,)``
    normalised. Only occupied (particle, cell) pairs are visited: the first target
    of each cell in a particle carries the particle's count in that cell; the mass
    not accounted for goes to ``t = 0``.
    """
    c = cells.T
    t_max = c.shape[0]
    first = _ranks(c) == 1
    n_in = np.zeros(c.shape, dtype=np.int64)
    for j in range(t_max):
        for k in range(t_max):
            n_in[j] += c[k] == c[j]
    keep = first & (c < n_cells)
    slot, particle = np.nonzero(keep)
    key = c[slot, particle] * n_counts + np.minimum(n_in[slot, particle], n_counts - 1)
    P = np.bincount(key, weights=weights[particle], minlength=n_cells * n_counts)
    P = P.reshape(n_cells, n_counts)
    P[:, 0] = np.maximum(1.0 - P[:, 1:].sum(axis=1), 0.0)
    P /= P.sum(axis=1, keepdims=True)
    return P


def _fold(pos: np.ndarray, vel: np.ndarray, length: float) -> tuple[np.ndarray, np.ndarray]:
    """Reflect positions into ``[0, length)``, flipping velocity on odd bounces."""
    folded = np.mod(pos, 2.0 * length)
    bounced = folded >= length
    pos = np.where(bounced, 2.0 * length - folded, folded)
    pos = np.minimum(pos, np.nextafter(length, 0.0))
    return pos, np.where(bounced, -vel, vel)


_PERMS: dict[int, np.ndarray] = {}


def _perms(n: int) -> np.ndarray:
    if n not in _PERMS:
        _PERMS[n] = np.array(list(itertools.permutations(range(n))), dtype=np.int64)
    return _PERMS[n]


def greedy_assignment(cost: np.ndarray) -> np.ndarray:
    """Greedy (closest pair first) assignment, vectorised over the leading axis.

    ``cost (n, a, b)`` with ``inf`` for forbidden pairs. Returns ``(n, b)`` int64:
    the row assigned to each column, ``-1`` where none is left.
    """
    cost = cost.copy()
    n, a, b = cost.shape
    out = np.full((n, b), -1, dtype=np.int64)
    rows = np.arange(n)
    for _ in range(min(a, b)):
        flat = cost.reshape(n, -1).argmin(axis=1)
        i, j = np.divmod(flat, b)
        ok = np.isfinite(cost[rows, i, j])
        out[rows[ok], j[ok]] = i[ok]
        cost[rows[ok], i[ok], :] = np.inf
        cost[rows[ok], :, j[ok]] = np.inf
    return out


def align_square(Y: np.ndarray, ref: np.ndarray) -> np.ndarray:
    """Reorder each particle's targets to match ``ref``.

    ``Y (n, R, 4)`` all valid, ``ref (R, 4)``; returns ``(n, R, 4)`` with row ``b``
    the target matched to ``ref[b]``, minimising ``sum_b |pos(Y[pi(b)]) - pos(ref_b)|^2``
    over permutations: exhaustively for ``R <= EXACT_ALIGN_MAX``, greedily above.
    """
    n, R, _ = Y.shape
    if R <= 1:
        return Y
    d = Y[:, :, None, [0, 2]] - ref[None, None, :, [0, 2]]
    cost = np.einsum("nabk,nabk->nab", d, d)  # (n, R targets, R refs)
    if R <= EXACT_ALIGN_MAX:
        perms = _perms(R)  # (P, R): perms[q, b] = target placed at ref b
        total = cost[:, perms, np.arange(R)].sum(axis=2)  # (n, P)
        order = perms[total.argmin(axis=1)]
    else:
        order = greedy_assignment(cost)
    return np.take_along_axis(Y, order[:, :, None], axis=1)


# --------------------------------------------------------------------- tracker
@register
class JMPDTracker(Tracker):
    """JMPD particle filter, bootstrap (kinematic prior) proposal by default.

    Parameters: ``n_particles`` N; ``t_max`` largest count a particle can hold;
    ``birth_rate`` (per particle and step, None: the model's rate or
    ``DEFAULT_BIRTH_RATE``); ``death_probability`` (per target and step, None:
    ``1 - p_s`` or ``DEFAULT_DEATH_PROBABILITY``); ``resample_threshold`` (resample
    when ESS < threshold * N); ``proposal`` "bootstrap" or "ip"; ``initial_count``
    (None: Poisson prior; an int: every particle starts with that many targets);
    ``move_steps`` Metropolis-Hastings sweeps after each resampling (0: none, the
    plain bootstrap; bootstrap proposal only) with proposal covariance
    ``move_scale^2 Q`` (module docstring, "Resample-move").
    """

    name = "jmpd"
    summary = "JMPD particle filter (Kreucher et al. 2005), bootstrap proposal"

    def __init__(self, n_particles: int = 2000, t_max: int = 5,
                 birth_rate: float | None = None, death_probability: float | None = None,
                 resample_threshold: float = 0.5,
                 proposal: Literal["bootstrap", "ip"] = "bootstrap",
                 initial_count: int | None = None, move_steps: int = 0,
                 move_scale: float = 1.0) -> None:
        self.n_particles = n_particles
        self.t_max = t_max
        self.birth_rate = birth_rate
        self.death_probability = death_probability
        self.resample_threshold = resample_threshold
        self.proposal = proposal
        self.initial_count = initial_count
        self.move_steps = move_steps
        self.move_scale = move_scale

    # ------------------------------------------------------------- views
    @property
    def states(self) -> np.ndarray:
        """Target states ``(N, t_max, 4)`` (a view; empty slots hold junk)."""
        return self._X.transpose(2, 1, 0)

    @property
    def mask(self) -> np.ndarray:
        """Slot validity ``(N, t_max)`` bool (a view)."""
        return self._valid.T

    @property
    def log_weights(self) -> np.ndarray:
        """Normalised log-weights ``(N,)``."""
        return self._logw

    # ------------------------------------------------------------- life cycle
    def reset(self, model: TrackingModel, rng: np.random.Generator) -> None:
        if self.proposal not in ("bootstrap", "ip"):
            raise ValueError(f"proposal must be 'bootstrap' or 'ip', got {self.proposal!r}")
        if int(self.n_particles) < 1 or int(self.t_max) < 1:
            raise ValueError("n_particles and t_max must be >= 1")
        if int(self.move_steps) < 0 or not float(self.move_scale) > 0.0:
            raise ValueError("move_steps must be >= 0 and move_scale > 0")
        if int(self.move_steps) > 0 and self.proposal != "bootstrap":
            raise ValueError("move_steps > 0 needs proposal='bootstrap' (the IP exchange "
                             "does not keep each slot's parent state)")
        N, T = int(self.n_particles), int(self.t_max)
        kernels = compiled_kernels()
        # whether predict runs the compiled boundary/cell pass (results are the same)
        self.uses_compiled_kernels = kernels is not None
        if kernels is not None:
            kernels.warm_up()  # compile (or load) them now, not in a timed step
        self._model, self._rng, self._N, self._T = model, rng, N, T
        bd, dyn = model.birth_death, model.dynamics
        self._grid = model.grid
        self._width, self._height = model.grid.extent
        self._n_cells = model.grid.n_cells
        self._F = dyn.F
        # L L^T = Q; the jitter admits Q = 0 (static targets)
        self._L = np.linalg.cholesky(dyn.Q + 1e-15 * np.eye(4))
        self._L[np.abs(self._L) < 1e-300] = 0.0
        rate = self.birth_rate
        if rate is None:
            rate = bd.birth_rate if bd.birth_rate > 0 else DEFAULT_BIRTH_RATE
        self._p_birth = 1.0 - math.exp(-float(rate))
        death = self.death_probability
        if death is None:
            death = 1.0 - bd.survival_probability
            death = death if death > 0 else DEFAULT_DEATH_PROBABILITY
        self._p_death = float(death)
        self._bv = float(bd.birth_velocity_std)

        # component-major state (4, T, N) and the step's standard normals, same shape
        # Two buffers (8, T, N): rows 0-3 the states, rows 4-7 the step's standard
        # normals, so that the move x <- F x + L e is one (4, 8) @ (8, T N) product
        # into the other buffer. Resampling also gathers into the other buffer; the
        # two then swap (no fresh 16 MB arrays per step).
        self._bufs = [np.empty((8, T, N)), np.empty((8, T, N))]
        self._X = self._bufs[0][:4]
        self._FL = np.hstack([dyn.F, self._L])
        self._valid = np.zeros((T, N), dtype=bool)
        self._valid_spare = np.empty((T, N), dtype=bool)
        # int32 cells (half the memory traffic of int64); int64 scratch for the keys
        self._cells_buf = np.empty((T, N), dtype=np.int32)
        self._col_buf = np.empty((T, N), dtype=np.int32)
        self._key_buf = np.empty((T, N), dtype=np.int32)
        self._flags = np.empty((T, N), dtype=bool)
        if self.initial_count is None:
            counts = np.minimum(rng.poisson(bd.initial_count_mean, size=N), T)
        else:
            counts = np.full(N, min(int(self.initial_count), T))
        self._valid[:] = np.arange(T)[:, None] < counts[None, :]
        X = self._X
        X[0] = rng.uniform(0.0, self._width, (T, N))
        X[2] = rng.uniform(0.0, self._height, (T, N))
        X[1] = rng.normal(0.0, self._bv, (T, N))
        X[3] = rng.normal(0.0, self._bv, (T, N))
        self._counts = counts.astype(np.int64)
        self._logw = np.full(N, -math.log(N))
        self._w = np.full(N, 1.0 / N)  # exp(self._logw), kept in step with it
        self._tmp = np.empty((T, N))
        # flat cell of every slot, valid or not (None: stale after a resampling)
        self._raw_cells: np.ndarray | None = None
        self._ref: np.ndarray | None = None
        self.count_mean = float(counts.mean())
        self.count_probabilities = np.bincount(counts, minlength=T + 1) / N
        self.n_resamples = 0
        # resample-move: where the current states' parents and noises live (None: no
        # predict since the last reset), the slots that may move, the current step's
        # likelihood inputs, and acceptance counters
        self._parents: np.ndarray | None = None
        self._movable = np.zeros((T, N), dtype=bool)
        self._lik: tuple | None = None
        self.move_proposed = 0
        self.move_accepted = 0
        self._update_cells()

    # ------------------------------------------------------------- predict
    def predict(self) -> None:
        rng, N, T = self._rng, self._N, self._T
        valid = self._valid
        # 1. deaths (Bernoulli per slot; empty slots "dying" changes nothing)
        dead = bernoulli_indices(rng, T * N, self._p_death)
        if dead.size:
            valid[np.divmod(dead, N)] = False
        # 2. x <- F x + L e, then the boundary rule; with the compiled kernel the
        # cells and counts come from the same pass (births patch them below)
        self._move()
        X = self._X
        fused = self.uses_compiled_kernels
        if fused:
            counts = np.empty(N, dtype=np.int64)
            cells = self._cells_buf
            grid, width, height = self._grid, self._width, self._height
            compiled_kernels().boundary_cells_counts(
                X[0], X[1], X[2], X[3], valid, width, height, np.nextafter(width, 0.0),
                np.nextafter(height, 0.0), grid.nx, grid.ny, 1.0 / grid.cell_size,
                grid.cell_size == 1.0, self._model.birth_death.boundary == "reflect",
                cells, counts)
        else:
            self._apply_boundary()
        if self.move_steps > 0:
            # the buffer the move read: rows 0-3 x_{k-1}, rows 4-7 this step's e; the
            # survivors (not the births below) may be moved after a resampling
            self._parents = self._other_buffer()
            np.copyto(self._movable, valid)
        # 3. births: at most one per particle, into its first free slot
        born = bernoulli_indices(rng, N, self._p_birth)
        if born.size:
            born = born[valid[:, born].sum(axis=0) < T]
            slot = np.argmin(valid[:, born], axis=0)
            n = born.size
            X[0, slot, born] = rng.uniform(0.0, self._width, n)
            X[2, slot, born] = rng.uniform(0.0, self._height, n)
            X[1, slot, born] = rng.normal(0.0, self._bv, n)
            X[3, slot, born] = rng.normal(0.0, self._bv, n)
            valid[slot, born] = True
            if fused:
                cells[slot, born] = self._cell_index(X[0, slot, born], X[2, slot, born])
                counts[born] += 1
        if fused:
            self._raw_cells = cells
        else:
            # valid.sum(axis=0) as row additions (a strided reduction is several times
            # slower)
            counts = valid[0].astype(np.int64)
            for row in valid[1:]:
                counts += row
            self._update_cells()
        self._counts = counts
        if self._ref is not None and len(self._ref):
            self._ref = self._ref @ self._F.T

    def _other_buffer(self) -> np.ndarray:
        """The buffer not holding the states (the target of the next move/gather)."""
        a, b = self._bufs
        if self._X.base is not a:
            if self._X.base is not b:  # replaced by a realignment: copy it home
                a[:4] = self._X
                self._X = a[:4]
                return b
            return a
        return b

    def _move(self) -> None:
        """``x <- F x + L e`` for every slot as one matrix product.

        ``e`` are ``4 T N`` standard normals from one ``standard_normal`` call, in
        rows 4-7 of the buffer holding ``x``; ``[F | L] (4, 8)`` times that buffer
        seen as ``(8, T N)`` goes into the other buffer's state rows.
        """
        out = self._other_buffer()
        src = self._X.base
        T, N = self._T, self._N
        self._rng.standard_normal(out=src[4:])
        np.matmul(self._FL, src.reshape(8, T * N), out=out[:4].reshape(4, T * N))
        self._X = out[:4]

    def _apply_boundary(self) -> None:
        """Reflect (or kill) the slots whose position left ``[0, length)``, every slot.

        The candidates come from one unsigned comparison of the float bits per row:
        for ``x >= 0`` the bits increase with ``x``, and a negative ``x`` has the sign
        bit set, so ``bits(x) >= bits(length)`` holds for every ``x`` outside (and
        also for -0.0 and NaN); the exact test then runs on the few candidates.
        """
        X, valid, flags = self._X, self._valid, self._flags
        for p_row, v_row, length in ((0, 1, self._width), (2, 3, self._height)):
            pos = X[p_row]
            np.greater_equal(pos.view(np.uint64), np.float64(length).view(np.uint64),
                             out=flags)
            out = np.flatnonzero(flags)
            if out.size == 0:
                continue
            at = np.divmod(out, pos.shape[1])
            p = pos[at]
            keep = (p < 0.0) | (p >= length)
            if not keep.all():
                at = (at[0][keep], at[1][keep])
                p = p[keep]
            if self._model.birth_death.boundary == "reflect":
                pos[at], X[v_row][at] = _fold(p, X[v_row][at], length)
            else:
                valid[at] = False
                # park dead slots inside so they do not leave again by themselves
                pos[at] = 0.5 * length

    def _update_cells(self) -> None:
        """Flat cell ``floor(py / s) nx + floor(px / s)`` of every slot, valid or not,
        ``(t_max, N)`` int32 (``s`` the cell size; empty slots hold positions inside
        the workspace too, so their cells are in range and the likelihood masks them).

        Computed as ``trunc(py * (1 / s)) nx + trunc(px * (1 / s))``; positions are
        inside the workspace, so the truncating cast is the floor. With ``s = 1`` the
        products are skipped (``x * 1.0 == x`` exactly); otherwise the indices are
        clamped to the grid, because a position one ulp below the edge can round up
        to ``nx`` (``ny``) in the product. :func:`trackers.kernels.boundary_cells_counts`
        is the compiled form.
        """
        X, tmp = self._X, self._tmp
        cells, col = self._cells_buf, self._col_buf
        grid = self._grid
        if grid.cell_size == 1.0:
            np.copyto(cells, X[2], casting="unsafe")
            np.copyto(col, X[0], casting="unsafe")
        else:
            inv = 1.0 / grid.cell_size
            np.multiply(X[2], inv, out=tmp)
            np.copyto(cells, tmp, casting="unsafe")
            np.minimum(cells, grid.ny - 1, out=cells)
            np.multiply(X[0], inv, out=tmp)
            np.copyto(col, tmp, casting="unsafe")
            np.minimum(col, grid.nx - 1, out=col)
        cells *= grid.nx
        cells += col
        self._raw_cells = cells

    def _cell_index(self, px: np.ndarray, py: np.ndarray) -> np.ndarray:
        """Flat int32 cells of positions inside the workspace, by the rule of
        :meth:`_update_cells` (for a few slots: births, resample-move proposals)."""
        grid = self._grid
        if grid.cell_size == 1.0:
            col, row = px.astype(np.int32), py.astype(np.int32)
        else:
            inv = 1.0 / grid.cell_size
            col = np.minimum((px * inv).astype(np.int32), grid.nx - 1)
            row = np.minimum((py * inv).astype(np.int32), grid.ny - 1)
        row *= grid.nx
        row += col
        return row

    @property
    def _cells(self) -> np.ndarray | None:
        """Flat cells ``(t_max, N)`` int64 with ``n_cells`` for empty slots (a new array)."""
        if self._raw_cells is None:
            return None
        return np.where(self._valid, self._raw_cells, self._n_cells).astype(np.int64)

    # ------------------------------------------------------------- P_c(t)
    def cell_count_distribution(self) -> np.ndarray:
        return cell_count_distribution_from(self._cells.T, self._w, self._n_cells, self._T + 1)

    # ------------------------------------------------------------- update
    def update(self, looks: Looks) -> None:
        sensor = self._model.sensor
        if isinstance(sensor, RayleighGridSensor):
            if len(looks) == 0:
                return
            slot_of_cell, table = grid_log_likelihood_tables(
                sensor, looks.cells, looks.returns, self._n_cells, self._T)
            self._lik = (slot_of_cell, table)
            if self.proposal == "ip":
                self._ip_partitions(slot_of_cell, table)
            ll = grid_log_likelihood(self._raw_cells.T, slot_of_cell, table, self._valid.T,
                                     key_buffer=self._key_buf)
        else:
            if looks.z is None:
                return
            ll = superposition_log_likelihood(self.states, self.mask, np.asarray(looks.z),
                                              sensor.H, sensor.R)
            self._lik = (np.asarray(looks.z), sensor.H, sensor.R)
        if self.proposal == "ip" and isinstance(sensor, RayleighGridSensor):
            ll -= self._ip_correction
        logw, w = self._logw, self._w
        logw += ll
        # normalise: w = exp(logw - max) / sum, logw -= max + log(sum) (= logsumexp)
        top = logw.max()
        np.subtract(logw, top, out=w)
        np.exp(w, out=w)
        total = w.sum()
        w /= total
        logw -= top + math.log(total)
        self._maybe_resample(ll)

    def _maybe_resample(self, ll: np.ndarray) -> None:
        """Resample when the ESS is low; ``ll (N,)`` the current states' log-likelihoods
        (used by the resample-move step)."""
        w = self._w
        ess = 1.0 / np.dot(w, w)
        if ess >= self.resample_threshold * self._N:
            return
        idx = systematic_resample(w, self._rng.random())
        move = self.move_steps > 0 and self._parents is not None
        if move:
            # before the states' gather below overwrites the buffer the parents sit in
            self._parents = np.take(self._parents, idx, axis=2)
            self._movable = self._movable[:, idx]
        # one gather per array into the spare buffer, then swap; np.take keeps C order
        # (fancy indexing on the last axis would not) and mode="clip" stops it from
        # buffering the output (idx is in range by construction)
        X, V = self._other_buffer()[:4], self._valid_spare
        np.take(self._X, idx, axis=2, out=X, mode="clip")
        self._gather_valid(idx, V)
        self._X = X
        self._valid_spare, self._valid = self._valid, V
        self._raw_cells = None  # stale until the next predict recomputes it
        self._counts = self._counts[idx]
        self._logw.fill(-math.log(self._N))
        w.fill(1.0 / self._N)
        self.n_resamples += 1
        if move:
            self._resample_move(ll[idx])

    def _gather_valid(self, idx: np.ndarray, out: np.ndarray) -> None:
        """``out[:, k] = valid[:, idx[k]]``: up to 8 slots go as the bits of one byte
        per particle (one gather of N bytes instead of T N)."""
        valid, T = self._valid, self._T
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

    def _log_likelihood(self, X: np.ndarray, cells: np.ndarray) -> np.ndarray:
        """This step's ``log p(z | X_i)`` (up to a constant) of states ``X (4, T, N)``
        with flat cells ``cells (T, N)`` (``n_cells`` for empty slots), shape ``(N,)``."""
        if isinstance(self._model.sensor, RayleighGridSensor):
            slot_of_cell, table = self._lik
            return grid_log_likelihood(cells.T, slot_of_cell, table)
        z, H, R = self._lik
        return superposition_log_likelihood(X.transpose(2, 1, 0), self._valid.T, z, H, R)

    def _resample_move(self, ll: np.ndarray) -> None:
        """``move_steps`` Metropolis-Hastings sweeps on the resampled particles (module
        docstring, "Resample-move"); ``ll (N,)`` the log-likelihoods of the current states.

        Each sweep proposes ``e' = e + move_scale * eps`` (``eps ~ N(0, I)``) for every
        movable slot of every particle at once, rebuilds ``x' = b(F x_{k-1} + L e')``
        (``b`` the boundary rule) and accepts per particle with probability
        ``min(1, p(z | X') N(e'; 0, I) / (p(z | X) N(e; 0, I)))``.
        """
        rng, T, N = self._rng, self._T, self._N
        movable = self._movable
        active = movable.any(axis=0)  # particles with something to move
        n_active = int(np.count_nonzero(active))
        if n_active == 0:
            return
        parents = self._parents  # (8, T, N): x_{k-1} and e, gathered with the states
        X, e = self._X, parents[4:]
        n_cells = self._n_cells
        reflect = self._model.birth_death.boundary == "reflect"
        prop = np.empty_like(parents)
        for _ in range(int(self.move_steps)):
            prop[:4] = parents[:4]
            rng.standard_normal(out=prop[4:])
            prop[4:] *= self.move_scale
            prop[4:] += e
            np.copyto(prop[4:], e, where=~movable)  # births and empty slots stay put
            Xn = (self._FL @ prop.reshape(8, T * N)).reshape(4, T, N)
            np.copyto(Xn, X, where=~movable)
            ok = np.ones(N, dtype=bool)
            for p_row, v_row, length in ((0, 1, self._width), (2, 3, self._height)):
                if reflect:
                    Xn[p_row], Xn[v_row] = _fold(Xn[p_row], Xn[v_row], length)
                else:
                    # leaving would kill the target: the kernel keeps every slot's
                    # alive/dead state, so such a proposal is rejected
                    out = (Xn[p_row] < 0.0) | (Xn[p_row] >= length)
                    ok &= ~(out & movable).any(axis=0)
                    np.clip(Xn[p_row], 0.0, np.nextafter(length, 0.0), out=Xn[p_row])
            # same cell rule as _update_cells: positions are inside, truncation is floor
            cells = self._cell_index(Xn[0], Xn[2]).astype(np.int64)
            cells[~self._valid] = n_cells
            ll_new = self._log_likelihood(Xn, cells)
            de = np.einsum("dtn,dtn->n", prop[4:], prop[4:]) - np.einsum("dtn,dtn->n", e, e)
            log_a = ll_new - ll - 0.5 * de
            acc = active & ok & (np.log(rng.random(N)) < log_a)
            np.copyto(X, Xn, where=acc)
            np.copyto(e, prop[4:], where=acc)
            ll = np.where(acc, ll_new, ll)
            self.move_proposed += n_active
            self.move_accepted += int(np.count_nonzero(acc))

    @property
    def move_acceptance(self) -> float:
        """Fraction of accepted resample-move proposals so far (NaN before any)."""
        if self.move_proposed == 0:
            return math.nan
        return self.move_accepted / self.move_proposed

    def _align_to_reference(self) -> None:
        """Permute every particle's slots so that slot ``b`` holds its target nearest
        (greedy) to reference target ``b``; unmatched targets follow, then holes."""
        ref = self._ref
        if ref is None or len(ref) == 0:
            return
        T, N = self._T, self._N
        R = min(len(ref), T)
        X, valid = self._X, self._valid
        dx = X[0][:, :, None] - ref[None, None, :R, 0]  # (T, N, R)
        dy = X[2][:, :, None] - ref[None, None, :R, 2]
        cost = dx * dx + dy * dy
        cost[~valid] = np.inf
        assign = greedy_assignment(cost.transpose(1, 0, 2))  # (N, R): old slot per ref
        matched = assign >= 0
        rows = np.arange(N)
        is_matched = np.zeros((N, T), dtype=bool)  # by old slot
        is_matched[rows[:, None].repeat(R, 1)[matched], assign[matched]] = True
        # old slots not matched: leftover targets first, then empty slots (stable)
        key = np.where(is_matched, 2, np.where(valid.T, 0, 1))
        rest_old = np.argsort(key, axis=1, kind="stable")
        used_new = np.zeros((N, T), dtype=bool)
        used_new[:, :R] = matched
        free_new = np.argsort(used_new, axis=1, kind="stable")  # free positions first
        # Leftover targets exist only when every reference is matched, so the free
        # positions are then exactly R..T-1 and the leftovers come right after the
        # matched slots; the pairs beyond the free ones are overwritten below.
        perm = np.empty((N, T), dtype=np.int64)  # perm[i, new slot] = old slot
        np.put_along_axis(perm, free_new, rest_old, axis=1)
        perm[:, :R] = np.where(matched, assign, perm[:, :R])
        pT = perm.T
        self._X = np.take_along_axis(X, pT[None], axis=1)
        self._valid = np.take_along_axis(valid, pT, axis=0)
        self._raw_cells = np.take_along_axis(self._raw_cells, pT, axis=0)

    def _ip_partitions(self, slot_of_cell: np.ndarray, table: np.ndarray) -> None:
        """Kreucher's independent-partition resampling (module docstring)."""
        self._align_to_reference()
        rng, N = self._rng, self._N
        corr = np.zeros(N)
        self._ip_correction = corr
        if self._ref is None:
            return
        X, valid, cells, logw = self._X, self._valid, self._raw_cells, self._logw
        # (T, N) log l of each target alone (empty slots: junk, never read)
        lp = table[:, 1][np.take(slot_of_cell, cells, mode="clip")]
        # only slots aligned to an estimated target are partitions; the others
        # (new or unmatched targets) keep the kinematic proposal, else every free
        # slot would be pulled onto the strongest detection (coupled partitions)
        for p in range(min(len(self._ref), self._T)):
            pool = np.flatnonzero(valid[p])
            if pool.size == 0:
                continue
            logb = logw[pool] + lp[p, pool]
            lse_b = logsumexp(logb)
            log_c = lse_b - logsumexp(logw[pool])
            donors = pool[systematic_resample(np.exp(logb - lse_b), rng.random())]
            donors = donors[rng.permutation(pool.size)]
            X[:, p, pool] = X[:, p, donors]
            cells[p, pool] = cells[p, donors]
            corr[pool] += lp[p, donors] - log_c
        self._ip_correction = corr

    # ------------------------------------------------------------- estimate
    def estimate(self) -> Estimate:
        w = self._w
        T = self._T
        pT = np.bincount(self._counts, weights=w, minlength=T + 1)
        pT /= pT.sum()
        self.count_probabilities = pT
        self.count_mean = float(np.dot(np.arange(T + 1), pT))
        mode = int(np.argmax(pT))
        if mode == 0:
            self._ref = np.zeros((0, 4))
            return Estimate(0, np.zeros((0, 4)), np.zeros((0, 4, 4)))
        sel = np.flatnonzero(self._counts == mode)
        ws = w[sel] / w[sel].sum()
        order = np.argsort(~self._valid[:, sel], axis=0, kind="stable")[:mode]  # (mode, n)
        Xs = self._X[:, :, sel]  # (4, T, n)
        Y = np.take_along_axis(Xs, order[None], axis=1).transpose(2, 1, 0)  # (n, mode, 4)
        if self._ref is not None and len(self._ref) == mode:
            ref = self._ref
        else:
            ref = Y[np.argmax(ws)]
        for _ in range(2):  # align, average, realign (K-means over permutations)
            Ya = align_square(Y, ref)
            ref = np.einsum("n,ntd->td", ws, Ya)
        d = Ya - ref[None]
        cov = np.einsum("n,ntd,nte->tde", ws, d, d)
        self._ref = ref.copy()
        return Estimate(mode, ref.astype(np.float64), cov)


@register
class JMPDIPTracker(JMPDTracker):
    """JMPD with Kreucher's independent-partition proposal (``proposal="ip"``)."""

    name = "jmpd-ip"
    summary = "JMPD particle filter (Kreucher et al. 2005), independent-partition proposal"

    def __init__(self, n_particles: int = 2000, t_max: int = 5,
                 birth_rate: float | None = None, death_probability: float | None = None,
                 resample_threshold: float = 0.5,
                 proposal: Literal["bootstrap", "ip"] = "ip",
                 initial_count: int | None = None, move_steps: int = 0,
                 move_scale: float = 1.0) -> None:
        super().__init__(n_particles=n_particles, t_max=t_max, birth_rate=birth_rate,
                         death_probability=death_probability,
                         resample_threshold=resample_threshold, proposal=proposal,
                         initial_count=initial_count, move_steps=move_steps,
                         move_scale=move_scale)
