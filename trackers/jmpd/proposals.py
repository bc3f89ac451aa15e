"""How particles move: the bootstrap predict (deaths, dynamics, boundary, births) and the
independent-partition exchange.

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
from .likelihood import GridLikelihood
from .resampling import systematic_resample
from .state import ParticleState, flat_cells

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
                      kernels: ModuleType | None = None) -> None:
    """One draw from the kinematic prior for every particle, in the simulator's order:

    1. deaths: every slot dies with ``p_death`` (empty slots "dying" changes nothing);
    2. ``x <- F x + L e`` (:meth:`.state.ParticleState.propagate`), then the boundary
       rule; with ``kernels`` (:mod:`.kernels`) the cells and counts come from the same
       pass, and the births below patch them;
    3. births: a particle gains one target, into its first free slot, with
       ``p_birth`` (none when full): uniform in the workspace, velocity
       ``N(0, birth_velocity_std^2)`` per axis.

    Leaves ``raw_cells`` and ``counts`` current.
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
