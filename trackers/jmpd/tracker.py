"""The JMPD trackers ("jmpd", "jmpd-ip"): the :class:`~..base.Tracker` life cycle
composed from the particle storage (:mod:`.state`), the proposals (:mod:`.proposals`),
the likelihood (:mod:`.likelihood`), the resampling (:mod:`.resampling`) and the
estimates (:mod:`.estimation`). The method is described in the package docstring.
"""

from __future__ import annotations

import math
from typing import ClassVar, Literal

import numpy as np

from ...scenarios.model import Looks, TrackingModel
from ..base import Estimate, ResourceTerms, Tracker, param_number, register
from ..cells import CellCounts
from ..params import Budget, Param, Search
from .backend import compiled_kernels
from .estimation import cell_count_distribution_from, estimate_targets
from .likelihood import GridLikelihood, SuperpositionLikelihood, step_likelihood
from .proposals import BootstrapPrior, bootstrap_predict, ip_exchange
from .resampling import effective_sample_size, systematic_resample
from .state import ParticleState

# measured costs (:meth:`JMPDTracker.resource_terms`, docs/resources.md)
#: bytes per JMPD particle slot, plus per slot and per unit of ``t_max``: bootstrap 268 B
#: per slot at t_max = 5 (N = 5e4), 478 B at t_max = 30 (N = 2e4); the IP proposal
#: 282 B and 1,197 B there
JMPD_SLOT_BYTES = 256
JMPD_SLOT_T_BYTES = 16
JMPD_IP_SLOT_T_BYTES = 48
#: per looked cell and count column of a JMPD's look tables: 22 B measured (jmpd-ap,
#: ``all`` on 700x700)
JMPD_LOOK_BYTES = 32
#: per JMPD slot and step, plus per slot and unit of t_max (the O(N t_max^2) passes):
#: 50-66 ms per step measured at N = 2000, t_max = 30
JMPD_SLOT_S = 5e-7
JMPD_SLOT_T_S = 2e-8
#: the IP proposal's cost relative to the bootstrap (measured 0.9 s against 0.22 s there)
JMPD_IP_FACTOR = 4.0


#: the horizon (steps) at which a model whose count grows without bound (``p_s = 1``,
#: births) is taken for its peak: the shipped presets' length
PEAK_HORIZON = 100
#: the Poisson quantile of the expected peak count that ``t_max`` None covers
T_MAX_QUANTILE = 0.99


def expected_peak_count(model: TrackingModel) -> tuple[float, str]:
    """The peak over the run of the expected target count, and how it arises.

    The expected count of the model's existence process (``BirthDeath``: ``n0``
    initial targets, survival ``p_s``, Poisson births ``b`` per step) after ``k`` steps
    is ``m(k) = n0 p_s^k + b (1 - p_s^k) / (1 - p_s)`` (``n0 + b k`` when ``p_s = 1``):

    * ``p_s < 1``: ``m(k)`` moves monotonically from ``n0`` to the stationary mean
      ``b / (1 - p_s)``, so the peak is ``max(n0, b / (1 - p_s))``;
    * ``p_s = 1`` and ``b > 0``: ``m(k)`` grows without bound; the peak is taken at
      :data:`PEAK_HORIZON` steps, ``n0 + 100 b`` (a longer run can outgrow it);
    * ``p_s = 1`` and ``b = 0``: ``n0``.

    Targets that die at a ``die`` boundary only lower the count, so this is an upper
    bound there.
    """
    bd = model.birth_death
    n0 = float(len(bd.initial_states) + bd.n_random_initial)
    p_s, b = float(bd.survival_probability), float(bd.birth_rate)
    if p_s < 1.0:
        return max(n0, b / (1.0 - p_s)), f"initial {n0:.0f}, stationary mean {b / (1.0 - p_s):.3g}"
    if b > 0.0:
        return n0 + PEAK_HORIZON * b, (f"initial {n0:.0f}, {PEAK_HORIZON * b:.3g} more births "
                                       f"in {PEAK_HORIZON} steps")
    return n0, f"initial {n0:.0f}"


