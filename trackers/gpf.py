"""The paper's Gaussian particle filter (GPF), on the superposition and the grid sensor.

Each particle is ``{w_i, N(mu_i, Sigma_i)}``: ``w_i`` is the probability that a target
with that Gaussian exists, and the estimated count is ``sum_i w_i`` (paper Section IV).
Arrays: ``w (K,)``, ``means (K, 4)``, ``covs (K, 4, 4)``; states ``[px, vx, py, vy]``.

Step (the harness calls predict, then update, then estimate):

* **Predict**: ``mu <- F mu``, ``Sigma <- F Sigma F^T + Q``, ``w <- p_s w``. Boundary
  "reflect": a mean that left the workspace is mirrored back (its velocity and the
  covariance's sign pattern flipped with it). Boundary "die": ``w`` is also multiplied by
  the probability that the position stays in the workspace (product of the marginal
  masses; the Gaussian itself is not truncated).
* **Death floor** (``death_probability``): the filter predicts with the survival
  probability ``min(p_s, 1 - death_probability)``, for the weights and the birth field
  alike. ``None`` (default) means ``DEFAULT_DEATH_FLOOR = 0.003`` on the grid sensor with
  births, and the model's ``p_s`` otherwise: without births (the exact reductions, e.g. the
  Kalman test) and on the superposition sensor, whose count lives in the prior weights and
  would only decay (no return re-confirms it). ``0`` is the model exactly. Why a floor: with
  ``p_s = 1`` the Bernoulli update ``w' = w L / (w L + 1 - w)`` raises the log-odds by
  ``log l(1) = 6.9`` per detection, so ``w`` rounds to exactly 1.0 after a few detections
  and then no negative look can lower it; a lost track keeps ``w = 1`` while its covariance
  grows. With the floor ``f`` the log-odds after every predict are at most ``log((1 - f) /
  f)`` (5.8 at 0.003) and every look without a return lowers them. Keeping the weights as
  log-odds instead (no rounding to 1) is not enough: the exact log-odds after tens of
  detections are in the hundreds, and a broad particle loses only ~0.1 per step; ``f =
  1e-15`` (weights just below 1, i.e. that numerical fix) measured no different from
  ``0``. Measured (``mttbench run``, raster 24 looks, 20 seeds; ``paper`` 50 steps, the
  others 100; differences to ``f = 0`` paired by seed, mean +- 95% half-width), OSPA /
  GOSPA / count error:

  - ``default`` (0.000: 1.394 / 2.091 / 0.820): 0.003 +0.005+-0.026 / -0.004+-0.026 /
    +0.059+-0.059; 0.01 +0.024+-0.032 / -0.044+-0.046 / +0.222+-0.072; 0.03
    +0.110+-0.044 / -0.057+-0.076 / +0.569+-0.091.
  - ``crossing`` (1.037 / 1.884 / 0.628): 0.003 -0.025+-0.045 / -0.091+-0.060 /
    +0.086+-0.124; 0.01 +0.035+-0.072 / -0.118+-0.106 / +0.357+-0.201; 0.03
    +0.209+-0.095 / -0.001+-0.171 / +0.842+-0.221.
  - ``paper`` (1.940 / 2.675 / 2.062): OSPA and GOSPA unchanged (+-0.005); count error
    +0.007+-0.001, +0.023+-0.004, +0.072+-0.014. ``births`` (``p_s = 0.98``): unchanged up to
    0.01; 0.03 count error +0.041+-0.020.

  Fraction of steps holding a particle with ``w > 0.9`` and position sd ``> 2`` cells
  (raster, 20 seeds; f = 0 / 0.003 / 0.01 / 0.03): ``default`` 0.36 / 0.30 / 0.13 / 0.03,
  ``crossing`` 0.19 / 0.12 / 0.01 / 0.00, ``births`` 0.005 at all up to 0.01, ``paper``
  0.91 / 0.91 / 0.89 / 0.64 (there every undetected target has sd ~4.5 cells after a
  predict, so this counts the process noise, not lost tracks). So a floor removes the lost
  confident tracks but does not improve OSPA, and it costs count accuracy: with ``p_d =
  0.5`` and each cell looked at every 6 steps, runs of misses on a tracked target are common,
  and a floored weight drops during them (``sum w`` undercounts). 0.003 is the smallest
  floor tried: no weight is stuck at 1 across steps, crossing GOSPA improves, and the count
  cost is within noise on ``default`` and ``crossing``; larger floors buy fewer lost tracks
  with count error.
* **Update**: superposition sensor -- :mod:`trackers.gpf_linear` (the paper's combinations
  ``E``, the appendix's gain, groups folded back by moment matching); grid sensor --
  :mod:`trackers.gpf_grid` (Gaussians truncated to the looked cells, exact Bernoulli
  weight update, combinations enumerated per cluster of particles sharing a cell).
* **Combinations** (``epsilon``, ``max_combinations``): as the paper says, combinations
  are cut on their *prior* probability ``<= epsilon``, then at most ``max_combinations``
  (the most probable) are kept, and the rest renormalised. A sharp likelihood (detections)
  can make a cut combination matter, so the default ``epsilon = 1e-4`` (was ``1e-3``) was
  chosen by measurement: on the 1000 grid updates of 5 seeds each of ``default`` and
  ``crossing`` (raster, 24 looks), against ``epsilon = 0`` with a cap of 20000, the largest
  weight error per update averaged 4.1e-3 (99th percentile 0.062, worst 0.29) at ``1e-3``,
  1.6e-3 (0.041, 0.12) at ``1e-4``, 6.5e-4 (0.0087, 0.12) at ``1e-5`` and 3.9e-4 at
  ``0`` with the cap 512, for 1.52, 1.53, 1.82 and 2.29 ms per update. The closed-loop
  scores (20 seeds, paired by seed) did not move beyond noise for any of them (OSPA
  differences <= 0.02 with 95% half-widths ~0.04), so ``1e-4`` takes the smaller error at
  no cost.
* **Merge** (the paper's Mahalanobis rule): greedily from the heaviest particle ``i``,
  particles ``j`` with ``(mu_i - mu_j)^T (Sigma_i + Sigma_j)^-1 (mu_i - mu_j) <
  merge_threshold`` join its group; the group becomes one moment-matched Gaussian (the paper
  sums the covariances, which ignores the spread of the means and inflates them; we
  moment-match instead). The paper sets the merged weight to the sum of the weights, which
  keeps the count but can exceed 1. Rules (``merge_weight``):

  - ``"bounded_sum"``: the paper's sum, kept a probability by admitting a particle to the
    group (nearest first) only while the sum stays ``<= 1``; the count ``sum w`` is kept
    exactly, and two particles that both surely exist are never merged.
  - ``"capped_sum"``: everything within the threshold merges, weight ``min(1, sum w)``; the
    excess over 1 is lost (read as duplicates of one target).
  - ``"union"``: ``1 - prod(1 - w)``, "at least one exists" for independent particles.
  - ``"auto"`` (default): ``"bounded_sum"`` on the superposition sensor, ``"capped_sum"`` on
    the grid. Why, measured (20 seeds, raster 24 looks, ``epsilon = 1e-3``): on
    ``superposition`` the data say almost nothing about the count (``z`` is a mean), so the
    weights must keep the prior's; ``capped_sum`` merged the two broad starting particles
    (with ``Sigma_i + Sigma_j`` of 24 cells^2 per axis everything is "close") into one of
    weight 1: count error 0.60 -> 0.00 and OSPA 1.91 -> 1.65..1.75 with ``bounded_sum`` (the
    OSPA depends on the randomly drawn starting means). On the grid a target whose particle
    was lost (a broad particle of weight ~1: with ``p_s = 1`` and no death floor nothing
    lowers it; measured before the floor) is found again by a birth, and ``capped_sum`` folds
    the two into one; ``bounded_sum`` keeps both,
    which measured better count error on ``default`` (0.54 vs 0.84) but worse GOSPA (2.25 vs
    2.10), slightly worse ``crossing`` (OSPA 1.07 vs 1.05) and an overcount on ``paper`` (4.4
    for 3 targets). Lattice starting priors (``L x L`` particles of weight ``n0 / L^2``) were
    worse on ``superposition``: the likelihood of a mean favours *more* particles whose mean
    matches ``z`` (it shrinks the predicted spread), so the count drifted up (3.98 with L = 2,
    8.2 with L = 3, truth 2).
* **Prune**: drop ``w < prune_threshold``; keep at most ``max_particles`` (the heaviest).

Births and the initial prior (``births=True``):

* Grid sensor: an *undetected-target field* ``u (n_cells,)`` holds, per cell, the
  probability that an as yet unseen target is there (start: ``initial_count_mean /
  n_cells``; each predict: ``u <- 1 - (1 - p_s u)(1 - birth_rate / n_cells)``, floored at
  ``birth_floor`` so a filter whose prior is wrong can still recover). At an update every
  looked cell with ``u_c > 0`` contributes a *candidate*: a particle with weight ``u_c``,
  uniform on the cell, that goes through the same update as the other particles (so a
  return that an existing particle explains gives it little weight). A candidate whose
  cell returned a detection becomes a Gaussian particle (cell centre, position variance
  ``cell^2/12``, velocity ``N(0, birth_velocity_std^2)``); the others give their posterior
  weight back to the field (``u_c <- w'``, which drops after negative looks). The field does
  not move with the targets: it is a per-cell probability without a velocity, and its
  predict only adds births (no diffusion with ``F``, ``Q``). That is an approximation for
  slow targets: on ``default`` (~0.1 cell/step, a raster revisits a cell every 6 steps) an
  undetected target stays near the cells that hold its mass; on ``paper`` (jumps of ~4.5
  cells/step) the field lags the targets and negative looks empty it where they were.
* Superposition sensor: the initial prior is ``ceil(n0)`` broad particles (uniform-matched
  position covariance over the workspace, means drawn uniformly with the run's
  generator), each with weight ``n0 / ceil(n0)``; each step with ``birth_rate > 0`` adds
  one such particle with weight ``min(birth_rate, 0.5)``.

What the paper's method can and cannot do on the superposition sensor: the data are the
mean of the positions, so (i) with the number of present particles fixed, the update is the
exact Kalman update of the stacked state and it pins the *mean* of the targets, but the
differences between targets are unobservable, so individual states stay wrong by about half
the targets' separation unless the prior places them (the broad starting particles do not);
folding each combination back into one Gaussian per particle also drops the cross-covariance
the update creates, so each particle's covariance shrinks as if its own position were
measured (over-confident). (ii) The count enters the likelihood only through ``1/n`` and
the predicted spread, which favours *any* set of particles whose mean matches ``z`` -- the
count is not identifiable from the data and is carried by the prior weights; the filter's
job is to not lose it (hence ``bounded_sum`` there).

``births=False`` turns all of that off (empty prior, no births), for reduction tests.

Estimate (``extraction``): ``"round_sum"`` reports the ``round(sum w)`` heaviest
particles; ``"threshold"`` those with ``w > extraction_threshold``. The count is ``sum w``.

``P_c(t)``: independent Bernoullis per cell -- particle ``i`` in cell ``c`` with probability
``w_i m_ic`` (product-of-marginals cell mass, :func:`trackers.cells.gaussian_cell_mass`) and
the field's ``u_c`` -- summed by :func:`trackers.cells.poisson_binomial`.
"""

