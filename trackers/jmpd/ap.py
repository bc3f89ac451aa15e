"""``jmpd-ap``: the JMPD particle filter at the strength its authors report.

Kreucher, Kastella and Hero (IEEE TAES 2005, Signal Processing 2005), Kreucher,
Morelande, Kastella and Hero (IEEE Aerospace 2005), Morelande, Kreucher and Kastella
(IEEE TSP 2007); the brief with sources is docs/literature/jmpd.md, the measurements
docs/jmpd-ap.md. A particle holds ``T_max`` slots (partitions); slot ``t`` means the
same target in every particle. Per slot: the position ``rho`` (a sample) and a Gaussian
velocity ``N(m, s)`` per axis given the position's past (Rao-Blackwellised, TSP 2007
Sec. IV-A; the measurements depend on positions only). With the model's per-axis noise
``[[q11, q12], [q12, q22]]`` the predictive and the velocity update are, per axis::

    rho_k ~ N(rho + tau m, Psi),  Psi = tau^2 s + q11
    m <- m + K (rho_k - rho - tau m),  K = (tau s + q12) / Psi
    s <- s + q22 - (tau s + q12)^2 / Psi

One update (every step; ``Lambda_c(n)`` is the product over this step's looks at cell
``c`` of ``p(z | n) / p(z | 0)``, 1 for unlooked cells):

1. **Partitions** (AP, TAES Table V with Morelande's closure): slot centres are the
   predicted positions averaged over the particles holding the slot; slots closer than
   ``cluster_distance`` cells, or whose holdings depend on each other (two slots
   holding one target in different particles: :func:`.partitions.coupled_slots`), are
   one cluster (:func:`.partitions.cluster_slots`). A cluster of one slot is sampled
   alone (IP), a larger one jointly.
2. **Persistent targets**: every particle draws its clusters' targets one after another
   from the locally optimal proposal given those already placed: slot ``t`` dies with
   weight ``beta + (1 - beta) m_out`` (removal, or leaving the workspace under ``die``)
   or moves to cell ``c`` of a window around its predictive mean with weight
   ``(1 - beta) gamma_c Lambda_c(n_c + 1) / Lambda_c(n_c)`` (``gamma_c`` the
   predictive's mass in ``c``, ``n_c`` the cluster's targets already in ``c``); inside
   the cell the position is the predictive truncated to it (TSP eqs. 26-31, the mixture
   of truncated Gaussians, drawn sequentially instead of over all cell combinations so
   that the cost is linear in the cluster size). ``Z_t`` is the sum of the weights;
   ``prod_t Z_t`` is the draw's importance weight (exactly the predictive likelihood
   for a single target).
3. **Recombination** (IP, TAES Table III; Morelande's per-cluster first stage): receiver
   ``i`` takes cluster ``l``'s draw from particle ``a`` picked ``∝ prod_{t in l} Z_t(a)``
   (systematic, shuffled), independently per cluster; the particle's undetected initial
   targets (6) come with its largest cluster's ancestor.
4. **Births** at detected cells (``Lambda_c(1) > 1``) not occupied by the particle:
   with ``pi_c`` the probability of an undetected target in ``c`` (below), born with
   ``b_c = pi_c Lambda_c(1) / (1 - pi_c + pi_c Lambda_c(1))``, uniform in the cell,
   velocity from the model's birth law, cell after cell, each birth from the undetected
   initial targets lowering ``r_i`` for the next cells. All particles born in ``c`` this
   step share a slot (TSP p. 1600): the slot whose centre is in ``c`` where the particle
   has it empty, else a fresh slot.
5. **Weights** (TSP eq. 58, whose correction multiplies; the Aerospace and dissertation
   tables divide by it)::

       log w_i = log p(z | X_i) - sum_l log pi_l(z | X_il)     (clusters sharing a cell)
                 + sum_{c born} log(pi_c / b_c) + sum_{c not born} log((1-pi_c)/(1-b_c))
                 + n log(1 - q (1 - s))      (undetected initial targets missed: 6)

   (a particle with more targets than a fixed-count model allows gets weight 0), then
   systematic resampling every step, K-means sorting of the slots within clusters
   (:func:`.partitions.sort_slots`) and merging of slots that hold one target
   (:func:`.partitions.merge_slots`).
6. **Undetected targets** (the existence grid of Aerospace 2005 eqs. 22-23, in a
   Poisson-binomial form): the initial ones, ``r_i`` per particle (``n0`` less the
   declared targets it starts with, ``r_i <- p_s r_i`` per step from step 1, less
   ``pi_init / pi`` at each of its births, and lowered by the looks that missed them
   (:meth:`JMPDAPTracker._undetected_misses`, which also weights the particle): a target
   it let die stays dead; where targets cannot die (``p_s = 1``, reflecting walls),
   ``max(n0 - T_i, 0)``), each in cell ``c`` with probability ``v_c / sum v`` (``v <- v
   l(0)`` per look, ``l(0) = (1 - p_d) / (1 - p_f)``); and arrivals from step 1 with
   intensity ``u_c`` (``u <- p_s u + alpha_c`` per step,
   ``u <- u l(0)`` per look), kept lazily (value and step of each cell's last
   look), so a step costs the looks, not the cells. ``pi_c = 1 - (1 - v_c / sum v)^r_i
   exp(-u_c)``. The cells never looked at share one value of ``v`` and ``u``
   (:class:`.sparse.CellTable`); ``P_c(t)`` (:meth:`JMPDAPTracker.cell_count_distribution`)
   has rows for the cells the particles occupy and the cells looked at so far, one
   default row for all others.

Cost per step: ``O(N T W + looks)`` (``W`` the proposal window's cells) and nothing per
cell of the grid: the look tables are keyed by the looked cells (:mod:`.sparse`), the
undetected values by the cells looked at so far (docs/jmpd-ap.md, "Grid size").

Estimate: count ``E[T]``, the held slots' mean count plus the undetected targets'
expected number; states: the ``round(mean held slots)`` slots of largest existence mass,
each averaged over the particles holding it (positions, velocity means).

Rates: the model's (``alpha_c`` = birth rate / cells, ``beta = 1 - p_s``), no floors.
Kreucher's removal 0.005 (:data:`KREUCHER_REMOVAL`) is an option
(``removal_probability``): it lets a track the filter lost be dropped and the target be
found again (a dropped target returns to the undetected initial targets), but with a
fixed count it also trades a missed target for a false alarm (docs/jmpd-ap.md).

Departures from the papers: recombination by the draws' weights (draw first, then
pick, as a bootstrap filter per cluster) rather than by a first-stage estimate;
births only at detected cells (an undetected target is
instantiated at its first detection; births elsewhere have posterior probability below
``alpha_c`` and are left to the intensity); no birth in a cell the particle occupies;
under ``reflect`` a predicted mean beyond a wall is folded back with its velocity mean
mirrored, and the predictive is truncated to the workspace (renormalised, not folded);
the predictive is truncated to the cells within 4 sd of the mean on each axis (at most
``2 max_window + 1``); the undetected intensity ignores motion (as Kreucher's grid);
the position noise variance per step is at least ``position_noise_floor`` (1e-3
cell^2, 0.03 cell of sd; Kreucher's Q has 2e-3): with the tiny noise of near-straight
paths, resampling leaves particles that share one velocity and a track a cell off that
can never move back (docs/jmpd-ap.md).
Grid sensor only.
"""