def default_t_max(model: TrackingModel) -> int:
    """Slots per particle when ``t_max`` is not given: the :data:`T_MAX_QUANTILE`
    quantile of a Poisson count whose mean is the expected peak
    (:func:`expected_peak_count`), at least 1. A particle then holds the counts the
    model makes likely; more slots cost ``O(N t_max^2)`` and, measured on the presets
    (docs/jmpd.md), buy no accuracy."""
    from scipy.stats import poisson

    peak, _ = expected_peak_count(model)
    return max(1, int(poisson.ppf(T_MAX_QUANTILE, peak))) if peak > 0 else 1


@register
class JMPDTracker(Tracker):
    """JMPD particle filter, bootstrap (kinematic prior) proposal by default.

    Parameters: ``n_particles`` N; ``t_max`` largest count a particle can hold;
    ``birth_rate`` (per particle and step, None: the model's rate or
    ``DEFAULT_BIRTH_RATE``); ``death_probability`` (per target and step, None:
    ``1 - p_s`` or ``DEFAULT_DEATH_PROBABILITY``); ``resample_threshold`` (resample
    when ESS < threshold * N); ``proposal`` "bootstrap" or "ip"; ``initial_count``
    (None: Poisson prior; an int: every particle starts with that many targets).

    After ``reset``: ``count_mean`` and ``count_probabilities`` (the count posterior of
    the last estimate), ``n_resamples``, ``uses_compiled_kernels`` (whether predict runs
    the numba pass; same results either way), and the read-only views below.
    """

    name = "jmpd"
    summary = "JMPD particle filter (Kreucher et al. 2005), bootstrap proposal"
    conformance_exceptions = {
        "check_tracks_two_targets": (
            "the bootstrap proposal over the joint density loses one of two separated "
            "targets even with every cell looked at (mean OSPA 1.0-1.25 over 8-seed blocks "
            "at N = 2000, 0.80 at N = 20000; bound 1.0); the IP proposal (jmpd-ip) holds "
            "them (docs/jmpd.md)"),
    }
    parameters: ClassVar[dict[str, Param]] = {
        "n_particles": Param(int, 1, doc="particles N"),
        "t_max": Param(int, 1, allow_none=True,
                       none="the 99% Poisson quantile of the expected peak count",
                       doc="largest count a particle can hold"),
        # tuning (mttbench tune; jmpd-ip inherits it): the birth and death floors about
        # their defaults 0.02 and 0.01 (log, two decades), the resampling threshold over
        # its range; the particle count is a cost, the proposal a method, neither tuned
        "birth_rate": Param(float, 0, allow_none=True,
                            none="the model's rate, or DEFAULT_BIRTH_RATE",
                            doc="births per particle and step",
                            search=Search(0.002, 0.2, log=True)),
        "death_probability": Param(float, 0, 1, allow_none=True,
                                   none="1 - p_s, or DEFAULT_DEATH_PROBABILITY",
                                   doc="per target and step",
                                   search=Search(0.001, 0.1, log=True)),
        "resample_threshold": Param(float, 0, 1, doc="resample when ESS < threshold * N",
                                    search=Search(0.1, 1.0)),
        "proposal": Param(choices=("bootstrap", "ip")),
        "initial_count": Param(int, 0, allow_none=True, none="Poisson prior",
                               doc="targets in every particle at first"),
    }
    budget: ClassVar[dict[str, Budget]] = {
        "n_particles": Budget(100, 16000, doc="particles N, about 6 us each per step: "
                                              "16000 is about 0.1 s per step on one core"),
    }
    def __init__(self, n_particles: int = 2000, t_max: int | None = None,
                 birth_rate: float | None = None, death_probability: float | None = None,
                 resample_threshold: float = 0.5,
                 proposal: Literal["bootstrap", "ip"] = "bootstrap",
                 initial_count: int | None = None) -> None:
        self.n_particles = n_particles
        self.t_max = t_max
        self.birth_rate = birth_rate
        self.death_probability = death_probability
        self.resample_threshold = resample_threshold
        self.proposal = proposal
        self.initial_count = initial_count

    # ------------------------------------------------------------- views
    @property
    def states(self) -> np.ndarray:
        """Target states ``(N, t_max, 4)`` (a view; empty slots hold junk). Writes reach
        the tracker (tests set start states this way); the cells follow at the next
        predict."""
        return self._particles.X.transpose(2, 1, 0)

    @property
    def mask(self) -> np.ndarray:
        """Slot validity ``(N, t_max)`` bool (a view)."""
        return self._particles.valid.T

    @property
    def log_weights(self) -> np.ndarray:
        """Normalised log-weights ``(N,)``."""
        return self._particles.logw

    @property
    def slot_cells(self) -> np.ndarray:
        """Flat cell of every slot's position, valid or not, ``(N, t_max)`` int32 (int64
        on grids of more than ``2^31 - 1`` cells; the grid rule of
        :func:`.state.flat_cells`; empty slots hold positions inside the workspace too).
        As computed by the last predict; recomputed from the positions when a
        resampling has made those stale. Read only."""
        return self._particles.slot_cells().T

    @property
    def cells(self) -> np.ndarray:
        """Flat cells ``(N, t_max)`` int64 with ``n_cells`` for empty slots (a new
        array): :attr:`slot_cells` where :attr:`mask`."""
        return self._particles.cells().T

    @property
    def prior(self) -> BootstrapPrior:
        """The kinematic prior in use (:class:`.proposals.BootstrapPrior`): ``F``, ``L``
        (``L L^T = Q``), ``p_death``, ``p_birth``, ... resolved at reset. ``p_death``
        and ``p_birth`` may be changed between steps."""
        return self._prior

    # ------------------------------------------------------------- life cycle
    def unsupported_reason(self, model: TrackingModel) -> str | None:
        """Refuses a scenario whose expected peak count (:func:`expected_peak_count`)
        exceeds a given ``t_max`` (a particle holds at most ``t_max`` targets, so it
        could not represent the truth). With ``t_max`` None every scenario is supported:
        the slots follow the model (:func:`default_t_max`)."""
        if self.t_max is None:
            return None
        peak, how = expected_peak_count(model)
        need = math.ceil(peak - 1e-9)  # 0.5 / (1 - 0.9) is 5.000000000000001
        if need <= int(self.t_max):
            return None
        return (f"expected target count {peak:.3g} ({how}) exceeds "
                f"t_max = {int(self.t_max)}: use t_max >= {need}")

    def _slots(self, model: TrackingModel) -> int:
        """``t_max`` as given, else :func:`default_t_max` (at least ``initial_count``)."""
        if self.t_max is not None:
            return int(self.t_max)
        return max(default_t_max(model), int(self.initial_count or 0))

    @classmethod
    def param_conflict(cls, params):
        n0, t_max = params["initial_count"], params["t_max"]
        if n0 is not None and t_max is not None and n0 > t_max:
            return (f"initial_count={n0} with t_max={t_max}: need initial_count <= t_max "
                    "(a particle holds at most t_max targets)")
        return None

    def reset(self, model: TrackingModel, rng: np.random.Generator) -> None:
        self.validate_params(self.get_params())  # the declaration above (built directly)
        N, T = int(self.n_particles), self._slots(model)
        kernels = compiled_kernels()
        self.uses_compiled_kernels = kernels is not None
        if kernels is not None:
            kernels.warm_up()  # compile (or load) them now, not in a timed step
        self._model, self._rng = model, rng
        self._prior = BootstrapPrior.from_model(model, self.birth_rate, self.death_probability)
        p = self._particles = ParticleState(N, T, model.grid)
        # prior before step 0: T_i ~ Poisson clipped to t_max (or initial_count),
        # positions uniform, velocities N(0, birth_velocity_std^2)
        if self.initial_count is None:
            counts = np.minimum(rng.poisson(model.birth_death.initial_count_mean, size=N), T)
        else:
            counts = np.full(N, int(self.initial_count))  # <= t_max (param_conflict)
        p.valid[:] = np.arange(T)[:, None] < counts[None, :]
        X, bv = p.X, self._prior.birth_velocity_std
        X[0] = rng.uniform(0.0, p.width, (T, N))
        X[2] = rng.uniform(0.0, p.height, (T, N))
        X[1] = rng.normal(0.0, bv, (T, N))
        X[3] = rng.normal(0.0, bv, (T, N))
        p.counts = counts.astype(np.int64)
        p.update_cells()
        self._ref: np.ndarray | None = None  # the last estimate, predicted to this step
        self._lik: GridLikelihood | SuperpositionLikelihood | None = None  # last update's
        self.count_mean = float(counts.mean())
        self.count_probabilities = np.bincount(counts, minlength=T + 1) / N
        self.n_resamples = 0

    def predict(self) -> None:
        kernels = compiled_kernels() if self.uses_compiled_kernels else None
        bootstrap_predict(self._particles, self._prior, self._rng, kernels)
        if self._ref is not None and len(self._ref):
            self._ref = self._ref @ self._prior.F.T

    def cell_count_distribution(self) -> CellCounts:
        """``P_c(t)`` with rows for the cells the particles' targets occupy
        (:func:`.estimation.cell_count_distribution_from`), ``O(N t_max log t_max)``."""
        p = self._particles
        return cell_count_distribution_from(p.cells().T, p.w, p.grid.n_cells, p.t_max + 1)

    def update(self, looks: Looks) -> None:
        p = self._particles
        lik = step_likelihood(self._model.sensor, looks, p.grid.n_cells, p.t_max)
        if lik is None:
            return
        self._lik = lik
        ip = self.proposal == "ip" and isinstance(lik, GridLikelihood)
        if ip:
            correction = ip_exchange(p, self._ref, lik, self._rng)
        ll = lik(p.X, p.valid, p.raw_cells, key_buffer=p.key_buf)
        if ip:
            ll -= correction
        logw, w = p.logw, p.w
        logw += ll
        # normalise: w = exp(logw - max) / sum, logw -= max + log(sum) (= logsumexp)
        top = logw.max()
        np.subtract(logw, top, out=w)
        np.exp(w, out=w)
        total = w.sum()
        w /= total
        logw -= top + math.log(total)
        # systematic resampling when the effective sample size is low
        if effective_sample_size(w) >= self.resample_threshold * p.n:
            return
        p.resample(systematic_resample(w, self._rng.random()))
        self.n_resamples += 1

    def estimate(self) -> Estimate:
        p = self._particles
        out = estimate_targets(p.X, p.valid, p.counts, p.w, self._ref)
        self.count_probabilities, self.count_mean = out.count_probabilities, out.count_mean
        self._ref = out.reference
        return out.estimate

    @classmethod
    def resource_terms(cls, params, model, looks_per_step, targets) -> ResourceTerms:
        """``N t_max`` slots (``O(N t_max^2)`` passes, the IP proposal's more), look
        tables of ``t_max + 1`` columns per looked cell; ``P_c(t)`` from the slots
        (``t_max + 1`` columns) and their in-particle counts from sorted runs."""
        n = param_number(params, "n_particles", 2000)
        t_max = (float(default_t_max(model)) if params.get("t_max") is None
                 else param_number(params, "t_max", 5))
        ip = params.get("proposal") == "ip"
        per_t = JMPD_IP_SLOT_T_BYTES if ip else JMPD_SLOT_T_BYTES
        return ResourceTerms(
            state_bytes=n * t_max * (JMPD_SLOT_BYTES + t_max * per_t),
            look_bytes=(t_max + 1) * JMPD_LOOK_BYTES,
            step_seconds=(n * t_max * (JMPD_SLOT_S + t_max * JMPD_SLOT_T_S)
                          * (JMPD_IP_FACTOR if ip else 1.0)),
            prediction_entries=n * t_max, prediction_counts=t_max + 1,
            prediction_seconds=n * t_max * math.log2(t_max + 1.0) * JMPD_SLOT_T_S)


@register
class JMPDIPTracker(JMPDTracker):
    """JMPD with Kreucher's independent-partition proposal (``proposal="ip"``)."""

    name = "jmpd-ip"
    summary = "JMPD particle filter (Kreucher et al. 2005), independent-partition proposal"
    conformance_exceptions: ClassVar[dict[str, str]] = {}  # passes every check
    #: only the default of ``proposal`` differs: ``jmpd-ip`` and ``jmpd:proposal=ip`` are
    #: one configuration and draw the same random numbers
    defaults_only = True

    def __init__(self, n_particles: int = 2000, t_max: int | None = None,
                 birth_rate: float | None = None, death_probability: float | None = None,
                 resample_threshold: float = 0.5,
                 proposal: Literal["bootstrap", "ip"] = "ip",
                 initial_count: int | None = None) -> None:
        super().__init__(n_particles=n_particles, t_max=t_max, birth_rate=birth_rate,
                         death_probability=death_probability,
                         resample_threshold=resample_threshold, proposal=proposal,
                         initial_count=initial_count)
