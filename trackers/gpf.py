"""The paper's Gaussian particle filter (GPF), on the superposition and the grid sensor.

Each particle is ``{w_i, N(mu_i, Sigma_i)}``: ``w_i`` is the probability that a target
with that Gaussian exists, and the estimated count is ``sum_i w_i`` (paper Section IV).
Arrays: ``w (K,)``, ``means (K, 4)``, ``covs (K, 4, 4)``; states ``[px, vx, py, vy]``.
The measurements behind the defaults, with commands that repeat them: docs/gpf.md.

Step (the harness calls predict, then update, then estimate):

* **Predict**: ``mu <- F mu``, ``Sigma <- F Sigma F^T + Q``, ``w <- p w`` with the survival
  ``p = min(p_s, 1 - death_probability)``. No probability stays outside the workspace
  (``truncate=True``, issue 14): under "reflect" the mass beyond a wall is mirrored back
  (position and that axis's velocity; :func:`.gpf_grid.fold_into_workspace`, the
  Gaussian's reflection images restricted to the workspace, moment matched), under
  "die" ``w`` is multiplied by the mass inside and the
  Gaussian becomes its truncation to the workspace (:func:`truncate_to_workspace`). So a
  broad Gaussian pays, in the grid update, for the looks that found nothing where its mass
  is (before, mass outside counted as "elsewhere", likelihood 1). ``truncate=False``
  keeps the earlier rule: mirror a mean that left (signs flipped), or weigh by the
  product of the marginal masses inside without truncating. Truncating under "reflect"
  instead of folding held tracks at the wall (``default``, every cell looked, 6 seeds:
  OSPA 0.433 -> 0.544); folding gives 0.400.
* **Death floor** (not in the paper): ``death_probability=None`` is ``DEFAULT_DEATH_FLOOR``
  on the grid sensor with births, else ``0`` (the model's ``p_s``). With ``p_s = 1`` each
  detection adds ``log l(1) = 6.9`` to the log-odds, ``w`` rounds to 1.0 and a lost track
  keeps ``w = 1`` while its covariance grows; the floor ``f`` caps the log-odds after each
  predict at ``log((1 - f) / f)``, so negative looks lower them again. 0.003, the smallest
  floor tried, frees such weights at no OSPA cost and a count cost within noise (``default``,
  ``crossing``); larger floors remove more lost tracks for more count error; ``1e-15`` is no
  fix (docs/gpf.md).
* **Update**: :mod:`trackers.gpf_linear` (superposition: the paper's combinations ``E`` and
  appendix gain, moment-matched fold-back) or :mod:`trackers.gpf_grid` (grid: truncated
  Gaussians, exact Bernoulli weights, combinations per cluster sharing a looked cell).
* **Combinations**: as in the paper, cut on their *prior* probability ``<= epsilon``, at most
  ``max_combinations`` (the most probable) kept, renormalised. ``epsilon = 1e-4`` (was
  ``1e-3``): 2.5x smaller weight error per update at the same cost, closed-loop scores
  unchanged within noise (docs/gpf.md).
* **Merge** (the paper's Mahalanobis rule): greedily from the heaviest particle ``i``, those
  ``j`` with ``(mu_i - mu_j)^T (Sigma_i + Sigma_j)^-1 (mu_i - mu_j) < merge_threshold``
  join it; a group becomes one moment-matched Gaussian (the paper sums the covariances). The
  paper's merged weight, the sum, can exceed 1; ``merge_weight``: ``"bounded_sum"`` admits
  members (nearest first) while the sum stays ``<= 1`` (``sum w`` kept exactly);
  ``"capped_sum"`` takes all, weight ``min(1, sum w)``; ``"union"`` ``1 - prod(1 - w)``.
  ``"auto"`` (default): ``"bounded_sum"`` on the superposition sensor, which hardly informs
  the count; ``"capped_sum"`` on the grid (better GOSPA, no overcount on ``paper``)
  (docs/gpf.md).
* **Prune**: drop ``w < prune_threshold``; keep at most ``max_particles`` (the heaviest).
* **Split** (``split_sd > 0``, off by default): before a grid update, a Gaussian whose
  position sd exceeds ``split_sd`` cells is split in three along its broadest axis keeping
  the mixture's first two moments (:func:`split_broad`). Off because the pieces become
  independent Bernoullis: a certain target split into ``w (1/4, 1/2, 1/4)`` loses half its
  existence at one step of misses (``paper``, every cell looked: OSPA 1.80 -> 1.56 but
  the count error stays 1.7, and ``default`` at raster 24 counts worse, 0.78 -> 0.90).

Births and the initial prior (``births=False``: empty prior, no births, for reduction tests):

* Grid: an undetected-target field ``u (n_cells,)`` (per cell, the probability of an unseen
  target): ``initial_count_mean / n_cells`` at first, ``u <- 1 - (1 - p u)(1 - birth_rate /
  n_cells)`` at each predict, floored at ``birth_floor``; with ``count_aware_births``
  (off by default) the field holds at least the targets the model expects and no
  particle holds, ``m(k) - sum w`` (scaled up keeping its shape), so that a detection a
  lost target made can start a track against a broad particle that would otherwise
  absorb it. Off: measured it does not help (``paper``, every cell looked, 6 seeds:
  OSPA 1.58 -> 1.55, count error 1.73 -> 1.71) and it widens the runs' spread (20
  seeds: ``births`` raster 24 +0.036 ± 0.039, ``crossing`` renyi 24 -0.002 ± 0.088
  against +0.023 ± 0.072 without it). Each looked
  cell with ``u_c > 0`` adds a candidate (weight ``u_c``, uniform on the cell) to the
  update; after it, a candidate whose cell returned a detection becomes a Gaussian (cell
  centre, position variance
  ``cell^2 / 12``, velocity sd ``birth_velocity_std``), the others go back to ``u_c``. The
  field does not move with the targets: fine for slow ones, lagging on ``paper``.
* Superposition: ``ceil(n0)`` broad particles (uniform-matched covariance, means drawn with
  the tracker's generator) of weight ``n0 / ceil(n0)``; with ``birth_rate > 0`` one more each step
  (weight ``min(birth_rate, 0.5)``). Lattice priors drift the count up (docs/gpf.md). ``z``
  is a mean: the update pins the targets' mean, not their differences, the fold-back drops
  the cross-covariance (over-confident particles), and the count rests on the prior weights.

Estimate (``extraction``): ``"round_sum"`` reports the ``round(sum w)`` heaviest particles,
``"threshold"`` those with ``w > extraction_threshold``; the count is ``sum w``. ``P_c(t)``:
per cell, independent Bernoullis -- particle ``i`` with ``w_i m_ic``
(:func:`trackers.cells.gaussian_cell_mass`) and the field's ``u_c`` -- summed by
:func:`trackers.cells.poisson_binomial`.
"""

