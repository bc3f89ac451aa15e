"""How particles move: the bootstrap predict (deaths, dynamics, boundary, births), the
independent-partition exchange and the resample-move sweeps.

Each function changes a :class:`.state.ParticleState` in place and draws from the
``rng`` it is given, in a fixed order (the order is part of the results).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from types import ModuleType

import numpy as np
from scipy.special import logsumexp

from ...scenarios.model import TrackingModel
from .estimation import align_slots
from .likelihood import GridLikelihood, SuperpositionLikelihood
from .resampling import systematic_resample
from .state import ParticleState, flat_cells, fold

DEFAULT_BIRTH_RATE = 0.02  # per particle and step, used when the model has no births
DEFAULT_DEATH_PROBABILITY = 0.01  # per target and step, used when the model has p_s = 1


@dataclass
class BootstrapPrior:
    """The kinematic prior of one run, resolved at ``reset`` from the model and the
    tracker's parameters.

    ``F (4, 4)`` the transition, ``L (4, 4)`` with ``L L^T = Q`` (plus a 1e-15 jitter that
    admits ``Q = 0``), ``FL = [F | L] (4, 8)``; ``p_death`` per target and step,
    ``p_birth = 1 - exp(-birth_rate)`` per particle and step, ``birth_velocity_std``;
    ``reflect`` the boundary rule (else ``die``). ``p_death`` and ``p_birth`` may be
    changed between steps (tests do, e.g. to kill every target); ``F``, ``L`` and ``FL``
    are read only.
    """

    F: np.ndarray
    L: np.ndarray
    FL: np.ndarray
    p_death: float
    p_birth: float
    birth_velocity_std: float
    reflect: bool

    @classmethod
    def from_model(cls, model: TrackingModel, birth_rate: float | None,
                   death_probability: float | None) -> BootstrapPrior:
        """``birth_rate`` None: the model's rate, or ``DEFAULT_BIRTH_RATE`` when it has
        none; ``death_probability`` None: ``1 - p_s``, or ``DEFAULT_DEATH_PROBABILITY``
        when that is 0."""
        bd, dyn = model.birth_death, model.dynamics
        # L L^T = Q; the jitter admits Q = 0 (static targets)
        L = np.linalg.cholesky(dyn.Q + 1e-15 * np.eye(4))
        L[np.abs(L) < 1e-300] = 0.0
        rate = birth_rate
        if rate is None:
            rate = bd.birth_rate if bd.birth_rate > 0 else DEFAULT_BIRTH_RATE
        death = death_probability
        if death is None:
            death = 1.0 - bd.survival_probability
            death = death if death > 0 else DEFAULT_DEATH_PROBABILITY
        return cls(F=dyn.F, L=L, FL=np.hstack([dyn.F, L]), p_death=float(death),
                   p_birth=1.0 - math.exp(-float(rate)),
                   birth_velocity_std=float(bd.birth_velocity_std),
                   reflect=bd.boundary == "reflect")


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


# ------------------------------------------------------------------ bootstrap
def bootstrap_predict(state: ParticleState, prior: BootstrapPrior, rng: np.random.Generator,
                      kernels: ModuleType | None = None, keep_parents: bool = False) -> None:
    """One draw from the kinematic prior for every particle, in the simulator's order:

    1. deaths: every slot dies with ``p_death`` (empty slots "dying" changes nothing);
    2. ``x <- F x + L e`` (:meth:`.state.ParticleState.propagate`), then the boundary
       rule; with ``kernels`` (:mod:`.kernels`) the cells and counts come from the same
       pass, and the births below patch them;
    3. births: a particle gains one target, into its first free slot, with
       ``p_birth`` (none when full): uniform in the workspace, velocity
       ``N(0, birth_velocity_std^2)`` per axis.

    ``keep_parents`` (resample-move): ``state.parents`` becomes the buffer the move
    read (``x_{k-1}`` and this step's ``e``) and ``state.movable`` the slots that
    survived step 2 (not the births). Leaves ``raw_cells`` and ``counts`` current.
    """
    N, T = state.n, state.t_max
    valid = state.valid
    dead = bernoulli_indices(rng, T * N, prior.p_death)
    if dead.size:
        valid[np.divmod(dead, N)] = False
    state.propagate(prior.FL, rng)
    X = state.X
    if kernels is not None:
        counts = state.boundary_cells_counts(kernels, prior.reflect)
    else:
        state.apply_boundary(prior.reflect)
    if keep_parents:
        state.parents = state.other_buffer()
        np.copyto(state.movable, valid)
    born = bernoulli_indices(rng, N, prior.p_birth)
    if born.size:
        born = born[valid[:, born].sum(axis=0) < T]
        slot = np.argmin(valid[:, born], axis=0)
        n, bv = born.size, prior.birth_velocity_std
        X[0, slot, born] = rng.uniform(0.0, state.width, n)
        X[2, slot, born] = rng.uniform(0.0, state.height, n)
        X[1, slot, born] = rng.normal(0.0, bv, n)
        X[3, slot, born] = rng.normal(0.0, bv, n)
        valid[slot, born] = True
        if kernels is not None:
            state.raw_cells[slot, born] = flat_cells(X[0, slot, born], X[2, slot, born],
                                                     state.grid)
            counts[born] += 1
    if kernels is None:
        counts = state.count_targets()
        state.update_cells()
    state.counts = counts


# ------------------------------------------------------- independent partitions
def ip_exchange(state: ParticleState, reference: np.ndarray | None, lik: GridLikelihood,
                rng: np.random.Generator) -> np.ndarray:
    """Kreucher's independent-partition proposal (package docstring); returns the
    weight correction ``sum_p log l_p(x_{p,i}) - log c_p`` ``(N,)`` to subtract from
    the log-likelihood.

    The slots are first aligned to ``reference`` (the predicted last estimate,
    :func:`.estimation.align_slots`); then, for every slot ``p`` aligned to a reference
    target, the particles holding slot ``p`` (the pool) exchange their slot-``p``
    targets by systematic resampling with probabilities ``b_j ∝ w_j l_p(x_{p,j})``, to
    a random permutation of the pool. Only the aligned slots are partitions: a free
    slot would otherwise be pulled onto the strongest detection of another target.
    """
    if reference is not None and len(reference):
        state.X, state.valid, state.raw_cells = align_slots(state.X, state.valid,
                                                            state.raw_cells, reference)
    corr = np.zeros(state.n)
    if reference is None:
        return corr
    X, valid, cells, logw = state.X, state.valid, state.raw_cells, state.logw
    lp = lik.single_target(cells)  # (T, N); empty slots: junk, never read
    for p in range(min(len(reference), state.t_max)):
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
    return corr


# ------------------------------------------------------------- resample-move
def resample_move(state: ParticleState, prior: BootstrapPrior,
                  lik: GridLikelihood | SuperpositionLikelihood, ll: np.ndarray,
                  rng: np.random.Generator, sweeps: int, scale: float) -> tuple[int, int]:
    """``sweeps`` Metropolis-Hastings sweeps on equally weighted particles (package
    docstring, "Resample-move"); ``ll (N,)`` the log-likelihoods of the current states.
    Returns ``(proposed, accepted)`` counts of particle proposals.

    Each sweep proposes ``e' = e + scale * eps`` (``eps ~ N(0, I)``) for every movable
    slot (``state.movable``) of every particle at once, keeping the parent ``x_{k-1}``
    (``state.parents``), rebuilds ``x' = b(F x_{k-1} + L e')`` (``b`` the boundary rule;
    with ``die`` a proposal that takes a movable target outside is rejected) and accepts
    per particle with probability ``min(1, p(z | X') N(e'; 0, I) / (p(z | X) N(e; 0, I)))``.

    Why the weights stay equal: the bootstrap step is a deterministic map
    ``X_k = g(X_{k-1}, u)`` of its draws ``u`` (deaths, noises, births), so resampled
    particles are equally weighted draws of ``pi(X_{k-1}, u) ∝ p(X_{k-1} | Z_{k-1}) p(u)
    p(z_k | g(X_{k-1}, u))``. A sweep is a Metropolis-within-Gibbs step on ``pi``'s
    conditional of the survivors' ``e`` given the rest, ``∝ N(e; 0, I) p(z_k | X(e))``;
    written on ``e`` the ratio is exact also for reflected targets (a folded Gaussian in
    ``x``), and rejecting exits under ``die`` keeps ``pi`` conditioned on which slots are
    alive. Keeping ``pi`` invariant keeps its marginal ``p(X_k | Z_k)``. The IP exchange
    does not keep each slot's parent, so the move is bootstrap only.
    """
    T, N = state.t_max, state.n
    movable = state.movable
    active = movable.any(axis=0)  # particles with something to move
    n_active = int(np.count_nonzero(active))
    proposed = accepted = 0
    if n_active == 0:
        return proposed, accepted
    parents = state.parents
    X, e = state.X, parents[4:]
    prop = np.empty_like(parents)
    for _ in range(int(sweeps)):
        prop[:4] = parents[:4]
        rng.standard_normal(out=prop[4:])
        prop[4:] *= scale
        prop[4:] += e
        np.copyto(prop[4:], e, where=~movable)  # births and empty slots stay put
        Xn = (prior.FL @ prop.reshape(8, T * N)).reshape(4, T, N)
        np.copyto(Xn, X, where=~movable)
        ok = np.ones(N, dtype=bool)
        for p_row, v_row, length in ((0, 1, state.width), (2, 3, state.height)):
            if prior.reflect:
                Xn[p_row], Xn[v_row] = fold(Xn[p_row], Xn[v_row], length)
            else:
                # leaving would kill the target: the kernel keeps every slot's
                # alive/dead state, so such a proposal is rejected
                out = (Xn[p_row] < 0.0) | (Xn[p_row] >= length)
                ok &= ~(out & movable).any(axis=0)
                np.clip(Xn[p_row], 0.0, np.nextafter(length, 0.0), out=Xn[p_row])
        ll_new = lik(Xn, state.valid, flat_cells(Xn[0], Xn[2], state.grid))
        de = np.einsum("dtn,dtn->n", prop[4:], prop[4:]) - np.einsum("dtn,dtn->n", e, e)
        log_a = ll_new - ll - 0.5 * de
        acc = active & ok & (np.log(rng.random(N)) < log_a)
        np.copyto(X, Xn, where=acc)
        np.copyto(e, prop[4:], where=acc)
        ll = np.where(acc, ll_new, ll)
        proposed += n_active
        accepted += int(np.count_nonzero(acc))
    return proposed, accepted