from __future__ import annotations

import functools
import math

import numpy as np
from scipy.special import ndtr

from ..scenarios.model import Looks, RayleighGridSensor, TrackingModel
from . import kalman
from .base import Estimate, Tracker, register
from .cells import gaussian_cell_mass, poisson_binomial
from .gpf_grid import grid_update
from .gpf_linear import superposition_update

_POS = np.array([0, 2])
_MERGE_RULES = ("bounded_sum", "capped_sum", "union")
_MERGE_CHOICES = _MERGE_RULES + ("auto",)
#: slack on "the group's weight sum stays <= 1" (float round-off of weights that are 1)
_SUM_TOL = 1e-9
#: per-step death probability floor of the grid tracker with births (``death_probability=None``)
DEFAULT_DEATH_FLOOR = 0.003


@functools.lru_cache(maxsize=256)
def _upper_pairs(K: int) -> tuple[np.ndarray, np.ndarray]:
    """``np.triu_indices(K, 1)``, cached (the particle count repeats from step to step)."""
    iu, ju = np.triu_indices(K, 1)
    iu.flags.writeable = False
    ju.flags.writeable = False
    return iu, ju


def _pair_distances(m: np.ndarray, P: np.ndarray, threshold: float) -> np.ndarray:
    """``d2 (K, K)``: ``(mu_i - mu_j)^T (Sigma_i + Sigma_j)^-1 (mu_i - mu_j)`` where it can be
    below ``threshold``, ``inf`` elsewhere (and on the diagonal).

    The position-only form is a lower bound of the full one (a marginal's quadratic form never
    exceeds the joint's), so it screens the pairs in closed form (2x2 inverse) and the 4x4
    solve runs only on the pairs that pass.
    """
    K = len(m)
    iu, ju = _upper_pairs(K)
    diff = m[iu] - m[ju]  # (n_pairs, 4)
    S = P[iu] + P[ju]
    a, b, c = S[:, 0, 0], S[:, 0, 2], S[:, 2, 2]
    dx, dy = diff[:, 0], diff[:, 2]
    det = a * c - b * b
    with np.errstate(divide="ignore", invalid="ignore"):
        lower = (c * dx * dx - 2.0 * b * dx * dy + a * dy * dy) / det
    cand = ~(lower >= threshold)  # NaN (degenerate) pairs go to the exact solve
    d2 = np.full((K, K), np.inf)
    if np.any(cand):
        dc = diff[cand]
        full = np.einsum("ka,ka->k", dc, np.linalg.solve(S[cand], dc[..., None])[..., 0])
        d2[iu[cand], ju[cand]] = full
        d2[ju[cand], iu[cand]] = full
    return d2