from __future__ import annotations

import functools
import math
from typing import ClassVar

import numpy as np
from scipy.special import ndtr

from ..scenarios.model import Looks, RayleighGridSensor, TrackingModel
from . import kalman
from .base import Estimate, Tracker, register
from .cells import gaussian_cell_mass, poisson_binomial
from .gpf_grid import fold_into_workspace, grid_update, rect_state_moments
from .gpf_linear import superposition_update
from .params import Param

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


#: a moment-preserving split of one axis into three: weights, offsets in sd, residual sd
#: (1/4 a^2 + 1/4 a^2 + r^2 = 1 with r = 1/2: a = sqrt(3/2))
_SPLIT_W = np.array([0.25, 0.5, 0.25])
_SPLIT_R = 0.5
_SPLIT_A = math.sqrt((1.0 - _SPLIT_R**2) / (2.0 * 0.25))


def truncate_to_workspace(m: np.ndarray, P: np.ndarray, width: float, height: float,
                          tol: float = 1e-9) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each Gaussian restricted to the workspace ``[0, width) x [0, height)`` and moment
    matched (mean and covariance of the truncated density, velocities by regression on
    position, :func:`.gpf_grid.rect_state_moments`). Returns ``mass (K,)`` (the Gaussian's
    mass inside) and the new ``m``, ``P``; Gaussians with mass inside above ``1 - tol``
    are returned unchanged."""
    K = len(m)
    mass = np.ones(K)
    if K == 0:
        return mass, m, P
    # which Gaussians reach outside: the marginals' masses (closed form; the quadrature
    # of rect_state_moments is ~1e-5 off for very narrow Gaussians, so it is used only
    # where there is mass outside to account for)
    sx, sy = np.sqrt(P[:, 0, 0]), np.sqrt(P[:, 2, 2])
    inside = ((ndtr((width - m[:, 0]) / sx) - ndtr(-m[:, 0] / sx))
              * (ndtr((height - m[:, 2]) / sy) - ndtr(-m[:, 2] / sy)))
    sel = np.nonzero(inside < 1.0 - tol)[0]
    if len(sel) == 0:
        return mass, m, P
    n = len(sel)
    zero, wid, hei = np.zeros(n), np.full(n, float(width)), np.full(n, float(height))
    mass_in, M1, M2 = rect_state_moments(m[sel], P[sel], zero, wid, zero, hei)
    ok = mass_in > 1e-12
    mass[sel] = np.where(ok, np.minimum(mass_in, 1.0), 0.0)
    sel, mass_in, M1, M2 = sel[ok], mass_in[ok], M1[ok], M2[ok]
    m, P = m.copy(), P.copy()
    d = M1 / mass_in[:, None]
    m[sel] = m[sel] + d
    cv = M2 / mass_in[:, None, None] - d[:, :, None] * d[:, None, :]
    P[sel] = 0.5 * (cv + np.swapaxes(cv, -1, -2))
    return mass, m, P


def split_broad(w: np.ndarray, m: np.ndarray, P: np.ndarray, max_sd: float,
                max_particles: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Split every Gaussian whose position spread (the larger eigenvalue's sd of its
    position covariance) exceeds ``max_sd`` into three along that eigenvector, keeping the
    first two moments of the mixture exactly: weights ``w (1/4, 1/2, 1/4)``, means shifted
    by ``(-a, 0, a) sigma`` along ``e`` with the velocities following by regression
    (``P e / sigma^2`` times the shift), covariance ``P - (1 - r^2) (P e)(P e)^T /
    sigma^2`` (``r = 1/2``, ``a = sqrt(3/2)``). Repeated until no Gaussian is broader or
    the split would exceed ``max_particles``; the broadest are split first."""
    pos = [0, 2]
    while len(w):
        Spp = P[:, pos][:, :, pos]
        evals, evecs = np.linalg.eigh(Spp)
        sd = np.sqrt(np.maximum(evals[:, -1], 0.0))
        broad = np.nonzero(sd > max_sd)[0]
        room = (max_particles - len(w)) // 2
        if len(broad) == 0 or room <= 0:
            break
        broad = broad[np.argsort(-sd[broad], kind="stable")][:room]
        e = np.zeros((len(broad), 4))
        e[:, pos] = evecs[broad, :, -1]
        Pe = (P[broad] @ e[..., None])[..., 0]  # (B, 4)
        var = sd[broad] ** 2
        g = Pe / var[:, None]  # the state's regression on the position along e
        shifts = np.array([-_SPLIT_A, 0.0, _SPLIT_A])[None, :] * sd[broad][:, None]  # (B, 3)
        new_m = m[broad][:, None, :] + shifts[..., None] * g[:, None, :]
        new_P = (P[broad] - (1.0 - _SPLIT_R**2) * Pe[:, :, None] * Pe[:, None, :]
                 / var[:, None, None])
        new_w = w[broad][:, None] * _SPLIT_W[None, :]
        keep = np.ones(len(w), dtype=bool)
        keep[broad] = False
        w = np.concatenate([w[keep], new_w.reshape(-1)])
        m = np.concatenate([m[keep], new_m.reshape(-1, 4)])
        P = np.concatenate([P[keep], np.repeat(new_P, 3, axis=0)])
    return w, m, P


