"""JMPD: the joint multitarget probability density particle filter.

Kreucher, Kastella and Hero, "Multitarget tracking using the joint multitarget
probability density", IEEE TAES 41(4), 2005. Each particle ``i`` holds a count
``T_i <= t_max`` and ``T_i`` states ``[px, vx, py, vy]`` (arrays ``(N, t_max, 4)`` plus a
validity mask, :mod:`.state`): the count is part of the state, no association is
needed. Prior: ``T_i ~ Poisson(initial_count_mean)`` clipped to ``t_max`` (or
``initial_count``), positions uniform, velocities ``N(0, birth_velocity_std^2)``. Step,
in the simulator's order (:mod:`.proposals`, :mod:`.likelihood`, :mod:`.resampling`):

1. death: each target dies with ``p_death`` (default ``1 - p_s``, at least 0.01);
2. ``x <- F x + L e``, ``e ~ N(0, I)``, ``L L^T = Q``; the boundary rule (reflect or die);
3. birth: with ``p_birth = 1 - exp(-birth_rate)`` (default the model's rate, at least
   0.02) a particle with ``T_i < t_max`` gains one target, drawn as in the prior;
4. ``log w_i += log p(z | X_i)``: grid sensor ``sum_looks log l_c(T_ic)``, ``T_ic`` the
   particle's targets in looked cell ``c``, ``l_c(T) = p(z | T) / p(z | 0)``;
   superposition sensor ``z ~ N(mean_i H x_i, R)`` (``N(0, R)`` without targets);
5. normalise; systematic resampling when ``1 / sum w_i^2 < resample_threshold * N``.

Departures: the death/birth floors let the filter drop ghosts and find targets when the
model's count never changes (0 switches them off); at most one birth per step.

Independent partitions (``proposal="ip"``, Kreucher et al. Table III): slots aligned to
the last estimate (greedy); per aligned slot ``p`` the particles holding it exchange
their slot-``p`` targets by systematic resampling with ``b_j ∝ w_j l_p(x_{p,j})``,
``l_p = prod_looks l_c(1)`` at the target's cell, and the weight is corrected::

    w_i <- w_i p(z | X_i) prod_{valid p} c_p / l_p(x_{p,i}),
    c_p = sum_pool w_j l_p(x_{p,j}) / sum_pool w_j,

exact for the factorised prior ``prod_p pi_p`` the method assumes. Departures: new
(unaligned) targets keep the kinematic proposal (a free slot would be pulled onto
another target's detection, inflating the count); on the superposition sensor ``ip``
weighs like the bootstrap (no single-target likelihood).

Estimates (:mod:`.estimation`): count = posterior mode of ``T``; states = weighted
means over the particles with ``T = mode``, targets aligned by K-means over
permutations. Three per-slot passes run as numba kernels when numba is installed
(:mod:`.kernels`), bit-identical to the numpy forms; so does ``jmpd-ap``'s
per-particle work (:mod:`.ap_kernels`: every number a computation reads is the numpy
form's, bit for bit).

Cost: ``O(N t_max^2 + looks)`` per step and ``O(N t_max + looks)`` memory, whatever the
grid's size. The look tables are keyed by the looked cells and ``P_c(t)`` is a
:class:`~..cells.CellCounts` with rows for the cells the particles occupy and the
no-target row elsewhere (:mod:`.sparse`); grids of more than ``2^31 - 1`` cells keep
int64 cells (docs/jmpd.md, section 6).

The bootstrap loses targets even with a hundredfold more particles or started on the
truth; the IP proposal holds them (docs/jmpd.md, with the switches retired and the
measurements that retired them).

Layout: one package. ``jmpd``/``jmpd-ip`` (:mod:`.tracker`, :mod:`.proposals`,
:class:`.state.ParticleState`, ``(4, t_max, N)`` buffers) and ``jmpd-ap`` (:mod:`.ap`,
:mod:`.partitions`, :mod:`.cell_proposal`, ``(N, T, 2)`` positions with RB velocities)
share no state and import nothing from each other, but share the kernels: look tables
and likelihood (:mod:`.likelihood`, :mod:`.sparse`), ``P_c(t)`` from slots, resampling
and the wall fold; two packages would need a third for those, so they stay one.
"""

from .ap import JMPDAPTracker
from .backend import compiled_kernels, use_backend
from .estimation import (
    EXACT_ALIGN_MAX,
    align_slots,
    align_square,
    cell_count_distribution_from,
    estimate_targets,
    greedy_assignment,
)
from .likelihood import (
    grid_log_likelihood,
    grid_log_likelihood_tables,
    step_likelihood,
    superposition_log_likelihood,
)
from .proposals import (
    DEFAULT_BIRTH_RATE,
    DEFAULT_DEATH_PROBABILITY,
    BootstrapPrior,
    bernoulli_indices,
)
from .resampling import effective_sample_size, systematic_resample
from .state import ParticleState, apply_boundary, flat_cells, fold, gather_mask
from .tracker import JMPDIPTracker, JMPDTracker

__all__ = [
    "DEFAULT_BIRTH_RATE", "DEFAULT_DEATH_PROBABILITY", "EXACT_ALIGN_MAX", "BootstrapPrior",
    "JMPDAPTracker", "JMPDIPTracker", "JMPDTracker", "ParticleState", "align_slots", "align_square",
    "apply_boundary", "bernoulli_indices", "cell_count_distribution_from",
    "compiled_kernels", "effective_sample_size", "estimate_targets", "flat_cells", "fold",
    "gather_mask", "greedy_assignment", "grid_log_likelihood", "grid_log_likelihood_tables",
    "step_likelihood", "superposition_log_likelihood", "systematic_resample", "use_backend",
]