from __future__ import annotations

import math
from typing import ClassVar

import numpy as np

from ...scenarios.model import Looks, RayleighGridSensor, TrackingModel
from ..base import (
    LOOKED_CELL_BYTES,
    LOOKED_CELL_S,
    Estimate,
    ResourceTerms,
    Tracker,
    param_number,
    register,
)
from ..cells import CellCounts
from ..params import Budget, Param, Search
from .backend import compiled_ap_kernels
from .cell_proposal import axis_window, truncated_normal
from .estimation import cell_count_distribution_from
from .likelihood import grid_log_likelihood, grid_log_likelihood_tables
from .partitions import SORT_MAX, cluster_slots, coupled_slots, merge_slots, sort_slots
from .resampling import effective_sample_size, systematic_resample
from .sparse import CellTable
from .state import fold
from .tracker import JMPD_LOOK_BYTES, JMPD_SLOT_T_S

#: Kreucher's removal probability per target and step (docs/literature/jmpd.md Sec.
#: 2.6), for ``removal_probability`` when the model has none and a user wants one
KREUCHER_REMOVAL = 0.005
#: bytes per jmpd-ap slot: 138 B (N = 5000 on ``large``, t_max 54) and 253 B (``scale``,
#: N = 500, t_max 2,004) measured (:meth:`JMPDAPTracker.resource_terms`)
AP_SLOT_BYTES = 384
#: per jmpd-ap slot and step: 0.35 s for 1e6 slots (``scale``), ~25 ms for 27,000
AP_SLOT_S = 1e-6