@register
class GaussianParticleFilter(Tracker):
    """The paper's GPF; see the module docstring for the equations and every choice."""

    name = "gpf"
    summary = "Gaussian particle filter (paper): existence-weighted Gaussians, combinations E"
    parameters: ClassVar[dict[str, Param]] = {
        "epsilon": Param(float, 0, 1, high_open=True,
                         doc="combinations with prior probability <= epsilon are cut"),
        "max_combinations": Param(int, 1, doc="at most this many combinations kept"),
        "interaction_threshold": Param(float, 0, 1, high_open=True,
                                       doc="w m_c above it: the particle takes part in a cell"),
        "merge_threshold": Param(float, 0, doc="squared Mahalanobis distance; 0: no merging"),
        "merge_weight": Param(choices=_MERGE_CHOICES, doc="merged weight rule"),
        "prune_threshold": Param(float, 0, 1, high_open=True, doc="drop w below it"),
        "max_particles": Param(int, 1, doc="keep at most this many (the heaviest)"),
        "births": Param(bool, doc="False: empty prior, no births"),
        "birth_floor": Param(float, 0, 1, doc="floor of the undetected-target field u"),
        "extraction": Param(choices=("round_sum", "threshold"), doc="which particles are "
                            "reported"),
        "extraction_threshold": Param(float, 0, 1, doc="w above it is reported (threshold)"),
        "n_counts": Param(int, 2, doc="count columns of P_c(t)"),
        "death_probability": Param(float, 0, 1, allow_none=True,
                                   none="DEFAULT_DEATH_FLOOR on the grid with births, else 0",
                                   doc="per-step death floor"),
        "split_sd": Param(float, 0, doc="grid: split Gaussians broader than this (cells, "
                                        "position sd) before an update; 0: never"),
        "truncate": Param(bool, doc="keep each Gaussian inside the workspace (moment-matched "
                                    "truncation after predict)"),
        "count_aware_births": Param(bool, doc="grid: the undetected field holds at least the "
                                              "targets the model expects and no particle "
                                              "holds"),
    }

    def __init__(self, epsilon: float = 1e-4, max_combinations: int = 512,
                 interaction_threshold: float = 1e-3, merge_threshold: float = 4.0,
                 merge_weight: str = "auto", prune_threshold: float = 1e-3,
                 max_particles: int = 100, births: bool = True, birth_floor: float = 1e-4,
                 extraction: str = "round_sum", extraction_threshold: float = 0.5,
                 n_counts: int = 4, death_probability: float | None = None,
                 split_sd: float = 0.0, truncate: bool = True,
                 count_aware_births: bool = False) -> None:
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
        self.split_sd = split_sd
        self.truncate = truncate
        self.count_aware_births = count_aware_births

    # ------------------------------------------------------------------ state
    def reset(self, model: TrackingModel, rng: np.random.Generator) -> None:
        self.validate_params(self.get_params())  # the declaration above (built directly)
        self._model = model
        self._rng = rng
        self._F, self._Q = model.dynamics.F, model.dynamics.Q
        self._grid = model.grid
        self._merge_rule = (self.merge_weight if self.merge_weight != "auto"
                            else "capped_sum" if model.is_grid else "bounded_sum")
        floor = self.death_probability
        if floor is None:
            floor = DEFAULT_DEATH_FLOOR if (self.births and model.is_grid) else 0.0
        #: the survival probability the filter predicts with: min(p_s, 1 - floor)
        self._survival = min(model.birth_death.survival_probability, 1.0 - floor)
        self._w = np.zeros(0)
        self._m = np.zeros((0, 4))
        self._P = np.zeros((0, 4, 4))
        bd = model.birth_death
        n0 = bd.initial_count_mean
        n_cells = model.grid.n_cells
        self._u = np.zeros(n_cells)
        self._k = -1  # steps predicted so far, minus one
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
        # x before y: the order of the draws is part of the results
        xy = np.column_stack([self._rng.uniform(0.0, width, n), self._rng.uniform(0.0, height, n)])
        self._append(np.full(n, weight), kalman.at_rest(xy),
                     np.repeat(self._broad_cov()[None], n, axis=0))

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
            if self.truncate and len(self._w):
                # no probability outside: the mass beyond a wall is reflected back
                self._m, self._P = fold_into_workspace(self._m, self._P, self._grid)
            else:
                for axis, length in ((0, width), (2, height)):
                    self._reflect_axis(axis, length)
        elif self.truncate and len(self._w):
            # the mass that left is death; what stays is the Gaussian inside
            mass, self._m, self._P = truncate_to_workspace(self._m, self._P, width, height)
            self._w = self._w * mass
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
            if self.count_aware_births:
                self._respread_missing()
            np.maximum(self._u, self.birth_floor, out=self._u)
        elif bd.birth_rate > 0:
            self._add_broad(1, min(bd.birth_rate, 0.5))

    def _respread_missing(self) -> None:
        """Targets the model expects but no particle holds go back to the undetected
        field: when ``sum u`` is below ``m(k) - sum w`` (``m(k)`` the model's expected
        count at this step), ``u`` is scaled up to it, keeping its shape (uniform when it
        is empty), each cell at most 1/2. Without it a fixed-count model's field decays
        to its floor under misses and a target a track lost can only be taken by that
        track (paper: the GPF held 1 of 3 targets)."""
        bd = self._model.birth_death
        self._k += 1
        p_s, b = bd.survival_probability, bd.birth_rate
        keep = p_s ** self._k
        expected = bd.initial_count_mean * keep + (
            b * self._k if p_s == 1.0 else b * (1.0 - keep) / (1.0 - p_s))
        missing = expected - float(self._w.sum())
        total = float(self._u.sum())
        if missing <= total:
            return
        shape = self._u / total if total > 0 else np.full(len(self._u), 1.0 / len(self._u))
        np.minimum(missing * shape, 0.5, out=self._u)

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
            mass = gaussian_cell_mass(self._grid, *kalman.position_marginal(self._m, self._P))
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
        self._merge_and_prune()

    def _update_grid(self, looks: Looks, sensor: RayleighGridSensor) -> None:
        if self.split_sd > 0 and len(self._w):
            self._w, self._m, self._P = split_broad(
                self._w, self._m, self._P, self.split_sd * self._grid.cell_size,
                self.max_particles)
        K = len(self._w)
        looked = np.unique(looks.cells)
        cand = looked[self._u[looked] > 0.0] if self.births else looked[:0]
        n_c = len(cand)
        s = self._grid.cell_size
        cm = kalman.at_rest(self._grid.cell_centers(cand))
        vs = self._model.birth_death.birth_velocity_std ** 2
        cP = np.repeat(np.diag([s * s / 12.0, vs, s * s / 12.0, vs])[None], n_c, axis=0)
        w = np.concatenate([self._w, self._u[cand]])
        m = np.concatenate([self._m, cm])
        P = np.concatenate([self._P, cP])
        ucell = np.concatenate([np.full(K, -1, dtype=np.int64), cand])
        res = grid_update(w, m, P, ucell, looks.cells, looks.returns, self._grid, sensor,
                          self.epsilon, self.max_combinations, self.interaction_threshold)
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
