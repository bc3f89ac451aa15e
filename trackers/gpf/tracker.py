"""The paper's Gaussian particle filter (GPF), on the superposition and the grid sensor.

Each particle is ``{w_i, N(mu_i, Sigma_i)}``: ``w_i`` is the probability that a target
with that Gaussian exists, and the estimated count is ``sum_i w_i`` (paper Section IV).
Arrays: ``w (K,)``, ``means (K, 4)``, ``covs (K, 4, 4)``; states ``[px, vx, py, vy]``.
The measurements behind the defaults, with commands that repeat them, and the switches
retired with the measurement that retired each: docs/gpf.md.

On the grid sensor a particle ("track") may carry a mixture of up to ``max_components``
Gaussians (a Bernoulli with a Gaussian-mixture density, as in multi-Bernoulli filters; a
deviation from the paper, whose particle is one Gaussian, ``max_components=1``): a
detection a broad track may have made splits off as a component (``split_share``,
:func:`.grid.grid_update`) instead of being blended with the rest into a broader
Gaussian, while the track keeps one existence probability. Each component is predicted
like a particle; within a track components merge by the Bhattacharyya rule below, those
below ``_COMPONENT_FLOOR`` go, and beyond ``max_components`` the lightest are moment
matched into one. A track reports its component with the highest peak
``a / sqrt(det Sigma_pos)`` (``a`` its weight within the track), skipping one within a
cell of a state already reported by a heavier track (tracks that share a detection each
hold a component on it).

Step (the harness calls predict, then update, then estimate):

* **Predict**: ``mu <- F mu``, ``Sigma <- F Sigma F^T + Q``, ``w <- p w`` with the survival
  ``p = min(p_s, 1 - death_probability)``. No probability stays outside the workspace:
  under "reflect" the mass beyond a wall is mirrored back (position and that axis's
  velocity; :func:`.grid.fold_into_workspace`, the Gaussian's reflection images
  restricted to the workspace, moment matched), under "die" ``w`` is multiplied by the
  mass inside and the Gaussian becomes its truncation to the workspace
  (:func:`truncate_to_workspace`). So a broad Gaussian pays, in the grid update, for the
  looks that found nothing where its mass is.
* **Death floor** (not in the paper): ``death_probability=None`` is ``DEFAULT_DEATH_FLOOR``
  on the grid sensor with births on a model with arrivals, else ``0`` (the model's
  ``p_s``). With ``p_s = 1`` each detection adds ``log l(1) = 6.9`` to the log-odds, ``w``
  rounds to 1.0 and a lost track keeps ``w = 1`` while its covariance grows; the floor
  ``f`` caps the log-odds after each predict at ``log((1 - f) / f)``, so negative looks
  lower them again. The default is the smallest floor that frees such weights at no OSPA
  cost; larger floors remove more lost tracks for more count error. A model without
  arrivals gets none: there the floor is a death the model does not have, and each step it
  moves ``f sum w`` of existence into the undetected field (count bound, below), from
  which any detection no track holds starts a track at ``w ~ 1`` (``u l(1) >> 1`` at low
  ``p_f``); at density that is a stream of extra tracks (docs/gpf.md section 13).
* **Update**: :mod:`trackers.gpf.linear` (superposition: the paper's combinations ``E`` and
  appendix gain, moment-matched fold-back) or :mod:`trackers.gpf.grid` (grid: truncated
  Gaussians, exact Bernoulli weights, combinations per cluster of tracks sharing a
  detected cell, each member's looked cells without a detection pooled into one option,
  JPDA* against coalescence).
* **Combinations**: as in the paper, cut on their probability ``<= epsilon``, at most
  ``max_combinations`` (the most probable) kept, renormalised; on the grid the cut acts
  on the combinations' posterior (:mod:`.grid`, "missed cells"; a deviation: the
  paper cuts on the prior), and a track joins a detected cell's cluster when its
  probability of being in the cell, prior ``w m_c`` or updated alone ``w m_c l_c / (w L
  + 1 - w)``, exceeds ``INTERACTION_THRESHOLD`` (the second: at very low ``p_f`` a track
  updated apart can move much of itself into a neighbour's detected cell where it had
  almost none of its mass; docs/gpf.md section 14).
* **Count bound** (models without arrivals): such a model never has more targets than it
  started with, ``n0``, so after each update the existences are replaced by their
  marginals given ``count <= n0`` (:func:`condition_on_count_bound`, exact for
  independent Bernoullis), and the undetected field holds the targets no track holds
  (births, below); without it a fixed-count scene collects false tracks that a broad
  prediction keeps alive.
* **Merge** (the paper's Mahalanobis rule): greedily from the heaviest particle ``i``, those
  ``j`` with ``(mu_i - mu_j)^T (Sigma_i + Sigma_j)^-1 (mu_i - mu_j) < merge_threshold``
  join it; a group becomes one moment-matched Gaussian (the paper sums the covariances).
  The paper's merged weight, the sum, can exceed 1; the model decides the rule:
  ``"bounded_sum"`` (members join, nearest first, while the sum stays ``<= 1``, so ``sum
  w`` is kept exactly: two broad tracks of two targets stay two) on the superposition
  sensor and on models without arrivals; ``"capped_sum"`` (all join, weight ``min(1, sum
  w)``: a lost track and the birth that found its target again become one) on the grid
  with arrivals. Components within a track merge by the Bhattacharyya form
  (:func:`_pair_distances`), so a narrow component never joins a much broader one.
* **Prune**: drop ``w < prune_threshold``; keep at most ``max_particles`` (the heaviest).

Births and the initial prior (:class:`EmptyPriorGPF`, for tests: none of either):

* Grid: an undetected-target field ``u`` (per cell, the probability of an unseen
  target): ``initial_count_mean / n_cells`` at first (at least ``birth_floor``). At each
  predict, on a model with arrivals, ``u <- 1 - (1 - p u)(1 - birth_rate / n_cells)``,
  floored at ``birth_floor``; on a model without arrivals the field holds the targets the
  model expects and no particle holds, ``m(k) - sum w`` (``u`` scaled up or down keeping
  its shape, no floor), so that a detection a lost target made can start a track against
  a broad particle that would otherwise absorb it, and no more tracks start than the
  count leaves. Each looked cell with ``u_c > 0`` adds a candidate (weight ``u_c``,
  uniform on the cell) to the update; after it, a candidate whose cell returned a
  detection becomes a Gaussian (cell centre, position variance ``cell^2 / 12``, velocity
  sd ``birth_velocity_std``), the others go back to ``u_c``. The field does not move with
  the targets: fine for slow ones, lagging on ``paper``.
* Superposition: ``ceil(n0)`` broad particles (uniform-matched covariance, means drawn with
  the tracker's generator) of weight ``n0 / ceil(n0)``; with ``birth_rate > 0`` one more each
  step (weight ``min(birth_rate, 0.5)``); a lattice prior would drift the count up
  (docs/gpf.md). ``z`` is a mean: the update pins the targets'
  mean, not their differences, the fold-back drops the cross-covariance (over-confident
  particles), and the count rests on the prior weights.

Estimate (``extraction``): ``"round_sum"`` reports the ``round(sum w)`` heaviest particles,
``"threshold"`` those with ``w > extraction_threshold``; the count is ``sum w``. ``P_c(t)``:
per cell, independent Bernoullis -- particle ``i`` with ``w_i m_ic`` (its cell masses within
6 sd of each Gaussian; beyond, below 1e-9, left out) and the field's ``u_c`` -- summed by the
Poisson-binomial recurrence, as :class:`trackers.cells.CellCounts`: cells no particle reaches
share the field's common row.

Cost: nothing per step is ``O(cells)``. The field is stored as one common value plus the
cells whose value differs (those looked at); the update meets the looked cells within 6 sd
of each Gaussian; ``P_c`` covers the Gaussians' 6-sd boxes.
"""