def _with_undetected(P: np.ndarray, pis: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
    """Rows ``P (m, n_counts)`` of count distributions with one more target with
    probability ``pi = 1 - (1 - pi_init)(1 - pi_arr)`` per row (``pis`` as returned by
    ``_undetected_probability`` for one particle: shapes ``(1, m)``); the last column
    keeps "that many or more"."""
    pi_init, pi_arr = pis
    pi = (1.0 - (1.0 - pi_init[0]) * (1.0 - pi_arr[0]))[:, None]
    shifted = np.zeros_like(P)
    shifted[:, 1:] = P[:, :-1]
    shifted[:, -1] += P[:, -1]
    return P * (1.0 - pi) + shifted * pi


def _auto_slots(model: TrackingModel) -> int:
    """Slots for the model: twice the expected peak count plus 4 (ghost and birth slots
    live a few steps before they are freed)."""
    bd = model.birth_death
    n0 = bd.initial_count_mean
    p_s, b = bd.survival_probability, bd.birth_rate
    peak = max(n0, b / (1.0 - p_s)) if p_s < 1.0 else n0 + 100.0 * b
    return int(2 * math.ceil(peak) + 4)


@register
class JMPDAPTracker(Tracker):
    """JMPD with measurement-directed births and deaths, adaptive partitions, partition
    sorting and Rao-Blackwellised velocities (the module docstring).

    After ``reset``: ``count_mean`` (``E[T]`` of the last estimate), ``ess`` (effective
    sample size before the last resampling), ``n_clusters`` and ``largest_cluster`` of
    the last update, ``undetected_mass`` (the expected number of undetected targets),
    ``uses_compiled_kernels`` (the per-particle passes run as the numba kernels of
    :mod:`.ap_kernels`, decided at ``reset``; the same numbers either way).
    """

    name = "jmpd-ap"
    summary = ("JMPD at literature strength: measurement-directed births/deaths, adaptive "
               "partitions, sorting (Kreucher, Morelande et al.)")
    parameters: ClassVar[dict[str, Param]] = {
        "n_particles": Param(int, 1, doc="particles N"),
        "t_max": Param(int, 1, allow_none=True, none="twice the expected peak count + 4",
                       doc="slots per particle"),
        # tuning (mttbench tune): cluster and merge distances and the position noise floor
        # about their defaults (docs/jmpd-ap.md). arrival_rate and removal_probability
        # replace model quantities (to run Kreucher's floors), so they are not tuned: a
        # tuned file must not set a model quantity. n_particles is a cost, not tuned;
        # sort_iterations and max_window trade time for accuracy
        "arrival_rate": Param(float, 0, allow_none=True, none="the model's birth rate",
                              doc="expected arrivals per step over the workspace, in place "
                                  "of the model's (Kreucher: 0.02); not tuned"),
        "removal_probability": Param(float, 0, 1, allow_none=True, none="1 - p_s",
                                     doc="per target and step, in place of the model's "
                                         "1 - p_s (Kreucher: 0.005); not tuned"),
        "cluster_distance": Param(float, 0, doc="AP threshold, in cells (Morelande: 2.5)",
                                  search=Search(1.0, 4.0)),
        "max_window": Param(int, 1, doc="the proposal window spans at most 2 max_window + 1 "
                                        "cells per axis"),
        "sort_iterations": Param(int, 0, doc="K-means sweeps per step"),
        "merge_distance": Param(float, 0, doc="slots whose means are closer (cells) merge",
                                search=Search(0.1, 1.5)),
        "undetected_in_policy": Param(bool, doc="add the undetected intensity to P_c(t)"),
        "init_fraction": Param(float, 0, 1,
                               doc="fraction of particles that start on the model's declared "
                                   "initial states (Kreucher SP 2005: 0.1); 0: from nothing"),
        "position_noise_floor": Param(float, 0,
                                      doc="least position noise variance per step, in "
                                          "cells^2 (the model's q11 when larger); 0: the "
                                          "model's",
                                      search=Search(1e-4, 1e-2, log=True)),
    }
    budget: ClassVar[dict[str, Budget]] = {
        "n_particles": Budget(100, 16000, doc="particles N, about 6 us each per step: "
                                              "16000 is 0.1-0.3 s per step on one core"),
    }

    def __init__(self, n_particles: int = 500, t_max: int | None = None,
                 arrival_rate: float | None = None,
                 removal_probability: float | None = None,
                 cluster_distance: float = 2.5, max_window: int = 6,
                 sort_iterations: int = 2, merge_distance: float = 0.5,
                 undetected_in_policy: bool = True, init_fraction: float = 0.0,
                 position_noise_floor: float = 1e-3) -> None:
        self.n_particles = n_particles
        self.t_max = t_max
        self.arrival_rate = arrival_rate
        self.removal_probability = removal_probability
        self.cluster_distance = cluster_distance
        self.max_window = max_window
        self.sort_iterations = sort_iterations
        self.merge_distance = merge_distance
        self.undetected_in_policy = undetected_in_policy
        self.init_fraction = init_fraction
        self.position_noise_floor = position_noise_floor

    # ------------------------------------------------------------- life cycle
    def unsupported_reason(self, model: TrackingModel) -> str | None:
        if not isinstance(model.sensor, RayleighGridSensor):
            return "grid sensor only (the proposal is built from per-cell likelihoods)"
        Q = model.dynamics.Q
        if np.any(Q[0:2, 2:4] != 0.0):
            return "process noise couples the x and y axes (the proposal factorises per axis)"
        if self.t_max is not None and _auto_slots(model) - 4 > 2 * int(self.t_max):
            return (f"t_max = {self.t_max} is less than half the expected peak count; "
                    f"use t_max >= {(_auto_slots(model) - 4) // 2}")
        return None

    def reset(self, model: TrackingModel, rng: np.random.Generator) -> None:
        self.validate_params(self.get_params())
        self._model, self._rng = model, rng
        self.uses_compiled_kernels = compiled_ap_kernels() is not None
        # compiled path: per-step arrays reuse these buffers (a fresh large array costs
        # its page faults every step), and the slot arrays' spares take gathers
        self._scratch_bufs: dict[str, np.ndarray] = {}
        self._spares: dict[str, np.ndarray] = {}
        if self._kernels is not None:
            self._kernels.warm_up()  # compile (or load) them now, not in a timed step
        grid, bd, dyn = model.grid, model.birth_death, model.dynamics
        N = int(self.n_particles)
        T = int(self.t_max) if self.t_max is not None else _auto_slots(model)
        self._N, self._T = N, T
        Q = dyn.Q
        self._tau = float(dyn.tau)
        # the position noise, at least the floor: with a model's tiny q11 the particles'
        # predictives are far narrower than a cell, and a track that resampling left a
        # cell off can never move back (docs/jmpd-ap.md)
        floor = float(self.position_noise_floor) * model.grid.cell_size ** 2
        self._q11 = np.maximum(np.array([Q[0, 0], Q[2, 2]]), floor)
        self._q12 = np.array([Q[0, 1], Q[2, 3]])
        self._q22 = np.array([Q[1, 1], Q[3, 3]])
        self._reflect = bd.boundary == "reflect"
        J = grid.n_cells
        self._arrivals = float(bd.birth_rate if self.arrival_rate is None
                               else self.arrival_rate)
        self._alpha = self._arrivals / J  # per cell and step
        self._beta = float(1.0 - bd.survival_probability if self.removal_probability is None
                           else self.removal_probability)
        self._p_s = float(bd.survival_probability)
        # deaths: by survival, or by leaving the workspace under ``die``
        self._can_die = self._p_s < 1.0 or not self._reflect
        fixed = not self._can_die and self._arrivals == 0.0
        self._fixed_count = int(round(bd.initial_count_mean)) if fixed else None
        self._birth_var = float(bd.birth_velocity_std) ** 2
        # slots: positions, velocity means and variances per axis, validity
        self.pos = np.zeros((N, T, 2))
        self.vel = np.zeros((N, T, 2))
        self.vvar = np.ones((N, T, 2))
        self.valid = np.zeros((N, T), dtype=bool)
        declared = np.asarray(bd.initial_states, dtype=float).reshape(-1, 4)
        n_start = int(round(float(self.init_fraction) * N)) if len(declared) <= T else 0
        if n_start and len(declared):
            # Kreucher's start: these particles hold the declared initial states, one
            # step back so that the first predict brings them to step 0; the velocity is
            # known to the model's velocity noise
            back = declared @ np.linalg.inv(dyn.F).T
            self.pos[:n_start, :len(declared)] = back[:, [0, 2]]
            self.vel[:n_start, :len(declared)] = back[:, [1, 3]]
            self.vvar[:n_start, :len(declared)] = self._q22
            self.valid[:n_start, :len(declared)] = True
        # undetected targets (module docstring, 6): the initial ones (r_i below, or n0 less
        # the particle's targets where none can die), spread over the cells in proportion
        # to v (v <- v l(0) per look); and the arrivals' intensity u, kept lazily as the value at
        # each cell's last look and its step; all three in a CellTable (one default value
        # per column, and the values of the cells looked at so far)
        self._n0 = float(bd.initial_count_mean)
        # per particle, the expected initial targets alive and not yet found (module
        # docstring, 6): the declared start's particles hold theirs already
        self._r = np.full(N, self._n0)
        self._r[:n_start] -= len(declared)
        # (arrivals start at step 1: the simulator's step 0 holds the initial targets only)
        self._undetected = CellTable(J, u=(0.0, np.float64), u_step=(0, np.int64),
                                     v=(1.0 / J, np.float64))
        self._v_total = 1.0
        self._k = -1
        self._pred: tuple[np.ndarray, np.ndarray] | None = None
        self.count_mean = 0.0
        self.ess = float(N)
        self.n_clusters = 0
        self.largest_cluster = 0

    # ------------------------------------------------------------- helpers
    def _undetected_values(self, cells: np.ndarray | None
                           ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(u, u_step, v)`` of the given cells; ``cells=None``: of a cell never looked
        at (the default values, as arrays of one)."""
        table = self._undetected
        if cells is None:
            return tuple(np.array([table.defaults[k]]) for k in ("u", "u_step", "v"))
        return tuple(table.get(k, cells) for k in ("u", "u_step", "v"))

    def _arrival_intensity(self, u: np.ndarray, u_step: np.ndarray) -> np.ndarray:
        """Intensity of undetected arrivals at the current step (after this step's
        arrivals, before its looks) of cells whose value was ``u`` after their last look
        at step ``u_step``: ``u <- p_s u + alpha`` per step since."""
        gap = self._k - u_step
        p_s, a = self._p_s, self._alpha
        if p_s == 1.0:
            return u + a * gap
        keep = p_s ** gap
        return u * keep + a * (1.0 - keep) / (1.0 - p_s)

    def _remaining(self) -> np.ndarray:
        """Initial targets alive and not found, per particle. Targets that cannot die
        (``p_s = 1``, reflecting walls): ``max(n0 - T_i, 0)``, so a track removed by
        ``removal_probability`` returns its target to the undetected ones. Else the
        particle's own count ``r_i`` (``r_i <- p_s r_i`` per step, less the chance that
        each of its births was an initial target): a target the particle let die stays
        dead, as in the model."""
        if not self._can_die:
            return np.maximum(self._n0 - self._held(), 0.0)
        return np.maximum(self._r, 0.0)

    def _held(self) -> np.ndarray:
        """The slots each particle holds, ``(N,)`` int64."""
        if self._kernels is not None:
            return self._kernels.held_per_particle(self.valid)
        return self.valid.sum(axis=1)

    def _undetected_probability(self, cells: np.ndarray | None, remaining: np.ndarray
                                ) -> tuple[np.ndarray, np.ndarray]:
        """``(pi_initial, pi_arrival)`` of an undetected target in each cell (``None``: a
        cell never looked at, as one cell), for particles with ``remaining`` initial
        targets not found; shapes ``remaining.shape + cells.shape``."""
        log_keep, pi_arr = self._undetected_cell_terms(cells)
        pi_init = -np.expm1(remaining[..., None] * log_keep)
        return pi_init, np.broadcast_to(pi_arr, pi_init.shape)

    def _undetected_cell_terms(self, cells: np.ndarray | None
                               ) -> tuple[np.ndarray, np.ndarray]:
        """Per cell (``None``: a cell never looked at), the parts of
        :meth:`_undetected_probability` that no particle changes: ``log(1 - share)``
        (an initial target's chance to be elsewhere, ``share`` below 1) and the arrivals'
        ``pi_arrival``."""
        u, u_step, v = self._undetected_values(cells)
        log_keep = np.log1p(-np.minimum(v / self._v_total, 1.0 - 1e-12))
        return log_keep, -np.expm1(-self._arrival_intensity(u, u_step))

    def _miss_factor(self, n_looks: np.ndarray) -> np.ndarray:
        """``l(0)^n = ((1 - p_d) / (1 - p_f))^n`` (the sensor's likelihood ratio of a miss,
        as a power: the stored references' numbers): a target in a cell missed by each of
        its ``n`` looks, against an empty cell."""
        sensor = self._model.sensor
        return ((1.0 - sensor.p_d) / (1.0 - sensor.p_f)) ** n_looks

    def _undetected_misses(self, cells: np.ndarray, n_looks: np.ndarray,
                           detected: np.ndarray) -> np.ndarray:
        """The undetected initial targets' part of each particle's weight, for this
        step's looks at ``cells`` (sorted unique) ``n_looks`` times each, ``detected`` the
        cells with ``Lambda_c(1) > 1`` (where births were proposed); in place, their
        posterior count. Each of the particle's ``r_i`` left after the births (as ``n =
        ceil(r_i)`` targets that exist with ``q = r_i / n`` each, exact for one) is in a
        cell ``c`` outside the detected ones with probability ``v_c / sum' v`` and missed
        there with ``l(0)^n_c``: the looks leave the share ``s = sum'_c v_c l(0)^n_c /
        sum' v`` unseen (``sum'`` over the cells not detected), the weight is ``(1 - q (1
        - s))^n``, and ``q <- q s / (1 - q (1 - s))`` when targets can die (else the
        count is known and only the weight applies). For one target this with the birth
        step's prior ``1 - pi_d`` is the exact ``sum_{c not detected} v_c Lambda_c(1) /
        sum v``. Log weights ``(N,)``."""
        v = self._undetected.get("v", cells)
        rest = self._v_total - float(v[detected].sum())
        if rest <= 0.0:
            return np.zeros(self._N)
        missed = ~detected
        seen = float((v[missed] * (1.0 - self._miss_factor(n_looks[missed]))).sum()) / rest
        seen = min(max(seen, 0.0), 1.0)
        remaining = self._remaining()
        n = np.ceil(remaining)
        q = remaining / np.maximum(n, 1.0)
        keep = 1.0 - q * seen
        if self._can_die:  # q (1 - s) / keep; a target seen for sure (keep = 0) is gone
            self._r = n * np.divide(q - q * seen, keep, out=np.zeros_like(q),
                                    where=keep > 0.0)
        with np.errstate(divide="ignore"):
            return n * np.log(keep)

    @property
    def undetected_mass(self) -> float:
        """Expected number of undetected targets now: the remaining initial targets
        (mean over the particles) plus the arrival intensity summed over the cells, the
        cells never looked at counted together (``O(cells looked at so far)``)."""
        remaining = self._remaining().mean()
        table = self._undetected
        own = self._arrival_intensity(table.columns["u"], table.columns["u_step"]).sum()
        rest = self._arrival_intensity(*self._undetected_values(None)[:2])[0] * table.n_default
        return float(remaining + own + rest)

    def predict(self) -> None:
        self._k += 1
        if self._k > 0:  # step 0 is the prior itself: no deaths before it
            self._r *= self._p_s
        if self._kernels is not None:  # the same in one compiled pass, with sqrt(psi)
            shape = self.pos.shape
            rhohat, psi = self._scratch("rhohat", shape), self._scratch("psi", shape)
            self._pred_sd = self._scratch("sd", shape)
            self._kernels.predict(self.pos, self.vel, self.vvar, self._tau, self._tau ** 2,
                                  self._q11, np.asarray(self._model.grid.extent, float),
                                  self._reflect, rhohat, psi, self._pred_sd)
            self._pred = (rhohat, psi)
            self._kp_cells = None
            return
        rhohat = self.pos + self._tau * self.vel
        psi = self._tau ** 2 * self.vvar + self._q11
        if self._reflect:
            # a predicted mean beyond a wall is folded back and its velocity mean
            # mirrored, as the truth reflects (the predictive's tails are then truncated
            # to the workspace in the update)
            for axis, length in enumerate(self._model.grid.extent):
                out = (rhohat[..., axis] < 0.0) | (rhohat[..., axis] >= length)
                if out.any():
                    folded, vel = fold(rhohat[..., axis][out], self.vel[..., axis][out],
                                       length)
                    rhohat[..., axis][out] = folded
                    self.vel[..., axis][out] = vel
        self._pred = (rhohat, psi)
        self._kp_cells = None

    def _kinematic_cells(self) -> np.ndarray:
        """Flat cells ``(N, T)`` of one draw from the predictive (kinematic prior),
        ``n_cells`` for empty slots and targets that left under ``die``."""
        if self._kp_cells is None:
            rhohat, psi = self._pred
            grid = self._model.grid
            x = rhohat + np.sqrt(psi) * self._rng.standard_normal(rhohat.shape)
            width, height = grid.extent
            ok = self.valid.copy()
            if self._reflect:
                x[..., 0], _ = fold(x[..., 0], np.zeros_like(x[..., 0]), width)
                x[..., 1], _ = fold(x[..., 1], np.zeros_like(x[..., 1]), height)
            else:
                ok &= (x[..., 0] >= 0) & (x[..., 0] < width) & (x[..., 1] >= 0) \
                    & (x[..., 1] < height)
            cells = grid.cell_of(x[..., 0], x[..., 1])
            self._kp_cells = np.where(ok & (cells >= 0), cells, grid.n_cells)
        return self._kp_cells

    def cell_count_distribution(self) -> CellCounts:
        """``P_c(t)`` of one draw from the predictive (kinematic prior), each cell's count
        raised by one undetected target with probability ``pi_c`` (module docstring, 6)
        when ``undetected_in_policy``. Rows for the cells the draw occupies and the
        cells looked at so far (whose ``pi_c`` has its own value); every other cell has
        the default row (no target, the ``pi`` of a cell never looked at)."""
        J = self._model.grid.n_cells
        n_counts = min(self._T, 4) + 1
        w = np.full(self._N, 1.0 / self._N)
        P = cell_count_distribution_from(self._kinematic_cells(), w, J, n_counts)
        if not self.undetected_in_policy:
            return P
        remaining = np.array([self._remaining().mean()])
        cells = np.union1d(P.cells, self._undetected.cells)
        rows = _with_undetected(P.row_of(cells), self._undetected_probability(cells, remaining))
        default = _with_undetected(P.default[None], self._undetected_probability(None,
                                                                                 remaining))
        return CellCounts(J, cells, rows, default[0])

    # ------------------------------------------------------------- update
    def update(self, looks: Looks) -> None:
        model, rng = self._model, self._rng
        grid = model.grid
        N, T, J = self._N, self._T, grid.n_cells
        rhohat, psi = self._pred
        sd = np.sqrt(psi) if self._kernels is None else self._pred_sd
        index, table = grid_log_likelihood_tables(
            model.sensor, np.asarray(looks.cells, dtype=np.int64),
            np.asarray(looks.returns, dtype=bool), J, T)
        beta = self._beta if self._k > 0 else 0.0  # step 0 is the prior: nobody dies

        # 1. partitions from the predicted centres
        held, centres = self._slot_means(rhohat)
        active = held > 0
        clusters = self._clusters(centres, active, self._coupled_links())
        self.n_clusters = len(clusters)
        self.largest_cluster = max((len(c) for c in clusters), default=0)

        log_w = np.zeros(N)
        if clusters:
            moved, anc = self._move_persistent(clusters, rhohat, psi, sd, index, table, beta)
            log_w += moved
            # the undetected initial targets go with the largest cluster's ancestor (all
            # of them when one cluster holds every target, as for a single target)
            self._r = self._r[anc[:, int(np.argmax([len(c) for c in clusters]))]]
        log_w += self._births(centres, active, index, table)
        if len(looks):
            lc, n_looks = np.unique(np.asarray(looks.cells, dtype=np.int64),
                                    return_counts=True)
            detected = np.isin(lc, index.keys[table[:-1, 1] > 0.0])
            log_w += self._undetected_misses(lc, n_looks, detected)

        # full likelihood (all targets, newborns included)
        if self._kernels is None:
            cells = grid.cell_of(self.pos[..., 0], self.pos[..., 1])
            cells = np.where(self.valid & (cells >= 0), cells, J)
            log_w += grid_log_likelihood(cells, index, table)
        else:
            direct = index.direct_table()
            self._kernels.slot_log_likelihood(
                self.pos, self.valid, grid.nx, grid.ny, float(grid.cell_size), J,
                direct is not None, np.zeros(1, np.int32) if direct is None else direct,
                index.keys, table, log_w)

        # weights, resampling every step
        if self._fixed_count is not None:
            # recombining clusters from different ancestors can give a particle more
            # targets than the model allows; their prior probability is 0
            over = self._held() > self._fixed_count
            if over.any() and not over.all():
                log_w[over] = -np.inf
        log_w -= log_w.max()
        w = np.exp(log_w)
        w /= w.sum()
        self.ess = float(effective_sample_size(w))
        idx = systematic_resample(w, rng.random())
        self._r = self._r[idx]
        names = ("pos", "vel", "vvar", "valid")
        if self._kernels is None:
            for name in names:
                setattr(self, name, getattr(self, name)[idx])
        else:
            spares = [self._spare(name) for name in names]
            self._kernels.gather_slots(self.pos, self.vel, self.vvar, self.valid, idx, *spares)
            for name, spare in zip(names, spares, strict=True):
                self._install(name, spare)

        # undetected targets after this step's looks: u, v <- (u, v) l(0)^(looks)
        if len(looks):
            miss = self._miss_factor(n_looks)
            u, u_step, v = self._undetected_values(lc)
            v_new = v * miss
            self._v_total += float((v_new - v).sum())
            self._undetected.set(lc, u=self._arrival_intensity(u, u_step) * miss,
                                 u_step=self._k, v=v_new)
            if self._v_total < 1e-6:
                # the running total has lost six digits to cancellation: only ratios
                # matter, so rescale by the exact sum (once per ~20 sweeps)
                self._rescale_shares()

        # K-means partition sorting within clusters (after resampling, before estimation)
        if self.sort_iterations > 0:
            if self._kernels is None:
                held, mean_pos = self._slot_means(self.pos)
            else:
                held, sums, _ = self._slot_sums(self.pos)
                mean_pos = sums / np.maximum(held, 1)[:, None]
            now = self._clusters(mean_pos, held > 0, None)
            arrays = [self.pos, self.vel, self.vvar, self.valid]
            if self._kernels is None:
                sort_slots(self.pos, self.valid, now, arrays, self.sort_iterations)
                merge_slots(self.pos, self.valid, arrays, self.merge_distance * grid.cell_size)
            else:
                self._sort_compiled(now, held, sums)
                merge_slots(self.pos, self.valid, arrays, self.merge_distance * grid.cell_size,
                            slot_sums=(held, sums))

    # ------------------------------------------------------------- per-slot passes
    @property
    def _kernels(self):
        """:mod:`.ap_kernels` when ``reset`` chose them (and the backend still offers
        them), else None. Looked up, not stored: a module does not deep-copy."""
        return compiled_ap_kernels() if self.uses_compiled_kernels else None

    def _scratch(self, name: str, shape: tuple[int, ...], dtype=np.float64) -> np.ndarray:
        """A C-contiguous array of ``shape`` on the persistent buffer ``name`` (contents
        undefined; valid until the next call with that name)."""
        n = math.prod(shape)
        buf = self._scratch_bufs.get(name)
        if buf is None or buf.size < n or buf.dtype != dtype:
            buf = np.empty(n, dtype=dtype)
            self._scratch_bufs[name] = buf
        return buf[:n].reshape(shape)

    def _spare(self, name: str) -> np.ndarray:
        """The spare of slot array ``name`` (``pos``, ``vel``, ``vvar``, ``valid``): an
        array of its shape and type that nothing else refers to, to be written and then
        installed (:meth:`_install`)."""
        arr = getattr(self, name)
        spare = self._spares.get(name)
        if spare is None or spare.shape != arr.shape or spare.dtype != arr.dtype:
            spare = np.empty_like(arr)
            self._spares[name] = spare
        return spare

    def _install(self, name: str, new: np.ndarray) -> None:
        """``new`` (the spare, written) becomes slot array ``name``; the old one the
        spare."""
        self._spares[name] = getattr(self, name)
        setattr(self, name, new)

    def _slot_sums(self, pos: np.ndarray, with_vel: bool = False
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Compiled: per slot the holders ``(T,)`` and the sums of ``pos`` and of the
        velocity means over them ``(T, 2)`` (in particle order, as numpy's
        ``sum(axis=0)``; velocities only ``with_vel``)."""
        T = self._T
        held, sums, vel_sums = np.empty(T, np.int64), np.empty((T, 2)), np.empty((T, 2))
        self._kernels.slot_sums(pos, self.vel, self.valid, with_vel, held, sums, vel_sums)
        return held, sums, vel_sums

    def _coupled_links(self) -> np.ndarray | None:
        """:func:`.partitions.coupled_slots` of the particles' holdings, for both backends
        (numpy's float32 BLAS product beats a compiled count; one place where a test can
        switch the coupling off)."""
        return coupled_slots(self.valid)

    def _clusters(self, centres: np.ndarray, active: np.ndarray,
                  links: np.ndarray | None) -> list[np.ndarray]:
        """:func:`.partitions.cluster_slots` of the slots' ``centres (T, 2)`` at
        ``cluster_distance`` cells and the ``links`` of :meth:`_coupled_links` (None:
        none; compiled: the same clusters)."""
        gamma = self.cluster_distance * self._model.grid.cell_size
        K = self._kernels
        if K is None:
            return cluster_slots(centres, active, gamma, links)
        T = len(active)
        members, sizes = np.empty(T, np.int64), np.empty(T, np.int64)
        n = K.cluster_slots(np.ascontiguousarray(centres, dtype=float), active, gamma,
                            np.zeros((0, 0), np.bool_) if links is None else links,
                            members, sizes)
        ends = np.cumsum(sizes[:n])
        return [members[end - size:end] for end, size in zip(ends, sizes[:n], strict=True)]

    def _slot_means(self, pos: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Per slot: the holders ``(T,)`` and the mean of ``pos (N, T, 2)`` over them (0
        for a slot held nowhere)."""
        if self._kernels is not None:
            held, sums, _ = self._slot_sums(pos)
            return held, sums / np.maximum(held, 1)[:, None]
        held = self.valid.sum(axis=0)
        means = (pos * self.valid[..., None]).sum(axis=0) / np.maximum(held, 1)[:, None]
        return held, means

    def _sort_compiled(self, clusters: list[np.ndarray], held: np.ndarray,
                       sums: np.ndarray) -> None:
        """:func:`.partitions.sort_slots` on the four slot arrays by
        :func:`.ap_kernels.sort_cluster`, sweep by sweep (the same means, costs and
        permutations). ``held (T,)`` and ``sums (T, 2)``: :meth:`_slot_sums`' holders and
        position sums of the arrays, kept current in place (each sweep returns its
        cluster's)."""
        for slots in clusters:
            slots = np.asarray(slots, dtype=np.int64)
            h = len(slots)
            if h < 2 or h > SORT_MAX:
                continue
            new_held, new_sums = np.empty(h, np.int64), np.empty((h, 2))
            for _ in range(self.sort_iterations):
                if (held[slots] == 0).all():
                    break
                means = sums[slots] / np.maximum(held[slots], 1)[:, None]
                moved = self._kernels.sort_cluster(self.pos, self.vel, self.vvar, self.valid,
                                                   slots, means, held[slots], new_held,
                                                   new_sums)
                held[slots], sums[slots] = new_held, new_sums
                if not moved:
                    break

    def _rescale_shares(self) -> None:
        """``v <- v / sum v`` over every cell, ``_v_total = 1``. The sum is numpy's over
        the dense array when at most half the cells have the default value (always, in
        fact: the total falls below 1e-6 only after all but a millionth of the cells
        were looked at; ``O(cells) = O(cells looked at)``), so the numbers are those of a
        dense ``v``; else the default's part plus the own values' sum."""
        table = self._undetected
        if table.n_default <= len(table.cells):
            total = table.dense("v").sum()
        else:
            total = table.defaults["v"] * table.n_default + table.columns["v"].sum()
        table.columns["v"] = table.columns["v"] / total
        table.defaults["v"] = table.defaults["v"] / total
        self._v_total = 1.0

    def _move_persistent(self, clusters, rhohat, psi, sd, index, table, beta):
        """Steps 2-3 of the module docstring for every cluster at once, in place; returns
        the per-particle ``-sum_l log pi_l(z | X_il)`` and the ancestors ``(N, clusters)``
        each receiver took its clusters from."""
        if self._kernels is not None:
            return self._move_persistent_compiled(clusters, rhohat, psi, sd, index, table,
                                                  beta)
        rng, grid = self._rng, self._model.grid
        N = self._N
        tau, q12, q22 = self._tau, self._q12, self._q22
        n_counts = table.shape[1]
        sizes = np.array([len(c) for c in clusters])
        h_max = int(sizes.max())
        members = np.full((len(clusters), h_max), -1, dtype=np.int64)
        for i, c in enumerate(clusters):
            members[i, :len(c)] = c
        slots = members[members >= 0]  # every active slot once
        cluster_of = np.repeat(np.arange(len(clusters)), sizes)

        # proposal windows of every active slot of every particle (as an ancestor)
        big = float(np.max(np.where(self.valid[:, slots][..., None], sd[:, slots], 0.0)))
        # per axis, the cells within 4 sd of every mean: 2 for a narrow predictive
        width = int(min(math.floor(8.0 * big / grid.cell_size) + 2, 2 * self.max_window + 1))
        mu, s = rhohat[:, slots], sd[:, slots]  # (N, S, 2)
        wx, wy = min(width, grid.nx), min(width, grid.ny)
        ix, gx, in_x = axis_window(mu[..., 0], s[..., 0], grid.nx, grid.cell_size, 0, width=wx)
        iy, gy, in_y = axis_window(mu[..., 1], s[..., 1], grid.ny, grid.cell_size, 0, width=wy)
        gamma = (gy[..., :, None] * gx[..., None, :]).reshape(*gx.shape[:2], -1)
        wcell = (iy[..., :, None] * grid.nx + ix[..., None, :]).reshape(*ix.shape[:2], -1)
        outside = (iy[..., :, None] < 0) | (ix[..., None, :] < 0)
        wcell = np.where(outside.reshape(wcell.shape), grid.n_cells, wcell)
        total = gamma.sum(axis=-1)
        if self._reflect:  # stays inside: the window's mass renormalised
            lost = total <= 0.0  # far outside the window's reach: the nearest cell
            if lost.any():
                near_x = np.clip(np.floor(mu[..., 0] / grid.cell_size), 0, grid.nx - 1) - ix[..., 0]
                near_y = np.clip(np.floor(mu[..., 1] / grid.cell_size), 0, grid.ny - 1) - iy[..., 0]
                near = (np.clip(near_y, 0, wy - 1) * wx + np.clip(near_x, 0, wx - 1)).astype(int)
                gamma[lost, near[lost]] = 1.0
                total = np.where(lost, 1.0, total)
            gamma /= total[..., None]
            m_out = np.zeros(total.shape)
        else:  # the mass outside the workspace leaves (dies)
            inside = in_x * in_y
            gamma *= np.where(total > 0, inside / np.where(total > 0, total, 1.0), 0.0)[..., None]
            m_out = 1.0 - inside
        row = index(wcell)  # (N, S, W) table rows
        dead = beta + (1.0 - beta) * m_out  # (N, S)

        # 3. every particle draws its own clusters, target after target
        valid_s = self.valid[:, slots]
        col = {int(t): j for j, t in enumerate(slots)}  # slot -> column in the S arrays
        new_cell = np.zeros((N, len(slots)), dtype=np.int64)
        new_valid = np.zeros((N, len(slots)), dtype=bool)
        log_z = np.zeros((N, len(clusters)))  # log prod_t Z_t per particle and cluster
        log_pi = np.zeros((N, len(clusters)))  # log pi_l(z | x_l) of the draws
        placed = np.full((N, len(clusters), h_max), -1, dtype=np.int64)
        for i in range(h_max):
            live = np.flatnonzero(sizes > i)
            j = np.array([col[int(t)] for t in members[live, i]])
            g, cells, r = gamma[:, j], wcell[:, j], row[:, j]  # (N, k, W)
            n_before = (placed[:, live, :i, None] == cells[:, :, None, :]).sum(axis=2)
            n_before = np.minimum(n_before, n_counts - 2)
            log_rho = table[r, n_before + 1] - table[r, n_before]
            weights = (1.0 - beta) * g * np.exp(log_rho)
            d = dead[:, j]
            z = d + weights.sum(axis=-1)  # (N, k)
            # choose: 0 = dies, 1 + w = window cell w
            cum = np.concatenate([d[..., None], d[..., None] + np.cumsum(weights, axis=-1)],
                                 axis=-1)
            u = rng.random(z.shape) * z
            choice = np.minimum((cum <= u[..., None]).sum(axis=-1), cum.shape[-1] - 1)
            held = valid_s[:, j]
            alive = (choice > 0) & held
            w_idx = np.maximum(choice - 1, 0)
            cell = np.take_along_axis(cells, w_idx[..., None], axis=-1)[..., 0]
            lr = np.take_along_axis(log_rho, w_idx[..., None], axis=-1)[..., 0]
            with np.errstate(divide="ignore"):
                log_z[:, live] += np.where(held, np.log(z), 0.0)
            log_pi[:, live] += np.where(alive, lr, 0.0)
            placed[:, live, i] = np.where(alive, cell, -1)
            new_cell[:, j] = cell
            new_valid[:, j] = alive

        # 2. recombination: receiver i takes cluster l's cells from particle a drawn
        # ∝ prod_t Z_t(a) (the draw's importance weight; Z = 1 for an empty slot)
        anc = np.empty((N, len(clusters)), dtype=np.int64)
        for c in range(len(clusters)):
            p = np.exp(log_z[:, c] - log_z[:, c].max())
            anc[:, c] = rng.permutation(systematic_resample(p / p.sum(), rng.random()))
        take = (anc[:, cluster_of], np.arange(len(slots))[None, :])
        alive, cell = new_valid[take], new_cell[take]
        mu, s = mu[take], s[take]
        # the weight depends on the cells only: each receiver draws its own positions
        # inside them, the ancestor's predictive truncated to the cell, per axis
        x0, x1, y0, y1 = grid.cell_bounds(np.where(alive, cell, 0))
        uu = rng.random(mu.shape)
        pos = np.stack([truncated_normal(mu[..., 0], s[..., 0], x0, x1, uu[..., 0]),
                        truncated_normal(mu[..., 1], s[..., 1], y0, y1, uu[..., 1])], axis=-1)
        # velocity posteriors given the drawn positions (RB update, per axis)
        vel, vvar = self.vel[:, slots][take], self.vvar[:, slots][take]
        cross = tau * vvar + q12
        gain = cross / psi[:, slots][take]
        self.pos[:, slots] = pos
        self.vel[:, slots] = vel + gain * (pos - mu)
        self.vvar[:, slots] = vvar + q22 - cross * gain
        self.valid[:, slots] = alive
        # the weight keeps p(z | X) / prod_l pi_l: nonzero only where clusters share a cell
        return -log_pi[anc, np.arange(len(clusters))[None, :]].sum(axis=1), anc

    def _move_persistent_compiled(self, clusters, rhohat, psi, sd, index, table, beta):
        """:meth:`_move_persistent` by :func:`.ap_kernels.propose` and
        :func:`.ap_kernels.place`: the same random draws in the same calls and order."""
        rng, grid, K = self._rng, self._model.grid, self._kernels
        N, T = self._N, self._T
        sizes = np.array([len(c) for c in clusters], dtype=np.int64)
        C, h_max = len(clusters), int(sizes.max())
        members = np.full((C, h_max), -1, dtype=np.int64)
        for i, c in enumerate(clusters):
            members[i, :len(c)] = c
        slots = members[members >= 0]
        S = len(slots)
        cluster_of = np.repeat(np.arange(C), sizes)
        col = np.full(T, -1, dtype=np.int64)
        col[slots] = np.arange(S)
        big = K.max_held_sd(sd, self.valid, slots)
        width = int(min(math.floor(8.0 * big / grid.cell_size) + 2, 2 * self.max_window + 1))
        wx, wy = min(width, grid.nx), min(width, grid.ny)
        # member i's uniforms, one call per member as in the numpy form
        uniforms = self._scratch("uniforms", (h_max, N, C))
        for i in range(h_max):
            live = np.flatnonzero(sizes > i)
            if len(live) == C:
                rng.random(out=uniforms[i])
            else:
                uniforms[i][:, live] = rng.random(out=self._scratch("draw", (N, len(live))))
        log_z, log_pi = self._scratch("log_z", (N, C)), self._scratch("log_pi", (N, C))
        new_cell = self._scratch("new_cell", (N, S), np.int64)
        new_valid = self._scratch("new_valid", (N, S), np.bool_)
        # per drawn cell and axis, the CDF values its position's draw starts from
        starts, masses = self._scratch("starts", (N, S, 2)), self._scratch("masses", (N, S, 2))
        sides = self._scratch("sides", (N, S, 2), np.int8)
        direct = index.direct_table()
        K.propose(rhohat, sd, self.valid, slots, members, sizes, col, uniforms, grid.nx,
                  grid.ny, float(grid.cell_size), grid.n_cells, wx, wy, self._reflect, beta,
                  direct is not None, np.zeros(1, np.int32) if direct is None else direct,
                  index.keys, table, log_z, log_pi, new_cell, new_valid, starts, masses,
                  sides)
        # the numpy form's rng.permutation(idx) is idx[rng.permutation(N)] (a shuffle's
        # swaps do not depend on the values; a test checks it). With one cluster, place
        # takes the receivers in the order of their ancestors (the inverse permutation:
        # the ancestors' rows are read in memory order); with more, in particle order
        # with its prefetches (docs/speed.md)
        anc = np.empty((N, C), dtype=np.int64)
        order = np.arange(N)
        for c in range(C):
            p = np.exp(log_z[:, c] - log_z[:, c].max())
            idx = systematic_resample(p / p.sum(), rng.random())
            perm = rng.permutation(N)
            anc[:, c] = idx[perm]
            if C == 1:
                order = np.empty(N, dtype=np.int64)
                order[perm] = np.arange(N)
        uu = rng.random(out=self._scratch("uu", (N, S, 2)))
        # the velocity posteriors go to the spares (the sources are the ancestors'); the
        # slots not in a cluster keep theirs (copied by the kernel)
        vel, vvar = self._spare("vel"), self._spare("vvar")
        K.place(anc, order, C > 1, cluster_of, slots, new_cell, new_valid, starts, masses,
                sides, rhohat, sd, psi, uu, grid.nx, float(grid.cell_size), self._tau,
                self._q12, self._q22, self.vel, self.vvar, np.flatnonzero(col < 0), self.pos,
                vel, vvar, self.valid)
        self._install("vel", vel)
        self._install("vvar", vvar)
        moved = np.empty(N)
        K.recombined_log_pi(log_pi, anc, moved)
        return moved, anc

    def _births(self, centres, active, index, table) -> np.ndarray:
        """Step 4 of the module docstring; returns the per-particle prior/proposal log
        ratio of the birth decisions at the detected cells."""
        grid, rng = self._model.grid, self._rng
        N = self._N
        looked = index.keys  # sorted; row r of the table is looked[r]
        if looked.size == 0:
            return np.zeros(N)
        lam = table[:-1, 1]
        det = looked[lam > 0.0]
        if det.size == 0:
            return np.zeros(N)
        lam = np.exp(lam[lam > 0.0])
        if self._kernels is None:
            cells = grid.cell_of(self.pos[..., 0], self.pos[..., 1])
            cells = np.where(self.valid, cells, -1)
            occupied = (cells[:, :, None] == det[None, None, :]).any(axis=1)  # (N, D)
        else:
            occupied = np.empty((N, det.size), dtype=bool)
            self._kernels.occupied(self.pos, self.valid, det, grid.nx, grid.ny,
                                   float(grid.cell_size), occupied)
        # the slot each particle's birth in cell d would take
        centre_cell = grid.cell_of(centres[:, 0], centres[:, 1])
        free = list(np.flatnonzero(~active)[::-1])
        slot = np.full((N, det.size), -1, dtype=np.int64)
        for k, d in enumerate(det):
            near = np.flatnonzero(active & (centre_cell == d))
            if near.size:
                s = near[np.argmax(self.valid[:, near].sum(axis=0))]
                slot[:, k] = np.where(self.valid[:, s], -1, s)
            need = slot[:, k] < 0
            if need.any() and free:
                slot[need, k] = free.pop()
        has_slot = slot >= 0
        uniforms = rng.random((N, det.size))
        born = np.zeros((N, det.size), dtype=bool)
        log_ratio = np.zeros(N)
        # cell after cell, each birth from the particle's undetected initial targets
        # lowers those left for the next cells (one undetected target is born once): a
        # newborn is an initial target with probability pi_init / pi, else an arrival
        remaining = self._remaining()
        if self._kernels is not None:  # the same decisions in one compiled pass
            log_keep, pi_arrival = self._undetected_cell_terms(det)
            self._kernels.birth_decisions(remaining, log_keep, pi_arrival, lam, np.log(lam),
                                          has_slot, occupied, uniforms, born, log_ratio)
        else:
            for k in range(det.size):
                pi_init, pi_arr = self._undetected_probability(det[k:k + 1], remaining)
                pi_init, pi = pi_init[:, 0], 1.0 - (1.0 - pi_init[:, 0]) * (1.0 - pi_arr[:, 0])
                z = 1.0 - pi + pi * lam[k]  # the cell's normaliser
                b = np.where(has_slot[:, k], pi * lam[k] / z, 0.0)
                born[:, k] = (uniforms[:, k] < b) & ~occupied[:, k]
                # prior / proposal: pi / b = z / lam if born, (1 - pi) / (1 - b) = z if not
                # (the newborn's lam is in the full likelihood); without a free slot b = 0:
                # 1 - pi
                kept = np.log(z) - np.where(born[:, k], np.log(lam[k]), 0.0)
                ratio = np.where(has_slot[:, k], kept, np.log1p(-pi))
                log_ratio += np.where(occupied[:, k], 0.0, ratio)
                with np.errstate(invalid="ignore", divide="ignore"):
                    initial = np.where(pi > 0.0, pi_init / pi, 0.0)
                remaining = np.maximum(remaining - np.where(born[:, k], initial, 0.0), 0.0)
        if self._can_die:
            self._r = remaining
        p_idx, k_idx = np.nonzero(born)
        if p_idx.size:
            s_idx = slot[p_idx, k_idx]
            x0, x1, y0, y1 = grid.cell_bounds(det[k_idx])
            u = rng.random((p_idx.size, 2))
            self.pos[p_idx, s_idx, 0] = x0 + u[:, 0] * (x1 - x0)
            self.pos[p_idx, s_idx, 1] = y0 + u[:, 1] * (y1 - y0)
            self.vel[p_idx, s_idx] = 0.0
            self.vvar[p_idx, s_idx] = self._birth_var
            self.valid[p_idx, s_idx] = True
        return log_ratio

    # ------------------------------------------------------------- estimate
    def estimate(self) -> Estimate:
        """Count: ``E[T]``, the mean number of held slots plus :attr:`undetected_mass`.
        States: the ``round(mean held slots)`` most-held slots' weighted means; labels: the slot
        (partition) index. The partition sorting keeps a target in the same slot across
        particles and steps, so a label follows its target while the target keeps its
        slot; a slot freed by a death (or emptied in every particle) may later be reused
        by another target, which then inherits the label (read as an identity switch)."""
        if self._kernels is not None:
            held, pos_sums, vel_sums = self._slot_sums(self.pos, with_vel=True)
        else:
            held = self.valid.sum(axis=0)
        held_mean = float(held.sum() / self._N)
        # E[T] counts the undetected targets too; states come from the slots only
        self.count_mean = held_mean + self.undetected_mass
        n_hat = int(round(held_mean))
        if n_hat == 0:
            return Estimate(self.count_mean, np.zeros((0, 4)), labels=np.zeros(0, np.int64))
        top = np.argsort(-held, kind="stable")[:n_hat]
        top = top[held[top] > 0]
        n = held[top][:, None]
        if self._kernels is not None:
            pos, vel = pos_sums[top] / n, vel_sums[top] / n
        else:
            v = self.valid[:, top][..., None]
            pos = (self.pos[:, top] * v).sum(axis=0) / n
            vel = (self.vel[:, top] * v).sum(axis=0) / n
        states = np.stack([pos[:, 0], vel[:, 0], pos[:, 1], vel[:, 1]], axis=1)
        return Estimate(self.count_mean, states, labels=top.astype(np.int64))

    @classmethod
    def resource_terms(cls, params, model, looks_per_step, targets) -> ResourceTerms:
        """``N t_max`` slots (``t_max`` the automatic slots when not given), look tables
        of ``t_max + 1`` columns per looked cell, the undetected field of the cells looked
        at so far; ``P_c(t)`` from the slots (``min(t_max, 4) + 1`` columns) and their
        in-particle counts from sorted runs."""
        n = param_number(params, "n_particles", 2000)
        t_max = (float(_auto_slots(model)) if params.get("t_max") is None
                 else param_number(params, "t_max", 5))
        return ResourceTerms(
            state_bytes=n * t_max * AP_SLOT_BYTES, look_bytes=(t_max + 1) * JMPD_LOOK_BYTES,
            looked_cell_bytes=LOOKED_CELL_BYTES, step_seconds=n * t_max * AP_SLOT_S,
            looked_cell_seconds=LOOKED_CELL_S,
            prediction_entries=n * t_max, prediction_counts=min(t_max, 4) + 1,
            prediction_seconds=n * t_max * math.log2(t_max + 1.0) * JMPD_SLOT_T_S)