def merge_particles(w: np.ndarray, m: np.ndarray, P: np.ndarray, threshold: float,
                    rule: str = "capped_sum") -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Greedy Mahalanobis merging (module docstring). Shapes ``(K,)``, ``(K, 4)``, ``(K, 4, 4)``.

    Returns the merged ``w``, ``m``, ``P``; a group's Gaussian is the ``w``-weighted moment
    match ``m = sum w_j m_j / sum w_j``, ``P = sum w_j (P_j + (m_j - m)(m_j - m)^T) / sum w_j``.
    Groups are formed from the heaviest remaining particle ``i`` (distances to the original
    ``mu_i``, ``Sigma_i``); with ``"bounded_sum"`` the particles within the threshold join in
    order of increasing distance, each only if the group's weight sum stays ``<= 1``.
    """
    if rule not in _MERGE_RULES:
        raise ValueError(f"merge_weight must be one of {_MERGE_RULES}, got {rule!r}")
    K = len(w)
    if K <= 1 or threshold <= 0:
        return w, m, P
    order = np.argsort(-w, kind="stable")
    w, m, P = w[order], m[order], P[order]
    close = _pair_distances(m, P, threshold)
    label = np.full(K, -1)
    out_w = []
    for i in range(K):
        if label[i] >= 0:
            continue
        g = len(out_w)
        label[i] = g
        grp = np.nonzero((close[i] < threshold) & (label < 0))[0]
        if rule == "bounded_sum":
            tot = w[i]
            for j in grp[np.argsort(close[i, grp], kind="stable")]:
                if tot + w[j] <= 1.0 + _SUM_TOL:
                    label[j] = g
                    tot += w[j]
            out_w.append(min(tot, 1.0))
        else:
            label[grp] = g
            wg = w[label == g]
            out_w.append(min(1.0, wg.sum()) if rule == "capped_sum"
                         else 1.0 - np.prod(1.0 - wg))
    n_g = len(out_w)
    if n_g == K:
        return np.array(out_w), m, P
    # w-weighted moment match per group; a group of total weight 0 keeps its head's Gaussian
    tot = np.bincount(label, weights=w, minlength=n_g)
    head = np.unique(label, return_index=True)[1]  # the first member is the group's head
    safe = np.where(tot > 0.0, tot, 1.0)
    wn = np.where(tot[label] > 0.0, w / safe[label], (np.arange(K) == head[label]) * 1.0)
    mean = np.zeros((n_g, 4))
    np.add.at(mean, label, wn[:, None] * m)
    dev = m - mean[label]
    cov = np.zeros((n_g, 4, 4))
    np.add.at(cov, label, wn[:, None, None] * (P + dev[:, :, None] * dev[:, None, :]))
    return np.array(out_w), mean, cov


@register
class GaussianParticleFilter(Tracker):
    """The paper's GPF; see the module docstring for the equations and every choice."""

    name = "gpf"
    summary = "Gaussian particle filter (paper): existence-weighted Gaussians, combinations E"

    def __init__(self, epsilon: float = 1e-4, max_combinations: int = 512,
                 interaction_threshold: float = 1e-3, merge_threshold: float = 4.0,
                 merge_weight: str = "auto", prune_threshold: float = 1e-3,
                 max_particles: int = 100, births: bool = True, birth_floor: float = 1e-4,
                 extraction: str = "round_sum", extraction_threshold: float = 0.5,
                 n_counts: int = 4, death_probability: float | None = None) -> None:
        self.epsilon = epsilon
        self.max_combinations = max_combinations
        self.interaction_threshold = interaction_threshold
        self.merge_threshold = merge_threshold
        self.merge_weight = merge_weight
        self.prune_threshold = prune_threshold
        self.max_particles = max_particles
        self.births = births
        self.birth_floor = birth_floor
        self.extraction = extraction
        self.extraction_threshold = extraction_threshold
        self.n_counts = n_counts
        self.death_probability = death_probability

    # ------------------------------------------------------------------ state
    def reset(self, model: TrackingModel, rng: np.random.Generator) -> None:
        if self.merge_weight not in _MERGE_CHOICES:
            raise ValueError(f"merge_weight must be one of {_MERGE_CHOICES}, "
                             f"got {self.merge_weight!r}")
        if self.extraction not in ("round_sum", "threshold"):
            raise ValueError(f"extraction must be 'round_sum' or 'threshold', "
                             f"got {self.extraction!r}")
        self._model = model
        self._rng = rng
        self._F, self._Q = model.dynamics.F, model.dynamics.Q
        self._grid = model.grid
        self._merge_rule = (self.merge_weight if self.merge_weight != "auto"
                            else "capped_sum" if model.is_grid else "bounded_sum")
        floor = self.death_probability
        if floor is None:
            floor = DEFAULT_DEATH_FLOOR if (self.births and model.is_grid) else 0.0
        if not 0.0 <= floor <= 1.0:
            raise ValueError(f"death_probability must be in [0, 1], got {floor!r}")
        #: the survival probability the filter predicts with: min(p_s, 1 - floor)
        self._survival = min(model.birth_death.survival_probability, 1.0 - floor)
        self._w = np.zeros(0)
        self._m = np.zeros((0, 4))
        self._P = np.zeros((0, 4, 4))
        bd = model.birth_death
        n0 = bd.initial_count_mean
        n_cells = model.grid.n_cells
        self._u = np.zeros(n_cells)
        self.last_dropped = 0.0
        if not self.births:
            return
        if model.is_grid:
            self._u[:] = max(min(n0 / n_cells, 0.5), self.birth_floor)
        elif n0 > 0:
            n = math.ceil(n0)
            self._add_broad(n, n0 / n)

    def set_particles(self, w: np.ndarray, m: np.ndarray, P: np.ndarray) -> None:
        """Replace the particle set (tests, warm starts): ``(K,)``, ``(K,4)``, ``(K,4,4)``."""
        self._w = np.array(w, dtype=float).reshape(-1)
        self._m = np.array(m, dtype=float).reshape(-1, 4)
        self._P = np.array(P, dtype=float).reshape(-1, 4, 4)

    @property
    def particles(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Copies of ``w (K,)``, ``means (K, 4)``, ``covs (K, 4, 4)``."""
        return self._w.copy(), self._m.copy(), self._P.copy()

    def _broad_cov(self) -> np.ndarray:
        width, height = self._grid.extent
        vs = self._model.birth_death.birth_velocity_std ** 2
        return np.diag([width**2 / 12.0, vs, height**2 / 12.0, vs])

    def _add_broad(self, n: int, weight: float) -> None:
        width, height = self._grid.extent
        m = np.zeros((n, 4))
        m[:, 0] = self._rng.uniform(0.0, width, n)
        m[:, 2] = self._rng.uniform(0.0, height, n)
        self._append(np.full(n, weight), m, np.repeat(self._broad_cov()[None], n, axis=0))

    def _append(self, w: np.ndarray, m: np.ndarray, P: np.ndarray) -> None:
        self._w = np.concatenate([self._w, w])
        self._m = np.concatenate([self._m, m])
        self._P = np.concatenate([self._P, P])

    # ---------------------------------------------------------------- predict
    def predict(self) -> None:
        bd = self._model.birth_death
        self._m, self._P = kalman.predict(self._m, self._P, self._F, self._Q)
        self._w = self._w * self._survival
        width, height = self._grid.extent
        if bd.boundary == "reflect":
            for axis, length in ((0, width), (2, height)):
                self._reflect_axis(axis, length)
        elif len(self._w):
            sx = np.sqrt(self._P[:, 0, 0])
            sy = np.sqrt(self._P[:, 2, 2])
            inside = ((ndtr((width - self._m[:, 0]) / sx) - ndtr(-self._m[:, 0] / sx))
                      * (ndtr((height - self._m[:, 2]) / sy) - ndtr(-self._m[:, 2] / sy)))
            self._w = self._w * inside
        if not self.births:
            return
        n_cells = self._grid.n_cells
        if self._model.is_grid:
            b = bd.birth_rate / n_cells
            self._u = 1.0 - (1.0 - self._survival * self._u) * (1.0 - b)
            np.maximum(self._u, self.birth_floor, out=self._u)
        elif bd.birth_rate > 0:
            self._add_broad(1, min(bd.birth_rate, 0.5))

    def _reflect_axis(self, axis: int, length: float) -> None:
        """Mirror means outside ``[0, length)`` on one axis: ``p -> -p`` or ``2L - p``,
        ``v -> -v``; the covariance becomes ``J P J`` with ``J`` negating that axis."""
        p = self._m[:, axis]
        low, high = p < 0.0, p >= length
        flip = low | high
        if not np.any(flip):
            return
        self._m[low, axis] = -p[low]
        self._m[high, axis] = 2.0 * length - p[high]
        self._m[flip, axis + 1] *= -1.0
        sign = np.ones(4)
        sign[axis:axis + 2] = -1.0
        self._P[flip] = self._P[flip] * sign[:, None] * sign[None, :]

    # ------------------------------------------------------- count distribution
    def cell_count_distribution(self) -> np.ndarray:
        probs = np.zeros((0, self._grid.n_cells))
        if len(self._w):
            mass = gaussian_cell_mass(self._grid, self._m[:, _POS],
                                      self._P[:, _POS][:, :, _POS])
            probs = self._w[:, None] * mass
        if np.any(self._u > 0):
            probs = np.concatenate([probs, self._u[None]])
        return poisson_binomial(probs, self.n_counts)

    # ----------------------------------------------------------------- update
    def update(self, looks: Looks) -> None:
        sensor = self._model.sensor
        if isinstance(sensor, RayleighGridSensor):
            if len(looks):
                self._update_grid(looks, sensor)
        elif looks.z is not None:
            res = superposition_update(self._w, self._m, self._P, np.asarray(looks.z, float),
                                       sensor.H, sensor.R, self.epsilon, self.max_combinations)
            self._w, self._m, self._P = res.weights, res.means, res.covs
            self.last_dropped = res.dropped
        self._merge_and_prune()

    def _update_grid(self, looks: Looks, sensor: RayleighGridSensor) -> None:
        K = len(self._w)
        looked = np.unique(looks.cells)
        cand = looked[self._u[looked] > 0.0] if self.births else looked[:0]
        n_c = len(cand)
        s = self._grid.cell_size
        centres = self._grid.cell_centers(cand)
        vs = self._model.birth_death.birth_velocity_std ** 2
        cm = np.zeros((n_c, 4))
        cm[:, 0], cm[:, 2] = centres[:, 0], centres[:, 1]
        cP = np.repeat(np.diag([s * s / 12.0, vs, s * s / 12.0, vs])[None], n_c, axis=0)
        w = np.concatenate([self._w, self._u[cand]])
        m = np.concatenate([self._m, cm])
        P = np.concatenate([self._P, cP])
        ucell = np.concatenate([np.full(K, -1, dtype=np.int64), cand])
        res = grid_update(w, m, P, ucell, looks.cells, looks.returns, self._grid, sensor,
                          self.epsilon, self.max_combinations, self.interaction_threshold)
        self.last_dropped = res.dropped
        wc = res.weights[K:]
        detected = np.zeros(self._grid.n_cells, dtype=bool)
        detected[looks.cells[looks.returns]] = True
        promote = detected[cand] & (wc > self.prune_threshold)
        self._u[cand] = np.where(promote, 0.0, wc)
        if self.births:
            np.maximum(self._u, self.birth_floor, out=self._u)
        keep = np.concatenate([np.ones(K, dtype=bool), promote])
        self._w, self._m, self._P = res.weights[keep], res.means[keep], res.covs[keep]

    def _merge_and_prune(self) -> None:
        alive = self._w >= self.prune_threshold
        w, m, P = self._w[alive], self._m[alive], self._P[alive]
        w, m, P = merge_particles(w, m, P, self.merge_threshold, self._merge_rule)
        if len(w) > self.max_particles:
            top = np.argsort(-w, kind="stable")[: self.max_particles]
            w, m, P = w[top], m[top], P[top]
        self._w, self._m, self._P = w, m, P

    # --------------------------------------------------------------- estimate
    def estimate(self) -> Estimate:
        count = float(self._w.sum())
        if self.extraction == "round_sum":
            n = min(int(round(count)), len(self._w))
            sel = np.argsort(-self._w, kind="stable")[:n]
        else:
            sel = np.nonzero(self._w > self.extraction_threshold)[0]
        return Estimate(count, self._m[sel].copy(), self._P[sel].copy())