from __future__ import annotations

import functools
import math
from typing import ClassVar

import numpy as np
from scipy.special import ndtr

from ...scenarios.model import Looks, RayleighGridSensor, TrackingModel
from .. import kalman
from ..base import (
    BOX_CELLS,
    LOOKED_CELL_BYTES,
    LOOKED_CELL_S,
    PAIR_BYTES,
    PAIR_S,
    TARGET_S,
    Estimate,
    ResourceTerms,
    Tracker,
    gaussian_boxes,
    param_number,
    register,
)
from ..cells import (
    CellCounts,
    CellField,
    bernoulli_cell_counts,
    gaussian_cell_mass_sparse,
)
from ..grid_backend import GPF_WAIT_S, compiled_gpf_kernels
from ..params import Budget, Param, Search
from .grid import (
    RANGE_SIGMAS,
    fold_into_workspace,
    grid_update,
    rect_state_moments,
    sorted_runs,
)
from .linear import superposition_update

#: merged weight rules of :func:`merge_groups` (module docstring, "Merge")
_MERGE_RULES = ("bounded_sum", "capped_sum")
#: on the grid, a track joins the cluster of a detected cell when its probability of being
#: in the cell, prior ``w m_c`` or updated alone, exceeds this (a birth candidate always
#: joins); below it the two are updated apart (:func:`.grid.grid_update`)
INTERACTION_THRESHOLD = 1e-3
#: slack on "the group's weight sum stays <= 1" (float round-off of weights that are 1)
_SUM_TOL = 1e-9
#: per-step death probability floor of the grid tracker with births on a model with arrivals
#: (``death_probability=None``; none without arrivals, docs/gpf.md section 13)
DEFAULT_DEATH_FLOOR = 0.003
#: a track's component with a smaller weight within the track is dropped
_COMPONENT_FLOOR = 0.02
# measured costs (:meth:`GaussianParticleFilter.resource_terms`, docs/resources.md)
#: bytes per GPF Gaussian (mean, covariance and their working copies)
GPF_GAUSSIAN_BYTES = 2048
#: per looked cell of the gpf: its birth candidate (a uniform row with its 4x4
#: covariance) and the update's per-cell arrays: 970-1,400 B measured above null (the
#: ``all`` policy on 300x300 and 700x700)
GPF_LOOK_BYTES = 2048
#: per looked cell of the gpf and step (its birth candidate): 3.4 us measured (``all`` on
#: 700x700: 5.0 s for 3 steps)
GPF_LOOK_S = 4e-6
#: per particle and step
GPF_PARTICLE_S = 1e-4


def condition_on_count_bound(w: np.ndarray, n_max: int) -> np.ndarray:
    """Existence probabilities of independent Bernoullis ``w (T,)`` conditioned on
    ``count <= n_max`` (the marginals of the conditioned law; exact):
    ``w_i' = w_i A_i / (w_i A_i + (1 - w_i) B_i)`` with ``A_i = P(C_-i <= n_max - 1)``,
    ``B_i = P(C_-i <= n_max)``, ``C_-i`` the count of the others (prefix and suffix
    Poisson-binomial tables, ``O(T n_max^2)``). Where the bound has probability 0 (more
    certain tracks than it allows) ``w`` is returned unchanged. With the compiled backend
    :func:`.step_kernels.count_bound` computes the same numbers."""
    T = len(w)
    if T <= n_max:
        return w.copy()
    if n_max <= 0:
        return np.zeros(T) if np.all(w < 1.0) else w.copy()
    kernels = compiled_gpf_kernels()
    if kernels is not None:
        return kernels.step_kernels.count_bound(np.ascontiguousarray(w, dtype=float),
                                                int(n_max))
    n = n_max + 1  # counts 0..n_max
    pre = np.zeros((T + 1, n))
    pre[0, 0] = 1.0
    for i in range(T):
        pre[i + 1] = pre[i] * (1.0 - w[i])
        pre[i + 1, 1:] += pre[i, :-1] * w[i]
    suf = np.zeros((T + 1, n))
    suf[T, 0] = 1.0
    for i in range(T - 1, -1, -1):
        suf[i] = suf[i + 1] * (1.0 - w[i])
        suf[i, 1:] += suf[i + 1, :-1] * w[i]
    cum = np.cumsum(suf[1:], axis=1)  # cum[i, b] = P(count of tracks after i <= b)
    a = pre[:T]  # a[i, j] = P(count of tracks before i = j)
    B = np.einsum("ij,ij->i", a, cum[:, ::-1])  # sum_j a_j P(after <= n_max - j)
    A = np.einsum("ij,ij->i", a[:, :-1], cum[:, -2::-1])  # <= n_max - 1 - j
    den = w * A + (1.0 - w) * B
    return np.where(den > 0.0, w * A / np.where(den > 0.0, den, 1.0), w)


@functools.lru_cache(maxsize=256)
def _upper_pairs(K: int) -> tuple[np.ndarray, np.ndarray]:
    """``np.triu_indices(K, 1)``, cached (the particle count repeats from step to step)."""
    iu, ju = np.triu_indices(K, 1)
    iu.flags.writeable = False
    ju.flags.writeable = False
    return iu, ju


#: ``ln det (S / 2) = ln det S - ln 16`` for a 4x4 ``S``
_LN16 = math.log(16.0)


def cholesky_forms(S: np.ndarray, d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per row of ``S (n, 4, 4)`` (symmetric positive definite; its lower triangle is read)
    and ``d (n, 4)``: ``d^T S^-1 d`` and ``ln det S``, by the Cholesky factor ``S = L L^T``
    written out: ``y = L^-1 d``, ``d^T S^-1 d = |y|^2``, ``ln det S = 2 sum_k ln L_kk``. A
    row that is not positive definite gets NaN (and is never merged). Elementwise over
    rows, so :func:`.step_kernels.pair_distances` performs the same operations pair by pair
    (a batched LAPACK solve costs more in its calls than in its arithmetic here)."""
    n = len(S)
    L = np.zeros((n, 4, 4))
    y = np.empty((n, 4))
    with np.errstate(divide="ignore", invalid="ignore"):
        for a in range(4):
            for b in range(a + 1):
                s = S[:, a, b]
                for k in range(b):
                    s = s - L[:, a, k] * L[:, b, k]
                L[:, a, b] = np.sqrt(s) if a == b else s / L[:, b, b]
        for a in range(4):
            s = d[:, a]
            for k in range(a):
                s = s - L[:, a, k] * y[:, k]
            y[:, a] = s / L[:, a, a]
        q = y[:, 0] * y[:, 0] + y[:, 1] * y[:, 1] + y[:, 2] * y[:, 2] + y[:, 3] * y[:, 3]
        logdet = 2.0 * (np.log(L[:, 0, 0]) + np.log(L[:, 1, 1]) + np.log(L[:, 2, 2])
                        + np.log(L[:, 3, 3]))
    return q, logdet


def _pair_distances(m: np.ndarray, P: np.ndarray, threshold: float,
                    metric: str = "mahalanobis", groups: np.ndarray | None = None
                    ) -> np.ndarray:
    """``d2 (K, K)``: ``(mu_i - mu_j)^T (Sigma_i + Sigma_j)^-1 (mu_i - mu_j)`` where it can be
    below ``threshold``, ``inf`` elsewhere (and on the diagonal). ``metric="bhattacharyya"``
    adds the shape term ``2 ln(det S_bar / sqrt(det Sigma_i det Sigma_j))``,
    ``S_bar = (Sigma_i + Sigma_j) / 2``: the sum is ``4 D_B``, four times the
    Bhattacharyya distance, equal to the Mahalanobis form for equal covariances and large
    when one Gaussian is much broader than the other (never negative).

    The position-only form is a lower bound of the full one (a marginal's quadratic form never
    exceeds the joint's, and the shape term is non-negative), so it screens the pairs in
    closed form (2x2 inverse) and the 4x4 form (:func:`cholesky_forms`) runs only on the
    pairs that pass. ``groups (K,)``: only pairs in the same group get a distance
    (components of one track). With the compiled backend :func:`.step_kernels.pair_distances`
    computes the same numbers.
    """
    K = len(m)
    bhattacharyya = metric == "bhattacharyya"
    kernels = compiled_gpf_kernels()
    if kernels is not None:
        return kernels.step_kernels.pair_distances(
            np.ascontiguousarray(m, dtype=float), np.ascontiguousarray(P, dtype=float),
            float(threshold), bhattacharyya, np.zeros(0, np.int64) if groups is None
            else np.ascontiguousarray(groups, dtype=np.int64), groups is not None)
    iu, ju = _upper_pairs(K)
    diff = m[iu] - m[ju]  # (n_pairs, 4)
    S = P[iu] + P[ju]
    a, b, c = S[:, 0, 0], S[:, 0, 2], S[:, 2, 2]
    dx, dy = diff[:, 0], diff[:, 2]
    det = a * c - b * b
    with np.errstate(divide="ignore", invalid="ignore"):
        lower = (c * dx * dx - 2.0 * b * dx * dy + a * dy * dy) / det
    cand = ~(lower >= threshold)  # NaN (degenerate) pairs go to the full form
    if groups is not None:
        cand &= groups[iu] == groups[ju]
    ci, cj = iu[cand], ju[cand]
    d2 = np.full((K, K), np.inf)
    if len(ci):
        full, ld_s = cholesky_forms(S[cand], diff[cand])
        if bhattacharyya:
            ld = cholesky_forms(P, np.zeros((K, 4)))[1]
            full = full + np.maximum(2.0 * (ld_s - _LN16) - ld[ci] - ld[cj], 0.0)
        d2[ci, cj] = full
        d2[cj, ci] = full
    return d2


def merge_particles(w: np.ndarray, m: np.ndarray, P: np.ndarray, threshold: float,
                    rule: str = "capped_sum", metric: str = "mahalanobis"
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Greedy Mahalanobis merging (module docstring); see :func:`merge_groups`."""
    out_w, mean, cov, _ = merge_groups(w, m, P, threshold, rule, metric)
    return out_w, mean, cov


def merge_groups(w: np.ndarray, m: np.ndarray, P: np.ndarray, threshold: float,
                 rule: str = "capped_sum", metric: str = "mahalanobis",
                 groups: np.ndarray | None = None
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Greedy Mahalanobis merging (module docstring). Shapes ``(K,)``, ``(K, 4)``, ``(K, 4, 4)``.

    Returns the merged ``w``, ``m``, ``P`` and ``label (K,)``, the merged Gaussian each
    input joined; ``groups``: only Gaussians of one group merge (the components of one
    track). A group's Gaussian is the ``w``-weighted moment
    match ``m = sum w_j m_j / sum w_j``, ``P = sum w_j (P_j + (m_j - m)(m_j - m)^T) / sum w_j``.
    Groups are formed from the heaviest remaining particle ``i`` (distances to the original
    ``mu_i``, ``Sigma_i``); with ``"bounded_sum"`` the particles within the threshold join in
    order of increasing distance, each only if the group's weight sum stays ``<= 1``.
    """
    if rule not in _MERGE_RULES:
        raise ValueError(f"rule must be one of {_MERGE_RULES}, got {rule!r}")
    K = len(w)
    if K <= 1 or threshold <= 0:
        return w, m, P, np.arange(K)
    order = np.argsort(-w, kind="stable")
    w, m, P = w[order], m[order], P[order]
    close = _pair_distances(m, P, threshold, metric,
                            None if groups is None else np.asarray(groups)[order])
    kernels = compiled_gpf_kernels()
    if kernels is not None:
        out_w, label, mean, cov = kernels.greedy_merge(
            np.ascontiguousarray(w, dtype=float), np.ascontiguousarray(m, dtype=float),
            np.ascontiguousarray(P, dtype=float), close, float(threshold),
            rule == "bounded_sum", _SUM_TOL)
        in_order = np.empty(K, dtype=np.int64)
        in_order[order] = label
        if len(out_w) == K:
            return out_w, m, P, in_order
        return out_w, mean, cov, in_order
    label = np.full(K, -1)
    out_w = []
    lonely = ~(close < threshold).any(axis=1)  # no partner: a group of its own
    for i in range(K):
        if label[i] >= 0:
            continue
        g = len(out_w)
        label[i] = g
        if lonely[i]:
            out_w.append(min(w[i], 1.0))
            continue
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
            out_w.append(min(1.0, wg.sum()))
    n_g = len(out_w)
    in_order = np.empty(K, dtype=np.int64)
    in_order[order] = label
    if n_g == K:
        return np.array(out_w), m, P, in_order
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
    return np.array(out_w), mean, cov, in_order


def group_heads(label: np.ndarray) -> np.ndarray:
    """``np.unique(label, return_index=True)[1]`` for :func:`merge_groups`' labels in its
    order (decreasing weight): it numbers the groups in the order their heads come, each
    head before its members, so a head is where the label exceeds every label before it
    (a boolean mask, in the same order)."""
    head = np.ones(len(label), dtype=bool)
    np.greater(label[1:], np.maximum.accumulate(label)[:-1], out=head[1:])
    return head


def truncate_to_workspace(m: np.ndarray, P: np.ndarray, width: float, height: float,
                          tol: float = 1e-9) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each Gaussian restricted to the workspace ``[0, width) x [0, height)`` and moment
    matched (mean and covariance of the truncated density, velocities by regression on
    position, :func:`.grid.rect_state_moments`). Returns ``mass (K,)`` (the Gaussian's
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


def collapse(w: np.ndarray, m: np.ndarray, P: np.ndarray, owner: np.ndarray, n: int
             ) -> tuple[np.ndarray, np.ndarray]:
    """Per group ``0..n-1`` of ``owner``, the moment match of its rows (weights ``w``,
    normalised within the group): ``means (n, 4)``, ``covs (n, 4, 4)``. With the compiled
    backend :func:`.step_kernels.collapse` computes the same numbers."""
    kernels = compiled_gpf_kernels()
    if kernels is not None:
        return kernels.step_kernels.collapse(
            np.ascontiguousarray(w, dtype=float), np.ascontiguousarray(m, dtype=float),
            np.ascontiguousarray(P, dtype=float), np.ascontiguousarray(owner, dtype=np.int64),
            int(n))
    tot = np.bincount(owner, weights=w, minlength=n)
    wn = w / np.where(tot > 0.0, tot, 1.0)[owner]
    mean = np.zeros((n, 4))
    np.add.at(mean, owner, wn[:, None] * m)
    dev = m - mean[owner]
    cov = np.zeros((n, 4, 4))
    np.add.at(cov, owner, wn[:, None, None] * (P + dev[:, :, None] * dev[:, None, :]))
    return mean, cov


@register
class GaussianParticleFilter(Tracker):
    """The paper's GPF; see the module docstring for the equations and every choice.

    Each parameter's doc says why a user would change it; the rules the model decides
    (the merged weight, the count bound, the field's recursion) and the numerical
    constants (``INTERACTION_THRESHOLD``, ``_COMPONENT_FLOOR``) are not parameters."""

    name = "gpf"
    summary = "Gaussian particle filter (paper): existence-weighted Gaussians, combinations E"
    parameters: ClassVar[dict[str, Param]] = {
        "epsilon": Param(float, 0, 1, high_open=True,
                         doc="combinations with posterior probability <= epsilon are cut "
                             "(the paper cuts on the prior): lower for more exact "
                             "weights at more cost"),
        "max_combinations": Param(int, 1, doc="at most this many combinations kept per "
                                              "cluster: bounds an update's cost in crowds"),
        "merge_threshold": Param(float, 0, doc="squared Mahalanobis distance below which "
                                               "tracks merge; 0: no merging. Lower keeps "
                                               "close targets apart, higher removes "
                                               "duplicate tracks",
                                 search=Search(1.0, 16.0, log=True)),
        "prune_threshold": Param(float, 0, 1, high_open=True,
                                 doc="drop tracks with w below it: higher is cheaper, "
                                     "lower keeps faint hypotheses"),
        "max_particles": Param(int, 1, doc="keep at most this many tracks (the heaviest): "
                                           "bounds time and memory"),
        "birth_floor": Param(float, 0, 1, doc="floor of the undetected-target field u (at "
                                              "start; every step with arrivals): how readily "
                                              "a detection starts a track",
                             search=Search(1e-6, 1e-2, log=True)),
        "extraction": Param(choices=("round_sum", "threshold"),
                            doc="which tracks are reported: the round(sum w) heaviest, or "
                                "those with w above extraction_threshold",
                            search=Search(choices=("round_sum", "threshold"))),
        "extraction_threshold": Param(float, 0, 1, doc="w above it is reported (threshold): "
                                                       "trades missed targets for false "
                                                       "tracks",
                                      search=Search(0.2, 0.8)),
        "n_counts": Param(int, 2, doc="count columns of P_c(t), the last 'n_counts - 1 or "
                                      "more': raise it for cells holding more targets"),
        "death_probability": Param(float, 0, 1, allow_none=True,
                                   none="DEFAULT_DEATH_FLOOR on the grid with births and "
                                        "arrivals, else 0",
                                   doc="per-step death floor: higher drops lost tracks "
                                       "sooner, at some count error",
                                   search=Search(1e-4, 0.05, log=True)),
        "max_components": Param(int, 1, doc="grid: Gaussians per track (a Bernoulli with a "
                                            "Gaussian-mixture density); 1: the paper's one, "
                                            "cheaper",
                                search=Search(1, 6)),
        "split_share": Param(float, 0, 1, high_open=True,
                             doc="grid: a detected cell's part of a track's posterior at "
                                 "least this large becomes a component of its own (lower: "
                                 "more components, more cost)",
                             search=Search(0.02, 0.5, log=True)),
    }
    budget: ClassVar[dict[str, Budget]] = {
        "max_components": Budget(1, 8, doc="Gaussians per track; split_share rarely "
                                           "fills more than 4 (equal runs at 4 and 16)"),
        "max_combinations": Budget(4, 512, doc="combinations per cluster; 512 is the "
                                               "default and bounds the crowds we run"),
    }
    #: the prior and the births (module docstring); False in :class:`EmptyPriorGPF`, a
    #: test hook (reductions, particles set by hand), not a parameter
    births: ClassVar[bool] = True
    def __init__(self, epsilon: float = 1e-4, max_combinations: int = 512,
                 merge_threshold: float = 4.0, prune_threshold: float = 1e-3,
                 max_particles: int = 100, birth_floor: float = 1e-4,
                 extraction: str = "round_sum", extraction_threshold: float = 0.5,
                 n_counts: int = 4, death_probability: float | None = None,
                 max_components: int = 4, split_share: float = 0.1) -> None:
        self.epsilon = epsilon
        self.max_combinations = max_combinations
        self.merge_threshold = merge_threshold
        self.prune_threshold = prune_threshold
        self.max_particles = max_particles
        self.birth_floor = birth_floor
        self.extraction = extraction
        self.extraction_threshold = extraction_threshold
        self.n_counts = n_counts
        self.death_probability = death_probability
        self.max_components = max_components
        self.split_share = split_share

    # ------------------------------------------------------------------ state
    # Tracks t = 0..T-1: existence w (T,). Gaussian rows r = 0..R-1: track own (R,),
    # weight a (R,) within the track (sums to 1 per track), mean m (R, 4), cov P (R, 4, 4).
    def reset(self, model: TrackingModel, rng: np.random.Generator) -> None:
        self.validate_params(self.get_params())  # the declaration above (built directly)
        # load the kernels now, not in a timed step (a compile goes on in the background)
        compiled_gpf_kernels(wait=GPF_WAIT_S)
        self._model = model
        self._rng = rng
        self._F, self._Q = model.dynamics.F, model.dynamics.Q
        self._grid = model.grid
        arrivals = model.birth_death.birth_rate > 0.0
        #: the merged weight rule (module docstring, "Merge")
        self._merge_rule = "capped_sum" if (arrivals and model.is_grid) else "bounded_sum"
        #: the count-aware field and count bound apply to models without arrivals
        self._count_bound = not arrivals
        floor = self.death_probability
        if floor is None:
            # no floor without arrivals: the count bound and the field hold lost targets
            floor = DEFAULT_DEATH_FLOOR if (self.births and model.is_grid and arrivals) else 0.0
        #: the survival probability the filter predicts with: min(p_s, 1 - floor)
        self._survival = min(model.birth_death.survival_probability, 1.0 - floor)
        #: a persistent id per track (the estimate's labels): a counter assigned at the
        #: track's creation, carried through prune and merge (a merged track keeps the
        #: id of its heaviest member)
        self._tid, self._next_tid = np.zeros(0, dtype=np.int64), 0
        self._set(np.zeros(0), np.zeros(0, dtype=np.int64), np.zeros(0), np.zeros((0, 4)),
                  np.zeros((0, 4, 4)))
        bd = model.birth_death
        n0 = bd.initial_count_mean
        n_cells = model.grid.n_cells
        #: the undetected-target field, one value per cell (stored sparsely)
        self._u = CellField(n_cells, 0.0)
        self._k = -1  # steps predicted so far, minus one
        if not self.births:
            return
        if model.is_grid:
            self._u = CellField(n_cells, max(min(n0 / n_cells, 0.5), self.birth_floor))
        elif n0 > 0:
            n = math.ceil(n0)
            self._add_broad(n, n0 / n)

    def _set(self, w: np.ndarray, own: np.ndarray, a: np.ndarray, m: np.ndarray,
             P: np.ndarray) -> None:
        if len(getattr(self, "_tid", ())) != len(w):  # tracks set from outside: new ids
            self._new_ids(len(w), fresh=True)
        self._w, self._own, self._a, self._m, self._P = w, own, a, m, P

    def set_particles(self, w: np.ndarray, m: np.ndarray, P: np.ndarray) -> None:
        """Replace the particle set (tests, warm starts): ``(K,)``, ``(K,4)``, ``(K,4,4)``,
        one Gaussian per track."""
        w = np.array(w, dtype=float).reshape(-1)
        self._set(w, np.arange(len(w)), np.ones(len(w)), np.array(m, dtype=float).reshape(-1, 4),
                  np.array(P, dtype=float).reshape(-1, 4, 4))

    @property
    def particles(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Copies of ``w (K,)``, ``means (K, 4)``, ``covs (K, 4, 4)`` per track (a track
        with several components as their moment match)."""
        m, P = self._collapsed()
        return self._w.copy(), m, P

    @property
    def components(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Copies of ``w (T,)`` and, per Gaussian row, ``track (R,)``, ``weight within the
        track (R,)``, ``means (R, 4)``, ``covs (R, 4, 4)``."""
        return (self._w.copy(), self._own.copy(), self._a.copy(), self._m.copy(),
                self._P.copy())

    def _collapsed(self) -> tuple[np.ndarray, np.ndarray]:
        if len(self._m) == len(self._w):  # one row per track, in track order
            return self._m.copy(), self._P.copy()
        return collapse(self._a, self._m, self._P, self._own, len(self._w))

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

    def _new_ids(self, n: int, fresh: bool = False) -> None:
        """Append ``n`` new track ids (``fresh``: replace all, for a new particle set)."""
        start = getattr(self, "_next_tid", 0)
        if n == 0 and not fresh and hasattr(self, "_next_tid"):
            return
        if fresh:
            self._tid = np.zeros(0, dtype=np.int64)
        self._tid = np.concatenate([self._tid, start + np.arange(n, dtype=np.int64)])
        self._next_tid = start + n

    def _append(self, w: np.ndarray, m: np.ndarray, P: np.ndarray) -> None:
        """New tracks, one Gaussian each."""
        T = len(self._w)
        self._new_ids(len(w))
        self._set(np.concatenate([self._w, w]),
                  np.concatenate([self._own, T + np.arange(len(w))]),
                  np.concatenate([self._a, np.ones(len(w))]),
                  np.concatenate([self._m, m]), np.concatenate([self._P, P]))

    def _weigh_rows(self, mass: np.ndarray) -> None:
        """Each row keeps the share ``mass (R,)`` of its probability: the track's existence
        is multiplied by ``sum_r a_r mass_r``, the rows' weights re-normalised."""
        kept = self._a * mass
        tot = np.bincount(self._own, weights=kept, minlength=len(self._w))
        self._w = self._w * np.minimum(tot, 1.0)
        self._a = np.where(tot[self._own] > 0.0,
                           kept / np.where(tot > 0.0, tot, 1.0)[self._own], self._a)

    # ---------------------------------------------------------------- predict
    def predict(self) -> None:
        bd = self._model.birth_death
        self._m, self._P = kalman.predict(self._m, self._P, self._F, self._Q)
        self._w = self._w * self._survival
        width, height = self._grid.extent
        kernels = compiled_gpf_kernels()
        if len(self._m) and bd.boundary == "reflect":
            # no probability outside: the mass beyond a wall is reflected back (the fold
            # returns copies when no row reaches a wall; the predicted arrays are new)
            if kernels is None or len(kernels.near_walls(
                    np.ascontiguousarray(self._m), np.ascontiguousarray(self._P),
                    RANGE_SIGMAS, float(width), float(height))):
                self._m, self._P = fold_into_workspace(self._m, self._P, self._grid)
        elif len(self._m):
            # the mass that left is death; what stays is the Gaussian inside
            mass, self._m, self._P = truncate_to_workspace(self._m, self._P, width, height)
            self._weigh_rows(mass)
        if not self.births:
            return
        n_cells = self._grid.n_cells
        if self._model.is_grid:
            b = bd.birth_rate / n_cells
            p_s = self._survival
            if kernels is not None:
                # the same maps and rejoins in one pass (step_kernels.field_predict)
                missing = self._missing() if self._count_bound else 0.0
                u = self._u
                u.default, u.cells, u.values = kernels.field_predict(
                    u.default, u.cells, u.values, p_s, b,
                    kernels.RESPREAD if self._count_bound else kernels.FLOOR,
                    float(self.birth_floor), missing, n_cells)
                return
            self._u.map(lambda u: 1.0 - (1.0 - p_s * u) * (1.0 - b))
            if self._count_bound:
                self._respread_missing()
            else:
                self._u.map(lambda u: np.maximum(u, self.birth_floor))
        elif bd.birth_rate > 0:
            self._add_broad(1, min(bd.birth_rate, 0.5))

    def _respread_missing(self) -> None:
        """Targets the model expects but no particle holds go back to the undetected
        field: when ``sum u`` is below ``m(k) - sum w`` (``m(k)`` the model's expected
        count at this step), ``u`` is scaled up to it, keeping its shape (uniform when it
        is empty), each cell at most 1/2, and above it down to it (no floor: no target can
        appear that the count does not leave). Used on models without arrivals only.
        Without it a fixed-count model's field decays to its floor under misses and a
        target a track lost can only be taken by that track (paper: the GPF held 1 of 3
        targets)."""
        missing = self._missing()
        total = self._u.total()
        if missing < total:  # no more undetected targets than the count leaves
            self._u.map(lambda u: u * (missing / total))
        elif total > 0:
            self._u.map(lambda u: np.minimum(missing * (u / total), 0.5))
        else:
            self._u = CellField(self._u.n_cells, min(missing * (1.0 / self._u.n_cells), 0.5))

    def _missing(self) -> float:
        """Advance the step count ``k`` and return ``max(m(k) - sum w, 0)``, the expected
        number of targets no track holds (:meth:`_respread_missing`); once per prediction."""
        bd = self._model.birth_death
        self._k += 1
        p_s, b = bd.survival_probability, bd.birth_rate
        keep = p_s ** self._k
        expected = bd.initial_count_mean * keep + (
            b * self._k if p_s == 1.0 else b * (1.0 - keep) / (1.0 - p_s))
        return max(expected - float(self._w.sum()), 0.0)

    # ------------------------------------------------------- count distribution
    def cell_count_distribution(self) -> CellCounts:
        """Per cell, the Poisson-binomial of the tracks' Bernoullis (``w_t`` times the
        track's mass in the cell, within 6 sd of each Gaussian, ``cells.BOX_SD``: the mass
        beyond, below 1e-9, is left out) and the field's ``u_c``; cells no track reaches
        share the row of the field's common value. ``O(tracks' boxes + field cells)``, not
        ``O(cells)``."""
        n_cells = self._grid.n_cells
        row, cell, mass = gaussian_cell_mass_sparse(
            self._grid, *kalman.position_marginal(self._m, self._P))
        # a track's mass in a cell: its components' sum (in row order), times its existence;
        # listed by track, so each cell adds its tracks' Bernoullis in track order
        key, inv = np.unique(self._own[row] * n_cells + cell, return_inverse=True)
        p = np.bincount(inv.reshape(-1), weights=self._a[row] * mass, minlength=len(key))
        p = self._w[key // n_cells] * p
        # the field's Bernoulli comes last in each cell, as it did in the dense form
        return bernoulli_cell_counts(n_cells, self.n_counts, key % n_cells, p,
                                     last_default=self._u.default, last_cells=self._u.cells,
                                     last_probs=self._u.values)

    def undetected_intensity(self) -> CellField:
        """The undetected field ``u`` (a copy): per cell the probability, hence the
        expected number, of a target no track holds (all zero without births)."""
        return self._u.copy()

    # ----------------------------------------------------------------- update
    def update(self, looks: Looks) -> None:
        sensor = self._model.sensor
        pruned = False  # by the compiled grid update's last pass
        if isinstance(sensor, RayleighGridSensor):
            if len(looks):
                pruned = self._update_grid(looks, sensor)
        elif looks.z is not None:  # one Gaussian per track on this sensor
            res = superposition_update(self._w, self._m, self._P, np.asarray(looks.z, float),
                                       sensor.H, sensor.R, self.epsilon, self.max_combinations)
            self.set_particles(res.weights, res.means, res.covs)
        self._merge_and_prune(pruned)
        if self._count_bound and len(self._w):
            # no arrivals: never more targets than the model started with
            n0 = int(round(self._model.birth_death.initial_count_mean))
            self._w = condition_on_count_bound(self._w, n0)

    def _update_grid(self, looks: Looks, sensor: RayleighGridSensor) -> bool:
        """The grid update with its birth candidates; True when it also pruned the
        tracks (the compiled form; the numpy form leaves that to the merge's prune)."""
        kernels = compiled_gpf_kernels()
        if kernels is None:
            self._update_grid_numpy(looks, sensor)
            return False
        T = len(self._w)
        look_cells = np.ascontiguousarray(looks.cells, dtype=np.int64)
        field = self._u
        cand, u_cand, w, own, alpha, m, P, ucell = kernels.candidates(
            look_cells, self.births, field.default, field.cells, field.values,
            self._w, self._own, self._a, self._m, self._P,
            float(self._grid.cell_size), self._grid.nx,
            float(self._model.birth_death.birth_velocity_std ** 2))
        res = grid_update(w, m, P, ucell, looks.cells, looks.returns, self._grid, sensor,
                          self.epsilon, self.max_combinations, INTERACTION_THRESHOLD,
                          owner=own, alpha=alpha,
                          split_share=self.split_share if self.max_components > 1 else 0.0)
        # the promoted candidates, the field's set (then the floor with births and
        # arrivals), their ids, and the merge's prune, in one pass
        n_new, field.default, field.cells, field.values, w, own, a, m, P, tid = (
            kernels.keep_and_prune(
                res.weights, res.owner, res.alpha, res.means, res.covs, T, cand, look_cells,
                np.ascontiguousarray(looks.returns, dtype=bool), float(self.prune_threshold),
                self._tid, self._next_tid, field.default, field.cells, field.values,
                float(self.birth_floor), self.births and not self._count_bound))
        self._tid, self._next_tid = tid, self._next_tid + n_new
        self._set(w, own, a, m, P)
        return True

    def _update_grid_numpy(self, looks: Looks, sensor: RayleighGridSensor) -> None:
        """:meth:`_update_grid` in numpy (the reference of its compiled form)."""
        T, R = len(self._w), len(self._m)
        looked = np.unique(looks.cells)
        cand = looked[self._u.at(looked) > 0.0] if self.births else looked[:0]
        n_c = len(cand)
        s = self._grid.cell_size
        cm = kalman.at_rest(self._grid.cell_centers(cand))
        vs = self._model.birth_death.birth_velocity_std ** 2
        cP = np.repeat(np.diag([s * s / 12.0, vs, s * s / 12.0, vs])[None], n_c, axis=0)
        w = np.concatenate([self._w, self._u.at(cand)])
        m = np.concatenate([self._m, cm])
        P = np.concatenate([self._P, cP])
        own = np.concatenate([self._own, T + np.arange(n_c)])
        alpha = np.concatenate([self._a, np.ones(n_c)])
        ucell = np.concatenate([np.full(R, -1, dtype=np.int64), cand])
        res = grid_update(w, m, P, ucell, looks.cells, looks.returns, self._grid, sensor,
                          self.epsilon, self.max_combinations, INTERACTION_THRESHOLD,
                          owner=own, alpha=alpha,
                          split_share=self.split_share if self.max_components > 1 else 0.0)
        wc = res.weights[T:]
        detected = np.isin(cand, looks.cells[looks.returns])
        promote = detected & (wc > self.prune_threshold)
        self._u.set(cand, np.where(promote, 0.0, wc))
        if self.births and not self._count_bound:
            self._u.map(lambda u: np.maximum(u, self.birth_floor))
        keep_track = np.concatenate([np.ones(T, dtype=bool), promote])
        self._new_ids(int(promote.sum()))
        new_index = np.cumsum(keep_track) - 1
        keep_row = keep_track[res.owner]
        self._set(res.weights[keep_track], new_index[res.owner[keep_row]],
                  res.alpha[keep_row], res.means[keep_row], res.covs[keep_row])

    def _merge_and_prune(self, pruned: bool = False) -> None:
        """Prune tracks (unless ``pruned`` already), merge tracks (on their moment-matched
        Gaussians; the merged track keeps every member's components), then reduce each
        track's mixture: merge its components by the same rule, drop those below
        ``_COMPONENT_FLOOR``, and beyond ``max_components`` moment-match the lightest into
        one."""
        kernels = compiled_gpf_kernels()
        if pruned:
            w, own, a, m, P, tid = self._w, self._own, self._a, self._m, self._P, self._tid
        elif kernels is not None:
            w, own, a, m, P, tid = kernels.prune_tracks(
                self._w, self._own, self._a, self._m, self._P, self._tid,
                float(self.prune_threshold))
        else:
            alive = self._w >= self.prune_threshold
            rows = alive[self._own]
            idx = np.cumsum(alive) - 1
            w, own, a = self._w[alive], idx[self._own[rows]], self._a[rows]
            m, P = self._m[rows], self._P[rows]
            tid = self._tid[alive]
        T = len(w)
        if T > 1 and self.merge_threshold > 0:
            one_each = len(m) == T  # one Gaussian per track, in any order
            cm, cP = (m, P) if one_each else collapse(a, m, P, own, T)
            # the screen does not depend on the order of the Gaussians; the merge does
            if kernels is None or kernels.any_close(cm, cP, float(self.merge_threshold)):
                if one_each:
                    by_track = np.argsort(own)
                    cm, cP = m[by_track], P[by_track]
                mw, _, _, label = merge_groups(w, cm, cP, self.merge_threshold,
                                               self._merge_rule, "mahalanobis")
            else:  # no pair passes the merge's screen: the merge would change nothing
                mw = w
            if len(mw) < T:
                # each merged track keeps the id of its heaviest member
                by_weight = np.argsort(-w, kind="stable")
                tid = tid[by_weight][group_heads(label[by_weight])]
                share = w / np.bincount(label, weights=w, minlength=len(mw))[label]
                a = a * np.where(np.isnan(share), 0.0, share)[own]  # 0 / 0: a group of 0
                own = label[own]
                tot = np.bincount(own, weights=a, minlength=len(mw))
                a = np.where(tot[own] > 0.0, a / np.where(tot > 0.0, tot, 1.0)[own],
                             1.0 / np.bincount(own, minlength=len(mw))[own])
                w, T = mw, len(mw)
        if len(m) > T:
            own, a, m, P = self._reduce_components(own, a, m, P, T)
        if T > self.max_particles:
            top = np.zeros(T, dtype=bool)
            top[np.argsort(-w, kind="stable")[: self.max_particles]] = True
            idx = np.cumsum(top) - 1
            rows = top[own]
            w, own, a, m, P = w[top], idx[own[rows]], a[rows], m[rows], P[rows]
            tid = tid[top]
        self._tid = tid
        if kernels is not None:
            self._set(w, *kernels.rows_by_track(
                *(np.ascontiguousarray(x) for x in (own, a, m, P))))
            return
        order = np.argsort(own, kind="stable")
        self._set(w, own[order], a[order], m[order], P[order])

    def _reduce_components(self, own: np.ndarray, a: np.ndarray, m: np.ndarray, P: np.ndarray,
                           T: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        if self.max_components == 1:  # the paper's one Gaussian: the moment match
            mean, cov = collapse(a, m, P, own, T)
            return np.arange(T), np.ones(T), mean, cov
        kernels = compiled_gpf_kernels()
        if kernels is not None:  # the same operations in one compiled pass
            return kernels.reduce_components(
                *(np.ascontiguousarray(x) for x in (own, a, m, P)), T, self.max_components,
                float(self.merge_threshold), _COMPONENT_FLOOR, _SUM_TOL)
        keep = a >= _COMPONENT_FLOOR
        # a track keeps its heaviest row even when all are below the floor
        best = np.zeros(len(a), dtype=bool)
        order = np.lexsort((-a, own))
        first = np.ones(len(order), dtype=bool)
        first[1:] = own[order[1:]] != own[order[:-1]]
        best[order[first]] = True
        keep |= best
        own, a, m, P = own[keep], a[keep], m[keep], P[keep]
        if self.merge_threshold > 0:
            # Bhattacharyya always: a cell's narrow component must not fold back into
            # the broad rest of its track, which Mahalanobis distances would allow
            a, m, P, label = merge_groups(a, m, P, self.merge_threshold, "capped_sum",
                                          "bhattacharyya", groups=own)
            merged_own = np.empty(len(a), dtype=np.int64)
            merged_own[label] = own
            own = merged_own
        # beyond max_components: the lightest of a track are moment-matched into one
        order = np.lexsort((-a, own))
        own, a, m, P = own[order], a[order], m[order], P[order]
        start = np.searchsorted(own, own)
        rank = np.arange(len(own)) - start
        excess = rank >= self.max_components - 1
        n_rows = np.bincount(own, minlength=T)
        excess &= n_rows[own] > self.max_components
        if excess.any():
            g = np.where(excess, self.max_components - 1, rank)
            key = own * self.max_components + g
            uk, grp, _ = sorted_runs(key)  # sorted: by track, then rank capped
            wsum = np.bincount(grp, weights=a)
            mean, cov = collapse(a, m, P, grp, len(uk))
            own, a, m, P = uk // self.max_components, wsum, mean, cov
        tot = np.bincount(own, weights=a, minlength=T)[own]
        # a track whose weights all vanished (underflow) keeps its rows at weight 1
        return own, np.where(tot > 0.0, a / np.where(tot > 0.0, tot, 1.0), 1.0), m, P

    # --------------------------------------------------------------- estimate
    def estimate(self) -> Estimate:
        count = float(self._w.sum())
        if self.extraction == "round_sum":
            n = min(int(round(count)), len(self._w))
            kernels = compiled_gpf_kernels()
            if kernels is not None and len(self._m) == len(self._w):
                return Estimate(count, *kernels.heaviest(
                    self._w, n, self._m, self._P, self._tid))
            sel = np.argsort(-self._w, kind="stable")[:n]
        else:
            sel = np.nonzero(self._w > self.extraction_threshold)[0]
        if len(self._m) == len(self._w):  # (indexing by an index array copies)
            return Estimate(count, self._m[sel], self._P[sel], self._tid[sel])
        # the peak height of each component, a / sqrt(det Sigma_pos)
        P = self._P
        det = P[:, 0, 0] * P[:, 2, 2] - P[:, 0, 2] * P[:, 2, 0]  # of the position block
        score = self._a / np.sqrt(np.maximum(det, 1e-300))
        rows = self._distinct_modes(sel, score)
        return Estimate(count, self._m[rows].copy(), self._P[rows].copy(),
                        self._tid[self._own[rows]].copy())

    def _distinct_modes(self, sel: np.ndarray, score: np.ndarray) -> np.ndarray:
        """One row per selected track (heaviest track first): its best-scoring component
        whose mean is at least a cell from the states already reported, else its best.
        Tracks that share a detection each hold a component on it; reporting it once and
        each other track's next component avoids stacking estimates on one cell. With the
        compiled backend :func:`.step_kernels.distinct_modes` picks the same rows."""
        kernels = compiled_gpf_kernels()
        if kernels is not None:
            return kernels.step_kernels.distinct_modes(
                np.ascontiguousarray(sel, dtype=np.int64), np.ascontiguousarray(score),
                np.ascontiguousarray(self._own, dtype=np.int64),
                np.ascontiguousarray(self._m, dtype=float), len(self._w),
                float(self._grid.cell_size ** 2))
        order = np.lexsort((-score, self._own))  # each track's rows, best first
        start = np.searchsorted(self._own[order], np.arange(len(self._w) + 1))
        chosen: list[int] = []
        min_d2 = self._grid.cell_size ** 2
        for t in sel:
            rows = order[start[t]:start[t + 1]]
            pick = rows[0]
            if chosen and len(rows) > 1:
                taken = self._m[chosen][:, 0::2]
                d2 = ((self._m[rows][:, None, 0::2] - taken[None]) ** 2).sum(-1).min(axis=1)
                free = np.nonzero(d2 >= min_d2)[0]
                if len(free):
                    pick = rows[free[0]]
            chosen.append(int(pick))
        return np.array(chosen, dtype=np.int64)

    @classmethod
    def resource_terms(cls, params, model, looks_per_step, targets) -> ResourceTerms:
        """``G = max_particles * max_components`` Gaussians and the combinations; on the
        grid the update's (Gaussian, looked cell) pairs in the boxes of ``min(G, 2 T +
        16)`` Gaussians, a birth candidate per looked cell and the undetected field of the
        cells looked at so far; ``P_c(t)`` from those Gaussians' boxes, ``n_counts``
        columns."""
        particles = param_number(params, "max_particles", 100)
        gaussians = particles * max(1.0, param_number(params, "max_components", 1))
        present = min(gaussian_boxes(targets), gaussians)  # Gaussians at once
        pairs = present * min(float(BOX_CELLS), looks_per_step)
        return ResourceTerms(
            state_bytes=(gaussians * GPF_GAUSSIAN_BYTES
                         + param_number(params, "max_combinations", 512) * particles * 32.0),
            update_bytes=pairs * PAIR_BYTES, look_bytes=GPF_LOOK_BYTES,
            looked_cell_bytes=LOOKED_CELL_BYTES,
            step_seconds=particles * GPF_PARTICLE_S, target_seconds=TARGET_S,
            update_seconds=pairs * PAIR_S, look_seconds=GPF_LOOK_S,
            looked_cell_seconds=LOOKED_CELL_S,
            prediction_entries=present * BOX_CELLS,
            prediction_counts=max(2.0, param_number(params, "n_counts", 4)))


class EmptyPriorGPF(GaussianParticleFilter):
    """The GPF without its prior and without births (not registered, not listed): a test
    hook for the reductions and for particles set by hand (``set_particles``). Its death
    floor defaults to 0 (``death_probability=None`` means the floor only with births and
    arrivals)."""

    births = False
